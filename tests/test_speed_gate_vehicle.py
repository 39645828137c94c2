"""Rule 24 (session 32): the flight-speed gate stays shut on a record whose log names a vehicle of a class in
``AnchorConfig.speed_gate_shut_for`` (multirotors and hand-held IMUs in the shipped model) — offline from the
record's ``vehicle_type``, live from the vehicle the bridge learns from the autopilot's heartbeat; and the class of
each vehicle name the readers write."""

from __future__ import annotations

import dataclasses
import math
import os

import numpy as np
import pytest

from tepinn_flight.errors import ConfigError
from tepinn_flight.model.anchor import AnchorConfig, AnchoredVQF, WindowOutput
from tepinn_flight.model.checkpoint import ANCHOR_CONFIG_BEFORE, anchor_config_from, default_model_path, load_model
from tepinn_flight.model.estimate import estimate_anchored
from tepinn_flight.model.streaming import StreamingEstimator
from tepinn_flight.model.synthetic import synthetic_record
from tepinn_flight.record import FlightRecord
from tepinn_flight.vehicle_class import FIXED_WING, HANDHELD, MULTIROTOR, OTHER, UNKNOWN, mav_type_suffix, vehicle_class

Q = ["q_est_w", "q_est_x", "q_est_y", "q_est_z"]


@pytest.mark.parametrize("name, cls", [
    # what the readers write (the shared logs, our simulations, BROAD) and the live heartbeat's MAV_TYPE names
    ("copter", MULTIROTOR), ("quadrotor", MULTIROTOR), ("hexarotor", MULTIROTOR), ("octorotor", MULTIROTOR),
    ("multirotor", MULTIROTOR), ("QUADROTOR", MULTIROTOR), ("plane", FIXED_WING), ("fixed-wing", FIXED_WING),
    ("fixed_wing", FIXED_WING), ("fixedwing", FIXED_WING), ("quad", MULTIROTOR), ("handheld-imu", HANDHELD), ("vtol-fixedrotor", OTHER), ("vtol_tailsitter", OTHER),
    ("helicopter", OTHER), ("submarine", OTHER), ("sub", OTHER), ("surface_boat", OTHER), ("rover", OTHER),
    (None, UNKNOWN), ("", UNKNOWN), ("unknown", UNKNOWN), ("generic", UNKNOWN), ("synthetic", UNKNOWN),
    ("mav_type_99", UNKNOWN), ("mav-type-99", UNKNOWN), ("99", UNKNOWN),
    # a class's own name is itself
    (MULTIROTOR, MULTIROTOR), (FIXED_WING, FIXED_WING), (HANDHELD, HANDHELD), (OTHER, OTHER), (UNKNOWN, UNKNOWN),
])  # fmt: skip
def test_the_class_of_each_vehicle_name(name, cls):
    assert vehicle_class(name) == cls


def test_a_record_replayed_or_written_as_a_tlog_reads_back_as_its_class():
    """mav_type_suffix gives the heartbeat a MAV_TYPE whose name (as the tlog reader and the bridge spell it) has the
    record's class again — for every class that has one."""
    from tepinn_flight.ingest.tlog import _enum_name
    from tepinn_flight.mavlink_dialect import dialect

    m = dialect()
    for name in ("copter", "hexarotor", "multirotor", "plane", "fixed-wing", "handheld-imu", "vtol-fixedrotor", None):
        back = _enum_name("MAV_TYPE", getattr(m, "MAV_TYPE_" + mav_type_suffix(name)))
        want = vehicle_class(name)
        assert vehicle_class(back) == (want if want in (MULTIROTOR, FIXED_WING) else UNKNOWN), (name, back)


def test_the_setting_names_classes_and_old_checkpoints_open_the_gate_on_any_vehicle():
    assert AnchorConfig().speed_gate_shut_for == (MULTIROTOR, HANDHELD)
    assert AnchorConfig(speed_gate_shut_for=["multirotor"]).speed_gate_shut_for == ("multirotor",)  # a checkpoint's list
    with pytest.raises(ConfigError, match="speed_gate_shut_for"):
        AnchorConfig(speed_gate_shut_for=("quadrotor",))  # a vehicle name, not a class
    assert ANCHOR_CONFIG_BEFORE["speed_gate_shut_for"] == ()
    raw = {k: v for k, v in dataclasses.asdict(AnchorConfig()).items() if k not in ("fusion_config", "speed_gate_shut_for")}
    assert anchor_config_from({"anchor_config": raw}).speed_gate_shut_for == ()
    _, shipped, _ = load_model(default_model_path())
    assert shipped.speed_gate_shut_for == (MULTIROTOR, HANDHELD)


