"""Baseline-filter speed: µs per sample of each filter beside VQF (C++) and beside its own former
pure-Python loop (``tests/filters_reference.py``), all measured in the same run.

One core, one process, the same closed-form motion for every estimator (constant-rate coning plus
gravity and sensor noise, 200 Hz). CPU time (``time.process_time``) is reported because the machine
may be shared; wall time is shown too. Peers that are not installed are listed as skipped. The
compiled loops are run once before timing (numba's compile or cache load is not a per-sample cost).

Also VQF's batch update alone, the ``vqf`` package's C++ ``updateBatch`` beside the anchored estimator's compiled port
(``model/vqf_kernel.py``, the same bits), 6-D and 9-D, with the same conversions around both (session 49: 0.24 / 0.28 µs,
9-D 0.37 / 0.41 µs).

Usage: python benchmarks/filters_speed.py [--samples 50000] [--repeat 3]
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from tepinn_flight.evaluation.estimators import FilterEstimator  # noqa: E402
from tepinn_flight.evaluation.filters import Complementary, Ekf, Madgwick, MadgwickParams  # noqa: E402
from tepinn_flight.evaluation.filters import complementary, ekf, madgwick  # noqa: E402
from tests import filters_reference as ref  # noqa: E402
from tepinn_flight.evaluation.names import display_name  # noqa: E402
from tepinn_flight.evaluation.peers import make_peer  # noqa: E402
from tepinn_flight.quat import gravity_body, quat_from_rotvec, quat_mul, quat_normalize  # noqa: E402
from tepinn_flight.record import FlightRecord, make_frame  # noqa: E402


def motion(n: int, rate_hz: float = 200.0, with_mag: bool = True) -> FlightRecord:
    t = np.arange(n) / rate_hz
    w = np.array([0.6, -0.4, 0.5])
    q = quat_normalize(quat_mul(quat_from_rotvec(np.array([0.3, -0.2, 0.1]))[None], quat_from_rotvec(w[None] * t[:, None])))
    rng = np.random.default_rng(0)
    gyr = w + np.array([0.01, -0.02, 0.015]) + rng.normal(0, 0.003, (n, 3))
    acc = -gravity_body(q, 9.80665) + rng.normal(0, 0.05, (n, 3))
    from tepinn_flight.quat import quat_conj, quat_rotate

    mag = quat_rotate(quat_conj(q), np.broadcast_to([20.0, 0.0, 45.0], (n, 3))) if with_mag else None
    return FlightRecord(make_frame(t, np.zeros(n, int), gyr, acc, mag, q), {"source_kind": "synthetic"})


def _lists(mag):
    return None if len(mag) == 0 else mag.tolist()


#: the former loops behind the compiled ones' signatures (taking lists, as they did)
OLD_LOOPS = {
    complementary: lambda g, a, m, dt, ta, tm, q: ref.complementary_run(g.tolist(), a.tolist(), _lists(m), dt.tolist(), ta, tm, q),
    madgwick: lambda g, a, m, dt, beta, k, q: ref.madgwick_run(g.tolist(), a.tolist(), _lists(m), dt.tolist(), beta, k, q),
    ekf: ref.ekf_run,
}  # fmt: skip


class OldLoop:
    """A filter run with its former pure-Python loop (the module's ``_run`` swapped for the call)."""

    def __init__(self, flt, module):
        self.flt, self.module, self.name = flt, module, flt.name

    def estimate(self, *args, **kw):
        new = self.module._run
        self.module._run = OLD_LOOPS[self.module]
        try:
            return self.flt.estimate(*args, **kw)
        finally:
            self.module._run = new


class BatchVqf:
    """VQF's batch update alone over a record, 6-D or 9-D, the same conversions around it: the ``vqf`` package's
    ``updateBatch`` (C++) or the anchored estimator's port (``model/vqf_kernel.py``: that filter compiled with numba,
    its bits)."""

    def __init__(self, compiled: bool, use_mag: bool):
        self.compiled, self.use_mag = compiled, use_mag
        self.name = ("vqf compiled" if compiled else "vqf updateBatch") + (" 9-D" if use_mag else "")

    def estimate(self, rec):
        from tepinn_flight.model import vqf_kernel as vk
        from tepinn_flight.model.anchor import to_sensor

        g, a = to_sensor(rec.gyr_rad_s), to_sensor(rec.acc_m_s2)
        m = to_sensor(np.nan_to_num(rec.mag_ut)) if self.use_mag else None
        ts = float(rec.t_s[1] - rec.t_s[0])
        if not self.compiled:
            import vqf

            return vqf.VQF(ts).updateBatch(g, a, m)["quat6D"]
        n = len(g)
        c, s = vk.new_filter(ts)
        q6, q9, b = np.empty((n, 4)), np.empty((n, 4)), np.empty((n, 3))
        if self.use_mag:
            vk.update_rows_9d(c, s, g, a, m, q6, q9, b)
        else:
            vk.update_rows(c, s, g, a, q6, b)
        return q6


def timed(est, rec, repeat: int) -> tuple[float, float]:
    best_cpu = best_wall = math.inf
    for _ in range(repeat):
        c0, w0 = time.process_time(), time.perf_counter()
        est.estimate(rec)
        best_cpu = min(best_cpu, time.process_time() - c0)
        best_wall = min(best_wall, time.perf_counter() - w0)
    return 1e6 * best_cpu / len(rec), 1e6 * best_wall / len(rec)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--samples", type=int, default=50_000)
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    rec = motion(args.samples)
    notes: list[str] = []
    ours = [
        (FilterEstimator(Complementary()), complementary),
        (FilterEstimator(Complementary(), use_mag=True), complementary),
        (FilterEstimator(Madgwick()), madgwick),
        (FilterEstimator(Madgwick(MadgwickParams(original_quirk=True)), name="madgwick-original-9d", use_mag=True), madgwick),
        (FilterEstimator(Ekf()), ekf),
    ]  # fmt: skip
    peers = [p for p in (make_peer(n, notes) for n in ("vqf", "vqf-9d", "offline-vqf", "fusion", "riann")) if p is not None]
    short = motion(2000)
    rows = []
    for est in peers:
        cpu, wall = timed(est, rec, args.repeat if est.name != "riann" else 1)
        rows.append((est.name, "peer", cpu, wall, None))
    for use_mag in (False, True):  # the anchored estimator's VQF beside the package's C++, the same work around both
        for compiled in (False, True):
            est = BatchVqf(compiled, use_mag)
            est.estimate(short)  # compile / load the cached machine code
            cpu, wall = timed(est, rec, args.repeat)
            rows.append((est.name, "ours" if compiled else "peer", cpu, wall, None))
    for est, module in ours:
        est.estimate(short)  # compile / load the cached machine code
        cpu, wall = timed(est, rec, args.repeat)
        old = FilterEstimator(OldLoop(est.filter, module), name=est.name, use_mag=est.uses_mag)
        old_cpu, _ = timed(old, rec, 1)
        rows.append((est.name, "ours", cpu, wall, old_cpu))
    vqf = next((r for r in rows if r[0] == "vqf"), None)
    print(f"{args.samples} samples at 200 Hz, best of {args.repeat}; µs per sample (CPU / wall)")
    print(f"{'estimator':24s} {'':5s} {'cpu µs':>9s} {'wall µs':>9s} {'samples/s':>11s} {'× VQF':>8s} "
          f"{'old cpu µs':>11s} {'speed-up':>9s}")  # fmt: skip
    for name, who, cpu, wall, old_cpu in rows:
        ratio = f"{cpu / vqf[2]:8.1f}" if vqf else "     n/a"
        old = f"{old_cpu:11.2f} {old_cpu / cpu:8.1f}×" if old_cpu else ""
        print(f"{display_name(name):24s} {who:5s} {cpu:9.2f} {wall:9.2f} {1e6 / cpu:11.0f} {ratio} {old}")
    print("old: the same filter with its former pure-Python loop (tests/filters_reference.py), one run")
    for n in notes:
        print(f"skipped: {n}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
