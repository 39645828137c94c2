"""The anchored filter as Python methods on ``vqf``'s C++ VQF: :class:`tepinn_flight.model.anchor.AnchoredVQF` up to
session 48, kept as the reference its compiled steps (``model/anchor_steps.py``) are held to, bit for bit
(``tests/test_anchor_steps.py``). Not used by the package."""

from __future__ import annotations

import math
from collections import deque

import numpy as np

from tepinn_flight.conventions import GRAVITY_M_S2
from tepinn_flight.quat_scalar import down_in_body
from tepinn_flight.record_gaps import GAP_PERIODS
from tepinn_flight.model.anchor import (AnchorConfig, WindowOutput, _rows, bias_fusion_gate_allowed, bias_pull_allowed, ffill_rows, q_nb_from_vqf,
                                        speed_gate_allowed, to_sensor)
from tepinn_flight.model.anchor_steps import BIAS_EVIDENCE_S, CLIP_SIGMA_CAP_RAD, THRUST_TAU_S
from numba import njit

from tepinn_flight.model.anchor_kernels import (clip_sigma_step, horizontal_bias, q_nb_from_vqf_f, rest_step, sigma_step,
                                                step_weight, step_weights, tilt_pull_f, turn_acc_state,
                                                up_in_earth_f)  # fmt: skip

# the former class's block kernels (model/anchor_kernels.py up to session 48; the compiled steps replaced them)


@njit(cache=True)
def clip_sigma_rows(sigma, clipped, g_s, e, decay, gain_dt, cap):
    """:func:`clip_sigma_step` over a block in place: ``sigma`` (n,), ``clipped`` (n,) bool, ``g_s``
    (n, 3) the gyro VQF integrated. Returns the last ``e``."""
    for i in range(sigma.shape[0]):
        sigma[i], e = clip_sigma_step(sigma[i], e, clipped[i], g_s[i, 0], g_s[i, 1], g_s[i, 2], decay, gain_dt, cap)
    return e


@njit(cache=True)
def vqf_inputs(gyr_b, acc_b, gyr_corr, vel, acc_v, centripetal, g_s, a_s):
    """The block VQF sees, in its sensor frame: ``g_s`` ← gyro − ``gyr_corr``; ``a_s`` ←
    accelerometer − (ω × ``vel`` + ``acc_v``) when ``centripetal`` and either is non-zero (ω: the
    gyro as measured), else the accelerometer. Returns how many rows hold a non-finite value
    (their outputs are then meaningless)."""
    cen = centripetal and (vel[0] != 0.0 or vel[1] != 0.0 or vel[2] != 0.0
                           or acc_v[0] != 0.0 or acc_v[1] != 0.0 or acc_v[2] != 0.0)  # fmt: skip
    bad = 0
    for i in range(gyr_b.shape[0]):
        gx, gy, gz = gyr_b[i, 0], gyr_b[i, 1], gyr_b[i, 2]
        ax, ay, az = acc_b[i, 0], acc_b[i, 1], acc_b[i, 2]
        if not (math.isfinite(gx) and math.isfinite(gy) and math.isfinite(gz)
                and math.isfinite(ax) and math.isfinite(ay) and math.isfinite(az)):  # fmt: skip
            bad += 1
        g_s[i, 0] = gx - gyr_corr[0]
        g_s[i, 1] = -(gy - gyr_corr[1])
        g_s[i, 2] = -(gz - gyr_corr[2])
        if cen:
            ax = ax - ((gy * vel[2] - gz * vel[1]) + acc_v[0])
            ay = ay - ((gz * vel[0] - gx * vel[2]) + acc_v[1])
            az = az - ((gx * vel[1] - gy * vel[0]) + acc_v[2])
        a_s[i, 0] = ax
        a_s[i, 1] = -ay
        a_s[i, 2] = -az
    return bad


