"""BROAD (HDF5) ingestion: frame conversion checked against scipy and against physics
(gravity at rest, gyro vs optical-reference rates), and shown to fail when done wrong."""

from __future__ import annotations

import h5py
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from tepinn_flight import quat as Q
from tests.consistency import rate_consistency
from tepinn_flight.errors import ConfigError, CorruptLog, NoImuData
from tepinn_flight.ingest import ingest_log
from tepinn_flight.ingest.broad import Q_NED_ENU_WXYZ, q_es_from_q_nb, q_nb_from_q_es, sensor_to_body
from tepinn_flight.record import FlightRecord, make_frame
from tests.conftest import broad_trial

SLOW = "broad_01_*.hdf5"  # undisturbed slow rotation A
FAST = "broad_06_*.hdf5"  # undisturbed fast rotation A (|gyro| up to 925 deg/s)
TRIALS = [SLOW, FAST]

_cache: dict = {}


def load(pattern):
    if pattern not in _cache:
        path = broad_trial(pattern)
        with h5py.File(path, "r") as h:
            raw = {k: h[k][()] for k in ("imu_gyr", "imu_acc", "imu_mag", "opt_quat", "movement")}
            raw["rate"] = float(h.attrs["sampling_rate"])
        _cache[pattern] = (path, raw, ingest_log(path))
    return _cache[pattern]


def rest_mask(rec: FlightRecord) -> np.ndarray:
    """Outside BROAD's movement phases, with the gyro nearly still and a reference."""
    return ~rec.valid & (np.linalg.norm(rec.gyr_rad_s, axis=1) < 0.05) & np.all(np.isfinite(rec.q_ref_wxyz), axis=1)


def acc_vs_up_deg(acc_b: np.ndarray, q_nb: np.ndarray) -> np.ndarray:
    up_b = -Q.gravity_body(q_nb)
    c = np.sum(up_b * acc_b, axis=1) / np.linalg.norm(acc_b, axis=1) / np.linalg.norm(up_b, axis=1)
    return np.degrees(np.arccos(np.clip(c, -1, 1)))


def physical_checks(rec: FlightRecord) -> tuple[bool, bool, dict]:
    """(gravity ok, rates ok, figures): the two checks the conversion must pass."""
    rest = rest_mask(rec)
    ang = acc_vs_up_deg(rec.acc_m_s2[rest], rec.q_ref_wxyz[rest])
    rc = rate_consistency(rec)
    gravity_ok = bool(rest.sum() > 1000 and np.median(ang) < 1.5 and np.percentile(ang, 95) < 2.5)
    rates_ok = bool(np.all(rc.corr >= 0.97) and np.all(np.abs(rc.gain - 1) <= 0.10))
    return gravity_ok, rates_ok, {"angle_median_deg": float(np.median(ang)), "corr": rc.corr, "gain": rc.gain}


def variant(rec: FlightRecord, gyr=None, acc=None, q=None) -> FlightRecord:
    df = make_frame(rec.t_s, rec.segment, rec.gyr_rad_s if gyr is None else gyr, rec.acc_m_s2 if acc is None else acc,
                    rec.mag_ut, rec.q_ref_wxyz if q is None else q, rec.clipped, valid=rec.valid)  # fmt: skip
    return FlightRecord(df, dict(rec.meta))


# --------------------------------------------------------------------------- the conversion


@pytest.mark.parametrize("pattern", TRIALS)
def test_physical_checks_pass(pattern):
    _, _, rec = load(pattern)
    gravity_ok, rates_ok, fig = physical_checks(rec)
    assert gravity_ok, fig
    assert rates_ok, fig


