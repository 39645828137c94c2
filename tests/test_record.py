"""Flight record: round trip, atomic writes, validation, format_version, assembly rules."""

from __future__ import annotations

import json
import os

import numpy as np
import pyarrow.parquet as pq
import pytest

from tepinn_flight import quat as Q
from tepinn_flight.errors import RecordFormatError
from tepinn_flight.ingest.assemble import build_record
from tepinn_flight.ingest.streams import ImuStream, MagStream, RawLog, RefStream, detect_epochs
from tepinn_flight.record import (
    FORMAT_VERSION,
    REQUIRED_COLUMNS,
    FlightRecord,
    make_frame,
    read_record,
    write_record,
)


def sample_record(n=500, seed=0, **extra) -> FlightRecord:
    rng = np.random.default_rng(seed)
    t = np.arange(n) / 100.0
    seg = np.zeros(n, int)
    seg[n // 2 :] = 1
    t[n // 2 :] += 1.0  # a gap
    q = Q.quat_canonical(Q.quat_normalize(rng.normal(size=(n, 4))))
    q[:10] = np.nan
    df = make_frame(t, seg, rng.normal(size=(n, 3)), rng.normal(size=(n, 3)) - [0, 0, 9.81], None, q,
                    rng.random(n) < 0.01, **extra)  # fmt: skip
    meta = {"source_file": "x.bin", "source_kind": "dataflash", "imu_rate_hz": 100.0,
            "reference_source": "ATT", "vehicle_type": "quadrotor", "notes": ["a", "b"]}  # fmt: skip
    return FlightRecord(df, meta)


def test_round_trip_is_exact(tmp_path):
    rec = sample_record(gyr_bias_rad_s=np.ones((500, 3)) * 0.01, valid=np.arange(500) % 2 == 0)
    p = tmp_path / "r.parquet"
    write_record(rec, p)
    back = read_record(p)
    assert list(back.data.columns[: len(REQUIRED_COLUMNS)]) == REQUIRED_COLUMNS
    for c in rec.data.columns:
        np.testing.assert_array_equal(back.data[c].to_numpy(), rec.data[c].to_numpy())
    assert back.meta["format_version"] == FORMAT_VERSION
    assert back.meta["notes"] == ["a", "b"] and back.meta["imu_rate_hz"] == 100.0
    # second trip: identical again
    write_record(back, tmp_path / "r2.parquet")
    again = read_record(tmp_path / "r2.parquet")
    assert again.data.equals(back.data) and again.meta == back.meta
    assert back.data["segment"].dtype == np.int32 and back.data["clipped"].dtype == bool


def test_gyro_clipping_column_round_trips_and_stands_in_for_clipped(tmp_path):
    rng = np.random.default_rng(3)
    gyr_clip = rng.random(500) < 0.02
    rec = sample_record(gyr_clipped=gyr_clip)
    np.testing.assert_array_equal(rec.gyr_clipped, gyr_clip)
    assert np.all(rec.clipped[gyr_clip])  # the gyro's clipping is part of clipped
    write_record(rec, tmp_path / "r.parquet")
    back = read_record(tmp_path / "r.parquet")
    assert back.data["gyr_clipped"].dtype == bool
    np.testing.assert_array_equal(back.gyr_clipped, gyr_clip)
    from tepinn_flight.record_stats import summarize

    st = summarize(back)
    assert st["gyr_clipped_samples"] == gyr_clip.sum() and st["clipped_samples"] == back.clipped.sum() > gyr_clip.sum()
    plain = sample_record()  # a reader that cannot tell the sensors apart: every clipped sample counts
    assert "gyr_clipped" not in plain.data and np.array_equal(plain.gyr_clipped, plain.clipped)
    bad = sample_record(gyr_clipped=gyr_clip)
    bad.data["clipped"] = False
    with pytest.raises(RecordFormatError, match="gyr_clipped marks samples that clipped does not"):
        write_record(bad, tmp_path / "bad.parquet")
    assert not (tmp_path / "bad.parquet").exists()


def test_metadata_is_plain_json_key_value(tmp_path):
    p = tmp_path / "r.parquet"
    write_record(sample_record(), p)
    md = pq.read_schema(p).metadata
    assert json.loads(md[b"format_version"]) == FORMAT_VERSION
    assert json.loads(md[b"source_kind"]) == "dataflash"


def test_unknown_format_version_refused(tmp_path):
    p = tmp_path / "r.parquet"
    write_record(sample_record(), p)
    table = pq.read_table(p)
    md = dict(table.schema.metadata)
    md[b"format_version"] = b"99"
    pq.write_table(table.replace_schema_metadata(md), p)
    with pytest.raises(RecordFormatError, match="unknown format_version 99"):
        read_record(p)


def test_non_record_parquet_and_garbage_refused(tmp_path):
    import pandas as pd

    p = tmp_path / "other.parquet"
    pd.DataFrame({"a": [1, 2]}).to_parquet(p)
    with pytest.raises(RecordFormatError, match="format_version"):
        read_record(p)
    g = tmp_path / "garbage.parquet"
    g.write_bytes(os.urandom(1000))
    with pytest.raises(RecordFormatError, match="not a Parquet"):
        read_record(g)


def test_validation_catches_bad_records(tmp_path):
    rec = sample_record()
    bad = FlightRecord(rec.data.drop(columns=["gyr_x_rad_s"]), rec.meta)
    with pytest.raises(RecordFormatError, match="missing columns"):
        write_record(bad, tmp_path / "x.parquet")
    d = rec.data.copy()
    d.loc[5, "t_s"] = d.loc[4, "t_s"]  # not strictly increasing inside segment 0
    with pytest.raises(RecordFormatError, match="strictly increase"):
        write_record(FlightRecord(d, rec.meta), tmp_path / "x.parquet")
    d = rec.data.copy()
    d.loc[5, "t_s"] = np.nan  # (passes every comparison: it used to reach the estimator, which failed inside)
    with pytest.raises(RecordFormatError, match="1 non-finite time stamp"):
        write_record(FlightRecord(d, rec.meta), tmp_path / "x.parquet")
    assert not list(tmp_path.iterdir())  # nothing left behind


def test_atomic_write_leaves_old_file_intact_on_crash(tmp_path, monkeypatch):
    import pyarrow.parquet as pqm

    p = tmp_path / "r.parquet"
    write_record(sample_record(seed=1), p)
    before = p.read_bytes()

    def boom(table, where, **kw):
        with open(where, "wb") as f:
            f.write(b"PAR1 half written")
        raise OSError("disk full")

    monkeypatch.setattr(pqm, "write_table", boom)
    with pytest.raises(OSError):
        write_record(sample_record(seed=2), p)
    assert p.read_bytes() == before
    assert [x.name for x in tmp_path.iterdir()] == ["r.parquet"]  # temp file removed


# ---------------------------------------------------------------- assembly rules


def _raw(t, ep=None, ref=None):
    n = len(t)
    imu = ImuStream(np.asarray(t, float), np.zeros((n, 3)), np.tile([0, 0, -9.81], (n, 1)), epoch=ep)
    return RawLog(imu=imu, ref=ref, meta={"source_kind": "tlog"})


def test_segments_split_at_gaps_reversals_and_reboots():
    t = np.r_[np.arange(0, 1, 0.01), np.arange(1.5, 2, 0.01)]  # gap of 0.5 s = 50 periods
    rec = build_record(_raw(t), "x")
    assert rec.meta["segments"] == 2 and np.all(np.diff(rec.segment) >= 0)
    assert abs(rec.meta["imu_rate_hz"] - 100) < 1e-6
    # a gap of exactly 2 periods stays in the segment, 3 periods splits
    t2 = np.r_[np.arange(0, 1, 0.01), 0.99 + 0.02 + np.arange(0, 1, 0.01)]
    assert build_record(_raw(t2), "x").meta["segments"] == 1
    t3 = np.r_[np.arange(0, 1, 0.01), 0.99 + 0.03 + np.arange(0, 1, 0.01)]
    assert build_record(_raw(t3), "x").meta["segments"] == 2
    # reboot: the clock starts again; record time continues and stays increasing
    tb = np.r_[np.arange(5, 6, 0.01), np.arange(0.2, 1.2, 0.01)]
    ep = detect_epochs(tb)
    rec = build_record(_raw(tb, ep), "x")
    assert rec.meta["segments"] == 2 and rec.meta["boot_epochs"] == 2
    assert np.all(np.diff(rec.t_s) > 0)
    assert rec.t_s[0] == 0.0


def test_reference_is_slerped_and_nan_outside_coverage():
    t = np.arange(0, 2, 0.01)
    w = np.array([0.0, 0.0, 1.0])  # 1 rad/s yaw
    tr = np.arange(0.5, 1.5, 0.1)
    qr = Q.quat_from_rotvec(tr[:, None] * w)
    rec = build_record(_raw(t, ref=RefStream(tr, qr, "ATT")), "x")
    q = rec.q_ref_wxyz
    inside = (t >= 0.5 - 1e-9) & (t <= tr[-1] - 1e-9)
    outside = (t < 0.5 - 1e-9) | (t > tr[-1] + 1e-9)
    assert np.all(np.isfinite(q[inside])) and np.all(np.isnan(q[outside]))
    np.testing.assert_allclose(Q.quat_to_rotvec(q[inside])[:, 2], t[inside], atol=1e-9)
    assert rec.meta["reference_source"] == "ATT"
    assert abs(rec.meta["reference_rate_hz"] - 10) < 1e-6


def test_reference_gap_gives_nan_not_interpolation():
    t = np.arange(0, 3, 0.01)
    tr = np.r_[np.arange(0, 1, 0.1), np.arange(2, 3, 0.1)]  # 1 s hole in the reference
    qr = np.tile([1.0, 0, 0, 0], (len(tr), 1))
    q = build_record(_raw(t, ref=RefStream(tr, qr, "ATT")), "x").q_ref_wxyz
    hole = (t > 1.0) & (t < 2.0)
    assert np.all(np.isnan(q[hole])) and np.all(np.isfinite(q[(t > 0.05) & (t < 0.85)]))


def test_mag_is_interpolated_onto_imu_times():
    t = np.arange(0, 1, 0.01)
    tm = np.arange(0, 1, 0.05)
    m = np.stack([tm, 2 * tm, -tm], 1) * 10
    raw = _raw(t)
    raw.mag = MagStream(tm, m)
    rec = build_record(raw, "x")
    ok = t <= tm[-1]
    np.testing.assert_allclose(rec.mag_ut[ok], np.stack([t, 2 * t, -t], 1)[ok] * 10, atol=1e-9)


def test_low_rate_is_said_plainly():
    rec = build_record(_raw(np.arange(0, 60, 0.5)), "x")  # 2 Hz telemetry
    assert rec.meta["estimation_ok"] is False
    assert any("too slow" in n for n in rec.meta["notes"])


def test_reference_nan_sample_is_a_hole_and_knots_are_exact():
    """A single NaN reference sample is not interpolated over; samples at knots take the knot."""
    t = np.arange(0, 1, 0.01)
    qr = Q.quat_from_rotvec(np.stack([t, 0 * t, 0 * t], 1))
    qr[50] = np.nan  # one dropout (e.g. optical markers lost)
    rec = build_record(_raw(t, ref=RefStream(t, qr, "optitrack")), "x")
    q = rec.q_ref_wxyz
    assert np.isnan(q[50]).all()
    ok = np.ones(len(t), bool)
    ok[50] = False
    np.testing.assert_allclose(q[ok], Q.quat_canonical(qr[ok]), atol=1e-12)  # 49 and 51 kept


def test_segment_slices_cover_each_segment_in_order():
    from tepinn_flight.record import segment_slices

    seg = np.array([0, 0, 0, 1, 3, 3, 4], np.int32)
    sl = segment_slices(seg)
    assert [(s.start, s.stop) for s in sl] == [(0, 3), (3, 4), (4, 6), (6, 7)]
    for s in sl:  # a naive reference: every slice holds one segment id, and all of it
        assert len(set(seg[s])) == 1 and (seg == seg[s][0]).sum() == s.stop - s.start
    assert segment_slices(np.zeros(0, np.int32)) == []


def test_info_counts_lost_samples_and_the_stamps_jitter_inside_segments(tmp_path, capsys):
    # 100 Hz, stamps jittered by N(0, (0.05 period)²), 7 single samples lost (steps of two periods) in the first
    # segment; the 1-s gap to the second is a break, not a lost sample
    from tepinn_flight.cli.main import main
    from tepinn_flight.record_stats import summarize

    rec = sample_record(n=2000)
    rng = np.random.default_rng(4)
    d = rec.data.copy()
    d["t_s"] = d["t_s"] + rng.normal(0.0, 0.0005, len(d))
    lost = np.zeros(len(d), bool)
    lost[[100, 250, 400, 555, 700, 850, 990]] = True
    rec = FlightRecord(d[~lost].reset_index(drop=True), dict(rec.meta))
    st = summarize(rec)
    assert st["lost_steps"] == 7 and st["steps"] == len(rec) - 2  # one step per pair inside each of the 2 segments
    steps = np.diff(rec.t_s)[np.diff(rec.segment) == 0] * 100.0
    assert st["step_jitter"] == pytest.approx(np.std(steps[steps < 1.5]), rel=1e-9)
    assert st["step_jitter"] == pytest.approx(0.05 * np.sqrt(2), rel=0.1)  # the difference of two stamps' errors
    write_record(rec, tmp_path / "r.parquet")
    assert main(["info", str(tmp_path / "r.parquet")]) == 0
    out = capsys.readouterr().out
    assert f"7 of {len(rec) - 2} (0.35 %) of about two periods" in out and "jitter 7.1 % of the period" in out


def test_info_says_a_stretch_logged_at_a_lower_rate_in_one_line(tmp_path, capsys):
    # 200 Hz for 10 s, then 25 Hz (a GCS lowering a tlog's stream rate), then 0.5 s of silence and 200 Hz again:
    # ingest breaks every 25-Hz step (8 periods of the 200-Hz median), each bridged; the 0.5-s gap is a plain break
    from tepinn_flight.cli.main import main
    from tepinn_flight.record_stats import slower_stretches, summarize

    t = np.r_[np.arange(0, 10, 0.005), 10 + np.arange(1, 201) * 0.04]
    t = np.r_[t, t[-1] + 0.5 + np.arange(0, 5, 0.005)]
    rec = build_record(_raw(t), "x")
    st = summarize(rec)
    assert st["segments"] == 202 and len(st["gaps"]) == 201  # 200 slow steps and the 0.5-s gap
    (slow,) = st["slower_stretches"]
    assert slow["steps"] == 200 and slow["rate_hz"] == pytest.approx(25.0)
    assert slow["from_s"] == pytest.approx(t[1999]) and slow["to_s"] == pytest.approx(t[2199])
    write_record(rec, tmp_path / "r.parquet")
    assert main(["info", str(tmp_path / "r.parquet")]) == 0
    out = capsys.readouterr().out
    assert "IMU at 25.0 Hz from t=9.995 s to 18.000 s: each of its 200 steps a break" in out
    assert out.count("break at t=") == 1 and "step +0.500 s" in out  # the one plain break, not 200 lines
    assert "15.0 s in segments, 8.0 s more across the dropouts the estimators bridge (span 23.5 s)" in out
    # scattered dropouts are no stretch: fewer than MIN_SLOWER_RUN in a row, or not all bridged
    assert slower_stretches(t, np.arange(100, 119), [True] * 19, 0.005) == []
    assert slower_stretches(t, np.arange(100, 130), [True] * 10 + [False] + [True] * 19, 0.005) == []


def test_info_reads_the_sensors_noise_per_sample_through_motion():
    # white noise of known σ on a 200-Hz record whose signal swings at 5 Hz, far larger than the noise:
    # the second differences read the noise, not the motion; a segment break is not a step
    from tepinn_flight.record_stats import sample_noise, summarize

    rng = np.random.default_rng(7)
    t = np.arange(0, 60, 0.005)
    seg = (t >= 30).astype(np.int32)
    swing = 3.0 * np.sin(2 * np.pi * 5.0 * t)[:, None] * np.ones(3)
    acc = swing + np.array([0.0, 0.0, -9.81]) + 0.4 * rng.normal(size=(len(t), 3))
    gyr = 0.02 * swing + np.radians(0.3) * rng.normal(size=(len(t), 3))
    assert sample_noise(acc, seg, 0.005) == pytest.approx(0.4, rel=0.05)
    assert np.degrees(sample_noise(gyr, seg, 0.005)) == pytest.approx(0.3, rel=0.05)
    jump = acc.copy()
    jump[seg == 1] += 50.0  # a jump between segments is no change inside one
    assert sample_noise(jump, seg, 0.005) == pytest.approx(sample_noise(acc, seg, 0.005), rel=1e-9)
    assert np.std(np.diff(acc, axis=0)) / np.sqrt(2) > 1.1 * 0.4  # a first difference reads the motion too
    assert sample_noise(acc[:5], seg[:5], 0.005) is None  # less than one window
    rec = sample_record(n=3000)
    st = summarize(rec)
    assert st["acc_noise_m_s2"] == pytest.approx(sample_noise(rec.acc_m_s2, rec.segment, 1.0 / rec.meta["imu_rate_hz"]))


def test_a_record_holding_values_past_any_sensor_is_refused_in_one_line(tmp_path, capsys):
    """A damaged record (a flipped byte made a gyro sample 2e295 rad/s: `info` and `estimate` printed pages of numpy
    overflow warnings and `evaluate` an internal ZeroDivisionError, session 57's fuzzing) is refused on reading with
    the column named, as is one written in other units (deg/s as rad/s); NaN holes and zero quaternions (no
    reference) stay allowed, and values at the limits pass."""
    from tepinn_flight.cli.main import main
    from tepinn_flight.model.synthetic import synthetic_record
    from tepinn_flight.record import MAX_GYRO_RAD_S, FlightRecord

    rec = synthetic_record(seed=1, duration_s=10.0, rate_hz=100.0)
    holes = rec.data.copy()
    holes.loc[5, "gyr_y_rad_s"] = np.nan
    holes.loc[7, ["q_ref_w", "q_ref_x", "q_ref_y", "q_ref_z"]] = 0.0
    holes.loc[9, "gyr_x_rad_s"] = MAX_GYRO_RAD_S
    write_record(FlightRecord(holes, dict(rec.meta)), tmp_path / "ok.parquet")
    assert read_record(tmp_path / "ok.parquet").gyr_rad_s[9, 0] == MAX_GYRO_RAD_S

    damaged = rec.data.copy()
    damaged.loc[100, "acc_y_m_s2"] = 9.8e307
    with pytest.raises(RecordFormatError, match=r"acc_y_m_s2 holds 1 value\(s\) beyond ±2000 m/s², past any sensor"):
        FlightRecord(damaged, dict(rec.meta)).validate()
    infinite = rec.data.copy()
    infinite.loc[100, "gyr_y_rad_s"] = -np.inf  # one infinity: said to be one, not a unit written wrong (review60)
    with pytest.raises(RecordFormatError, match=r"gyr_y_rad_s holds 1 infinite value\(s\): a damaged file") as e:
        FlightRecord(infinite, dict(rec.meta)).validate()
    assert "degrees per second" not in str(e.value)
    degrees = rec.data.copy()
    degrees[["gyr_x_rad_s", "gyr_y_rad_s", "gyr_z_rad_s"]] *= 3000.0  # a hand-written record in the wrong unit
    with pytest.raises(RecordFormatError, match=r"degrees per second written as rad/s"):
        FlightRecord(degrees, dict(rec.meta)).validate()

    path = tmp_path / "damaged.parquet"  # written around the check, as a damaged file would be
    import pyarrow as pa

    table = pa.Table.from_pandas(damaged, preserve_index=False)
    meta = {k.encode(): json.dumps(v).encode() for k, v in {**rec.meta, "format_version": FORMAT_VERSION}.items()}
    pq.write_table(table.replace_schema_metadata({**(table.schema.metadata or {}), **meta}), path)
    for verb in (["info", str(path)], ["estimate", str(path), "-o", str(tmp_path / "e.parquet")],
                 ["evaluate", str(path), "-o", str(tmp_path / "ev"), "--no-peers", "-q"]):  # fmt: skip
        assert main(verb) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "acc_y_m_s2 holds 1 value(s)" in err[0] and "Warning" not in err[0], err


def test_a_reference_quaternion_that_is_no_rotation_is_no_reference(tmp_path, capsys):
    """Zeros (a broken logger's "none") or a row whose norm is off 1 by more than 0.1 read as NaN from
    ``q_ref_wxyz`` — every scorer had taken them for attitudes: an all-zero reference scored 180° for all nine
    estimators. On a record half zeros, `evaluate` scores the other half against the truth."""
    from tepinn_flight.cli.main import main
    from tepinn_flight.model.synthetic import synthetic_record

    rec = synthetic_record(seed=3, duration_s=30.0, rate_hz=100.0)
    d = rec.data.copy()
    q = d[["q_ref_w", "q_ref_x", "q_ref_y", "q_ref_z"]].to_numpy().copy()
    q[: len(q) // 2] = 0.0
    q[-3] *= 1.2  # a damaged row
    d[["q_ref_w", "q_ref_x", "q_ref_y", "q_ref_z"]] = q
    half = FlightRecord(d, dict(rec.meta))
    got = half.q_ref_wxyz
    assert np.isnan(got[: len(q) // 2]).all() and np.isnan(got[-3]).all()
    assert np.array_equal(got[len(q) // 2 : -3], q[len(q) // 2 : -3])  # unit rows untouched, to the bit
    write_record(half, tmp_path / "half.parquet")
    assert main(["evaluate", str(tmp_path / "half.parquet"), "-o", str(tmp_path / "ev"), "--no-peers", "-q"]) == 0
    metrics = json.loads((tmp_path / "ev" / "metrics.json").read_text())
    capsys.readouterr()
    text = json.dumps(metrics)
    assert "180.0" not in text
    d[["q_ref_w", "q_ref_x", "q_ref_y", "q_ref_z"]] = 0.0
    write_record(FlightRecord(d, dict(rec.meta)), tmp_path / "none.parquet")
    assert main(["evaluate", str(tmp_path / "none.parquet"), "-o", str(tmp_path / "ev2"), "--no-peers", "-q"]) == 2
    assert "no reference" in capsys.readouterr().err


def test_evaluate_refuses_a_record_without_an_accelerometer_sample_and_leaves_it_out_of_a_folder(tmp_path, capsys):
    """As `estimate` does: a record without one finite accelerometer (or gyro) sample has nothing to estimate; named,
    it is a one-line error; in a folder it is left out with a note and the others are scored (every estimator had
    been scored on it: TE-PINN 85°, RIANN 113°)."""
    from tepinn_flight.cli.main import main
    from tepinn_flight.model.synthetic import synthetic_record

    rec = synthetic_record(seed=4, duration_s=20.0, rate_hz=100.0)
    d = rec.data.copy()
    d[["acc_x_m_s2", "acc_y_m_s2", "acc_z_m_s2"]] = np.nan
    folder = tmp_path / "in"
    folder.mkdir()
    write_record(FlightRecord(d, dict(rec.meta)), folder / "no_acc.parquet")
    assert main(["evaluate", str(folder / "no_acc.parquet"), "-o", str(tmp_path / "ev"), "--no-peers", "-q"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "no finite accelerometer sample in the record" in err[0]
    write_record(rec, folder / "good.parquet")
    assert main(["evaluate", str(folder), "-o", str(tmp_path / "ev2"), "--no-peers", "-q"]) == 0
    capsys.readouterr()
    assert "no_acc.parquet: left out (no finite accelerometer sample" in (tmp_path / "ev2" / "report.md").read_text()
    names = [r["name"] for r in json.loads((tmp_path / "ev2" / "metrics.json").read_text())["records"]]
    assert names == ["good"]
