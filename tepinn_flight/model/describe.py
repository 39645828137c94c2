"""What a model file is: ``tepinn-flight info MODEL.pt|MODEL.onnx`` (a checkpoint or an export, read without running
it; an untrusted checkpoint is read as tensors and plain data only, as every loader here reads it).

:func:`describe_model` gives a JSON-ready dict: the file's kind and versions, the network's shape, the estimator it
runs in with the settings a user asks about (mode, the offline steps, σ's floor), what it was trained on and its
validation figures as the training wrote them, and whether the export beside a checkpoint (or the checkpoint beside
an export) is the same model."""

from __future__ import annotations

import dataclasses
from pathlib import Path

from ..errors import ConfigError, TepinnError

#: the estimator settings :func:`describe_model` lists (the anchored estimator's; the rest are in the file)
ANCHOR_KEYS = ("mode", "smoother", "gnss_aid", "gyro_selfcal", "accel_scale_selfcal", "busy_stride", "sigma_floor_deg",
               "sigma_aircraft_deg", "speed_gate_shut_for", "bias_pull_shut_for")  # fmt: skip
#: the validation figures a training run writes into ``metrics`` (where present)
METRIC_KEYS = ("epoch", "elapsed_s", "val_tilt_rmse_deg", "val_nees", "fusion_val_tilt_rmse_mean_deg")


def describe_model(path) -> dict:
    """The description of the checkpoint or export at ``path``. A checkpoint needs torch to be read; where torch is
    absent its export in sync beside it is read instead (said in ``read_from``). Raises :class:`ConfigError` (or a
    :class:`CheckpointError`) for a file that is neither, in one line."""
    from .checkpoint import is_training_checkpoint
    from .runtime import OnnxRunner, export_in_sync, is_onnx_path, torch_available

    path = Path(path)
    if not path.exists():
        raise ConfigError("no such model", path)
    d: dict = {"file": str(path)}
    params = None
    if is_onnx_path(path) or not torch_available():
        src = path if is_onnx_path(path) else export_in_sync(path)
        if src is None:
            from .runtime import _checkpoint_without_torch

            raise _checkpoint_without_torch(path)
        runner = OnnxRunner(src, threads=1)
        meta, config = runner.meta, runner.config
        d["kind"] = "ONNX export" if src == path else "checkpoint"
        if src != path:
            d["read_from"] = f"{src.name} (in sync beside it; PyTorch is not installed)"
    else:
        from .checkpoint import load_model

        model, _, meta = load_model(path)
        config = model.config
        params = sum(int(p.numel()) for p in model.parameters())
        d["kind"] = "checkpoint"
    from .checkpoint import estimator_settings

    try:
        settings = estimator_settings(meta)
    except TepinnError as exc:
        raise ConfigError(exc.reason, path) from None
    d["format"] = f"{meta.get('format')} v{meta.get('version')}" + (" (its export's)" if "read_from" in d else "")
    for k in ("tepinn_flight_version", "exported_by", "opset", "source"):
        if meta.get(k) is not None:
            d[{"tepinn_flight_version": "written_by"}.get(k, k)] = meta[k]
    d["network"] = {"variant": config.variant, "encoder": config.encoder, "d_model": config.d_model,
                    "n_layers": config.n_layers, "n_heads": config.n_heads, "window_tokens": config.window_tokens,
                    "token_rate_hz": config.token_rate_hz, "window_s": config.window_tokens / config.token_rate_hz,
                    "magnetometer": config.use_mag, **({"parameters": params} if params is not None else {})}  # fmt: skip
    from .anchor import AnchorConfig

    if isinstance(settings, AnchorConfig):
        s = dataclasses.asdict(settings)
        d["estimator"] = {"kind": "filter-anchored VQF", **{k: s[k] for k in ANCHOR_KEYS if k in s}}
    else:
        d["estimator"] = {"kind": "network-centred fusion", "yaw": settings.yaw}
    if is_training_checkpoint(meta):
        d["estimator"]["note"] = ("written as a training run goes (best.pt, last.pt): it runs the network-centred "
                                  "fusion uncalibrated; the run's estimator is its model.pt")  # fmt: skip
    tr, m = meta.get("training") or {}, meta.get("metrics") or {}
    d["training"] = {
        **({"train_files": len(tr["train_flights"])} if isinstance(tr.get("train_flights"), list) else {}),
        **({"val_files": len(tr["val_flights"])} if isinstance(tr.get("val_flights"), list) else {}),
        **{k: tr[k] for k in ("imu_rates_hz", "seed") if k in tr},
        **{k: m[k] for k in METRIC_KEYS if isinstance(m.get(k), (int, float))},
    }
    if meta.get("notes"):
        d["notes"] = meta["notes"]
    d["beside"] = _beside(path)
    return d


def _beside(path: Path) -> str:
    """Whether the checkpoint's export beside it (or the export's checkpoint) is the same model."""
    from .runtime import export_in_sync, file_sha256, is_onnx_path, read_onnx_metadata

    if not is_onnx_path(path):
        other = path.with_suffix(".onnx")
        if not other.is_file():
            return "no export beside it"
        return (f"{other.name}: exported from this file (runs it in onnxruntime)" if export_in_sync(path) is not None
                else f"{other.name}: not exported from this file (another model, or this one changed since)")
    pt = path.with_suffix(".pt")
    if not pt.is_file():
        return "no checkpoint beside it"
    try:
        same = read_onnx_metadata(path).get("source_sha256") == file_sha256(pt)
    except (ConfigError, OSError):
        same = False
    return f"{pt.name}: {'the checkpoint it was exported from' if same else 'another checkpoint (not its source)'}"
