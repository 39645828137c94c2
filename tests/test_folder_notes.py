"""A folder given to a verb: files named as logs that hold none are said to be left out, and each error is a line of
its own beside the progress bar (session 58's review: an empty ``00000042.BIN`` had gone unsaid, and an error written
while the bar was live began in the middle of the bar's line, so ``grep '^tepinn-flight'`` missed it)."""

from __future__ import annotations

from tepinn_flight.cli.main import main
from tests.conftest import real_log


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


def test_a_damaged_or_unreadable_log_in_a_folder_is_an_error_and_exit_2(tmp_path, capsys):
    """A folder's log that cannot be read — random bytes under an ArduPilot `.BIN` name, a tlog without a frame, a file
    the user may not read — is one error line and exit 2 at the end, as where it is named on the command line
    (review60: a note and exit 0, so a nightly batch never learned of them); an empty `.BIN` stays a note, and a
    `.log` that is no DataFlash text — every program's log file, such as this run's own — stays a note too."""
    import os

    import numpy as np

    from tepinn_flight.model.synthetic import synthetic_record
    from tepinn_flight.record import write_record

    d = tmp_path / "LOGS"
    d.mkdir()
    write_record(synthetic_record(seed=1, duration_s=6.0, rate_hz=100.0), d / "good.parquet")
    (d / "00000042.BIN").write_bytes(b"")
    (d / "00000043.BIN").write_bytes(np.random.default_rng(0).integers(0, 256, 4096, dtype=np.uint8).tobytes())
    (d / "flight.tlog").write_bytes(bytes(2000))
    (d / "run.log").write_text("estimating 3 records\n")
    locked = d / "00000044.BIN"
    locked.write_bytes(b"\xa3\x95" + bytes(100))
    locked.chmod(0)
    can_lock = not os.access(locked, os.R_OK)  # (root reads any file: the permission case is then not made)
    assert main(["estimate", str(d), "-o", str(tmp_path / "est")]) == 2
    lines = _lines(capsys.readouterr().err)
    errors = [ln for ln in lines if ln.startswith("tepinn-flight estimate: error:")]
    assert any("00000043.BIN" in ln for ln in errors) and any("flight.tlog" in ln for ln in errors), lines
    assert can_lock == any("00000044.BIN" in ln and "Permission denied" in ln for ln in errors), lines
    notes = [ln for ln in lines if ln.startswith("tepinn-flight estimate: note:")]
    assert any(ln.endswith("00000042.BIN: left out (empty file)") for ln in notes), lines
    assert any("run.log: left out" in ln for ln in notes) and not any("run.log" in ln for ln in errors), lines
    assert (tmp_path / "est" / "good.parquet").exists()
    # every verb the same way: ingest and info exit 2; evaluate leaves them out with a note (its documented rule)
    assert main(["info", str(d)]) == 2
    assert any("00000043.BIN" in ln for ln in _lines(capsys.readouterr().err) if ": error:" in ln)
    assert main(["ingest", str(d), "-o", str(tmp_path / "ing")]) == 2
    assert any("00000043.BIN" in ln for ln in _lines(capsys.readouterr().err) if ": error:" in ln)


def test_a_folders_notes_come_in_path_order(tmp_path):
    """The left-out notes in the order of the files' names, not the folder's listing order (review60)."""
    from tepinn_flight.ingest.inputs import RECORD_OR_LOG_FORMATS, files_in

    for n in (11, 9, 10, 12, 3, 17, 1, 14, 6, 20, 8, 2):  # (twelve: a listing in name order by chance is ~1 in 5e8)
        (tmp_path / f"{n:08d}.BIN").write_bytes(b"")
    notes: list[str] = []
    assert files_in(tmp_path, RECORD_OR_LOG_FORMATS, notes=notes) == []
    assert notes == sorted(notes) and len(notes) == 12


def test_a_folder_run_ends_with_its_count_and_ingest_says_each_logs_notes(tmp_path, capsys):
    """After a folder's run with failures, one closing line counts them (review60: the errors had to be counted);
    `ingest` says each record's notes under its line — what the reader dropped or chose (review60: said by `info`
    alone); a read-only output folder is refused once, before any log is read (shown where the user is not root)."""
    import os

    from tepinn_flight.model.synthetic import synthetic_record
    from tepinn_flight.record import write_record

    d = _folder(tmp_path)
    write_record(synthetic_record(seed=1, duration_s=6.0, rate_hz=100.0), d / "r.parquet")
    assert main(["estimate", str(d), "-o", str(tmp_path / "est")]) == 2
    err = capsys.readouterr().err.splitlines()
    assert err[-1] == "tepinn-flight estimate: 2 of 3 input(s) failed (the lines above); 1 estimated or up to date"
    src = real_log("aplogan_nan.log")
    assert main(["ingest", str(src), "-o", str(tmp_path / "a.parquet")]) == 0
    out = capsys.readouterr().out.splitlines()
    from tepinn_flight.record import read_record

    notes = read_record(tmp_path / "a.parquet").meta["notes"]
    assert notes and out[1:] == [f"  note: {n}" for n in notes]
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o555)
    if not os.access(ro, os.W_OK):  # (root writes anywhere)
        assert main(["ingest", str(d), "-o", str(ro / "x")]) == 2
        assert capsys.readouterr().err.count("cannot write") == 1