@pytest.mark.parametrize("pattern", TRIALS)
def test_conversion_matches_scipy_and_closed_form(pattern):
    _, raw, rec = load(pattern)
    # vectors: body = sensor turned 180 deg about x -> (x, -y, -z)
    flip = np.array([1.0, -1.0, -1.0])
    np.testing.assert_allclose(rec.gyr_rad_s, raw["imu_gyr"] * flip, atol=1e-12)
    np.testing.assert_allclose(rec.acc_m_s2, raw["imu_acc"] * flip, atol=1e-12)
    np.testing.assert_allclose(rec.mag_ut, raw["imu_mag"] * flip, atol=1e-12)
    # quaternion: R_NB = R_NE R_ES R_SB with scipy, from the matrices stated in words
    q_es = raw["opt_quat"]
    ok = np.all(np.isfinite(q_es), axis=1) & np.all(np.isfinite(rec.q_ref_wxyz), axis=1)
    r_ne = Rotation.from_matrix([[0, 1, 0], [1, 0, 0], [0, 0, -1]])
    r_sb = Rotation.from_matrix(np.diag([1.0, -1.0, -1.0]))
    r_nb = r_ne * Rotation.from_quat(q_es[ok][:, [1, 2, 3, 0]]) * r_sb
    got = Rotation.from_quat(rec.q_ref_wxyz[ok][:, [1, 2, 3, 0]])
    assert np.degrees((got * r_nb.inv()).magnitude()).max() < 1e-6
    # and back to BROAD's sensor -> ENU for its published metrics
    back = q_es_from_q_nb(rec.q_ref_wxyz[ok])
    assert np.abs(np.abs(np.sum(back * q_es[ok], axis=1)) - 1).max() < 1e-9


def test_level_sensor_is_a_level_body():
    """At rest with z up (trial start) the FRD body reads acc z ~ -9.81 and the reference is level."""
    _, raw, rec = load(SLOW)
    first = slice(0, 200)
    assert np.all(raw["imu_acc"][first, 2] > 9.5)  # BROAD's sensor z points up at the start
    assert np.median(rec.acc_m_s2[first, 2]) == pytest.approx(-9.81, abs=0.15)
    roll, pitch, _ = Q.quat_to_euler_zyx(rec.q_ref_wxyz[first])
    assert np.degrees(np.abs(roll)).max() < 5 and np.degrees(np.abs(pitch)).max() < 5


@pytest.mark.parametrize("pattern", TRIALS)
def test_movement_is_valid_and_nan_reference_stays_nan(pattern):
    _, raw, rec = load(pattern)
    np.testing.assert_array_equal(rec.valid, raw["movement"])
    assert rec.t_s[1] == pytest.approx(1 / 285.714, rel=1e-5) and rec.meta["segments"] == 1
    nan_file = ~np.all(np.isfinite(raw["opt_quat"]), axis=1)
    nan_rec = ~np.all(np.isfinite(rec.q_ref_wxyz), axis=1)
    assert nan_file.sum() > 100 and np.all(nan_rec[nan_file])
    # the assembler also blanks the last finite sample before each dropout run (one per run)
    runs = int(np.sum(np.diff(nan_file.astype(int)) == 1) + nan_file[0])
    assert nan_rec.sum() - nan_file.sum() <= runs
    assert rec.meta["broad_reference_nan_samples"] == int(nan_file.sum())


def test_metadata():
    path, raw, rec = load(FAST)
    m = rec.meta
    assert m["source_kind"] == "broad" and m["vehicle_type"] == "handheld-imu"
    assert m["reference_source"] == "optitrack" and m["broad_trial"] == "06_undisturbed_fast_rotation_A"
    assert m["imu_rate_hz"] == pytest.approx(285.714, abs=1e-3) == raw["rate"]
    assert m["reference_rate_hz"] == pytest.approx(285.714, abs=1e-3)
    assert m["broad_q_sensor_body_wxyz"] == [0.0, 1.0, 0.0, 0.0]
    np.testing.assert_allclose(m["broad_q_ned_enu_wxyz"], [0, np.sqrt(0.5), np.sqrt(0.5), 0])
    assert "q_NB = q_NE * q_ES * q_SB" in m["broad_earth_frame_conversion"]
    assert np.abs(rec.gyr_rad_s).max() > np.radians(900)  # the fast trial really is fast


# --------------------------------------------------------------------------- wrong conversions fail


def test_skipping_the_sensor_to_body_flip_fails_the_checks():
    """Vectors left in sensor axes while the reference is converted: both checks must fail."""
    _, raw, rec = load(FAST)
    bad = variant(rec, gyr=raw["imu_gyr"], acc=raw["imu_acc"])
    gravity_ok, rates_ok, fig = physical_checks(bad)
    assert not gravity_ok and not rates_ok
    assert fig["corr"][1] < -0.9 and fig["corr"][2] < -0.9  # y and z reversed
    assert fig["angle_median_deg"] > 150


