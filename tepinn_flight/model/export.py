"""Export a TE-PINN checkpoint to ONNX for onnxruntime (no torch at run time).

The graph (export version 3) is the network from its token features to its heads' linear layers
(:meth:`~tepinn_flight.model.network.TEPINN.encode`, :meth:`~tepinn_flight.model.network.TEPINN.linear_heads`):
inputs the features it reads, ``x`` (B, K, n_inputs) before normalisation and ``t_rel`` (B, K),
float32; outputs :data:`~.runtime.GRAPH_OUTPUTS`: ``q_head`` (B, 4), ``pool`` (B, K), ``sigma`` (B,),
``bias``, ``vel``, ``acc_v`` (B, 3), float32. The runner computes the features from the windows
(:mod:`.window_features`, compiled: the sensor model, RK4 rotations and rotated forces were half of a
batch-1 run as graph operators) with the trained sensor model stored in the metadata
(``sensor_model``), and the window's attitude from the heads' outputs and the physics features
(:mod:`.head_physics`, compiled: the pooled gravity and the correction layer were a quarter of a batch-1
run as graph operators, session 41). The batch axis B is dynamic; the window length K is fixed by the
model config (``window_tokens``). Opset :data:`OPSET`. (Version 1 exports, whose graph took the windows
themselves, and version 2, whose graph took all the features and gave ``q``, still run.)

``metadata_props`` carry, as JSON strings: ``format`` ("tepinn-flight-onnx"), ``version``,
``model_config``, ``fusion_config``, ``anchor_config`` (when the checkpoint has one),
``conventions``, ``graph_inputs``, ``graph_outputs``, ``sensor_model``, ``outputs_present`` (the heads the model has: the others are zeros in the graph
and the runner replaces them with the estimators' defaults), ``opset``, ``source`` (checkpoint
file name), ``source_sha256`` (of the checkpoint file: a checkpoint with an export of the same name
beside it runs that export only while they match), ``training``, ``metrics`` and ``loss_config`` where
JSON-serialisable. :func:`~.runtime.load_runner`
rebuilds from them the same estimator settings as :func:`~.checkpoint.load_model`.

Needs torch and the ``onnx`` package (the ``[torch]`` extra).
"""

from __future__ import annotations

import io
import json
import os
import warnings
from pathlib import Path

import torch
from torch import nn

from .. import __version__
from ..record import atomic_write
from .checkpoint import load_model
from .runtime import GRAPH_OUTPUTS, INPUTS, ONNX_FORMAT, ONNX_VERSION, OUTPUTS
from .window_features import SensorValues, feature_names

#: ONNX opset of the exported graph
OPSET = 17


class ExportWrapper(nn.Module):
    """The network from its token features to its heads' linear layers (:meth:`~.network.TEPINN.encode`,
    :meth:`~.network.TEPINN.linear_heads`) with a fixed output tuple :data:`~.runtime.GRAPH_OUTPUTS`
    ``(q_head, pool, sigma, bias, vel, acc_v)``; heads the model does not have are zeros. Its inputs are
    :func:`~.window_features.feature_names`, in that order (the export keeps those the graph reads:
    ``x`` and ``t_rel``; the runner's compiled tail reads the others, :mod:`.head_physics`)."""

    def __init__(self, model: nn.Module):
        super().__init__()
        self.model = model

    def forward(self, *features):
        f = dict(zip(feature_names(self.model.config), features))
        out = self.model.linear_heads(self.model.encode(f["x"], f["t_rel"]))
        q = out["q_head"]
        zeros3 = torch.zeros_like(q[:, :3])
        sigma = out["sigma"] if "sigma" in out else torch.zeros_like(q[:, 0])
        pool = out["pool"] if "pool" in out else torch.zeros_like(f["t_rel"])
        return (q, pool, sigma, out["bias"], out.get("vel", zeros3), out.get("acc_v", zeros3))


def sensor_values(model: nn.Module) -> SensorValues:
    """The trained sensor model's effective values (what :mod:`.window_features` applies)."""
    if not model.config.physics:
        return SensorValues.identity()
    v = {k: t.detach().double().numpy() for k, t in model.sensor.values().items()}
    kappa = model.sensor.clip_gain()
    return SensorValues(tuple(map(float, v["b_g"])), tuple(tuple(map(float, r)) for r in v["S_g"]),
                        tuple(map(float, v["b_a"])), tuple(tuple(map(float, r)) for r in v["S_a"]),
                        None if kappa is None else float(kappa.detach()))  # fmt: skip


def example_features(model: nn.Module, batch: int = 2, seed: int = 0) -> tuple:
    """The features of :func:`example_inputs`' windows, as the export takes them."""
    gyr, acc, count, t_rel, dt, mag, clip = example_inputs(model.config, batch, seed)
    with torch.no_grad():
        x, _, _, v, u, cen = model.features(gyr, acc, count, mag, dt, clip, t_rel)
    cen, cen_rate = cen if isinstance(cen, tuple) else (cen, None)
    f = {"x": x, "t_rel": t_rel, "v": v, "u": u, "cen": cen, "cen_rate": cen_rate}
    return tuple(f[n].float() for n in feature_names(model.config))


def present_outputs(model: nn.Module) -> list[str]:
    c = model.config
    present = ["q", "bias"]
    if c.uncertainty:
        present.append("sigma")
    if c.physics and c.centripetal:
        present += ["vel", "acc_v"]
    return [k for k in OUTPUTS if k in present]


