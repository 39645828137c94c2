"""The first run after an install compiles the package's loops (numba): about 25 s of one core for ``estimate`` on
the 2-core machine this was measured on (session 37), 60 % of it the older fusion (``model/fusion.py``). Where the
cache is cold, :func:`warm_up` compiles them in two processes at once — a helper process
(``python -m tepinn_flight.jit_warmup``) the anchored filter's steps and its VQF (:func:`warm_anchored`; since session
49 VQF itself is compiled, the largest share: ~12 s of a core here), this one the fusion (:func:`warm_fusion`, ~6 s)
and the estimator's other loops (:func:`warm_kernels`, ~7 s) — and then everything loads from numba's cache; where it
is warm it does nothing.

The warm calls go through the same entry points the estimator calls (each loop is compiled for one signature
whatever its callers pass: ``tests/test_first_run_compile.py``), on a few made-up samples. A loop they miss is
compiled where it is first used, as without the warm-up; the helper failing or missing its time costs the same.
``tests/test_first_run_compile.py`` checks that an estimate after the warm-up compiles nothing.
"""

from __future__ import annotations

import math
import os
import subprocess
import sys

#: the longest this process waits for the helper after its own part (a slow machine; then it goes on)
HELPER_WAIT_S = 600.0


def _dispatchers(filters: bool = False) -> list:
    """The loops whose cache state says whether the warm-up is needed (one or two per module it warms)."""
    from .model import (accel_scale_kernels, anchor_kernels, anchor_steps, fusion, gnss_aid_kernels, gyro_selfcal,
                        head_physics, streaming_kernels, tokens_kernels, window_features)

    found = [fusion._run, fusion._step, fusion._step_live, anchor_steps.run_segment, anchor_steps.update_one,
             streaming_kernels.live_sample, anchor_kernels.step_weights,
             anchor_kernels.blend_tilt_rows, window_features._features, head_physics._attitude,
             gnss_aid_kernels.window_sums,
             gyro_selfcal.attitude_at, accel_scale_kernels.track_step, accel_scale_kernels.quiet_rows,
             tokens_kernels.token_means]  # fmt: skip
    if filters:
        from .evaluation.filters import complementary, ekf, madgwick

        found += [complementary._run, madgwick._run, ekf._loop]
    return found


def cold(dispatchers=None) -> bool:
    """Whether any of the loops has no entry in numba's cache (its index file is missing: never compiled here, or
    the function moved in its file — the index is named by its line). Where numba's cache cannot be inspected:
    False (nothing is started)."""
    try:
        return any(not os.path.exists(d._cache._cache_file._index_path) for d in (dispatchers or _dispatchers()))
    except AttributeError:  # another numba's internals: the warm-up is an optimisation, leave it out
        return False


class WarmUp:
    """The warm-up under way (:func:`start`): ``ran`` whether it found the cache cold; :meth:`join` waits for its
    helper process (at most ``wait_s``; then what it has not compiled yet compiles where first used), :meth:`stop`
    ends it at once (the caller stops: an error, Ctrl-C)."""

    def __init__(self, ran: bool, helper: subprocess.Popen | None = None):
        self.ran, self.helper = ran, helper

    def join(self, wait_s: float = HELPER_WAIT_S) -> None:
        h = self.helper
        if h is None:
            return
        try:
            h.wait(timeout=wait_s)
        except subprocess.TimeoutExpired:
            pass
        self.stop()

    def stop(self) -> None:
        h, self.helper = self.helper, None
        if h is not None and h.poll() is None:
            h.kill()
            h.wait()


def start(filters: bool = False) -> WarmUp:
    """On a cold cache: start the helper process on :func:`warm_anchored` (and with ``filters`` the baseline filters
    ``evaluate`` runs, :func:`warm_filters`) and compile :func:`warm_fusion` and :func:`warm_kernels` here meanwhile
    → the :class:`WarmUp`
    (join it before the loops the helper compiles are used: the caller may do other work first). Nothing with
    ``NUMBA_DISABLE_JIT`` or on a warm cache."""
    if os.environ.get("NUMBA_DISABLE_JIT", "0") not in ("", "0") or not cold(_dispatchers(filters)):
        return WarmUp(False)
    from .jit_notice import announce

    announce()  # the helper's compiles are not seen here (the fusion's may load from the cache)
    # the helper imports this very package (a checkout put on sys.path by a script, not installed, included): its
    # compiles must be cached for these source files
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(p for p in (root, os.environ.get("PYTHONPATH")) if p)}
    try:
        helper = subprocess.Popen([sys.executable, "-m", "tepinn_flight.jit_warmup", *(["--filters"] if filters else [])],
                                  stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                                  env=env)  # fmt: skip
    except OSError:
        helper = None
    w = WarmUp(True, helper)
    try:
        warm_fusion()
        warm_kernels()
    except BaseException:
        w.stop()
        raise
    return w


