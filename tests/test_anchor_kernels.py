"""The anchored VQF's compiled kernels (``model/anchor_kernels.py``) against independent references:
scipy's Rotation, numpy written out the slow obvious way, and the numpy frame conversion the peers
use (``evaluation/peers.py``), which the kernels must match to the last bit (the estimator with every
learned correction off is VQF bit for bit: ``tests/test_anchor.py``)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import vqf
from scipy.spatial.transform import Rotation

from tepinn_flight.evaluation.peers import Q_NED_ENU, q_nb_from_earth_sensor
from tepinn_flight.model.anchor import q_nb_from_vqf
from tepinn_flight.model.anchor_kernels import horizontal_bias, sigma_step, turn_acc_state

from .anchor_reference import rest_rows, vqf_inputs, vqf_output_one, vqf_outputs  # (the former class's block kernels)
from tepinn_flight.quat_scalar import rotmat_entries
from tests.conftest import broad_trial


def _scipy(q_wxyz) -> Rotation:
    return Rotation.from_quat(np.asarray(q_wxyz)[..., [1, 2, 3, 0]])


def _random_quats(n: int, seed: int) -> np.ndarray:
    q = Rotation.random(n, random_state=seed).as_quat()[:, [3, 0, 1, 2]]
    return q * (1.0 + np.random.default_rng(seed).normal(0, 1e-9, (n, 1)))  # not quite unit, as a filter's


def test_vqf_to_ned_is_the_peers_numpy_conversion_bit_for_bit():
    q = np.concatenate([_random_quats(20000, 1), np.tile([1.0, 0, 0, 0], (3, 1))])
    np.testing.assert_array_equal(q_nb_from_vqf(q), q_nb_from_earth_sensor(q, Q_NED_ENU))
    # VQF's own output on a real trial (the rows the estimator converts)
    from tepinn_flight.evaluation.peers import body_to_zup_sensor
    from tepinn_flight.ingest import load_record

    rec = load_record(broad_trial("broad_03_*.hdf5"))
    out = vqf.VQF(float(np.median(np.diff(rec.t_s[:52])))).updateBatch(body_to_zup_sensor(rec.gyr_rad_s[:20000]),
                                                                      body_to_zup_sensor(rec.acc_m_s2[:20000]))  # fmt: skip
    np.testing.assert_array_equal(q_nb_from_vqf(out["quat6D"]), q_nb_from_earth_sensor(out["quat6D"], Q_NED_ENU))
    # and it is the rotation scipy composes: NED←ENU ∘ q_ES ∘ (180° about x)
    want = (_scipy(Q_NED_ENU) * _scipy(q[:100]) * Rotation.from_euler("x", math.pi)).as_quat()[:, [3, 0, 1, 2]]
    got = q_nb_from_vqf(q[:100])
    np.testing.assert_allclose(got * np.sign(got[:, :1] * want[:, :1]), want, atol=1e-12)
    np.testing.assert_array_equal(q_nb_from_vqf(q[7]), got[7])  # one quaternion


def test_rotmat_entries_are_scipys_matrix():
    for q in _random_quats(50, 2):
        q = q / np.linalg.norm(q)
        np.testing.assert_allclose(np.reshape(rotmat_entries(*q), (3, 3)), _scipy(q).as_matrix(), atol=1e-14)


def test_block_inputs_against_numpy():
    rng = np.random.default_rng(3)
    n = 40
    gyr, acc = rng.normal(0, 2, (n, 3)), rng.normal(0, 9, (n, 3))
    corr, vel, acc_v = rng.normal(0, 0.01, 3), rng.normal(0, 30, 3), rng.normal(0, 2, 3)
    flip = np.array([1.0, -1.0, -1.0])
    for centripetal, v, av in ((True, vel, acc_v), (False, vel, acc_v), (True, np.zeros(3), np.zeros(3)),
                               (True, np.zeros(3), acc_v)):  # fmt: skip
        g_s, a_s = np.empty((n, 3)), np.empty((n, 3))
        assert vqf_inputs(gyr, acc, corr, v, av, centripetal, g_s, a_s) == 0
        np.testing.assert_array_equal(g_s, (gyr - corr) * flip)
        a = acc - (np.cross(gyr, v) + av) if centripetal else acc
        np.testing.assert_allclose(a_s, a * flip, rtol=0, atol=1e-12)
    gyr[5, 1] = np.nan
    acc[7, 2] = -np.inf
    acc[5, 0] = np.inf  # the same row again: counted once
    assert vqf_inputs(gyr, acc, corr, vel, acc_v, True, g_s, a_s) == 2


def _sigma_reference(q_es, a_s, g_s, e0, alpha, var0, gain, samp, var_net):
    """σ row by row, the slow way: the earth's vertical in sensor axes from scipy, the angle to the
    accelerometer, a first-order low-pass; the sampling term from the gyro's norm."""
    up = _scipy(q_es).inv().apply([0.0, 0.0, 1.0])
    ang = [math.acos(min(1.0, max(-1.0, float(u @ a) / np.linalg.norm(a)))) for u, a in zip(up, a_s)]
    e, out = e0, []
    for x, w in zip(ang, np.linalg.norm(g_s, axis=1)):
        e = e + alpha * (x - e)
        out.append(math.sqrt(var0 + (gain * e) ** 2 + samp * w**2 + var_net))
    return np.array(out), e


