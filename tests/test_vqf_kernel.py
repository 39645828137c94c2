"""The compiled VQF (``model/vqf_kernel.py``) against the ``vqf`` package's C++ VQF: the same bits, state included.

On real BROAD trials (6-D and 9-D: their magnetometer, disturbed trials among them) and on synthetic motion that
visits every branch: rests long enough for the rest bias estimate, a magnetometer that is disturbed then changes for
good, zero samples, a gyro bias beyond the clip, the accelerometer's time constant changed mid-run (and below Ts/2,
the pass-through) and the state turned between samples as the anchored filter turns it.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

vqf = pytest.importorskip("vqf")

from tepinn_flight.model import vqf_kernel as vk  # noqa: E402
from tepinn_flight.model.anchor import to_sensor  # noqa: E402

BROAD = Path(__file__).resolve().parents[2] / "shared" / "broad"


def _state_diffs(s: np.ndarray, pkg_state: dict) -> list[str]:
    mine = vk.state_dict(s)
    return [k for k in mine if not np.array_equal(np.asarray(mine[k], float), np.asarray(pkg_state[k], float), equal_nan=True)]


def _synthetic(n: int = 12000, ts: float = 0.005, seed: int = 3):
    """Gyro, accelerometer and magnetometer (sensor frame) of a body that rests, turns and shakes; the
    magnetometer disturbed for a while, then in a new field; a few zero accelerometer and magnetometer samples."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) * ts
    w = np.zeros((n, 3))
    moving = (t % 20.0) > 4.0  # 4 s at rest every 20 s
    w[moving] = np.cumsum(rng.normal(0, 0.08, (moving.sum(), 3)), axis=0) % 6.0 - 3.0
    w += np.array([0.004, -0.003, 0.002])  # a bias within the clip
    w[6000:6400] += np.array([0.2, 0.0, 0.0])  # ... and beyond it for 2 s
    from scipy.spatial.transform import Rotation

    steps = Rotation.from_rotvec(w * ts)  # the true attitude (sensor → earth), the gyro integrated
    rots = [Rotation.identity()]
    for i in range(1, n):
        rots.append(rots[-1] * steps[i])
    att = Rotation.concatenate(rots)

    def to_body(v):  # earth → sensor
        return att.inv().apply(v)

    acc = to_body(np.tile([0.0, 0.0, 9.81], (n, 1))) + rng.normal(0, 0.05, (n, 3))
    acc[moving] += rng.normal(0, 1.5, (moving.sum(), 3))  # motion acceleration
    field = np.tile([20.0, 0.0, -40.0], (n, 1))
    field[3000:3800] += [15.0, 10.0, 0.0]  # a disturbance
    field[8000:] = [25.0, 5.0, -35.0]  # a new field for good
    mag = to_body(field) + rng.normal(0, 0.3, (n, 3))
    acc[[100, 5000, 5001]] = 0.0  # skipped by VQF
    mag[[200, 7000]] = 0.0
    gyr = w + rng.normal(0, 0.002, (n, 3))
    return ts, *(np.ascontiguousarray(x) for x in (gyr, acc, mag))


def _compare(ts, gyr, acc, mag=None, **params):
    f = vqf.VQF(ts, **params)
    out = f.updateBatch(gyr, acc, mag)
    c, s = vk.new_filter(ts, **params)
    n = len(gyr)
    q6, q9, b = np.empty((n, 4)), np.empty((n, 4)), np.empty((n, 3))
    if mag is None:
        vk.update_rows(c, s, gyr, acc, q6, b)
    else:
        vk.update_rows_9d(c, s, gyr, acc, mag, q6, q9, b)
        assert np.array_equal(q9, out["quat9D"])
    assert np.array_equal(q6, out["quat6D"])
    assert np.array_equal(b, out["bias"])
    assert _state_diffs(s, f.state) == []
    assert vk.bias_sigma(c, s) == f.getBiasEstimate()[1]
    return out


