"""argparse ``type=`` helpers: a bad value is argparse's one-line usage error (exit code 2)."""

from __future__ import annotations

import argparse


def int_at_least(lo: int, what: str = ""):
    """An integer ``>= lo`` (``what`` says what 0 means, for the message)."""

    def parse(text: str) -> int:
        try:
            v = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
        if v < lo:
            raise argparse.ArgumentTypeError(f"must be an integer >= {lo}{what}, got {v}")
        return v

    parse.__name__ = "integer"
    return parse


#: ``--threads``: 0 lets torch choose
threads = int_at_least(0, " (0: torch's choice)")

#: ``--busy-stride``: every N-th window of a busy block (>= 1; left out: the model's own setting)
busy_stride = int_at_least(1)

#: ``--workers``: processes estimating records side by side (>= 1)
workers = int_at_least(1)


def add_runtime(p) -> None:
    """``--runtime auto|torch|onnx``, as ``estimate``, ``evaluate``, ``benchmark broad``, ``demo`` and ``bridge`` take it
    (:func:`~tepinn_flight.model.runtime.resolve_runtime`)."""
    p.add_argument("--runtime", choices=["auto", "torch", "onnx"], default="auto",
                   help="run the network in PyTorch or onnxruntime (auto: onnx for an .onnx model, for a checkpoint "
                        "whose export made from it lies beside it — the shipped model — or where torch is not "
                        "installed, else torch)")


def check_runtime(models, runtime: str) -> None:
    """Refuse now, before the records are read, in one line, a ``--runtime`` the models given (the shipped one where
    none is) cannot run in — ``torch`` without PyTorch, an ``.onnx`` export under ``torch`` — and a model file the loader
    would refuse (:func:`~tepinn_flight.model.runtime.check_model`: without torch, a checkpoint with no export of it
    beside it; review61)."""
    from pathlib import Path

    from ..model.checkpoint import default_model_path
    from ..model.runtime import check_model, resolve_runtime

    if not models:
        resolve_runtime(default_model_path(), runtime)  # (the shipped model: its export ships beside it)
    for m in models:
        if not Path(m).exists():
            from ..errors import ConfigError

            raise ConfigError("no such model", m)
        check_model(Path(m), runtime)
