"""The runtime's compiled token features (model/window_features.py) are the network's own
(:meth:`TEPINN.features`, PyTorch) for every switch that changes them, with a non-trivial sensor
model; and an export that takes them (version 2) gives PyTorch's outputs from the windows, as did
the graph that took the windows itself (version 1, still read)."""

from __future__ import annotations

import io
import json
import warnings

import numpy as np
import pytest

torch = pytest.importorskip("torch")
pytest.importorskip("onnx")
pytest.importorskip("onnxruntime")

from tepinn_flight.model.config import ModelConfig  # noqa: E402
from tepinn_flight.model.export import example_inputs, sensor_values  # noqa: E402
from tepinn_flight.model.network import TEPINN  # noqa: E402
from tepinn_flight.model.window_features import feature_names, window_features  # noqa: E402

#: the export's equality bound (tests/test_onnx_runtime.py): 1e-5 in each head's own units
ATOL = {"q": 1e-5, "sigma": 1e-5, "bias": 1e-5, "vel": 30 * 1e-5, "acc_v": 5 * 1e-5}
SMALL = dict(d_model=16, n_heads=2, n_layers=1, d_ff=32, window_tokens=24)
CONFIGS = {
    "shipped": ModelConfig(),
    "small": ModelConfig(**SMALL),
    "no rate term": ModelConfig(**SMALL, centripetal_rate=False),
    "no centripetal": ModelConfig(**SMALL, centripetal=False, centripetal_rate=False),
    "not clip-aware": ModelConfig(**SMALL, clip_aware=False),
    "no declip": ModelConfig(**SMALL, declip=False),
    "physics off": ModelConfig(**SMALL, physics=False, centripetal=False, centripetal_rate=False),
    "9-D": ModelConfig(**SMALL, use_mag=True),
    "lstm": ModelConfig(**SMALL, encoder="lstm"),
    "mlp": ModelConfig(**SMALL, encoder="mlp"),
}


def _model(config: ModelConfig, seed: int = 0) -> TEPINN:
    """A model whose sensor model is far from the identity (biases, scale and misalignment, κ ≠ 1)."""
    torch.manual_seed(seed)
    m = TEPINN(config).double().eval()
    g = torch.Generator().manual_seed(seed + 1)
    with torch.no_grad():
        for name in ("b_g", "S_g", "b_a", "S_a"):
            p = getattr(m.sensor, name)
            p.copy_(0.03 * torch.randn(p.shape, generator=g, dtype=p.dtype))
        if hasattr(m.sensor, "k_clip_raw"):
            m.sensor.k_clip_raw.fill_(0.7)
        for p in (m.head_vel.weight, m.head_vel.bias) if hasattr(m, "head_vel") else ():
            p.copy_(0.5 * torch.randn(p.shape, generator=g, dtype=p.dtype))  # the compensation in use
    return m


