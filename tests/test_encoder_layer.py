"""The network's transformer layer written for a clean export (``network.encoder_layer``) is
``nn.TransformerEncoderLayer`` with the same weights: in eval mode for any batch, window length,
width and head count; in training mode its dropouts are the layer's own (same mask stream)."""

from __future__ import annotations

import pytest

torch = pytest.importorskip("torch")

from tepinn_flight.model.network import encoder_layer  # noqa: E402


@pytest.mark.parametrize("b,k,d,heads,ff", [(1, 80, 48, 4, 96), (5, 24, 16, 2, 32), (3, 7, 12, 3, 8)])
def test_equals_torch_layer_in_eval(b, k, d, heads, ff):
    torch.manual_seed(k)
    layer = torch.nn.TransformerEncoderLayer(d, heads, ff, 0.1, activation="gelu", batch_first=True).eval()
    h = torch.randn(b, k, d)
    with torch.no_grad():
        want = layer(h)
        got = encoder_layer(layer, h, k, d, heads)
    torch.testing.assert_close(got, want, rtol=0, atol=2e-6)
    assert (got - layer.norm2(h)).abs().max() > 0.1  # not a pass-through


def test_dropout_in_training_is_the_layers():
    torch.manual_seed(0)
    layer = torch.nn.TransformerEncoderLayer(16, 2, 32, 0.3, activation="gelu", batch_first=True).train()
    h = torch.randn(4, 10, 16)
    a, b = encoder_layer(layer, h, 10, 16, 2), encoder_layer(layer, h, 10, 16, 2)
    assert (a - b).abs().max() > 1e-3  # dropout is live
    layer.eval()
    torch.testing.assert_close(encoder_layer(layer, h, 10, 16, 2), layer(h), rtol=0, atol=2e-6)
