"""`evaluate`, `benchmark broad` and `demo` run the learned models where `estimate` does (`--runtime`, issue 17): the
shipped models' exports in onnxruntime by default, PyTorch when asked, and without torch the exports."""

from __future__ import annotations

import json

import pytest

torch = pytest.importorskip("torch")
pytest.importorskip("onnxruntime")

from tepinn_flight.cli.main import main  # noqa: E402
from tepinn_flight.model.checkpoint import default_lstm_path, default_model_path  # noqa: E402


@pytest.fixture(scope="module")
def c172x(tmp_path_factory):
    """A short fixed-wing flight, where the network's gates act (its outputs reach the estimate)."""
    from tepinn_flight.record import write_record
    from tepinn_flight.sim.simulate import simulate_record

    path = tmp_path_factory.mktemp("rt") / "c172x.parquet"
    write_record(simulate_record("c172x", 25.0, rate_hz=100.0, seed=3), path)
    return path


def _evaluate(tmp_path, name, record, *extra):
    out = tmp_path / name
    assert main(["evaluate", str(record), "-o", str(out), "--no-peers", "-q", *extra]) == 0
    return json.loads((out / "metrics.json").read_text()), (out / "report.md").read_text()


def test_evaluate_runs_the_shipped_exports_by_default_and_torch_when_asked(tmp_path, c172x):
    """By default (auto) the shipped TE-PINN and LSTM run in onnxruntime from their exports, as `estimate` runs them;
    `--runtime torch` runs the checkpoints; the scores agree to 1e-4° (the runtimes agree to 1e-5 in the network's
    outputs), and report.md and metrics.json say which file ran where."""
    auto, md_auto = _evaluate(tmp_path, "auto", c172x)
    tor, md_torch = _evaluate(tmp_path, "torch", c172x, "--runtime", "torch")
    models = {e["name"]: (e["model"], e["runtime"]) for e in auto["estimators"] if "model" in e}
    assert models == {"tepinn": (str(default_model_path().with_suffix(".onnx")), "onnx"),
                      "lstm": (str(default_lstm_path().with_suffix(".onnx")), "onnx")}  # fmt: skip
    assert {e["name"]: e.get("runtime") for e in tor["estimators"] if "model" in e} == {"tepinn": "torch", "lstm": "torch"}
    assert "tepinn_default.onnx` in onnxruntime" in md_auto and "lstm_default.onnx` in onnxruntime" in md_auto
    assert "tepinn_default.pt` in PyTorch" in md_torch and "PyTorch" not in md_auto.split("Learned models:")[1].split("\n")[0]
    for name in ("tepinn", "lstm"):
        a, b = auto["dataset"][name]["inclination_rmse_deg"], tor["dataset"][name]["inclination_rmse_deg"]
        assert a > 0.05 and abs(a - b) < 1e-4, (name, a, b)
    # the filters are the same bits either way
    assert auto["dataset"]["ekf"]["inclination_rmse_deg"] == tor["dataset"]["ekf"]["inclination_rmse_deg"]


