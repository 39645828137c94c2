"""``estimate --tlog``: the source tlog's messages plus the estimate from component 191, read back by pymavlink."""

from __future__ import annotations

import os

os.environ["MAVLINK20"] = "1"  # before pymavlink (mavlink.md §2)

import numpy as np
import pandas as pd
import pytest

from tepinn_flight.cli.main import main
from tepinn_flight.record import write_record
from tepinn_flight.tlog_writer import DEFAULT_BOOT_OFFSET_S, write_tlog

torch = pytest.importorskip("torch")

EST = ["q_est_w", "q_est_x", "q_est_y", "q_est_z"]


def _read(path):
    from pymavlink import mavutil

    conn = mavutil.mavlink_connection(str(path))
    out = []
    while (m := conn.recv_match()) is not None:
        if m.get_type() != "BAD_DATA":
            out.append(m)
    return out


@pytest.fixture(scope="module")
def flight(tmp_path_factory):
    """A simulated flight as an ArduPilot tlog, ingested into a record next to it."""
    from tepinn_flight.ingest import ingest_log
    from tepinn_flight.model.synthetic import synthetic_record

    d = tmp_path_factory.mktemp("flight")
    write_tlog(d / "flight.tlog", synthetic_record(seed=3, duration_s=10.0, rate_hz=100.0))
    rec = ingest_log(d / "flight.tlog")
    write_record(rec, d / "flight.parquet")
    return d


def _check(msgs, est, t_boot_of_row):
    """Every 191 estimate message sits right after the IMU message it belongs to (same receive time,
    same boot time) and carries that row's estimate."""
    t_rows = t_boot_of_row(est["t_s"].to_numpy())
    q_rows = est[EST].to_numpy()
    aq_seen = 0
    last_imu = None
    for m in msgs:
        src = (m.get_srcSystem(), m.get_srcComponent())
        if src == (1, 1) and m.get_type() == "HIGHRES_IMU":
            last_imu = m
        if src != (1, 191) or m.get_type() == "HEARTBEAT":
            continue
        assert last_imu is not None
        assert m._timestamp == pytest.approx(last_imu._timestamp, abs=1e-6)  # on the log's clock
        if m.get_type() == "ATTITUDE_QUATERNION":
            assert m.time_boot_ms == round(last_imu.time_usec / 1000)
            i = int(np.argmin(np.abs(t_rows - m.time_boot_ms / 1e3)))
            assert abs(t_rows[i] - m.time_boot_ms / 1e3) < 1e-3
            np.testing.assert_allclose([m.q1, m.q2, m.q3, m.q4], q_rows[i], atol=1e-6)
            aq_seen += 1
        elif m.get_type() == "DEBUG_VECT":
            assert m.name == "TP_RPY" and m.time_usec == last_imu.time_usec
    return aq_seen


def test_estimate_tlog_from_a_tlog_source(flight, capsys):
    out = flight / "est.parquet"
    code = main(["estimate", str(flight / "flight.parquet"), "-o", str(out), "--tlog", str(flight / "est.tlog")])
    assert code == 0, capsys.readouterr().err
    est = pd.read_parquet(out)
    src, msgs = _read(flight / "flight.tlog"), _read(flight / "est.tlog")
    # the source log's own messages, all of them, unchanged and in order
    own = [m for m in msgs if m.get_srcComponent() != 191]
    assert [m.get_msgbuf() for m in own] == [m.get_msgbuf() for m in src]
    assert [m._timestamp for m in own] == [m._timestamp for m in src]
    ts = [m._timestamp for m in msgs]
    assert ts == sorted(ts)  # the estimate interleaves in time
    types = {m.get_type() for m in msgs if m.get_srcComponent() == 191}
    assert types == {"HEARTBEAT", "ATTITUDE_QUATERNION", "DEBUG_VECT"}  # no second ATTITUDE stream by default
    # boot time of a record row: the tlog writer's boot offset, one boot epoch
    n = _check(msgs, est, lambda t: t + DEFAULT_BOOT_OFFSET_S)
    ok = est["q_est_w"].notna()
    span = est["t_s"][ok].iloc[-1] - est["t_s"][ok].iloc[0]
    assert abs(n - (span * 50 + 1)) <= 2  # 50 Hz of log time while the estimate exists


