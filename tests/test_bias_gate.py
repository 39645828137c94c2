"""The uncalibrated-gyro gate's evidence from the older fusion counts only where VQF's own bias
estimate agrees (``AnchorConfig.bias_gate_vqf_deg_s``, session 16): out of its domain — a record
that starts mid-motion — the older fusion's bias passes its 3 °/s within seconds while a calibrated
gyro's VQF bias stays near zero."""

from __future__ import annotations

import copy
import dataclasses
import math

import numpy as np
import pytest

from tepinn_flight.model.anchor import AnchorConfig, AnchoredVQF, WindowOutput
from tests.conftest import broad_trial

LEVEL = np.array([1.0, 0.0, 0.0, 0.0])


def _latched(cfg: AnchorConfig, gyro_bias_deg_s: float, fusion_bias_deg_s: float, seconds: float = 30.0,
             acc=(0.0, 0.0, -9.81)) -> bool:  # fmt: skip
    """An IMU at rest (level, or as ``acc`` says; gyro reading ``gyro_bias_deg_s`` on x) for ``seconds``
    at 100 Hz, a window every 0.1 s whose older-fusion bias is ``fusion_bias_deg_s`` on x (horizontal)
    → the gate latched?"""
    ts = 0.01
    f = AnchoredVQF(cfg, ts)
    gyr = np.array([math.radians(gyro_bias_deg_s), 0.0, 0.0])
    acc = np.asarray(acc, float)
    fb = np.array([math.radians(fusion_bias_deg_s), 0.0, 0.0])
    for k in range(int(seconds / 0.1)):
        t = k * 0.1 + np.arange(10) * ts
        f.update(t, np.tile(gyr, (10, 1)), np.tile(acc, (10, 1)))
        f.correct(WindowOutput(LEVEL, 0.01, np.zeros(3), np.zeros(3), np.zeros(3), fb))
    return f.bias_latched


def test_the_fusions_evidence_latches_only_where_vqf_sees_a_bias_too():
    cfg = AnchorConfig()
    assert cfg.bias_gate_vqf_deg_s == 0.2 and cfg.bias_gate_fusion_deg_s == 3.0
    before = dataclasses.replace(cfg, bias_gate_vqf_deg_s=0.0)
    # a calibrated gyro, the older fusion claiming 5 °/s: latched before (its evidence alone), not now
    assert _latched(before, 0.0, 5.0)
    assert not _latched(cfg, 0.0, 5.0)
    # a gyro 1 °/s off at rest: VQF's rest bias estimate moves toward 1 °/s (past 0.2) but never to its
    # own latch (0.95 × its 2 °/s clip), so with the fusion's evidence the gate latches through this path
    assert _latched(cfg, 1.0, 5.0)
    assert not _latched(cfg, 1.0, 0.0)  # ... and not without it
    assert not _latched(dataclasses.replace(cfg, bias_gate_vqf_deg_s=1.5), 1.0, 5.0)  # VQF's 1 °/s does not reach 1.5


@pytest.mark.parametrize("tilt_deg, latched", [(0.0, True), (45.0, True), (75.0, False), (90.0, False)])
def test_the_fusions_evidence_counts_only_where_the_accelerometer_points_along_the_bodys_z(tilt_deg, latched):
    """The same 1 °/s gyro at rest, the IMU rolled by ``tilt_deg`` (its x axis stays horizontal, so the
    bias stays perpendicular to gravity): within 60° of level the fusion's evidence latches the gate;
    on its side (a hand-held IMU, out of the network's domain) it does not — and did before."""
    cfg = AnchorConfig()
    assert cfg.bias_gate_thrust_deg == 60.0
    r = math.radians(tilt_deg)
    acc = (0.0, -9.81 * math.sin(r), -9.81 * math.cos(r))  # FRD, rolled right by tilt_deg
    assert _latched(cfg, 1.0, 5.0, acc=acc) is latched
    assert _latched(dataclasses.replace(cfg, bias_gate_thrust_deg=0.0), 1.0, 5.0, acc=acc)  # before: any orientation


