"""Training: the loop — adaptive physics-informed loss, early stopping, atomic checkpoints,
``--resume``, determinism for a seed, and DistributedDataParallel under ``torchrun`` (gloo:
training runs on the CPU). The recipe is in :mod:`.train_config`, the flights it trains on come
from :mod:`.train_data`, and the fusion is fitted at the end by :mod:`.calibration`.

The global batch is ``optim.batch_size`` windows; under DDP each of the N processes takes an
equal share of the same globally-drawn windows, so N processes compute the same step as one:
every loss term is a mean over the share, DDP averages the gradients, and the mean of equal-share
means is the global mean. Two details keep that exact (see :class:`TrainStep`): the adaptive
loss weights are initialised from the *global* first batch (all-reduced), not from each rank's
share, and ``L_bias`` (a mean over the windows with a known gyro bias only) is weighted by each
rank's share of those windows (:func:`deal_to_ranks` deals them evenly, so this is rarely needed).

Checkpoints are written at the end of every epoch (``last.pt``, atomically); ``--resume``
continues from the last one, so a killed run redoes at most the epoch it was in and ends with the
same weights as an uninterrupted run. ``optim.max_minutes`` is checked at epoch ends: the run stops
when the next epoch would end past the limit (the limit counts from the start of this invocation).
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import sys
import time
from pathlib import Path

import numpy as np
import torch
from torch import nn

from .. import __version__
from ..config import to_dict
from ..errors import ConfigError, TepinnError
from ..record import atomic_write
from .calibration import calibrate_fusion, calibrate_with, recalibrate
from .checkpoint import CheckpointError, read_checkpoint, save_checkpoint
from .dataset import TokenBank, build_bank, input_statistics, make_batch
from .losses import TERMS, TEPINNLoss, tilt_angle
from .network import TEPINN
from .train_config import CalibrationConfig, DataConfig, OptimConfig, TrainConfig, load_train_config
from .train_data import load_records, resolve_records, split_by_flight

# re-exported: `from tepinn_flight.model.train import X` keeps working for the recipe, data and
# calibration names that moved to their own modules
__all__ = [
    "CalibrationConfig", "DataConfig", "OptimConfig", "TrainConfig", "load_train_config",
    "load_records", "resolve_records", "split_by_flight",
    "calibrate_fusion", "calibrate_with", "recalibrate",
    "lr_factor", "dist_info", "deal_to_ranks", "TrainStep", "validate", "resolve_device", "train",
    "gyro_bias_augmentation", "add_gyro_bias", "scale_augmentation", "scale_sensors",
]  # fmt: skip


def lr_factor(step: int, optim: OptimConfig) -> float:
    """Learning-rate multiplier at a global step: linear warm-up, then optional cosine decay."""
    f = min(1.0, (step + 1) / optim.warmup_steps) if optim.warmup_steps > 0 else 1.0
    if optim.cosine_decay:
        total = max(1, optim.epochs * optim.steps_per_epoch - optim.warmup_steps)
        p = min(1.0, max(0.0, (step - optim.warmup_steps) / total))
        f *= 0.1 + 0.9 * 0.5 * (1.0 + math.cos(math.pi * p))
    return f



# ---------------------------------------------------------------------- distributed


def dist_info() -> tuple[int, int]:
    ws = int(os.environ.get("WORLD_SIZE", "1"))
    rank = int(os.environ.get("RANK", "0"))
    return rank, ws


def deal_to_ranks(ends: np.ndarray, has_bias: np.ndarray, rank: int, world: int) -> np.ndarray:
    """This rank's equal share of the global batch ``ends``.

    Windows with a known gyro bias are dealt round-robin first, so every share holds the same
    number of them (±1 when their count is not a multiple of ``world``): ``L_bias`` is a mean over
    those windows only, and equal counts make the mean of the ranks' means the global mean.
    """
    if world == 1:
        return ends
    order = np.argsort(~has_bias, kind="stable")
    return ends[order][rank::world]


class TrainStep(nn.Module):
    """Model + loss in one module, so DDP synchronises the loss weights too.

    With ``world`` > 1 processes (DDP averages their gradients) two corrections make the step
    equal to one process on the global batch:

    - the adaptive loss weights are initialised from the global batch: :class:`TEPINNLoss` starts
      each weight at ``1/L_i`` of the first batch it sees, which on a rank is only its share.
      Before such a first use, the ranks' ``L_i`` are all-reduced (``L_bias`` weighted by each
      rank's count of bias windows) and every rank starts from the global value;
    - ``L_bias`` is a mean over the windows with a known gyro bias only. When this rank holds
      ``n`` of the global batch's ``N`` such windows and ``n·world ≠ N``, its bias term is scaled by
      ``world·n/N`` (computed as the loss with minus the loss without the bias windows), so the
      ranks' average is ``Σ S_r / N``. :func:`deal_to_ranks` makes this rare (odd ``N`` only).
    """

    def __init__(self, model: TEPINN, loss: TEPINNLoss, world: int = 1):
        super().__init__()
        self.model = model
        self.loss = loss
        self.world = world

    def forward(self, batch: dict, batch_prev: dict | None, n_bias_global: int | None = None):
        m = self.model
        if batch_prev is None:
            cur = m(batch["gyr"], batch["acc"], batch["count"], batch["t_rel"], batch["dt"], batch["mag"], batch["clip"])
            prev = None
        else:
            both = {k: torch.cat([batch[k], batch_prev[k]]) for k in ("gyr", "acc", "count", "t_rel", "dt", "mag", "clip")}
            out = m(both["gyr"], both["acc"], both["count"], both["t_rel"], both["dt"], both["mag"], both["clip"])
            b = len(batch["gyr"])
            cur = {k: v[:b] for k, v in out.items()}
            prev = {k: v[b:] for k, v in out.items()}
        n_bias = int(batch["has_bias"].sum())
        if self.world > 1 and self.loss.config.adaptive and not bool(self.loss.initialised.all()):
            self._init_weights_globally(cur, batch, prev, n_bias)
        total, logs = self.loss(cur, batch, prev)
        if self.world > 1 and n_bias_global and n_bias * self.world != n_bias_global:
            rest, _ = self.loss(cur, {**batch, "has_bias": torch.zeros_like(batch["has_bias"])}, prev)
            total = rest + (self.world * n_bias / n_bias_global) * (total - rest)
        return total, logs

    @torch.no_grad()
    def _init_weights_globally(self, cur: dict, batch: dict, prev: dict | None, n_bias: int) -> None:
        # every rank gets here together: DDP broadcasts the `initialised` buffer before forward
        before = self.loss.initialised.detach().cpu().clone()
        det = {k: v.detach() for k, v in cur.items()}
        _, logs = self.loss(det, batch, None if prev is None else {k: v.detach() for k, v in prev.items()})
        vals = torch.zeros(len(TERMS), dtype=torch.float64)
        cnt = torch.zeros(len(TERMS), dtype=torch.float64)
        for i, name in enumerate(TERMS):
            if not before[i] and f"L_{name}" in logs:
                w = float(n_bias) if name == "bias" else 1.0  # L_bias: a mean over n_bias windows
                vals[i], cnt[i] = w * float(logs[f"L_{name}"]), w
        torch.distributed.all_reduce(vals)
        torch.distributed.all_reduce(cnt)
        new = (cnt > 0) & ~before
        lv = self.loss.log_vars
        lv[new.to(lv.device)] = torch.log((vals[new] / cnt[new]).clamp_min(1e-8)).to(lv)
        self.loss.initialised.copy_(before | new)


def _mean_over_ranks(logs: dict[str, float]) -> dict[str, float]:
    """Average each rank's epoch-mean training logs (a term may be missing on some ranks)."""
    keys = ["tilt_rmse_deg", *(f"L_{t}" for t in TERMS), "L_nll"]
    vals = torch.tensor([logs.get(k, 0.0) for k in keys], dtype=torch.float64)
    cnt = torch.tensor([float(k in logs) for k in keys], dtype=torch.float64)
    torch.distributed.all_reduce(vals)
    torch.distributed.all_reduce(cnt)
    return {**logs, **{k: float(v / c) for k, v, c in zip(keys, vals, cnt) if c > 0}}