def _window(speed_m_s: float) -> WindowOutput:
    return WindowOutput(np.array([1.0, 0.0, 0.0, 0.0]), 0.01, np.zeros(3), np.array([speed_m_s, 0.0, 0.0]), np.zeros(3))


@pytest.mark.parametrize("vehicle, shut_for, opens", [
    ("quadrotor", (MULTIROTOR, HANDHELD), False), ("handheld-imu", (MULTIROTOR, HANDHELD), False),
    ("plane", (MULTIROTOR, HANDHELD), True), (None, (MULTIROTOR, HANDHELD), True),
    ("vtol-fixedrotor", (MULTIROTOR, HANDHELD), True), ("quadrotor", (), True),
])  # fmt: skip
def test_the_flight_speed_gate_at_30_m_s_by_vehicle(vehicle, shut_for, opens):
    cfg = dataclasses.replace(AnchorConfig(), speed_gate_shut_for=shut_for)
    flt = AnchoredVQF(cfg, 0.01, vehicle=vehicle)
    flt.update(np.arange(20) * 0.01, np.zeros((20, 3)), np.tile([0.0, 0.0, -9.81], (20, 1)))
    flt.correct(_window(30.0))
    assert flt.gate_parts[0] == (1.0 if opens else 0.0)
    assert flt.gate == (1.0 if opens else 0.0)


def _with_vehicle(rec: FlightRecord, vehicle: str) -> FlightRecord:
    return FlightRecord(rec.data, {**rec.meta, "vehicle_type": vehicle})


def test_offline_and_live_keep_the_gate_shut_for_a_multirotor_log():
    """With the flight-speed gate forced open on every window (its threshold at 0), a record named a quadrotor is
    estimated as with that gate out of reach, live (told the vehicle) as offline; named a plane, the gate acts."""
    model, settings, _ = load_model(default_model_path())
    every = dataclasses.replace(settings, speed_lo_m_s=0.0, speed_hi_m_s=1e-3)
    never = dataclasses.replace(settings, speed_lo_m_s=1e9, speed_hi_m_s=2e9)
    rec = synthetic_record(seed=3, duration_s=8.0, rate_hz=100.0)
    quad, plane = _with_vehicle(rec, "quadrotor"), _with_vehicle(rec, "plane")
    est_quad = estimate_anchored(model, quad, every)
    q_quad = est_quad[Q].to_numpy()
    assert est_quad.attrs["speed_gate"] == "flight-speed gate: not used on a multirotor log (it names a quadrotor)"
    np.testing.assert_array_equal(q_quad, estimate_anchored(model, quad, never)[Q].to_numpy())
    est_plane = estimate_anchored(model, plane, every)
    q_plane = est_plane[Q].to_numpy()
    assert "speed_gate" not in est_plane.attrs
    assert np.nanmax(np.abs(q_plane - q_quad)) > 1e-3  # the gate acted on the plane
    every = dataclasses.replace(every, smoother=False)  # live: nothing smoothed (the offline-only step)
    q_quad = estimate_anchored(model, quad, every)[Q].to_numpy()
    for told_late in (False, True):  # the vehicle known from the start, or told before the first window
        live = StreamingEstimator(model, every, vehicle=None if told_late else "quadrotor")
        q_live = np.full((len(rec), 4), np.nan)
        for i in range(len(rec)):
            if told_late and i == 60:
                live.set_vehicle("quadrotor")
            e = live.push(rec.t_s[i], rec.gyr_rad_s[i], rec.acc_m_s2[i])
            if e.q_nb_wxyz is not None:
                q_live[i] = e.q_nb_wxyz
        have = np.all(np.isfinite(q_live), 1)
        assert have.sum() > len(rec) - 60
        np.testing.assert_allclose(q_live[have], q_quad[have], atol=1e-6)


