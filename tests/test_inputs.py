"""What a folder on the command line stands for (ingest/inputs.py): the logs and records in it, told by
content, not by name; a named file as given; one-line errors; the verbs that take folders."""

from __future__ import annotations

import json
import os

import pytest

from tepinn_flight.cli.main import main
from tepinn_flight.errors import TepinnError
from tepinn_flight.ingest.inputs import LOG_FORMATS, RECORD_OR_LOG_FORMATS, expand, files_in
from tepinn_flight.ingest.sniff import sniff
from tests.conftest import real_log

FMT_LINE = b"FMT, 128, 89, FMT, BBnNZ, Type,Length,Name,Format,Columns\n"


@pytest.fixture
def folder(tmp_path):
    """A log folder as users have them: logs under any name, a record, notes, a hidden file, a subfolder."""
    from tepinn_flight.model.synthetic import synthetic_record
    from tepinn_flight.record import write_record

    d = tmp_path / "logs"
    (d / "2024-05-01").mkdir(parents=True)
    (d / "flight.txt").write_bytes(FMT_LINE)  # a DataFlash text log, whatever its name
    (d / "00000042.BIN").write_bytes(b"\xa3\x95\x80\x80" + bytes(60))  # DataFlash binary
    (d / "LASTLOG.TXT").write_text("42\n")
    (d / "notes.ulg").write_text("not a log, whatever its name")
    (d / ".partial.ulg").write_bytes(b"ULog\x01\x12\x35" + bytes(60))  # hidden: a download in progress
    (d / "2024-05-01" / "12_34_56.ulg").write_bytes(b"ULog\x01\x12\x35" + bytes(60))
    write_record(synthetic_record(seed=1, duration_s=2.0, rate_hz=100.0), d / "rec.parquet")
    return d


def test_a_folder_stands_for_its_logs_and_records_told_by_content(folder):
    logs = files_in(folder, LOG_FORMATS)
    # sorted; the content decides what a log is; a file under a name only logs go by that holds none (notes.ulg) is
    # handed on as a log that cannot be read — the verb says so, exit 2 (review60: a note and exit 0 before)
    assert [p.name for p in logs] == ["00000042.BIN", "flight.txt", "notes.ulg"]
    assert [sniff(p) for p in logs[:2]] == ["dataflash-bin", "dataflash-text"]
    with pytest.raises(TepinnError, match="not a ULog"):
        sniff(logs[2])
    both = files_in(folder, RECORD_OR_LOG_FORMATS)
    assert [p.name for p in both] == ["00000042.BIN", "flight.txt", "notes.ulg", "rec.parquet"]
    deep = files_in(folder, RECORD_OR_LOG_FORMATS, recursive=True)
    assert [p.relative_to(folder).as_posix() for p in deep] == ["00000042.BIN", "2024-05-01/12_34_56.ulg",
                                                               "flight.txt", "notes.ulg", "rec.parquet"]  # fmt: skip


def test_expand_keeps_named_files_and_fails_in_one_line(folder, tmp_path):
    named = folder / "notes.ulg"  # named on the command line: taken as given (the verb says what it is)
    assert expand([str(named), str(folder)]) == [named, *(f for f in files_in(folder, RECORD_OR_LOG_FORMATS) if f != named)]
    with pytest.raises(TepinnError, match="no such file or folder") as e:
        expand([str(tmp_path / "nope")])
    assert e.value.path == str(tmp_path / "nope")
    empty = tmp_path / "empty"
    empty.mkdir()
    (empty / "rec.parquet").write_bytes(b"PAR1" + bytes(20))
    with pytest.raises(TepinnError, match="holds no logs"):
        expand([str(empty)], LOG_FORMATS)  # a record is not a log to ingest
    assert expand([str(empty)]) == [empty / "rec.parquet"]