@njit(cache=True)
def vqf_outputs(q_es, bias_s, a_s, g_s, gyr_corr, e, alpha, var0, gain, samp, var_net, q_nb, bias_b, sigma):
    """VQF's block out to the estimator's frames: ``q_nb`` (n, 4) body FRD → NED, ``bias_b`` (n, 3) its
    bias in body axes plus ``gyr_corr`` (what was removed before VQF), ``sigma`` (n,) by
    :func:`sigma_step` from state ``e`` (``a_s``, ``g_s``: the block VQF saw). Returns the last ``e``."""
    for i in range(q_es.shape[0]):
        qw, qx, qy, qz = q_es[i, 0], q_es[i, 1], q_es[i, 2], q_es[i, 3]
        q_nb[i, 0], q_nb[i, 1], q_nb[i, 2], q_nb[i, 3] = q_nb_from_vqf_f(qw, qx, qy, qz)
        bias_b[i, 0] = bias_s[i, 0] + gyr_corr[0]
        bias_b[i, 1] = -bias_s[i, 1] + gyr_corr[1]
        bias_b[i, 2] = -bias_s[i, 2] + gyr_corr[2]
        sigma[i], e = sigma_step(qw, qx, qy, qz, a_s[i, 0], a_s[i, 1], a_s[i, 2], g_s[i, 0], g_s[i, 1], g_s[i, 2], e,
                                 alpha, var0, gain, samp, var_net)  # fmt: skip
    return e


@njit(cache=True)
def vqf_output_one(q_es, bias_s, a_s, gx, gy, gz, gyr_corr, sp, out):
    """:func:`vqf_outputs` of one sample, for the live path (one compiled call where there were three):
    ``q_es`` (4,) and ``bias_s`` (3,) VQF's after its update, ``a_s`` (3,) the accelerometer it saw and
    (``gx``, ``gy``, ``gz``) the gyro, sensor axes, before any step weighting; ``sp`` = (e, α, var0, gain,
    samp, var_net) as :func:`sigma_step` takes them, its ``e`` updated in place; ``out`` (8,) ← q_nb (4),
    σ, bias_b (3)."""
    qw, qx, qy, qz = q_es[0], q_es[1], q_es[2], q_es[3]
    out[0], out[1], out[2], out[3] = q_nb_from_vqf_f(qw, qx, qy, qz)
    out[5] = bias_s[0] + gyr_corr[0]
    out[6] = -bias_s[1] + gyr_corr[1]
    out[7] = -bias_s[2] + gyr_corr[2]
    out[4], sp[0] = sigma_step(qw, qx, qy, qz, a_s[0], a_s[1], a_s[2], gx, gy, gz, sp[0], sp[1], sp[2], sp[3], sp[4],
                               sp[5])  # fmt: skip


@njit(cache=True)
def rest_rows(st, gyr_b, acc_b, gyr_max2, acc_dev2, spike2):
    """:func:`rest_step` of each row of ``gyr_b`` / ``acc_b`` (n, 3), in order."""
    for i in range(gyr_b.shape[0]):
        rest_step(st, gyr_b[i, 0], gyr_b[i, 1], gyr_b[i, 2], acc_b[i, 0], acc_b[i, 1], acc_b[i, 2], gyr_max2, acc_dev2,
                  spike2)  # fmt: skip


def _read_only(x) -> np.ndarray:
    """``x`` C-contiguous and read-only (a view where it is C-contiguous already): a record's columns are read-only, so
    that is the one signature a kernel reading them is compiled for, whoever calls it (a caller's writable array was
    a second compile: tests/test_first_run_compile.py)."""
    v = np.ascontiguousarray(x).view()
    v.flags.writeable = False
    return v


def _floats(v) -> list:
    return np.asarray(v, np.float64).tolist()


def _norm3(v) -> float:
    return math.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2])