def test_the_worker_tells_the_estimator_what_the_vehicle_is():
    """The bridge's vehicle record (its heartbeat's MAV_TYPE name) reaches the worker's estimator as its class."""
    from tepinn_flight.live.worker import pack_sample, vehicle_record, worker_loop

    class Est:
        def __init__(self):
            self.told = []

        def set_vehicle(self, v):
            self.told.append(v)

        def push(self, *a):
            raise AssertionError("no sample was sent")

        def reset(self, sensor=False):
            pass

    est = Est()
    r_in, w_in = os.pipe()
    r_out, w_out = os.pipe()
    os.write(w_in, vehicle_record("quadrotor") + vehicle_record(None) + vehicle_record("fixed_wing"))
    os.close(w_in)
    import tepinn_flight.live.worker as worker

    warm, worker.warm_up = worker.warm_up, lambda e: None
    try:
        assert worker_loop(r_in, w_out, lambda: est) == 0
    finally:
        worker.warm_up = warm
        for fd in (r_in, r_out, w_out):
            os.close(fd)
    assert est.told == [MULTIROTOR, UNKNOWN, FIXED_WING]
    assert len(pack_sample(1, 0.0, 0.0, (0, 0, 0), (0, 0, 0), None, 0, None)) == len(vehicle_record("plane"))


@pytest.mark.parametrize("vehicle, cls", [("multirotor", MULTIROTOR), ("fixed-wing", FIXED_WING)])
def test_the_bridge_tells_its_estimator_the_vehicle_the_heartbeat_names_before_any_sample(vehicle, cls):
    """A record replayed as a vehicle (its heartbeat's MAV_TYPE from the record's vehicle_type) through the bridge:
    the estimator learns the vehicle's class before its first sample, once."""
    import time

    from tepinn_flight.live.replay import record_stream
    from tepinn_flight.model.fusion import FusionConfig
    from tests.test_bridge import FakeAutopilot, UdpListener, _bridge, _finish, _small_model

    calls = []

    class Told(StreamingEstimator):
        def set_vehicle(self, v):
            calls.append((v, self.t_prev))  # t_prev None: no sample pushed yet
            super().set_vehicle(v)

    rec = synthetic_record(seed=4, duration_s=1.5, rate_hz=200.0)
    rec = FlightRecord(rec.data, {**rec.meta, "vehicle_type": vehicle})
    gcs = UdpListener()
    b, stop, th, box = _bridge(gcs.port, make_estimator=lambda: Told(_small_model(), FusionConfig()), min_imu_rate_hz=0)
    ap = FakeAutopilot(b.master.local_port())
    try:
        ap.play(list(record_stream(rec)), time.monotonic())
        time.sleep(0.5)
    finally:
        s = _finish(stop, th, box)
        gcs.close()
        ap.close()
    assert s["imu"]["samples"] > 200
    assert calls == [(cls, None)]


def test_info_says_what_the_estimator_does_with_the_vehicle_a_log_names():
    from tepinn_flight.cli.summary import render_info

    line = lambda v: next(x for x in render_info("log", {"vehicle_type": v}).splitlines() if x.strip().startswith("vehicle"))  # noqa: E731
    assert line("copter").endswith("copter (class multirotor: TE-PINN's flight-speed gate stays shut)")
    assert line("handheld-imu").endswith("(class handheld: TE-PINN's flight-speed gate stays shut, its uncalibrated-gyro "
                                         "gate opens only on VQF's own bias estimate and takes the network's bias out of "
                                         "the gyro without pulling the tilt)")  # (rules 31, 33)
    assert line("fixed_wing").endswith("(class fixed-wing: TE-PINN's flight-speed gate may open)")
    assert line(None).endswith("unknown (not named: TE-PINN's gates as for any vehicle)")


@pytest.mark.parametrize("needs_gate", [True, False])
def test_speed_makes_a_block_busy_only_where_the_flight_speed_gate_may_open(needs_gate):
    """Rule 26: |v̂| over the quiet threshold makes a block busy only where the flight-speed gate may open for the
    vehicle (without the rule, on any vehicle); a segment's first blocks and the older fusion's bias still do."""
    cfg = dataclasses.replace(AnchorConfig(), quiet_speed_needs_gate=needs_gate)
    late, fast, slow, calm, biased = cfg.quiet_after_blocks, 30.0, 1.0, np.zeros(3), np.radians([0.0, 3.0, 0.0])
    assert cfg.block_busy(late, fast, calm, speed_gate=True)
    assert cfg.block_busy(late, fast, calm, speed_gate=False) is not needs_gate
    assert not cfg.block_busy(late, slow, calm, speed_gate=True)
    assert cfg.block_busy(late - 1, slow, calm, speed_gate=False)  # the start-up
    assert cfg.block_busy(late, slow, biased, speed_gate=False)  # the uncalibrated-gyro gate may open