@pytest.mark.parametrize("params", [{}, {"tauAcc": 1.0, "biasClip": 5.0}, {"tauAcc": 0.001}])
def test_synthetic_motion_bit_for_bit(params):
    ts, gyr, acc, mag = _synthetic()
    out = _compare(ts, gyr, acc, None, **params)
    if not params:  # the data visits the branches this test is about
        assert out["restDetected"].any() and not out["restDetected"].all()
    out = _compare(ts, gyr, acc, mag, **params)
    if not params:
        assert out["magDistDetected"].any() and not out["magDistDetected"].all()


def test_tau_changes_and_turned_state_bit_for_bit():
    """``set_tau_acc`` mid-run (its states kept continuous, as the package's ``setTauAcc``) and the inclination
    state written between blocks, as the anchored filter's pull writes it."""
    ts, gyr, acc, _ = _synthetic(seed=5)
    f = vqf.VQF(ts)
    c, s = vk.new_filter(ts)
    rng = np.random.default_rng(1)
    for k0 in range(0, len(gyr), 701):
        sl = slice(k0, k0 + 701)
        g, a = np.ascontiguousarray(gyr[sl]), np.ascontiguousarray(acc[sl])
        o = f.updateBatch(g, a)
        q6, b = np.empty((len(g), 4)), np.empty((len(g), 3))
        vk.update_rows(c, s, g, a, q6, b)
        assert np.array_equal(q6, o["quat6D"]) and np.array_equal(b, o["bias"])
        tau = float(rng.choice([3.0, 10.0, 1.5, 3.0]))
        f.setTauAcc(tau)
        vk.set_tau_acc(c, s, tau)
        st = f.state
        for key in ("accQuat", "lastAccLp", "accLpState"):
            i, n = vk.STATE_KEYS[key]
            v = np.array(st[key], float) * (1.0 + 1e-3 * rng.standard_normal(n))
            st[key] = v
            s[i : i + n] = v
        f.state = st
    assert _state_diffs(s, f.state) == []


def test_a_changed_formula_is_seen():
    """The comparison can fail: a filter whose bias estimate runs on a slightly different clip differs."""
    ts, gyr, acc, _ = _synthetic()
    with pytest.raises(AssertionError):
        f = vqf.VQF(ts, biasClip=2.0)
        out = f.updateBatch(gyr, acc)
        c, s = vk.new_filter(ts, biasClip=2.0 * (1 + 1e-9))
        q6, b = np.empty((len(gyr), 4)), np.empty((len(gyr), 3))
        vk.update_rows(c, s, gyr, acc, q6, b)
        assert np.array_equal(b, out["bias"])


def test_unknown_parameter_and_bad_period_refused():
    with pytest.raises(ValueError, match="magDistRejectionEnabled"):
        vk.new_filter(0.01, magDistRejectionEnabled=False)
    with pytest.raises(ValueError, match="positive sample period"):
        vk.new_filter(0.0)


@pytest.mark.skipif(not BROAD.is_dir(), reason="../shared/broad (the BROAD trials) is not beside the repository")
@pytest.mark.parametrize("trial", ["broad_06", "broad_26", "broad_32"])
def test_real_broad_trials_bit_for_bit(trial):
    """Real IMUs (BROAD: fast rotation, a vibrating phone, a magnet attached), 6-D and 9-D."""
    from tepinn_flight.ingest import load_record

    path = next(BROAD.glob(f"{trial}_*.hdf5"), None)
    if path is None:
        pytest.skip(f"{trial} is not in ../shared/broad")
    rec = load_record(path)
    ts = float(np.median(np.diff(rec.t_s)))
    g, a = to_sensor(rec.gyr_rad_s), to_sensor(rec.acc_m_s2)
    _compare(ts, g, a)
    _compare(ts, g, a, to_sensor(np.nan_to_num(rec.mag_ut)))
