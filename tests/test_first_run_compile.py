"""The first run after installing, on a cold numba cache, checked in one fresh process (each full compile is ~40 s
of a core here, so the checks share one). Where this checkout's cache is empty as the tests start (a fresh clone:
CI), that process is the test session's warm-up (``tests/conftest.py``) on the checkout's own cache, its output kept
for the test — CI's one cold compile instead of two; otherwise the test runs it with a ``NUMBA_CACHE_DIR`` of its
own, read by numba at import, so the cache state is known either way:

- the notice: a cold ``estimate`` says once that it compiles, a warm one nothing; with only the anchored filter's
  steps missing from the cache (the helper process's share) it is said once without ``-q`` and not with it
  (``tepinn_flight/jit_notice.py``);
- the warm-up (``tepinn_flight/jit_warmup.py``): the helper process compiles the anchored filter's steps and its
  VQF, the command's process the fusion's and the estimator's other loops, and afterwards an offline estimate (GNSS
  aid, a clipped gyro, rests, a magnetometer) and the live estimator compile nothing; on a warm cache it does
  nothing;
- one signature per loop, whatever its callers pass: the offline and the live fusion share ``_step``'s, and a
  record's read-only Fortran-ordered columns, C arrays, 6-D and 9-D calls give each filter one; so do the anchored
  VQF's kernels, offline and live, from record columns, lists, tuples and configs holding ints, and the live
  accelerometer-scale reading's step (every extra signature is another full compile on first use: seconds each;
  ``benchmarks/jit_compile.py``). The fusion's loops are compiled in this process (the warm-up's own share), so a
  kernel only its compiled callers call (``fusion._step``) shows every signature compiled for it; the anchored
  filter's steps and kernels, compiled by the helper, are each called from Python and so counted as they load."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import textwrap
from types import SimpleNamespace

import numpy as np
import pytest

from tepinn_flight.jit_notice import COMPILE_NOTICE

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

#: the anchored VQF's kernels called from Python (model/anchor_kernels.py; the rest are called from the compiled steps)
ANCHOR_KERNELS = ("q_nb_rows", "tilt_pull_f", "fusion_tilt_f", "fusion_tilt_rows")
#: the anchored filter's compiled steps (model/anchor_steps.py), offline and live
ANCHOR_STEPS = ("update_rows", "update_one", "correct", "run_segment", "clip_room", "pull")
#: every loop whose signatures are counted (``name`` as the script prints it)
COUNTED = ("ask.track_step", "ask.quiet_rows", "fusion._run", "fusion._step", "fusion._step_live", "wf._features",
           "hp._attitude", "gs.attitude_at", "complementary._run", "madgwick._run", "ekf._loop", "gk.window_sums",
           "gk.rotate_rows") + tuple(f"ak.{k}" for k in ANCHOR_KERNELS) + tuple(f"st.{k}" for k in ANCHOR_STEPS)

#: the cold estimate of a flight (not quiet: the notice), with the warm-up's own compiles recorded apart; then an
#: estimate of the turns and the live estimator on them, which must compile nothing; then the warm-up on a warm cache
_FIRST_RUN = """
    import sys
    from numba.core import event
    from tepinn_flight import jit_warmup
    from tepinn_flight.ingest import load_record

    names = []

    class Compiles(event.Listener):
        def on_start(self, ev):
            f = ev.data["dispatcher"].py_func
            if f.__module__.startswith("tepinn_flight."):
                names.append(f.__module__ + "." + f.__qualname__)

        def on_end(self, ev):
            pass

    warm_up = jit_warmup.warm_up

    def recorded_warm_up(*args, **kwargs):  # what the estimate's warm-up compiled in this process, apart
        ran = warm_up(*args, **kwargs)
        print("@@ ran", ran)
        print("@@ here", " ".join(sorted(set(names))))
        names.clear()
        return ran

    jit_warmup.warm_up = recorded_warm_up
    flight, turns = sys.argv[1:3]
    with event.install_listener("numba:compile", Compiles()):
        print("@@ cold", jit_warmup.cold())
        from tepinn_flight.cli.main import main

        assert main(["estimate", flight, "-o", flight + ".est.parquet"]) == 0
        print("@@ cold", jit_warmup.cold())
        print("@@ notice", file=sys.stderr)  # the notices before this line are the cold estimate's
        assert main(["estimate", turns, "-o", turns + ".est.parquet"]) == 0
        from tepinn_flight.model.runtime import default_onnx_path, load_runner
        from tepinn_flight.model.streaming import StreamingEstimator

        runner, settings, _ = load_runner(default_onnx_path(), "onnx")
        rec = load_record(turns)
        live = StreamingEstimator(runner, settings, threads=1)
        mag = rec.mag_ut
        for i in range(len(rec)):
            live.push(rec.t_s[i], rec.gyr_rad_s[i], rec.acc_m_s2[i], mag[i], bool(rec.clipped[i]), bool(rec.gyr_clipped[i]))
        print("@@ after", " ".join(sorted(set(names))))
        print("@@ ran", warm_up())
