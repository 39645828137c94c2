"""Training recipes: the strict TOML config of ``tepinn-flight train`` (``[data]``, ``[optim]``,
``[calibration]``, and the model, loss and fusion sections) and its loading. Defaults are the
recipe of the shipped model (``train/default.toml``) except the data's paths (``records``,
``campaign``, ``optional_records``: a recipe names its own data)."""

from __future__ import annotations

import os
from dataclasses import dataclass, field

from ..config import check_range, load_config
from ..errors import ConfigError
from .config import ModelConfig
from .anchor import AnchorConfig
from .fusion import FusionConfig
from .losses import LossConfig


@dataclass(frozen=True)
class DataConfig:
    records: tuple[str, ...] = ()  # record files, folders or globs (relative to the config file)
    # like `records`, but used only where present (e.g. the real data in ../shared): a missing
    # path is skipped with a note. Files that are not records (*.parquet) are ingested as logs.
    optional_records: tuple[str, ...] = ()
    campaign: str | None = None  # a simulation campaign TOML, flown into RUN_DIR/data (resumable)
    campaign_workers: int = 0  # processes for the campaign (0: one per CPU)
    synthetic_flights: int = 0  # closed-form synthetic flights (tests, tiny runs)
    synthetic_duration_s: float = 20.0
    val_fraction: float = 0.15  # share of flights held out for validation (at least one)
    rate_factors: tuple[int, ...] = (1, 4, 16)  # IMU decimation factors: rate augmentation
    max_val_windows: int = 2048
    # sensor-error augmentation: with this probability a training window (and its L_gyro partner)
    # gets an extra constant gyro bias drawn per axis from N(0, σ) — an uncalibrated IMU's turn-on
    # bias — added to the input and, where the true bias is known, to the bias target (0: off)
    gyro_bias_aug_deg_s: float = 5.0
    gyro_bias_aug_prob: float = 0.3
    # sensor-scale augmentation: with probability ``scale_aug_prob`` a window (and its partner) is
    # read by an IMU whose accelerometer has a common scale error U(1 ± acc_scale_aug) (a real board
    # reads |a| ≈ 7.8 m/s² at rest: −20 %) and whose gyro and accelerometer axes have their own
    # scale errors U(1 ± axis_scale_aug) (0: off; session 7 retrained with 0.2 / 0.03 together with a
    # 50 Hz rate factor and 6 BROAD trials held out: held-out simulations 6.08° -> 6.82°, not shipped)
    acc_scale_aug: float = 0.0
    axis_scale_aug: float = 0.0
    scale_aug_prob: float = 0.5
    # a split file (TOML, relative to the config file) whose ``[heldout]`` lists name real files that
    # are never trained on: any record or log with such a file name is left out, with a note
    heldout_split: str = ""

    def __post_init__(self):
        check_range("campaign_workers", self.campaign_workers, 0, 4096)
        check_range("synthetic_flights", self.synthetic_flights, 0, 100000)
        check_range("synthetic_duration_s", self.synthetic_duration_s, 0, 1e6, lo_open=True)
        check_range("val_fraction", self.val_fraction, 0, 1, hi_open=True)
        if not self.rate_factors:
            raise ConfigError("'rate_factors' must list at least one factor (1: the log's own rate)")
        for i, f in enumerate(self.rate_factors):
            check_range(f"rate_factors[{i}]", f, 1, 10000)
        check_range("max_val_windows", self.max_val_windows, 1, 10**9)
        check_range("gyro_bias_aug_deg_s", self.gyro_bias_aug_deg_s, 0, 1000)
        check_range("gyro_bias_aug_prob", self.gyro_bias_aug_prob, 0, 1)
        check_range("acc_scale_aug", self.acc_scale_aug, 0, 0.5)
        check_range("axis_scale_aug", self.axis_scale_aug, 0, 0.5)
        check_range("scale_aug_prob", self.scale_aug_prob, 0, 1)


#: the largest batch a recipe may ask for (windows): ~0.4 GB of tensors on top of the model's
MAX_BATCH = 16384