def test_estimate_tlog_other_sources_and_options(tmp_path, capsys):
    from tepinn_flight.model.synthetic import synthetic_record

    rec = synthetic_record(seed=4, duration_s=10.0, rate_hz=100.0)  # source_kind "synthetic": no tlog
    write_record(rec, tmp_path / "syn.parquet")
    code = main(["estimate", str(tmp_path / "syn.parquet"), "-o", str(tmp_path / "syn-est.parquet"), "-q",
                 "--tlog", str(tmp_path / "syn.tlog"), "--tlog-messages", "attitude,named_value", "--tlog-rate", "10"])  # fmt: skip
    assert code == 0, capsys.readouterr().err
    est = pd.read_parquet(tmp_path / "syn-est.parquet")
    msgs = _read(tmp_path / "syn.tlog")
    by = {}
    for m in msgs:
        by.setdefault((m.get_srcComponent(), m.get_type()), []).append(m)
    assert len(by[(1, "HIGHRES_IMU")]) == len(rec)  # the record's IMU as standard messages
    assert (1, "ATTITUDE_QUATERNION") in by  # and its reference attitude
    att = by[(191, "ATTITUDE")]
    nv = by[(191, "NAMED_VALUE_FLOAT")]
    assert (191, "ATTITUDE_QUATERNION") not in by and (191, "DEBUG_VECT") not in by
    assert len(nv) == 3 * len(att) and {m.name for m in nv} == {"tp_roll", "tp_pitch", "tp_yaw"}
    t0 = est["t_s"].iloc[0]
    t_rows = est["t_s"].to_numpy() - t0 + DEFAULT_BOOT_OFFSET_S
    q = est[EST].to_numpy()
    from tepinn_flight.quat import quat_to_euler_zyx

    for a in att:
        i = int(np.argmin(np.abs(t_rows - a.time_boot_ms / 1e3)))
        r, p, y = (float(v[0]) for v in quat_to_euler_zyx(q[i : i + 1]))
        np.testing.assert_allclose([a.roll, a.pitch, a.yaw], [r, p, y], atol=1e-5)
    ms = np.array([a.time_boot_ms for a in att])
    assert np.all(np.abs(np.diff(ms) - 100) <= 10)  # --tlog-rate 10 Hz of log time


def test_estimate_tlog_bad_options_are_one_line_errors(flight, capsys):
    rec = str(flight / "flight.parquet")
    for extra, words in (
        (["--tlog", str(flight / "x.tlog"), "--tlog-messages", "hud"], "--tlog-messages"),
        (["--source-log", str(flight / "flight.tlog")], "--source-log goes with --tlog"),
        (["--tlog", str(flight / "x.tlog"), "--source-log", str(flight / "nope.tlog")], "no such file"),
    ):
        code = main(["estimate", rec, "-o", str(flight / "x.parquet"), *extra])
        err = capsys.readouterr().err
        assert code == 2 and words in err and err.count("\n") == 1, err
        assert not (flight / "x.parquet").exists() and not (flight / "x.tlog").exists()


def test_a_source_log_of_another_flight_is_refused(flight, tmp_path, capsys, monkeypatch):
    """Another flight of the same autopilot, logged from the same boot time at the same rate, holds IMU samples at
    the record's times: it was taken as the source and the record's estimate written among that flight's messages.
    Its gyro readings are not the record's: one line, exit 2, no tlog."""
    from tepinn_flight import estimate_tlog
    from tepinn_flight.model.synthetic import synthetic_record

    other = tmp_path / "other.tlog"
    write_tlog(other, synthetic_record(seed=4, duration_s=10.0, rate_hz=100.0))
    args = ["estimate", str(flight / "flight.parquet"), "-o", str(tmp_path / "e.parquet"), "-q", "--tlog",
            str(tmp_path / "e.tlog")]  # fmt: skip
    code = main([*args, "--source-log", str(other)])
    err = capsys.readouterr().err
    assert code == 2 and "not the record's gyro readings" in err and err.count("\n") == 1, err
    assert not (tmp_path / "e.tlog").exists()
    assert not (tmp_path / "e.parquet").exists()  # an input error leaves no output (the Parquet was written first)
    # the times alone matched it (the check the samples' values now add)
    monkeypatch.setattr(estimate_tlog, "_same_samples", lambda a, b: True)
    assert main([*args, "--source-log", str(other)]) == 0 and (tmp_path / "e.tlog").exists()
    # the record's own tlog passes, named or found next to the record
    (tmp_path / "e.tlog").unlink()
    monkeypatch.undo()
    assert main([*args, "--source-log", str(flight / "flight.tlog")]) == 0 and (tmp_path / "e.tlog").exists()


