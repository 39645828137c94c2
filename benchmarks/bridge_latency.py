"""Live bridge latency and throughput over loopback UDP, against a direct path in the same run.

A sender process plays a fake autopilot (HIGHRES_IMU at 400 Hz from a synthetic flight,
ATTITUDE_QUATERNION at 50 Hz, HEARTBEAT at 1 Hz; for the throughput phase filler telemetry up to
2,000 messages/s) and records when it sent each frame; a receiver thread (raw socket) records when
each frame arrived. Phases, each with the same traffic:

  direct      sender → receiver                      (the peer: what loopback + Python costs)
  bridge      sender → ``tepinn-flight bridge`` → receiver, estimator in a child process (default)
  bridge-thr  the same with ``--worker thread`` (estimator thread inside the bridge's process)
  2k msg/s    sender → bridge (process worker) → receiver at 2,000 messages/s: lost frames

Figures: one-way latency of forwarded frames (p50/p99, direct vs bridge, and what the bridge
adds), IMU message in → estimate out (the bridge's own wall-clock figure and, end to end, sender
→ receiver), estimate rate on the autopilot clock, lost frames, and where the time goes (network
call per token vs per-sample fusion step, from the worker's counters).

    python benchmarks/bridge_latency.py [--seconds 15] [--model CKPT]

Without ``--model`` the shipped model is used, else an untrained default-size TE-PINN (the same
compute per call as a trained one). Targets (2-core machine): estimates >= 50 Hz, IMU in → estimate
out p99 <= 5 ms (the issue's target, as checked below), forwarding adds <= 1 ms p99, no lost frame at 2,000 messages/s.
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

os.environ["MAVLINK20"] = "1"

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]


# ---------------------------------------------------------------------------- traffic
def make_traffic(seconds: float, total_rate: float | None, imu_hz: float = 400.0):
    """[(due_s, frame, kind)] for an ``imu_hz`` IMU autopilot; filler up to ``total_rate`` msg/s."""
    from tepinn_flight.live import dialect
    from tepinn_flight.live.replay import record_stream
    from tepinn_flight.model.synthetic import synthetic_record

    m = dialect()
    rec = synthetic_record(seed=11, duration_s=seconds, rate_hz=imu_hz)
    items = []
    for p, fr in record_stream(rec, attitude_rate_hz=50.0):
        mid = fr[7] | (fr[8] << 8) | (fr[9] << 16)
        kind = "imu" if mid == m.MAVLINK_MSG_ID_HIGHRES_IMU else "other"
        items.append((p, fr, kind))
    if total_rate:
        from tepinn_flight.live.messages import Encoder

        enc = Encoder(1, 1)
        extra = int(total_rate * seconds) - len(items)
        ts = np.sort(np.random.default_rng(0).uniform(0, seconds, max(extra, 0)))
        fill = []
        for k, t in enumerate(ts):
            if k % 2:
                msg = m.MAVLink_servo_output_raw_message(int(t * 1e6) & 0xFFFFFFFF, 0, *([1500] * 8))
            else:
                msg = m.MAVLink_vfr_hud_message(12.0, 12.5, 90, 50, float(k), 0.5)  # alt: unique frames
            fill.append((float(t), enc.pack(msg), "other"))
        items = sorted(items + fill, key=lambda x: x[0])  # stable: autopilot frames keep their order
    return items


def sender(port: int, items, conn, start_delay: float, twin_port: int | None = None) -> None:
    """Child process: send frames at their due times (also to ``twin_port``), return the send times."""
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, 4 << 20)
    dest = ("127.0.0.1", port)
    twin = ("127.0.0.1", twin_port) if twin_port else None
    sent = np.zeros(len(items))
    t0 = time.monotonic() + start_delay
    for i, (p, fr, _) in enumerate(items):
        d = t0 + p - time.monotonic()
        if d > 0.0002:
            time.sleep(d)
        sock.sendto(fr, dest)
        sent[i] = time.monotonic()
        if twin is not None:
            sock.sendto(fr, twin)  # the same frame straight to the receiver: the paired reference
    conn.send(sent)
    conn.close()


class Receiver:
    """Two sockets read by one thread: ``port`` (the path under test) and ``twin_port`` (direct)."""

    def __init__(self):
        self.socks = []
        for _ in range(2):
            s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 16 << 20)
            s.bind(("127.0.0.1", 0))
            s.setblocking(False)
            self.socks.append(s)
        self.port = self.socks[0].getsockname()[1]
        self.twin_port = self.socks[1].getsockname()[1]
        self.got = []
        self.twin = []
        self.stop = threading.Event()
        self.t = threading.Thread(target=self.run, daemon=True)
        self.t.start()

    def run(self):
        import select

        while not self.stop.is_set():
            ready, _, _ = select.select(self.socks, [], [], 0.05)
            for s in ready:
                while True:
                    try:
                        d = s.recv(65536)
                    except BlockingIOError:
                        break
                    (self.got if s is self.socks[0] else self.twin).append((time.monotonic(), d))

    def close(self):
        self.stop.set()
        self.t.join()
        for s in self.socks:
            s.close()
        return self.got


def _compid(fr: bytes) -> int:
    return fr[6] if fr[0] == 0xFD else fr[4]


def run_phase(items, model: str | None, worker: str | None, seconds: float) -> dict:
    """Send ``items`` directly (model None) or through a bridge; returns the figures."""
    from tepinn_flight.live import dialect

    rx = Receiver()
    bridge = None
    summary = None
    ctx = mp.get_context("spawn")
    try:
        if model is None:
            port = rx.port
        else:
            s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            s.bind(("127.0.0.1", 0))
            port = s.getsockname()[1]
            s.close()
            tmp = tempfile.mkdtemp(prefix="bridge-bench-")
            summ = Path(tmp) / "summary.json"
            bridge = subprocess.Popen(
                [sys.executable, "-m", "tepinn_flight", "bridge", "--master", f"udpin:127.0.0.1:{port}",
                 "--out", f"udpout:127.0.0.1:{rx.port}", "--model", model, "--worker", worker,
                 "--summary-json", str(summ), "--status-interval", "1000", "--min-imu-rate", "0",
                 "--estimate-as", "attitude_quaternion"],  # what the receiver decodes (cost as named_value)
                stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, cwd=ROOT,
            )  # fmt: skip
            for line in bridge.stderr:
                if "estimator ready" in line:
                    break
            threading.Thread(target=lambda: bridge.stderr.read(), daemon=True).start()
        a, b = ctx.Pipe(duplex=False)
        proc = ctx.Process(target=sender, args=(port, items, b, 0.3, rx.twin_port if model is not None else None))
        proc.start()
        sent = a.recv()
        proc.join()
        time.sleep(0.5)
        if bridge is not None:
            bridge.terminate()
            bridge.wait(30)
            summary = json.loads(summ.read_text())
    finally:
        if bridge is not None and bridge.poll() is None:
            bridge.kill()
        got = rx.close()
    lat = []
    arrived = np.zeros(len(items), bool)
    imu_time = {}
    m = dialect()
    for i, (_, fr, kind) in enumerate(items):
        if kind == "imu":
            imu_time[int.from_bytes(fr[10:18], "little") // 1000] = i  # HIGHRES_IMU time_usec → ms
    est_lat = []
    est_ms = []
    j = 0  # loopback keeps the order: match received frames to sent ones in sequence
    for t, d in got:
        if _compid(d) == 191:
            parser = m.MAVLink(None)
            for msg in parser.parse_buffer(d) or []:
                if msg.get_type() == "ATTITUDE_QUATERNION":
                    est_ms.append(msg.time_boot_ms)
                    i = imu_time.get(msg.time_boot_ms)
                    if i is not None:
                        est_lat.append(t - sent[i])
            continue
        k = j
        while k < len(items) and items[k][1] != d:
            k += 1
        if k < len(items):
            arrived[k] = True
            lat.append(t - sent[k])
            j = k + 1
    paired = []
    j = 0  # both paths keep the sending order: match frame by frame
    for t, d in got:
        if _compid(d) == 191:
            continue
        k = j
        while k < len(rx.twin) and rx.twin[k][1] != d:
            k += 1
        if k < len(rx.twin):
            paired.append(t - rx.twin[k][0])
            j = k + 1
    out = {
        "paired_ms": np.percentile(np.array(paired) * 1e3, [50, 99, 100]) if paired else [np.nan] * 3,
        "sent": len(items),
        "lost": int((~arrived).sum()),
        "lat_ms": np.percentile(np.array(lat) * 1e3, [50, 99, 100]) if lat else [np.nan] * 3,
        "rate_in": len(items) / seconds,
    }
    if est_ms:
        ms = np.array(est_ms, float)
        span = (ms.max() - ms.min()) / 1e3
        out["est_rate_hz"] = (len(ms) - 1) / span if span > 0 else float("nan")
        out["e2e_ms"] = np.percentile(np.array(est_lat) * 1e3, [50, 99, 100]) if est_lat else [np.nan] * 3
    out["summary"] = summary
    return out


def _burn() -> None:
    """A stress-like load: one core kept busy with arithmetic until the benchmark ends."""
    x = 0
    while True:
        x = (x * 1103515245 + 12345) & 0x7FFFFFFF


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seconds", type=float, default=15.0, help="traffic per phase (default 15)")
    ap.add_argument("--model", default=None, help="checkpoint (default: shipped model, else untrained default size)")
    ap.add_argument("--busy", type=int, default=0, metavar="N",
                    help="also run N processes that keep a core busy during every phase (the issue's loaded machine)")
    ap.add_argument("--imu-hz", type=float, default=400.0,
                    help="the autopilot's IMU rate (default 400; 50: an ArduCopter log's, where the network's once-a-"
                         "second run falls among the top 2 %% of samples' latencies)")
    a = ap.parse_args()

    from tepinn_flight.model.checkpoint import default_model_path

    burners = [mp.get_context("spawn").Process(target=_burn, daemon=True) for _ in range(max(0, a.busy))]
    for b in burners:
        b.start()

    tmpdir = tempfile.mkdtemp(prefix="bridge-bench-model-")
    if a.model:
        model, label = a.model, Path(a.model).name
    elif default_model_path().exists():
        model, label = str(default_model_path()), "shipped"
    else:
        import torch

        from tepinn_flight.model.checkpoint import save_checkpoint
        from tepinn_flight.model.config import ModelConfig
        from tepinn_flight.model.fusion import FusionConfig
        from tepinn_flight.model.network import TEPINN

        torch.manual_seed(0)
        model = str(Path(tmpdir) / "default_size.pt")
        save_checkpoint(model, TEPINN(ModelConfig()).eval(), FusionConfig())
        label = "untrained, default size"
    print(f"model: {label}; IMU at {a.imu_hz:g} Hz; {os.cpu_count()} CPU cores; {a.seconds:g} s of traffic per phase; "
          f"{len(burners)} busy process(es) beside it\n")
    traffic = make_traffic(a.seconds, None, a.imu_hz)
    busy = make_traffic(a.seconds, 2000.0, a.imu_hz)
    res = {
        "direct": run_phase(traffic, None, None, a.seconds),
        "bridge": run_phase(traffic, model, "process", a.seconds),
        "bridge-thr": run_phase(traffic, model, "thread", a.seconds),
        "direct 2k": run_phase(busy, None, None, a.seconds),
        "bridge 2k": run_phase(busy, model, "process", a.seconds),
    }

    print(f"{'phase':<12} {'msg/s':>7} {'lost':>5} {'fwd p50':>8} {'fwd p99':>8} {'fwd max':>8} "
          f"{'est Hz':>7} {'e2e p50':>8} {'e2e p99':>8} {'in->est p99':>12}")  # fmt: skip
    for k, r in res.items():
        s = r["summary"] or {}
        lat = s.get("latency_ms", {})
        est = f"{r['est_rate_hz']:7.1f}" if "est_rate_hz" in r else f"{'-':>7}"
        e2e = r.get("e2e_ms", [np.nan] * 3)
        print(f"{k:<12} {r['rate_in']:7.0f} {r['lost']:5d} {r['lat_ms'][0]:8.3f} {r['lat_ms'][1]:8.3f} "
              f"{r['lat_ms'][2]:8.2f} {est} {e2e[0]:8.2f} {e2e[1]:8.2f} {lat.get('p99', float('nan')):12.2f}")  # fmt: skip
    print("(ms; fwd = sender → receiver one way; e2e = IMU frame sent → its estimate received; "
          "in->est = the bridge's own IMU-in → estimate-out figure)\n")  # fmt: skip

    d, b, t = res["direct"], res["bridge"], res["bridge-thr"]
    added = b["paired_ms"][1]
    print("forwarding adds (each frame via the bridge minus the same frame sent straight to the receiver):")
    for k in ("bridge", "bridge-thr", "bridge 2k"):
        pm = res[k]["paired_ms"]
        print(f"  {k:<11} p50 {pm[0]:.3f} ms, p99 {pm[1]:.3f} ms, max {pm[2]:.2f} ms")
    print(f"one-way p99 ratio bridge/direct {b['lat_ms'][1] / d['lat_ms'][1]:.1f}x; "
          f"thread/process worker p99 {t['lat_ms'][1] / b['lat_ms'][1]:.1f}x")  # fmt: skip
    bs = b["summary"] or {}
    fl = bs.get("forward_latency_ms", {})
    print(f"inside the bridge (read → written to every out): p50 {fl.get('p50', float('nan')):.3f} ms, "
          f"p99 {fl.get('p99', float('nan')):.3f} ms")  # fmt: skip
    est = bs.get("estimates", {})
    if est.get("model_runs"):
        n = est["samples_processed"]
        runs = est["model_runs"]
        steps = est.get("steps", n - runs)  # pushes without the network (it runs between samples since session 46)
        mm, su = est["model_ms_mean"], est["step_us_mean"]
        total = runs * mm / 1e3 + steps * su / 1e6
        print(f"where the estimator's time goes: network {runs} calls x {mm:.2f} ms = {runs * mm / 1e3:.2f} s "
              f"({100 * runs * mm / 1e3 / total:.0f} %), fusion step {steps} samples x {su:.1f} us = "
              f"{steps * su / 1e6:.2f} s; estimator busy {100 * total / a.seconds:.0f} % of one core")  # fmt: skip
        pm = est.get("push_ms") or {}
        if pm.get("n"):
            print(f"the worker's push of each sent estimate's sample: p50 {pm['p50']:.3f} ms, p99 {pm['p99']:.3f} ms, "
                  f"max {pm['max']:.2f} ms; {est.get('sent_after_network', 0)} of {pm['n']} sent estimates waited for "
                  "the network in their push")  # fmt: skip
    b2 = res["bridge 2k"]
    print(f"2,000 msg/s through the bridge: {b2['lost']} of {b2['sent']} frames lost "
          f"(direct: {res['direct 2k']['lost']})")  # fmt: skip
    lat = bs.get("latency_ms", {})
    checks = [
        ("estimates >= 50 Hz", b.get("est_rate_hz", 0) >= 49.9),
        ("IMU in -> estimate out p99 <= 5 ms (the issue's target)", lat.get("p99", 1e9) <= 5.0),
        (f"forwarding adds <= 1 ms p99 (paired, {a.imu_hz:g} Hz IMU)", added <= 1.0),
        ("no lost frame at 2,000 msg/s", b2["lost"] == 0),
    ]
    print("\n" + "\n".join(f"  [{'ok' if ok else 'MISSED'}] {name}" for name, ok in checks))
    return 0


if __name__ == "__main__":
    sys.exit(main())