def test_ingest_a_folder_writes_each_log_and_names_the_one_that_fails(tmp_path, capsys):
    """A real log in a folder (a link to the shared one) beside a broken log and a note: the real one is
    ingested as when named, the broken one is a one-line error (exit 2), the note is not a log."""
    from tepinn_flight.ingest import ingest_log
    from tepinn_flight.record import read_record

    log = real_log("erle_pxf_copter_15-12-2014_16.BIN")
    d = tmp_path / "LOGS"
    d.mkdir()
    os.symlink(log, d / "00000016.BIN")
    (d / "00000017.BIN").write_bytes(b"\xa3\x95" + os.urandom(200))  # cut short by a brown-out
    (d / "LASTLOG.TXT").write_text("17\n")
    out = tmp_path / "records"
    assert main(["ingest", str(d), "-o", str(out)]) == 2
    cap = capsys.readouterr()
    errors = [ln for ln in cap.err.splitlines() if "error" in ln]
    assert len(errors) == 1 and "00000017.BIN" in errors[0]
    assert sorted(p.name for p in out.iterdir()) == ["00000016.parquet"]
    rec, direct = read_record(out / "00000016.parquet"), ingest_log(log)
    assert len(rec) == len(direct) == 7600
    assert (rec.gyr_rad_s == direct.gyr_rad_s).all()
    # a folder's logs go to a folder even where it holds one: -o names the folder
    one = tmp_path / "one"
    one.mkdir()
    os.symlink(log, one / "00000016.BIN")
    assert main(["ingest", str(one), "-o", str(tmp_path / "out1"), "-q"]) == 0
    assert [p.name for p in (tmp_path / "out1").iterdir()] == ["00000016.parquet"]


def test_evaluate_a_folder_leaves_out_what_it_cannot_read_with_a_note(tmp_path, capsys):
    from tepinn_flight.model.synthetic import synthetic_record
    from tepinn_flight.record import write_record

    d = tmp_path / "recs"
    d.mkdir()
    write_record(synthetic_record(seed=3, duration_s=12.0, rate_hz=100.0), d / "good.parquet")
    (d / "broken.ulg").write_bytes(b"ULog\x01\x12\x35" + bytes(60))  # a ULog with nothing after its header
    rep = tmp_path / "rep"
    assert main(["evaluate", str(d), "-o", str(rep), "--no-peers", "--no-model", "-q"]) == 0
    metrics = json.loads((rep / "metrics.json").read_text())
    assert [r["name"] for r in metrics["records"]] == ["good"]
    assert any(str(d / "broken.ulg") in n and "left out" in n for n in metrics["notes"])
    # named on the command line, the same file is an error, not a note
    assert main(["evaluate", str(d / "good.parquet"), str(d / "broken.ulg"), "-o", str(tmp_path / "rep2"),
                 "--no-peers", "--no-model", "-q"]) == 2  # fmt: skip
    assert "broken.ulg" in capsys.readouterr().err
    # a folder of which nothing can be read: one line naming what was wrong (no evaluation, so no notes after it)
    only = tmp_path / "only"
    only.mkdir()
    (only / "broken.ulg").write_bytes(b"ULog\x01\x12\x35" + bytes(60))
    assert main(["evaluate", str(only), "-o", str(tmp_path / "rep3"), "--no-peers", "--no-model", "-q"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "none of the 1 records or logs given could be read" in err[0] and "broken.ulg" in err[0]


def test_recursive_takes_the_subfolders_too(folder, capsys):
    """``-r``: the PX4 SD card's dated folder is searched too — ``info`` reads (here: reports in one line, a 60-byte
    stub does not parse) the log in it, which it does not look at without ``-r``."""
    from tepinn_flight.cli.paths import collect_records

    sub = folder / "2024-05-01" / "12_34_56.ulg"
    assert sub in collect_records([str(folder)], recursive=True) and sub not in collect_records([str(folder)])
    main(["info", str(folder)])
    assert str(sub) not in capsys.readouterr().err
    main(["info", "-r", str(folder)])
    cap = capsys.readouterr()
    assert str(sub) in cap.err and str(folder / "rec.parquet") in cap.out
