"""Each compiled loop is compiled for one signature, whatever its callers pass: the offline and the
live fusion share ``_step``'s, and a record's read-only Fortran-ordered columns, C arrays, 6-D and
9-D calls give each filter one; so do the anchored VQF's kernels, offline and live, from record
columns, lists, tuples and configs holding ints, and the live accelerometer-scale reading's step. (Every extra signature is another full compile on first use —
seconds each; ``benchmarks/jit_compile.py``.) Run in a fresh process, so the dispatchers hold only
what these calls compiled."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap

import pytest

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

#: the anchored VQF's kernels called from Python (model/anchor_kernels.py; the rest are called from the compiled steps)
ANCHOR_KERNELS = ("q_nb_rows", "tilt_pull_f", "fusion_tilt_f", "fusion_tilt_rows")
#: the anchored filter's compiled steps (model/anchor_steps.py), offline and live
ANCHOR_STEPS = ("update_rows", "update_one", "correct", "run_segment", "clip_room", "pull")

_CALLS = textwrap.dedent("""
    import numpy as np
    from tepinn_flight.evaluation.estimators import FilterEstimator
    from tepinn_flight.evaluation.filters import Complementary, Ekf, Madgwick, complementary, ekf, madgwick
    from tepinn_flight.model import fusion
    from tepinn_flight.model.fusion import AttitudeFusion, FusionConfig, FusionRun
    from tepinn_flight.model.synthetic import synthetic_record
    from tepinn_flight.record import MAG_COLS

    rec = synthetic_record(seed=2, duration_s=6.0, rate_hz=100.0)
    n = len(rec)
    mag = np.tile([20.0, 0.0, 45.0], (n, 1))
    rec.data[MAG_COLS] = mag
    assert np.isfinite(rec.mag_ut).all()
    assert not rec.gyr_rad_s.flags.writeable and rec.gyr_rad_s.flags.f_contiguous  # as a record hands them out
    for cfg in (FusionConfig(), FusionConfig.uncalibrated()):
        for t, g in ((rec.t_s, rec.gyr_rad_s), (np.array(rec.t_s), np.ascontiguousarray(rec.gyr_rad_s))):
            run = FusionRun(t, g, cfg, rec.clipped)
            idx = np.arange(20, n, 16)
            run.add(idx, np.tile([1.0, 0, 0, 0], (len(idx), 1)), np.full(len(idx), 0.05), np.zeros((len(idx), 3)))
            run.advance(n)
        live = AttitudeFusion(cfg)
        for i in range(60):
            est = (rec.q_ref_wxyz[i], 0.05, np.zeros(3)) if i % 16 == 15 else None  # read-only rows, arrays
            live.step(rec.t_s[i], rec.gyr_rad_s[i], est, bool(rec.clipped[i]))
            live.step(rec.t_s[i] + 1e-4, tuple(rec.gyr_rad_s[i]), None if est is None else (tuple(est[0]), 0.05, (0, 0, 0)))
    for use_mag in (False, True):
        for f in (Complementary(), Madgwick(), Ekf()):
            FilterEstimator(f, use_mag=use_mag and f.name != "ekf").estimate(rec)
            f.estimate(np.ascontiguousarray(rec.gyr_rad_s), np.ascontiguousarray(rec.acc_m_s2), rec.t_s,
                       mag if use_mag else None)
    import dataclasses
    from tepinn_flight.model import anchor_kernels as ak
    from tepinn_flight.model import anchor_steps as st
    from tepinn_flight.model.anchor import AnchorConfig, AnchoredVQF, WindowOutput, q_nb_from_vqf, tilt_pull_quat, window_rows

    every_gate = dataclasses.replace(AnchorConfig(), speed_lo_m_s=0.0, speed_hi_m_s=1e-3)  # centripetal, pulls
    for cfg in (every_gate, AnchorConfig(sigma_acc_gain=1, pull_gain=1, bias_gate_weight=1)):  # ints in the config
        for use_mag in (False, True):
            f = AnchoredVQF(cfg, 0.01, use_mag)
            f.update(rec.t_s[:50], rec.gyr_rad_s[:50], rec.acc_m_s2[:50], rec.mag_ut[:50], rec.clipped[:50])
            f.correct(WindowOutput(rec.q_ref_wxyz[50], 0.05, np.zeros(3), np.array([30.0, 0, 0]), np.zeros(3),
                                   np.array([0.1, 0.0, 0.0])))  # fmt: skip
            f.update([rec.t_s[50]], [list(rec.gyr_rad_s[50])], [tuple(rec.acc_m_s2[50])])  # lists
            f.update(rec.t_s[51], rec.gyr_rad_s[51], rec.acc_m_s2[51])  # one row, read-only
            f.update_one(rec.t_s[52], rec.gyr_rad_s[52], rec.acc_m_s2[52], rec.mag_ut[52], True)
            f.correct(WindowOutput((1, 0, 0, 0), 0.05, [0, 0, 0], (40, 0, 0), [0, 1, 0], None))  # tuples, lists
            g = np.array(rec.gyr_rad_s[53:60])
            g[2] = np.nan  # a hole
            f.update(rec.t_s[53:60], g, np.ascontiguousarray(rec.acc_m_s2[53:60]))
            f.pull((1, 0, 0, 0))
            ends = np.arange(15, n, 16)  # a whole segment from a record's columns, windows with and without a fusion bias
            for fb in (None, np.zeros((len(ends), 3))):
                wins = window_rows(rec.q_ref_wxyz[ends], np.full(len(ends), 0.05, np.float32), np.zeros((len(ends), 3)),
                                   np.zeros((len(ends), 3)), np.zeros((len(ends), 3)), fb, np.zeros(len(ends), bool),
                                   np.zeros(len(ends), bool))  # fmt: skip
                AnchoredVQF(cfg, 0.01, use_mag).run_windows(rec.t_s, rec.gyr_rad_s, rec.acc_m_s2, rec.mag_ut, rec.clipped,
                                                            ends, wins)  # fmt: skip
                AnchoredVQF(cfg, 0.01, use_mag).run_windows(list(rec.t_s), rec.gyr_rad_s, rec.acc_m_s2, None, None,
                                                            list(ends), wins.tolist())  # fmt: skip
    q_nb_from_vqf(rec.q_ref_wxyz)
    q_nb_from_vqf(rec.q_ref_wxyz[0])
    tilt_pull_quat(rec.q_ref_wxyz[0], [0, 0, 1], 1)
    ak.fusion_tilt_f(*rec.q_ref_wxyz[0], *rec.q_ref_wxyz[1])  # a record's rows, and floats (the live path)
    ak.fusion_tilt_f(1.0, 0.0, 0.0, 0.0, *(float(v) for v in rec.q_ref_wxyz[1]))
    from tepinn_flight.model.anchor import with_fusion_tilt
    with_fusion_tilt(rec.q_ref_wxyz, rec.q_ref_wxyz)
    from tepinn_flight.model import window_features as wf
    from tepinn_flight.model.config import ModelConfig

    k = ModelConfig().window_tokens
    w = [np.zeros((2, k, 3)), np.tile([0.0, 0.0, -9.81], (2, k, 1)), np.full((2, k), 8), np.zeros((2, k)),
         np.full((2, k), 0.04, np.float32), None, None]  # ints, float32, no magnetometer, no clipping
    for cfg, sv in ((ModelConfig(), wf.SensorValues((0, 0, 0), ((0,) * 3,) * 3, (0, 0, 0), ((0,) * 3,) * 3, 1)),
                    (ModelConfig(use_mag=True, physics=False, centripetal=False, centripetal_rate=False),
                     wf.SensorValues.identity())):
        wf.window_features(cfg, sv, *w)
        wf.window_features(cfg, sv, *(None if a is None else np.asarray(a, np.float32)[:1] for a in w[:5]),
                           np.ones((1, k, 3)), np.zeros((1, k), np.float32))  # fmt: skip
    from tepinn_flight.model import head_physics as hp

    for cfg in (ModelConfig(), ModelConfig(physics=False, centripetal=False, centripetal_rate=False)):
        for b in (1, 2):  # the physics head after a run of the graph: its outputs and the features
            feats = wf.window_features(cfg, wf.SensorValues.identity(), *(None if a is None else np.asarray(a)[:b] for a in w))
            graph = {"q_head": np.tile(np.float32([1, 0, 0, 0]), (b, 1)), "pool": np.zeros((b, k), np.float32),
                     "vel": np.zeros((b, 3), np.float32), "acc_v": np.ones((b, 3), np.float32)}
            hp.window_attitude(cfg, graph, feats)
    from tepinn_flight.model import gyro_selfcal as gs
    from tests.test_gyro_selfcal import turns_with_rests

    turns, _ = turns_with_rests((1.0, 1.01, 0.99), n_turns=4)  # a record's read-only columns, and C arrays
    gs.self_calibrate(turns.t_s, turns.gyr_rad_s, turns.acc_m_s2, turns.segment, turns.gyr_clipped)
    gs.self_calibrate(list(turns.t_s), np.ascontiguousarray(turns.gyr_rad_s, np.float32), turns.acc_m_s2.tolist())
    from tepinn_flight.model import gnss_aid as ga
    from tepinn_flight.model import gnss_aid_kernels as gk

    n = 300  # the aid on a record's read-only Fortran columns, on C arrays, float32 and lists, real and complex sums
    t = np.arange(n) / 50.0
    acc = np.asfortranarray(np.column_stack([np.sin(t), np.cos(t), np.full(n, -9.81)]))
    acc.flags.writeable = False
    vel = np.column_stack([-np.cos(t), np.sin(t)])
    for q in (np.tile([1.0, 0, 0, 0], (n, 1)), np.tile(np.float32([1, 0, 0, 0]), (n, 1))):
        ga.motion_acc_body(t, q, acc, vel, ga.GnssAidConfig())
    ga.motion_acc_body(t, np.tile([1.0, 0, 0, 0], (n, 1)).tolist(), acc.tolist(), vel, ga.GnssAidConfig())
    ga._centred_mean(np.exp(1j * t), 7)
    ga._centred_mean(np.float32(t), np.int32(5))
    from tepinn_flight.model import accel_scale_kernels as ask
    from tepinn_flight.model.accel_scale import AccelScaleTracker

    tr = AccelScaleTracker()  # the live accelerometer-scale reading: ints, tuples, read-only rows, float32, lists
    tr.update(0, (0, 0, 0), (0, 0, -10))
    tr.update(np.float64(0.01), rec.gyr_rad_s[0], rec.acc_m_s2[0])
    tr.update(0.02, [0.0, 0.0, 0.0], np.array([0, 0, -9.81], np.float32))
    from tepinn_flight.model.accel_scale import quiet_samples  # the offline reading: a record's columns, rows, float32
    quiet_samples(rec.t_s, rec.gyr_rad_s, rec.acc_m_s2)
    quiet_samples(rec.t_s, np.ascontiguousarray(rec.gyr_rad_s), rec.acc_m_s2.astype(np.float32))
    for name, d in (("ask.track_step", ask.track_step), ("ask.quiet_rows", ask.quiet_rows), ("fusion._run", fusion._run), ("fusion._step", fusion._step), ("fusion._step_live", fusion._step_live), ("wf._features", wf._features),
                    ("hp._attitude", hp._attitude), ("gs.attitude_at", gs.attitude_at), ("gk.window_sums", gk.window_sums),
                    ("gk.rotate_rows", gk.rotate_rows),
                    ("complementary._run", complementary._run), ("madgwick._run", madgwick._run),
                    ("ekf._loop", ekf._loop)) + tuple((f"ak.{k}", getattr(ak, k)) for k in ANCHOR_KERNELS) + tuple(
                        (f"st.{k}", getattr(st, k)) for k in ANCHOR_STEPS):
        print(name, len(d.signatures))
""").replace("ANCHOR_KERNELS", repr(ANCHOR_KERNELS)).replace("ANCHOR_STEPS", repr(ANCHOR_STEPS))


@pytest.mark.slow
def test_every_loop_is_compiled_for_one_signature(tmp_path):
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "cache"), "PYTHONPATH": REPO}
    env.pop("NUMBA_DISABLE_JIT", None)
    p = subprocess.run([sys.executable, "-c", _CALLS], capture_output=True, text=True, env=env, cwd=REPO, timeout=600)
    assert p.returncode == 0, p.stderr
    counts = dict(line.split() for line in p.stdout.splitlines())
    assert counts == {k: "1" for k in ("ask.track_step", "ask.quiet_rows", "fusion._run", "fusion._step", "fusion._step_live", "wf._features", "hp._attitude", "gs.attitude_at", "complementary._run", "madgwick._run",
                                       "ekf._loop", "gk.window_sums", "gk.rotate_rows")
                      + tuple(f"ak.{k}" for k in ANCHOR_KERNELS) + tuple(f"st.{k}" for k in ANCHOR_STEPS)}, p.stdout  # fmt: skip