# ---------------------------------------------------------------------- evaluation


@torch.no_grad()
def validate(model: TEPINN, bank: TokenBank, ends: np.ndarray, cfg: TrainConfig) -> dict:
    model.eval()
    errs, sig = [], []
    for a in range(0, len(ends), 512):
        dev = model.in_mean.device
        b = _on(make_batch(bank, ends[a : a + 512], cfg.model.window_tokens, cfg.model.correction_layer), dev)
        out = model(b["gyr"], b["acc"], b["count"], b["t_rel"], b["dt"], b["mag"], b["clip"])
        errs.append(tilt_angle(out["q"], b["q_ref"]).double().cpu().numpy())
        if "sigma" in out:
            sig.append(out["sigma"].double().cpu().numpy())
    model.train()
    e = np.concatenate(errs)
    res = {"val_tilt_rmse_deg": float(np.degrees(np.sqrt(np.mean(e**2))))}
    if sig:
        s = np.concatenate(sig)
        res["val_nees"] = float(np.mean(e**2 / s**2))  # 2 when calibrated (2-D tilt error)
        res["val_sigma_corr"] = float(np.corrcoef(s, e)[0, 1]) if len(e) > 2 else float("nan")
    return res


# ---------------------------------------------------------------------- main loop


def resolve_device(name: str = "cpu") -> torch.device:
    """``cpu``, ``cuda`` or ``auto`` (CUDA when available) → the device of this process (under
    torchrun each process takes the GPU of its LOCAL_RANK)."""
    if name not in ("cpu", "cuda", "auto"):
        raise ConfigError(f"unknown device {name!r} (cpu, cuda or auto)")
    if name == "auto":
        name = "cuda" if torch.cuda.is_available() else "cpu"
    if name == "cuda":
        if not torch.cuda.is_available():
            raise ConfigError("--device cuda: this torch build sees no CUDA GPU (use --device cpu)")
        return torch.device("cuda", int(os.environ.get("LOCAL_RANK", "0")) % torch.cuda.device_count())
    return torch.device("cpu")


