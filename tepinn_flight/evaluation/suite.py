"""The standard set of estimators the harness compares, and its TOML configuration.

``[madgwick]``, ``[complementary]`` and ``[ekf]`` tables hold the filters' parameters (unknown
keys are refused); ``peers`` lists the published peers to run.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from .estimators import FilterEstimator
from .filters.complementary import Complementary, ComplementaryParams
from .filters.ekf import Ekf, EkfParams
from .filters.madgwick import Madgwick, MadgwickParams
from .peers import make_peer


@dataclass(frozen=True)
class SuiteConfig:
    madgwick: MadgwickParams = field(default_factory=MadgwickParams)
    complementary: ComplementaryParams = field(default_factory=ComplementaryParams)
    ekf: EkfParams = field(default_factory=EkfParams)
    peers: tuple[str, ...] = ("vqf", "offline-vqf", "riann", "fusion")


def load_suite_config(path=None, overrides=()) -> SuiteConfig:
    from ..config import apply_overrides, load_config

    if path is None:
        return apply_overrides(SuiteConfig(), list(overrides)) if overrides else SuiteConfig()
    return load_config(SuiteConfig, path, list(overrides))


def baseline_estimators(cfg: SuiteConfig | None = None, with_mag: bool = False) -> list:
    """The project's own filters: complementary ("analytical"), Madgwick, the bias-estimating EKF."""
    cfg = cfg or SuiteConfig()
    out = [
        FilterEstimator(Complementary(cfg.complementary), kind="analytical"),
        FilterEstimator(Madgwick(cfg.madgwick)),
        FilterEstimator(Ekf(cfg.ekf)),
    ]
    if with_mag:
        out += [FilterEstimator(Complementary(cfg.complementary), use_mag=True, kind="analytical"),
                FilterEstimator(Madgwick(cfg.madgwick), use_mag=True)]  # fmt: skip
    return out


def peer_estimators(cfg: SuiteConfig | None = None, with_mag: bool = False, notes: list | None = None) -> list:
    cfg = cfg or SuiteConfig()
    names = list(cfg.peers)
    if with_mag:
        names += [n + "-9d" for n in cfg.peers if n != "riann"]
    from ..errors import ConfigError
    from .peers import PEERS

    unknown = [n for n in names if n not in PEERS]
    if unknown:
        raise ConfigError(f"unknown peer(s) {unknown}; known: {', '.join(PEERS)}")
    return [p for p in (make_peer(n, notes) for n in names) if p is not None]