def warm_up(filters: bool = False, wait_s: float = HELPER_WAIT_S) -> bool:
    """:func:`start`, then wait for its helper → whether it ran."""
    w = start(filters)
    try:
        w.join(wait_s)
    except BaseException:
        w.stop()
        raise
    return w.ran


def warm_fusion() -> None:
    """The older fusion's loops, offline (``FusionRun``) and live (``AttitudeFusion.step``: the same ``_step`` on one
    buffer, ``_step_live``)."""
    import numpy as np

    from .model.fusion import AttitudeFusion, FusionConfig, FusionRun

    n = 64
    t = np.arange(n) / 100.0
    gyr = np.tile([0.05, -0.02, 0.1], (n, 1))
    idx = np.arange(15, n, 16)
    q = np.tile([1.0, 0.0, 0.0, 0.0], (len(idx), 1))
    run = FusionRun(t, gyr, FusionConfig(), np.zeros(n, bool))
    run.add(idx, q, np.full(len(idx), 0.02), np.zeros((len(idx), 3)))
    run.advance(n)
    live = AttitudeFusion(FusionConfig())
    live.step(0.0, (0.05, -0.02, 0.1))
    live.step(0.01, (0.05, -0.02, 0.1), ((1.0, 0.0, 0.0, 0.0), 0.02, (0.0, 0.0, 0.0)))


def _turns(rate_hz: float = 50.0):
    """(t, gyr, acc, clipped): rests of 2 s between 1-s turns of 90° about x, y, z and −x (level at the start),
    the last sample of the last turn marked clipped — what the self-calibration (three phases between rests that
    cross no clipping), the rest detector and the saturation paths read."""
    import numpy as np

    from .conventions import GRAVITY_M_S2
    from .quat import gravity_body, quat_from_rotvec, quat_mul, quat_normalize

    m = int(rate_hz)
    parts = []
    for axis in ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0), (-1.0, 0.0, 0.0)):
        parts.append(np.zeros((2 * m, 3)))
        parts.append(np.tile(np.array(axis) * (math.pi / 2), (m, 1)))
    parts.append(np.zeros((2 * m, 3)))
    w = np.concatenate(parts)
    n = len(w)
    q = np.empty((n, 4))
    q[0] = (1.0, 0.0, 0.0, 0.0)
    for i in range(1, n):
        q[i] = quat_normalize(quat_mul(q[i - 1], quat_from_rotvec(w[i - 1] / rate_hz)))
    acc = -gravity_body(q) * GRAVITY_M_S2
    clipped = np.zeros(n, bool)
    clipped[11 * m - 1] = True
    return np.arange(n) / rate_hz, w + 0.002, acc, clipped


def warm_anchored() -> None:
    """The anchored filter's steps (offline and live, every gate, 6-D and 9-D) and its VQF: the helper's share."""
    import dataclasses

    import numpy as np

    from .model.anchor import AnchorConfig, AnchoredVQF, WindowOutput, window_rows

    t, gyr, acc, clipped = _turns()
    n = len(t)
    mag = np.tile([20.0, 0.0, 45.0], (n, 1))
    every_gate = dataclasses.replace(AnchorConfig(), speed_lo_m_s=0.0, speed_hi_m_s=1e-3)
    for use_mag in (False, True):
        for cfg in (AnchorConfig(), every_gate):
            f = AnchoredVQF(cfg, float(t[1] - t[0]), use_mag)
            h = n // 2
            f.update(t[:h], gyr[:h], acc[:h], mag[:h], clipped[:h])
            f.correct(WindowOutput((1.0, 0.0, 0.0, 0.0), 0.05, np.zeros(3), np.array([30.0, 0.0, 0.0]), np.zeros(3),
                                   np.array([0.1, 0.0, 0.0])))  # fmt: skip
            for i in range(h, h + 3):
                f.update_one(t[i], gyr[i], acc[i], mag[i], bool(i == h))
            f.correct(WindowOutput((0.9, 0.1, 0.0, 0.0), 0.05, np.zeros(3), np.zeros(3), np.zeros(3), None))
            f.update(t[h + 3 :], gyr[h + 3 :], acc[h + 3 :], mag[h + 3 :], clipped[h + 3 :])
            ends = np.arange(15, n, 16)  # a whole segment, as offline
            m = len(ends)
            wins = window_rows(np.tile([1.0, 0.0, 0.0, 0.0], (m, 1)), np.full(m, 0.05, np.float32), np.zeros((m, 3)),
                               np.tile([30.0, 0.0, 0.0], (m, 1)), np.zeros((m, 3)), None, np.zeros(m, bool),
                               np.zeros(m, bool))  # fmt: skip
            AnchoredVQF(cfg, float(t[1] - t[0]), use_mag).run_windows(t, gyr, acc, mag, clipped, ends, wins)
    _warm_live_sample(t, gyr, acc)


