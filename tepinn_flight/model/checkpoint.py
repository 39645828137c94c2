"""Self-describing, versioned checkpoints: everything needed to rebuild and run the model.

A checkpoint is a plain dict saved with ``torch.save`` and loadable with
``torch.load(weights_only=True)`` (tensors, dicts, lists, strings and numbers only):

``format`` ("tepinn-flight-checkpoint"), ``version``, ``model_config``, ``loss_config``,
``fusion_config`` (dicts), ``state_dict`` (weights incl. the input normalisation buffers),
``conventions``, ``training`` (data summary, seed, epochs), ``metrics``, plus, for resumable
training checkpoints, ``optimizer``/``loss_state``/``rng``/``epoch``.

Settings a checkpoint lacks (written before they existed) are filled with the values it was made
with (:data:`MODEL_CONFIG_BEFORE`, :data:`ANCHOR_CONFIG_BEFORE`), not with today's defaults.
``loss_config`` records how the network was trained; nothing rebuilds a loss from it, so an option
removed since (``skip_clipped``, off in every shipped model) stays in old files as written.

torch is imported where a checkpoint is read or written, not at import (the paths below and the
runtime without torch need this module).
"""

from __future__ import annotations

import dataclasses
import os
import warnings
from pathlib import Path
from typing import TYPE_CHECKING

from .. import conventions
from ..errors import ConfigError, TepinnError
from ..record import atomic_write
from .anchor import AnchorConfig
from .config import ModelConfig
from .fusion import FusionConfig

if TYPE_CHECKING:
    from .network import TEPINN

FORMAT = "tepinn-flight-checkpoint"
VERSION = 1


class CheckpointError(TepinnError):
    """A checkpoint that cannot be used (corrupt, foreign, or from an unknown version)."""


#: Settings a version-1 checkpoint may lack because it was written before they existed, with the
#: values it was trained or run with then. The dataclass defaults are the shipped model's, not these:
#: a missing key is filled from here so that an old checkpoint loads as it always ran.
MODEL_CONFIG_BEFORE = {
    "clip_aware": False, "sensor_scale_max": 0.0, "sensor_gyro_bias_max_rad_s": 0.0, "sensor_accel_bias_max_m_s2": 0.0,
    "declip": False, "learned_pooling": False, "centripetal": False, "centripetal_rate": False,
}  # fmt: skip
#: ... and of the filter-anchored estimator's settings (``anchor_config``): VQF's own accelerometer time
#: constant in flight (0), no uncalibrated-gyro evidence from the older fusion (0: off), the network on
#: every token (no quiet blocks), the gyro's scale not read from the record, the older fusion's bias
#: evidence counted without VQF's and in any orientation, σ without the sampling term and the saturation term,
#: no re-levelling at rest after a saturation, the saturation gate's pull at any gyro range, no offline
#: tilt smoothing (opt-in before session 25), no gap term in σ, the filter's own tilt while the saturation gate is on, the gates at any IMU rate, VQF fed each gyro sample over one fixed period, no gap term while the uncalibrated-gyro gate's evidence builds, each sample of the still run below the rest rate and a fresh one at a re-levelling, the flight-speed gate on any vehicle, the uncalibrated-gyro gate's older-fusion path and its pull on any vehicle, |v̂| making a block busy on any vehicle, no aircraft term in σ and the causal σ's accelerometer gain the same on every vehicle
ANCHOR_CONFIG_BEFORE = {"tau_acc_flight_s": 0.0, "bias_gate_fusion_deg_s": 0.0, "quiet_blocks": False, "clip_min_s": 0.0,
                        "gyro_selfcal": False, "gnss_aid": False, "gnss_aid_in_flight": False,
                        "bias_gate_vqf_deg_s": 0.0, "bias_gate_thrust_deg": 0.0,
                        "sigma_sampling_gain": 0.0, "accel_scale_selfcal": False, "sigma_clip_gain": 0.0,
                        "rest_relevel_s": 0.0, "clip_gate_max_deg_s": 0.0, "smoother": False,
                        "sigma_gap_gain": 0.0, "clip_tilt_from_fusion": False,
                        "min_network_rate_hz": 0.0, "gyro_step_weighting": False,
                        "sigma_gap_bias_evidence": False, "rest_spike_factor": 1.0,
                        "rest_keeps_run": False, "speed_gate_shut_for": (), "quiet_speed_needs_gate": False,
                        "bias_gate_fusion_shut_for": (), "bias_pull_shut_for": (),
                        "sigma_aircraft_deg": 0.0, "sigma_acc_gain_aircraft": 0.0}  # fmt: skip