def train(cfg: TrainConfig, out_dir: str | os.PathLike, data_dirs=(), resume: bool = False,
          config_base: Path = Path("."), progress: bool = True, log=print, device: str = "cpu",
          report_gates: bool = True, model_name: str = "model.pt") -> dict:  # fmt: skip
    """Train and write ``out_dir/{last.pt,best.pt,model.pt,metrics.jsonl,config.json}`` (the final model under
    ``model_name``: the fine-tuning writes its untuned network under another name).

    ``device``: ``cpu`` (bitwise deterministic for a seed, with the same thread count and torch build: 1 and 2 threads differ
    by ~1e-5 in the weights), ``cuda`` or ``auto``. Under DDP on
    GPUs, gradients go through NCCL and the few CPU-side reductions through gloo.

    Refuses a folder that already holds a run (``last.pt``) unless ``resume``. Returns the best
    validation tilt RMSE, the number of epochs done and why the run stopped (``stop_reason``:
    ``epochs``, ``early_stop`` or ``time_limit``) plus the fusion calibration metrics and, with
    ``report_gates`` and real validation files, where the trained estimator's network gates act on
    them (``real_val_network_gates``; a network out of its domain can open one, session 24).
    """
    rank, world = dist_info()
    dev = resolve_device(device)
    out = Path(out_dir)
    if (out / "last.pt").exists() and not resume:
        raise TepinnError(f"{out} already holds a run (last.pt): use --resume to continue it or pick a new folder")
    if cfg.optim.batch_size % world:
        raise ConfigError(f"optim.batch_size {cfg.optim.batch_size} is not divisible by {world} processes")
    own_group = world > 1 and not torch.distributed.is_initialized()
    if own_group:
        if dev.type == "cuda":
            torch.cuda.set_device(dev)
        torch.distributed.init_process_group("cpu:gloo,cuda:nccl" if dev.type == "cuda" else "gloo")
    made = [d for d in (out, *out.parents) if not d.exists()]  # the folders this run makes (removed if it stops first)
    try:
        return _train(cfg, out, data_dirs, resume, config_base, progress, log, rank, world, dev, report_gates,
                      model_name)
    except (TepinnError, KeyboardInterrupt):
        # bad input found, or a stop (Ctrl-C, SIGTERM) before the first checkpoint: leave no half-made run folder
        # behind (one this invocation created and that holds nothing but its config and empty metrics; session 60)
        if rank == 0 and not (out / "last.pt").exists():
            _remove_unstarted_run(out, made)
        raise
    finally:
        if own_group and torch.distributed.is_initialized():
            torch.distributed.destroy_process_group()


