"""The runner's compiled physics head (model/head_physics.py) is the network's own
(:meth:`TEPINN.physics_head`, PyTorch, float64) for every switch that changes it: from the same linear
heads' outputs and token features it gives the same attitude; and each input it reads moves it."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from tepinn_flight.model.config import ModelConfig  # noqa: E402
from tepinn_flight.model.export import sensor_values  # noqa: E402
from tepinn_flight.model.head_physics import window_attitude  # noqa: E402
from tepinn_flight.model.window_features import window_features  # noqa: E402
from tests.test_window_features import CONFIGS as WF_CONFIGS  # noqa: E402
from tests.test_window_features import SMALL, _model, _windows  # noqa: E402

CONFIGS = {k: WF_CONFIGS[k] for k in ("shipped", "small", "no rate term", "no centripetal", "physics off")} | {
    "mean pooling": ModelConfig(**SMALL, learned_pooling=False),
    "mean pooling, not clip-aware": ModelConfig(**SMALL, learned_pooling=False, clip_aware=False),
    "no correction layer": ModelConfig(**SMALL, correction_layer=False),
    "physics and correction off": replace(WF_CONFIGS["physics off"], correction_layer=False),
}


def _heads(config: ModelConfig, batch: int = 6, seed: int = 4):
    """The model's linear heads' outputs (float64; the pooling logits and the velocity far from zero) and
    the runner's features for the same windows; and the model."""
    m = _model(config)
    g = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        if hasattr(m, "head_pool"):
            m.head_pool.weight.copy_(torch.randn(m.head_pool.weight.shape, generator=g, dtype=m.head_pool.weight.dtype))
    x = _windows(config, batch, seed)
    feats = window_features(config, sensor_values(m), *x)
    with torch.no_grad():
        h = m.encode(torch.as_tensor(feats["x"], dtype=torch.float64), torch.as_tensor(feats["t_rel"], dtype=torch.float64))
        lin = m.linear_heads(h)
    zeros3 = np.zeros((batch, 3))
    graph = {"q_head": lin["q_head"].numpy(), "pool": lin["pool"].numpy() if "pool" in lin else np.zeros((batch, 1)),
             "vel": lin["vel"].numpy() if "vel" in lin else zeros3, "acc_v": lin["acc_v"].numpy() if "acc_v" in lin else zeros3}
    return m, lin, graph, feats


@pytest.mark.parametrize("name", list(CONFIGS))
def test_compiled_head_equals_the_networks(name):
    config = CONFIGS[name]
    m, lin, graph, feats = _heads(config)
    graph = {k: v.astype(np.float32) for k, v in graph.items()}  # as the graph gives them
    got = window_attitude(config, graph, feats)
    t = {k: None if k not in feats else torch.as_tensor(feats[k], dtype=torch.float64) for k in ("v", "u", "cen", "cen_rate")}
    with torch.no_grad():
        lin = {k: torch.as_tensor(v.astype(np.float64)) for k, v in graph.items() if k in lin} | {"q_head": torch.as_tensor(graph["q_head"], dtype=torch.float64)}
        want = m.physics_head(lin, t["v"], t["u"], t["cen"], t["cen_rate"])["q"].numpy()
    assert got.dtype == np.float64 and got.shape == want.shape
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-6)
    if config.physics or config.correction_layer:  # the head quaternion is corrected (or its yaw zeroed)
        assert np.abs(got - graph["q_head"]).max() > 1e-3
    else:  # the head quaternion as it is
        np.testing.assert_array_equal(got, graph["q_head"])


def test_each_input_it_reads_moves_the_attitude():
    config = CONFIGS["shipped"]
    _, _, graph, feats = _heads(config)
    base = window_attitude(config, graph, feats)
    for part, key in (("graph", "pool"), ("graph", "vel"), ("graph", "acc_v"), ("graph", "q_head"),
                      ("feats", "v"), ("feats", "cen"), ("feats", "cen_rate")):
        g, f = dict(graph), dict(feats)
        d = g if part == "graph" else f
        bumped = np.array(d[key], dtype=np.float32)
        bumped[0] += 0.3 * np.sign(bumped[0]) + 0.1  # the first window's only
        d[key] = bumped
        q = window_attitude(config, g, f)
        assert np.abs(q[0] - base[0]).max() > 1e-5, key
        np.testing.assert_array_equal(q[1:], base[1:], err_msg=key)
    # mean pooling reads the trust: a token's trust cut moves the estimate
    config = CONFIGS["mean pooling"]
    _, _, graph, feats = _heads(config)
    base = window_attitude(config, graph, feats)
    f = dict(feats, u=np.array(feats["u"]))
    assert f["u"][1].min() == 1  # (the first window's saturated token cut the trust of half its tokens already)
    f["u"][1, : config.window_tokens // 3] = 0.0
    assert np.abs(window_attitude(config, graph, f)[1] - base[1]).max() > 1e-5


def test_a_window_without_trust_gives_nan_as_the_network_does():
    # mean pooling over tokens none of which is trusted: 0/0 in PyTorch's pooling, NaN here too (not an exception)
    config = CONFIGS["mean pooling"]
    m, lin, graph, feats = _heads(config, batch=2)
    f = dict(feats, u=np.array(feats["u"]))
    f["u"][0] = 0.0
    got = window_attitude(config, graph, f)
    t = {k: None if k not in f else torch.as_tensor(f[k], dtype=torch.float64) for k in ("v", "u", "cen", "cen_rate")}
    with torch.no_grad():
        want = m.physics_head(lin, t["v"], t["u"], t["cen"], t["cen_rate"])["q"].numpy()
    assert np.isnan(want[0]).all() and np.isnan(got[0]).all()
    np.testing.assert_allclose(got[1], want[1], rtol=0, atol=1e-6)
