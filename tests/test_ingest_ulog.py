"""PX4 ULog ingestion against pyulog read directly (golden summaries), scipy (reference
interpolation) and physics (gravity at rest, gyro vs reference-derived rates)."""

from __future__ import annotations

import numpy as np
import pytest
from pyulog import ULog
from scipy.spatial.transform import Rotation, Slerp

from tepinn_flight import quat as Q
from tepinn_flight.conventions import Q_ENU_FROM_NED_WXYZ
from tests.consistency import rate_consistency
from tepinn_flight.errors import ConfigError, CorruptLog, NoImuData
from tepinn_flight.ingest import ingest_log
from tepinn_flight.ingest.assemble import build_record
from tepinn_flight.ingest.streams import ImuStream, RawLog
from tepinn_flight.ingest.ulog import ensure_breaks, firmware_string, integral_dt_s
from tepinn_flight.record import FlightRecord
from tests.conftest import real_log

EVENTS = "pyulog_sample_px4_events.ulg"  # SITL, PX4 v1.15, UNIX-time stamps
TAGGED = "pyulog_sample_logging_tagged_and_default_params.ulg"  # SITL, groundtruth
SMALL = "pyulog_sample_log_small.ulg"  # VTOL on ground, v1.11, 3 IMUs, 1 dropout
APPENDED = "pyulog_sample_appended_multiple.ulg"  # v1.6, appended data sections
DECIMATED = "pxrs_esc_status_log.ulg"  # real flight, sensor_combined at 9.6 Hz

# facts measured once by hand (log-formats.md §4, SOURCES.md): samples, rate Hz, version, vehicle
KNOWN = {
    DECIMATED: (341, 9.6, "v1.9.0", "quadrotor"),
    APPENDED: (2373, 250.0, "v1.6.0", "quadrotor"),
    SMALL: (1298, 204.6, "v1.11.2", "vtol-fixedrotor"),
    TAGGED: (2028, 250.0, "v1.13.0", "quadrotor"),
    EVENTS: (7783, 250.0, "v1.15.0", "quadrotor"),
}

_cache: dict = {}


def ulog(name: str) -> ULog:
    if name not in _cache:
        _cache[name] = ULog(str(real_log(name)))
    return _cache[name]


def topic(name: str, t: str, k: int = 0) -> dict:
    return ulog(name).get_dataset(t, k).data


def ingest(name: str, **kw):
    key = (name, tuple(sorted(kw.items())))
    if key not in _cache:
        _cache[key] = ingest_log(real_log(name), **kw)
    return _cache[key]


def angle_acc_vs_down_deg(rec: FlightRecord, q: np.ndarray | None = None) -> np.ndarray:
    """Angle between the accelerometer and -gravity in body from the reference, per sample."""
    q = rec.q_ref_wxyz if q is None else q
    ok = np.all(np.isfinite(q), axis=1)
    up_b = -Q.gravity_body(q[ok])
    a = rec.acc_m_s2[ok]
    c = np.sum(up_b * a, axis=1) / np.linalg.norm(a, axis=1) / np.linalg.norm(up_b, axis=1)
    return np.degrees(np.arccos(np.clip(c, -1, 1)))


# --------------------------------------------------------------------------- golden summaries


