"""The paper's ablation: the full TE-PINN and one variant per removed component, trained from the same
recipe, budget and seed, evaluated on the same held-out records, in one table (``tepinn-flight
ablate``; the CLI only parses arguments and prints).

Nothing heavy at import (torch, JSBSim): :data:`VARIANTS` is read by the CLI's ``--help``.
"""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path

#: variant → (ModelConfig overrides, LossConfig overrides)
VARIANTS = {
    "full": ({}, {}),
    "no-physics": ({"physics": False, "centripetal": False, "centripetal_rate": False}, {}),
    "no-transformer": ({"encoder": "mlp"}, {}),
    "no-correction-layer": ({"correction_layer": False}, {}),
    "no-adaptive-weighting": ({}, {"adaptive": False}),
    "no-uncertainty": ({"uncertainty": False}, {}),
    "lstm-baseline": ({"encoder": "lstm", "physics": False, "centripetal": False, "centripetal_rate": False}, {}),
}


def check_variants(names: list[str]) -> None:
    from ..errors import ConfigError

    unknown = [v for v in names if v not in VARIANTS]
    if unknown:
        raise ConfigError(f"unknown variant(s) {unknown}; known: {', '.join(VARIANTS)}")


def variant_config(base, name: str):
    """The training recipe ``base`` (a ``TrainConfig``) with variant ``name``'s components removed."""
    m_over, l_over = VARIANTS[name]
    return dataclasses.replace(base, model=dataclasses.replace(base.model, **m_over),
                               loss=dataclasses.replace(base.loss, **l_over))  # fmt: skip


def heldout_campaign() -> Path:
    """The default held-out records: the ``heldout`` simulation campaign of the checkout."""
    from ..sim import FLIGHT_SIMS_DIR

    return FLIGHT_SIMS_DIR / "campaigns" / "heldout.toml"


def train_variants(base, names: list[str], out: Path, data_dirs=(), config_base: Path = Path("."),
                   progress: bool = True, say=lambda s: None) -> dict[str, Path]:  # fmt: skip
    """Train each variant into ``out/<variant>`` (resumable: a finished variant is skipped);
    returns variant → its ``model.pt``."""
    from ..errors import ConfigError
    from ..model.train import run_recipe_differences, train

    ckpts = {}
    for v in names:
        run_dir = out / v
        if (run_dir / "model.pt").exists():
            diff = run_recipe_differences(run_dir, variant_config(base, v))  # taken only where this variant's recipe
            if diff:  # made it (review60: any finished variant was, silently)
                shown = "; ".join(diff[:4]) + ("; ..." if len(diff) > 4 else "")
                raise ConfigError(f"{run_dir} holds the variant {v} trained from another recipe ({shown}): ablate "
                                  "into a new folder (-o), or remove that one to train it again")  # fmt: skip
            say(f"{v}: already trained ({run_dir / 'model.pt'})")
        else:
            say(f"{v}: training ...")
            train(variant_config(base, v), run_dir, data_dirs=data_dirs, resume=(run_dir / "last.pt").exists(),
                  config_base=config_base, progress=progress, log=say)  # fmt: skip
        ckpts[v] = run_dir / "model.pt"
    return ckpts


def heldout_records(out: Path, progress: bool = True) -> list[Path]:
    """Fly the held-out campaign into ``out/heldout`` (resumable) and return its records."""
    from ..sim.campaign import run_campaign

    run_campaign(heldout_campaign(), out / "heldout", progress=progress)
    return sorted((out / "heldout").glob("*.parquet"))


