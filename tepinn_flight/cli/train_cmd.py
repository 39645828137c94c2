"""``tepinn-flight train --config train/NAME.toml [--data DIR ...] -o RUN_DIR [--resume]``."""

from __future__ import annotations

import sys

from .argtypes import threads
from .helptext import add_examples

HELP = "train TE-PINN from a TOML recipe, or fine-tune a model on your own logs (--init)"
DESCRIPTION = (
    "Train from a strict TOML recipe (unknown keys are refused). Writes RUN_DIR/metrics.jsonl every "
    "epoch, atomic checkpoints (last.pt, best.pt) and the final RUN_DIR/model.pt. Resumable with "
    "--resume; deterministic for a seed (bit for bit on the CPU with the same --threads and torch build). Runs under `torchrun --nproc_per_node=N` with "
    "DistributedDataParallel (gloo on CPU, NCCL on GPUs: --device). "
    "Fine-tuning on your own logs, no recipe needed: tepinn-flight train --init default --data logs/ -o runs/mine "
    "(any format ingest reads; the autopilot's estimate is the label; a few minutes on 2 CPU cores), then "
    "tepinn-flight estimate flight.parquet --model runs/mine/model.pt -o est.parquet."
)


#: below this share of validation samples within 3σ (and below the start's), fine-tuning warns about its σ
SIGMA_WARN_WITHIN_3SIGMA = 0.95


def add_arguments(p) -> None:
    add_examples(p,
                 'tepinn-flight train --init default --data logs/ -o runs/mine     # fine-tune on your own logs',
                 'tepinn-flight train --config train/tiny.toml -o runs/tiny',
                 'torchrun --nproc_per_node=4 -m tepinn_flight train --config train/default.toml -o runs/full --device cuda')
    p.add_argument("--config", default=None, metavar="TOML",
                   help="training recipe, e.g. train/tiny.toml (without it: --init fine-tunes with the built-in recipe)")
    p.add_argument("--init", default=None, metavar="MODEL",
                   help="start from this checkpoint ('default': the shipped model); without --config, fine-tune it on --data")
    p.add_argument("--data", action="extend", nargs="+", default=[], metavar="PATH",
                   help="folder(s) of flight records (added to the recipe's); with --init alone: logs or folders of logs "
                        "in any format ingest reads (one or more after --data, and --data may be repeated)")
    p.add_argument("--minutes", type=float, default=None,
                   help="fine-tuning: training time limit (default 6); a recipe's is optim.max_minutes (--set)")
    p.add_argument("--align-reference", action="store_true",
                   help="fine-tuning: a log whose reference is refused for being off the IMU's time (> 0.1 s) or frame "
                        "(> 20°) is learned from once moved by the lag and turned by the rotation its check measures, "
                        "where it then passes (the moved copies in RUN_DIR/aligned/); without it such a log is skipped")
    p.add_argument("-o", "--output", required=True, metavar="RUN_DIR", help="run folder (checkpoints, metrics)")
    p.add_argument("--resume", action="store_true", help="continue from RUN_DIR/last.pt")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="override a recipe value, e.g. optim.epochs=5")
    p.add_argument("--device", default="auto", choices=["auto", "cpu", "cuda"],
                   help="where to train: auto (a CUDA GPU when torch sees one, else the CPU), cpu, cuda")
    p.add_argument("--threads", type=threads, default=0, metavar="N", help="torch CPU threads per process (default: torch's choice)")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress bar")