def test_block_outputs_against_scipy_and_a_slow_sigma():
    q = _random_quats(300, 4)
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    rng = np.random.default_rng(5)
    a_s = rng.normal(0, 1, (300, 3)) + _scipy(q).inv().apply([0.0, 0.0, 9.81])  # roughly the vertical
    bias_s, corr = rng.normal(0, 0.01, (300, 3)), rng.normal(0, 0.01, 3)
    q_nb, bias_b, sigma = np.empty((300, 4)), np.empty((300, 3)), np.empty(300)
    g_s = rng.normal(0, 3.0, (300, 3))  # rad/s
    args = (0.02, 0.0025, math.radians(0.45) ** 2, 0.025, 0.01**2 / 12, 1e-5)  # Δt 10 ms
    e = vqf_outputs(q, bias_s, a_s, g_s, corr, *args, q_nb, bias_b, sigma)
    np.testing.assert_array_equal(q_nb, q_nb_from_earth_sensor(q, Q_NED_ENU))
    np.testing.assert_array_equal(bias_b, bias_s * [1.0, -1.0, -1.0] + corr)
    want, e_want = _sigma_reference(q, a_s, g_s, *args)
    np.testing.assert_allclose(sigma, want, rtol=0, atol=1e-13)  # acos near 0: ~1e-16 / sin(angle)
    assert e == pytest.approx(e_want, abs=1e-13)
    # one sample at a time (the live path) gives the same bits
    e1 = args[0]
    for i in range(300):
        s, e1 = sigma_step(*q[i], *a_s[i], *g_s[i], e1, *args[1:])
        assert s == sigma[i]
    assert e1 == e
    # ... and so does the live path's one call per sample, the quaternion and the bias too
    sp, out = np.array([args[0], *args[1:]]), np.empty(8)
    for i in range(300):
        vqf_output_one(q[i].copy(), bias_s[i].copy(), a_s[i].copy(), *g_s[i], corr, sp, out)
        assert out[:4].tolist() == q_nb[i].tolist() and out[4] == sigma[i] and out[5:].tolist() == bias_b[i].tolist()
    assert sp[0] == e and sp[1:].tolist() == list(args[1:])
    # a low-pass gain of 1 (τ below the sample period): the angle itself
    vqf_outputs(q, bias_s, a_s, g_s, corr, 0.3, 1.0, 0.0, 1.0, 0.0, 0.0, q_nb, bias_b, sigma)
    np.testing.assert_allclose(sigma, _sigma_reference(q, a_s, g_s, 0.0, 1.0, 0.0, 1.0, 0.0, 0.0)[0], rtol=0, atol=1e-13)
    # the sampling term alone: |ω|·Δt/√12, the closed form of a uniform timing offset within a sample
    vqf_outputs(q, bias_s, a_s, g_s, corr, 0.3, 1.0, 0.0, 0.0, 0.01**2 / 12, 0.0, q_nb, bias_b, sigma)
    np.testing.assert_allclose(sigma, np.linalg.norm(g_s, axis=1) * 0.01 / math.sqrt(12), rtol=1e-12)


def test_horizontal_bias_against_a_projection():
    rng = np.random.default_rng(6)
    for q in _random_quats(30, 7):
        b = rng.normal(0, 0.05, 3)
        down = _scipy(q_nb_from_vqf(q)).inv().apply([0.0, 0.0, 1.0])  # NED down in body axes
        got = np.array(horizontal_bias(*q, *b))
        np.testing.assert_allclose(got, b - down * (down @ b), atol=1e-15)
        assert abs(got @ down) < 1e-15


