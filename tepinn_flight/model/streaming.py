"""Live TE-PINN: push IMU samples one at a time, get an estimate for each (same math as offline).

Tokens are accumulated exactly as :mod:`tepinn_flight.model.tokens` does offline; when a sample
opens a new token, the finished token joins the window, the network runs on the window (once per
token, 25 Hz by default; with quiet blocks, once per block where no gate may open) and the fusion
is corrected at the finished token's last sample before propagating to the new one. A time reversal or a gap longer than 2.5 nominal periods starts a new
segment (the state is reset; estimates resume when the next window is full) — except a short
logging dropout (≤ ``record_gaps.MAX_BRIDGED_GAP_S``), bridged as offline: the samples that fill it
(interpolated between the samples on either side) are pushed first, their estimates not returned.

The network runs through a :class:`~.runtime.NetworkRunner`: a :class:`~.network.TEPINN` module
(PyTorch) or e.g. an :class:`~.runtime.OnnxRunner` (no torch).

Between samples, :meth:`StreamingEstimator.prepare` may run the network early (session 46): where the next sample,
arriving no sooner than half a period after the last, opens a new token, the token is closed and its window run now,
in the time the stream leaves idle, instead of inside the next sample's push. The next push then takes that window's
output as it would have computed it, so its estimate comes out without waiting for the network: the same estimates to
the bit. Where the next sample after all falls into the same token (a stamp that came early), or the vehicle's class
was learnt in between, the early close is undone from a snapshot and the push goes on as without it.

Three offline steps have no live counterpart, all reading the whole record around the pass: the gyro
self-calibration (``AnchorConfig.gyro_selfcal``, :mod:`.gyro_selfcal`), the GNSS-aided tilt
(``AnchorConfig.gnss_aid``, :mod:`.gnss_aid`: centred averages, a heading fitted over 30 s, a second
pass) and the tilt smoothing (``AnchorConfig.smoother``, on in the shipped model since session 25, :mod:`.smoother`: VQF backward too).
Live, the gyro is scaled by ``AnchorConfig.gyro_scale`` only, the accelerometer is taken as it is and
nothing is smoothed, so where an offline step applies the two differ.
"""

from __future__ import annotations

import math
import time
from collections import deque
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from ..record_gaps import (GAP_PERIODS, PERIOD_STEPS, RateRise, filler_times, interpolate_rows, is_bridgeable,
                           segment_period_s)  # fmt: skip
from .accel_scale import AccelScaleTracker
from .anchor import (AnchorConfig, AnchoredVQF, WindowOutput, acc_gain, aircraft_var_rad2, bias_fusion_gate_allowed,
                     bias_pull_allowed, fusion_tilt_f, speed_gate_allowed)  # fmt: skip
from .fusion import AttitudeFusion, FusionConfig, feedback_bias
from .runtime import NetworkRunner, as_runner
from .streaming_kernels import (N_OUT, OUT_BIAS, OUT_FUS_BIAS, OUT_FUS_OK, OUT_FUS_Q, OUT_Q, OUT_Q_OK, OUT_SIGMA, TOK_A,
                                TOK_CLIP, TOK_G, TOK_M, TOK_M_N, TOK_N, TOK_T_LAST, live_sample, new_token, token_add)  # fmt: skip

if TYPE_CHECKING:
    from .network import TEPINN

#: the anchored filter's sample period is the median of a segment's first steps (offline the same)
TS_STEPS = PERIOD_STEPS
#: :meth:`StreamingEstimator.prepare` closes the token early where a next sample this many periods after the last
#: would already open a new one (a sample sooner than that, in the same token, undoes the early close)
PREPARE_SOONEST_PERIODS = 0.5


@dataclass
class Estimate:
    t_s: float  # time of the IMU sample this estimate belongs to
    q_nb_wxyz: tuple | None  # None until the first window is full
    sigma_rad: float
    gyr_bias_rad_s: tuple
    model_ran: bool  # the network ran in this push (a token closed here, not already run by prepare)
    compute_s: float  # processing time of this push


_NAN3 = (float("nan"),) * 3


