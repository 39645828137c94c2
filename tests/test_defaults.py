"""Every config dataclass's defaults are the shipped model: read from the shipped checkpoint file
itself (``torch.load``, not the package's loader) and from ``train/default.toml``, its recipe."""

from __future__ import annotations

import dataclasses
import tomllib
from pathlib import Path

import pytest
import torch

from tepinn_flight.config import to_dict
from tepinn_flight.model.anchor import AnchorConfig
from tepinn_flight.model.checkpoint import (ANCHOR_CONFIG_BEFORE, MODEL_CONFIG_BEFORE, REMOVED_ANCHOR_OPTIONS,
                                            CheckpointError, default_model_path, estimator_settings, load_model)  # fmt: skip
from tepinn_flight.cli.main import main
from tepinn_flight.model.config import ModelConfig
from tepinn_flight.model.losses import LossConfig
from tepinn_flight.model.train_config import DataConfig, TrainConfig, load_train_config

REPO = Path(__file__).resolve().parents[1]
DEFAULT_TOML = REPO / "train" / "default.toml"
#: keys of train/default.toml that are not the defaults on purpose: a recipe names its own data
#: (paths relative to the recipe file)
INTENTIONALLY_DIFFERENT = {("data", "campaign"), ("data", "optional_records"), ("data", "heldout_split")}


@pytest.fixture(scope="module")
def shipped() -> dict:
    return torch.load(default_model_path(), map_location="cpu", weights_only=True)


def test_model_config_defaults_are_the_shipped_model(shipped):
    assert shipped["model_config"] == dataclasses.asdict(ModelConfig())


#: loss options removed since the shipped model was trained (measured worse, kept off): their off value
REMOVED_LOSS_OPTIONS = {"skip_clipped": False}


def test_loss_config_defaults_are_the_shipped_model(shipped):
    stored = dict(shipped["loss_config"])
    for key, off in REMOVED_LOSS_OPTIONS.items():
        assert stored.pop(key) == off and not hasattr(LossConfig(), key)
    assert stored == dataclasses.asdict(LossConfig())


def test_anchor_config_defaults_are_the_shipped_model(shipped):
    default = {k: v for k, v in dataclasses.asdict(AnchorConfig()).items() if k != "fusion_config"}
    stored = dict(shipped["anchor_config"])
    for key, (kept, _, _) in REMOVED_ANCHOR_OPTIONS.items():
        assert stored.pop(key) == kept and key not in default
    assert stored == default


def test_training_defaults_are_the_shipped_run(shipped):
    assert list(DataConfig().rate_factors) == shipped["training"]["rate_factors"]
    assert TrainConfig().seed == shipped["training"]["seed"]


def test_default_recipe_is_the_defaults_and_the_shipped_model(shipped):
    """Every key train/default.toml sets is the default (but its data), and what it builds is what
    the shipped checkpoint stores."""
    raw = tomllib.loads(DEFAULT_TOML.read_text())
    defaults = to_dict(TrainConfig())
    differ = []
    for table, value in raw.items():
        items = value.items() if isinstance(value, dict) else [(None, value)]
        for key, v in items:
            d = defaults[table] if key is None else defaults[table].get(key)
            if (table, key) not in INTENTIONALLY_DIFFERENT and v != d:
                differ.append(f"{table}.{key} = {v!r} (default {d!r})")
    assert not differ, differ
    for table, key in INTENTIONALLY_DIFFERENT:  # still there (else the exception list is stale)
        assert key in raw[table]
    cfg = load_train_config(DEFAULT_TOML)
    assert dataclasses.asdict(cfg.model) == shipped["model_config"]
    assert dataclasses.asdict(cfg.loss) == {k: v for k, v in shipped["loss_config"].items() if k not in REMOVED_LOSS_OPTIONS}
    assert {k: v for k, v in dataclasses.asdict(cfg.anchor).items() if k != "fusion_config"} == {
        k: v for k, v in shipped["anchor_config"].items() if k not in REMOVED_ANCHOR_OPTIONS}