#: Anchor options removed after they measured worse: key → (the value kept, the one this tepinn-flight
#: runs and drops from the checkpoint; the value of checkpoints written before the key existed; a key
#: added while the option existed). A checkpoint lacking the option ran with the kept value if it has
#: that later key (written after the removal), else with the value before. Any value but the kept one
#: is refused: the checkpoint would run differently.
REMOVED_ANCHOR_OPTIONS = {"pull_target": ("fusion", "window", "bias_gate_fusion_deg_s")}


def model_config_from(meta: dict) -> ModelConfig:
    """The :class:`ModelConfig` of a checkpoint dict or an export's metadata; keys it lacks take
    their :data:`MODEL_CONFIG_BEFORE` values."""
    return ModelConfig(**{**MODEL_CONFIG_BEFORE, **meta["model_config"]})


def anchor_config_from(meta: dict) -> AnchorConfig | None:
    """The :class:`AnchorConfig` of a checkpoint dict or an export's metadata (None where it has
    none), keys it lacks taking their :data:`ANCHOR_CONFIG_BEFORE` values, its ``fusion_config``
    the checkpoint's."""
    raw = meta.get("anchor_config")
    if raw is None:
        return None
    raw = {k: v for k, v in raw.items() if k != "fusion_config"}
    for key, (kept, before, later) in REMOVED_ANCHOR_OPTIONS.items():
        value = raw.pop(key, kept if later in raw else before)
        if value != kept and raw.get("enabled", True):
            raise CheckpointError(f"its anchored estimator has {key} = {value!r}, an option removed after it measured "
                                  f"worse; this tepinn-flight runs only {key} = {kept!r}")  # fmt: skip
    fusion = fusion_config_from(meta.get("fusion_config"))
    return AnchorConfig(**{**ANCHOR_CONFIG_BEFORE, **raw}, fusion_config=fusion)


def estimator_settings(meta: dict) -> FusionConfig | AnchorConfig:
    """The estimator a checkpoint dict or an export's metadata runs in: an enabled ``anchor_config``
    (:class:`AnchorConfig`, the filter-anchored VQF, its pull target the checkpoint's fusion) or
    else its ``fusion_config`` (:class:`FusionConfig`)."""
    anchor = anchor_config_from(meta)
    if anchor is not None and anchor.enabled:
        return anchor
    return fusion_config_from(meta.get("fusion_config"))


def save_checkpoint(path: str | os.PathLike, model: TEPINN, fusion: FusionConfig, anchor: AnchorConfig | None = None,
                    **extra) -> None:  # fmt: skip
    """``anchor``: the filter-anchored estimator's settings (``anchor_config``); without it the
    checkpoint runs the network-centred fusion ``fusion``."""
    import torch

    ckpt = {
        "format": FORMAT,
        "version": VERSION,
        "model_config": dataclasses.asdict(model.config),
        "fusion_config": dataclasses.asdict(fusion),
        **({"anchor_config": {k: v for k, v in dataclasses.asdict(anchor).items() if k != "fusion_config"}}
           if anchor is not None else {}),
        "state_dict": {k: v.detach().cpu() for k, v in model.state_dict().items()},
        "conventions": conventions.describe(),
        **extra,
    }
    atomic_write(path, lambda tmp: torch.save(ckpt, tmp))


def fusion_config_from(stored: dict | None) -> FusionConfig:
    """The :class:`FusionConfig` a checkpoint stored. A field it lacks (written before the field
    existed) gets the value it ran with then: :meth:`FusionConfig.uncalibrated`'s, never today's
    defaults (the shipped model's)."""
    return FusionConfig.uncalibrated(**(stored or {}))