class _TokenWindow:
    """The last ``k`` finished tokens as rows (t, g(3), a(3), m(3), count, clipped fraction) of one
    float64 array: each row is written twice, ``k`` apart, so the window is always one contiguous
    slice (no per-window list → array conversion)."""

    __slots__ = ("k", "buf", "n")

    def __init__(self, k: int):
        self.k = k
        self.buf = np.zeros((2 * k, 12))
        self.n = 0  # rows appended

    def append(self, t: float, g, a, m, count: float, clip: float) -> None:
        i = self.n % self.k
        row = (t, *g, *a, *m, count, clip)
        self.buf[i] = row
        self.buf[i + self.k] = row
        self.n += 1

    def __len__(self) -> int:
        return min(self.n, self.k)

    def rows(self) -> np.ndarray:
        """The window, oldest token first: (len, 12)."""
        i = self.n % self.k if self.n >= self.k else 0
        return self.buf[i:i + len(self)]


class StreamingEstimator:
    def __init__(self, model: TEPINN | NetworkRunner, fusion: FusionConfig | AnchorConfig | None = None,
                 threads: int | None = 1, vehicle: str | None = None):  # fmt: skip
        """``model``: a TE-PINN module (put in eval mode, run in PyTorch) or a network runner;
        ``threads``: the runtime's CPU threads (None/0: its own choice); ``vehicle``: what the vehicle is (a
        record's ``vehicle_type``, the autopilot's MAV_TYPE name, or a :mod:`..vehicle_class` class; None: not
        known), as offline from the record (:meth:`set_vehicle` when it is learnt later)."""
        self.model = model if isinstance(model, NetworkRunner) else model.eval()
        self.runner = as_runner(self.model)
        self.cfg = self.runner.config
        self.anchor_cfg = a = fusion if isinstance(fusion, AnchorConfig) else None
        if a is not None:  # the older fusion runs alongside as the pulls' target
            self.fusion_cfg = a.fusion_config or FusionConfig()
        else:
            self.fusion_cfg = fusion or FusionConfig()
        self.last_imu = ((0.0, 0.0, 0.0), (0.0, 0.0, 0.0))  # the last finite gyro and accelerometer sample
        self.holes = 0  # non-finite samples bridged with it
        self.last_raw = None  # the previous sample's gyro, accelerometer, magnetometer: three tuples (gap filling)
        self.bridged_gaps = 0  # short logging dropouts propagated through
        self.rate_rises = 0  # new segments where the sample rate rose (record_gaps.RateRise)
        # the last segment's sample period: a new segment's first steps are told gaps by it (offline: the record's
        # nominal period) until the segment's own is known (a lone sample between two gaps had been one segment live)
        self.prev_period = None
        self.delta = 1.0 / self.cfg.token_rate_hz
        # the accelerometer's scale, read causally and kept across segments (a sensor's property)
        self.acc_scale = AccelScaleTracker() if a is not None and a.accel_scale_selfcal else None
        self.vehicle = vehicle  # kept across segments (the vehicle's, not the segment's)
        self.sigma_add = aircraft_var_rad2(a, vehicle) if a is not None else 0.0  # σ² an aircraft's IMU adds (rule 28)
        self.clip_tilt = a is not None and bool(a.clip_tilt_from_fusion)  # saturated: the older fusion's tilt
        self._out = np.zeros(N_OUT)  # streaming_kernels.live_sample's output
        # a push that applies no window is one compiled call (session 51, streaming_kernels.live_sample); False: the
        # calls one by one from Python, as before it (the same numbers: the reference the tests hold it to)
        self.compiled = True
        if threads:
            self.runner.set_threads(threads)
        self.reset()

    def reset(self, sensor: bool = False) -> None:
        """Forget the segment (a new one: reboot, time jump, dropout); with ``sensor``, also what was
        read of the sensor itself (the accelerometer's scale, otherwise kept across segments): a
        different IMU, or samples that were not the vehicle's (the bridge's warm-up)."""
        if sensor and self.acc_scale is not None:
            self.acc_scale = AccelScaleTracker(self.acc_scale.cfg)
        if sensor:
            self.prev_period = None
        elif getattr(self, "period", None) is not None:
            self.prev_period = self.period
        self.fusion = AttitudeFusion(self.fusion_cfg)
        self.old_q = None  # the older fusion's estimate at the previous sample (the pulls' target)
        self.old_bias = None  # ... and its gyro-bias estimate
        self.anchored = None  # AnchoredVQF, made once the segment's sample period is known
        self.pending: list = []  # the segment's first samples (and windows) until then
        self.t0 = None
        self.t_prev = None
        self.period = None  # nominal sample period, running median of the first steps
        self._dts: list[float] = []
        self.rise = None  # RateRise, once the segment's period is known
        self.k = 0
        self.cur = new_token()  # the open token (streaming_kernels.TOK_*)
        k = self.cfg.window_tokens
        self.win = _TokenWindow(k)  # finished tokens
        self.last_means = None
        self.n_windows = 0  # full windows closed in this segment (bias feedback refreshes every L of them)
        self.feedback = (0.0, 0.0, 0.0)  # the fusion's bias the current block of windows sees
        self.busy = True  # the current block runs every window (quiet blocks: AnchorConfig.block_busy)
        self.block_speed = 0.0  # the largest |v̂| on the current block's windows ...
        self.speeds = deque(maxlen=self.anchor_cfg.quiet_memory_blocks) if self.anchor_cfg else None  # ... of the last blocks
        self.quiet = self.anchor_cfg.quiet_in(self.fusion_cfg) if self.anchor_cfg is not None else 0
        self.early = None  # prepare()'s early close: (the state before it, the window's output)

    def push(self, t_s: float, gyr_rad_s, acc_m_s2, mag_ut=None, clipped: bool = False,
             gyr_clipped: bool | None = None) -> Estimate:
        """One sample → its estimate. ``clipped``: a sensor axis at its range (the network's tokens, the
        older fusion); ``gyr_clipped``: the gyro's (the anchored filter's saturation gate; None: ``clipped``)
        — a record's ``clipped`` and ``gyr_clipped`` columns."""
        t0c = time.perf_counter()
        t = float(t_s)
        # (unpacked and made floats once: this path runs per sample, its Python is most of its cost; a numpy row, as a
        # record's columns give it, through tolist: unpacking it into numpy scalars cost ~1.3 µs a vector more. The
        # bridge's worker passes tuples of floats)
        gx, gy, gz = gyr_rad_s.tolist() if type(gyr_rad_s) is np.ndarray else gyr_rad_s
        ax, ay, az = acc_m_s2.tolist() if type(acc_m_s2) is np.ndarray else acc_m_s2
        gx, gy, gz, ax, ay, az = float(gx), float(gy), float(gz), float(ax), float(ay), float(az)
        if math.isfinite(gx + gy + gz + ax + ay + az):  # a NaN or inf makes the sum one
            gyr_rad_s, acc_m_s2 = (gx, gy, gz), (ax, ay, az)
            self.last_imu = (gyr_rad_s, acc_m_s2)
        else:  # a hole: bridged with the last finite sample, as offline
            gyr_rad_s, acc_m_s2 = self.last_imu
            (gx, gy, gz), (ax, ay, az) = gyr_rad_s, acc_m_s2
            self.holes += 1
        mag_row = _NAN3 if mag_ut is None else tuple(float(v) for v in mag_ut)
        period = self.period if self.period is not None else self.prev_period
        if self.t_prev is not None and period is not None and self.last_raw is not None \
                and t - self.t_prev > GAP_PERIODS * period and is_bridgeable(t - self.t_prev, period):  # fmt: skip
            self._bridge(t, (*gyr_rad_s, *acc_m_s2, *mag_row), period)
        self.last_raw = (gyr_rad_s, acc_m_s2, mag_row)  # (joined only where a gap is bridged)
        if self.acc_scale is not None:  # divided by the accelerometer's scale once read (where ≥ 10 % off)
            acc_m_s2 = self.acc_scale.update(t, gyr_rad_s, acc_m_s2)
            ax, ay, az = acc_m_s2
        t_prev = self.t_prev  # a new segment: the first sample, a time reversal or a gap (not bridged above)
        dt = None if t_prev is None else t - t_prev
        period = self.period if self.period is not None else self.prev_period  # (the bridge's pushes may set it)
        if dt is None or dt <= 0 or (period is not None and dt > GAP_PERIODS * period):
            self.reset()
            self.t0 = t
        elif len(self._dts) < TS_STEPS:
            self._dts.append(dt)
            self.period = float(np.median(self._dts))
            if len(self._dts) == TS_STEPS:  # the anchored filter's period (_first_samples): a rise from it is watched
                self.rise = RateRise(self.period, self._dts)
        elif self.rise.step(dt):  # the rate rose: a new segment here, as offline (record_gaps.rate_rise_cuts)
            self.reset()
            self.t0 = t
            self.rate_rises += 1
        k = 0 if t == self.t0 else int(math.ceil((t - self.t0) / self.delta - 1e-6))
        est = None
        ran = False
        if self.early is not None and k <= self.k:  # this sample belongs to the token prepare() closed after all
            self._undo_early()
        if k > self.k:
            if self.early is not None:  # the token prepare() closed did end with the last sample: its window's output
                est = self.early[1]
                self.early = None
            else:
                est = self._close_token()
                ran = est is not None
            for j in range(self.k + 1, k):  # empty tokens: hold the previous means (causal)
                g, a, m, cl = self.last_means
                self.win.append(self.t0 + j * self.delta, g, a, m, 0.0, cl)
            self.k = k
            self.cur = new_token()
        mx, my, mz = mag_row
        g_clip = bool(clipped) if gyr_clipped is None else bool(gyr_clipped)
        anchored = self.anchored
        if est is None and anchored is not None and self.compiled:  # the usual push: one compiled call
            if g_clip:
                anchored.room(1)
            out = self._out
            live_sample(self.cur, self.fusion._buf, anchored.buf, anchored.cb, t, gx, gy, gz, ax, ay, az, mx, my, mz,
                        bool(clipped), g_clip, False, anchored.use_mag, self.clip_tilt, self.sigma_add, out)  # fmt: skip
            o = out.tolist()
            self.old_q = (o[OUT_FUS_Q], o[OUT_FUS_Q + 1], o[OUT_FUS_Q + 2], o[OUT_FUS_Q + 3]) if o[OUT_FUS_OK] else None
            self.old_bias = (o[OUT_FUS_BIAS], o[OUT_FUS_BIAS + 1], o[OUT_FUS_BIAS + 2])
            q = (o[OUT_Q], o[OUT_Q + 1], o[OUT_Q + 2], o[OUT_Q + 3]) if o[OUT_Q_OK] else None
            self.t_prev = t
            return Estimate(t, q, o[OUT_SIGMA], (o[OUT_BIAS], o[OUT_BIAS + 1], o[OUT_BIAS + 2]), ran,
                            time.perf_counter() - t0c)  # fmt: skip
        token_add(self.cur, t, gx, gy, gz, ax, ay, az, mx, my, mz, bool(clipped))
        if self.anchor_cfg is not None:
            q, sigma, bias = self._anchored_step(t, gyr_rad_s, acc_m_s2, mag_ut, bool(clipped), g_clip, est)
            if self.sigma_add:  # as offline (anchor.with_aircraft_sigma)
                sigma = math.sqrt(sigma * sigma + self.sigma_add)
        else:
            q, sigma, bias = self.fusion.step(t, gyr_rad_s, est, bool(clipped))
        self.t_prev = t
        return Estimate(t, q, sigma, bias, ran, time.perf_counter() - t0c)

    def prepare(self) -> tuple[bool, float]:
        """Between samples (the bridge's worker, once it has sent the last estimate): close the current token and run
        its window now where the next sample, due about a period after the last and arriving no sooner than
        :data:`PREPARE_SOONEST_PERIODS` of one, would open a new token — so the next push does not wait for the network.
        The estimates are the same bits as without it (:meth:`push` takes the output, or undoes the early close where
        the next sample falls into the same token after all). → (the network ran, seconds spent)."""
        if self.early is not None or self.t_prev is None or self.period is None or self.cur[TOK_N] == 0:
            return False, 0.0
        t_soonest = self.t_prev + PREPARE_SOONEST_PERIODS * self.period
        if int(math.ceil((t_soonest - self.t0) / self.delta - 1e-6)) <= self.k:
            return False, 0.0
        t0c = time.perf_counter()
        win = self.win
        saved = (win.buf.copy(), win.n, self.last_means, self.feedback, self.n_windows,
                 None if self.speeds is None else list(self.speeds), self.busy, self.block_speed)  # fmt: skip
        est = self._close_token()
        self.early = (saved, est)
        return est is not None, time.perf_counter() - t0c

    def _undo_early(self) -> None:
        """The state as it was before :meth:`prepare` closed the token."""
        buf, n, self.last_means, self.feedback, self.n_windows, speeds, self.busy, self.block_speed = self.early[0]
        self.win.buf[:] = buf
        self.win.n = n
        if speeds is not None:
            self.speeds.clear()
            self.speeds.extend(speeds)
        self.early = None

    def set_vehicle(self, vehicle: str | None) -> None:
        """What the vehicle is, learnt after the start (the bridge: the autopilot's heartbeat): from the next window on
        (σ's aircraft term from the next sample)."""
        if self.early is not None:  # the early window read the class it replaces
            self._undo_early()
        self.vehicle = vehicle
        if self.anchor_cfg is not None:
            self.sigma_add = aircraft_var_rad2(self.anchor_cfg, vehicle)
        if self.anchored is not None:
            self.anchored.speed_gate = speed_gate_allowed(self.anchor_cfg, vehicle)
            self.anchored.bias_fusion_gate = bias_fusion_gate_allowed(self.anchor_cfg, vehicle)
            self.anchored.bias_pull = bias_pull_allowed(self.anchor_cfg, vehicle)
            self.anchored.set_acc_gain(acc_gain(self.anchor_cfg, vehicle, causal=True))

    def _bridge(self, t: float, row: tuple, period: float) -> None:
        """Push the samples that fill the gap from the previous sample to ``t`` at ``period`` (as offline)."""
        t_a = self.t_prev
        tf = filler_times(t_a, t, period)
        g, a, m = self.last_raw
        vals = interpolate_rows(t_a, np.asarray((*g, *a, *m)), t, np.asarray(row), tf)
        for t_i, v in zip(tf, vals):
            m = v[6:9]
            self.push(float(t_i), v[0:3], v[3:6], m if np.all(np.isfinite(m)) else None, False)
        self.bridged_gaps += 1

    def _anchored_step(self, t, gyr, acc, mag, clipped, gyr_clipped, est):
        """The filter-anchored estimate of this sample; ``est`` (the network's window at the
        previous sample, or None) is applied first; ``clipped`` feeds the older fusion, ``gyr_clipped``
        the filter's saturation gate."""
        # pull toward the older fusion's estimate before this window
        target, b_target = self.old_q, self.old_bias
        old = None if est is None else (list(est.q_nb_wxyz), est.sigma_rad, list(est.gyr_bias_rad_s))
        self.old_q, _, self.old_bias = self.fusion.step(t, gyr, old, clipped)
        if est is not None:  # (built directly, no nan_to_num: a window's Python adds up live — dataclasses.replace
            # cost 13 µs a window; every field of WindowOutput is named here)
            b = np.array([v if math.isfinite(v) else 0.0 for v in b_target] if b_target is not None else (0.0, 0.0, 0.0))
            q_pull = est.q_nb_wxyz
            if target is not None and all(math.isfinite(v) for v in target):
                q_pull = np.asarray(target, np.float64)
            est = WindowOutput(q_pull, est.sigma_rad, est.gyr_bias_rad_s, est.vel_m_s, est.acc_m_s2, b, est.gnss_aided,
                               est.gnss_fast)  # fmt: skip
        anchored = self.anchored
        if anchored is not None:  # (the usual case, without the list below)
            if est is not None:
                anchored.correct(est)
            out = anchored.update_one(t, gyr, acc, mag, gyr_clipped)
        else:
            out = self._first_samples(t, gyr, acc, mag, gyr_clipped, est)
            if out is None:
                return None, float("nan"), (float("nan"),) * 3
        q6, q9, sig, bias = out
        q = q9 if q9 is not None else q6
        if not math.isfinite(q[0] + q[1] + q[2] + q[3]):
            return None, sig, bias
        if self.anchored.gate_parts[1] > 0 and self.anchor_cfg.clip_tilt_from_fusion and self.old_q is not None:
            q = fusion_tilt_f(*q, *self.old_q)  # saturated: the older fusion's tilt (offline: with_fusion_tilt)
        return q, sig, bias

    def _first_samples(self, t, gyr, acc, mag, gyr_clipped, est):
        """A segment's first samples: held until its sample period is known (the median of its first
        steps), then the anchored filter made and run over them → the last one's outputs (None: still held)."""
        self.pending.append((t, gyr, acc, mag, gyr_clipped, est))
        if len(self.pending) <= TS_STEPS:
            return None
        mode = self.anchor_cfg.mode  # auto: 9-D when the segment's first samples carry a magnetometer
        use_mag = mode == "9d" or (mode == "auto" and any(p[3] is not None and all(math.isfinite(float(v)) for v in p[3])
                                                          for p in self.pending))  # fmt: skip
        self.anchored = AnchoredVQF(self.anchor_cfg, segment_period_s([p[0] for p in self.pending]), use_mag=use_mag,
                                    vehicle=self.vehicle,
                                    causal=True)  # fmt: skip
        pending, self.pending = self.pending, []
        out = None
        for t_i, g_i, a_i, m_i, c_i, e_i in pending:
            if e_i is not None:
                self.anchored.correct(e_i)
            out = self.anchored.update_one(t_i, g_i, a_i, m_i, c_i)
        return out

    def _close_token(self):
        tok = self.cur.tolist()
        n = tok[TOK_N]
        if n == 0:
            return None
        g = [v / n for v in tok[TOK_G : TOK_G + 3]]
        a = [v / n for v in tok[TOK_A : TOK_A + 3]]
        m_n = tok[TOK_M_N]
        m = [v / m_n for v in tok[TOK_M : TOK_M + 3]] if m_n else [float("nan")] * 3
        cl = tok[TOK_CLIP] / n
        self.last_means = (g, a, m, cl)
        self.win.append(tok[TOK_T_LAST], g, a, m, n, cl)
        if len(self.win) < self.cfg.window_tokens:
            return None
        return self._run_model()

    def _run_model(self):
        fb_every = self.fusion_cfg.bias_feedback_windows
        first = fb_every > 0 and self.n_windows % fb_every == 0
        if first:
            self.feedback = feedback_bias(self.fusion_cfg, self.fusion.bias)  # after the previous estimate
        self.n_windows += 1
        if self.quiet and not first:  # quiet blocks: only their first window (and those holding a saturated token) run
            block, j = divmod(self.n_windows - 1, fb_every)
            if not self.anchor_cfg.runs_window(block, j, self.busy, bool((self.win.rows()[:, 11] > 0).any())):
                return None
        w = self.win.rows()
        fb = self.feedback if fb_every > 0 else (0.0, 0.0, 0.0)
        g = (w[:, 1:4] - np.asarray(fb, np.float64))[None]
        a = w[None, :, 4:7]
        m = w[None, :, 7:10]  # NaN where no magnetometer: the network's features zero them (nan_to_num), as offline
        n = w[None, :, 10]
        cl = w[None, :, 11]
        t_rel = (w[:, 0] - w[-1, 0])[None]
        dt = np.full_like(n, self.delta)
        out = self.runner.run(g, a, n, t_rel, dt, m, cl)
        sigma = float(out["sigma"][0])
        bias = [v + fb[i] for i, v in enumerate(out["bias"][0].tolist())]
        if self.quiet:
            speed_gate = speed_gate_allowed(self.anchor_cfg, self.vehicle)
            # |v̂| only where a block reads it (as offline: a multirotor's or a hand-held log's blocks do not)
            speed = float(np.linalg.norm(out["vel"][0])) if self.anchor_cfg.reads_speed(speed_gate) else 0.0
            if first:
                block = (self.n_windows - 1) // fb_every
                if block > 0:
                    self.speeds.append(self.block_speed)
                self.busy = self.anchor_cfg.block_busy(block, max(speed, max(self.speeds, default=0.0)), self.fusion.bias,
                                                       speed_gate)  # fmt: skip
                self.block_speed = speed
            else:
                self.block_speed = max(self.block_speed, speed)
        if self.anchor_cfg is not None:
            return WindowOutput(out["q"][0], sigma, np.array(bias), out["vel"][0], out["acc_v"][0])
        return (out["q"][0].tolist(), sigma, bias)


