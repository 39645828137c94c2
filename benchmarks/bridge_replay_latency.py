"""The live bridge's latency on a real log played as a live autopilot: IMU message in → estimate out.

``tepinn-flight replay LOG`` plays the log's messages in real time to ``tepinn-flight bridge``, whose ``--out`` goes
to a listener that drains it; all three on this machine's cores, as a companion computer would run the bridge beside
the traffic (``--busy N`` adds N processes that keep a core busy each: the issue's loaded machine). Printed from the
bridge's exit summary (``--summary-json``):

* the estimates' rate on the autopilot's clock and their count;
* IMU message in → estimate out (the bridge's own wall-clock figure): p50, p99, max — against the issue's 5 ms p99;
* the worker's push of each sent estimate's sample (p50, p99) and how many of those pushes ran the network, and the
  network's runs in all (since session 46 the worker runs the network's window between samples:
  ``StreamingEstimator.prepare``) — the estimator's share of the latency; the rest is pipes and scheduling.

The peer measured in the same run is the replay's own sending: how late it sent its messages against the log's clock
(its summary's lateness), which is what the machine's load does to any process here.

    python benchmarks/bridge_replay_latency.py [LOG] [--seconds 50] [--busy 1]

Without LOG the shared 50 Hz ArduCopter log (erle, held out: used here for latency only, no accuracy figure).
"""

from __future__ import annotations

import argparse
import json
import multiprocessing as mp
import os
import socket
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(Path(__file__).resolve().parent))
from bridge_latency import _burn  # noqa: E402  (the same load as that benchmark's --busy)
DEFAULT_LOG = ROOT.parent / "shared" / "real-logs" / "erle_pxf_copter_15-12-2014_16.BIN"
TARGET_P99_MS = 5.0


def _free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _drain(port: int, stop: threading.Event, counter: list) -> None:
    """The ground station: receive and drop everything the bridge sends."""
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind(("127.0.0.1", port))
    s.settimeout(0.2)
    while not stop.is_set():
        try:
            s.recv(65536)
            counter[0] += 1
        except socket.timeout:
            pass
    s.close()


def run(log: Path, seconds: float, start_wait_s: float, busy: int) -> dict:
    """One replay through the bridge → {"bridge": its summary, "replay": the replay's summary line(s), "received": n}."""
    master, out = _free_udp_port(), _free_udp_port()
    stop, received = threading.Event(), [0]
    th = threading.Thread(target=_drain, args=(out, stop, received), daemon=True)
    th.start()
    burners = [mp.get_context("spawn").Process(target=_burn, daemon=True) for _ in range(max(0, busy))]
    for b in burners:
        b.start()
    with tempfile.TemporaryDirectory() as d:
        summary = Path(d) / "bridge.json"
        bridge = subprocess.Popen(
            [sys.executable, "-m", "tepinn_flight", "bridge", "--master", f"udpin:127.0.0.1:{master}",
             "--out", f"udpout:127.0.0.1:{out}", "--duration", f"{seconds + start_wait_s + 5:g}", "-q",
             "--summary-json", str(summary)],
            stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, cwd=ROOT,
        )  # fmt: skip
        try:
            time.sleep(start_wait_s)  # the worker compiles and warms up before it estimates
            rep = subprocess.run(
                [sys.executable, "-m", "tepinn_flight", "replay", str(log), "--to", f"udpout:127.0.0.1:{master}",
                 "--duration", f"{seconds:g}"],
                stdin=subprocess.DEVNULL, capture_output=True, text=True, cwd=ROOT,
            )  # fmt: skip
            _, err = bridge.communicate(timeout=seconds + start_wait_s + 60)
        finally:
            if bridge.poll() is None:
                bridge.kill()
            for b in burners:
                b.terminate()
            stop.set()
        if rep.returncode != 0:
            raise SystemExit(f"bridge_replay_latency.py: replay failed: {(rep.stderr or rep.stdout).strip()[-300:]}")
        if not summary.exists():
            raise SystemExit(f"bridge_replay_latency.py: the bridge wrote no summary: {err.strip()[-300:]}")
        return {"bridge": json.loads(summary.read_text()), "replay": (rep.stdout + rep.stderr).strip(),
                "received": received[0]}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("log", nargs="?", default=str(DEFAULT_LOG), help="a log `replay` plays (default: the shared erle log)")
    ap.add_argument("--seconds", type=float, default=50.0, help="seconds of the log played (default 50)")
    ap.add_argument("--busy", type=int, default=0, metavar="N", help="N processes keeping a core busy each (default 0)")
    ap.add_argument("--start-wait", type=float, default=8.0, help="seconds the bridge gets to start (default 8)")
    a = ap.parse_args()
    log = Path(a.log)
    if not log.exists():
        print(f"bridge_replay_latency.py: no such log: {log} (the shared real logs belong in ../shared/real-logs)",
              file=sys.stderr)  # fmt: skip
        return 2
    print(f"{log.name}: {a.seconds:g} s replayed live through the bridge; {os.cpu_count()} CPU cores, "
          f"{a.busy} busy process(es) beside it; load average {os.getloadavg()[0]:.2f}")  # fmt: skip
    r = run(log, a.seconds, a.start_wait, a.busy)
    s = r["bridge"]
    e = s.get("estimates", {})
    lat, push = s.get("latency_ms", {}), e.get("push_ms") or {}
    print(f"estimates: {e.get('count', 0)} at {e.get('rate_hz')} Hz of autopilot time; {r['received']} datagrams at "
          f"the listener")  # fmt: skip
    if lat.get("n"):
        print(f"IMU in -> estimate out: p50 {lat['p50']:.2f} ms, p99 {lat['p99']:.2f} ms, max {lat['max']:.2f} ms "
              f"(target p99 <= {TARGET_P99_MS:g} ms: {'met' if lat['p99'] <= TARGET_P99_MS else 'MISSED'})")  # fmt: skip
    if push.get("n"):
        print(f"the worker's push of each sent estimate's sample: p50 {push['p50']:.3f} ms, p99 {push['p99']:.3f} ms; "
              f"{e.get('sent_after_network', 0)} of {push['n']} ran the network; network runs in all "
              f"{e.get('model_runs', 0)} x {e.get('model_ms_mean') or float('nan'):.2f} ms")  # fmt: skip
    late = [ln for ln in r["replay"].splitlines() if "late" in ln.lower()]
    print("the replay (peer, same run): " + (late[-1].strip() if late else (r["replay"].splitlines() or ["no summary"])[-1]))
    return 0


if __name__ == "__main__":
    sys.exit(main())