def _remove_unstarted_run(out: Path, made: list[Path]) -> None:
    """Remove what :func:`_train` writes before training starts from a run folder that holds nothing else, and the
    folders in ``made`` (this run made them: the run folder and any above it, review60), innermost first, while empty."""
    try:
        names = {p.name for p in out.iterdir()}
    except OSError:
        return
    if names <= {"config.json", "metrics.jsonl"}:
        for n in names:
            (out / n).unlink(missing_ok=True)
        for d in made:
            try:
                d.rmdir()
            except OSError:
                break


#: what a resumed run may change of its recipe: how long it trains (session 60's review: a resume with another seed and
#: learning rate had trained its last epochs on other flights, and config.json then claimed the new recipe made it all)
RESUMABLE_CHANGES = ("optim.epochs", "optim.max_minutes")


def _flat(d, prefix: str = "") -> dict:
    out = {}
    for k, v in (d or {}).items():
        key = f"{prefix}{k}"
        out |= _flat(v, key + ".") if isinstance(v, dict) else {key: v}
    return out


def recipe_differences(before: dict, now: dict, allowed=()) -> list[str]:
    """The keys two recipes (``to_dict`` form, as config.json holds them) differ in, each "key A -> B", leaving out
    ``allowed``."""
    a, b = _flat(json.loads(json.dumps(before))), _flat(json.loads(json.dumps(now)))
    return [f"{k} {a.get(k, '(unset)')!r} -> {b.get(k, '(unset)')!r}" for k in sorted(set(a) | set(b))
            if k not in allowed and a.get(k) != b.get(k)]  # fmt: skip


def run_recipe_differences(out: Path, cfg: TrainConfig, allowed=()) -> list[str]:
    """:func:`recipe_differences` between the recipe the run in ``out`` was started with (its ``config.json``) and
    ``cfg``; none for a folder without one (nothing to hold the recipe against)."""
    try:
        before = json.loads((out / "config.json").read_text())
    except (OSError, ValueError):
        return []
    return recipe_differences(before, to_dict(cfg), allowed)


def check_resume_recipe(out: Path, cfg: TrainConfig) -> None:
    """Refuse, in one line naming the keys, to resume the run in ``out`` with a recipe other than the one its
    ``config.json`` says started it, but for :data:`RESUMABLE_CHANGES`."""
    diff = run_recipe_differences(out, cfg, RESUMABLE_CHANGES)
    if diff:
        shown = "; ".join(diff[:4]) + ("; ..." if len(diff) > 4 else "")
        raise ConfigError(f"cannot resume {out} with another recipe ({shown}): a resume may change only "
                          f"{', '.join(RESUMABLE_CHANGES)}; train the new recipe into a new folder")  # fmt: skip