def stream_record(model: TEPINN | NetworkRunner, rec, fusion: FusionConfig | AnchorConfig | None = None,
                  threads: int | None = 1) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # fmt: skip
    """Every sample of the record ``rec`` pushed through a :class:`StreamingEstimator` in order, as the bridge pushes
    the autopilot's (6-D: no magnetometer; the record's clipping flags; its vehicle as the log names it) → (q (n, 4),
    σ (n,), gyro bias (n, 3)), NaN where the live estimator has no estimate yet. What ``evaluate --live`` scores:
    the live path itself, not the offline one with its offline steps off (the accelerometer's scale, for one, is read
    live from the first quiet seconds, offline from the whole record)."""
    live = StreamingEstimator(model, fusion, threads=threads, vehicle=rec.meta.get("vehicle_type"))
    n = len(rec)
    q, sigma, bias = np.full((n, 4), np.nan), np.full(n, np.nan), np.full((n, 3), np.nan)
    # (the record's columns taken once: each of its properties makes a new array from the frame)
    t, gyr, acc, clipped, gyr_clipped = rec.t_s, rec.gyr_rad_s, rec.acc_m_s2, rec.clipped, rec.gyr_clipped
    for i in range(n):
        e = live.push(t[i], gyr[i], acc[i], None, bool(clipped[i]), bool(gyr_clipped[i]))
        if e.q_nb_wxyz is not None:
            q[i], sigma[i], bias[i] = e.q_nb_wxyz, e.sigma_rad, e.gyr_bias_rad_s
    return q, sigma, bias