@pytest.mark.parametrize("name", list(KNOWN))
def test_shared_ulog_matches_pyulog_golden_summary(name):
    n_known, rate_known, version, vehicle = KNOWN[name]
    sc = topic(name, "sensor_combined")
    t_us = sc["timestamp"].astype(np.int64)
    rec = ingest(name)
    # sample count and rate: pyulog's own arrays, and the hand-measured figures
    assert len(rec) == len(t_us) == n_known
    assert rec.meta["imu_rate_hz"] == pytest.approx(1e6 / np.median(np.diff(t_us)), rel=1e-9)
    assert rec.meta["imu_rate_hz"] == pytest.approx(rate_known, rel=0.01)
    # duration from the samples, not from the header
    assert rec.t_s[-1] == pytest.approx((t_us[-1] - t_us[0]) * 1e-6, abs=1e-6)
    # values untouched (already rad/s, m/s^2, FRD)
    gyr = np.column_stack([sc[f"gyro_rad[{i}]"] for i in range(3)])
    acc = np.column_stack([sc[f"accelerometer_m_s2[{i}]"] for i in range(3)])
    np.testing.assert_array_equal(rec.gyr_rad_s, gyr.astype(np.float64))
    np.testing.assert_array_equal(rec.acc_m_s2, acc.astype(np.float64))
    m = rec.meta
    assert m["source_kind"] == "ulog" and m["autopilot"] == "px4"
    assert version in m["firmware"] and m["vehicle_type"] == vehicle
    assert int(ulog(name).initial_parameters["MAV_TYPE"]) in (2, 22)
    assert m["imu_instance"] == 0 and m["imu_topic"] == "sensor_combined"
    assert m["skipped_frames"] == len(ulog(name).dropouts)
    assert m["corrupt_frames"] == int(ulog(name).file_corruption)
    # reference: rate from the chosen topic's own stamps
    ref = topic(name, m["reference_source"])
    ref_step_us = np.median(np.diff(ref["timestamp"].astype(np.int64)))
    assert m["reference_rate_hz"] == pytest.approx(1e6 / ref_step_us, rel=1e-6)
    # magnetometer: gauss -> uT, plausible earth field on the logs with a calibrated one
    if name != APPENDED:
        assert 30 < np.nanmedian(np.linalg.norm(rec.mag_ut, axis=1)) < 65


def test_firmware_string_decodes_ver_sw_release():
    # 0x010B0200: v1.11.2, type 0 = dev; 0x010900FF: v1.9.0 release
    assert firmware_string({"ver_sw_release": 0x010B0200, "ver_sw": "8583f1da30b6"}) == "PX4 v1.11.2 dev (git 8583f1da)"
    assert firmware_string({"ver_sw_release": 0x010900FF, "sys_name": "PX4"}) == "PX4 v1.9.0"
    assert firmware_string({}) == "unknown"


def test_gyro_integral_dt_unit_seconds_in_2016_logs_us_later():
    assert integral_dt_s(topic(APPENDED, "sensor_combined")["gyro_integral_dt"])[1] == "s"
    assert integral_dt_s(topic(EVENTS, "sensor_combined")["gyro_integral_dt"])[1] == "us"
    assert ingest(APPENDED).meta["gyro_integral_dt_s"] == pytest.approx(0.004, abs=1e-4)
    assert ingest(EVENTS).meta["gyro_integral_dt_s"] == pytest.approx(0.004, abs=1e-9)


# --------------------------------------------------------------------------- reference choice


def test_groundtruth_is_the_default_reference_in_sitl():
    rec = ingest(TAGGED)
    assert rec.meta["reference_source"] == "vehicle_attitude_groundtruth"
    assert rec.meta["reference_candidates"][:2] == ["vehicle_attitude_groundtruth", "vehicle_attitude"]
    # groundtruth's timestamp_sample is logged as 0: timed by timestamp (125 Hz), and said so
    assert np.all(topic(TAGGED, "vehicle_attitude_groundtruth")["timestamp_sample"] == 0)
    assert rec.meta["reference_rate_hz"] == pytest.approx(125.0, rel=1e-6)
    assert any("timestamp_sample not usable" in n for n in rec.meta["notes"])
    assert rec.meta["reference_coverage"] > 0.99


def _scipy_reference_on_imu(name, ref_topic, rec):
    """Independent interpolation of the reference onto the record's rows with scipy's Slerp."""
    d = topic(name, ref_topic)
    ts = d.get("timestamp_sample")
    t_ref = (d["timestamp"] if ts is None or np.all(ts == 0) else ts).astype(np.int64) * 1e-6
    q = np.column_stack([d[f"q[{i}]"] for i in range(4)]).astype(np.float64)
    t_imu = topic(name, "sensor_combined")["timestamp"].astype(np.int64) * 1e-6
    inside = (t_imu >= t_ref[0]) & (t_imu <= t_ref[-1])
    slerp = Slerp(t_ref, Rotation.from_quat(q[:, [1, 2, 3, 0]]))
    return inside, slerp(t_imu[inside])


