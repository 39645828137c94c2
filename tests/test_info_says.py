"""What `info` says of a record beyond its streams (review60): what a simulated record flew — the aircraft, seed,
sensor, turbulence and maneuvers had been only in the Parquet metadata — and the samples a reader dropped as logged
twice, which had gone unsaid."""

from __future__ import annotations

from tepinn_flight.cli.main import main
from tests.conftest import real_log


def test_info_names_what_a_simulated_record_flew(tmp_path, capsys):
    from tepinn_flight.record import write_record
    from tepinn_flight.sim.simulate import simulate_record

    rec = simulate_record("F450", 3.0, 400.0, 3, maneuvers=["hover", "flip"], turbulence="light")
    write_record(rec, tmp_path / "f.parquet")
    assert main(["info", str(tmp_path / "f.parquet")]) == 0
    line = next(ln for ln in capsys.readouterr().out.splitlines() if ln.strip().startswith("simulated"))
    assert f"F450, seed 3, sensor {rec.meta['sensor_preset']}, turbulence light, {rec.meta['termination']}" in line
    assert "maneuvers hover" in line


def test_info_says_how_many_samples_were_dropped_as_logged_twice(tmp_path, capsys):
    """A real text DataFlash log with 20 of its IMU lines written twice: the record holds each once, and `info` says
    20 were dropped."""
    src = real_log("aplogan_nan.log")
    lines = src.read_text().splitlines(keepends=True)
    out, doubled = [], 0
    for ln in lines:
        out.append(ln)
        if ln.startswith("IMU,") and doubled < 20:
            out.append(ln)
            doubled += 1
    log = tmp_path / "doubled.log"
    log.write_text("".join(out))
    assert main(["info", str(src)]) == 0
    plain = capsys.readouterr().out
    assert main(["info", str(log)]) == 0
    said = capsys.readouterr().out
    assert "duplicate samples" not in plain
    assert "duplicate samples    20 dropped (a time stamp logged twice: the first kept)" in said, said


def test_one_row_stamped_out_of_order_is_dropped_not_taken_for_a_reboot(tmp_path):
    """A real text DataFlash log with one IMU row stamped 60 ms early (a damaged low byte; under the 1-s spike rule):
    that row is dropped with a note, the record's time only goes forward, and no segment starts there (review60: it
    was kept, time went back and forth and the estimators restarted at that row)."""
    import numpy as np

    from tepinn_flight.ingest import ingest_log

    src = real_log("aplogan_nan.log")
    base = ingest_log(src)
    lines = src.read_text().splitlines(keepends=True)
    imu = [i for i, ln in enumerate(lines) if ln.startswith("IMU,")]
    k = imu[300]
    parts = lines[k].split(",")
    parts[1] = f" {int(parts[1]) - 60}"
    lines[k] = ",".join(parts)
    log = tmp_path / "early.log"
    log.write_text("".join(lines))
    rec = ingest_log(log)
    assert len(rec) == len(base) - 1 and rec.meta["segments"] == base.meta["segments"]
    assert np.all(np.diff(rec.t_s) > 0)
    assert any("out of order with their neighbours" in n for n in rec.meta["notes"]), rec.meta["notes"]


def test_a_reboot_is_not_out_of_order_but_a_lone_row_is():
    import numpy as np

    from tepinn_flight.ingest.assemble import out_of_order

    reboot = np.array([10.0, 10.1, 10.2, 10.3, 0.5, 0.6, 0.7])  # time goes back and stays back
    assert not out_of_order(reboot).any()
    early = np.array([10.0, 10.1, 10.2, 10.3, 10.14, 10.5, 10.6])  # one row stamped 260 ms early
    assert np.flatnonzero(out_of_order(early)).tolist() == [4]
    late = np.array([10.0, 10.1, 10.45, 10.3, 10.4, 10.5])  # one row stamped 250 ms late
    assert np.flatnonzero(out_of_order(late)).tolist() == [2]
    # under two periods off, a row and its neighbour read as two rows swapped: neither is dropped (the segment rule
    # breaks there, as before); so do a boot's first two samples logged in each other's place
    assert not out_of_order(np.array([10.0, 10.1, 10.35, 10.3, 10.4, 10.5])).any()
    assert not out_of_order(np.array([10.0, 10.1, 10.2, 10.14, 10.4, 10.5])).any()
    assert not out_of_order(np.array([109.98, 109.99, 5.01, 5.0, 5.02, 5.03])).any()
    assert not out_of_order(np.arange(10.0)).any() and not out_of_order(np.array([1.0, 0.0])).any()


def test_a_text_log_cut_inside_its_last_line_does_not_read_it(tmp_path):
    """A real text DataFlash log cut in the middle of a number on its last IMU line ("-9.504646" → "-9"): that line is
    not read, with a note (review60: read as −9.0 m/s², and a cut ATT yaw "186.16" as 1°, unsaid); the same log cut
    after a line end reads every whole line."""
    import numpy as np

    from tepinn_flight.ingest import ingest_log

    src = real_log("aplogan_nan.log")
    text = src.read_bytes()
    k = text.rfind(b"\nIMU,")
    end = text.index(b"\n", k + 1)
    whole = tmp_path / "whole.log"
    whole.write_bytes(text[: end + 1])
    line = text[k + 1 : end]
    cut_at = line.rfind(b".")  # inside the last field's number
    cut = tmp_path / "cut.log"
    cut.write_bytes(text[: k + 1 + cut_at])
    a, b = ingest_log(whole), ingest_log(cut)
    assert len(b) == len(a) - 1 and np.array_equal(b.acc_m_s2, a.acc_m_s2[:-1])
    assert any("ends inside a line" in n for n in b.meta["notes"]) and not any("ends inside" in n for n in a.meta["notes"])
    assert not any("no FMT definition" in n for n in b.meta["notes"])


def test_a_log_of_one_imu_sample_is_said_to_be_one(tmp_path):
    """One IMU sample has no rate: said so, not "0.0 Hz ... typical of a telemetry link" (review60)."""
    from tepinn_flight.ingest import ingest_log
    from tests.test_reader_choices import _dataflash

    rec = ingest_log(_dataflash(tmp_path / "one.bin", n=1))
    assert len(rec) == 1 and not rec.meta["estimation_ok"]
    assert "1 IMU sample(s): no rate to read, nothing to estimate (a log cut short?)" in rec.meta["notes"]
    assert not any("0.0 Hz" in n for n in rec.meta["notes"])