def test_a_real_trial_started_mid_motion_no_longer_latches_the_gate_on_the_fusions_evidence():
    """BROAD trial 08 (fast rotation; seen by the network) cut to start 40 s in, during the motion:
    the older fusion's bias passed 3 °/s within 7 s and latched the gate (session 15's estimator: over
    the per-file bound against the optical truth); now it stays VQF's. The same record with a 5 °/s gyro
    bias still latches it and stays far ahead of VQF."""
    from tepinn_flight.evaluation.peers import VqfEstimator
    from tepinn_flight.ingest import load_record
    from tepinn_flight.model.checkpoint import default_model_path, load_model
    from tepinn_flight.model.estimate import anchored_windows, estimate_anchored
    from tepinn_flight.model.finetune import inclination_rmse_deg as rmse
    from tepinn_flight.record import GYR_COLS

    rec0 = load_record(broad_trial("broad_08_*.hdf5"))
    rec = copy.copy(rec0)
    rec.data = rec0.data[rec0.t_s >= rec0.t_s[0] + 40.0].reset_index(drop=True)
    model, anchor, _ = load_model(default_model_path())
    assert anchor.bias_gate_vqf_deg_s == 0.2  # the shipped estimator asks VQF

    def scores(r):
        w = anchored_windows(model, r, 256, anchor.fusion_config, anchor)
        new, old = (rmse(r, estimate_anchored(model, r, a, windows=w))
                    for a in (anchor, dataclasses.replace(anchor, bias_gate_vqf_deg_s=0.0, bias_gate_thrust_deg=0.0)))  # fmt: skip
        return new, old, rmse(r, VqfEstimator().estimate(r))

    new, old, vqf = scores(rec)
    assert old > max(1.5 * vqf, vqf + 0.5), (old, vqf)  # the false latch (2.73° against VQF's 1.77°)
    assert new < vqf, (new, vqf)  # VQF's, with the gyro's scale read from the record (1.10°)
    biased = copy.copy(rec)
    biased.data = rec.data.copy()
    biased.data[GYR_COLS] = rec.gyr_rad_s + math.radians(5.0)
    new, old, vqf = scores(biased)
    assert new < 0.7 * vqf, (new, vqf)  # the gate latched: the network's bias beyond 2 °/s taken out (5.4° against 9.3°)
    assert new == pytest.approx(old, abs=0.3), (new, old)  # as it latched before


def test_a_checkpoint_written_before_runs_the_fusions_evidence_alone():
    from tepinn_flight.model.checkpoint import anchor_config_from

    old = {"anchor_config": {"enabled": True, "pull_target": "fusion", "bias_gate_fusion_deg_s": 3.0}, "fusion_config": None}
    assert anchor_config_from(old).bias_gate_vqf_deg_s == 0.0
    assert anchor_config_from({**old, "anchor_config": {**old["anchor_config"], "bias_gate_vqf_deg_s": 0.2}}).bias_gate_vqf_deg_s == 0.2


def test_a_real_trial_with_the_imu_on_its_side_no_longer_latches_the_gate():
    """BROAD trial 12 (slow translation; seen by the network) with the IMU mounted 90° about x (sensor
    axes and optical reference turned by scipy's Rotation): the older fusion's bias, the network out of
    its domain, latched the gate (8.75° against VQF's 0.25°); now the estimate is the upright one's."""
    from scipy.spatial.transform import Rotation

    from tepinn_flight.evaluation.peers import VqfEstimator
    from tepinn_flight.ingest import load_record
    from tepinn_flight.model.checkpoint import default_model_path, load_model
    from tepinn_flight.model.estimate import anchored_windows, estimate_anchored
    from tepinn_flight.model.finetune import inclination_rmse_deg
    from tepinn_flight.quat import quat_mul
    from tepinn_flight.record import ACC_COLS, GYR_COLS, QREF_COLS

    up = load_record(broad_trial("broad_12_*.hdf5"))
    rot = Rotation.from_euler("x", 90.0, degrees=True)  # body → mounted sensor: v_s = Rᵀ v_b
    side = copy.copy(up)
    side.data = up.data.copy()
    for cols in (ACC_COLS, GYR_COLS):
        side.data[cols] = rot.inv().apply(np.array(up.data[cols].to_numpy(), dtype=float))
    side.data[QREF_COLS] = quat_mul(np.array(up.q_ref_wxyz), np.tile(rot.as_quat(scalar_first=True), (len(up), 1)))
    model, anchor, _ = load_model(default_model_path())

    def rmse(r, a):
        return inclination_rmse_deg(r, estimate_anchored(model, r, a, windows=anchored_windows(model, r, 256, anchor.fusion_config, a)))

    vqf_rmse = inclination_rmse_deg(side, VqfEstimator().estimate(side))
    before = rmse(side, dataclasses.replace(anchor, bias_gate_thrust_deg=0.0))
    assert before > max(1.5 * vqf_rmse, vqf_rmse + 0.5), (before, vqf_rmse)
    now, upright = rmse(side, anchor), rmse(up, anchor)
    assert now == pytest.approx(upright, abs=0.02), (now, upright)  # VQF turns with its sensor; the gate stays shut
    assert now <= vqf_rmse + 0.02