def test_evaluate_takes_an_export_and_refuses_it_under_torch(tmp_path, c172x, capsys):
    onnx = default_model_path().with_suffix(".onnx")
    res, _ = _evaluate(tmp_path, "x", c172x, "--model", str(onnx))
    assert [(e["name"], e["runtime"]) for e in res["estimators"] if "model" in e] == [("tepinn", "onnx")]
    capsys.readouterr()
    assert main(["evaluate", str(c172x), "-o", str(tmp_path / "y"), "--model", str(onnx), "--runtime", "torch", "-q"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "runs with the onnx runtime" in err[0] and not (tmp_path / "y").exists()


def test_an_ablation_variant_is_named_from_its_export_as_from_its_checkpoint(tmp_path):
    """The export carries the checkpoint's loss_config, so a model trained without the adaptive weighting is
    `tepinn-noadaptive` in either runtime (an export made before had read as `tepinn`)."""
    from tepinn_flight.evaluation.estimators import TepinnEstimator
    from tepinn_flight.model.runtime import read_onnx_metadata

    ck = torch.load(default_model_path(), weights_only=True)
    ck["loss_config"] = {**ck["loss_config"], "adaptive": False}
    path = tmp_path / "model.pt"
    torch.save(ck, path)
    assert TepinnEstimator.from_checkpoint(path, runtime="torch").name == "tepinn-noadaptive"
    est = TepinnEstimator.from_checkpoint(path, runtime="onnx")  # exported in memory
    assert est.runtime == "onnx" and est.name == "tepinn-noadaptive"
    assert main(["export", str(path), "-o", str(tmp_path / "model.onnx"), "-q", "--no-check"]) == 0
    assert read_onnx_metadata(tmp_path / "model.onnx")["loss_config"]["adaptive"] is False
    assert TepinnEstimator.from_checkpoint(tmp_path / "model.onnx").name == "tepinn-noadaptive"
    assert TepinnEstimator.from_checkpoint(default_model_path(), runtime="auto").name == "tepinn"  # adaptive: no suffix


def test_models_of_one_run_folder_get_names_of_their_own_and_what_ran_is_said(tmp_path):
    """Three models of one run folder are named apart (review61: the third had taken the second's name and the run was
    refused after loading them all); a checkpoint run in onnxruntime is named by the export that ran — the one beside
    it made from it — or said to be exported in memory."""
    import shutil

    from tepinn_flight.evaluation.estimators import learned_estimators

    run = tmp_path / "run"
    run.mkdir()
    for src, dst in ((default_model_path(), "model.pt"), (default_model_path().with_suffix(".onnx"), "model.onnx"),
                     (default_model_path(), "best.pt")):  # fmt: skip
        shutil.copy(src, run / dst)
    notes: list[str] = []
    ests = learned_estimators([run / "model.onnx", run / "model.pt", run / "best.pt"], notes, "onnx")
    assert len({e.name for e in ests}) == 3 and ests[0].name == "tepinn"
    assert [e.checkpoint for e in ests] == [str(run / "model.onnx"), str(run / "model.onnx"), str(run / "best.pt")]
    assert [e.exported_in_memory for e in ests] == [False, False, True] and all(e.runtime == "onnx" for e in ests)
    assert len(notes) == 1 and "best.pt: no export made from it lies beside it; exported in memory" in notes[0]
    # a run folder named as a variant's suffix: its model is not named as the first model's `--live` (or 9-D) column
    for folder in ("live", "9d"):
        (tmp_path / folder).mkdir()
        shutil.copy(default_model_path(), tmp_path / folder / "model.pt")
        shutil.copy(default_model_path().with_suffix(".onnx"), tmp_path / folder / "model.onnx")  # (not exported again)
        first, second = learned_estimators([run / "model.onnx", tmp_path / folder / "model.pt"], [], "onnx")
        variants = {first.live().name, first.nine_d().name}
        assert second.name == f"tepinn-{folder}-model" and second.name not in variants, (second.name, variants)


def test_evaluate_refuses_a_model_file_before_reading_the_records(tmp_path, capsys, monkeypatch):
    """A model the loader would refuse is refused before the records are read (review61: after them)."""
    import tepinn_flight.cli.paths as paths

    read = []
    monkeypatch.setattr(paths, "read_records", lambda *a, **k: read.append(1) or [])
    (tmp_path / "x.pt").write_text("not a checkpoint")
    assert main(["evaluate", str(tmp_path), "-o", str(tmp_path / "rep"), "--model", str(tmp_path / "x.pt"), "-q"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "x.pt" in err[0] and "not a readable checkpoint" in err[0] and not read
    assert main(["evaluate", str(tmp_path), "-o", str(tmp_path / "rep"), "--model", str(tmp_path / "none.pt"), "-q"]) == 2
    assert "no such model" in capsys.readouterr().err