@pytest.mark.parametrize("ref", ["vehicle_attitude", "vehicle_attitude_groundtruth", "estimator_attitude[1]"])
def test_reference_selectable_by_topic_name_and_matches_scipy_slerp(ref):
    rec = ingest(TAGGED, reference=ref)
    assert rec.meta["reference_source"] == ref
    if ref == "estimator_attitude[1]":  # 2 Hz instance: only check it is that topic's data
        q0 = np.array([topic(TAGGED, "estimator_attitude", 1)[f"q[{i}]"][0] for i in range(4)])
        first = rec.q_ref_wxyz[np.all(np.isfinite(rec.q_ref_wxyz), axis=1)][0]
        assert np.degrees(Q.quat_angle_between(first, q0)) < 1.0
        return
    inside, r_scipy = _scipy_reference_on_imu(TAGGED, ref, rec)
    q = rec.q_ref_wxyz[inside]
    ok = np.all(np.isfinite(q), axis=1)
    assert ok.mean() > 0.95  # NaN only across EKF resets (vehicle_attitude)
    err = (Rotation.from_quat(q[ok][:, [1, 2, 3, 0]]) * r_scipy[ok].inv()).magnitude()
    assert np.degrees(err).max() < 1e-3


def test_ekf_resets_leave_the_reference_uncovered_across_the_jump():
    rec = ingest(EVENTS)  # vehicle_attitude with 2 quat resets, the first a 1.45 deg jump
    d = topic(EVENTS, "vehicle_attitude")
    t_reset = d["timestamp_sample"][np.flatnonzero(np.diff(d["quat_reset_counter"])) + 1].astype(np.int64) * 1e-6
    t0 = topic(EVENTS, "sensor_combined")["timestamp"][0] * 1e-6
    nan = ~np.all(np.isfinite(rec.q_ref_wxyz), axis=1)
    for tr in t_reset - t0:
        near = np.abs(rec.t_s - tr) < 0.02
        assert nan[near].all()
    # the reference is never interpolated through a jump: rates from it stay small
    q, t = rec.q_ref_wxyz, rec.t_s
    ok = np.all(np.isfinite(q[1:]), axis=1) & np.all(np.isfinite(q[:-1]), axis=1)
    w = Q.body_rates_from_quats(q, np.diff(t))[ok]
    assert np.abs(w).max() < 0.5


def test_unknown_reference_is_a_clear_error_listing_what_exists():
    with pytest.raises(ConfigError) as e:
        ingest_log(real_log(TAGGED), reference="vehicle_odometry")
    msg = str(e.value)
    assert "\n" not in msg and "vehicle_attitude_groundtruth" in msg and "estimator_attitude[2]" in msg
    with pytest.raises(ConfigError, match="available: vehicle_attitude"):
        ingest_log(real_log(EVENTS), reference="vehicle_attitude_groundtruth")


# --------------------------------------------------------------------------- time, appended, dropouts


def test_unix_time_sample_is_converted_on_its_own_clock():
    rec = ingest(EVENTS)
    t_us = topic(EVENTS, "sensor_combined")["timestamp"].astype(np.int64)
    assert t_us[0] > 1e15  # the file really uses UNIX µs
    assert rec.meta["time_base"] == "unix"
    assert rec.t_s[0] == 0.0 and rec.t_s[-1] == pytest.approx(31.128, abs=1e-3)
    assert np.allclose(np.diff(rec.t_s), 0.004, atol=2e-6)  # float64 keeps µs at UNIX magnitude
    assert rec.meta["segments"] == 1 and rec.meta["estimation_ok"]
    assert ingest(TAGGED).meta["time_base"] == "boot"


