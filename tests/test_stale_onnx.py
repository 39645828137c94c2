"""Without PyTorch a checkpoint runs only through an export beside it made from exactly that file (session 53: an
out-of-date export beside a changed checkpoint was run silently, 20° off the checkpoint's own estimate)."""

from __future__ import annotations

import shutil

import pytest

import tepinn_flight.model.runtime as runtime
from tepinn_flight.errors import ConfigError
from tepinn_flight.model.checkpoint import default_model_path
from tepinn_flight.model.runtime import default_onnx_path, load_runner


def test_a_stale_export_beside_a_checkpoint_is_refused_without_torch(tmp_path, monkeypatch):
    ck = tmp_path / "mine.pt"
    shutil.copy(default_model_path(), ck)
    shutil.copy(default_onnx_path(), tmp_path / "mine.onnx")
    monkeypatch.setattr(runtime, "torch_available", lambda: False)
    load_runner(ck, "auto")  # in sync (made from the same bytes): taken
    with open(ck, "ab") as f:  # the checkpoint changed since its export
        f.write(b"\0")
    for rt in ("auto", "onnx"):
        with pytest.raises(ConfigError, match="was not exported from this checkpoint"):
            load_runner(ck, rt)