def test_before_values_are_not_the_defaults():
    """The fill-ins for old checkpoints are the settings they ran with, not today's defaults (else
    an old checkpoint would silently load as a different model)."""
    model, anchor = dataclasses.asdict(ModelConfig()), dataclasses.asdict(AnchorConfig())
    assert all(model[k] != v for k, v in MODEL_CONFIG_BEFORE.items())
    assert all(anchor[k] != v for k, v in ANCHOR_CONFIG_BEFORE.items())


def test_old_anchor_config_loads_with_its_old_settings(shipped, tmp_path):
    """An anchor_config written before tau_acc_flight_s and the fusion-bias gate existed runs with
    VQF's own time constant in flight and without that gate (0 = off), not with today's 10 s / 3 °/s."""
    old = {**shipped, "anchor_config": {k: v for k, v in shipped["anchor_config"].items()
                                        if k not in ("tau_acc_flight_s", "bias_gate_fusion_deg_s")}}  # fmt: skip
    a = estimator_settings(old)
    assert isinstance(a, AnchorConfig) and a.tau_acc_flight_s == 0.0 and a.bias_gate_fusion_deg_s == 0.0
    assert a.pull_gain == shipped["anchor_config"]["pull_gain"]
    torch.save(old, tmp_path / "old.pt")
    _, a2, _ = load_model(tmp_path / "old.pt")
    assert a2 == a and a2.fusion_config == a.fusion_config


@pytest.mark.parametrize("stored", ["window", None], ids=["window", "written-before-the-key"])
def test_a_checkpoint_with_a_removed_option_on_is_refused_in_one_line(shipped, tmp_path, capsys, stored):
    """pull_target = "window" (removed, measured worse) cannot run as it was made: refused, naming
    the file and the option, by the loader and by the CLI (exit 2, one line). Held at the kept
    value ("fusion", the shipped model) the key is dropped and the checkpoint loads."""
    anchor = {k: v for k, v in shipped["anchor_config"].items() if k != "pull_target"}
    if stored is not None:
        anchor["pull_target"] = stored
    else:  # as written before pull_target existed: without the keys added after it either
        del anchor["bias_gate_fusion_deg_s"]
    path = tmp_path / "old.pt"
    torch.save({**shipped, "anchor_config": anchor}, path)
    with pytest.raises(CheckpointError, match="pull_target = 'window', an option removed"):
        load_model(path)
    rec = tmp_path / "r.parquet"
    from tepinn_flight.model.synthetic import synthetic_record
    from tepinn_flight.record import write_record

    write_record(synthetic_record(seed=1, duration_s=5.0, rate_hz=100.0), rec)
    assert main(["estimate", str(rec), "--model", str(path), "-o", str(tmp_path / "e.parquet"), "-q"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and str(path) in err and "pull_target" in err, err
    assert not (tmp_path / "e.parquet").exists()
    disabled = {**shipped, "anchor_config": {**anchor, "enabled": False}}  # not run: nothing to refuse
    assert not isinstance(estimator_settings(disabled), AnchorConfig)


def test_a_removed_option_at_its_kept_value_is_dropped(shipped):
    assert shipped["anchor_config"]["pull_target"] == "fusion"
    a = estimator_settings(shipped)
    assert isinstance(a, AnchorConfig) and not hasattr(a, "pull_target")


def test_a_checkpoint_written_after_the_removal_loads_as_the_kept_value(tmp_path):
    """save_checkpoint writes no pull_target any more: such a checkpoint is not mistaken for one
    written before the option existed."""
    from tepinn_flight.model.checkpoint import save_checkpoint
    from tepinn_flight.model.fusion import FusionConfig
    from tepinn_flight.model.network import TEPINN

    model = TEPINN(ModelConfig(window_tokens=12, d_model=8, n_heads=2, n_layers=1, d_ff=16))
    save_checkpoint(tmp_path / "new.pt", model, FusionConfig(), AnchorConfig())
    assert "pull_target" not in torch.load(tmp_path / "new.pt", weights_only=True)["anchor_config"]
    _, settings, _ = load_model(tmp_path / "new.pt")
    assert settings == AnchorConfig()