def test_resume_rewrites_a_tlog_whose_options_changed(flight, tmp_path, capsys):
    """`estimate --resume` with other `--tlog-messages` or `--tlog-rate`: the tlog's options are part of the output's
    key, so it is written again (it had been "up to date" and left as it was); the same options skip it."""
    args = ["estimate", str(flight / "flight.parquet"), "-o", str(tmp_path / "e.parquet"), "--tlog", str(tmp_path / "e.tlog")]
    assert main([*args, "-q", "--tlog-messages", "attitude_quaternion"]) == 0
    kinds = {m.get_type() for m in _read(tmp_path / "e.tlog") if m.get_srcComponent() == 191} - {"HEARTBEAT"}
    assert kinds == {"ATTITUDE_QUATERNION"}
    assert main([*args, "--resume", "--tlog-messages", "attitude_quaternion"]) == 0
    assert "up to date" in capsys.readouterr().out
    assert main([*args, "--resume", "--tlog-messages", "named_value", "--tlog-rate", "5"]) == 0
    assert "up to date" not in capsys.readouterr().out
    kinds = {m.get_type() for m in _read(tmp_path / "e.tlog") if m.get_srcComponent() == 191} - {"HEARTBEAT"}
    assert kinds == {"NAMED_VALUE_FLOAT"}


def test_resume_rewrites_a_tlog_another_run_left_there(flight, tmp_path, capsys):
    """A tlog at the asked place that is not the one written with the estimate (another run wrote its tlogs elsewhere
    after): `--resume` writes both again (review61: a 10-Hz tlog had been kept "up to date" for a 50-Hz estimate)."""
    a = ["estimate", str(flight / "flight.parquet"), "-o", str(tmp_path / "e.parquet"), "-q"]
    assert main([*a, "--tlog", str(tmp_path / "A.tlog"), "--tlog-rate", "10"]) == 0
    assert main([*a, "--tlog", str(tmp_path / "B.tlog")]) == 0  # e.parquet now goes with B.tlog (50 Hz)
    capsys.readouterr()
    assert main([*a[:-1], "--tlog", str(tmp_path / "A.tlog"), "--resume"]) == 0
    assert "up to date" not in capsys.readouterr().out
    rate = lambda p: len([m for m in _read(p) if m.get_srcComponent() == 191 and m.get_type() == "ATTITUDE_QUATERNION"])  # noqa: E731
    assert rate(tmp_path / "A.tlog") == rate(tmp_path / "B.tlog") > 0  # A rewritten at the 50 Hz asked now
    assert main([*a[:-1], "--tlog", str(tmp_path / "A.tlog"), "--resume"]) == 0  # the pair written together: kept
    assert "up to date" in capsys.readouterr().out