def test_appended_data_sample_reads_whole_log():
    u = ulog(APPENDED)
    assert u.has_data_appended
    rec = ingest(APPENDED)
    assert len(rec) == 2373 and rec.meta["reference_source"] == "vehicle_attitude"
    assert any("appended data" in n and "hardfault_plain" in n for n in rec.meta["notes"])
    # 2016 layout: magnetometer inside sensor_combined, gauss -> uT at its own sample times
    sc = topic(APPENDED, "sensor_combined")
    assert rec.meta["magnetometer_source"] == "sensor_combined.magnetometer_ga"
    t0 = sc["timestamp"][0].astype(np.int64)
    t_mag_all = sc["timestamp"].astype(np.int64) + sc["magnetometer_timestamp_relative"] - t0
    t_mag, first = np.unique(t_mag_all, return_index=True)
    mag_ga = np.column_stack([sc[f"magnetometer_ga[{i}]"] for i in range(3)])[first]
    ok = np.all(np.isfinite(rec.mag_ut), axis=1)
    assert ok.mean() > 0.95
    expect = np.column_stack([np.interp(rec.t_s[ok], t_mag * 1e-6, 100.0 * mag_ga[:, k]) for k in range(3)])
    np.testing.assert_allclose(rec.mag_ut[ok], expect, rtol=1e-5, atol=1e-4)


def test_header_duration_misleads_samples_do_not():
    u = ulog(SMALL)
    rec = ingest(SMALL)
    assert (u.last_timestamp - u.start_timestamp) * 1e-6 > 1000  # the header/last message says ~1174 s
    assert rec.t_s[-1] == pytest.approx(6.496, abs=1e-3)  # the IMU holds 6.5 s
    assert len(u.dropouts) == 1 and rec.meta["skipped_frames"] == 1
    assert len(rec.meta["ulog_dropouts"]) == 1 and rec.meta["ulog_dropouts"][0]["duration_s"] == pytest.approx(0.03)
    # a 161 ms logging gap right after the first sample: a segment boundary
    assert rec.meta["segments"] == 2


def test_ensure_breaks_ends_coverage_at_a_break():
    """ensure_breaks (what leaves the reference uncovered across an EKF reset): one missing sample (2 periods) is no
    gap for the assembler; a break there drops the samples after it until the step is one."""
    t = np.arange(100) * 0.004
    t = np.delete(t, 50)  # step 49 -> 51 is 8 ms = 2 periods < 2.5
    n = len(t)
    raw = RawLog(ImuStream(t, np.zeros((n, 3)), np.tile([0, 0, -9.81], (n, 1))), meta={"source_kind": "ulog"})
    assert build_record(raw, "x.ulg").meta["segments"] == 1  # without the rule
    keep, info = ensure_breaks(t, np.array([t[49] + 0.001]))
    assert info[0]["samples_dropped"] == 1 and not keep[50] and keep.sum() == n - 1
    m = n - 1
    raw2 = RawLog(ImuStream(t[keep], np.zeros((m, 3)), np.tile([0, 0, -9.81], (m, 1))), meta={"source_kind": "ulog"})
    rec = build_record(raw2, "x.ulg")
    assert rec.meta["segments"] == 2 and rec.segment[49] == 0 and rec.segment[50] == 1
    # a break that already lies inside a gap costs nothing; one outside the samples neither
    t_gap = np.r_[np.arange(50) * 0.004, 1.0 + np.arange(50) * 0.004]
    keep, info = ensure_breaks(t_gap, np.array([0.5, 5.0]))
    assert keep.all() and [i["inside_span"] for i in info] == [True, False]


