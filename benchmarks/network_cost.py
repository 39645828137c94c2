"""What the network's window costs by its shape, beside the shipped network in the same run.

The offline estimate of a busy flight (fixed wing, a saturating gyro) and the live stream of one are bound by the
network's run per window (`benchmarks/PROFILE.md`, session 52). This times, on the windows of one record, the
shipped network's ONNX export and the exports of networks of other shapes (random weights: speed only, no accuracy),
at a busy block's batch (21 windows: what `anchored_windows` runs in the calling thread) and at a large one (128),
and prints each one's cost per window and its ratio to the shipped network's. A shape's windows per second of flight
are its token rate: the last column is the cost per second of a flight that runs every window.

Usage: python benchmarks/network_cost.py [--record REC] [--windows 2400] [--rounds 3]
       [--shape d_model=32,d_ff=64] [--shape n_layers=1] [--shape window_tokens=40] ...
(default shapes: width 32, one layer, 40-token windows, and 12.5 tokens/s with 40-token windows)
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

DEFAULT_SHAPES = ["d_model=32,d_ff=64", "n_layers=1", "window_tokens=40", "token_rate_hz=12.5,window_tokens=40"]
DEFAULT_RECORD = Path(__file__).resolve().parents[1] / "runs/default/data/0008-F450-agile-tactical-none-r0.parquet"


def parse_shape(text: str) -> dict:
    """``"d_model=32,d_ff=64"`` → ``{"d_model": 32, "d_ff": 64}`` (ints where they read as ints, else floats)."""
    out = {}
    for part in text.split(","):
        key, _, value = part.partition("=")
        if not value:
            raise SystemExit(f"network_cost.py: --shape {text!r}: each part is KEY=VALUE")
        out[key.strip()] = int(value) if value.strip().lstrip("-").isdigit() else float(value)
    return out


def time_windows(runner, tok, ends: np.ndarray, batch: int) -> float:
    """Seconds per window of the network's outputs for ``ends``, ``batch`` windows a call."""
    from tepinn_flight.model.estimate import network_outputs

    t0 = time.perf_counter()
    for a in range(0, len(ends), batch):
        network_outputs(runner, tok, ends[a : a + batch], None, 256)
    return (time.perf_counter() - t0) / max(len(ends), 1)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--record", default=str(DEFAULT_RECORD),
                    help="a record or log (default: training flight 0008 in runs/default/data, flown by the default "
                         "recipe or `simulate --campaign flight_sims/campaigns/mixed.toml -o runs/default/data`)")
    ap.add_argument("--windows", type=int, default=2400, help="windows timed per shape (the record's first)")
    ap.add_argument("--rounds", type=int, default=3, help="rounds over every shape; the best of each is printed")
    ap.add_argument("--shape", action="append", help="KEY=VALUE[,KEY=VALUE...] of the model config (repeatable)")
    args = ap.parse_args()

    import torch

    from tepinn_flight.errors import TepinnError
    from tepinn_flight.ingest import load_record
    from tepinn_flight.model.checkpoint import default_model_path, load_model, save_checkpoint
    from tepinn_flight.model.export import export_onnx
    from tepinn_flight.model.fusion import FusionConfig
    from tepinn_flight.model.network import TEPINN
    from tepinn_flight.model.runtime import OnnxRunner, export_in_sync
    from tepinn_flight.model.tokens import tokenize_record

    try:
        rec = load_record(args.record)
    except (TepinnError, OSError) as exc:
        print(f"network_cost.py: {exc}", file=sys.stderr)
        return 2
    ckpt = default_model_path()
    model, settings, _ = load_model(ckpt)
    shapes = {"shipped": {}}
    for text in args.shape or DEFAULT_SHAPES:
        shapes[text] = parse_shape(text)
    runners = {}
    with tempfile.TemporaryDirectory(prefix="tepinn-network-cost.") as tmp:
        for name, change in shapes.items():
            if not change:
                runners[name] = (OnnxRunner(export_in_sync(ckpt)), model.config)
                continue
            try:
                cfg = dataclasses.replace(model.config, **change)
            except TypeError as exc:
                print(f"network_cost.py: --shape {name}: {exc}", file=sys.stderr)
                return 2
            torch.manual_seed(0)
            path = Path(tmp) / f"shape{len(runners)}.pt"
            save_checkpoint(path, TEPINN(cfg).eval(), settings.fusion_config or FusionConfig(), settings)
            export_onnx(path, path.with_suffix(".onnx"))
            runners[name] = (OnnxRunner(path.with_suffix(".onnx")), cfg)
        toks = {}
        for runner, cfg in runners.values():  # first runs (allocations, the I/O binding) are not timed
            if cfg.token_rate_hz not in toks:
                toks[cfg.token_rate_hz] = tokenize_record(rec, cfg.token_rate_hz)
            tok = toks[cfg.token_rate_hz]
            for b in (21, 128):
                time_windows(runner, tok, tok.windows_ending(cfg.window_tokens)[:b], b)
        best = {(name, b): np.inf for name in runners for b in (21, 128)}
        for _ in range(args.rounds):  # interleaved: the machine's moments fall on every shape alike
            for name, (runner, cfg) in runners.items():
                tok = toks[cfg.token_rate_hz]
                ends = tok.windows_ending(cfg.window_tokens)[: args.windows]
                for b in (21, 128):
                    best[(name, b)] = min(best[(name, b)], time_windows(runner, tok, ends, b))
    print(f"{Path(args.record).name}: {args.windows} windows a shape, best of {args.rounds} rounds, onnxruntime")
    print(f"{'shape':40s} {'ms/window b21':>14s} {'b128':>8s} {'/ shipped':>10s} {'ms per s of flight':>19s}")
    ref = best[("shipped", 21)]
    for name, (_, cfg) in runners.items():
        b21, b128 = best[(name, 21)], best[(name, 128)]
        per_s = b21 * cfg.token_rate_hz * 1e3
        print(f"{name:40s} {b21 * 1e3:14.3f} {b128 * 1e3:8.3f} {b21 / ref:10.2f} {per_s:19.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
