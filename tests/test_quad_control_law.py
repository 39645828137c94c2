"""The multirotor controller's compiled laws against independent references: scipy rotations for the
quaternion formulas, the vehicle's geometry for the mixer, the PI + damping law in closed form."""

from __future__ import annotations

import math

import numpy as np
import pytest

from tepinn_flight.quat_scalar import rotmat_to_quat
from tepinn_flight.sim import quad_control_law as law
from tepinn_flight.sim.multirotor import AGILE_QUAD, F450, _mixer_inverse

Rotation = pytest.importorskip("scipy.spatial.transform").Rotation


def _params(p, dt_s=0.005):
    return law.pack_params(p, dt_s, 10.0, 6.0, 4.0, _mixer_inverse(p))


def _allocation(p) -> np.ndarray:
    """[T, L, M, N] = A @ thrusts, written from the geometry: thrust along -z at (x, y) in FRD gives
    roll torque -y*f, pitch torque x*f; each motor's reaction torque is sense * arm * f."""
    return np.array([[1.0] * 4, [-y for _, y in p.motor_xy_m], [x for x, _ in p.motor_xy_m],
                     [s * p.yaw_arm_m for s in p.yaw_sense]])  # fmt: skip


def _thrusts(p, cmds) -> np.ndarray:
    return p.thrust_max_n * np.asarray(cmds) ** p.cmd_exponent


def _same_rotation(q_wxyz, r: Rotation, atol=1e-12):
    q = np.asarray(q_wxyz)
    ref = r.as_quat()[[3, 0, 1, 2]]
    assert abs(abs(float(np.dot(q, ref))) - 1.0) < atol, (q, ref)


def test_rotmat_to_quat_matches_scipy_on_every_branch():
    rots = list(Rotation.random(200, random_state=1))
    # half turns about x, y, z and about a diagonal: trace -1, each diagonal term the largest once
    rots += [Rotation.from_rotvec(math.pi * np.array(a) / np.linalg.norm(a))
             for a in ([1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 0], [0, 1, 1], [1, 0, 1])]  # fmt: skip
    for r in rots:
        q = rotmat_to_quat(*r.as_matrix().ravel())
        assert abs(np.linalg.norm(q) - 1.0) < 1e-12
        _same_rotation(q, r)


@pytest.mark.parametrize("yaw", [0.0, 1.0, -2.5, 3.1])
def test_attitude_from_thrust_points_body_up_along_thrust_facing_the_heading(yaw):
    rng = np.random.default_rng(3)
    for _ in range(50):
        t = rng.normal(size=3)
        t[2] = -abs(t[2]) - 0.2  # thrust upwards (NED z < 0), tilted less than 90 deg
        q = law.attitude_from_thrust(t[0], t[1], t[2], yaw)
        r = Rotation.from_quat([q[1], q[2], q[3], q[0]])  # body FRD -> NED
        np.testing.assert_allclose(r.apply([0.0, 0.0, -1.0]), t / np.linalg.norm(t), atol=1e-12)
        # heading: the horizontal direction yaw lies in the body x-z plane, ahead of the nose
        c = np.array([math.cos(yaw), math.sin(yaw), 0.0])
        assert abs(np.dot(r.apply([0.0, 1.0, 0.0]), c)) < 1e-12
        assert np.dot(r.apply([1.0, 0.0, 0.0]), c) > 0.0


@pytest.mark.parametrize("p", [F450, AGILE_QUAD], ids=["F450", "agile_quad"])
def test_mixer_realises_collective_and_torques_when_not_saturated(p):
    par = _params(p)
    rng = np.random.default_rng(7)
    a = _allocation(p)
    for _ in range(100):
        want = np.array([rng.uniform(0.3, 0.6) * 4 * p.thrust_max_n, *rng.uniform(-0.05, 0.05, 2),
                         rng.uniform(-0.01, 0.01)])  # fmt: skip
        cmds = law.mix(par, *want)
        assert all(0.0 < c < 1.0 for c in cmds)
        np.testing.assert_allclose(a @ _thrusts(p, cmds), want, rtol=0, atol=1e-9)