def test_a_logging_dropout_keeps_every_imu_sample(tmp_path):
    """A logging dropout where the IMU lost no sample (other topics did) keeps every IMU sample, and one where it
    lost some leaves the longer step its stamps show (session 53: samples after each dropout were dropped to force a
    segment break, which the estimators then bridged anyway)."""
    from tepinn_flight.ingest import load_record

    from .ulog_writer import SENSOR_COMBINED_V1_14, ULogWriter

    w = ULogWriter()
    w.fmt("sensor_combined", SENSOR_COMBINED_V1_14)
    w.subscribe("sensor_combined")
    stamps = [1_000_000 + 4000 * k for k in range(2500) if k not in (1801, 1802)]  # two samples lost at the second
    for k, t in enumerate(stamps):
        if k in (1000, 1801):  # (pyulog stamps a dropout with the last timestamp before it)
            w.dropout(3)
        w.data("sensor_combined", 0, t, (0.0, 0.0, 0.0), 4000, 0, (0.0, 0.0, -9.8), 4000, 0)
    rec = load_record(w.write(tmp_path / "drops.ulg"))
    assert len(rec) == len(stamps)  # none dropped
    lost = [d["imu_samples_lost"] for d in rec.meta["ulog_dropouts"]]
    assert lost == [0, 2]
    assert any("no IMU sample lost there" in n for n in rec.meta["notes"])
    assert any("2 IMU sample(s) lost there" in n for n in rec.meta["notes"])
    # the logger's own figure (3 ms) is said as its, beside the step the IMU's stamps show (12 ms: two 4-ms samples lost)
    assert any("dropout of 3 ms (the logger's figure)" in n and "the IMU's stamps skipping 12 ms" in n
               for n in rec.meta["notes"])  # fmt: skip


def test_decimated_log_is_ingested_but_flagged():
    rec = ingest(DECIMATED)
    assert rec.meta["imu_rate_hz"] == pytest.approx(9.6, abs=0.1)
    assert rec.meta["estimation_ok"] is False
    notes = " ".join(rec.meta["notes"])
    assert "decimated" in notes and "alias" in notes and "below 20 Hz" in notes
    assert rec.meta["gyro_integral_dt_s"] == pytest.approx(0.004, abs=2e-4)
    # a full-rate log is not flagged
    assert not any("decimated" in n for n in ingest(EVENTS).meta["notes"])


# --------------------------------------------------------------------------- IMU instances


def test_imu_instances_listed_and_selectable():
    rec = ingest(SMALL)
    inst = rec.meta["imu_instances"]
    assert [i["instance"] for i in inst] == [0, 1, 2]
    assert inst[0]["name"] == "sensor_combined" and inst[0]["selected"]
    # sensor_selection's gyro device id is vehicle_imu[0]'s: sensor_combined carries instance 0
    sel = topic(SMALL, "sensor_selection")["gyro_device_id"][0]
    assert topic(SMALL, "vehicle_imu", 0)["gyro_device_id"][0] == sel
    assert inst[1]["name"] == "vehicle_imu[1]" and inst[1]["rate_hz"] == pytest.approx(2.0, abs=0.1)
    # --imu 1: vehicle_imu[1], rates = delta_angle / delta_angle_dt from pyulog directly
    r1 = ingest(SMALL, imu=1)
    d = topic(SMALL, "vehicle_imu", 1)
    assert r1.meta["imu_instance"] == 1 and r1.meta["imu_topic"] == "vehicle_imu[1]"
    assert len(r1) == len(d["timestamp"]) and r1.meta["estimation_ok"] is False
    da = np.column_stack([d[f"delta_angle[{i}]"] for i in range(3)]) / (d["delta_angle_dt"][:, None] * 1e-6)
    dv = np.column_stack([d[f"delta_velocity[{i}]"] for i in range(3)]) / (d["delta_velocity_dt"][:, None] * 1e-6)
    np.testing.assert_allclose(r1.gyr_rad_s, da, rtol=1e-6)
    np.testing.assert_allclose(r1.acc_m_s2, dv, rtol=1e-6)
    assert np.median(r1.acc_m_s2[:, 2]) == pytest.approx(-9.7, abs=0.3)  # same body frame as instance 0
    # --imu 0 is the selected IMU: the same as the default
    assert len(ingest(SMALL, imu=0)) == len(rec)
    with pytest.raises(NoImuData, match=r"instance 5 .*instances: 0 \(sensor_combined"):
        ingest_log(real_log(SMALL), imu=5)


def test_old_logs_have_a_single_instance():
    inst = ingest(APPENDED).meta["imu_instances"]
    assert [(i["instance"], i["name"]) for i in inst] == [(0, "sensor_combined")]
    with pytest.raises(NoImuData):
        ingest_log(real_log(APPENDED), imu=1)


