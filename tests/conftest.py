"""Shared fixtures: where the real logs live, and skips with a reason when they are absent."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
SHARED = Path(os.environ.get("TEPINN_SHARED", REPO.parent / "shared"))
REAL_LOGS = SHARED / "real-logs"
BROAD = SHARED / "broad"


def real_log(name: str) -> Path:
    """Path of a shared real log, or skip the test with a clear reason."""
    p = REAL_LOGS / name
    if not p.exists():
        pytest.skip(f"real log {name} not available (expected in {REAL_LOGS}; set TEPINN_SHARED)")
    return p


def broad_trial(pattern: str = "broad_01_*.hdf5") -> Path:
    hits = sorted(BROAD.glob(pattern))
    if not hits:
        pytest.skip(f"BROAD trial {pattern} not available (expected in {BROAD}; set TEPINN_SHARED)")
    return hits[0]
