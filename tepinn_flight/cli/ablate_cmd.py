"""``tepinn-flight ablate --config train/ablation.toml -o DIR [--eval RECORDS...]``."""

from __future__ import annotations

HELP = "train and evaluate the paper's ablation (no physics, no transformer, no correction layer, ...)"
DESCRIPTION = (
    "Trains the full TE-PINN and one variant per removed component from the same recipe, budget and "
    "seed (no physics, no transformer, no correction layer, no adaptive weighting, no uncertainty, and "
    "the LSTM baseline), evaluates all of them on the same held-out records, and writes one table "
    "(DIR/ablation.md, DIR/ablation.json). Resumable: finished variants are skipped."
)

VARIANTS = {
    "full": ({}, {}),
    "no-physics": ({"physics": False, "centripetal": False, "centripetal_rate": False}, {}),
    "no-transformer": ({"encoder": "mlp"}, {}),
    "no-correction-layer": ({"correction_layer": False}, {}),
    "no-adaptive-weighting": ({}, {"adaptive": False}),
    "no-uncertainty": ({"uncertainty": False}, {}),
    "lstm-baseline": ({"encoder": "lstm", "physics": False, "centripetal": False, "centripetal_rate": False}, {}),
}


def add_arguments(p) -> None:
    p.add_argument("--config", required=True, metavar="TOML", help="training recipe shared by all variants")
    p.add_argument("-o", "--output", required=True, metavar="DIR", help="folder for the runs and the table")
    p.add_argument("--data", action="append", default=[], metavar="DIR", help="training records (added to the recipe's)")
    p.add_argument("--eval", nargs="+", default=None, metavar="RECORD",
                   help="held-out records or folders (default: flight_sims/campaigns/heldout.toml flown into DIR/heldout)")
    p.add_argument("--variants", default=",".join(VARIANTS), help=f"comma-separated subset of {', '.join(VARIANTS)}")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="override a recipe value for all variants")
    p.add_argument("-q", "--quiet", action="store_true")


def run(args) -> int:
    import dataclasses
    import json
    import sys
    from pathlib import Path

    from ..errors import ConfigError
    from ..evaluation.estimators import TepinnEstimator
    from ..evaluation.harness import HarnessConfig, evaluate
    from ..evaluation.names import display_name
    from ..evaluation.suite import peer_estimators
    from ..model.train import train
    from ..model.train_config import load_train_config
    from ..record import atomic_write, read_record
    from .evaluate_cmd import collect_records

    names = [v.strip() for v in args.variants.split(",") if v.strip()]
    unknown = [v for v in names if v not in VARIANTS]
    if unknown:
        raise ConfigError(f"unknown variant(s) {unknown}; known: {', '.join(VARIANTS)}")
    base = load_train_config(args.config, args.set)
    out = Path(args.output)
    out.mkdir(parents=True, exist_ok=True)
    cfg_base = Path(args.config).resolve().parent
    say = (lambda s: None) if args.quiet else (lambda s: sys.stderr.write(s + "\n"))
    ckpts = {}
    for v in names:
        m_over, l_over = VARIANTS[v]
        cfg = dataclasses.replace(base, model=dataclasses.replace(base.model, **m_over),
                                  loss=dataclasses.replace(base.loss, **l_over))  # fmt: skip
        run_dir = out / v
        if (run_dir / "model.pt").exists():
            say(f"{v}: already trained ({run_dir / 'model.pt'})")
        else:
            say(f"{v}: training ...")
            train(cfg, run_dir, data_dirs=args.data, resume=(run_dir / "last.pt").exists(), config_base=cfg_base,
                  progress=not args.quiet, log=say)  # fmt: skip
        ckpts[v] = run_dir / "model.pt"
    if args.eval:
        paths = collect_records(args.eval)
    else:
        from ..sim.campaign import run_campaign

        repo = Path(__file__).resolve().parents[2]
        run_campaign(repo / "flight_sims" / "campaigns" / "heldout.toml", out / "heldout", progress=not args.quiet)
        paths = sorted((out / "heldout").glob("*.parquet"))
    records = [read_record(p) for p in paths]
    ests = [TepinnEstimator.from_checkpoint(p, v) for v, p in ckpts.items()]
    notes: list[str] = []
    ests += [e for e in peer_estimators(notes=notes) if e.name == "vqf"]
    res = evaluate(records, ests, HarnessConfig(warmup_s=5.0), progress=not args.quiet, keep_series=False, notes=notes)
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
    table = ["| variant | inclination RMSE ° (mean over flights) | median ° | gyro-bias RMSE °/s | NEES (2 = calibrated) | × full |",
             "|---|---:|---:|---:|---:|---:|"]  # fmt: skip
    f = lambda x, nd=2: "–" if x is None else f"{x:.{nd}f}"  # noqa: E731
    for r in rows:
        table.append(f"| {display_name(r['variant'])} | {f(r['inclination_rmse_deg'])} | {f(r['inclination_rmse_median_deg'])} | "
                     f"{f(r['gyr_bias_rms_deg_s'], 3)} | {f(r['nees'])} | {f(r['vs_full'])} |")  # fmt: skip
    md = (f"# TE-PINN ablation\n\nRecipe `{args.config}`, same data, budget and seed for every variant; "
          f"evaluated on {len(records)} held-out flights (5 s warm-up).\n\n" + "\n".join(table) + "\n")
    if notes:
        md += "\n" + "\n".join(f"- {n}" for n in notes) + "\n"
    atomic_write(out / "ablation.md", lambda tmp: Path(tmp).write_text(md))
    atomic_write(out / "ablation.json", lambda tmp: Path(tmp).write_text(json.dumps(rows, indent=2)))
    print(md)
    return 0