def test_a_tlogs_record_without_its_source_keeps_the_logs_clock(flight, tmp_path, capsys):
    """A record of a tlog whose source tlog is not beside it is written as itself, on the log's own boot clock: each
    estimate's time_boot_ms is the Parquet's t_log_s (review61: 10 s after the record's start, up to 13.7 s off)."""
    from tepinn_flight.ingest import ingest_log
    from tepinn_flight.model.synthetic import synthetic_record

    (tmp_path / "src").mkdir()
    write_tlog(tmp_path / "src" / "f.tlog", synthetic_record(seed=6, duration_s=10.0, rate_hz=100.0), boot_offset_s=123.4)
    write_record(ingest_log(tmp_path / "src" / "f.tlog"), tmp_path / "moved.parquet")  # (not beside its tlog)
    assert main(["estimate", str(tmp_path / "moved.parquet"), "-o", str(tmp_path / "e.parquet"), "-q",
                 "--tlog", str(tmp_path / "e.tlog")]) == 0  # fmt: skip
    assert "source tlog" in capsys.readouterr().err  # (the fallback is said)
    est = pd.read_parquet(tmp_path / "e.parquet")
    t_log = est["t_log_s"].to_numpy()
    aq = [m for m in _read(tmp_path / "e.tlog") if m.get_srcComponent() == 191 and m.get_type() == "ATTITUDE_QUATERNION"]
    assert len(aq) > 100 and abs(t_log[0] - 123.4) < 0.02  # (a clock the writer's default would not give)
    for m in aq:
        i = int(np.argmin(np.abs(t_log - m.time_boot_ms / 1e3)))
        assert abs(t_log[i] - m.time_boot_ms / 1e3) <= 0.6e-3
        np.testing.assert_allclose([m.q1, m.q2, m.q3, m.q4], est[EST].to_numpy()[i], atol=1e-6)


