"""The live view (Rerun): ``bridge --rrd`` and ``replay --rrd`` record TE-PINN beside the autopilot's
attitude. The recordings are read back with Rerun's own reader (``rerun.chunk.RrdReader``) and
checked against the messages on the wire, with angles from scipy's Rotation (not the package's)."""

from __future__ import annotations

import os

os.environ["MAVLINK20"] = "1"  # before pymavlink (mavlink.md §2)

import subprocess
import sys
import threading
import time

import numpy as np
import pyarrow as pa
import pytest
from rerun.chunk import RrdReader
from scipy.spatial.transform import Rotation, Slerp

from tepinn_flight.live import dialect
from tepinn_flight.live.bridge import Bridge, BridgeConfig
from tepinn_flight.live.inputs import EstimateDecoder
from tepinn_flight.live.messages import ESTIMATE_AS, Encoder, diagnostic_msgs, estimate_msgs
from tepinn_flight.live.replay import replay
from tepinn_flight.live.view import ViewConfig
from tepinn_flight.model.checkpoint import default_model_path
from tests.conftest import real_log
from tests.test_replay import UdpListener

M = dialect()
ENTITIES = {f"/attitude/{a}/{w}" for a in ("roll", "pitch", "heading") for w in ("tepinn", "ekf")} | {
    f"/difference/{d}" for d in ("roll", "pitch", "heading", "inclination")} | {
    "/world", "/world/tepinn", "/world/ekf", "/world/tepinn/body", "/world/ekf/body"}  # fmt: skip


# ---------------------------------------------------------------------------- reading a recording back
def read_rrd(path) -> dict[str, dict[str, np.ndarray]]:
    """entity path -> {"t": autopilot time in s, column name: values} of the temporal rows, sorted
    by time; static entities map to {} (present, no rows)."""
    out: dict[str, dict[str, list]] = {}
    for chunk in RrdReader(path).stream().collect().stream():
        ent = out.setdefault(str(chunk.entity_path), {})
        if chunk.is_static:
            continue
        rb = chunk.to_record_batch()
        names = rb.schema.names
        ent.setdefault("t", []).append(rb.column(names.index("autopilot_time")).cast(pa.int64()).to_numpy() / 1e9)
        for name in names:
            if ":" in name:
                ent.setdefault(name, []).append(np.array([np.asarray(v[0], float) for v in rb.column(names.index(name)).to_pylist()]))
    res = {}
    for k, ent in out.items():
        if not ent:
            res[k] = {}
            continue
        cols = {c: np.concatenate(v) for c, v in ent.items()}
        order = np.argsort(cols["t"], kind="stable")
        res[k] = {c: v[order] for c, v in cols.items()}
    return res


def scipy_rpy_deg(q_wxyz: np.ndarray) -> np.ndarray:
    """(roll, pitch, yaw) in degrees, intrinsic Z-Y-X, by scipy."""
    q = np.asarray(q_wxyz, float).reshape(-1, 4)
    return Rotation.from_quat(q[:, [1, 2, 3, 0]]).as_euler("ZYX", degrees=True)[:, ::-1]


def _angle_diff_deg(a, b):
    return (np.asarray(a) - np.asarray(b) + 180.0) % 360.0 - 180.0


def _wire(gcs):
    """(estimates, ekf): time_boot_ms -> q_wxyz of the ATTITUDE_QUATERNIONs from 1/191 and 1/1."""
    est, ekf = {}, {}
    for _, m in gcs.messages():
        if m.get_type() == "ATTITUDE_QUATERNION":
            side = est if m.get_srcComponent() == 191 else ekf
            side[int(m.time_boot_ms)] = np.array([m.q1, m.q2, m.q3, m.q4])
    return est, ekf


def _check_source(rows, wire: dict[int, np.ndarray], who: str, match_ms: float = 1.0) -> int:
    """Every wire attitude has a recorded row at its time whose transform is its quaternion and
    whose roll/pitch/heading are scipy's angles of it; returns how many matched."""
    t = rows[f"/world/{who}"]["t"]
    assert np.all(np.diff(t) > 0)
    for a in ("roll", "pitch", "heading"):
        np.testing.assert_array_equal(rows[f"/attitude/{a}/{who}"]["t"], t)
    q_xyzw = rows[f"/world/{who}"]["Transform3D:quaternion"]
    rpy = np.stack([rows[f"/attitude/{a}/{who}"]["Scalars:scalars"] for a in ("roll", "pitch", "heading")], 1)
    ms = np.array(sorted(wire))
    i = np.searchsorted(t, ms / 1e3 - match_ms / 1e3)
    i = np.clip(i, 0, len(t) - 1)
    hit = np.abs(t[i] - ms / 1e3) < match_ms / 1e3
    q_wire = np.array([wire[k] for k in ms])[hit]
    got_q = q_xyzw[i[hit]][:, [3, 0, 1, 2]]
    sign = np.sign(np.sum(got_q * q_wire, 1, keepdims=True))
    np.testing.assert_allclose(got_q * sign, q_wire, atol=2e-6)  # float32 on the wire and in the recording
    d = _angle_diff_deg(rpy[i[hit]], scipy_rpy_deg(q_wire))
    assert np.max(np.abs(d)) < 1e-4, np.max(np.abs(d))
    return int(hit.sum())