def _warm_live_sample(t, gyr, acc) -> None:
    """The live estimator's compiled push (:mod:`.model.streaming_kernels`) with the argument types its push passes."""
    import numpy as np

    from .model import streaming_kernels as K
    from .model.anchor import AnchorConfig, AnchoredVQF
    from .model.fusion import AttitudeFusion, FusionConfig

    f, fus = AnchoredVQF(AnchorConfig(), float(t[1] - t[0]), False), AttitudeFusion(FusionConfig())
    tok, out = K.new_token(), np.zeros(K.N_OUT)
    nan = float("nan")
    for i in range(3):
        g, a = gyr[i].tolist(), acc[i].tolist()
        K.token_add(tok, float(t[i]), *g, *a, nan, nan, nan, False)
        K.live_sample(tok, fus._buf, f.buf, f.cb, float(t[i]), *g, *a, nan, nan, nan, bool(i), False, False, f.use_mag,
                      True, 0.0, out)  # fmt: skip


def warm_kernels() -> None:
    """The estimator's other loops: the smoothing's, the GNSS aid's, the gyro self-calibration's, the network's token
    features and the accelerometer-scale reading's, offline and live; the frames' conversions."""
    import numpy as np

    from .model.accel_scale import AccelScaleConfig, AccelScaleTracker, quiet_samples
    from .model.anchor import AnchorConfig, q_nb_from_vqf, with_fusion_tilt
    from .model.anchor_kernels import fusion_tilt_f
    from .model.config import ModelConfig
    from .model.estimate import offline_vqf
    from .model.gnss_aid import GnssAidConfig, motion_acc_body
    from .model.gyro_selfcal import self_calibrate
    from .model.head_physics import window_attitude
    from .model.rotation_memory import rotation_memory
    from .model.smoother import blend_tilt, disagreement_sigma
    from .model.window_features import SensorValues, window_features

    t, gyr, acc, clipped = _turns()
    n = len(t)
    t_ro = t.copy()
    t_ro.flags.writeable = False  # (a record's time column, as the smoothing's VQF reads it)
    offline_vqf(AnchorConfig(), t_ro, gyr, acc)
    q = np.tile([1.0, 0.0, 0.0, 0.0], (n, 1))
    q_nb_from_vqf(q)
    with_fusion_tilt(q, q)
    fusion_tilt_f(1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0)
    blend_tilt(q, q, np.ones(n))
    disagreement_sigma(t, q, q, np.zeros(n, np.int64), 1.0)
    rotation_memory(t, gyr, np.zeros(n, np.int64), 1.0)
    vel = np.column_stack([np.cos(t), np.sin(t)])
    motion_acc_body(t, q, acc, vel, GnssAidConfig())
    self_calibrate(t, gyr, acc, np.zeros(n, np.int64), clipped)
    cfg = ModelConfig()
    k = cfg.window_tokens
    feats = window_features(cfg, SensorValues.identity(), np.zeros((1, k, 3)), np.tile([0.0, 0.0, -9.81], (1, k, 1)),
                            np.full((1, k), 8.0), np.zeros((1, k)), np.full((1, k), 0.04), np.ones((1, k, 3)),
                            np.zeros((1, k)))  # fmt: skip
    window_attitude(cfg, {"q_head": np.float32([[1, 0, 0, 0]]), "pool": np.zeros((1, k), np.float32),
                          "vel": np.zeros((1, 3), np.float32), "acc_v": np.zeros((1, 3), np.float32)}, feats)
    tracker = AccelScaleTracker()
    for i in range(3):
        tracker.update(float(t[i]), gyr[i], acc[i])
    quiet_samples(t[:40], gyr[:40], acc[:40], AccelScaleConfig(avg_s=0.05, steady_s=0.1))  # the offline reading


def warm_filters() -> None:
    """The baseline filters ``evaluate`` and ``demo`` run (complementary, Madgwick, the EKF; 6-D and 9-D)."""
    import numpy as np

    from .evaluation.filters import Complementary, Ekf, Madgwick

    t, gyr, acc, _ = _turns()
    mag = np.tile([20.0, 0.0, 45.0], (len(t), 1))
    for f in (Complementary(), Madgwick(), Ekf()):
        for m in (None, mag):
            f.estimate(gyr, acc, t, m)


if __name__ == "__main__":  # the helper process
    warm_anchored()
    if "--filters" in sys.argv[1:]:
        warm_filters()
