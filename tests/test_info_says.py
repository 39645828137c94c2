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
