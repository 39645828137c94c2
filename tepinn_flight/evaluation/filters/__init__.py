"""Baseline attitude filters (numpy, causal, batch API; see :mod:`.common`)."""

from .complementary import Complementary, ComplementaryParams
from .ekf import Ekf, EkfParams, tune
from .madgwick import Madgwick, MadgwickParams

FILTERS = {"complementary": Complementary, "madgwick": Madgwick, "ekf": Ekf}

__all__ = ["Complementary", "ComplementaryParams", "Ekf", "EkfParams", "tune", "Madgwick", "MadgwickParams", "FILTERS"]
