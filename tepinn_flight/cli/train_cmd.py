"""``tepinn-flight train --config train/NAME.toml [--data DIR ...] -o RUN_DIR [--resume]``."""

from __future__ import annotations

from .argtypes import threads

HELP = "train TE-PINN (or an ablation/LSTM baseline) from a TOML recipe"
DESCRIPTION = (
    "Train from a strict TOML recipe (unknown keys are refused). Writes RUN_DIR/metrics.jsonl every "
    "epoch, atomic checkpoints (last.pt, best.pt) and the final RUN_DIR/model.pt. Resumable with "
    "--resume; deterministic for a seed. Runs under `torchrun --nproc_per_node=N` with "
    "DistributedDataParallel (gloo on CPU, NCCL on GPUs: --device)."
)


def add_arguments(p) -> None:
    p.add_argument("--config", required=True, metavar="TOML", help="training recipe, e.g. train/tiny.toml")
    p.add_argument("--data", action="append", default=[], metavar="DIR", help="folder(s) of flight records (added to the recipe's)")
    p.add_argument("-o", "--output", required=True, metavar="RUN_DIR", help="run folder (checkpoints, metrics)")
    p.add_argument("--resume", action="store_true", help="continue from RUN_DIR/last.pt")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="override a recipe value, e.g. optim.epochs=5")
    p.add_argument("--device", default="auto", choices=["auto", "cpu", "cuda"],
                   help="where to train: auto (a CUDA GPU when torch sees one, else the CPU), cpu, cuda")
    p.add_argument("--threads", type=threads, default=0, help="torch CPU threads per process (default: torch's choice)")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress bar")


def run(args) -> int:
    from pathlib import Path

    import torch

    from ..model.train import train
    from ..model.train_config import load_train_config
    from ..record import check_output

    if args.threads:
        torch.set_num_threads(args.threads)
    cfg = load_train_config(args.config, args.set)
    # a place that cannot be written is a one-line error before any work (creates nothing);
    # train() refuses a folder holding a run (last.pt) without --resume
    out = check_output(args.output, folder=True)
    train(cfg, out, data_dirs=args.data, resume=args.resume, config_base=Path(args.config).resolve().parent,
          progress=not args.quiet, device=args.device)  # fmt: skip
    return 0
