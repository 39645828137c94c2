"""Bad input found before any work and said in one line, nothing lost (session 53's review,
`/work/review53/evalcli`): two options naming one output, an output that cannot be written only found at the end,
a report replacing the record it reads, records with nothing to estimate, a file where a folder goes, a bad
checkpoint found after a demo's flights, NaN in `info --json`, a checkpoint's refused setting without its file."""

from __future__ import annotations

import json
import warnings
from pathlib import Path

import numpy as np
import pytest

from tepinn_flight.cli.main import main
from tepinn_flight.model.synthetic import synthetic_record
from tepinn_flight.record import ACC_COLS, GYR_COLS, FlightRecord, write_record


def _one_error_line(capsys, *words) -> str:
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in err, err
    for w in words:
        assert w in err, err
    return err


def _record(tmp_path, name="r.parquet", **cols):
    rec = synthetic_record(seed=1, duration_s=8.0, rate_hz=100.0)
    data = rec.data.copy()
    for c, v in cols.items():
        data[c] = v
    p = tmp_path / name
    write_record(FlightRecord(data, dict(rec.meta)), p)
    return p


def test_bridge_refuses_one_name_for_two_outputs(tmp_path, capsys):
    s = tmp_path / "session"
    assert main(["bridge", "--master", "udpin:127.0.0.1:14971", "--tlog", str(s), "--summary-json", str(s),
                 "--duration", "1"]) == 2  # fmt: skip
    _one_error_line(capsys, "--summary-json", "is also --tlog", "name two outputs")
    assert not s.exists()


def test_bridge_refuses_a_summary_it_could_not_write_before_the_session(tmp_path, capsys):
    f = tmp_path / "a_file"
    f.write_text("x")
    assert main(["bridge", "--master", "udpin:127.0.0.1:14972", "--summary-json", str(f / "s.json"),
                 "--duration", "30"]) == 2  # fmt: skip (refused now, not 30 s later)
    _one_error_line(capsys, "cannot create it")


def test_evaluate_never_replaces_a_record_it_reads(tmp_path, capsys):
    p = _record(tmp_path, "metrics.json")  # a record is told by its content, whatever its name
    before = p.read_bytes()
    assert main(["evaluate", str(p), "-o", str(tmp_path), "-q", "--no-peers"]) == 2
    _one_error_line(capsys, "is the input", "metrics.json")
    assert p.read_bytes() == before


@pytest.mark.parametrize("col, what", [("acc_x", "accelerometer"), ("gyr_y", "gyro")])
def test_estimate_refuses_a_record_with_no_finite_imu_sample(tmp_path, capsys, col, what):
    cols = dict.fromkeys(ACC_COLS if col.startswith("acc") else GYR_COLS, np.nan)
    p = _record(tmp_path, **cols)
    assert main(["estimate", str(p), "-o", str(tmp_path / "e.parquet"), "-q"]) == 2
    _one_error_line(capsys, f"no finite {what} sample")
    assert not (tmp_path / "e.parquet").exists()


def test_estimate_refuses_an_accelerometer_written_as_zeros_and_reads_a_g_unit_one(tmp_path, capsys):
    """An accelerometer of zeros (a sensor not logged) shows no gravity: `estimate` had given a full attitude with a σ
    as confident as on real data, and the scale reading called 0 g "within the tolerance". One written in g (1.0 at
    rest) is still estimated: the scale self-calibration divides it out."""
    p = _record(tmp_path, **dict.fromkeys(ACC_COLS, 0.0))
    assert main(["estimate", str(p), "-o", str(tmp_path / "e.parquet"), "-q"]) == 2
    _one_error_line(capsys, "the accelerometer reads under 0.5 m/s² on every sample")
    assert not (tmp_path / "e.parquet").exists()
    from tepinn_flight.model.accel_scale import AccelScale

    assert "no gravity to read a scale from" in AccelScale(1.0, False, 0.0, 6.0).describe()
    rec = synthetic_record(seed=2, duration_s=20.0, rate_hz=100.0)
    data = rec.data.copy()
    data[ACC_COLS] = data[ACC_COLS] / 9.80665
    g = tmp_path / "g.parquet"
    write_record(FlightRecord(data, dict(rec.meta)), g)
    assert main(["estimate", str(g), "-o", str(tmp_path / "eg.parquet"), "-q"]) == 0


def test_estimate_refuses_a_record_without_samples(tmp_path, capsys):
    rec = synthetic_record(seed=1, duration_s=2.0, rate_hz=100.0)
    p = tmp_path / "zero.parquet"
    write_record(FlightRecord(rec.data.iloc[:0].reset_index(drop=True), dict(rec.meta)), p)
    assert main(["estimate", str(p), "-o", str(tmp_path / "e.parquet"), "-q"]) == 2
    _one_error_line(capsys, "no IMU sample")


def test_ablate_to_a_file_is_one_line(tmp_path, capsys):
    f = tmp_path / "f.parquet"
    f.write_text("x")
    tiny = Path(__file__).resolve().parents[1] / "train" / "tiny.toml"
    assert main(["ablate", "--config", str(tiny), "-o", str(f), "-q"]) == 2
    _one_error_line(capsys, "exists and is not a folder")


