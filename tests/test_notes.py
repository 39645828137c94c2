"""What ingest/info/estimate tell a user: slow-IMU advice per format, ULog dropout notes on the
record's clock, and one clear line for a raw log or an unknown file given to `estimate`."""

from __future__ import annotations

import numpy as np
import pytest

from tepinn_flight.ingest.assemble import build_record
from tepinn_flight.ingest.streams import ImuStream, RawLog
from tests.conftest import real_log


def _slow_note(rec) -> str:
    return next(n for n in rec.meta["notes"] if "too slow" in n)


def test_slow_imu_advice_fits_the_format():
    from tepinn_flight.ingest import ingest_log

    # a 10 Hz DataFlash log IS the onboard log: never "use the onboard log instead"
    t = np.arange(200) * 0.1
    raw = RawLog(ImuStream(t, np.zeros((200, 3)), np.tile([0, 0, -9.81], (200, 1))), meta={"source_kind": "dataflash"})
    note = _slow_note(build_record(raw, "plane.bin"))
    assert "this is the onboard log" in note and "LOG_BITMASK" in note and "instead" not in note
    # a telemetry tlog (4.2 Hz, real): the onboard log is the answer
    note = _slow_note(ingest_log(real_log("uavlv_vtol.tlog")))
    assert "telemetry" in note and "onboard log" in note and "instead" in note
    # a decimated ULog (9.6 Hz, real): the logging profile is
    note = _slow_note(ingest_log(real_log("pxrs_esc_status_log.ulg")))
    assert "SDLOG_PROFILE" in note and "instead" not in note


def test_ulog_dropout_notes_are_on_the_record_clock_and_skip_zero_ms(monkeypatch):
    """pyulog_sample_px4_events.ulg is stamped in UNIX µs; two dropouts are added to what pyulog
    parsed: one of 0 ms (nothing lost) and one of 20 ms 10 s into the IMU samples."""
    import tepinn_flight.ingest.ulog as U
    from tepinn_flight.ingest import ingest_log

    path = real_log("pyulog_sample_px4_events.ulg")
    parse = U._parse

    class Drop:
        def __init__(self, timestamp, duration):
            self.timestamp, self.duration = timestamp, duration

    def with_dropouts(p):
        ulog, printed = parse(p)
        t_us = ulog.get_dataset("sensor_combined").data["timestamp"]
        ulog._dropouts = [Drop(int(t_us[0]) + 5_000_000, 0), Drop(int(t_us[0]) + 10_000_000, 20)]
        return ulog, printed

    monkeypatch.setattr(U, "_parse", with_dropouts)
    rec = ingest_log(path)
    drops = [n for n in rec.meta["notes"] if "dropout" in n]
    assert not any(" 0 ms" in n for n in drops)
    assert rec.meta["skipped_frames"] == 1 and len(rec.meta["ulog_dropouts"]) == 1
    assert len(drops) == 1 and "t=10.000 s (record time)" in drops[0], drops
    # the IMU lost no sample there (its stamps run on): no sample dropped, no break made (session 53)
    assert "no IMU sample lost there" in drops[0]
    assert not np.any(np.abs(rec.t_s[np.flatnonzero(np.diff(rec.segment))] - 10.0) < 0.05)
    assert rec.meta["ulog_dropouts"][0]["imu_samples_lost"] == 0


def test_estimate_on_a_raw_log_ingests_it_and_on_an_unknown_file_says_one_line(tmp_path, capsys):
    from tepinn_flight.cli.main import main
    from tepinn_flight.record import RecordFormatError, read_record

    unknown = tmp_path / "notes.txt"
    unknown.write_text("not a log\n")
    assert main(["estimate", str(unknown), "-o", str(tmp_path / "o.parquet")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "not a ULog, DataFlash, HDF5 (BROAD), MAVLink tlog or flight record" in err[0]
    assert "Parquet magic" not in err[0] and "footer" not in err[0]
    # read_record itself (other verbs that take records only) points at `ingest`, not at pyarrow
    with pytest.raises(RecordFormatError, match="run `tepinn-flight ingest` on it first") as ei:
        read_record(real_log("ardusub_small.BIN"))
    assert "footer" not in str(ei.value)
    # a raw log: ingested on the fly, estimated, one row per IMU sample
    out = tmp_path / "est.parquet"
    assert main(["estimate", str(real_log("ardusub_small.BIN")), "-o", str(out), "-q"]) == 0
    import pandas as pd

    assert len(pd.read_parquet(out)) == 594