def _scipy_inclination_deg(q_est: np.ndarray, t_est: np.ndarray, ekf: dict[int, np.ndarray]) -> np.ndarray:
    """Angle between the gravity directions in the body frame of the estimate and of the EKF
    slerped (scipy) onto the estimate's time."""
    ms = np.array(sorted(ekf))
    slerp = Slerp(ms / 1e3, Rotation.from_quat(np.array([ekf[k] for k in ms])[:, [1, 2, 3, 0]]))
    r_ekf = slerp(t_est)
    r_est = Rotation.from_quat(q_est[:, [1, 2, 3, 0]])
    down = np.array([0.0, 0.0, 1.0])
    ge, gr = r_est.inv().apply(down), r_ekf.inv().apply(down)
    return np.degrees(np.arccos(np.clip(np.sum(ge * gr, 1), -1.0, 1.0)))


# ---------------------------------------------------------------------------- end to end
@pytest.mark.slow
def test_bridge_and_replay_record_tepinn_beside_the_autopilot(tmp_path):
    """A shared real PX4 log played (replay --rrd) into the bridge (--rrd, estimates also sent back
    to the "autopilot"); a ground station records what goes on the wire."""
    log = real_log("pyulog_sample_log_small.ulg")  # 6.5 s, IMU at ~205 Hz, PX4's attitude
    if not default_model_path().exists():
        pytest.skip("the shipped model is not in this checkout")
    gcs = UdpListener()
    cfg = BridgeConfig(master="udpin:127.0.0.1:0", outs=(f"udpout:127.0.0.1:{gcs.port}",), worker="thread",
                       model_path=str(default_model_path()), estimate_as="attitude_quaternion", estimates_to_master=True,
                       min_imu_rate_hz=0, max_sample_age_s=5.0, rrd_path=str(tmp_path / "bridge.rrd"))  # fmt: skip
    bridge = Bridge(cfg)
    stop = threading.Event()
    box = {}
    th = threading.Thread(target=lambda: box.setdefault("summary", bridge.run(stop)), daemon=True)
    th.start()
    try:
        assert bridge.ready.wait(60), "estimator did not start"
        out = replay(log, f"udpout:127.0.0.1:{bridge.master.local_port()}", speed=2.0,
                     view=ViewConfig(rrd_path=str(tmp_path / "replay.rrd")))  # fmt: skip
        time.sleep(1.5)  # let the estimator drain its queue
    finally:
        stop.set()
        th.join(15)
        gcs.close()
    assert not th.is_alive()
    summary = box["summary"]
    assert out["messages_sent"] > 1000
    assert not (tmp_path / "bridge.rrd.part").exists() and not (tmp_path / "replay.rrd.part").exists()
    est, ekf = _wire(gcs)
    assert len(est) == summary["estimates"]["count"] >= 100, summary["estimates"]

    # the bridge's recording: every estimate and every EKF attitude, as scipy reads the wire
    rb = read_rrd(tmp_path / "bridge.rrd")
    assert ENTITIES <= set(rb), sorted(set(rb))
    assert _check_source(rb, est, "tepinn") == len(est) == len(rb["/world/tepinn"]["t"])
    assert _check_source(rb, ekf, "ekf") >= len(ekf) - 1  # the first EKF sample may come from ATTITUDE
    assert len(rb["/world/ekf"]["t"]) == len(ekf)
    # the differences: the bridge's own comparison, and scipy's from the wire
    dif = rb["/difference/inclination"]
    n = summary["ekf_difference_deg"]["n"]
    assert len(dif["t"]) == n > 0.9 * len(est)
    assert np.mean(dif["Scalars:scalars"]) == pytest.approx(summary["ekf_difference_deg"]["mean"], abs=1e-3)
    t_est = np.array(sorted(est)) / 1e3
    q_est = np.array([est[k] for k in sorted(est)])
    j = np.searchsorted(t_est, dif["t"] - 1e-3)
    assert np.all(np.abs(t_est[j] - dif["t"]) < 1e-3)
    ref = _scipy_inclination_deg(q_est[j], dif["t"], ekf)
    np.testing.assert_allclose(dif["Scalars:scalars"], ref, atol=2e-3)  # float32 wire; µs vs ms stamps
    for a in ("roll", "pitch"):
        np.testing.assert_array_equal(rb[f"/difference/{a}"]["t"], dif["t"])
    droll = rb["/difference/roll"]["Scalars:scalars"]
    assert np.max(np.abs(droll)) >= np.max(dif["Scalars:scalars"]) * 0.3  # not a copy of another trace
    # TE-PINN beside PX4's EKF on this log: close, as the exit summary says
    assert 0.0 < summary["ekf_difference_deg"]["mean"] < 2.0

    # the emulator's recording: the attitude it sent, and the estimates that came back to it
    rr_ = read_rrd(tmp_path / "replay.rrd")
    assert ENTITIES <= set(rr_)
    assert _check_source(rr_, ekf, "ekf") == len(ekf) == len(rr_["/world/ekf"]["t"])
    back = _check_source(rr_, est, "tepinn", match_ms=0.5)
    assert back == len(rr_["/world/tepinn"]["t"]) >= 0.8 * len(est)  # the last ones may come after it stopped
    d2 = rr_["/difference/inclination"]["Scalars:scalars"]
    assert len(d2) >= 0.8 * len(est)
    assert np.mean(d2) == pytest.approx(np.mean(dif["Scalars:scalars"][: len(d2)]), abs=0.01)