def test_demo_checks_its_model_before_flying(tmp_path, capsys):
    out = tmp_path / "demo"
    assert main(["demo", "--duration", "11", "-o", str(out), "--model", str(tmp_path / "missing.pt"), "-q"]) == 2
    _one_error_line(capsys, "no such model")
    assert not out.exists()


def test_info_json_is_json_with_an_all_nan_gyro(tmp_path, capsys):
    p = _record(tmp_path, **dict.fromkeys(GYR_COLS, np.nan))
    assert main(["info", str(p), "--json"]) == 0
    cap = capsys.readouterr()
    s = json.loads(cap.out, parse_constant=lambda c: pytest.fail(f"{c} in info --json"))[str(p)]
    assert s["max_axis_rate_deg_s"] == [None, None, None]
    assert "Warning" not in cap.err


def test_a_checkpoint_setting_refused_names_the_file(tmp_path, capsys):
    import torch

    from tepinn_flight.model.checkpoint import default_model_path

    ck = torch.load(default_model_path(), map_location="cpu", weights_only=True)
    ck["model_config"] = {**ck["model_config"], "window_tokens": -3}
    bad = tmp_path / "bad_setting.pt"
    torch.save(ck, bad)
    p = _record(tmp_path)
    assert main(["estimate", str(p), "-o", str(tmp_path / "e.parquet"), "-q", "--model", str(bad)]) == 2
    _one_error_line(capsys, "bad_setting.pt", "window_tokens")


def test_a_plain_pickle_checkpoint_is_one_line_and_not_run(tmp_path, capsys):
    import pickle

    bad = tmp_path / "pickled.pt"
    bad.write_bytes(pickle.dumps({"a": [1, 2, 3]}, protocol=4))
    p = _record(tmp_path)
    with warnings.catch_warnings(record=True) as seen:  # torch's two lines on the pickle's protocol: not shown
        warnings.simplefilter("always")
        assert main(["estimate", str(p), "-o", str(tmp_path / "e.parquet"), "-q", "--model", str(bad)]) == 2
    assert not [w for w in seen if "pickle" in str(w.message).lower()]
    _one_error_line(capsys, "pickled.pt", "not a readable checkpoint")


def test_export_never_writes_over_its_checkpoint_through_a_link(tmp_path, capsys):
    import shutil

    from tepinn_flight.model.checkpoint import default_model_path

    ck = tmp_path / "mine.pt"
    shutil.copy(default_model_path(), ck)
    before = ck.read_bytes()
    link = tmp_path / "mine_link.onnx"
    link.symlink_to(ck)
    assert main(["export", str(ck), "-o", str(link), "-q"]) == 2
    _one_error_line(capsys, "is the input")
    assert ck.read_bytes() == before


def test_fine_tuning_never_writes_over_the_model_it_starts_from(tmp_path, capsys):
    import shutil

    from tepinn_flight.model.checkpoint import default_model_path

    run = tmp_path / "run"
    run.mkdir()
    shutil.copy(default_model_path(), run / "model.pt")
    before = (run / "model.pt").read_bytes()
    p = _record(tmp_path)
    assert main(["train", "--init", str(run / "model.pt"), "--data", str(p), "-o", str(run), "-q"]) == 2
    err = _one_error_line(capsys, f"-o {run}: the run writes its model.pt there, which is --init")
    assert "model.pt is the input" not in err  # (review59: said of a path the user never gave)
    assert (run / "model.pt").read_bytes() == before


def test_a_sensor_step_past_its_range_is_refused():
    from tepinn_flight.errors import ConfigError
    from tepinn_flight.sim.sensors import AccelConfig, GyroConfig

    with pytest.raises(ConfigError, match="'lsb_deg_s' must be below 'range_deg_s'"):
        GyroConfig(lsb_deg_s=1e9)
    with pytest.raises(ConfigError, match="'lsb_mg' must be below 'range_g'"):
        AccelConfig(range_g=2.0, lsb_mg=2500.0)
    AccelConfig(range_g=16.0, lsb_mg=20.0)  # (mg against g: a coarse step well inside the range is fine)


def test_an_empty_output_name_and_two_report_folders_are_refused(tmp_path, capsys):
    """`-o ""` (a shell variable never set) had been read as the current folder and refused as "the input"; `evaluate
    -o A --report B` silently wrote B only. One line each, exit 2."""
    p = _record(tmp_path)
    assert main(["estimate", str(p), "-o", ""]) == 2
    _one_error_line(capsys, "-o is empty")
    with pytest.raises(SystemExit) as exc:  # (a usage error: argparse's exit)
        main(["evaluate", str(p), "-o", str(tmp_path / "a"), "--report", str(tmp_path / "b"), "-q"])
    assert exc.value.code == 2
    _one_error_line(capsys, "not allowed with")
    assert not (tmp_path / "a").exists() and not (tmp_path / "b").exists()


def test_an_onnx_export_where_a_checkpoint_is_needed_says_so(tmp_path, capsys):
    from tepinn_flight.model.runtime import default_onnx_path

    assert main(["export", str(default_onnx_path()), "-o", str(tmp_path / "again.onnx"), "-q"]) == 2
    _one_error_line(capsys, "an ONNX export, not a checkpoint: estimate, evaluate and bridge run it")  # (evaluate too: session 61)
    assert not (tmp_path / "again.onnx").exists()
