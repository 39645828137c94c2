"""Quaternion math against scipy's Rotation (an independent implementation), on numpy and torch.

scipy is scalar-last (x, y, z, w); we are scalar-first. Convert only here, at the edge.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from scipy.spatial.transform import Rotation

from tepinn_flight import quat as Q

finite = st.floats(-1.0, 1.0, allow_nan=False, allow_infinity=False)


def to_scipy(q_wxyz: np.ndarray) -> Rotation:
    return Rotation.from_quat(np.asarray(q_wxyz)[..., [1, 2, 3, 0]])


def from_scipy(r: Rotation) -> np.ndarray:
    return r.as_quat()[..., [3, 0, 1, 2]]


def same_rotation(p, q, atol=1e-9):
    """q ≡ -q: compare up to sign."""
    p, q = np.asarray(p), np.asarray(q)
    return np.all(np.minimum(np.abs(p - q).max(-1), np.abs(p + q).max(-1)) < atol)


@st.composite
def unit_quats(draw, n=8):
    """Uniform-ish, near-identity (×1e-7) and near-π rotations, both signs."""
    kind = draw(st.sampled_from(["general", "near_identity", "near_pi"]))
    raw = draw(arrays(np.float64, (n, 4), elements=finite))
    raw[np.linalg.norm(raw, axis=1) < 1e-3] = [1.0, 0.2, -0.1, 0.3]
    q = raw / np.linalg.norm(raw, axis=1, keepdims=True)
    if kind == "near_identity":
        r = raw[:, 1:] * 1e-7
        q = Q.quat_from_rotvec(r)
    elif kind == "near_pi":
        axis = raw[:, 1:] / np.maximum(np.linalg.norm(raw[:, 1:], axis=1, keepdims=True), 1e-3)
        axis[np.linalg.norm(axis, axis=1) < 0.5] = [0.0, 0.0, 1.0]
        axis /= np.linalg.norm(axis, axis=1, keepdims=True)
        angle = np.pi - np.abs(raw[:, :1]) * 1e-6
        q = Q.quat_from_rotvec(axis * angle)
    sign = draw(st.sampled_from([1.0, -1.0]))
    return sign * q


@settings(max_examples=60, deadline=None)
@given(unit_quats(), unit_quats())
def test_composition_matches_scipy(p, q):
    got = Q.quat_mul(p, q)
    want = from_scipy(to_scipy(p) * to_scipy(q))
    assert same_rotation(got, want, 1e-12)


@settings(max_examples=60, deadline=None)
@given(unit_quats(), arrays(np.float64, (8, 3), elements=st.floats(-10, 10)))
def test_rotate_and_matrix_match_scipy(q, v):
    np.testing.assert_allclose(Q.quat_rotate(q, v), to_scipy(q).apply(v), atol=1e-12)
    np.testing.assert_allclose(Q.quat_to_rotmat(q), to_scipy(q).as_matrix(), atol=1e-12)


@settings(max_examples=60, deadline=None)
@given(unit_quats())
def test_round_trips(q):
    assert same_rotation(Q.rotmat_to_quat(Q.quat_to_rotmat(q)), q, 1e-9)
    assert same_rotation(Q.quat_from_rotvec(Q.quat_to_rotvec(q)), q, 1e-9)
    r, p, y = Q.quat_to_euler_zyx(q)
    assert same_rotation(Q.quat_from_euler_zyx(r, p, y), q, 1e-6)  # gimbal lock costs digits
    # rotation vectors agree with scipy (both canonical, angle in [0, π]) away from exactly π
    rv = Q.quat_to_rotvec(q)
    ang = np.linalg.norm(rv, axis=1)
    ok = ang < np.pi - 1e-3
    np.testing.assert_allclose(rv[ok], to_scipy(q[ok]).as_rotvec(), atol=1e-9)


@settings(max_examples=60, deadline=None)
@given(unit_quats())
def test_double_cover(q):
    """q and -q: same matrix, same vector rotation, angle between them is 0."""
    np.testing.assert_allclose(Q.quat_to_rotmat(q), Q.quat_to_rotmat(-q), atol=1e-14)
    np.testing.assert_allclose(Q.quat_angle_between(q, -q), 0.0, atol=1e-7)
    c = Q.quat_canonical(-q)
    assert np.all(c[:, 0] >= 0)
    assert same_rotation(c, q)


@settings(max_examples=40, deadline=None)
@given(unit_quats(), unit_quats())
def test_angle_between_matches_scipy(p, q):
    want = (to_scipy(p) * to_scipy(q).inv()).magnitude()
    np.testing.assert_allclose(Q.quat_angle_between(p, q), want, atol=1e-7)


def test_euler_zyx_matches_scipy_intrinsic_ZYX():
    rng = np.random.default_rng(1)
    rpy = rng.uniform([-np.pi, -1.5, -np.pi], [np.pi, 1.5, np.pi], size=(500, 3))
    q = Q.quat_from_euler_zyx(rpy[:, 0], rpy[:, 1], rpy[:, 2])
    want = Rotation.from_euler("ZYX", rpy[:, ::-1])  # yaw, pitch, roll intrinsic
    assert same_rotation(q, from_scipy(want), 1e-12)
    r, p, y = Q.quat_to_euler_zyx(q)
    np.testing.assert_allclose(np.stack([r, p, y], 1), rpy, atol=1e-9)


def test_gravity_body_closed_form():
    # level: down is +z; rolled 90° right (right wing down): down is +y in body
    np.testing.assert_allclose(Q.gravity_body(np.array([1.0, 0, 0, 0])), [0, 0, 1], atol=1e-15)
    q = Q.quat_from_euler_zyx(np.pi / 2, 0.0, 0.0)
    np.testing.assert_allclose(Q.gravity_body(q), [0, 1, 0], atol=1e-15)
    # pitched 90° nose up: down is -x in body
    q = Q.quat_from_euler_zyx(0.0, np.pi / 2, 0.3)
    np.testing.assert_allclose(Q.gravity_body(q), [-1, 0, 0], atol=1e-12)


def test_inclination_heading_split_closed_form():
    # pure heading error of 30°, pure tilt of 10°, and a combination with a known split
    qz = Q.quat_about_z(np.radians(30.0))
    inc, hdg = Q.inclination_heading_split(qz)
    assert abs(np.degrees(inc)) < 1e-9 and abs(np.degrees(hdg) - 30) < 1e-9
    qx = Q.quat_from_rotvec(np.array([np.radians(10.0), 0, 0]))
    inc, hdg = Q.inclination_heading_split(qx)
    assert abs(np.degrees(inc) - 10) < 1e-9 and abs(np.degrees(hdg)) < 1e-9
    inc, hdg = Q.inclination_heading_split(Q.quat_mul(qz, qx))  # heading after tilt, earth frame
    assert abs(np.degrees(inc) - 10) < 1e-9 and abs(np.degrees(hdg) - 30) < 1e-9


def test_slerp_against_scipy():
    from scipy.spatial.transform import Slerp

    rng = np.random.default_rng(2)
    tk = np.cumsum(rng.uniform(0.01, 0.1, 20))
    qk = Q.quat_normalize(rng.normal(size=(20, 4)))
    tq = rng.uniform(tk[0], tk[-1], 300)
    got = Q.slerp(tq, tk, qk)
    # scipy's Slerp also takes the short path between consecutive knots
    want = from_scipy(Slerp(tk, to_scipy(qk))(tq))
    assert same_rotation(got, want, 1e-9)
    out = Q.slerp(np.array([tk[0] - 1, tk[-1] + 1]), tk, qk)
    assert np.all(np.isnan(out))


def test_body_rates_from_quats_constant_rate():
    w = np.array([0.3, -1.2, 2.0])
    t = np.arange(0, 1, 0.01)
    q = Q.quat_from_rotvec(t[:, None] * w)  # constant body rate from identity
    rates = Q.body_rates_from_quats(q, np.diff(t))
    np.testing.assert_allclose(rates, np.tile(w, (len(t) - 1, 1)), atol=1e-9)


# ---------------------------------------------------------------- torch: same results, gradients


@pytest.mark.parametrize("fn", ["quat_mul", "quat_rotate", "quat_to_rotmat", "quat_log", "quat_from_rotvec"])
def test_torch_matches_numpy(fn):
    rng = np.random.default_rng(3)
    q = Q.quat_normalize(rng.normal(size=(50, 4)))
    p = Q.quat_normalize(rng.normal(size=(50, 4)))
    v = rng.normal(size=(50, 3))
    args = {
        "quat_mul": (p, q),
        "quat_rotate": (q, v),
        "quat_to_rotmat": (q,),
        "quat_log": (q,),
        "quat_from_rotvec": (v,),
    }[fn]
    want = getattr(Q, fn)(*args)
    got = getattr(Q, fn)(*[torch.tensor(a) for a in args])
    assert isinstance(got, torch.Tensor)
    np.testing.assert_allclose(got.numpy(), want, atol=1e-12)


@pytest.mark.parametrize(
    "q",
    [
        [1.0, 0.0, 0.0, 0.0],  # angle 0
        [-1.0, 0.0, 0.0, 0.0],
        [0.0, 1.0, 0.0, 0.0],  # angle π
        [1e-9, 0.0, 0.6, 0.8],  # just below π
        [np.cos(1e-6), np.sin(1e-6), 0.0, 0.0],  # near identity (Taylor branch)
    ],
)
def test_log_gradients_finite_at_0_and_pi(q):
    qt = torch.tensor(q, dtype=torch.float64, requires_grad=True)
    Q.quat_log(qt).sum().backward()
    assert torch.all(torch.isfinite(qt.grad))
    assert torch.autograd.gradcheck(lambda x: Q.quat_log(x), (qt.detach().clone().requires_grad_(),))


@pytest.mark.parametrize("r", [[0.0, 0.0, 0.0], [1e-8, 0.0, 0.0], [0.0, np.pi, 0.0], [0.5, -0.3, 2.0]])
def test_exp_gradients_finite_and_correct(r):
    rt = torch.tensor(r, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(Q.quat_from_rotvec, (rt,))
    Q.quat_from_rotvec(rt).sum().backward()
    assert torch.all(torch.isfinite(rt.grad))


def test_exp_log_jacobian_matches_finite_difference_near_pi():
    """Central differences, independent of autograd, at an angle just below π."""
    r0 = np.array([0.0, 0.0, np.pi - 1e-3])
    h = 1e-6
    jac = np.stack([(Q.quat_from_rotvec(r0 + h * e) - Q.quat_from_rotvec(r0 - h * e)) / (2 * h) for e in np.eye(3)], 1)
    rt = torch.tensor(r0, requires_grad=True)
    ja = torch.autograd.functional.jacobian(Q.quat_from_rotvec, rt).numpy()
    np.testing.assert_allclose(ja, jac, atol=1e-6)


@pytest.mark.parametrize("pitch", [np.pi / 2, -np.pi / 2])
def test_euler_at_gimbal_lock_keeps_the_rotation(pitch):
    """At pitch ±90° only roll ∓ yaw is defined; the round trip must still give the same rotation
    (scipy as the reference) with yaw reported as 0 and roll in (−π, π]."""
    rng = np.random.default_rng(1)
    roll, yaw = rng.uniform(-np.pi, np.pi, (2, 50))
    q = Q.quat_from_euler_zyx(roll, np.full(50, pitch), yaw)
    r, p, y = Q.quat_to_euler_zyx(q)
    assert np.all(y == 0) and np.all(np.abs(r) <= np.pi)
    ref = Rotation.from_euler("ZYX", np.stack([yaw, np.full(50, pitch), roll], 1)).as_quat()[:, [3, 0, 1, 2]]
    np.testing.assert_allclose(Q.quat_canonical(Q.quat_from_euler_zyx(r, p, y)), Q.quat_canonical(ref), atol=1e-7)


def test_scalar_euler_is_the_array_formula_bit_for_bit():
    """quat_from_euler_zyx_f (math, per step) and quat_from_euler_zyx (numpy) share one formula:
    equal to the last bit where math and numpy agree on cos/sin, and equal to scipy's ZYX."""
    import math

    from scipy.spatial.transform import Rotation

    from tepinn_flight.quat import quat_from_euler_zyx, quat_from_euler_zyx_f

    rng = np.random.default_rng(7)
    for roll, pitch, yaw in rng.uniform(-3.0, 3.0, (50, 3)):
        q = np.array(quat_from_euler_zyx_f(roll, pitch, yaw))
        half = [0.5 * roll, 0.5 * pitch, 0.5 * yaw]
        if all(np.cos(h) == math.cos(h) and np.sin(h) == math.sin(h) for h in half):
            assert np.array_equal(q, quat_from_euler_zyx(roll, pitch, yaw))
        ref = Rotation.from_euler("ZYX", [yaw, pitch, roll]).as_quat()[[3, 0, 1, 2]]
        np.testing.assert_allclose(q * np.sign(q[0] * ref[0]), ref, atol=1e-12)