def evaluate_variants(ckpts: dict[str, Path], records, progress: bool = True) -> tuple[list[dict], list[str]]:
    """Every variant and VQF on the same records (5 s warm-up): one row per estimator, and notes."""
    from .estimators import TepinnEstimator
    from .harness import HarnessConfig, evaluate
    from .suite import peer_estimators

    ests = [TepinnEstimator.from_checkpoint(p, v) for v, p in ckpts.items()]
    notes: list[str] = []
    ests += [e for e in peer_estimators(notes=notes) if e.name == "vqf"]
    res = evaluate(records, ests, HarnessConfig(warmup_s=5.0), progress=progress, keep_series=False, notes=notes)
    ref = res.dataset.get("full", {}).get("inclination_rmse_deg")
    rows = []
    for e in ests:
        d = res.dataset[e.name]
        unc = d.get("uncertainty") or {}
        rows.append({
            "variant": e.name,
            "inclination_rmse_deg": d.get("inclination_rmse_deg"),
            "inclination_rmse_median_deg": d.get("inclination_rmse_median_deg"),
            "gyr_bias_rms_deg_s": d.get("gyr_bias_rms_deg_s"),
            "nees": unc.get("nees"),
            "vs_full": (d.get("inclination_rmse_deg") / ref) if ref and d.get("inclination_rmse_deg") else None,
        })  # fmt: skip
    if len(ckpts) > 1 and identical_variants(res.records, list(ckpts)):
        notes.append(IDENTICAL_NOTE)
    return rows, notes


#: said when every variant scores the same on every record (a recipe whose anchored estimator kept every gate shut)
IDENTICAL_NOTE = ("every variant scores the same on every record: the filter-anchored estimator's gates stayed shut, "
                  "so the network (the part the variants change) corrected nothing here and this ablation measures no "
                  "component. Ablate on records where a gate acts (fixed-wing flight, a saturating or uncalibrated "
                  "gyro: the default held-out campaign), or with a recipe whose estimator is the network-centred fusion alone "
                  "(--set anchor.enabled=false)")


def identical_variants(records: list[dict], names: list[str], tol_deg: float = 1e-9) -> bool:
    """Whether every variant's inclination RMSE equals the others' on every record (finite scores only; at least two
    of them on some record, else there is nothing to call equal)."""
    compared = False
    for r in records:
        vals = [r["results"][n].get("inclination_rmse_deg") for n in names]
        vals = [float(v) for v in vals if v is not None and math.isfinite(float(v))]
        if len(vals) >= 2:
            compared = True
            if max(vals) - min(vals) > tol_deg:
                return False
    return compared


def ablation_markdown(rows: list[dict], recipe: str, n_records: int, notes=(), overrides=()) -> str:
    """The ablation table (``ablation.md``)."""
    from .names import display_name

    table = ["| variant | inclination RMSE ° (mean over flights) | median ° | gyro-bias RMSE °/s | NEES (2 = calibrated) | × full |",
             "|---|---:|---:|---:|---:|---:|"]  # fmt: skip
    f = lambda x, nd=2: "–" if x is None else f"{x:.{nd}f}"  # noqa: E731
    for r in rows:
        table.append(f"| {display_name(r['variant'])} | {f(r['inclination_rmse_deg'])} | {f(r['inclination_rmse_median_deg'])} | "
                     f"{f(r['gyr_bias_rms_deg_s'], 3)} | {f(r['nees'])} | {f(r['vs_full'])} |")  # fmt: skip
    sets = f" with {', '.join(f'`{o}`' for o in overrides)}" if overrides else ""  # (review60: the --set unsaid)
    md = (f"# TE-PINN ablation\n\nRecipe `{recipe}`{sets}, same data, budget and seed for every variant; "
          f"evaluated on {n_records} held-out flights (5 s warm-up).\n\n" + "\n".join(table) + "\n")
    if notes:
        md += "\n" + "\n".join(f"- {n}" for n in notes) + "\n"
    return md


def write_ablation(out: Path, rows: list[dict], md: str) -> None:
    """``out/ablation.md`` and ``out/ablation.json``, atomically."""
    from ..record import atomic_write

    atomic_write(out / "ablation.md", lambda tmp: Path(tmp).write_text(md))
    atomic_write(out / "ablation.json", lambda tmp: Path(tmp).write_text(json.dumps(rows, indent=2)))