# --------------------------------------------------------------------------- physical checks


@pytest.mark.parametrize("name", [TAGGED, EVENTS, SMALL, APPENDED])
def test_gravity_at_rest_agrees_with_reference(name):
    """Vehicles on the ground (or hovering gently): acc points opposite to 'down' from q_ref."""
    rec = ingest(name)
    ang = angle_acc_vs_down_deg(rec)
    assert np.median(ang) < 1.0
    # a wrong earth frame (the reference taken as body -> ENU) fails the same check by far
    q_wrong = Q.quat_mul(np.broadcast_to(Q_ENU_FROM_NED_WXYZ, rec.q_ref_wxyz.shape), rec.q_ref_wxyz)
    assert np.median(angle_acc_vs_down_deg(rec, q_wrong)) > 45.0


def test_gyro_agrees_with_rates_from_the_reference_on_the_sitl_flight():
    """The v1.15 SITL hover is gentle (reference rates ~0.005 rad/s, below rate_consistency's
    default 0.05 rad/s 'moving' threshold), so we lower the threshold and assert roll/pitch; yaw
    moves least and is left out (corr ~0.3)."""
    rec = ingest(EVENTS)
    assert not rate_consistency(rec).moving.any()  # documented: nothing moves at 0.05 rad/s
    rc = rate_consistency(rec, min_std_rad_s=0.002)
    assert rc.moving[:2].all() and rc.n > 500
    assert np.all(rc.corr[:2] > 0.75), rc.corr
    assert np.all((rc.gain[:2] > 0.6) & (rc.gain[:2] < 1.2)), rc.gain
    # the same check fails with swapped gyro axes (a wrong axis mapping)
    df = rec.data.copy()
    df[["gyr_x_rad_s", "gyr_y_rad_s"]] = df[["gyr_y_rad_s", "gyr_x_rad_s"]].to_numpy()
    bad = rate_consistency(FlightRecord(df, rec.meta), min_std_rad_s=0.002)
    assert np.all(bad.corr[:2] < 0.5), bad.corr


# --------------------------------------------------------------------------- bad files


def _garbage_after(name, n_keep, n_random, seed):
    src = real_log(name).read_bytes()
    return src[:n_keep] + np.random.default_rng(seed).bytes(n_random)


@pytest.mark.parametrize(
    "make, why",
    [
        (lambda: real_log(EVENTS).read_bytes()[:10], "Header too short"),
        (lambda: _garbage_after(EVENTS, 7, 5000, 0), "not a readable ULog"),
        (lambda: _garbage_after(EVENTS, 16, 20000, 1), "not a readable ULog"),
        (lambda: _garbage_after(EVENTS, 100, 20000, 12), "without any logged data"),
        (lambda: _garbage_after(EVENTS, 20000, 20000, 19), "stopped advancing"),  # pyulog loops forever
        (lambda: real_log(EVENTS).read_bytes()[:3000], "without any logged data"),
    ],
    ids=["truncated-header", "random-after-magic", "random-after-header", "random-after-defs", "parser-loop",
         "truncated-defs"],
)
def test_bad_ulog_is_a_one_line_corrupt_log(tmp_path, make, why):
    p = tmp_path / "bad.ulg"
    p.write_bytes(make())
    with pytest.raises(CorruptLog) as e:
        ingest_log(p)
    assert why in str(e.value) and "\n" not in str(e.value) and str(p) in str(e.value)


