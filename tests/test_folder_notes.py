"""A folder given to a verb: files named as logs that hold none are said to be left out, and each error is a line of
its own beside the progress bar (session 58's review: an empty ``00000042.BIN`` had gone unsaid, and an error written
while the bar was live began in the middle of the bar's line, so ``grep '^tepinn-flight'`` missed it)."""

from __future__ import annotations

from tepinn_flight.cli.main import main


def _lines(text: str) -> list[str]:
    return [ln for ln in text.replace("\r", "\n").split("\n") if "tepinn-flight" in ln]


def _folder(tmp_path):
    d = tmp_path / "LOGS"
    d.mkdir()
    (d / "00000042.BIN").write_bytes(b"")  # the commonest broken log on an SD card
    (d / "LASTLOG.TXT").write_text("42\n")  # not named as a log: left out silently
    for name in ("a.ulg", "b.ulg"):  # ULogs no reader can read: one error line each
        (d / name).write_bytes(b"ULog" + bytes(300))
    return d


def test_ingest_says_what_it_left_out_and_each_error_is_a_line(tmp_path, capsys):
    assert main(["ingest", str(_folder(tmp_path)), "-o", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    lines = _lines(err)
    assert any(ln.startswith("tepinn-flight ingest: note:") and ln.endswith("00000042.BIN: left out (empty file)")
               for ln in lines), lines  # fmt: skip
    assert sum(ln.startswith("tepinn-flight ingest: error:") for ln in lines) == 2, lines
    assert "LASTLOG" not in err


def test_info_and_estimate_say_it_too(tmp_path, capsys):
    from tepinn_flight.model.synthetic import synthetic_record
    from tepinn_flight.record import write_record

    d = _folder(tmp_path)
    write_record(synthetic_record(seed=1, duration_s=6.0, rate_hz=100.0), d / "r.parquet")
    assert main(["info", str(d)]) == 2
    assert any(ln.startswith("tepinn-flight info: note:") and "00000042.BIN: left out (empty file)" in ln
               for ln in _lines(capsys.readouterr().err))  # fmt: skip
    assert main(["estimate", str(d), "-o", str(tmp_path / "est")]) == 2
    lines = _lines(capsys.readouterr().err)
    assert any(ln.startswith("tepinn-flight estimate: note:") and "00000042.BIN: left out (empty file)" in ln
               for ln in lines), lines  # fmt: skip
    assert sum(ln.startswith("tepinn-flight estimate: error:") for ln in lines) == 2, lines
    assert (tmp_path / "est" / "r.parquet").exists()


def test_info_says_it_ignores_a_raw_logs_stream_choice_on_a_record(tmp_path, capsys):
    """`info --imu N` / `--reference SRC` choose among a raw log's streams; on a record they had been ignored unsaid."""
    from tepinn_flight.model.synthetic import synthetic_record
    from tepinn_flight.record import write_record

    write_record(synthetic_record(seed=1, duration_s=6.0, rate_hz=100.0), tmp_path / "r.parquet")
    assert main(["info", str(tmp_path / "r.parquet"), "--reference", "XKQ"]) == 0
    assert any("--imu and --reference choose among a raw log's streams" in ln for ln in _lines(capsys.readouterr().err))


def test_ingest_and_info_say_the_same_reference_coverage():
    """`ingest`'s line had rounded a reference on 99.7 % of the samples to "100% covered", where `info` said 99.7 %."""
    import numpy as np

    from tepinn_flight.cli.summary import record_summary_line, render_info
    from tepinn_flight.model.synthetic import synthetic_record
    from tepinn_flight.record import QREF_COLS, FlightRecord
    from tepinn_flight.record_stats import summarize

    rec = synthetic_record(seed=1, duration_s=10.0, rate_hz=100.0)
    data = rec.data.copy()
    data.loc[data.index[:3], QREF_COLS] = np.nan  # 3 of 1000 rows without a reference
    rec = FlightRecord(data, dict(rec.meta))
    s = summarize(rec)
    rec.meta["reference_coverage"] = s["reference_coverage"]
    assert "(99.7% covered)" in record_summary_line(rec) and "covers 99.7% of IMU samples" in render_info("r", s)