def run(args) -> int:
    from pathlib import Path

    import torch

    from ..model.train import train
    from ..model.train_config import load_train_config
    from ..record import check_output

    from ..errors import ConfigError

    if args.threads:
        torch.set_num_threads(args.threads)
    if args.config is None:
        if args.init is None:
            raise ConfigError("give --config TOML (train from a recipe) or --init MODEL (fine-tune on --data)")
        if not args.data:
            raise ConfigError("--init without --config fine-tunes on your logs: give --data LOG_OR_DIR")
        if args.minutes is not None and not 0 < args.minutes < float("inf"):
            raise ConfigError(f"--minutes must be a finite number > 0, got {args.minutes}")
        ignored = [f for f, given in (("--set", args.set), ("--resume", args.resume), ("--device", args.device != "auto"))
                   if given]  # fmt: skip
        if ignored:  # (they were taken and ignored: a recipe's options, which the built-in fine-tuning has no use for)
            raise ConfigError(f"{', '.join(ignored)}: options of a recipe (--config); fine-tuning (--init without "
                              "--config) runs its built-in recipe on the CPU, its length set by --minutes, from the "
                              "start each time")  # fmt: skip
        from ..model.finetune import finetune

        out = check_output(args.output, folder=True)
        _refuse_init_in_run(args.init, out)
        length = {} if args.minutes is None else {"minutes": args.minutes}  # (None: the fine-tuning's own default)
        s = finetune(args.init, args.data, out, progress=not args.quiet, align_reference=args.align_reference, **length)
        # (one file: nothing is held out, and the figures below are on the file it was tuned on: said so, not "validation")
        files = "validation files" if s["val_files"] else "file it was tuned on"
        fit = s["fitted_sigma"]
        fitted = (f"σ₀ {fit['sigma_floor_deg']:g}°, c {fit['sigma_acc_gain']:g}, sampling term "
                  f"{'on' if fit['sigma_sampling_gain'] else 'off'}")
        if s["sigma_kept"] == "init":  # the fit on the training files scored worse on the others than the start's σ
            n_f, c_f = s["val_sigma_by_choice"]["fitted"]
            sigma = (f"σ kept from {args.init} (fitted on the training files, {fitted}, it scored NEES {n_f:.2f}, "
                     f"{100 * c_f:.1f} % within 3σ on the {files})")
        else:
            sigma = fitted
        held = ("" if s["val_files"] else
                " (no file held out: give two or more logs to validate; the figures are on the file it was tuned on)")
        print(f"fine-tuned on {len(s['train_files'])} file(s), validated on {len(s['val_files'])}{held}: "
              f"inclination RMSE {s['val_inclination_rmse_deg_before']:.3f}° -> {s['val_inclination_rmse_deg_after']:.3f}° "
              f"(VQF accelerometer time constant {s['tau_acc_s']:g} s, gyro scale "
              f"{', '.join(f'{v:g}' for v in s['gyro_scale'])}; {sigma}: "
              f"NEES {s['val_sigma_nees_before']:.2f} -> {s['val_sigma_nees_after']:.2f}, within 3σ "
              f"{100 * s['val_sigma_within_3sigma_before']:.1f} -> {100 * s['val_sigma_within_3sigma_after']:.1f} % causal; "
              f"offline tilt smoothing {'kept' if s['smoother'] else 'off'}: training files "
              f"{s['smoother_grid_deg']['on']:.3f}° with it, {s['smoother_grid_deg']['off']:.3f}° without); "
              f"on the {files} {s['val_network_gates_summary']}; model: {out / 'model.pt'}")  # fmt: skip
        in3_0, in3_1 = s["val_sigma_within_3sigma_before"], s["val_sigma_within_3sigma_after"]
        if in3_1 < SIGMA_WARN_WITHIN_3SIGMA and in3_1 < in3_0:  # σ refitted on the training files: said where it
            # fails the others (NEES 0.77 -> 19.3, 39.5 % within 3σ passed without a word)
            print(f"warning: the fine-tuned σ is over-confident on the {files}: {100 * in3_1:.1f} % of samples within 3σ "
                  f"({100 * in3_0:.1f} % before), NEES {s['val_sigma_nees_after']:.2f} (2 is calibrated); trust "
                  f"sigma_rad less than the attitude, or add logs of this vehicle", file=sys.stderr)  # fmt: skip
        if s["val_worse_than_init"]:
            print(f"warning: the fine-tuned model is worse than {args.init} on the {files} "
                  f"({s['val_inclination_rmse_deg_before']:.3f}° -> {s['val_inclination_rmse_deg_after']:.3f}°): keep using "
                  f"{args.init}, or add logs of this vehicle (finetune.json: the figures per setting)", file=sys.stderr)  # fmt: skip
        return 0
    if args.align_reference:  # (a recipe reads records as they are: align them with evaluate's check first)
        raise ConfigError("--align-reference is the fine-tuning's (--init without --config); a recipe reads its records "
                          "as they are")  # fmt: skip
    if args.minutes is not None:  # (it was taken and ignored: the recipe's own time limit ran)
        raise ConfigError(f"--minutes is the fine-tuning's time limit (--init without --config); a recipe's is "
                          f"optim.max_minutes: --set optim.max_minutes={args.minutes:g}")  # fmt: skip
    cfg = load_train_config(args.config, args.set)
    if args.init:
        import dataclasses

        cfg = dataclasses.replace(cfg, init=args.init)
    # a place that cannot be written is a one-line error before any work (creates nothing);
    # train() refuses a folder holding a run (last.pt) without --resume
    out = check_output(args.output, folder=True)
    if args.init:
        _refuse_init_in_run(args.init, out)
    train(cfg, out, data_dirs=args.data, resume=args.resume, config_base=Path(args.config).resolve().parent,
          progress=not args.quiet, device=args.device)  # fmt: skip
    return 0


def _refuse_init_in_run(init: str, out) -> None:
    """The run writes ``model.pt`` and ``last.pt`` in ``out``: never over the model it starts from (``--init
    RUN/model.pt -o RUN`` had replaced it; session 53)."""
    from pathlib import Path

    if init == "default":
        return
    from ..errors import ConfigError
    from .paths import refuse_overwriting_inputs

    for name in ("model.pt", "last.pt", "model.onnx"):
        try:
            refuse_overwriting_inputs([("-o", Path(out) / name)], [init])
        except ConfigError:  # (said of -o as given: "-o RUN/model.pt is the input" had named a path the user never gave)
            raise ConfigError(f"-o {out}: the run writes its {name} there, which is --init {init}: name another folder") from None