def test_mixer_keeps_roll_and_pitch_and_gives_up_yaw_first():
    p = F450
    par = _params(p)
    a = _allocation(p)
    want = np.array([2.0 * p.thrust_max_n, 0.3, -0.2, 5.0])  # far more yaw than the motors can give
    cmds = law.mix(par, *want)
    assert all(0.0 <= c <= 1.0 for c in cmds)
    got = a @ _thrusts(p, cmds)
    np.testing.assert_allclose(got[:3], want[:3], atol=1e-9)
    assert 0.0 < got[3] < want[3]
    # roll/pitch beyond the motors' range: commands stay within [0, 1], the torque keeps its sign
    cmds = law.mix(par, 2.0 * p.thrust_max_n, 50.0, 0.0, 0.0)
    assert all(0.0 <= c <= 1.0 for c in cmds)
    assert (a @ _thrusts(p, cmds))[1] > 0.0


def test_rate_step_is_the_pi_law_with_damping_and_returns_the_attitude():
    p = F450
    dt = 0.005
    par = _params(p, dt)
    st = np.zeros(4)
    phi, theta, psi = 0.1, -0.2, 0.7
    wp, wq, wr = 0.3, -0.2, 0.1
    pd, qd = 1.5, -0.5
    ref = (2.0, 1.0, -0.5)
    thrust = p.mass_kg * law.G0
    out = law.rate_step(par, st, (phi, theta, psi, wp, wq, wr, pd, qd, *ref, thrust))
    _same_rotation(out[:4], Rotation.from_euler("ZYX", [psi, theta, phi]))
    ixx, iyy, izz = p.inertia_kg_m2
    e = np.subtract(ref, (wp, wq, wr))
    np.testing.assert_allclose(st[:3], e * dt, atol=1e-15)  # integrators after one update
    tl = ixx * (p.rate_kp * e[0] + p.rate_ki * e[0] * dt - p.rate_kd * p.rate_kp * pd) + (izz - iyy) * wq * wr
    tm = iyy * (p.rate_kp * e[1] + p.rate_ki * e[1] * dt - p.rate_kd * p.rate_kp * qd) + (ixx - izz) * wp * wr
    tn = dt / (p.yaw_lpf_s + dt) * izz * (p.rate_kp * e[2] + p.rate_ki * e[2] * dt)  # first low-pass step
    got = _allocation(p) @ _thrusts(p, out[4:])
    np.testing.assert_allclose(got, [thrust, tl, tm, tn], rtol=0, atol=1e-9)
    assert st[3] == pytest.approx(tn, abs=1e-12)


def test_attitude_step_commands_a_rate_along_the_error():
    """Reference rolled right of the current attitude: positive roll rate demand -> positive roll torque."""
    par = _params(F450)
    r = Rotation.from_euler("ZYX", [0.3, 0.0, 0.2])
    rx, ry, rz, rw = r.as_quat()
    out = law.attitude_step(par, np.zeros(4), (0.0, 0.0, 0.3, 0.0, 0.0, 0.0, 0.0, 0.0, rw, rx, ry, rz, 0.0,
                                               F450.mass_kg * law.G0))  # fmt: skip
    got = _allocation(F450) @ _thrusts(F450, out[4:])
    assert got[1] > 0.0 and abs(got[2]) < 1e-9 and abs(got[3]) < 1e-9


def test_position_step_holds_at_the_reference_and_climbs_below_it():
    p = F450
    par = _params(p)
    level = (0.0, 0.0, 0.5, 0.0, 0.0, 0.0, 0.0, 0.0)
    at_ref = (0.0, 0.0, -1.0, 0.0, 0.0, 0.0, 0.0, 0.0, -1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.5, 0.0)
    out = law.position_step(par, np.zeros(4), level + at_ref)
    assert out[4] == 0.5  # yaw reference unchanged without a yaw-rate feed-forward
    got = _allocation(p) @ _thrusts(p, out[5:])
    np.testing.assert_allclose(got, [p.mass_kg * law.G0, 0.0, 0.0, 0.0], atol=1e-9)  # hover thrust
    below = at_ref[:8] + (-3.0,) + at_ref[9:]  # reference 2 m above (NED z more negative)
    out = law.position_step(par, np.zeros(4), level + below)
    assert (_allocation(p) @ _thrusts(p, out[5:]))[0] > p.mass_kg * law.G0
