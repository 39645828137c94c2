"""`info MODEL.pt|MODEL.onnx`: what a model file is (session 61: `info` had refused it as "not a ULog, ...")."""

from __future__ import annotations

import json
import shutil

import pytest

torch = pytest.importorskip("torch")
pytest.importorskip("onnxruntime")

from tepinn_flight.cli.main import main  # noqa: E402
from tepinn_flight.model.checkpoint import default_model_path, load_model  # noqa: E402


def _info_json(capsys, *paths):
    capsys.readouterr()
    assert main(["info", "--json", *map(str, paths)]) == 0
    return json.loads(capsys.readouterr().out)


def test_info_describes_the_shipped_checkpoint_and_its_export(capsys):
    pt = default_model_path()
    d = _info_json(capsys, pt, pt.with_suffix(".onnx"))
    a, b = d[str(pt)], d[str(pt.with_suffix(".onnx"))]
    model, settings, ck = load_model(pt)
    # the network's shape as the checkpoint's own config gives it; the parameters counted from its state (less buffers)
    buffers = {n for n, _ in model.named_buffers()}
    n_params = sum(v.numel() for k, v in ck["state_dict"].items() if k not in buffers)
    assert a["kind"] == "checkpoint" and b["kind"] == "ONNX export"
    for key, want in (("d_model", ck["model_config"]["d_model"]), ("n_layers", ck["model_config"]["n_layers"]),
                      ("window_tokens", ck["model_config"]["window_tokens"]), ("variant", "tepinn")):  # fmt: skip
        assert a["network"][key] == b["network"][key] == want
    assert a["network"]["parameters"] == n_params and "parameters" not in b["network"]
    assert a["network"]["window_s"] == ck["model_config"]["window_tokens"] / ck["model_config"]["token_rate_hz"]
    assert a["estimator"] == b["estimator"] and a["estimator"]["kind"] == "filter-anchored VQF"
    assert a["estimator"]["smoother"] is settings.smoother and a["estimator"]["mode"] == settings.mode
    assert a["training"]["train_files"] == len(ck["training"]["train_flights"])
    assert a["training"]["val_tilt_rmse_deg"] == ck["metrics"]["val_tilt_rmse_deg"]
    assert "exported from this file" in a["beside"] and "the checkpoint it was exported from" in b["beside"]
    assert b["source"] == pt.name and b["opset"] == 17
    assert main(["info", str(pt)]) == 0
    out = capsys.readouterr().out
    assert f"windows of {ck['model_config']['window_tokens']} tokens" in out and f"{n_params:,} parameters" in out
    # the epoch its figures are from, as the run's own history numbers it, not taken for how many ran (review61)
    assert f"figures from epoch {ck['metrics']['epoch']}," in out and " epochs" not in out


def test_info_says_when_the_pair_beside_differs_and_names_a_training_checkpoint(tmp_path, capsys):
    pt = tmp_path / "model.pt"
    shutil.copy(default_model_path(), pt)
    shutil.copy(default_model_path().with_suffix(".onnx"), tmp_path / "model.onnx")  # the shipped model's export
    d = _info_json(capsys, pt, tmp_path / "model.onnx")
    assert "exported from this file" in d[str(pt)]["beside"]
    ck = torch.load(pt, weights_only=True)
    del ck["anchor_config"]  # what a training run writes as it goes (best.pt, last.pt)
    ck["metrics"] = {k: v for k, v in ck["metrics"].items() if not k.startswith("fusion_")}
    torch.save(ck, pt)
    d = _info_json(capsys, pt, tmp_path / "model.onnx")
    assert "not exported from this file" in d[str(pt)]["beside"]
    assert "another checkpoint" in d[str(tmp_path / "model.onnx")]["beside"]
    assert d[str(pt)]["estimator"]["kind"] == "network-centred fusion" and "model.pt" in d[str(pt)]["estimator"]["note"]
    (tmp_path / "model.onnx").unlink()
    assert _info_json(capsys, pt)[str(pt)]["beside"] == "no export beside it"


def test_info_refuses_a_damaged_model_in_one_line(tmp_path, capsys):
    bad = tmp_path / "m.onnx"
    bad.write_bytes(b"not a model")
    assert main(["info", str(bad)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "not a readable ONNX model" in err[0] and f"{bad}: {bad}:" not in err[0]  # (named once)
    text = tmp_path / "notes.pt"  # a file named as a checkpoint that is none: said so, not "not a ULog, ..."
    text.write_text("hello")
    assert main(["info", str(text)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "not a readable checkpoint" in err[0] and "ULog" not in err[0]
    other = tmp_path / "state.pt"  # a torch archive that is no tepinn-flight checkpoint
    torch.save({"weights": torch.zeros(3)}, other)
    assert main(["info", str(other)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "not a tepinn-flight checkpoint" in err[0]