def test_truncated_or_damaged_data_still_ingests_with_notes(tmp_path):
    src = real_log(EVENTS).read_bytes()
    p = tmp_path / "half.ulg"
    p.write_bytes(src[: len(src) // 2])
    rec = ingest_log(p)
    assert 1000 < len(rec) < 7783
    assert any(n.startswith("the log ends inside a message (the logger stopped mid-write or the file was cut)")
               for n in rec.meta["notes"]), rec.meta["notes"]  # fmt: skip
    p.write_bytes(src[:400_000] + np.random.default_rng(3).bytes(20_000) + src[420_000:])
    rec = ingest_log(p)
    # a garbled length reads short too: not said to be a cut file alone where pyulog found corruption (review60: a
    # whole ULog with a byte flipped every 16 kB was "truncated")
    flipped = bytearray(real_log("pxrs_esc_status_log.ulg").read_bytes())
    flipped[3000::16384] = bytes(b ^ 0xFF for b in flipped[3000::16384])
    p.write_bytes(bytes(flipped))
    notes = ingest_log(p).meta["notes"]
    assert "the log ends inside a message (cut, or a damaged message's length read past its end); the samples before " \
           "are kept" in notes and any("corruption" in n for n in notes), notes
    # one corrupt region, plus the IMU rows in it that passed the parser with impossible values
    assert rec.meta["corrupt_frames"] == 1 + rec.meta["implausible_samples_dropped"]
    assert any("corruption" in n for n in rec.meta["notes"])
    assert 7000 < len(rec) < 7783


def test_cli_reports_bad_ulog_in_one_line(tmp_path):
    from tests.test_cli import run_cli

    p = tmp_path / "bad.ulg"
    p.write_bytes(_garbage_after(EVENTS, 16, 20000, 1))
    code, out, err = run_cli("ingest", str(p), "-o", str(tmp_path / "out.parquet"))
    assert code == 2 and "Traceback" not in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "out.parquet").exists()


def test_px4_clipping_fields_keep_the_gyro_apart():
    """sensor_combined / vehicle_imu clipping bit fields: the accelerometer's marks clipped alone, the
    gyro's clipped and gyr_clipped; a log with the accelerometer's field only (older PX4) marks no gyro."""
    from tepinn_flight.ingest.ulog import _clip_flags

    acc_f = np.array([0, 1, 0, 0, 4, 0], np.uint8)
    gyr_f = np.array([0, 0, 2, 0, 1, 0], np.uint8)
    c, g = _clip_flags({"accelerometer_clipping": acc_f, "gyro_clipping": gyr_f}, "gyro_clipping", "accelerometer_clipping",
                       slice(None), 6)  # fmt: skip
    np.testing.assert_array_equal(c, [False, True, True, False, True, False])
    np.testing.assert_array_equal(g, [False, False, True, False, True, False])
    c, g = _clip_flags({"accelerometer_clipping": acc_f}, "gyro_clipping", "accelerometer_clipping", slice(None), 6)
    np.testing.assert_array_equal(c, acc_f != 0)
    assert g.dtype == bool and not g.any()
    ok = np.array([True, True, False, True, True, True])
    c, g = _clip_flags({"delta_velocity_clipping": acc_f, "delta_angle_clipping": gyr_f}, "delta_angle_clipping",
                       "delta_velocity_clipping", ok, 5)  # fmt: skip
    np.testing.assert_array_equal(g, [False, False, False, True, False])


def test_a_gyro_at_its_range_is_marked_clipped_in_a_px4_log_without_a_gyro_clipping_field(tmp_path):
    """PX4 before v1.15 logs no gyro clipping field: the value rule every reader applies (ingest.saturation) marks
    the samples of a flip at ±2000 °/s, gyro apart (session 53: none were, where a DataFlash log's were)."""
    from tepinn_flight.ingest import load_record

    from .ulog_writer import SENSOR_COMBINED_V1_14, ULogWriter

    w = ULogWriter()
    w.fmt("sensor_combined", SENSOR_COMBINED_V1_14)
    w.subscribe("sensor_combined")
    full = np.radians(2000.0)
    for k in range(2500):  # 250 Hz, 0.4 s of it at the gyro's full scale, one sample at 16 g
        g = (full if 1000 <= k < 1100 else 0.1, 0.0, 0.0)
        a = (0.0, 0.0, -9.8 if k != 2000 else -16 * 9.81)
        w.data("sensor_combined", 0, 1_000_000 + 4000 * k, g, 4000, 0, a, 4000, 0)
    rec = load_record(w.write(tmp_path / "flip.ulg"))
    np.testing.assert_array_equal(np.flatnonzero(rec.gyr_clipped), np.arange(1000, 1100))
    np.testing.assert_array_equal(np.flatnonzero(rec.clipped), np.r_[np.arange(1000, 1100), 2000])
    assert any("marked clipped" in n for n in rec.meta["notes"])


def test_px4_gyro_clipping_bits_count_where_the_logged_rate_shows_a_saturation(tmp_path):
    """Rule 35: PX4's gyro clipping bits are the gyro's saturation where the logged rate reaches half its range (a flip
    at the range); bits set while the logged rate is far below it (raw samples clipped by vibration spikes) are left
    in `clipped` only, and said (review61: they had opened the saturation gate on a hand-held trial, 0.27° → 3.80°)."""
    from tepinn_flight.ingest import load_record

    from .ulog_writer import SENSOR_COMBINED_V1_15, ULogWriter

    w = ULogWriter()
    w.fmt("sensor_combined", SENSOR_COMBINED_V1_15)
    w.subscribe("sensor_combined")
    full = np.radians(2000.0)
    rate = np.full(2500, 0.1)
    rate[1000:1020] = np.linspace(0.45, 0.7, 20) * full  # a flip's rise: under half the range, then over it
    rate[1020:1100] = 0.97 * full  # at the range (under the value rule's 98 %): the bits alone say it
    bits = np.zeros(2500, np.uint8)
    bits[1000:1100] = 1  # the flip's clipped intervals
    bits[[300, 301, 1500, 1800, 1801]] = 1  # vibration: the logged rate 0.1 rad/s
    for k in range(2500):
        w.data("sensor_combined", 0, 1_000_000 + 4000 * k, (rate[k], 0.0, 0.0), 4000, 0, (0.0, 0.0, -9.8), 4000, 0, bits[k])
    rec = load_record(w.write(tmp_path / "bits.ulg"))
    kept = np.flatnonzero(rec.gyr_clipped)
    want = np.flatnonzero((bits != 0) & (np.abs(rate) >= 0.5 * full))
    np.testing.assert_array_equal(kept, want)
    assert kept[0] == 1004 and kept[-1] == 1099  # (the rise's first four bits are under half the range)
    np.testing.assert_array_equal(np.flatnonzero(rec.clipped), np.flatnonzero(bits))  # a sensor did clip
    assert any("9 of 105 sample(s) with PX4's gyro clipping bit" in n for n in rec.meta["notes"])


def test_sensor_combined_with_no_valid_accelerometer_sample_says_so(tmp_path):
    from tepinn_flight.errors import NoImuData
    from tepinn_flight.ingest import load_record
    from tepinn_flight.ingest.ulog import RELATIVE_TIMESTAMP_INVALID

    from .ulog_writer import SENSOR_COMBINED_V1_14, ULogWriter

    w = ULogWriter()
    w.fmt("sensor_combined", SENSOR_COMBINED_V1_14)
    w.subscribe("sensor_combined")
    for k in range(500):
        w.data("sensor_combined", 0, 1_000_000 + 4000 * k, (0.0, 0.0, 0.0), 4000, RELATIVE_TIMESTAMP_INVALID,
               (0.0, 0.0, -9.8), 4000, 0)  # fmt: skip
    with pytest.raises(NoImuData, match="every accelerometer sample is marked invalid"):
        load_record(w.write(tmp_path / "no_acc.ulg"))


def test_a_corrupt_float_in_a_ulog_field_is_cast_without_numpys_warning():
    """A damaged ULog can hold a signalling NaN in a float32 field: numpy's cast to float64 printed "RuntimeWarning:
    invalid value encountered in cast" with a source line into `estimate`'s output (a fuzzed copy of a shared PX4
    log, session 57). The row becomes NaN, which the readers judge as a non-finite sample."""
    import warnings

    from tepinn_flight.ingest.ulog import vec

    snan = np.array([0x7F800001], np.uint32).view(np.float32)
    data = {f"gyro_rad[{i}]": np.concatenate([np.float32([0.5]), snan]) for i in range(3)}
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        out = vec(data, "gyro_rad")
    assert out.dtype == np.float64 and (out[0] == 0.5).all() and np.isnan(out[1]).all()
