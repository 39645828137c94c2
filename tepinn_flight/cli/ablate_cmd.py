"""``tepinn-flight ablate --config train/ablation.toml -o DIR [--eval RECORDS...]``."""

from __future__ import annotations

from ..evaluation.ablation import VARIANTS
from .helptext import add_examples

HELP = "train and evaluate the paper's ablation (no physics, no transformer, no correction layer, ...)"
DESCRIPTION = (
    "Trains the full TE-PINN and one variant per removed component from the same recipe, budget and "
    "seed (no physics, no transformer, no correction layer, no adaptive weighting, no uncertainty, and "
    "the LSTM baseline), evaluates all of them on the same held-out records, and writes one table "
    "(DIR/ablation.md, DIR/ablation.json). Resumable: finished variants are skipped."
)


def add_arguments(p) -> None:
    add_examples(p,
                 'tepinn-flight ablate --config train/ablation.toml -o ablation/ --eval sims/test/')
    p.add_argument("--config", required=True, metavar="TOML", help="training recipe shared by all variants")
    p.add_argument("-o", "--output", required=True, metavar="DIR", help="folder for the runs and the table")
    p.add_argument("--data", action="extend", nargs="+", default=[], metavar="DIR",
                   help="folder(s) of training records, added to the recipe's (one or more; repeatable)")
    p.add_argument("--eval", nargs="+", default=None, metavar="RECORD",
                   help="held-out records or folders (default: flight_sims/campaigns/heldout.toml flown into DIR/heldout)")
    p.add_argument("--variants", default=",".join(VARIANTS), help=f"comma-separated subset of {', '.join(VARIANTS)}")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="override a recipe value for all variants")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress bar and no progress lines")


def run(args) -> int:
    import sys
    from pathlib import Path

    from ..evaluation.ablation import (ablation_markdown, check_variants, evaluate_variants, heldout_records,
                                       train_variants, write_ablation)  # fmt: skip
    from ..model.train_config import load_train_config
    from ..record import check_output, read_record
    from .paths import collect_records, read_records

    from ..errors import ConfigError

    names = [v.strip() for v in args.variants.split(",") if v.strip()]
    if not names:  # (review60: a table of VQF alone)
        raise ConfigError("--variants names no variant")
    check_variants(names)
    eval_paths = collect_records(args.eval) if args.eval else None  # before the training (review60: a typo after it)
    base = load_train_config(args.config, args.set)
    out = Path(args.output)
    check_output(out, folder=True)  # a file, or a folder that cannot be made: one line, before the training
    out.mkdir(parents=True, exist_ok=True)
    say = (lambda s: None) if args.quiet else (lambda s: sys.stderr.write(s + "\n"))
    ckpts = train_variants(base, names, out, data_dirs=args.data, config_base=Path(args.config).resolve().parent,
                           progress=not args.quiet, say=say)  # fmt: skip
    if args.eval:
        read_notes: list[str] = []
        records = read_records(args.eval, eval_paths, read_notes)
        for n in read_notes:
            say(f"note: {n}")
    else:
        records = [read_record(p) for p in heldout_records(out, progress=not args.quiet)]
    rows, notes = evaluate_variants(ckpts, records, progress=not args.quiet)
    md = ablation_markdown(rows, args.config, len(records), notes, overrides=args.set or ())
    write_ablation(out, rows, md)
    print(md)
    return 0
