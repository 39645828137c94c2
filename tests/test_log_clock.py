"""The estimate on the log's own clock (``t_log_s``): the times the autopilot stamped its IMU with, read back
from a record's ``t_s``, checked against pymavlink reading the same logs."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from tests.conftest import real_log
from tepinn_flight.log_clock import log_clock_s


def _pymavlink_imu_times(path, message: str) -> np.ndarray:
    """Seconds on the log's clock of every autopilot ``message`` (component 1 in a tlog), in file order."""
    from pymavlink import mavutil

    conn = mavutil.mavlink_connection(str(path))
    out = []
    while (m := conn.recv_match(type=message)) is not None:
        if path.suffix == ".tlog" and m.get_srcComponent() != 1:
            continue
        d = m.to_dict()
        us = d.get("time_usec", d.get("TimeUS"))
        out.append(us / 1e6 if us is not None else d.get("time_boot_ms", d.get("TimeMS")) / 1e3)
    return np.array(out)


def test_the_log_clock_restarts_with_the_autopilot_at_a_reboot():
    """A real tlog with two boots: the record's t_s runs on across the reboot, the log clock restarts where the
    autopilot's did, and every sample's log time is one pymavlink reads from the log, in the same order."""
    from tepinn_flight.ingest import ingest_log

    path = real_log("uavlv_pr437_flight_logs.tlog")
    rec = ingest_log(path)
    assert rec.meta["boot_epochs"] == 2
    t_log = log_clock_s(rec.t_s, rec.meta)
    want = _pymavlink_imu_times(path, rec.meta["imu_message"])
    assert len(want) == len(t_log)  # (this log has no duplicate or out-of-order sample to drop)
    np.testing.assert_allclose(t_log, want, rtol=0, atol=1e-9)
    assert np.all(np.diff(rec.t_s) > 0) and np.sum(np.diff(t_log) < 0) == 1
    # a record of several boots that does not say where each starts (ingested before session 45): no clock
    old = {k: v for k, v in rec.meta.items() if k != "epoch_start_t_s"}
    assert log_clock_s(rec.t_s, old) is None


def test_the_estimate_carries_the_dataflash_clock_and_a_simulation_none(tmp_path):
    """`estimate LOG -o x.csv`: t_log_s beside t_s holds the DataFlash IMU's TimeMS; a simulated record (no log
    clock) gets no such column."""
    from tepinn_flight.cli.main import main
    from tepinn_flight.model.synthetic import synthetic_record
    from tepinn_flight.record import write_record

    path = real_log("erle_pxf_copter_15-12-2014_16.BIN")
    assert main(["estimate", str(path), "-o", str(tmp_path / "e.csv"), "-q"]) == 0
    est = pd.read_csv(tmp_path / "e.csv")
    assert list(est.columns[:3]) == ["t_s", "t_log_s", "q_est_w"]
    import json

    import pyarrow.parquet as pq

    assert main(["estimate", str(path), "-o", str(tmp_path / "e.parquet"), "-q"]) == 0
    conv = json.loads(pq.read_schema(tmp_path / "e.parquet").metadata[b"conventions"])  # the frames travel with it
    assert (conv["body_frame"], conv["earth_frame"], conv["quaternion_order"]) == ("FRD", "NED", "wxyz")
    want = _pymavlink_imu_times(path, "IMU")
    assert est["t_log_s"].iloc[0] == pytest.approx(want[0], abs=1e-9) and want[0] > 1.0  # not the record's 0
    got = est["t_log_s"].to_numpy()
    k = np.clip(np.searchsorted(want, got), 1, len(want) - 1)
    assert np.minimum(np.abs(want[k] - got), np.abs(want[k - 1] - got)).max() < 1e-9  # each one a TimeMS of the log
    np.testing.assert_allclose(got - est["t_s"].to_numpy(), want[0], rtol=0, atol=1e-9)  # one boot: one offset
    sim = tmp_path / "s.parquet"
    write_record(synthetic_record(seed=1, duration_s=8.0, rate_hz=100.0), sim)
    assert main(["estimate", str(sim), "-o", str(tmp_path / "s_est.parquet"), "-q"]) == 0
    assert "t_log_s" not in pd.read_parquet(tmp_path / "s_est.parquet").columns


def test_a_ulog_stamped_in_unix_time_gets_unix_time_back():
    """PX4 v1.15 SITL stamps in UNIX µs; ingest counts them from their first whole second to keep µs in float64.
    The log clock is the UNIX time again: pyulog's ``sensor_combined`` timestamps, sample for sample."""
    from pyulog import ULog

    from tepinn_flight.ingest import ingest_log

    path = real_log("pyulog_sample_px4_events.ulg")
    rec = ingest_log(path)
    assert rec.meta["time_base"] == "unix"
    t_log = log_clock_s(rec.t_s, rec.meta)
    want = ULog(str(path), ["sensor_combined"]).get_dataset("sensor_combined").data["timestamp"] / 1e6
    assert want[0] > 1.5e9 and t_log[0] == pytest.approx(want[0], abs=2e-6)
    k = np.clip(np.searchsorted(want, t_log), 1, len(want) - 1)
    nearest = np.minimum(np.abs(want[k] - t_log), np.abs(want[k - 1] - t_log))
    assert nearest.max() < 2e-6  # every sample one of the log's own stamps


def test_info_gives_the_log_clock_span(capsys):
    """`info` says where the record's t = 0 lies on the log's clock (erle: TimeMS 51.686 s, pymavlink's first IMU)."""
    from tepinn_flight.cli.main import main

    path = real_log("erle_pxf_copter_15-12-2014_16.BIN")
    want = _pymavlink_imu_times(path, "IMU")
    assert main(["info", str(path)]) == 0
    line = next(ln for ln in capsys.readouterr().out.splitlines() if "log clock" in ln)
    assert f"{want[0]:.3f} s to {want[-1]:.3f} s (TimeMS" in line


def test_a_boot_whose_first_sample_came_late_still_reads_its_own_clock():
    """A new boot's first two samples in file order swapped: its start was taken as the first in file order, so
    the earlier one fell before the boot's start in t_s and read the previous boot's clock (~100 s off)."""
    from tepinn_flight.ingest.assemble import build_record
    from tepinn_flight.ingest.streams import ImuStream, RawLog

    t0 = 100 + np.arange(1000) * 0.01
    t1 = 5 + np.arange(1000) * 0.01
    t1[[0, 1]] = t1[[1, 0]]
    t = np.concatenate([t0, t1])
    ep = np.r_[np.zeros(1000, int), np.ones(1000, int)]
    n = len(t)
    raw = RawLog(imu=ImuStream(t, np.zeros((n, 3)), np.tile([0.0, 0.0, -9.81], (n, 1)), epoch=ep),
                 meta={"source_kind": "dataflash"})  # fmt: skip
    rec = build_record(raw, "x.bin")
    t_log = log_clock_s(rec.t_s, rec.meta)
    # every sample of the record reads a time the log holds, and the second boot's start reads 5.00 s
    assert np.abs(t_log[:, None] - np.sort(t)[None, :]).min(axis=1).max() < 1e-9
    assert np.isclose(t_log[rec.t_s >= rec.meta["epoch_start_t_s"][1]], 5.0).any()
    assert not (t_log[rec.t_s >= rec.meta["epoch_start_t_s"][1]] > 50).any()