@pytest.mark.parametrize("averaging", [False, True])
def test_turn_acc_state_turns_the_inclination_and_its_filter_states_together(averaging):
    """``acc_quat`` becomes d ⊗ a, and the low-passed accelerometer states turn by the rotation
    a* ⊗ d* ⊗ a (both composed by scipy): VQF keeps them in the frame in between, so the pull is
    not undone at the next sample (``tests/test_anchor.py``)."""
    rng = np.random.default_rng(8 + averaging)
    a = _random_quats(1, 9)[0]
    a /= np.linalg.norm(a)
    d = Rotation.from_rotvec([0.1, -0.05, 0.0]).as_quat()[[3, 0, 1, 2]]  # horizontal axis, as a pull
    lp, st = rng.normal(0, 1, 3), rng.normal(0, 1, 6)
    if averaging:
        st[0] = np.nan
    aq, lp2, st2 = a.copy(), lp.copy(), st.copy()
    turn_acc_state(aq, *d, lp2, st2)
    want_q = (_scipy(d) * _scipy(a)).as_quat()[[3, 0, 1, 2]]
    np.testing.assert_allclose(aq * np.sign(aq[0] * want_q[0]), want_q, atol=1e-14)
    r = (_scipy(a).inv() * _scipy(d).inv() * _scipy(a)).as_matrix()
    np.testing.assert_allclose(lp2, r @ lp, atol=1e-13)
    if averaging:  # NaN first, the sum of the first samples in [2:5], the rest untouched
        assert np.isnan(st2[0]) and st2[1] == st[1] and st2[5] == st[5]
        np.testing.assert_allclose(st2[2:5], r @ st[2:5], atol=1e-13)
    else:  # two filter states per axis: x0 x1 y0 y1 z0 z1
        np.testing.assert_allclose(st2.reshape(3, 2), r @ st.reshape(3, 2), atol=1e-13)


def _still_runs_slowly(gyr, acc, gyr_max, acc_dev, spike=1.0):
    """The still run after each sample, written out: its start index (None: no run) recomputed from
    the definition — a sample continues the run when it lies within acc_dev of the mean of the run's samples
    before it and |ω| < gyr_max, or |ω| < spike·gyr_max while the mean gyro of the run with it stays below
    gyr_max (rule 23); else a run starts at it if |ω| < gyr_max."""
    start, out = None, []
    for i in range(len(gyr)):
        w = np.linalg.norm(gyr[i])
        finite = np.all(np.isfinite(acc[i]))
        if not (finite and w < spike * gyr_max):
            start = None
        elif (start is not None and np.linalg.norm(acc[i] - acc[start:i].mean(0)) < acc_dev
              and (w < gyr_max or np.linalg.norm(gyr[start : i + 1].mean(0)) < gyr_max)):  # fmt: skip
            pass
        else:
            start = i if w < gyr_max else None
        out.append(start)
    return out


@pytest.mark.parametrize("spike", [1.0, 4.0])
def test_the_still_run_against_its_definition_written_out(spike):
    """rest_rows keeps (length, sum of the accelerometer, sum of the gyro) of the still run: checked sample by
    sample against the run recomputed from its definition on a record of rests, turns, jolts, a hole and a noisy
    gyro's single samples up to 6 °/s (rule 23: spike 4 keeps a run through them while its mean gyro stays still;
    spike 1, the rule before it, breaks at each)."""
    rng = np.random.default_rng(23)
    n = 400
    gyr = rng.normal(0, 0.005, (n, 3))
    acc = np.array([0.3, -0.2, -9.8]) + rng.normal(0, 0.05, (n, 3))
    gyr[50:80, 1] = 2.0  # a turn
    acc[150] += [0.0, 3.0, 0.0]  # a jolt: the run starts again at it
    acc[200:260] += np.linspace(0, 1.5, 60)[:, None] * [1, 0, 0]  # a slow drift out of the run's mean
    acc[300] = np.nan  # a hole
    for i, deg_s in ((110, 5.0), (111, -4.0), (320, 6.0), (340, 3.0), (341, 3.0), (342, 3.0)):
        gyr[i, 0] = math.radians(deg_s)  # single noisy samples (and a short run of 3 °/s: its mean grows)
    gyr[302, 2] = math.radians(3.0)  # the sample after the hole: no run to keep, none starts at it
    gyr_max, acc_dev = math.radians(2.0), 0.5
    want = _still_runs_slowly(gyr, acc, gyr_max, acc_dev, spike)
    st = np.zeros(7)
    for i in range(n):
        rest_rows(st, gyr[i : i + 1].copy(), acc[i : i + 1].copy(), gyr_max**2, acc_dev**2, (spike * gyr_max) ** 2)
        if want[i] is None:
            assert st[0] == 0.0, i
        else:
            assert st[0] == i - want[i] + 1, i
            np.testing.assert_allclose(st[1:4] / st[0], acc[want[i] : i + 1].mean(0), atol=1e-12)
            np.testing.assert_allclose(st[4:7] / st[0], gyr[want[i] : i + 1].mean(0), atol=1e-12)
    assert {None} < set(want) and len(set(want)) > 4  # the record holds several runs and breaks
    if spike > 1:  # the single samples at 110, 111 and 320 no longer break their runs
        assert want[112] == want[109] and want[321] == want[319]
    else:
        assert want[110] is None and want[320] is None
    st2 = np.zeros(7)  # a block gives what sample after sample gives
    rest_rows(st2, gyr, acc, gyr_max**2, acc_dev**2, (spike * gyr_max) ** 2)
    np.testing.assert_allclose(st2, st, rtol=1e-15)