def test_skipping_the_earth_frame_conversion_fails_the_gravity_check():
    _, raw, rec = load(FAST)
    q_enu_b = Q.quat_mul(Q.quat_conj(np.broadcast_to(Q_NED_ENU_WXYZ, rec.q_ref_wxyz.shape)), rec.q_ref_wxyz)
    gravity_ok, rates_ok, fig = physical_checks(variant(rec, q=q_enu_b))
    assert not gravity_ok and fig["angle_median_deg"] > 150
    assert rates_ok  # body rates cannot see the earth frame: the gravity check is what catches it


def test_skipping_the_flip_everywhere_breaks_the_frd_convention():
    """Sensor axes used as body throughout are self-consistent, but a level sensor reads +9.81."""
    _, raw, rec = load(SLOW)
    q_ns = q_nb_from_q_es(raw["opt_quat"], q_sensor_body=np.array([1.0, 0, 0, 0]))
    bad = variant(rec, gyr=raw["imu_gyr"], acc=raw["imu_acc"], q=Q.quat_canonical(q_ns))
    gravity_ok, rates_ok, _ = physical_checks(bad)
    assert gravity_ok and rates_ok
    roll, _, _ = Q.quat_to_euler_zyx(bad.q_ref_wxyz[:200])
    assert np.degrees(np.abs(roll)).min() > 170  # "level" is upside down
    assert np.median(bad.acc_m_s2[:200, 2]) > 9.5


def test_sensor_to_body_is_its_own_inverse():
    v = np.random.default_rng(0).normal(size=(10, 3))
    np.testing.assert_allclose(sensor_to_body(sensor_to_body(v)), v, atol=1e-12)
    np.testing.assert_allclose(sensor_to_body(v), v * [1, -1, -1], atol=1e-12)


# --------------------------------------------------------------------------- bad input


@pytest.mark.parametrize("cut", [1000, 0.5, 0.95])
def test_truncated_hdf5_is_a_one_line_corrupt_log(tmp_path, cut):
    src = broad_trial("broad_03_*.hdf5").read_bytes()
    p = tmp_path / "trunc.hdf5"
    p.write_bytes(src[: cut if isinstance(cut, int) else int(len(src) * cut)])
    with pytest.raises(CorruptLog) as e:
        ingest_log(p)
    assert "\n" not in str(e.value) and "truncated" in str(e.value) and str(p) in str(e.value)


def test_hdf5_that_is_not_a_broad_trial(tmp_path):
    p = tmp_path / "other.h5"
    with h5py.File(p, "w") as h:
        h["x"] = np.arange(3)
    with pytest.raises(CorruptLog, match="not a BROAD trial: no dataset"):
        ingest_log(p)
    with h5py.File(p, "w") as h:
        h["imu_gyr"] = np.zeros((5, 3))
        h["imu_acc"] = np.zeros((4, 3))
        h["opt_quat"] = np.zeros((5, 4))
        h["movement"] = np.zeros(5, bool)
        h.attrs["sampling_rate"] = 100.0
    with pytest.raises(CorruptLog, match="inconsistent shapes"):
        ingest_log(p)


def test_options_that_a_broad_trial_cannot_satisfy():
    path = broad_trial(SLOW)
    with pytest.raises(NoImuData, match="instance 1"):
        ingest_log(path, imu=1)
    with pytest.raises(ConfigError, match="available: optitrack"):
        ingest_log(path, reference="vehicle_attitude")


def test_cli_reports_truncated_hdf5_in_one_line(tmp_path):
    from tests.test_cli import run_cli

    p = tmp_path / "trunc.hdf5"
    p.write_bytes(broad_trial("broad_03_*.hdf5").read_bytes()[:5000])
    code, _, err = run_cli("ingest", str(p), "-o", str(tmp_path / "out.parquet"))
    assert code == 2 and "Traceback" not in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "out.parquet").exists()