"""

#: the same loops called as every caller does (after the estimates above, in the same process)
_CALLS = """
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
        print("@@ sig", name, len(d.signatures))
"""

_SCRIPT = (textwrap.dedent(_FIRST_RUN) + textwrap.dedent(_CALLS)).replace("ANCHOR_KERNELS", repr(ANCHOR_KERNELS)).replace(
    "ANCHOR_STEPS", repr(ANCHOR_STEPS))


def _env(cache) -> dict:
    """The environment of a first run: numba's cache in ``cache`` (None: numba's own, beside the sources)."""
    env = {**os.environ, "PYTHONPATH": REPO}
    env.pop("NUMBA_DISABLE_JIT", None)
    env.pop("NUMBA_CACHE_DIR", None)
    if cache is not None:
        env["NUMBA_CACHE_DIR"] = str(cache)
    return env


def first_run(folder, cache=None) -> dict:
    """The first run's script on its two records (written into ``folder``), numba's cache in ``cache`` (None: this
    checkout's own, which must then be empty: a fresh clone) → its exit status, output, the records' paths and the
    cache's folder. conftest runs it as the test session's warm-up where this checkout's cache is empty (CI's clean
    clone: the one cold compile serves both), else the test runs it on a cache of its own."""
    from tepinn_flight.record import MAG_COLS, write_record
    from tepinn_flight.sim.simulate import simulate_record
    from tests.test_gyro_selfcal import turns_with_rests

    flight = simulate_record("F450", 12.0, rate_hz=200.0, seed=2)  # a receiver: the GNSS aid
    assert flight.gnss_vel_ne_m_s is not None
    turns, _ = turns_with_rests(clipped_turn=6, n_turns=8)  # rests (the self-calibration), a clipped gyro
    turns.data[MAG_COLS] = np.tile([20.0, 0.0, 45.0], (len(turns), 1))  # 9-D
    paths = [os.path.join(folder, "flight.parquet"), os.path.join(folder, "turns.parquet")]
    write_record(flight, paths[0])
    write_record(turns, paths[1])
    p = subprocess.run([sys.executable, "-c", _SCRIPT, *paths], capture_output=True, text=True, env=_env(cache),
                       cwd=REPO, timeout=900)  # fmt: skip
    return {"returncode": p.returncode, "stdout": p.stdout, "stderr": p.stderr, "paths": paths,
            "cache": None if cache is None else str(cache)}  # fmt: skip


def in_tree_cache_copy(dst) -> None:
    """This checkout's numba cache (``__pycache__`` beside each source) copied into ``dst`` laid out as numba lays out
    a ``NUMBA_CACHE_DIR`` (its own rule for a source folder's place there)."""
    from numba.core.caching import _CacheLocator

    pkg = os.path.join(REPO, "tepinn_flight")
    for folder, _, files in os.walk(pkg):
        if os.path.basename(folder) != "__pycache__":
            continue
        src_dir = os.path.dirname(folder)
        place = os.path.join(dst, _CacheLocator.get_suitable_cache_subpath(os.path.join(src_dir, "x.py")))
        for f in files:
            if f.endswith((".nbi", ".nbc")):
                os.makedirs(place, exist_ok=True)
                shutil.copy2(os.path.join(folder, f), place)


@pytest.mark.slow
def test_the_first_run_compiles_each_loop_once_in_two_processes_and_says_so_once(tmp_path, first_run_of_session):
    """(The first run is the session's warm-up where this checkout's cache was empty; else run here on a cache of its
    own.)"""
    pytest.importorskip("torch")
    pytest.importorskip("onnxruntime")
    run = first_run_of_session or first_run(tmp_path, tmp_path / "cache")
    p = SimpleNamespace(returncode=run["returncode"], stdout=run["stdout"], stderr=run["stderr"])
    paths = run["paths"]
    assert p.returncode == 0, p.stderr
    said = [ln[3:].split(" ", 1) for ln in p.stdout.splitlines() if ln.startswith("@@ ")]
    said = [(k, v[0] if v else "") for k, *v in said]
    keys = [k for k, _ in said]
    # each estimate's warm-up records what this process compiled until it ended: the first the whole of its share, the
    # second (the turns') what the rest of the flight's estimate compiled after the warm-up: nothing
    assert keys.count("sig") == len(COUNTED) and keys[:8] == ["cold", "ran", "here", "cold", "ran", "here", "after",
                                                              "ran"], p.stdout  # fmt: skip
    assert [v for k, v in said if k == "cold"] == ["True", "False"], p.stdout
    assert [v for k, v in said if k == "ran"] == ["True", "False", "False"], p.stdout  # warm: nothing started
    got = dict(said[6:7])
    here = set(said[2][1].split())
    assert said[5][1] == "", f"the flight's estimate compiled after the warm-up: {said[5][1]}"
    assert {"tepinn_flight.model.fusion._run", "tepinn_flight.model.fusion._step", "tepinn_flight.model.fusion._step_live",
            "tepinn_flight.model.window_features._features", "tepinn_flight.model.gnss_aid_kernels.window_sums",
            "tepinn_flight.model.gyro_selfcal.attitude_at"} <= here, said[2][1]  # (this process's share)
    # the helper's share was compiled there, not here
    helper_only = {"tepinn_flight.model.anchor_steps.run_segment", "tepinn_flight.model.anchor_steps.update_one",
                   "tepinn_flight.model.anchor_steps.correct", "tepinn_flight.model.vqf_kernel.update"}
    assert not here & helper_only, said[2][1]
    assert got["after"] == "", f"compiled after the warm-up: {got['after']}"
    # the notice: said once by the cold estimate (the first stage of stderr), not by the warm one
    cold_err, warm_err = p.stderr.split("@@ notice\n")
    assert [ln for ln in cold_err.splitlines() if COMPILE_NOTICE in ln] == [
        f"tepinn-flight estimate: note: {COMPILE_NOTICE}"], p.stderr  # fmt: skip
    assert COMPILE_NOTICE not in warm_err, p.stderr
    # one signature per loop
    counts = {name: n for k, v in said if k == "sig" for name, n in [v.split()]}
    assert counts == {k: "1" for k in COUNTED}, p.stdout
    # the warm cache less one of the anchored filter's steps (the helper's share): only it compiles (seconds, not the
    # whole set) — said once without -q, and not at all with it (and compiled all the same: cached again)
    args = ["estimate", str(paths[0]), "-o", str(tmp_path / "e.parquet")]
    for name, extra in (("part", []), ("quiet", ["-q"])):
        part = tmp_path / name
        if run["cache"]:
            shutil.copytree(run["cache"], part)
        else:  # the first run filled this checkout's own cache
            in_tree_cache_copy(part)
        gone = sorted(f.name for f in part.rglob("anchor_steps.update_one-*"))
        assert gone, sorted(f.name for f in part.rglob("*"))
        for f in part.rglob("anchor_steps.update_one-*"):
            f.unlink()
        before = {f.name for f in part.rglob("*.nbi")}
        q = subprocess.run([sys.executable, "-m", "tepinn_flight", *args, *extra], capture_output=True, text=True,
                           env=_env(part), cwd=REPO, timeout=600)  # fmt: skip
        assert q.returncode == 0, q.stderr
        if extra:
            assert q.stderr == "", q.stderr
        else:
            assert [ln for ln in q.stderr.splitlines() if COMPILE_NOTICE in ln] == [
                f"tepinn-flight estimate: note: {COMPILE_NOTICE}"], q.stderr  # fmt: skip
        assert sorted(f.name for f in part.rglob("anchor_steps.update_one-*")) == gone
        # and nothing else was compiled: every other loop was loaded from the cache
        assert {f.name for f in part.rglob("*.nbi")} - before == {g for g in gone if g.endswith(".nbi")}