def example_inputs(config, batch: int = 2, seed: int = 0) -> tuple:
    """Plausible random float32 windows (B, K): gyro, accel near 1 g, counts, times, mag, clip."""
    g = torch.Generator().manual_seed(seed)
    k = config.window_tokens
    delta = 1.0 / config.token_rate_hz
    gyr = 0.5 * torch.randn(batch, k, 3, generator=g)
    acc = torch.tensor([0.0, 0.0, -9.81]) + 2.0 * torch.randn(batch, k, 3, generator=g)
    count = torch.full((batch, k), 8.0)
    t_rel = (torch.arange(k, dtype=torch.float32) - (k - 1)) * delta
    t_rel = t_rel.expand(batch, k).contiguous()
    dt = torch.full((batch, k), delta)
    mag = torch.tensor([20.0, 0.0, 40.0]) + 5.0 * torch.randn(batch, k, 3, generator=g)
    clip = torch.zeros(batch, k)
    return gyr, acc, count, t_rel, dt, mag, clip


def _metadata(ckpt: dict, model: nn.Module, source: str, opset: int, source_sha256: str,
              graph_inputs: list[str]) -> dict[str, str]:  # fmt: skip
    meta = {
        "format": ONNX_FORMAT,
        "version": ONNX_VERSION,
        "model_config": ckpt["model_config"],
        "fusion_config": ckpt.get("fusion_config", {}),
        "conventions": ckpt.get("conventions", {}),
        "outputs_present": present_outputs(model),
        "opset": opset,
        "source": source,
        "source_sha256": source_sha256,
        "inputs": list(INPUTS),
        "graph_inputs": graph_inputs,  # the features the graph reads (x, t_rel; the physics head reads the others)
        "graph_outputs": list(GRAPH_OUTPUTS),
        "sensor_model": sensor_values(model).to_json(),
        "outputs": list(OUTPUTS),
        "exported_by": f"tepinn-flight {__version__}",  # (review60: which version wrote a deployed model, unsaid)
    }
    if ckpt.get("tepinn_flight_version"):  # the version that made the checkpoint
        meta["tepinn_flight_version"] = ckpt["tepinn_flight_version"]
    if ckpt.get("anchor_config") is not None:
        meta["anchor_config"] = ckpt["anchor_config"]
    for k in ("training", "metrics", "loss_config"):  # (loss_config: evaluate names an ablation's -noadaptive by it)
        if k in ckpt:
            try:
                json.dumps(ckpt[k])
            except (TypeError, ValueError):
                continue
            meta[k] = ckpt[k]
    return {k: (v if k == "format" else json.dumps(v)) for k, v in meta.items()}


def export_bytes(ckpt_path: str | os.PathLike, opset: int = OPSET) -> bytes:
    """The checkpoint as a serialized ONNX model (float32, metadata included)."""
    import onnx

    model, _, ckpt = load_model(ckpt_path)
    model = model.float().eval()
    wrapper = ExportWrapper(model).eval()
    buf = io.BytesIO()
    batch = {0: "batch"}
    names = list(feature_names(model.config))
    dyn = {n: batch for n in names} | {n: batch for n in GRAPH_OUTPUTS}
    # the transformer's fused inference kernel (taken under no_grad/inference_mode) has no ONNX
    # form: trace the layer-by-layer path (the same math)
    fast = torch.backends.mha.get_fastpath_enabled()
    torch.backends.mha.set_fastpath_enabled(False)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # tracer notes on Python-level shape checks (K is fixed)
            torch.onnx.export(wrapper, example_features(model), buf, input_names=names,
                              output_names=list(GRAPH_OUTPUTS), dynamic_axes=dyn, opset_version=opset, dynamo=False)  # fmt: skip
    finally:
        torch.backends.mha.set_fastpath_enabled(fast)
    proto = onnx.load_from_string(buf.getvalue())
    graph_inputs = [i.name for i in proto.graph.input]  # (the export keeps the inputs the graph reads)
    del proto.metadata_props[:]
    from .runtime import file_sha256

    for k, v in _metadata(ckpt, model, Path(ckpt_path).name, opset, file_sha256(ckpt_path), graph_inputs).items():
        proto.metadata_props.add(key=k, value=v)
    proto.producer_name = "tepinn-flight"
    return proto.SerializeToString()


def export_onnx(ckpt_path: str | os.PathLike, out_path: str | os.PathLike, opset: int = OPSET) -> Path:
    """Write ``ckpt_path`` as ONNX to ``out_path`` (atomically)."""
    data = export_bytes(ckpt_path, opset)
    atomic_write(out_path, lambda tmp: Path(tmp).write_bytes(data))
    return Path(out_path)


def check_export(ckpt_path: str | os.PathLike, onnx_path: str | os.PathLike, batch: int = 4, seed: int = 1) -> float:
    """Largest |onnxruntime − torch| over all outputs on random windows."""
    import numpy as np

    from .runtime import OnnxRunner, TorchRunner

    model, _, _ = load_model(ckpt_path)
    x = [v.numpy() for v in example_inputs(model.config, batch, seed)]
    a = OnnxRunner(onnx_path).run(*x)
    b = TorchRunner(model).run(*x)
    return max(float(np.max(np.abs(a[k] - b[k]))) for k in OUTPUTS)
