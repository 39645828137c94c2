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


def test_the_bridges_first_check_refuses_what_the_loader_would_without_torch(tmp_path, monkeypatch):
    """`check_model` — the bridge's check before it routes — refuses without torch every checkpoint `load_runner`
    refuses there, with the same line (review60: it passed any torch archive, and the worker refused it 7 s into the
    session); an export renamed .pt is said to be no checkpoint, and a folder a folder (not "needs PyTorch")."""
    from tepinn_flight.model.runtime import check_model

    monkeypatch.setattr(runtime, "torch_available", lambda: False)
    stale = tmp_path / "stale.pt"
    shutil.copy(default_model_path(), stale)
    shutil.copy(default_onnx_path(), tmp_path / "stale.onnx")
    with open(stale, "ab") as f:
        f.write(b"\0")
    alone = tmp_path / "alone" / "mine.pt"
    alone.parent.mkdir()
    shutil.copy(default_model_path(), alone)
    renamed = tmp_path / "renamed" / "model.pt"
    renamed.parent.mkdir()
    shutil.copy(default_onnx_path(), renamed)
    for path, said in ((stale, "was not exported from this checkpoint"), (alone, "a checkpoint needs PyTorch to be read"),
                       (renamed, "not a torch checkpoint file (an ONNX export is read under its .onnx name)"),
                       (tmp_path / "alone", "a folder, not a model file")):  # fmt: skip
        with pytest.raises(ConfigError, match=said.replace("(", r"\(").replace(")", r"\)")) as by_check:
            check_model(path)
        with pytest.raises(ConfigError) as by_loader:
            load_runner(path)
        assert str(by_check.value) == str(by_loader.value)
    shutil.copy(default_model_path(), tmp_path / "ok.pt")
    shutil.copy(default_onnx_path(), tmp_path / "ok.onnx")
    check_model(tmp_path / "ok.pt")  # in sync: taken


def _edited_export(tmp_path, name, edit):
    """The shipped export with its metadata edited by ``edit(dict)`` (values as JSON text)."""
    import onnx

    proto = onnx.load(str(default_onnx_path()))
    meta = {p.key: p.value for p in proto.metadata_props}
    edit(meta)
    del proto.metadata_props[:]
    for k, v in meta.items():
        proto.metadata_props.add(key=k, value=v)
    path = tmp_path / f"{name}.onnx"
    onnx.save(proto, str(path))
    return path


@pytest.mark.parametrize("name,edit,said", [
    ("nocfg", lambda m: m.pop("model_config"), "export without a sound 'model_config'"),
    ("tokens", lambda m: m.update(model_config=m["model_config"].replace('"window_tokens": 80', '"window_tokens": 40')),
     "its graph takes windows of 80 tokens"),
    ("v1", lambda m: m.update(version="1"), "which an export of version 1 is not given"),
])  # fmt: skip
def test_an_export_whose_metadata_does_not_match_its_graph_is_refused_when_opened(tmp_path, name, edit, said):
    """A hand-edited or damaged export: one line naming the file, when the model is opened — by `estimate` and by the
    bridge's first check alike (review60: "internal error: KeyError", or found at the first window, mid-flight)."""
    import json

    from tepinn_flight.model.runtime import check_model

    assert json.loads(dict((p.key, p.value) for p in __import__("onnx").load(str(default_onnx_path())).metadata_props)
                      ["model_config"])["window_tokens"] == 80  # (the edit above is one)
    path = _edited_export(tmp_path, name, edit)
    with pytest.raises(ConfigError, match=said) as e:
        load_runner(path)
    assert str(path) in str(e.value)
    with pytest.raises(ConfigError, match=said):
        check_model(path)