def read_checkpoint(path: str | os.PathLike) -> dict:
    import torch

    p = Path(path)
    if not p.exists():
        raise CheckpointError("no such checkpoint", p)
    try:
        with warnings.catch_warnings():  # torch warns of a plain pickle's protocol before refusing it: the one line below
            warnings.simplefilter("ignore", UserWarning)
            ckpt = torch.load(p, map_location="cpu", weights_only=True)
    except Exception as exc:  # torch raises many types on corrupt files
        if p.suffix.lower() == ".onnx":  # an export: what runs it, and what needs the checkpoint it came from
            raise CheckpointError("an ONNX export, not a checkpoint: estimate, evaluate and bridge run it (--model "
                                  "X.onnx); export and train --init need the .pt checkpoint it was exported from", p) from None
        raise CheckpointError(_load_failure(exc), p) from None
    if not isinstance(ckpt, dict) or ckpt.get("format") != FORMAT:
        raise CheckpointError("not a tepinn-flight checkpoint", p)
    if ckpt.get("version") != VERSION:
        raise CheckpointError(f"unknown checkpoint version {ckpt.get('version')!r} (this tepinn-flight reads {VERSION})", p)
    return ckpt


def _load_failure(exc: Exception) -> str:
    """One line for a failed ``torch.load``. torch's own message for a file holding Python objects
    advises loading it with ``weights_only=False`` (running whatever code the file names): that
    advice is not repeated; the checkpoint is refused as not ours."""
    import re

    text = re.sub(r"\x1b\[[0-9;]*m", "", str(exc))  # torch bolds parts of its messages
    if "Weights only load failed" in text or "WeightsUnpickler" in text:
        m = re.search(r"Unsupported global: GLOBAL ([\w.]+)", text)
        if m:
            return (f"not a readable checkpoint: it holds Python objects ({m.group(1)}); tepinn-flight reads "
                    "checkpoints as tensors and plain data only")  # fmt: skip
        detail = text.split("WeightsUnpickler error:", 1)[-1] if "WeightsUnpickler error:" in text else ""
        first = next((ln.strip() for ln in detail.splitlines() if ln.strip()), "")[:200]
        return f"not a readable checkpoint (not a torch checkpoint file{': ' + first if first else ''})"
    first = (text.strip().splitlines() or [type(exc).__name__])[0][:200]
    if isinstance(exc, KeyError) or first.strip("'\" ").isdigit():  # (a text file: torch's unpickler reads a
        return "not a readable checkpoint (not a torch checkpoint file)"  # byte as a record key: "101")
    return f"not a readable checkpoint ({first})"


def load_model(path: str | os.PathLike) -> tuple[TEPINN, FusionConfig | AnchorConfig, dict]:
    """Rebuild the model (eval mode, float32) and the settings of the estimator it runs in: an
    :class:`AnchorConfig` (filter-anchored VQF, the shipped model) where the checkpoint has an
    enabled ``anchor_config``, else its :class:`FusionConfig` (network-centred fusion)."""
    from .network import TEPINN

    ckpt = read_checkpoint(path)
    try:
        fusion = estimator_settings(ckpt)
        model = TEPINN(model_config_from(ckpt))
        model.load_state_dict(ckpt["state_dict"])
    except CheckpointError as exc:  # a removed option: say which file
        raise CheckpointError(exc.reason, path) from None
    except ConfigError as exc:  # a value its settings refuse: which file too
        raise CheckpointError(f"settings refused: {exc}", path) from None
    except (TypeError, KeyError, RuntimeError) as exc:
        first = (str(exc).strip().splitlines() or [type(exc).__name__])[0][:200]
        raise CheckpointError(f"checkpoint does not match this model ({first})", path) from None
    model.eval()
    return model, fusion, ckpt


def default_model_path() -> Path:
    """The shipped model inside the package."""
    return Path(__file__).resolve().parents[1] / "assets" / "tepinn_default.pt"


def default_lstm_path() -> Path:
    """The shipped LSTM baseline (the paper's DL model, trained by the same recipe)."""
    return Path(__file__).resolve().parents[1] / "assets" / "lstm_default.pt"


def is_training_checkpoint(ck: dict) -> bool:
    """Whether a checkpoint (or an export's metadata) is one a training run writes as it goes — ``best.pt``,
    ``last.pt``: no anchored estimator and no fitted fusion, so it runs the network-centred fusion uncalibrated; the
    run's estimator is its ``model.pt`` (review60: such a file had run without a word)."""
    return ck.get("anchor_config") is None and "fusion_val_tilt_rmse_mean_deg" not in (ck.get("metrics") or {})