def test_a_block_s_bias_test_is_numpy_s_max_of_the_absolute_bias():
    """:meth:`AnchorConfig.block_busy`'s bias test on three Python floats equals numpy's ``max(abs(b)) >= threshold``
    (its former form) for tuples and arrays, at the threshold, with NaN (numpy's max: NaN, not busy) and inf; and
    :meth:`AnchorConfig.reads_speed` says where a speed is read at all."""
    cfg = AnchorConfig()
    late, thr = cfg.quiet_after_blocks, math.radians(cfg.quiet_bias_deg_s)
    rng = np.random.default_rng(0)
    cases = [rng.normal(0, thr, 3) for _ in range(200)]
    cases += [np.array([thr, 0.0, 0.0]), np.array([0.0, -thr, 0.0]), np.array([np.nextafter(thr, 0), 0, 0]),
              np.array([np.nan, 1.0, 0.0]), np.array([1.0, np.nan, 0.0]), np.array([0.0, 0.0, -np.inf])]
    for b in cases:
        expect = bool(np.max(np.abs(b)) >= thr)
        assert cfg.block_busy(late, 0.0, tuple(b.tolist()), speed_gate=False) is expect, b
        assert cfg.block_busy(late, 0.0, b, speed_gate=True) is expect, b
    assert sum(bool(np.max(np.abs(b)) >= thr) for b in cases) > 20  # both outcomes are exercised
    assert cfg.reads_speed(True) and not cfg.reads_speed(False)
    assert dataclasses.replace(cfg, quiet_speed_needs_gate=False).reads_speed(False)

def test_shipped_model_and_old_checkpoints_on_speed_and_busy_blocks():
    assert ANCHOR_CONFIG_BEFORE["quiet_speed_needs_gate"] is False
    raw = {k: v for k, v in dataclasses.asdict(AnchorConfig()).items() if k not in ("fusion_config", "quiet_speed_needs_gate")}
    assert anchor_config_from({"anchor_config": raw}).quiet_speed_needs_gate is False
    _, shipped, _ = load_model(default_model_path())
    assert shipped.quiet_speed_needs_gate is True


def test_a_fast_multirotor_log_runs_fewer_windows_and_live_runs_the_same_ones_as_offline():
    """A fixed-wing flight (the network reads 15 m/s and more on most blocks) named a quadrotor: offline, the blocks
    busy by |v̂| alone go quiet (far fewer windows than named a plane, or than without rule 26); live, told the
    vehicle, runs exactly those windows and gives the offline estimate."""
    from tepinn_flight.model.estimate import anchored_windows
    from tepinn_flight.sim.simulate import simulate_record

    from .live_run import live_run

    model, settings, _ = load_model(default_model_path())
    cfg = dataclasses.replace(settings, smoother=False, gnss_aid=False, quiet_speed_needs_gate=True)  # live: causal
    rec = simulate_record("c172x", 40.0, 100.0, seed=3)
    quad, plane = _with_vehicle(rec, "quadrotor"), _with_vehicle(rec, "plane")
    idx_quad, _ = anchored_windows(model, quad, fusion=cfg.fusion_config, anchor=cfg)
    idx_plane, _ = anchored_windows(model, plane, fusion=cfg.fusion_config, anchor=cfg)
    before = dataclasses.replace(cfg, quiet_speed_needs_gate=False)
    idx_before, _ = anchored_windows(model, quad, fusion=cfg.fusion_config, anchor=before)
    np.testing.assert_array_equal(idx_before, idx_plane)
    assert len(idx_quad) < 0.5 * len(idx_plane)
    assert np.isin(idx_quad, idx_plane).all()
    off = estimate_anchored(model, quad, cfg)[Q].to_numpy()
    q_live, ran = live_run(model, cfg, quad, vehicle="quadrotor")
    np.testing.assert_array_equal(ran, idx_quad)
    have = np.all(np.isfinite(q_live), 1)
    assert have.sum() > len(rec) - 60
    np.testing.assert_allclose(q_live[have], off[have], atol=1e-6)
