"""The live view's cost on the bridge's thread: CPU µs per estimate + EKF attitude pair logged to a
Rerun recording (``LiveView`` with the bridge's differences passed in, buffered columns), beside
the bridge's own comparison of the same pair (``EkfComparator``: pairing and slerp), measured in the
same run, and beside logging every row with ``rr.log`` (what batching avoids). The view sends its
buffered rows as at 50 Hz of flight: every 0.1 s (a viewer) or every 2 s (a file alone); process
CPU time, so Rerun's own encoder threads count too.

Usage: python benchmarks/view_cost.py [--pairs 3000]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from tepinn_flight.live.inputs import EkfComparator  # noqa: E402
from tepinn_flight.live.view import ViewConfig, open_view  # noqa: E402
from tepinn_flight.quat import quat_from_euler_zyx  # noqa: E402


def attitudes(n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """50 Hz estimates and EKF attitudes 1 ms later, a slow roll/pitch/yaw wobble."""
    t = 10.0 + np.arange(n) * 0.02
    q = quat_from_euler_zyx(0.3 * np.sin(t), 0.2 * np.cos(0.7 * t), 0.1 * t)
    return t, q, q[:, [0, 1, 2, 3]]


def cpu_us_per_pair(fn, n: int) -> float:
    t0 = time.process_time()
    fn()
    return (time.process_time() - t0) / n * 1e6


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--pairs", type=int, default=3000)
    args = ap.parse_args()
    n = args.pairs
    t, q_est, q_ekf = attitudes(n)
    est = [tuple(v) for v in q_est]
    ekf = [tuple(v) for v in q_ekf]
    with tempfile.TemporaryDirectory() as tmp:
        cmp = EkfComparator()
        diffs = []

        def compare():
            for i in range(n):
                diffs.append(cmp.add_estimate(t[i], est[i]))
                diffs.append(cmp.add_ekf(t[i] + 0.001, ekf[i]))

        us_cmp = cpu_us_per_pair(compare, n)
        us_view = {}
        for flush_s in (ViewConfig.view_flush_s, 0.25, 0.5, ViewConfig.file_flush_s):
            view = open_view(ViewConfig(rrd_path=str(Path(tmp) / f"b{flush_s}.rrd")), compare=False)
            clock = [0.0]
            view.clock, view.flush_s, view._next_flush = (lambda: clock[0]), flush_s, flush_s  # 50 Hz of flight

            def log_view():
                for i in range(n):
                    clock[0] = i * 0.02
                    view.estimate(t[i], est[i])
                    view.ekf(t[i] + 0.001, ekf[i])
                    view.differences(diffs[2 * i] + diffs[2 * i + 1])
                view.close()

            us_view[flush_s] = cpu_us_per_pair(log_view, n)
        import rerun as rr  # noqa: PLC0415

        rec = rr.RecordingStream("rows")
        rec.set_sinks(rr.FileSink(str(Path(tmp) / "rows.rrd")))

        def log_rows():
            for i in range(n):
                for who, q in (("tepinn", est[i]), ("ekf", ekf[i])):
                    rec.set_time("autopilot_time", duration=float(t[i]))
                    rec.log(f"world/{who}", rr.Transform3D(quaternion=rr.Quaternion(xyzw=[q[1], q[2], q[3], q[0]])))
                    for a in ("roll", "pitch", "heading"):
                        rec.log(f"attitude/{a}/{who}", rr.Scalars(0.0))

        us_rows = cpu_us_per_pair(log_rows, n)
        rec.disconnect()
    print(f"{n} estimate + EKF pairs, CPU time per pair (time.process_time)")
    print(f"  bridge's comparison (EkfComparator)       {us_cmp:8.1f} us   1.00x")
    for flush_s, us in us_view.items():
        label = f"live view, columns every {flush_s:g} s (LiveView)"
        print(f"  {label:<42}{us:8.1f} us   {us / us_cmp:.2f}x")
    print(f"  the same rows one rr.log each             {us_rows:8.1f} us   {us_rows / us_cmp:.2f}x")


if __name__ == "__main__":
    main()