# ---------------------------------------------------------------------------- decoding the estimate back
@pytest.mark.parametrize("kind", ESTIMATE_AS)
def test_the_estimate_is_read_back_from_any_estimate_as(kind):
    rng = np.random.default_rng(3)
    enc, ap = Encoder(1, 191), Encoder(1, 1)
    rx = M.MAVLink(None)
    dec = EstimateDecoder()
    sent, got = [], []
    for k in range(20):
        ms = 10_000 + 20 * k
        q = Rotation.random(random_state=rng).as_quat()[[3, 0, 1, 2]]
        us = ms * 1000 + 703  # the IMU sample's own µs: DEBUG_VECT carries them, the others whole ms
        msgs = estimate_msgs(ms, q, (0.0, 0.0, 0.0), kind, us)
        msgs += diagnostic_msgs(ms, us, q, sigma_rad=0.01, latency_s=0.001, imu_rate_hz=200.0,
                                bias_rad_s=(0.0, 0.0, 0.0), diff=(0.1, 0.1, 0.1, 0.1))  # fmt: skip
        frames = [enc.pack(m) for m in msgs] + [ap.pack(M.MAVLink_attitude_quaternion_message(ms, 1, 0, 0, 0, 0, 0, 0, [0] * 4))]
        for m in rx.parse_buffer(b"".join(frames)):
            r = dec.add(m)
            if r is not None:
                got.append(r)
        sent.append((ms / 1e3, q))
    assert [t for t, _ in got] == [t for t, _ in sent]  # each estimate once (TP_RPY is also a diagnostic)
    for (_, qg), (_, qs) in zip(got, sent):
        ang = (Rotation.from_quat(np.array(qg)[[1, 2, 3, 0]]).inv() * Rotation.from_quat(qs[[1, 2, 3, 0]])).magnitude()
        assert np.degrees(ang) < 1e-3


# ---------------------------------------------------------------------------- errors: one line
def _cli_without_rerun(args, env=None):
    code = ("import sys; sys.modules['rerun'] = None; from tepinn_flight.cli.main import main; "
            f"sys.exit(main({list(args)!r}))")  # fmt: skip
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, env=env)


def test_rrd_without_rerun_installed_is_one_line(tmp_path):
    log = real_log("pyulog_sample_log_small.ulg")
    r = _cli_without_rerun(["replay", str(log), "--to", "udpout:127.0.0.1:9", "--rrd", str(tmp_path / "v.rrd")])
    assert r.returncode == 2, r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and "Rerun" in lines[0] and "pip install 'tepinn-flight[view]'" in lines[0], r.stderr
    assert list(tmp_path.iterdir()) == []


def test_view_without_a_display_is_one_line_and_leaves_no_file(tmp_path):
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    r = subprocess.run([sys.executable, "-m", "tepinn_flight", "bridge", "--master", "udpin:127.0.0.1:0", "--view",
                        "--rrd", str(tmp_path / "v.rrd"), "--duration", "1"],
                       capture_output=True, text=True, timeout=120, env=env)  # fmt: skip
    assert r.returncode == 2, r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and "no display" in lines[0] and "--rrd" in lines[0], r.stderr
    assert list(tmp_path.iterdir()) == []


def test_the_readme_graph_expression_reads_the_named_value_estimate():
    """README: MAVProxy/MAVExplorer graph the default estimate with NAMED_VALUE_FLOAT['tp_roll'].value
    (pymavlink's evaluator over its per-name message store); unquoted it evaluates to nothing."""
    from pymavlink import mavutil
    from pymavlink.mavexpression import evaluate_expression

    enc, rx = Encoder(1, 191), M.MAVLink(None)
    q = Rotation.from_euler("ZYX", [30.0, -4.0, 12.5], degrees=True).as_quat()[[3, 0, 1, 2]]
    store = {}
    for m in rx.parse_buffer(b"".join(enc.pack(m) for m in estimate_msgs(1000, q, (0, 0, 0), "named_value"))):
        mavutil.add_message(store, m.get_type(), m)
    assert evaluate_expression("NAMED_VALUE_FLOAT['tp_roll'].value", store) == pytest.approx(12.5, abs=1e-4)
    assert evaluate_expression("NAMED_VALUE_FLOAT['tp_yaw'].value", store) == pytest.approx(30.0, abs=1e-4)
    assert evaluate_expression("NAMED_VALUE_FLOAT[tp_roll].value", store) is None