def _windows(config: ModelConfig, batch: int, seed: int) -> list[np.ndarray]:
    x = [v.numpy().astype(np.float64) for v in example_inputs(config, batch, seed)]
    rng = np.random.default_rng(seed)
    x[3] = x[3] + rng.uniform(-0.004, 0.004, x[3].shape) * (np.arange(config.window_tokens) < config.window_tokens - 1)
    x[4] = x[4] * rng.uniform(0.8, 1.2, x[4].shape)  # uneven token durations
    x[6][0, config.window_tokens // 2] = 0.25  # a saturated token in the first window
    x[6][-1, -1] = 0.5  # and in the last token of the last
    x[5][0, 3] = np.nan  # a magnetometer hole
    return x


@pytest.mark.parametrize("name", list(CONFIGS))
def test_compiled_features_equal_the_networks(name):
    config = CONFIGS[name]
    m = _model(config)
    gyr, acc, count, t_rel, dt, mag, clip = _windows(config, 5, 3)
    got = window_features(config, sensor_values(m), gyr, acc, count, t_rel, dt, mag, clip)
    with torch.no_grad():
        t = [torch.as_tensor(a) for a in (gyr, acc, count, t_rel, dt, mag, clip)]
        x, _, _, v, u, cen = m.features(t[0], t[1], t[2], t[5], t[4], t[6], t[3])
    cen, cen_rate = cen if isinstance(cen, tuple) else (cen, None)
    want = {"x": x, "t_rel": t[3], "v": v, "u": u, "cen": cen, "cen_rate": cen_rate}
    assert set(got) == set(feature_names(config))
    for k, a in got.items():
        assert a.dtype == np.float32 and a.shape == tuple(want[k].shape), k
        np.testing.assert_allclose(a, want[k].numpy(), rtol=0, atol=2e-6, err_msg=k)
    if config.physics and config.clip_aware:  # the saturated token cuts the trust of those before it
        assert got["u"][0, : config.window_tokens // 2 + 1].max() == 0 and got["u"][0, -1] == 1
    if config.physics:  # and the sensor model is applied: not the raw gyro
        assert np.abs(got["x"][..., :3] - gyr).max() > 1e-3


def _export(m: TEPINN, tmp_path, name: str) -> str:
    from tepinn_flight.model.checkpoint import save_checkpoint
    from tepinn_flight.model.export import export_onnx
    from tepinn_flight.model.fusion import FusionConfig

    ck = tmp_path / f"{name}.pt"
    save_checkpoint(ck, m.float(), FusionConfig())
    return str(export_onnx(ck, tmp_path / f"{name}.onnx"))


@pytest.mark.parametrize("name", ["small", "no rate term", "physics off", "9-D", "lstm", "mlp"])
def test_feature_export_equals_torch_from_the_windows(tmp_path, name):
    from tepinn_flight.model.runtime import OUTPUTS, OnnxRunner, TorchRunner, read_onnx_metadata

    config = CONFIGS[name]
    m = _model(config)
    path = _export(m, tmp_path, "m")
    meta = read_onnx_metadata(path)
    assert meta["version"] == 3 and meta["graph_inputs"] == ["x", "t_rel"]  # (the physics head reads the others)
    x = _windows(config, 6, 4)
    a, b = OnnxRunner(path).run(*x), TorchRunner(m.float()).run(*x)
    for k in OUTPUTS:
        np.testing.assert_allclose(a[k], b[k], rtol=0, atol=ATOL[k], err_msg=k)
    assert np.abs(a["q"] - TorchRunner(_model(config, seed=5).float()).run(*x)["q"]).max() > 1e-3  # another model differs


class _WindowsGraph(torch.nn.Module):
    """The version-1 graph: the whole forward pass, windows in."""

    def __init__(self, model):
        super().__init__()
        self.model = model

    def forward(self, gyr, acc, count, t_rel, dt, mag, clip):
        out = self.model(gyr, acc, count, t_rel, dt, mag, clip)
        return out["q"], out["sigma"], out["bias"], out["vel"], out["acc_v"]


class _FeaturesGraph(torch.nn.Module):
    """The version-2 graph: the features in, the attitude out (the physics head inside)."""

    def __init__(self, model):
        super().__init__()
        self.model = model

    def forward(self, *features):
        f = dict(zip(feature_names(self.model.config), features))
        out = self.model.head(f["x"], f["t_rel"], f.get("v"), f.get("u"), f.get("cen"), f.get("cen_rate"))
        return out["q"], out["sigma"], out["bias"], out["vel"], out["acc_v"]


def test_a_version_2_export_still_runs(tmp_path):
    import onnx

    from tepinn_flight.model.export import example_features
    from tepinn_flight.model.runtime import OUTPUTS, OnnxRunner, TorchRunner

    config = CONFIGS["small"]
    m = _model(config).float()
    v3 = onnx.load(_export(m, tmp_path, "v3"))
    names = list(feature_names(config))
    buf = io.BytesIO()
    torch.backends.mha.set_fastpath_enabled(False)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            torch.onnx.export(_FeaturesGraph(m).eval(), example_features(m), buf, input_names=names,
                              output_names=list(OUTPUTS), dynamic_axes={n: {0: "batch"} for n in names + list(OUTPUTS)},
                              opset_version=17, dynamo=False)  # fmt: skip
    finally:
        torch.backends.mha.set_fastpath_enabled(True)
    v2 = onnx.load_from_string(buf.getvalue())
    for p in v3.metadata_props:
        if p.key != "graph_outputs":
            value = {"version": "2", "graph_inputs": json.dumps(names)}.get(p.key, p.value)
            v2.metadata_props.add(key=p.key, value=value)
    runner = OnnxRunner(v2.SerializeToString())
    assert not runner.physics_head and {"v", "cen", "cen_rate"} <= set(runner.input_names) and "q" in runner.output_names
    x = _windows(config, 3, 6)
    a, b = runner.run(*x), TorchRunner(m).run(*x)
    for k in OUTPUTS:
        np.testing.assert_allclose(a[k], b[k], rtol=0, atol=ATOL[k], err_msg=k)


def test_a_version_1_export_still_runs(tmp_path):
    import onnx

    from tepinn_flight.model.runtime import INPUTS, OUTPUTS, OnnxRunner, TorchRunner

    config = CONFIGS["small"]
    m = _model(config).float()
    path = _export(m, tmp_path, "v2")
    v2 = onnx.load(path)
    buf = io.BytesIO()
    torch.backends.mha.set_fastpath_enabled(False)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            torch.onnx.export(_WindowsGraph(m).eval(), example_inputs(config), buf, input_names=list(INPUTS),
                              output_names=list(OUTPUTS), dynamic_axes={n: {0: "batch"} for n in INPUTS + OUTPUTS},
                              opset_version=17, dynamo=False)  # fmt: skip
    finally:
        torch.backends.mha.set_fastpath_enabled(True)
    v1 = onnx.load_from_string(buf.getvalue())
    for p in v2.metadata_props:
        if p.key not in ("graph_inputs", "graph_outputs", "sensor_model"):
            v1.metadata_props.add(key=p.key, value="1" if p.key == "version" else p.value)
    runner = OnnxRunner(v1.SerializeToString())
    assert runner.sensor is None and "gyr" in runner.input_names
    x = _windows(config, 3, 6)
    a, b = runner.run(*x), TorchRunner(m).run(*x)
    for k in OUTPUTS:
        np.testing.assert_allclose(a[k], b[k], rtol=0, atol=ATOL[k], err_msg=k)


@pytest.mark.parametrize("bad", [None, '{"b_g": [0, 0, 0], "S_g": [[0, 0], [0, 0]], "b_a": [0, 0, 0], '
                                 '"S_a": [[0, 0, 0], [0, 0, 0], [0, 0, 0]], "kappa": 1}',
                                 '{"b_g": [0, 0, NaN], "S_g": [[0, 0, 0], [0, 0, 0], [0, 0, 0]], "b_a": [0, 0, 0], '
                                 '"S_a": [[0, 0, 0], [0, 0, 0], [0, 0, 0]], "kappa": 1}'])
def test_a_version_2_export_without_a_sound_sensor_model_is_refused(tmp_path, bad):
    """(missing; a 2×2 matrix, which the compiled loop would read past; a NaN)"""
    import onnx

    from tepinn_flight.errors import ConfigError
    from tepinn_flight.model.runtime import OnnxRunner

    proto = onnx.load(_export(_model(CONFIGS["small"]).float(), tmp_path, "m"))
    keep = [(p.key, p.value) for p in proto.metadata_props if p.key != "sensor_model"]
    del proto.metadata_props[:]
    for k, v in keep + ([("sensor_model", bad)] if bad else []):
        proto.metadata_props.add(key=k, value=v)
    with pytest.raises(ConfigError, match="sensor_model"):
        OnnxRunner(proto.SerializeToString())


def test_mismatched_windows_are_refused():
    config = CONFIGS["small"]
    gyr, acc, count, t_rel, dt, mag, clip = _windows(config, 2, 1)
    with pytest.raises(ValueError, match="mismatched"):
        window_features(config, sensor_values(_model(config)), gyr[:1], acc, count, t_rel, dt, mag, clip)
    with pytest.raises(ValueError, match="mismatched"):
        window_features(CONFIGS["9-D"], sensor_values(_model(config)), gyr, acc, count, t_rel, dt, mag[:, :3], clip)


def test_dataclass_round_trip():
    m = _model(CONFIGS["small"])
    s = sensor_values(m)
    from tepinn_flight.model.window_features import SensorValues

    assert SensorValues.from_json(json.loads(json.dumps(s.to_json()))) == s  # through the metadata's JSON
    assert s.kappa is not None and s.S_g != SensorValues.identity().S_g