def test_a_record_of_two_boots_runs_on_from_its_first_boots_clock(tmp_path):
    """A tlog's record of two boots, without its source: the written tlog's clock is the first boot's, run on across
    the reboot (as the docs say; review61: the writer's 10-s default, 113 s off the log's clock)."""
    from tepinn_flight.ingest import ingest_log
    from tepinn_flight.model.synthetic import synthetic_record
    from tepinn_flight.tlog_writer import DEFAULT_START_UNIX_S

    (tmp_path / "src").mkdir()
    for k, (boot, seed) in enumerate(((123.4, 7), (2.0, 8))):
        write_tlog(tmp_path / f"b{k}.tlog", synthetic_record(seed=seed, duration_s=8.0, rate_hz=100.0), boot_offset_s=boot,
                   start_unix_s=DEFAULT_START_UNIX_S + 60.0 * k)  # fmt: skip
    (tmp_path / "src" / "two.tlog").write_bytes((tmp_path / "b0.tlog").read_bytes() + (tmp_path / "b1.tlog").read_bytes())
    rec = ingest_log(tmp_path / "src" / "two.tlog")
    assert len(rec.meta["epoch_time_offsets_s"]) == 2
    write_record(rec, tmp_path / "two.parquet")
    assert main(["estimate", str(tmp_path / "two.parquet"), "-o", str(tmp_path / "e.parquet"), "-q",
                 "--tlog", str(tmp_path / "e.tlog")]) == 0  # fmt: skip
    est = pd.read_parquet(tmp_path / "e.parquet")
    t_log, t = est["t_log_s"].to_numpy(), est["t_s"].to_numpy()
    ms = np.array([m.time_boot_ms for m in _read(tmp_path / "e.tlog")
                   if m.get_srcComponent() == 191 and m.get_type() == "ATTITUDE_QUATERNION"])  # fmt: skip
    assert len(ms) > 500 and np.all(np.diff(ms) > 0)  # one clock, on across the reboot
    np.testing.assert_allclose(ms / 1e3, t_log[0] + (t[:: max(1, len(t) // len(ms))][: len(ms)] - t[0]), atol=0.1)
    assert abs(ms[0] / 1e3 - t_log[0]) <= 0.6e-3 and abs(t_log[0] - 123.4) < 0.02


def test_the_tlogs_rates_bridge_a_hole_as_the_estimate_does(tmp_path, capsys):
    """(review61: NaN rollspeed in the estimate's ATTITUDE where the gyro had a non-finite sample)"""
    from tepinn_flight.model.synthetic import synthetic_record

    rec = synthetic_record(seed=5, duration_s=8.0, rate_hz=100.0)
    rec.data.loc[400:404, "gyr_x_rad_s"] = np.nan
    write_record(rec, tmp_path / "holes.parquet")
    assert main(["estimate", str(tmp_path / "holes.parquet"), "-o", str(tmp_path / "e.parquet"), "-q",
                 "--tlog", str(tmp_path / "e.tlog"), "--tlog-rate", "100", "--tlog-messages", "attitude"]) == 0  # fmt: skip
    att = [m for m in _read(tmp_path / "e.tlog") if m.get_srcComponent() == 191 and m.get_type() == "ATTITUDE"]
    assert len(att) > 500
    rates = np.array([[m.rollspeed, m.pitchspeed, m.yawspeed] for m in att])
    assert np.all(np.isfinite(rates))
    est = pd.read_parquet(tmp_path / "e.parquet")
    b = est[["gyr_bias_est_x_rad_s", "gyr_bias_est_y_rad_s", "gyr_bias_est_z_rad_s"]].to_numpy()
    i = int(np.argmin(np.abs(np.array([m.time_boot_ms for m in att]) / 1e3 - (est["t_s"][402] - est["t_s"][0] + DEFAULT_BOOT_OFFSET_S))))
    np.testing.assert_allclose(rates[i, 0], rec.gyr_rad_s[399, 0] - b[402, 0], atol=1e-6)  # the last finite sample's


def test_mavexplorer_graphs_evaluate_on_the_written_tlog(flight):
    """tools/mavexplorer_tepinn.xml: well-formed, and every expression evaluates (pymavlink's own
    evaluator, as MAVExplorer's grapher uses it) once the tlog's messages are seen."""
    import xml.etree.ElementTree as ET
    from pathlib import Path

    from pymavlink import mavutil

    from tepinn_flight.estimate_tlog import write_estimate_tlog  # noqa: F401 - the writer the graphs are for

    xml = Path(__file__).resolve().parents[1] / "tools" / "mavexplorer_tepinn.xml"
    graphs = ET.parse(xml).getroot().findall("graph")
    assert len(graphs) >= 2 and all(g.get("name", "").startswith("TE-PINN/") for g in graphs)
    tlog = flight / "est.tlog"
    if not tlog.exists():
        assert main(["estimate", str(flight / "flight.parquet"), "-o", str(flight / "est.parquet"), "-q", "--tlog", str(tlog)]) == 0
    latest = {}
    for m in _read(tlog):
        latest[m.get_type()] = m
    for g in graphs:
        for expr in g.findall("expression"):
            for field in expr.text.split():
                v = mavutil.evaluate_expression(field, latest)
                assert v is not None and np.isfinite(v), (g.get("name"), field)


def test_a_dataflash_logs_tlog_keeps_the_logs_clock_and_every_sample_at_its_rate(tmp_path, capsys):
    """`estimate erle.BIN --tlog`: the tlog was stamped 10 s after an invented boot, so its estimate did not line up
    with the log's TimeMS, and fixed 20-ms ticks dropped 22 % of this 50-Hz log's estimates (its stamps step
    18–21 ms). Now time_boot_ms is the log's own clock (the estimate's t_log_s) and every estimate is written."""
    from tests.conftest import real_log

    log = real_log("erle_pxf_copter_15-12-2014_16.BIN")
    out = tmp_path / "e.parquet"
    assert main(["estimate", str(log), "-o", str(out), "--tlog", str(tmp_path / "e.tlog"), "-q"]) == 0
    est = pd.read_parquet(out)
    aq = [m for m in _read(tmp_path / "e.tlog") if m.get_srcComponent() == 191 and m.get_type() == "ATTITUDE_QUATERNION"]
    ok = est["q_est_w"].notna().to_numpy()
    assert len(aq) == int(ok.sum())  # every estimate of a log at the tlog's rate
    want_ms = np.round(est["t_log_s"].to_numpy()[ok] * 1e3).astype(np.int64)
    assert [m.time_boot_ms for m in aq] == want_ms.tolist()
    np.testing.assert_allclose([[m.q1, m.q2, m.q3, m.q4] for m in aq], est[EST].to_numpy()[ok], atol=1e-6)