def epochs_within(optim, done: int, epoch_s: float, left_s: float) -> int:
    """How many epochs a run with ``optim``'s time limit ends after, ``done`` done, each ``epoch_s`` long, ``left_s``
    left of the limit: the loop's rule — it stops when the next epoch would end past the limit — run forward."""
    more = int(max(0.0, left_s) // epoch_s) if epoch_s > 0 else optim.epochs
    return min(optim.epochs, done + more)


def gyro_bias_augmentation(rng: np.random.Generator, n: int, sigma_deg_s: float, prob: float) -> np.ndarray:
    """(n, 3) extra gyro biases in rad/s: N(0, σ) per axis for a ``prob`` share of windows, else 0."""
    b = rng.normal(size=(n, 3)) * np.radians(sigma_deg_s)
    return b * (rng.random(n) < prob)[:, None]


def add_gyro_bias(batch: dict, bias_rad_s: np.ndarray) -> dict:
    """The batch as an IMU with these extra constant gyro biases would have recorded it (token
    means shift by exactly the bias); known bias targets shift with it."""
    b = torch.as_tensor(bias_rad_s, dtype=batch["gyr"].dtype)
    known = batch["has_bias"][:, None].to(b.dtype)
    return {**batch, "gyr": batch["gyr"] + b[:, None, :], "bias_true": batch["bias_true"] + known * b}


def scale_augmentation(rng: np.random.Generator, n: int, acc_common: float, per_axis: float, prob: float):
    """(n, 3) gyro and (n, 3) accelerometer scale factors: for a ``prob`` share of windows a common
    accelerometer factor U(1 ± acc_common) times per-axis factors U(1 ± per_axis) (gyro: per-axis
    only), else 1."""
    on = (rng.random(n) < prob)[:, None]
    sg = 1.0 + per_axis * rng.uniform(-1, 1, (n, 3))
    sa = (1.0 + acc_common * rng.uniform(-1, 1, (n, 1))) * (1.0 + per_axis * rng.uniform(-1, 1, (n, 3)))
    return np.where(on, sg, 1.0), np.where(on, sa, 1.0)


def scale_sensors(batch: dict, gyr_scale: np.ndarray, acc_scale: np.ndarray) -> dict:
    """The batch as an IMU with these per-axis scale factors would have recorded it (token means are
    linear in the samples, so they scale exactly; the reference attitude and bias targets stay)."""
    g = torch.as_tensor(gyr_scale, dtype=batch["gyr"].dtype)[:, None, :]
    a = torch.as_tensor(acc_scale, dtype=batch["acc"].dtype)[:, None, :]
    return {**batch, "gyr": batch["gyr"] * g, "acc": batch["acc"] * a}


def _on(batch: dict, dev: torch.device) -> dict:
    return batch if dev.type == "cpu" else {k: v.to(dev, non_blocking=True) for k, v in batch.items()}


def _train(cfg: TrainConfig, out: Path, data_dirs, resume: bool, config_base: Path, progress: bool, log,
           rank: int, world: int, dev: torch.device = torch.device("cpu"), report_gates: bool = True,
           model_name: str = "model.pt") -> dict:  # fmt: skip
    out.mkdir(parents=True, exist_ok=True)
    torch.manual_seed(cfg.seed)
    rng = np.random.default_rng(cfg.seed)

    if world > 1 and rank != 0:
        torch.distributed.barrier()  # rank 0 flies the campaign (if any) first
    records = load_records(cfg, data_dirs, config_base, out, progress and rank == 0)
    if world > 1 and rank == 0:
        torch.distributed.barrier()
    tr_idx, va_idx = split_by_flight(len(records), cfg.data.val_fraction, cfg.seed)
    train_recs = [records[i] for i in tr_idx]
    val_recs = [records[i] for i in va_idx] or train_recs[:1]
    pair = cfg.loss.gyro_pair_tokens
    try:
        bank = build_bank(train_recs, cfg.model, cfg.data.rate_factors, pair)
    except ValueError as exc:
        raise ConfigError(f"training flights: {exc}") from None
    try:
        vbank = build_bank(val_recs, cfg.model, (1,), pair)
    except ValueError as exc:
        raise ConfigError(f"validation flights: {exc}") from None
    val_ends = vbank.ends
    if len(val_ends) > cfg.data.max_val_windows:
        val_ends = np.sort(np.random.default_rng(cfg.seed + 1).choice(val_ends, cfg.data.max_val_windows, replace=False))

    init_ck = None
    if cfg.init:  # fine-tuning: the init checkpoint's weights and input normalisation
        from .checkpoint import default_model_path, load_model

        model, _, init_ck = load_model(default_model_path() if cfg.init == "default" else cfg.init)
        model.train()
        if model.config != cfg.model:
            diff = recipe_differences(dataclasses.asdict(model.config), dataclasses.asdict(cfg.model))
            raise ConfigError(f"init: the checkpoint's model config differs from the recipe's [model] ("
                              f"{'; '.join(f'model.{d}' for d in diff[:4])}: checkpoint -> recipe; fine-tuning keeps "
                              "the architecture; leave [model] out or copy the checkpoint's)")  # fmt: skip
    else:
        model = TEPINN(cfg.model)
        mean, std = input_statistics(model.features, bank, cfg.model, seed=cfg.seed)
        model.set_normalization(mean, std)
    model.to(dev)
    loss_fn = TEPINNLoss(cfg.loss, model.body).to(dev)
    step_mod = TrainStep(model, loss_fn, world)
    groups = [
        {"params": model.network_parameters(), "lr": cfg.optim.lr, "weight_decay": cfg.optim.weight_decay},
        {"params": model.physics_parameters() + list(loss_fn.parameters()), "lr": cfg.optim.lr_physics, "weight_decay": 0.0},
    ]
    opt = torch.optim.AdamW(groups)
    base_lrs = [g["lr"] for g in groups]  # the schedule scales these (resume-safe: a function of the step)
    start_epoch, best_val, stale = 0, float("inf"), 0
    history: list[dict] = []
    if resume and (out / "last.pt").exists():
        check_resume_recipe(out, cfg)
        ck = read_checkpoint(out / "last.pt")
        try:
            model.load_state_dict(ck["state_dict"])
            loss_fn.load_state_dict(ck["loss_state"])
            opt.load_state_dict(ck["optimizer"])
            start_epoch, best_val, stale = ck["epoch"], ck["best_val"], ck["stale"]
            rng = np.random.default_rng(cfg.seed)
            rng.bit_generator.state = json.loads(ck["rng"])
            torch.set_rng_state(ck["torch_rng"])
            history = json.loads(ck.get("history", "[]"))
        except (KeyError, RuntimeError, ValueError, TypeError) as exc:
            first = (str(exc).strip().splitlines() or [type(exc).__name__])[0][:200]
            raise CheckpointError(f"cannot resume: checkpoint does not match this recipe ({first})", out / "last.pt") from None
        if rank == 0:
            log(f"resumed from epoch {start_epoch} (best validation tilt RMSE {best_val:.3f}°)")
    elif resume and rank == 0:
        log(f"nothing to resume in {out} (no last.pt): starting a new run")
    ddp = step_mod
    if world > 1:
        ddp = torch.nn.parallel.DistributedDataParallel(
            step_mod, device_ids=[dev.index] if dev.type == "cuda" else None, find_unused_parameters=True
        )

    summary = {
        "train_flights": [r.meta.get("source_file") for r in train_recs],
        "val_flights": [r.meta.get("source_file") for r in val_recs],
        "train_windows": int(len(bank)), "val_windows": int(len(val_ends)),
        "imu_rates_hz": sorted({round(float(r.meta.get("imu_rate_hz") or 0), 1) for r in records}),
        "rate_factors": list(cfg.data.rate_factors), "seed": cfg.seed, "world_size": world,
    }  # fmt: skip
    if rank == 0:
        atomic_write(out / "config.json", lambda tmp: Path(tmp).write_text(json.dumps(to_dict(cfg), indent=2)))
        # epochs after the checkpoint (a killed run) are redone: drop their lines
        lines = "".join(json.dumps(r) + "\n" for r in history)
        atomic_write(out / "metrics.jsonl", lambda tmp: Path(tmp).write_text(lines))
        held = f"validating on {len(val_recs)}" if va_idx else "no flight held out: validating on the training"
        log(f"training on {len(train_recs)} flights ({len(bank)} windows), {held} "
            f"flights ({len(val_ends)} windows), {world} process(es)")  # fmt: skip

    t_start = time.monotonic()
    bar = None
    if progress and rank == 0:
        from tqdm import tqdm

        bar = tqdm(total=cfg.optim.epochs * cfg.optim.steps_per_epoch, initial=start_epoch * cfg.optim.steps_per_epoch,
                   unit="step", file=sys.stderr, dynamic_ncols=True)  # fmt: skip
    B = cfg.optim.batch_size
    stop_reason = "epochs"
    if start_epoch and stale >= cfg.optim.early_stop_patience:  # a resumed run that had stopped early: as it ended
        # (review60: it trained one epoch more and added its line)
        stop_reason, start_epoch = "early_stop", cfg.optim.epochs
    for epoch in range(start_epoch, cfg.optim.epochs):
        t_epoch = time.monotonic()
        logs_acc: dict[str, float] = {}
        for step in range(cfg.optim.steps_per_epoch):
            use_pair = cfg.model.physics and pair > 0
            pool = bank.ends[bank.prev_ok] if use_pair and bank.prev_ok.any() else bank.ends
            ends = rng.choice(pool, size=B, replace=len(pool) < B)
            has_bias = np.all(np.isfinite(bank.bias[ends]), axis=1)
            pos = deal_to_ranks(np.arange(B), has_bias, rank, world)  # this rank's share
            mine = ends[pos]
            batch = make_batch(bank, mine, cfg.model.window_tokens, cfg.model.correction_layer)
            prev = make_batch(bank, mine - pair, cfg.model.window_tokens, cfg.model.correction_layer) if use_pair and bank.prev_ok.any() else None
            if cfg.data.acc_scale_aug > 0 or cfg.data.axis_scale_aug > 0:
                sg, sa = scale_augmentation(rng, B, cfg.data.acc_scale_aug, cfg.data.axis_scale_aug, cfg.data.scale_aug_prob)
                sg, sa = sg[pos], sa[pos]
                batch, prev = scale_sensors(batch, sg, sa), (None if prev is None else scale_sensors(prev, sg, sa))
            if cfg.data.gyro_bias_aug_deg_s > 0:
                aug = gyro_bias_augmentation(rng, B, cfg.data.gyro_bias_aug_deg_s, cfg.data.gyro_bias_aug_prob)[pos]
                batch, prev = add_gyro_bias(batch, aug), (None if prev is None else add_gyro_bias(prev, aug))
            batch, prev = _on(batch, dev), (None if prev is None else _on(prev, dev))
            total, logs = ddp(batch, prev, int(has_bias.sum()))
            opt.zero_grad(set_to_none=True)
            total.backward()
            torch.nn.utils.clip_grad_norm_(step_mod.parameters(), cfg.optim.grad_clip)
            f = lr_factor(epoch * cfg.optim.steps_per_epoch + step, cfg.optim)
            for g, lr0 in zip(opt.param_groups, base_lrs):
                g["lr"] = lr0 * f
            opt.step()
            for k, v in logs.items():
                logs_acc[k] = logs_acc.get(k, 0.0) + float(v) / cfg.optim.steps_per_epoch
            if bar:
                bar.update(1)
                if step % 10 == 0:
                    bar.set_postfix(loss=f"{float(total.detach()):.3g}", tilt=f"{float(logs['tilt_rmse_deg']):.2f}°")
        if world > 1:
            logs_acc = _mean_over_ranks(logs_acc)
        val = validate(model, vbank, val_ends, cfg)
        elapsed = time.monotonic() - t_start
        rec = {"epoch": epoch + 1, **{k: round(v, 6) for k, v in logs_acc.items()}, **val,
               "loss_weights": [round(float(x), 4) for x in loss_fn.log_vars.detach().cpu()], "elapsed_s": round(elapsed, 1),
               **({"device": str(dev)} if dev.type != "cpu" else {})}  # fmt: skip
        history.append(rec)
        improved = val["val_tilt_rmse_deg"] < best_val - 1e-6
        if improved:
            best_val, stale = val["val_tilt_rmse_deg"], 0
        else:
            stale += 1
        if rank == 0:
            common = {"training": summary, "metrics": rec, "tepinn_flight_version": __version__,
                      "loss_config": dataclasses.asdict(cfg.loss)}  # fmt: skip
            if improved:
                save_checkpoint(out / "best.pt", model, cfg.fusion, **common)
            save_checkpoint(
                out / "last.pt", model, cfg.fusion, **common, epoch=epoch + 1, best_val=best_val, stale=stale,
                optimizer=opt.state_dict(), loss_state=loss_fn.state_dict(),
                rng=json.dumps(rng.bit_generator.state), torch_rng=torch.get_rng_state(),
                history=json.dumps(history),
            )  # fmt: skip
            with open(out / "metrics.jsonl", "a") as f:  # after last.pt: never an epoch that is not saved
                f.write(json.dumps(rec) + "\n")
            msg = f"epoch {epoch + 1}: train tilt {logs_acc.get('tilt_rmse_deg', float('nan')):.2f}°, val tilt {val['val_tilt_rmse_deg']:.2f}°"
            if bar:  # through the caller's log, where it writes (ablate: stderr, beside its table on stdout; review60)
                with bar.external_write_mode():
                    log(msg)
            else:
                log(msg)
        if stale >= cfg.optim.early_stop_patience:  # the same on every rank (same weights, same data)
            if rank == 0:
                log(f"early stop: no validation improvement for {stale} epochs")
            stop_reason = "early_stop"
            break
        # time limit: stop when the next epoch (as long as this one) would end past it; rank 0's
        # clock decides for everyone, or the ranks could part ways and hang in an all-reduce
        next_end = elapsed + (time.monotonic() - t_epoch)
        out_of_time = bool(cfg.optim.max_minutes) and next_end > 60 * cfg.optim.max_minutes
        if world > 1:
            flag = torch.tensor([int(out_of_time)])
            torch.distributed.broadcast(flag, 0)
            out_of_time = bool(flag.item())
        if out_of_time and epoch + 1 < cfg.optim.epochs:
            if rank == 0:
                # the budget is wall time: a slower machine trains fewer epochs within it (session 33: 21-37 of the
                # default recipe's 80 on a machine ~2.5x slower than the shipped run's 73)
                log(f"stopping at the time limit ({cfg.optim.max_minutes} min) after {epoch + 1} of {cfg.optim.epochs} "
                    "epochs (a slower machine trains fewer within it: to train longer, raise the limit — --set "
                    "optim.max_minutes=N for a recipe, --minutes N when fine-tuning)")
            stop_reason = "time_limit"
            break
        if bar and cfg.optim.max_minutes:  # the bar's end where the time limit will stop the run (session 60)
            bar.total = cfg.optim.steps_per_epoch * epochs_within(cfg.optim, epoch + 1, next_end - elapsed,
                                                                   60 * cfg.optim.max_minutes - elapsed)
            bar.refresh()
    if bar:
        if stop_reason == "early_stop":  # the bar ends where the run did (review60: at 39 %)
            bar.total = bar.n
            bar.refresh()
        bar.close()
    result = {"best_val_tilt_rmse_deg": best_val, "epochs": len(history), "stop_reason": stop_reason}
    if rank == 0:
        from .checkpoint import load_model

        best_model, _, ck = load_model(out / "best.pt") if (out / "best.pt").exists() else (model.cpu().eval(), None, {})
        anchor = None
        if init_ck is not None:  # fine-tuning keeps the init's estimator settings (finetune.py tunes them)
            from .checkpoint import anchor_config_from, fusion_config_from
            
            fusion, fus_metrics = fusion_config_from(init_ck.get("fusion_config")), {}
            anchor = anchor_config_from(init_ck)
        else:
            fusion, fus_metrics = calibrate_with(cfg, best_model, val_recs, train_recs)
            anchor = cfg.anchor if cfg.anchor.enabled else None
        final_metrics = {**(ck.get("metrics") or {}), **fus_metrics}
        save_checkpoint(out / model_name, best_model, fusion, anchor, training=summary, metrics=final_metrics,
                        loss_config=dataclasses.asdict(cfg.loss),
                        tepinn_flight_version=__version__)  # fmt: skip
        result.update(fus_metrics)
        fused = f", fused {fus_metrics['fusion_val_tilt_rmse_mean_deg']:.3f}° (mean over validation flights)" if fus_metrics else ""
        log(f"best validation tilt RMSE {best_val:.3f}° (window){fused}; "
            + (f"model: {out / model_name}" if init_ck is None else "its filter's settings and σ tuned next"))
        from ..record import SIMULATED_KINDS

        real_val = [r for r in val_recs if r.meta.get("source_kind") not in SIMULATED_KINDS]
        if report_gates and real_val and anchor is not None:
            from .estimate import estimate_anchored, gates_acted

            m1, a1, _ = load_model(out / model_name)
            lines = {}
            for i, r in enumerate(real_val):
                try:
                    lines[str(r.meta.get("source_file", i))] = estimate_anchored(m1, r, a1).attrs.get("network_gates", "")
                except TepinnError as exc:  # the model is written: a file it cannot run on is said, not fatal
                    lines[str(r.meta.get("source_file", i))] = f"not run ({exc})"
            result["real_val_network_gates"] = lines
            log(f"on the real validation files: {gates_acted(lines)}")
    if world > 1:
        torch.distributed.barrier()
    return result
