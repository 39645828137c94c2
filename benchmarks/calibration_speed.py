"""Fusion calibration speed in the default recipe: ``calibrate_with`` (what ``train`` runs at its end)
with the shipped network on the recipe's validation flights, timed whole and split into the network
(``network_outputs``) and the rest (the fusion runs and scoring); with ``--reference``, the same
calibration again with the former pure-Python fusion (``tests/fusion_reference.py``) in the same run,
and the ratio.

The recipe's flights must be there (``train --config train/default.toml -o RUN`` flies them into
``RUN/data``; the BROAD trials are read from ../shared where present): pass ``--run RUN``.

Usage: python benchmarks/calibration_speed.py --run runs/default [--max-flights 8] [--reference]
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from tepinn_flight.ingest import load_record  # noqa: E402
from tepinn_flight.model import estimate as estimate_mod  # noqa: E402
from tepinn_flight.model.calibration import calibrate_with  # noqa: E402
from tepinn_flight.model.train_config import load_train_config  # noqa: E402
from tepinn_flight.model.train_data import resolve_records, split_by_flight  # noqa: E402


def timed_calibration(cfg, model, val, train) -> tuple[float, float, object]:
    """(total s, network s, fitted FusionConfig)."""
    spent = [0.0]
    inner = estimate_mod.network_outputs

    def counted(*a, **k):
        t0 = time.perf_counter()
        try:
            return inner(*a, **k)
        finally:
            spent[0] += time.perf_counter() - t0

    estimate_mod.network_outputs = counted
    try:
        t0 = time.perf_counter()
        fusion, _ = calibrate_with(cfg, model, val, train)
        return time.perf_counter() - t0, spent[0], fusion
    finally:
        estimate_mod.network_outputs = inner


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--run", required=True, help="a run folder of the default recipe (its data/ holds the flights)")
    ap.add_argument("--config", default=str(REPO / "train" / "default.toml"))
    ap.add_argument("--max-flights", type=int, default=None, help="override [calibration] max_flights")
    ap.add_argument("--reference", action="store_true", help="also run it with the former pure-Python fusion")
    args = ap.parse_args()
    import torch

    from tepinn_flight.model.checkpoint import default_model_path, load_model

    torch.set_num_threads(2)
    cfg = load_train_config(args.config)
    if args.max_flights:
        cfg = dataclasses.replace(cfg, calibration=dataclasses.replace(cfg.calibration, max_flights=args.max_flights))
    base = Path(args.config).parent
    paths = resolve_records([str(Path(args.run).resolve() / "data")], base)
    for pat in cfg.data.optional_records:
        try:
            paths += [p for p in resolve_records([pat], base) if p not in paths]
        except Exception as exc:  # noqa: BLE001 - optional data, as train does
            print(f"note: optional data skipped ({exc})")
    records = [load_record(p) for p in paths]
    tr, va = split_by_flight(len(records), cfg.data.val_fraction, cfg.seed)
    val, train = [records[i] for i in va], [records[i] for i in tr]
    model, _, _ = load_model(default_model_path())
    print(f"{len(records)} flights, {len(val)} validation; max_flights {cfg.calibration.max_flights}")
    total, net, fusion = timed_calibration(cfg, model, val, train)
    print(f"compiled fusion:  {total:7.1f} s  (network {net:6.1f} s, the rest {total - net:6.1f} s)")
    if args.reference:
        from tests import fusion_reference

        compiled = estimate_mod.FusionRun
        estimate_mod.FusionRun = fusion_reference.FusionRun
        try:
            r_total, r_net, r_fusion = timed_calibration(cfg, model, val, train)
        finally:
            estimate_mod.FusionRun = compiled
        print(f"former fusion:    {r_total:7.1f} s  (network {r_net:6.1f} s, the rest {r_total - r_net:6.1f} s)")
        print(f"speed-up: {r_total / total:.1f}× in all, {(r_total - r_net) / max(total - net, 1e-9):.1f}× outside the network")
        # the two fusions' Kalman updates differ by round-off (1e-14), and so may a fitted float: "the same" to 1e-9
        diff = {f.name: (getattr(fusion, f.name), getattr(r_fusion, f.name)) for f in dataclasses.fields(fusion)
                if not _same(getattr(fusion, f.name), getattr(r_fusion, f.name))}  # fmt: skip
        print("same settings chosen (floats to 1e-9 relative)" if not diff
              else f"settings that differ (compiled, former): {diff}")  # fmt: skip
    return 0


def _same(a, b) -> bool:
    """Settings equal, a float to 1e-9 of the other's magnitude (the two fusions' round-off)."""
    if isinstance(a, float) and isinstance(b, float):
        return math.isclose(a, b, rel_tol=1e-9, abs_tol=1e-12)
    return a == b


if __name__ == "__main__":
    sys.exit(main())
