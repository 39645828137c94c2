"""Training data: a recipe's ``[data]`` section → flight records (record files, folders and globs;
optional real logs, ingested; a simulation campaign flown into the run folder; synthetic flights)
and the split into training and validation flights."""

from __future__ import annotations

import sys
import tomllib
from pathlib import Path

import numpy as np

from ..errors import ConfigError, TepinnError
from ..ingest import load_record
from ..record import FlightRecord
from .train_config import TrainConfig


def resolve_records(patterns, base: Path) -> list[Path]:
    out: list[Path] = []
    for pat in patterns:
        p = Path(pat)
        p = p if p.is_absolute() else base / p
        if p.is_dir():
            found = sorted(p.rglob("*.parquet"))
            if not found:
                raise ConfigError(f"no flight records (*.parquet) in training data folder {pat}")
            out += found
        elif p.exists():  # a file whose name holds [, * or ? is that file, not a pattern (session 53)
            out.append(p)
        elif any(ch in str(pat) for ch in "*?["):
            found = sorted(Path(p.anchor).glob(str(p.relative_to(p.anchor))) if p.is_absolute() else base.glob(str(pat)))
            if not found:
                raise ConfigError(f"training data pattern matches nothing: {pat}")
            out += found
        else:
            raise ConfigError(f"training data not found: {pat}")
    return sorted(set(out))


def load_records(cfg: TrainConfig, extra_dirs=(), base: Path = Path("."), run_dir: Path | None = None,
                 progress: bool = True) -> list[FlightRecord]:  # fmt: skip
    recs: list[FlightRecord] = []
    extra = [str(Path(d).resolve()) for d in extra_dirs]  # --data folders are relative to the cwd
    if cfg.data.campaign:
        from ..sim.campaign import run_campaign

        camp = Path(cfg.data.campaign)
        camp = camp if camp.is_absolute() else base / camp
        data_dir = (run_dir or Path(".")) / "data"
        res = run_campaign(camp, data_dir, workers=cfg.data.campaign_workers or None, progress=progress)
        if res.failed:
            raise TepinnError(f"{len(res.failed)} simulated flight(s) failed: {res.failure_causes()}")
        extra.append(str(data_dir.resolve()))
    paths = resolve_records(list(cfg.data.records) + extra, base)
    for pat in cfg.data.optional_records:
        try:
            paths += [p for p in resolve_records([pat], base) if p not in paths]
        except ConfigError as exc:
            print(f"note: optional training data skipped ({exc})", file=sys.stderr)
    if cfg.data.heldout_split:
        paths = drop_heldout(paths, base / cfg.data.heldout_split)
    recs += [load_record(p) for p in paths]  # records are read, logs (optional real data) ingested
    if cfg.data.synthetic_flights:
        from .synthetic import synthetic_record

        for i in range(cfg.data.synthetic_flights):
            recs.append(synthetic_record(seed=1000 * cfg.seed + i, duration_s=cfg.data.synthetic_duration_s))
    if not recs:
        raise ConfigError("no training data: give --data DIR, data.records or data.synthetic_flights")
    return recs


def heldout_names(split_path: Path) -> set[str]:
    """The file names a split TOML's ``[heldout]`` section lists (every list in it)."""
    try:
        split = tomllib.loads(Path(split_path).read_text())
    except (OSError, tomllib.TOMLDecodeError) as exc:
        raise ConfigError(f"heldout_split {split_path}: {exc}") from None
    held = split.get("heldout", {})
    if not isinstance(held, dict):
        raise ConfigError(f"heldout_split {split_path}: [heldout] must be a table of file-name lists")
    return {str(n) for v in held.values() if isinstance(v, list) for n in v}


def drop_heldout(paths: list, split_path: Path) -> list:
    """``paths`` without the files the split holds out (matched by file name), with a note."""
    held = heldout_names(split_path)
    keep = [p for p in paths if Path(p).name not in held]
    if len(keep) < len(paths):
        print(f"note: {len(paths) - len(keep)} held-out file(s) of {Path(split_path).name} left out of training",
              file=sys.stderr)  # fmt: skip
    return keep


def split_by_flight(n: int, val_fraction: float, seed: int) -> tuple[list[int], list[int]]:
    """Hold out whole flights: a seeded permutation, at least one flight on each side when n ≥ 2."""
    perm = np.random.default_rng(seed).permutation(n)
    n_val = 0 if n < 2 else min(n - 1, max(1, int(round(val_fraction * n))))
    return sorted(perm[n_val:].tolist()), sorted(perm[:n_val].tolist())