@dataclass(frozen=True)
class OptimConfig:
    batch_size: int = 64  # global batch (windows)
    epochs: int = 80
    steps_per_epoch: int = 100
    lr: float = 1e-3  # network weights
    lr_physics: float = 3e-4  # sensor model, inertia and loss weights
    weight_decay: float = 1e-4  # network weights only
    grad_clip: float = 1.0
    early_stop_patience: int = 12  # epochs without validation improvement
    max_minutes: float = 16.0  # stop after this wall time (0: no limit)
    warmup_steps: int = 400  # linear learning-rate warm-up (post-LayerNorm transformers need it)
    cosine_decay: bool = True  # cosine decay to 10 % of the learning rate at the last epoch

    def __post_init__(self):
        # (a window's tensors take ~24 kB: 10^6 had taken 24 GB and the OOM killer; review60)
        check_range("batch_size", self.batch_size, 1, MAX_BATCH)
        check_range("epochs", self.epochs, 1, 10**6)
        check_range("steps_per_epoch", self.steps_per_epoch, 1, 10**7)
        check_range("lr", self.lr, 0, 10)  # 0: frozen (tests use it)
        check_range("lr_physics", self.lr_physics, 0, 10)
        check_range("weight_decay", self.weight_decay, 0, 10)
        check_range("grad_clip", self.grad_clip, 0, None, lo_open=True)
        check_range("early_stop_patience", self.early_stop_patience, 1, 10**6)
        check_range("max_minutes", self.max_minutes, 0, None)  # 0: no limit
        check_range("warmup_steps", self.warmup_steps, 0, 10**9)



@dataclass(frozen=True)
class CalibrationConfig:
    """The fusion calibration at the end of training (:func:`calibrate_fusion`)."""

    max_flights: int = 8  # validation flights it runs on (spread over the split)
    bias_state_sweeps: int = 1  # coordinate-search sweeps over the bias-state settings (0: low-pass only)
    # bias feedback dead zones tried (°/s; empty: no feedback), refreshed every this many windows
    feedback_deadzones_deg_s: tuple[float, ...] = (2.0, 4.0)
    feedback_windows: int = 25

    def __post_init__(self):
        check_range("max_flights", self.max_flights, 1, 100000)
        check_range("bias_state_sweeps", self.bias_state_sweeps, 0, 1000)
        for i, d in enumerate(self.feedback_deadzones_deg_s):
            check_range(f"feedback_deadzones_deg_s[{i}]", d, 0, 1000)
        check_range("feedback_windows", self.feedback_windows, 1, 10**6)


@dataclass(frozen=True)
class TrainConfig:
    seed: int = 0
    # start from this checkpoint's weights and model config ("default": the shipped model) instead of
    # a fresh network; its estimator settings (anchor/fusion) are carried to model.pt, not recalibrated
    init: str = ""
    model: ModelConfig = field(default_factory=ModelConfig)
    loss: LossConfig = field(default_factory=LossConfig)
    data: DataConfig = field(default_factory=DataConfig)
    optim: OptimConfig = field(default_factory=OptimConfig)
    fusion: FusionConfig = field(default_factory=FusionConfig.uncalibrated)  # where calibration starts
    calibration: CalibrationConfig = field(default_factory=CalibrationConfig)
    # the estimator model.pt runs: the filter-anchored VQF with these settings (its pull target, the
    # older fusion, is the one calibrated above); enabled = false: the older fusion alone
    anchor: AnchorConfig = field(default_factory=AnchorConfig)

    def __post_init__(self):
        check_range("seed", self.seed, 0, 2**31 - 1)  # numpy's seeds are non-negative
        if self.loss.gyro_pair_tokens >= self.model.window_tokens:
            raise ConfigError(f"loss: 'gyro_pair_tokens' must be < model.window_tokens ({self.model.window_tokens}), "
                              f"got {self.loss.gyro_pair_tokens}")  # fmt: skip
        # the fusion's numbers: ranges for a training recipe (FusionConfig checks them too)
        f = self.fusion
        for name in ("process_noise_rad2_s", "process_noise_rate_rad", "clip_inflation_rad", "clip_rate_gain",
                     "adaptive_nis", "bias_sigma_rad_s", "bias_rw_rad_s_sqrt_s", "bias_init_sigma_rad_s",
                     "clip_hold_s", "bias_feedback_deadzone_rad_s"):  # fmt: skip
            _fusion_range(name, getattr(f, name), 0, None)
        for name in ("bias_time_constant_s", "sigma_scale", "output_sigma_scale"):
            _fusion_range(name, getattr(f, name), 0, None, lo_open=True)
        _fusion_range("bias_feedback_windows", f.bias_feedback_windows, 0, 10**6)


def _fusion_range(name: str, value, lo, hi, lo_open: bool = False) -> None:
    try:
        check_range(name, value, lo, hi, lo_open=lo_open)
    except ConfigError as exc:
        raise ConfigError(f"fusion: {exc.reason}") from None


def load_train_config(path: str | os.PathLike, overrides=()) -> TrainConfig:
    return load_config(TrainConfig, path, overrides)
