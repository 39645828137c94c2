"""Gaps in a record's IMU stream: when a step is a break, and which breaks are bridged.

A step longer than :data:`GAP_PERIODS` nominal periods is a gap; ``ingest`` starts a new record
segment there (and at a reboot or a time reversal). Short gaps — logging dropouts, typically 10–70 ms
in PX4 and ArduPilot logs — are **bridged** by every estimator instead of restarting it:
:func:`bridge_gaps` merges the two segments and fills the gap with samples at the nominal period
whose gyro, accelerometer, magnetometer (and GNSS velocity, where the record has it) are linearly
interpolated between the samples on either side, so filters keep propagating through it (a restart
loses the attitude, re-converges and costs every estimator its warm-up). The filled samples carry no reference (never scored), ``clipped``
(and ``gyr_clipped``) False and ``valid`` False. Gaps longer than :data:`MAX_BRIDGED_GAP_S`, reboots and time reversals
still restart.

The live estimator (:mod:`tepinn_flight.model.streaming`) bridges the same gaps with the same
samples (:func:`filler_times`, :func:`interpolate_rows`).

**A rise of the sample rate** starts a new segment too (session 53). The estimators take a segment's sample
period from its first :data:`PERIOD_STEPS` steps (VQF's time constants, the gyro's step weights), so a stream that
turns faster inside a segment — the bridge's own request for a faster IMU, granted mid-flight — was run on a period
several times too long (the live tilt 80–157° off). Where more than half of the last :data:`PERIOD_STEPS` steps are
shorter than the segment's period / :data:`RATE_RISE`, the sample there starts a new segment
(:func:`rate_rise_cuts` offline, in :func:`bridge_gaps`; :class:`RateRise` live: the same sample). A falling rate is
a run of gaps, bridged or restarted as above.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np
import pandas as pd

from .record import ACC_BIAS_COLS, ACC_COLS, GNSS_VEL_COLS, GYR_BIAS_COLS, GYR_COLS, MAG_COLS, QREF_COLS, FlightRecord

#: A step longer than this many nominal sample periods is a gap (a segment break at ingest).
GAP_PERIODS = 2.5

#: Gaps up to this long (seconds) are bridged by propagating through them, not by a restart: at
#: 100 ms the gyro integrated over a held/interpolated rate errs by well under a degree for rates
#: a vehicle changes within a tenth of a second, while a restart loses far more (the attitude, the
#: gyro-bias estimate and every estimator's warm-up). Longer gaps restart.
MAX_BRIDGED_GAP_S = 0.1

#: a segment's sample period is the median of its first this-many steps (the anchored filter, offline and live)
PERIOD_STEPS = 51
#: ... and a new segment starts where most of the last PERIOD_STEPS steps are shorter than that period / RATE_RISE
RATE_RISE = 1.5
_RISE_COUNT = PERIOD_STEPS // 2 + 1  # "most": the median of PERIOD_STEPS (odd) steps is below iff this many are

_INTERPOLATED = [*GYR_COLS, *ACC_COLS, *MAG_COLS, *GYR_BIAS_COLS, *ACC_BIAS_COLS, *GNSS_VEL_COLS]


@dataclass(frozen=True)
class Bridged:
    """A record with its short gaps filled: ``record`` (segments merged across the bridged gaps),
    ``rows`` (row in ``record`` of each original row), ``gaps`` bridged and ``filled`` samples added."""

    record: FlightRecord
    rows: np.ndarray
    gaps: int
    filled: int

    def original(self, frame: pd.DataFrame) -> pd.DataFrame:
        """The rows of a per-sample table of ``record`` that belong to the original samples."""
        if self.filled == 0:
            return frame
        return frame.iloc[self.rows].reset_index(drop=True)


#: a step inside a segment longer than this many nominal periods (and at most GAP_PERIODS) is a lost sample
LOST_STEP_PERIODS = 1.5


def inner_steps(rec: FlightRecord) -> np.ndarray:
    """The steps between consecutive samples inside segments, in nominal periods (empty where unknown)."""
    period = record_period_s(rec)
    if not (np.isfinite(period) and period > 0) or len(rec) < 2:
        return np.zeros(0)
    return np.diff(rec.t_s)[np.diff(rec.segment) == 0] / period


def lost_steps(steps: np.ndarray) -> int:
    """How many of :func:`inner_steps` are about two periods: a sample lost between them (a logger or a radio
    dropping IMU rows; the anchored estimator integrates the gyro over each step's time, VQF over one period)."""
    return int(np.sum((steps > LOST_STEP_PERIODS) & (steps <= GAP_PERIODS)))


def logged_timing(rng: np.random.Generator, t_s: np.ndarray, period_s: float, lost_fraction: float,
                  jitter_s: float) -> tuple[np.ndarray, np.ndarray]:
    """What a log that loses samples and jitters its stamps keeps of samples at times ``t_s`` → (the rows kept,
    their stamps): ``lost_fraction`` of them lost one at a time (never the first or last 5, never two in a row: a
    longer gap is a new segment), the stamps off by N(0, ``jitter_s``²) clipped at ±0.45 period (kept in order), the
    first one's on time (a record's clock starts at its first stamp: its offset would shift every other one).
    ``simulate``'s ``lost_fraction`` / ``stamp_jitter_s`` and ``benchmarks/robustness.py``'s probes.

    Each sample is lost with probability p where the one before was kept, and kept where it was lost: a share
    p / (1 + p) lost, ``lost_fraction`` for p = f / (1 − f) (review60: each drawn loss that followed another drawn one
    had been dropped, a share f (1 − f) — 0.45 asked, 0.25 lost; session 29's 2 % probes lost 1.96 %)."""
    n = len(t_s)
    f = float(lost_fraction)
    drawn = rng.random(n) < (f / (1.0 - f) if f < 1.0 else 1.0)
    # in a run of drawn losses every second one is kept: the one after a loss is never lost
    start = drawn & ~np.concatenate(([False], drawn[:-1]))
    first = np.maximum.accumulate(np.where(start, np.arange(n), 0))
    lost = drawn & ((np.arange(n) - first) % 2 == 0)
    lost[:5] = lost[max(0, n - 5) :] = False
    half = 0.45 * period_s
    jitter = np.clip(rng.normal(0.0, jitter_s, n), -half, half) if jitter_s > 0 else np.zeros(n)
    if n:
        jitter[0] = 0.0
    keep = ~lost
    return keep, (np.asarray(t_s, np.float64) + jitter)[keep]


def is_bridgeable(dt_s: float, period_s: float, max_gap_s: float = MAX_BRIDGED_GAP_S) -> bool:
    """A forward step that is a gap (> ``GAP_PERIODS`` periods) and no longer than ``max_gap_s``."""
    return bool(np.isfinite(period_s) and period_s > 0 and GAP_PERIODS * period_s < dt_s <= max_gap_s)


def filler_times(t_a: float, t_b: float, period_s: float) -> np.ndarray:
    """Times of the samples that fill the gap between samples at ``t_a`` and ``t_b``: equally spaced,
    as close to the nominal period as a whole number of steps allows (both ends excluded)."""
    n_steps = max(1, int(round((t_b - t_a) / period_s)))
    return t_a + (t_b - t_a) * np.arange(1, n_steps) / n_steps


def interpolate_rows(t_a: float, row_a: np.ndarray, t_b: float, row_b: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Values at times ``t`` on the straight line between ``row_a`` (at ``t_a``) and ``row_b`` (at
    ``t_b``), column by column; NaN where either end is NaN."""
    w = ((np.asarray(t, np.float64) - t_a) / (t_b - t_a))[:, None]
    return (1.0 - w) * np.asarray(row_a, np.float64)[None, :] + w * np.asarray(row_b, np.float64)[None, :]


def record_period_s(rec: FlightRecord) -> float:
    """The nominal IMU sample period: from ``imu_rate_hz`` in the metadata, else the median step
    inside segments (NaN when unknown)."""
    rate = rec.meta.get("imu_rate_hz")
    if rate and np.isfinite(rate) and rate > 0:
        return 1.0 / float(rate)
    t, seg = rec.t_s, rec.segment
    dt = np.diff(t)[np.diff(seg) == 0]
    return float(np.median(dt)) if dt.size else float("nan")


def segment_period_s(t_s, default: float = float("nan")) -> float:
    """A segment's sample period from its times: the median of its first :data:`PERIOD_STEPS` steps (``default``
    for a segment of one sample). What the anchored filter, its offline VQF runs and the live estimator take."""
    dt = np.diff(np.asarray(t_s[: PERIOD_STEPS + 1], np.float64))
    return float(np.median(dt)) if dt.size else default


def rate_rise_cuts(t_s: np.ndarray, segment: np.ndarray) -> np.ndarray:
    """The rows that start a new segment because the sample rate rose (see the module): in each segment, after
    its first :data:`PERIOD_STEPS` steps, the first row at which more than half of the last :data:`PERIOD_STEPS`
    steps are shorter than the segment's period / :data:`RATE_RISE`; the new segment is scanned in turn."""
    t = np.asarray(t_s, np.float64)
    seg = np.asarray(segment)
    starts = np.r_[0, np.flatnonzero(np.diff(seg) != 0) + 1]
    ends = np.r_[starts[1:], len(t)]
    cuts = []
    for a, b in zip(starts.tolist(), ends.tolist()):
        while b - a > PERIOD_STEPS + 1:
            ts = segment_period_s(t[a:b])
            short = np.diff(t[a:b]) < ts / RATE_RISE  # short[j]: the step into row a + j + 1
            if not (ts > 0) or int(short.sum()) < _RISE_COUNT:
                break
            c = np.cumsum(short)
            last = c[PERIOD_STEPS - 1 :] - np.r_[0, c[: -PERIOD_STEPS]]  # over the steps into rows i-50 .. i
            i = np.arange(PERIOD_STEPS, b - a)  # rows a + i whose last PERIOD_STEPS steps are all in the segment
            hit = np.flatnonzero(last[i - PERIOD_STEPS] >= _RISE_COUNT) if len(i) else i
            hit = hit[i[hit] > PERIOD_STEPS]  # after the steps that gave the period (the live filter is made then)
            if not len(hit):
                break
            a = a + int(i[hit[0]])
            cuts.append(a)
    return np.asarray(cuts, np.int64)


class RateRise:
    """The live form of :func:`rate_rise_cuts`: ``step(dt)`` for each step after a segment's period ``ts`` is
    known (its first :data:`PERIOD_STEPS` steps) → True at the sample that starts a new segment."""

    def __init__(self, ts: float, steps: list[float]):
        self.limit = ts / RATE_RISE
        self.short = deque((d < self.limit for d in steps[-PERIOD_STEPS:]), maxlen=PERIOD_STEPS)
        self.count = sum(self.short)

    def step(self, dt: float) -> bool:
        s = dt < self.limit
        if len(self.short) == PERIOD_STEPS:
            self.count -= self.short[0]
        self.short.append(s)
        self.count += s
        return len(self.short) == PERIOD_STEPS and self.count >= _RISE_COUNT


def _with_cuts(b: "Bridged") -> "Bridged":
    """``b`` with its record's segments cut where the sample rate rose (:func:`rate_rise_cuts`)."""
    rec = b.record
    cuts = rate_rise_cuts(rec.t_s, rec.segment)
    if not len(cuts):
        return b
    data = rec.data.copy()
    is_break = np.r_[False, np.diff(rec.segment) != 0]
    is_break[cuts] = True
    data["segment"] = np.cumsum(is_break).astype(np.int32)
    return Bridged(FlightRecord(data, dict(rec.meta)), b.rows, b.gaps, b.filled)


def bridge_gaps(rec: FlightRecord, max_gap_s: float = MAX_BRIDGED_GAP_S) -> Bridged:
    """``rec`` with every segment break that is a gap of at most ``max_gap_s`` bridged (see the
    module), and cut where the sample rate rose (:func:`rate_rise_cuts`). The record itself is returned
    (``filled == 0``) when there is nothing to bridge or cut."""
    return _with_cuts(_bridged(rec, max_gap_s))


def _bridged(rec: FlightRecord, max_gap_s: float) -> Bridged:
    n = len(rec)
    ident = Bridged(rec, np.arange(n), 0, 0)
    if n < 2:
        return ident
    t, seg = rec.t_s, rec.segment
    period = record_period_s(rec)
    # a step inside a segment longer than GAP_PERIODS periods is a gap too, as the live estimator takes it (a record
    # whose rate fell, in one segment: its long steps had been integrated as 2.5 periods each; session 53)
    inner = (np.diff(seg) == 0) & (np.diff(t) > GAP_PERIODS * period) if np.isfinite(period) else np.zeros(n - 1, bool)
    is_break = np.r_[False, (np.diff(seg) != 0) | inner]
    breaks = np.flatnonzero(is_break)  # first row of each later segment
    bridge = [int(b) for b in breaks if is_bridgeable(t[b] - t[b - 1], period, max_gap_s)]
    if not bridge and not inner.any():
        return ident
    data = rec.data.copy()
    is_break[bridge] = False
    data["segment"] = np.cumsum(is_break).astype(np.int32)
    seg = data["segment"].to_numpy()
    cols = [c for c in _INTERPOLATED if c in data.columns]
    pieces, fill_at = [], []
    prev = 0
    for b in bridge:
        pieces.append(data.iloc[prev:b])
        tf = filler_times(t[b - 1], t[b], period)
        vals = interpolate_rows(t[b - 1], data[cols].iloc[b - 1].to_numpy(np.float64),
                                t[b], data[cols].iloc[b].to_numpy(np.float64), tf)  # fmt: skip
        fill = pd.DataFrame({"t_s": tf, "segment": np.full(len(tf), seg[b - 1], np.int32)})
        for i, c in enumerate(cols):
            fill[c] = vals[:, i]
        for c in QREF_COLS:
            fill[c] = np.nan
        fill["clipped"] = False
        for c in ("valid", "gyr_clipped"):
            if c in data.columns:
                fill[c] = False
        pieces.append(fill[[c for c in data.columns]])
        fill_at.append((b, len(tf)))
        prev = b
    pieces.append(data.iloc[prev:])
    if not bridge:  # inner gaps longer than a bridge: breaks only
        return Bridged(FlightRecord(data, dict(rec.meta)), np.arange(n), 0, 0)
    out = pd.concat(pieces, ignore_index=True)
    for c in data.columns:
        out[c] = out[c].astype(data[c].dtype)
    shift = np.zeros(n, np.int64)
    for b, k in fill_at:
        shift[b:] += k
    filled = int(sum(k for _, k in fill_at))
    return Bridged(FlightRecord(out, dict(rec.meta)), np.arange(n) + shift, len(bridge), filled)