class AnchoredVQFReference:
    """One segment of the anchored estimator; samples in, one estimate per sample out.

    ``update(gyr, acc, mag)`` takes a block of samples (rows, body FRD, SI) — one sample or many:
    the result is the same — and ``correct(window)`` applies a network window made at the last
    sample pushed, for the samples after it (causal)."""

    def __init__(self, config: AnchorConfig, ts_s: float, use_mag: bool = False, vehicle: str | None = None):
        """``vehicle``: what the record says the vehicle is (its ``vehicle_type``; None: nothing) —
        ``config.speed_gate_shut_for`` keeps the flight-speed gate shut for some classes of it."""
        import vqf

        self.cfg = c = config
        self.centripetal = bool(c.centripetal)
        self.speed_gate = speed_gate_allowed(c, vehicle)
        self.bias_fusion_gate = bias_fusion_gate_allowed(c, vehicle)  # (rule 31)
        self.bias_pull = bias_pull_allowed(c, vehicle)  # (rule 33)
        self.use_mag = use_mag
        self.ts = ts_s
        self.f = vqf.VQF(ts_s, tauAcc=c.tau_acc_s, biasClip=c.bias_clip_deg_s)
        self.vel = np.zeros(3)  # gated v̂ and â in body axes
        self.acc_v = np.zeros(3)
        self.turn_on = False  # centripetal and (v̂, â) not both zero: update_one removes them
        self.gyr_corr = np.zeros(3)  # body axes, removed from the gyro
        self.bias_latched = False
        self.t_bias_over = None  # since when the older fusion's horizontal bias is beyond its gate
        self.acc_mean = None  # the accelerometer low-passed window by window (THRUST_TAU_S), body axes
        self.t_acc_mean = 0.0
        self.tau_acc = c.tau_acc_s
        self.clip_times = deque()  # times of the saturated samples of the last clip_hold_s
        self.clip_gate_max = math.radians(c.clip_gate_max_deg_s) if c.clip_gate_max_deg_s > 0 else math.inf
        self.t_clip_high = -math.inf  # the last saturated sample reading beyond clip_gate_max_deg_s
        self.t_clip_last = -math.inf  # the last saturated sample
        self.still = np.zeros(7)  # the still run while the saturation gate may be on (rest_step)
        self.at_rest = False  # re-levelled at rest and still since: no gate opens (rest_relevel_s)
        self.rest_samples = 0  # samples since that re-levelling (the still run's length while it lasts)
        self.rest_base = 0.0  # the still run's length at that re-levelling (rest_keeps_run; else 0: a fresh run)
        self.rest_gyr2 = math.radians(c.rest_gyr_deg_s) ** 2
        self.rest_acc2 = float(c.rest_acc_m_s2) ** 2
        self.rest_spike2 = self.rest_gyr2 * float(c.rest_spike_factor) ** 2
        self.t = 0.0
        self.gate = 0.0
        self.gate_parts = (0.0, 0.0, 0.0)  # the last window's flight-speed, saturation and bias gates
        self.sigma_net = 0.0
        self.var_gap = 0.0  # σ²'s gap term (sigma_gap_gain), set at each window
        self.t_gated = -math.inf  # the last window where a gate acted
        # σ's accelerometer term and constants as vqf_output_one takes them: (e, α, var0, gain, samp, var_net) —
        # e the low-passed accelerometer-vs-gravity angle (rad), α its low-pass gain per sample, samp × |ω|² the
        # sampling term, var_net the network's share (_var_net, kept current by correct)
        self._sp = np.array([0.0, min(1.0, self.ts / c.sigma_acc_tau_s), math.radians(c.sigma_floor_deg) ** 2,
                             float(c.sigma_acc_gain), float(c.sigma_sampling_gain) * self.ts * self.ts / 12.0, 0.0])  # fmt: skip
        self.e_clip = 0.0  # the gyro-saturation term E (rad)
        self.clip_decay = math.exp(-self.ts / c.sigma_clip_tau_s)
        self.clip_gain_dt = float(c.sigma_clip_gain) * self.ts
        self.last_imu = (np.zeros(3), np.zeros(3))  # the last finite gyro/accelerometer sample
        self.holes = 0  # non-finite samples bridged
        self.relevel_t: list[float] = []  # when the tilt was set from the accelerometer at rest (rest_relevel_s)
        self.gscale = None if c.gyro_scale == (1.0, 1.0, 1.0) else c.gyro_scale  # gyro × this (calibration)
        # an IMU slower than the network learned: every gate stays shut (min_network_rate_hz)
        self.slow = c.min_network_rate_hz > 0 and ts_s * c.min_network_rate_hz > 1.0
        self.step_weighting = bool(c.gyro_step_weighting)  # the gyro into VQF × dt/Ts (gyro_step_weighting)
        self.t_prev = math.nan  # the previous sample's time (NaN: none yet in this segment)
        self._g1, self._a1 = np.empty(3), np.empty(3)  # update_one's sample in VQF's frame
        self._out1 = np.empty(8)  # ... and its outputs (vqf_output_one)
        # gyr_corr, vel and acc_v as floats for update_one (numpy's scalar reads cost it ~1 µs a sample), set with them
        self._gc, self._vel_f, self._acc_v_f = (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0)

    # ------------------------------------------------------------------ samples

    def update(self, t_s, gyr_b, acc_b, mag=None, clipped=None):
        """Rows of samples → (q_nb (n, 4), q_nb_9d (n, 4) or None, sigma (n,), bias_b (n, 3)).
        A non-finite gyro/accelerometer row is a hole, bridged with the last finite sample."""
        t_s = np.atleast_1d(np.asarray(t_s, np.float64))
        gyr_b, acc_b = _rows(gyr_b), _rows(acc_b)
        if self.gscale is not None:  # the vehicle's gyro calibration (a hole stays a hole)
            gyr_b = gyr_b * np.array(self.gscale)
        n = len(t_s)
        cl = None
        if clipped is not None:
            cl = np.flatnonzero(np.atleast_1d(clipped))
            self.clip_times.extend(t_s[cl].tolist())
            if cl.size:
                self.t_clip_last = float(t_s[cl[-1]])
                high = cl[np.max(np.abs(gyr_b[cl]), axis=1) > self.clip_gate_max]  # (inf: none)
                if high.size:
                    self.t_clip_high = float(t_s[high[-1]])
        if self.cfg.rest_relevel_s > 0:  # the still run, only while a saturation or a re-levelling is remembered
            if self.clip_times or self.at_rest:
                rest_rows(self.still, gyr_b, acc_b, self.rest_gyr2, self.rest_acc2, self.rest_spike2)
                self._rest_goes_on(n)
            elif self.still[0]:
                self.still[:] = 0.0
        g_s, a_s = np.empty((n, 3)), np.empty((n, 3))
        bad = vqf_inputs(gyr_b, acc_b, self.gyr_corr, self.vel, self.acc_v, self.centripetal, g_s, a_s)
        if bad:  # a hole: bridged with the last finite sample (counted)
            bad = ~(np.all(np.isfinite(gyr_b), 1) & np.all(np.isfinite(acc_b), 1))
            gyr_b, acc_b = gyr_b.copy(), acc_b.copy()
            gyr_b[bad] = np.nan
            acc_b[bad] = np.nan
            ffill_rows(gyr_b, self.last_imu[0])
            ffill_rows(acc_b, self.last_imu[1])
            self.holes += int(bad.sum())
            vqf_inputs(gyr_b, acc_b, self.gyr_corr, self.vel, self.acc_v, self.centripetal, g_s, a_s)
        if n:
            self.last_imu = (gyr_b[-1].copy(), acc_b[-1].copy())
        m = None
        if self.use_mag:
            m = np.full((n, 3), np.nan) if mag is None else np.atleast_2d(np.asarray(mag, np.float64))
            m = to_sensor(np.where(np.isfinite(m), m, 0.0))  # zero: VQF skips the magnetometer update
        g_v = g_s  # what VQF integrates: over each sample's own step (gyro_step_weighting)
        if self.step_weighting and n:
            w = np.empty(n)
            if step_weights(_read_only(t_s), self.t_prev, self.ts, GAP_PERIODS, w):
                g_v = g_s * w[:, None]
            self.t_prev = float(t_s[-1])
        out = self.f.updateBatch(g_v, a_s, m)
        q6, sig, bias = np.empty((n, 4)), np.empty(n), np.empty((n, 3))
        sp = self._sp
        e, alpha, var0, gain, samp, var_net = sp.tolist()  # (var_net: _var_net(), kept current by correct)
        sp[0] = vqf_outputs(_rows(out["quat6D"]), _rows(out["bias"]), a_s, g_s, self.gyr_corr, e, alpha, var0, gain, samp,
                            var_net, q6, bias, sig)  # fmt: skip
        if self.clip_gain_dt > 0 and (self.e_clip > 0 or (cl is not None and cl.size)):  # the saturation term
            flags = np.zeros(n, np.bool_)
            if cl is not None:
                flags[cl] = True
            self.e_clip = clip_sigma_rows(sig, flags, g_s, self.e_clip, self.clip_decay, self.clip_gain_dt,
                                          CLIP_SIGMA_CAP_RAD)  # fmt: skip
        q9 = q_nb_from_vqf(out["quat9D"]) if self.use_mag else None
        if n:
            self.t = float(t_s[-1])
        return q6, q9, sig, bias

    def update_one(self, t_s: float, gyr_b, acc_b, mag=None, clipped: bool = False):
        """:meth:`update` of one sample in plain floats (the live path: numpy's per-call overhead
        on one row cost 10× the arithmetic) → (q_nb, q_nb_9d or None, sigma, bias_b) as tuples and
        a float; the numbers of a one-row :meth:`update` (tested)."""
        gx, gy, gz = gyr_b
        ax, ay, az = acc_b
        g = [float(gx), float(gy), float(gz)]
        a = [float(ax), float(ay), float(az)]
        if self.gscale is not None:  # as update()
            sx, sy, sz = self.gscale
            g = [g[0] * sx, g[1] * sy, g[2] * sz]
        if clipped:
            self.clip_times.append(float(t_s))
            self.t_clip_last = float(t_s)
            if max(abs(g[0]), abs(g[1]), abs(g[2])) > self.clip_gate_max:  # as update()
                self.t_clip_high = float(t_s)
        if self.cfg.rest_relevel_s > 0:  # as update(): on the sample as it came (a hole is no rest)
            if self.clip_times or self.at_rest:
                rest_step(self.still, g[0], g[1], g[2], a[0], a[1], a[2], self.rest_gyr2, self.rest_acc2, self.rest_spike2)
                self._rest_goes_on(1)
            elif self.still[0]:
                self.still[:] = 0.0
        if not math.isfinite(g[0] + g[1] + g[2] + a[0] + a[1] + a[2]):  # a hole (a NaN or inf in the sum):
            g, a = [float(v) for v in self.last_imu[0]], [float(v) for v in self.last_imu[1]]  # the last finite sample
            self.holes += 1
        self.last_imu = (g, a)
        gc, v, av = self._gc, self._vel_f, self._acc_v_f
        gx, gy, gz = g[0] - gc[0], g[1] - gc[1], g[2] - gc[2]
        ax, ay, az = a
        if self.turn_on:  # a − (ω × v̂ + â)
            ax = ax - ((g[1] * v[2] - g[2] * v[1]) + av[0])
            ay = ay - ((g[2] * v[0] - g[0] * v[2]) + av[1])
            az = az - ((g[0] * v[1] - g[1] * v[0]) + av[2])
        k = 1.0  # VQF integrates the gyro over the sample's own step (as update(); × −k: S's y and z, exactly −gy·k)
        if self.step_weighting:
            k = step_weight(float(t_s) - self.t_prev, self.ts, GAP_PERIODS)
            self.t_prev = float(t_s)
        g1, a1 = self._g1, self._a1  # VQF's z-up sensor frame, into arrays made once (new ones cost more than VQF's update)
        g1[0], g1[1], g1[2] = gx * k, gy * -k, gz * -k
        a1[0], a1[1], a1[2] = ax, -ay, -az
        if self.use_mag:
            m = [0.0, 0.0, 0.0] if mag is None else [float(x) if math.isfinite(float(x)) else 0.0 for x in mag]
            self.f.update(g1, a1, np.array([m[0], -m[1], -m[2]]))
        else:
            self.f.update(g1, a1)
        out = self._out1
        vqf_output_one(self.f.getQuat6D(), self.f.getBiasEstimate()[0], a1, gx, -gy, -gz, self.gyr_corr, self._sp, out)
        o = out.tolist()
        q6, sig, bias = (o[0], o[1], o[2], o[3]), o[4], (o[5], o[6], o[7])
        q9 = q_nb_from_vqf_f(*self.f.getQuat9D().tolist()) if self.use_mag else None
        if self.clip_gain_dt > 0 and (clipped or self.e_clip > 0):  # the saturation term
            sig, self.e_clip = clip_sigma_step(sig, self.e_clip, bool(clipped), gx, -gy, -gz, self.clip_decay,
                                               self.clip_gain_dt, CLIP_SIGMA_CAP_RAD)  # fmt: skip
        self.t = float(t_s)
        return q6, q9, sig, bias

    def _var_net(self) -> float:
        """The network's share of σ²: while a gate acts, its σ; in a gap after one, the gap term."""
        return float(self.gate * (self.cfg.sigma_net_scale * self.sigma_net) ** 2) + self.var_gap

    # ------------------------------------------------------------------ network windows

    def correct(self, w: WindowOutput) -> None:
        """Apply the network's window made at the last sample pushed (see module doc)."""
        self._correct(w)
        # what update_one reads per sample, set once a window (the same numbers as the arrays: tolist is exact)
        self._sp[5] = self._var_net()
        self._gc, self._vel_f, self._acc_v_f = (tuple(x.tolist()) for x in (self.gyr_corr, self.vel, self.acc_v))

    def _correct(self, w: WindowOutput) -> None:
        c = self.cfg
        if self.slow:  # below the rates the network learned: nothing of the window acts; σ's E decays as VQF recovers
            self.gate, self.gate_parts, self.var_gap = 0.0, (0.0, 0.0, 0.0), 0.0
            self.clip_decay = math.exp(-self.ts / self.tau_acc)
            return
        shut = w.gnss_aided and not (c.gnss_aid_in_flight and w.gnss_fast)  # aided and slow: the gate shut
        vx, vy, vz = (0.0, 0.0, 0.0) if shut else _floats(w.vel_m_s)
        speed = math.sqrt(vx * vx + vy * vy + vz * vz)
        g_flight = min(1.0, max(0.0, (speed - c.speed_lo_m_s) / (c.speed_hi_m_s - c.speed_lo_m_s)))
        if not self.speed_gate:  # a vehicle the gate was not learned on (speed_gate_shut_for)
            g_flight = 0.0
        ct = self.clip_times  # enough saturated time in the last clip_hold_s (clip_min_s 0: one sample)
        while ct and self.t - ct[0] >= c.clip_hold_s:
            ct.popleft()
        g_clip = 1.0 if ct and len(ct) * self.ts >= c.clip_min_s else 0.0
        if g_clip and c.rest_relevel_s > 0 and self.still[0] * self.ts >= c.rest_relevel_s:
            g_clip = self._relevel()
        if self.at_rest:  # still at rest since: whatever windows still holding the tumble say of speed
            g_flight = 0.0
        if g_clip and self.t - self.t_clip_high < c.clip_hold_s:  # a range the network did not learn to declip
            g_clip = 0.0
        # σ's saturation term E decays as what brings the tilt back: the network's pull (sigma_clip_tau_s,
        # fitted where it acts) or, after a range it did not learn, VQF's accelerometer (its time constant)
        tau_e = self.tau_acc if -math.inf < self.t_clip_last <= self.t_clip_high else c.sigma_clip_tau_s
        self.clip_decay = math.exp(-self.ts / tau_e)
        # only the bias component perpendicular to gravity turns the tilt (the one along it turns the
        # heading, which no tilt measurement can check): that part is the evidence and the correction
        qw, qx, qy, qz = self.f.getQuat6D().tolist()
        b_src = w.gyr_bias_rad_s if w.fusion_bias_rad_s is None else w.fusion_bias_rad_s
        b_h = horizontal_bias(qw, qx, qy, qz, *_floats(b_src))
        if c.bias_gate_weight > 0 and not self.bias_latched:
            b = self.f.getBiasEstimate()[0].tolist()
            self.bias_latched = max(abs(b[0]), abs(b[1]), abs(b[2])) >= 0.95 * math.radians(c.bias_clip_deg_s)
            if c.bias_gate_fusion_deg_s > 0 and self.bias_fusion_gate and w.fusion_bias_rad_s is not None:  # 2 s on end
                over = _norm3(b_h) > math.radians(c.bias_gate_fusion_deg_s)
                over &= max(abs(b[0]), abs(b[1]), abs(b[2])) >= math.radians(c.bias_gate_vqf_deg_s)  # VQF agrees
                if c.bias_gate_thrust_deg > 0:  # ... in the network's domain
                    over &= self._thrust_cos() > math.cos(math.radians(c.bias_gate_thrust_deg))
                self.t_bias_over = (self.t_bias_over if self.t_bias_over is not None else self.t) if over else None
                self.bias_latched |= over and self.t - self.t_bias_over >= BIAS_EVIDENCE_S
        g_bias = c.bias_gate_weight if self.bias_latched else 0.0
        self.gate = max(g_flight, g_clip, g_bias)
        self.var_gap = 0.0
        if self.gate > 0:
            self.t_gated = self.t
        elif c.sigma_gap_gain > 0 and (self.t - self.t_gated <= c.sigma_gap_hold_s or self._bias_evidence(b_h)):
            d = down_in_body(*_floats(w.q_nb_wxyz))  # the target's up in S: (−d₀, d₁, d₂), as for the pull below
            ex, ey, ez = up_in_earth_f(qw, qx, qy, qz, -d[0], d[1], d[2])
            self.var_gap = (c.sigma_gap_gain * math.atan2(math.hypot(ex, ey), ez)) ** 2
        # what each gate did to the attitude (reported per record): none where nothing it drives is on
        pulls = c.pull_gain > 0
        self.gate_parts = (g_flight if pulls or c.centripetal or c.tau_acc_flight_s > 0 else 0.0, g_clip if pulls else 0.0,
                           g_bias)  # fmt: skip
        if c.tau_acc_flight_s > 0:
            tau = c.tau_acc_flight_s if g_flight > 0.5 else c.tau_acc_s
            if tau != self.tau_acc:
                self.f.setTauAcc(tau)
                self.tau_acc = tau
        self.sigma_net = float(w.sigma_rad)
        if c.centripetal:  # not where GNSS-aided: the receiver's acceleration is already out of the accelerometer
            g_cen = 0.0 if w.gnss_aided else g_flight
            v3 = [g_cen * vx, g_cen * vy, g_cen * vz]
            a3 = [g_cen * v for v in _floats(w.acc_m_s2)]
            self.vel, self.acc_v = np.array(v3), np.array(a3)
            self.turn_on = any(x != 0.0 for x in v3 + a3)  # (numpy's any on 3 floats cost more, per window)
        if self.bias_latched:  # the older fusion's bias where it runs (bias states), else the network's
            nb = _norm3(b_h)
            dz = math.radians(c.bias_deadzone_deg_s)
            self.gyr_corr = np.array(b_h) * max(0.0, 1.0 - dz / nb) if nb > 0 else np.zeros(3)
        k = c.pull_gain * (self.gate if self.bias_pull else max(g_flight, g_clip))  # (rule 33: no pull of the bias gate)
        if k > 0:
            d = down_in_body(*_floats(w.q_nb_wxyz))  # the target's down in body axes; its up in S: (−d₀, d₁, d₂)
            self.pull(tilt_pull_f(qw, qx, qy, qz, -d[0], d[1], d[2], float(k)))

    def _bias_evidence(self, b_h) -> bool:
        """The uncalibrated-gyro gate's evidence building (``sigma_gap_bias_evidence``, rule 22): the older fusion's
        horizontal bias ``b_h`` beyond ``quiet_bias_deg_s`` and VQF's own bias at ``bias_gate_vqf_deg_s`` or more."""
        c = self.cfg
        if not c.sigma_gap_bias_evidence or _norm3(b_h) <= math.radians(c.quiet_bias_deg_s):
            return False
        b = self.f.getBiasEstimate()[0].tolist()
        return max(abs(b[0]), abs(b[1]), abs(b[2])) >= math.radians(c.bias_gate_vqf_deg_s)

    def _relevel(self) -> float:
        """At rest after a saturation: VQF's tilt set to the still run's mean specific force (gravity
        alone) and the saturation gate shut (its remembered samples and E cleared) → the gate, 0.
        A mean under half of g (a free fall, no gravity to read) leaves it on → 1."""
        n, sx, sy, sz = self.still[:4].tolist()
        f = math.sqrt(sx * sx + sy * sy + sz * sz) / n
        if f < 0.5 * GRAVITY_M_S2:
            return 1.0
        qw, qx, qy, qz = self.f.getQuat6D().tolist()
        # the specific force at rest points up: the earth's down in body axes is −f, its up in S (f₀, −f₁, −f₂)
        self.pull(tilt_pull_f(qw, qx, qy, qz, sx, -sy, -sz, 1.0))
        # VQF's accelerometer low-pass still holds the tumble and the impact (a 16-g spike is degrees in a
        # 3-s mean): it starts again, as at VQF's own start, averaging the samples from here on
        st = self.f.state
        st["accLpState"] = np.full(6, np.nan)
        self.f.state = st
        self.clip_times.clear()
        if self.cfg.rest_keeps_run:
            self.rest_base = float(self.still[0])
        else:
            self.still[:] = 0.0
        self.e_clip = 0.0
        self.relevel_t.append(self.t)
        self.at_rest, self.rest_samples = True, 0
        return 0.0

    def _rest_goes_on(self, n: int) -> None:
        """After ``n`` more samples: the rest a re-levelling found ends with its still run."""
        if self.at_rest:
            self.rest_samples += n
            self.at_rest = self.still[0] == self.rest_base + self.rest_samples

    def _thrust_cos(self) -> float:
        """Cosine of the angle between the body's −z axis and the accelerometer's mean, the last sample
        of each window low-passed over :data:`THRUST_TAU_S` (1 while that mean is zero)."""
        a = self.last_imu[1]  # (a row of update's, or update_one's floats)
        a = a.tolist() if isinstance(a, np.ndarray) else [float(v) for v in a]
        if self.acc_mean is None:
            self.acc_mean = a
        else:
            k = min(1.0, max(0.0, self.t - self.t_acc_mean) / THRUST_TAU_S)
            m0, m1, m2 = self.acc_mean
            self.acc_mean = [m0 + k * (a[0] - m0), m1 + k * (a[1] - m1), m2 + k * (a[2] - m2)]
        self.t_acc_mean = self.t
        n = _norm3(self.acc_mean)
        return -self.acc_mean[2] / n if n > 0 else 1.0

    def pull(self, d) -> None:
        """Turn the filter's attitude by the earth-frame rotation ``d`` (horizontal axis): its
        inclination quaternion and, with it, its low-passed accelerometer states."""
        st = self.f.state
        aq = np.array(st["accQuat"], np.float64)
        lp = np.array(st["lastAccLp"], np.float64)
        s = np.array(st["accLpState"], np.float64)
        dw, dx, dy, dz = _floats(d)
        turn_acc_state(aq, dw, dx, dy, dz, lp, s)
        st["accQuat"], st["lastAccLp"], st["accLpState"] = aq, lp, s
        self.f.state = st
