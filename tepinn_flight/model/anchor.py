"""Filter-anchored TE-PINN: a VQF filter does the attitude; the network corrects what VQF cannot know.

The physics filter is VQF (Laidig & Seel 2023, the ``vqf`` package): strapdown integration of the
gyro, the accelerometer's gravity low-passed in a quasi-inertial frame, gyro-bias estimation in
motion and at rest, and, with a magnetometer, heading with magnetic-disturbance rejection. With
every learned correction at zero this module *is* VQF, bit for bit (tested).

The network (TE-PINN, :mod:`.network`) runs on each 3.2 s window of IMU tokens (25 Hz) and gives
its tilt ``q``, a σ, a gyro bias ``b̂`` and, from its transport-theorem head, a body velocity ``v̂``
and its rate ``â``. Each enters only where there is run-time evidence that VQF's assumptions fail:

- **flight speed** (``|v̂|`` between ``speed_lo_m_s`` and ``speed_hi_m_s`` ramps a gate 0 → 1): an
  aircraft at tens of m/s reads ``ω × v + v̇`` besides gravity, for seconds on end in a turn or a
  loop; VQF's low-pass takes that for gravity. The gate removes ``ω × v̂ + â`` from the
  accelerometer VQF sees (per sample, with the current gyro) and pulls VQF's tilt toward the
  network's. Hand-held and multirotor motion stays below the gate (|v̂| < 10 m/s typically, on the training
  multirotors 0.2 % of windows above it: misreadings), and a record that names such a vehicle keeps it shut
  (``speed_gate_shut_for``, rule 24).
- **gyro saturation** (at least ``clip_min_s`` of samples with the gyro clipped within ``clip_hold_s``:
  the ``clipped`` argument of :meth:`AnchoredVQF.update`, a record's ``gyr_clipped``): the integrated
  rate is wrong, so VQF's tilt is pulled toward the network's window tilt (its physics inputs are
  clip-aware), and while the gate is on the estimate's tilt *is* the pull target's — the older fusion's,
  propagated with the network's declipping — on VQF's heading (``clip_tilt_from_fusion``, rule 17). An accelerometer at its range leaves the integrated rate right and does not open it;
  nor does a handful of clipped samples, whose missed rotation is smaller than the network's error
  on real sensors. Only at the gyro ranges the network learned to declip (``clip_gate_max_deg_s``: a
  clipped reading beyond it — an autopilot's ±2000 °/s — keeps the pull shut; VQF's accelerometer brings
  the tilt back and E decays at its pace). **At rest** it shuts early: once the samples since the saturation hold a still run
  of ``rest_relevel_s`` (VQF's rest thresholds on the raw samples; a mean of at least half of g), the
  accelerometer *is* the tilt — VQF's tilt is set to it, its accelerometer low-pass starts again (it
  still holds the tumble or an impact), E is cleared, and while that rest lasts no gate opens (after a
  crash the windows hold the tumble for 3 s and may read a flight speed).
- **gyro bias beyond VQF's clip** (VQF's bias estimate reaches ``bias_clip_deg_s``, an
  uncalibrated gyro; or the older fusion's horizontal bias stays beyond ``bias_gate_fusion_deg_s``
  for 2 s while VQF's own estimate reaches ``bias_gate_vqf_deg_s`` and the accelerometer's 10-s mean
  lies within ``bias_gate_thrust_deg`` of the body's −z axis, the vehicles the network learned): from
  then on, in that segment, the network's bias beyond ``bias_deadzone_deg_s`` is removed from the
  gyro VQF sees, and its tilt pulls with weight ``bias_gate_weight``.

**Below the rates the network learned** (``min_network_rate_hz``, 20 Hz: a segment whose sample period, as the
filter takes it, is longer) no gate opens at all: the windows are out of the network's domain (rule 18).

**Each gyro sample over its own time step** (``gyro_step_weighting``, rule 19): VQF integrates every sample over
one fixed period Ts, so it is fed the gyro × Δt/Ts (Δt the step from the segment's previous sample): a sample a
logger lost keeps its rotation, and jittered stamps are no gyro scale error. Regular stamps: bit for bit as VQF.

**Quiet blocks** (``quiet_blocks``): where every gate stays shut the estimate is VQF's whatever the
windows say, so the network need not run there. Windows come in the older fusion's bias-feedback
blocks (``bias_feedback_windows`` tokens, 1 s); a block whose first window and those of the last
``quiet_memory_blocks`` blocks show |v̂| below ``quiet_speed_m_s`` (the network reads a fixed wing's
speed only while it turns; |v̂| is not read on a vehicle whose flight-speed gate stays shut, rule 26:
``quiet_speed_needs_gate``) and the older fusion's gyro bias below ``quiet_bias_deg_s`` (so
neither the flight-speed nor the bias gate can open before the next block) runs only that window,
and those holding a saturated token (the clip gate); a segment's first ``quiet_after_blocks`` and any
other block run every window (after the start-up, every ``busy_stride``-th, and every one holding a
saturated token: :meth:`AnchorConfig.runs_window`; the shipped 1 is every window). Decided from what has been seen, so live and offline run the same
windows.

A *pull* by a fraction k turns VQF's attitude about a horizontal earth axis by k times its tilt
difference to the network's (heading untouched). VQF keeps its tilt in the low-passed
accelerometer, so the pull rotates that filter state with it (``accLpState``, ``lastAccLp``) —
turning only ``accQuat`` would be undone at the next sample.

σ (``sigma_rad``, per-axis σ of the 2-D tilt error): ``σ² = σ₀² + (c·e)² + g·(|ω|·Δt)²/12 +
w·(s·σ_net)² + E²`` with e a 1-s average of the angle between the accelerometer VQF sees and its gravity
(motion acceleration the filter is averaging out), the sampling term (|ω| the gyro VQF integrates,
Δt its sample period: how far the attitude turns within one sample, which a sample rate of 25–50 Hz
makes large in fast motion), w the gate, σ_net the network's σ, and E the tilt a saturated gyro may
have lost (each sample with the gyro clipped adds k·|ω|·Δt, |ω| its clipped reading; E decays with
time constant τ after; at most π/2: ``sigma_clip_gain``, ``sigma_clip_tau_s``, fitted on simulated
flights that clip); and, where no gate acts but one did within ``sigma_gap_hold_s``, (k·D)² with D the
tilt angle between the network's pull target and VQF (``sigma_gap_gain``: the witness the gate just
stopped using, session 26) — also while the uncalibrated-gyro gate's evidence builds before it latches
(``sigma_gap_bias_evidence``, rule 22: VQF then carries a bias beyond its clip);
σ₀ and c fitted on real files with a trusted reference (and g chosen there, by the fine-tuning).

Frames: VQF works in a z-up sensor frame ``S`` (body FRD turned 180° about x) and a z-up earth
frame; conversions happen only at this module's edges (body FRD / NED outside). The arithmetic
between the network's windows (the samples into ``S``, VQF's outputs out of it with σ, the tilt
pull) is compiled in :mod:`.anchor_kernels`, where the frames are defined.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field, replace
from typing import Literal

import numpy as np

from ..config import check_choice, check_range
from ..conventions import GRAVITY_M_S2
from ..errors import ConfigError
from ..quat_scalar import down_in_body
from ..record_gaps import GAP_PERIODS
from ..vehicle_class import CLASSES as VEHICLE_CLASSES
from ..vehicle_class import vehicle_class
from .anchor_kernels import FLIP as _FLIP
from .anchor_kernels import Q_NED_ENU, Q_SENSOR_BODY  # noqa: F401  (VQF's frames; peers import them from here)
from .anchor_kernels import (clip_sigma_rows, clip_sigma_step, fusion_tilt_f, fusion_tilt_rows, horizontal_bias, q_nb_from_vqf_f, q_nb_rows, rest_rows,
                             rest_step, step_weight, step_weights, tilt_pull_f, turn_acc_state,
                             up_in_earth_f, vqf_inputs, vqf_output_one, vqf_outputs)  # fmt: skip
from .fusion import FusionConfig
BIAS_EVIDENCE_S = 2.0  # the older fusion's bias must stay beyond its gate this long
THRUST_TAU_S = 10.0  # the accelerometer's mean direction (bias_gate_thrust_deg) is low-passed over this
CLIP_SIGMA_CAP_RAD = math.pi / 2  # the saturation term's most: a tilt σ of 90° says nothing is known
MODES = ("6d", "9d", "auto")


@dataclass(frozen=True)
class AnchorConfig:
    """The filter-anchored estimator. Defaults are the shipped model's."""

    enabled: bool = True  # False: the checkpoint's older network-centred fusion (FusionConfig)
    mode: Literal["6d", "9d", "auto"] = "6d"  # "6d", "9d" (magnetometer heading), "auto" (9-D when the record has a magnetometer)
    tau_acc_s: float = 3.0  # VQF's accelerometer low-pass (its default)
    # ... while the flight-speed gate is on (> ½): the accelerometer then holds ω × v residuals, so VQF
    # leans on the gyro and the pulls (0: tau_acc_s)
    tau_acc_flight_s: float = 10.0
    bias_clip_deg_s: float = 2.0  # VQF's bias limit (its default)
    pull_gain: float = 0.8  # fraction of the tilt difference removed per window at gate 1
    # (the pulls pull toward the older network-centred fusion of the same windows run alongside:
    # gyro-propagated, Kalman-weighted by the network's σ, gyro-bias states, the windows' noise
    # averaged out; pulling toward each window's own tilt, the option pull_target = "window" that
    # was removed, measured worse: validation flights 6.21° against 5.05°)
    speed_lo_m_s: float = 20.0  # flight-speed gate: 0 below, 1 above speed_hi_m_s
    speed_hi_m_s: float = 30.0
    # ... and stays shut on a record whose log names a vehicle of these classes (:mod:`..vehicle_class`; unnamed:
    # as any other): the gate's correction was learned on fixed-wing flight only. On the training campaign the
    # shipped network's |v̂| reached 20 m/s on 46–84 % of the c172x's windows but on 0.2 % of the F450's (flights
    # that never fly that fast) and none of the agile quad's: on a multirotor an opening is a misreading; and a
    # network that never saw hand-held motion opened it on BROAD (2.41° against VQF's 0.68°; with the rule 0.63°).
    # Session 32, rule 24; () — any vehicle — before
    speed_gate_shut_for: tuple[str, ...] = ("multirotor", "handheld")
    centripetal: bool = True  # remove ω × v̂ + â (times the flight gate) from VQF's accelerometer
    clip_hold_s: float = 4.0  # gyro-saturation gate stays on this long after the last clipped sample
    # ... and opens only where the last clip_hold_s hold at least clip_min_s of clipped samples (0: one)
    clip_min_s: float = 0.1
    # ... and shuts early at rest: while it is on, once the samples since its last clipped one hold a
    # still run this long (|ω| below rest_gyr_deg_s, the accelerometer within rest_acc_m_s2 of the run's
    # mean, that mean at least half of g: gravity alone), VQF's tilt is set to the accelerometer's
    # and the saturation term E cleared — after a tumble past the gyro's range (a crash) the network's
    # windows still hold the tumble for 3 s while the accelerometer at rest is the tilt (0: off,
    # before session 23). VQF's own rest thresholds (restThGyr, restThAcc)
    rest_relevel_s: float = 0.5
    rest_gyr_deg_s: float = 2.0
    rest_acc_m_s2: float = 0.5
    # ... a sample up to this × rest_gyr_deg_s keeps the run while the run's mean gyro stays below rest_gyr_deg_s: a
    # noisy gyro's single samples (2 °/s of white noise per sample at 400 Hz broke every run after a crash past the
    # range: crash_probe.py --gyro-noise 2, at rest 35.9° / 5.3° / 3.4° against 0.2° / 1.8° / 0.0°). Session 31, rule 23;
    # 1: each sample below rest_gyr_deg_s (before it)
    rest_spike_factor: float = 4.0
    # ... and the re-levelling keeps the still run it was made from: "at rest" (no gate opens) lasts while that run goes
    # on — not while a fresh one, started at the re-levelling, grows in lockstep (a fresh run's first samples are the
    # fragile ones on a noisy gyro: at rest ended 16 samples after the re-levelling, then the flight-speed gate pulled
    # the tilt toward windows still holding the tumble). Rule 23; False: before it
    rest_keeps_run: bool = True
    # ... and pulls only for gyros whose range the network learned to declip: a clipped sample reading
    # more than this on an axis (the ±2000 °/s of autopilot gyros, past their range) keeps the pull shut
    # for clip_hold_s — the network saw saturation only at ±400 °/s (the training's tactical gyro; this
    # is 1.25× that), and its declipping, learned there, turned a roll just past ±2000 °/s into a
    # tilt 140° off (benchmarks/flip_probe.py). VQF then integrates the reading and the accelerometer
    # brings the tilt back; σ's saturation term, the re-levelling at rest and the other gates act as
    # anywhere (0: any range, before session 23)
    clip_gate_max_deg_s: float = 500.0
    # ... and while it is on, the estimate's tilt is the older fusion's (the pull target, run alongside, causal)
    # on the filter's heading: between windows the filter integrates the clipped gyro, which the pulls can only
    # take back a window later; the older fusion propagates with the network's declipping (rule 17, session 28;
    # False: the filter's pulled tilt, before it)
    clip_tilt_from_fusion: bool = True
    # no network gate at all on a segment whose IMU is slower than this (its sample period as the filter takes it):
    # the network learned 25 Hz and faster, and below the tool's own 20 Hz (record.MIN_ESTIMATION_RATE_HZ, a log too
    # slow for windowed estimation: telemetry tlogs) its windows fired gates that cost a 4-Hz VTOL log 12.4° against
    # VQF's 8.0° (rule 18, session 28); 0: any rate (before it)
    min_network_rate_hz: float = 20.0
    # each gyro sample integrated over its own time step: VQF takes a fixed sample period Ts (a segment's first
    # steps' median), so it is fed gyro × dt/Ts (dt the step from the segment's previous sample, clamped to
    # [0, GAP_PERIODS]; the first sample 1): a lost sample's rotation is not lost, and jittered time stamps do
    # not turn into a gyro scale error (rule 19, session 29: the seen BROAD trials at 48 Hz with 2 % of their
    # samples lost, and with stamps jittered). Regular stamps: bit for bit as without it; False: before it
    gyro_step_weighting: bool = True
    bias_gate_weight: float = 0.6  # pull weight while the uncalibrated-gyro gate is on (0: never)
    bias_deadzone_deg_s: float = 2.0  # the network's bias beyond this is removed from the gyro
    # ... and the gate also opens when the older fusion's bias estimate (pull target "fusion") exceeds
    # this on an axis (calibrated autopilot gyros and BROAD stay below 1 °/s there; 0: off)
    bias_gate_fusion_deg_s: float = 3.0
    # ... while VQF's own bias estimate reaches this on an axis (0: the older fusion's evidence alone,
    # before session 16). Out of its domain, the older fusion's bias can pass 3 °/s within seconds
    # of a record that starts mid-motion: seen BROAD trials cut to start during fast rotation latched
    # the gate on it alone (3 of 51, each then over the per-file bound; VQF's bias there 0.04–0.06 °/s;
    # where the training flights' uncalibrated gyros latched it, VQF's bias was 0.22–1.2 °/s)
    bias_gate_vqf_deg_s: float = 0.2
    # ... and only while the accelerometer's mean over the last THRUST_TAU_S points within this of the
    # body's −z axis (thrust, lift, or gravity near level: the vehicles the network learned from; 0:
    # off, before session 16). A hand-held IMU held on its side reads it at 90°: the network's tilt is
    # out of its domain there and the older fusion's bias with it (seen BROAD trials mounted 90° about
    # x latched the gate on 12 of 17, each then over the per-file bound)
    bias_gate_thrust_deg: float = 60.0
    sigma_floor_deg: float = 0.45  # σ₀ (fitted on the 17 BROAD trials the network was trained or validated on)
    # c: 0.025 before session 17; refitted with the sampling term on the same trials, σ₀ kept (c = 0
    # nearest NEES 2 at >= 97.5 % within 3σ: VQF's 3-s low-pass leaves the motion acceleration that e
    # measures out of its tilt). `train --init` fits σ₀, c and g again on a vehicle's own logs
    sigma_acc_gain: float = 0.0
    # g: σ² += g·(|ω|·Δt)²/12, the attitude's change within one sample period Δt (std of an estimate
    # held over a sample against a reference taken anywhere in it); 1 the physical value, 0 off
    # (checkpoints before session 17). The seen BROAD trials decimated to 48 / 26 Hz: without it
    # NEES 3.03 / 9.15, 90.7 / 72.6 % within 3σ; with it (c = 0) 1.03 / 1.77, 99.1 / 97.9 %
    sigma_sampling_gain: float = 1.0
    sigma_net_scale: float = 1.0  # s
    sigma_acc_tau_s: float = 1.0
    # k and τ of the gyro-saturation term E (σ² += E²; 0: off, before session 20): a clipped sample
    # adds k·|ω|·Δt (|ω| its clipped reading, of which k went missing), E decays over τ after. Fitted
    # by fit_sigma's rule (per-file NEES nearest 2 with ≥ 97 % within 3σ) on simulated multirotor
    # flights whose ±400 °/s gyro clips (training flights at 400, 50, 25 Hz; seeds 77 and 78 at 400,
    # 50 Hz as validation); tested on fresh ones (seed 79, 24 flights): per-file NEES 19.17 → 1.23,
    # 77.4 → 96.6 % within 3σ at 400 Hz (50 Hz: 13.25 → 1.05, 79.2 → 97.3 %). No shared real file
    # clips: σ there is unchanged (docs/design-log.md, session 20)
    sigma_clip_gain: float = 0.3
    sigma_clip_tau_s: float = 1.75
    # k and T of the gap term: at a window where no gate acts but one acted within the last T s (a fixed wing's
    # short gaps between its flight-speed gate's spells, in vertical manoeuvres; a tactical multirotor between
    # saturation spells), σ² += (k·D)² until the next window, D the tilt angle between the network's pull target
    # and VQF's — what the gate just stopped using is the witness of VQF's error there. No gate ever acts on a
    # real file we have: σ there is unchanged. Session 26, rule 16's fit on every 4th training flight (k = 1,
    # T = min_stretch_s a priori; c172x flights' NEES 9–101 → 0.5–2.2); 0: off (checkpoints before it)
    sigma_gap_gain: float = 1.0
    sigma_gap_hold_s: float = 30.0
    # ... and while the uncalibrated-gyro gate's evidence builds, before it latches: the older fusion's horizontal
    # bias beyond quiet_bias_deg_s and VQF's own at bias_gate_vqf_deg_s or more on an axis (its existing thresholds).
    # VQF then carries a bias beyond its clip (training flights' uncalibrated IMUs: tilt error 8–20° for 8–13 s with σ
    # at its floor, NEES 300–1800 there) and the network's target is the witness. It did not appear on any calibrated
    # gyro we have (the 17 BROAD trials and the 6 held-out drone logs: σ identical). Session 31, rule 22; False: before it (checkpoints without the key)
    sigma_gap_bias_evidence: bool = True
    # quiet blocks (speed): the windows matter only where a gate may open. A block of the older
    # fusion's bias feedback (its bias_feedback_windows tokens) whose first window shows |v̂| below
    # quiet_speed_m_s and a fusion gyro bias below quiet_bias_deg_s on every axis runs only that window
    # (and those holding a saturated token); False: the network runs on every token
    quiet_blocks: bool = True
    quiet_speed_m_s: float = 15.0  # ... on the windows of the last quiet_memory_blocks blocks too
    quiet_memory_blocks: int = 10
    quiet_bias_deg_s: float = 1.5
    quiet_after_blocks: int = 10  # a segment's first blocks run every window (the older fusion's bias converges)
    # |v̂| makes a block busy only where the flight-speed gate may open for the record's vehicle (speed_gate_shut_for):
    # it feeds nothing else (rule 26, session 36); False: on any vehicle (before it)
    quiet_speed_needs_gate: bool = True
    # a busy block after those runs every busy_stride-th window (and every one holding a saturated token)
    busy_stride: int = 1
    # the vehicle's gyro calibration, per body axis (FRD): VQF integrates gyro × gyro_scale. The
    # shipped model: 1; `train --init` fits it on a vehicle's logs against their reference
    gyro_scale: tuple[float, float, float] = (1.0, 1.0, 1.0)
    # offline, the gyro's per-axis scale is also read from the record itself (rests' gravity vs the
    # gyro's turn between them) and applied on evidence only (:mod:`.gyro_selfcal`); live: not
    gyro_selfcal: bool = True
    # offline, the motion acceleration the record's GNSS velocity shows is taken out of the
    # accelerometer (:mod:`.gnss_aid`; records without GNSS velocity: nothing changes); live: not
    gnss_aid: bool = True
    # ... also in fast flight: where the aid holds at a window's end and the receiver's ground speed is
    # at least GnssAidConfig.max_speed_m_s, the flight-speed gate keeps its pull and time constant and
    # drops only its centripetal term ω × v̂ + â, which the receiver measured (session 15). Slower, and
    # always with False (session 14: the aid stops at max_speed_m_s), aided windows shut the gate:
    # the receiver says the vehicle is not flying fast, whatever v̂ says
    gnss_aid_in_flight: bool = True
    # offline: the accelerometer divided by the scale the record itself shows at its quiet, steady
    # moments (rest, hover, straight flight) where that is clearly not 1 (:mod:`.accel_scale`: ≥ 10 %;
    # a board at 0.8 g); every other record is estimated bit for bit as without it. Live: read causally
    # from the first quiet seconds and applied from then on (:class:`.accel_scale.AccelScaleTracker`)
    accel_scale_selfcal: bool = True
    # offline: the tilt of every long stretch where no gate acts is VQF's run forward and backward on the
    # same inputs (:mod:`.smoother`, ``vqf.offlineVQF``; heading kept); live: never (`estimate --no-smooth`
    # gives the causal estimate the bridge gives). Opt-in from session 15 (farther from an autopilot's own
    # causal estimate on the held-out drone logs: 0.37 -> 0.38°); the shipped default since session 25, on
    # accuracy against a true attitude: the BROAD trials each by a network that never saw it 0.633 -> 0.511°
    # (VQF 0.683), training flights 3.84 -> 3.59°, crash and flip probes better on all 18 (docs/estimator.md, rule 10)
    smoother: bool = True
    # the older fusion's settings (the checkpoint's fusion_config; filled in when loaded)
    fusion_config: FusionConfig | None = field(default=None, compare=False)

    def __post_init__(self):
        if isinstance(self.fusion_config, dict):  # from a checkpoint's JSON-like dict
            object.__setattr__(self, "fusion_config", FusionConfig(**self.fusion_config))
        check_choice("mode", self.mode, MODES)
        gs = tuple(self.gyro_scale) if isinstance(self.gyro_scale, (list, tuple)) else ()  # (a checkpoint: a list)
        if len(gs) != 3:
            raise ConfigError(f"'gyro_scale' must be three factors (x, y, z), got {self.gyro_scale!r}")
        for v in gs:
            check_range("gyro_scale", v, 0.5, 2.0)
        object.__setattr__(self, "gyro_scale", tuple(float(v) for v in gs))
        shut = self.speed_gate_shut_for
        shut = (shut,) if isinstance(shut, str) else tuple(shut) if isinstance(shut, (list, tuple)) else None
        if shut is None or any(v not in VEHICLE_CLASSES for v in shut):
            raise ConfigError(f"'speed_gate_shut_for' must name vehicle classes among {', '.join(VEHICLE_CLASSES)}, "
                              f"got {self.speed_gate_shut_for!r}")  # fmt: skip
        object.__setattr__(self, "speed_gate_shut_for", shut)
        for name in ("tau_acc_s", "bias_clip_deg_s", "sigma_acc_tau_s", "sigma_clip_tau_s"):
            check_range(name, getattr(self, name), 0, None, lo_open=True)
        check_range("tau_acc_flight_s", self.tau_acc_flight_s, 0, None)  # 0: tau_acc_s
        check_range("pull_gain", self.pull_gain, 0, 1)
        check_range("bias_gate_weight", self.bias_gate_weight, 0, 1)
        check_range("speed_lo_m_s", self.speed_lo_m_s, 0, None)
        check_range("quiet_after_blocks", self.quiet_after_blocks, 0, 10**6)
        check_range("quiet_memory_blocks", self.quiet_memory_blocks, 0, 10**6)
        check_range("busy_stride", self.busy_stride, 1, 10**6)
        check_range("speed_hi_m_s", self.speed_hi_m_s, self.speed_lo_m_s, None, lo_open=True)
        check_range("bias_gate_thrust_deg", self.bias_gate_thrust_deg, 0, 180)
        check_range("min_network_rate_hz", self.min_network_rate_hz, 0, 100000)
        check_range("rest_spike_factor", self.rest_spike_factor, 1, None)
        for name in ("clip_min_s", "quiet_speed_m_s", "quiet_bias_deg_s", "clip_hold_s", "rest_relevel_s", "clip_gate_max_deg_s", "rest_gyr_deg_s", "rest_acc_m_s2", "bias_deadzone_deg_s", "bias_gate_fusion_deg_s", "bias_gate_vqf_deg_s", "sigma_floor_deg", "sigma_acc_gain",
                     "sigma_net_scale", "sigma_sampling_gain", "sigma_clip_gain", "sigma_gap_gain", "sigma_gap_hold_s"):  # fmt: skip
            check_range(name, getattr(self, name), 0, None)

    def quiet_in(self, fusion: FusionConfig) -> int:
        """Tokens per quiet block with the older fusion ``fusion`` alongside (0: no quiet blocks)."""
        return fusion.bias_feedback_windows if self.quiet_blocks else 0

    def block_busy(self, block: int, speed_m_s: float, fusion_bias_rad_s, speed_gate: bool = True) -> bool:
        """Whether block ``block`` (0: a segment's first) runs every window: too early in the segment,
        or |v̂| (``speed_m_s``: the largest on the windows of the last ``quiet_memory_blocks`` blocks and
        this block's first) or the older fusion's gyro bias then (body axes) say a gate may open in it
        (never below the flight-speed gate's own threshold). ``speed_gate``: whether that gate may open for the
        record's vehicle (:func:`speed_gate_allowed`); where it may not, |v̂| counts only without
        ``quiet_speed_needs_gate``."""
        if block < self.quiet_after_blocks:
            return True
        if self.reads_speed(speed_gate) and speed_m_s >= min(self.quiet_speed_m_s, self.speed_lo_m_s):
            return True
        b = [abs(float(x)) for x in fusion_bias_rad_s]  # three floats: numpy's max of an array cost 27 µs a block
        return not any(x != x for x in b) and max(b) >= math.radians(self.quiet_bias_deg_s)  # NaN: as numpy's max, not busy

    def reads_speed(self, speed_gate: bool = True) -> bool:
        """Whether :meth:`block_busy` reads |v̂| for a record whose flight-speed gate may open (``speed_gate``) or not:
        where it does not, the caller need not compute it."""
        return speed_gate or not self.quiet_speed_needs_gate

    def runs_window(self, block: int, j: int, busy: bool, saturated: bool) -> bool:
        """Whether the ``j``-th window (0: first) of block ``block`` runs, in a busy block or a quiet
        one, holding a saturated token or not (the live estimator decides by this; offline by
        :meth:`runs_windows`, the same rule on arrays)."""
        if j == 0 or saturated:
            return True
        if not busy:
            return False
        return block < self.quiet_after_blocks or j % self.busy_stride == 0

    def runs_windows(self, block: int, j: np.ndarray, busy: bool, saturated: np.ndarray) -> np.ndarray:
        """:meth:`runs_window` of the windows ``j`` (ints) of one block, ``saturated`` (bools) each → (bool array)."""
        j = np.asarray(j, np.int64)
        run = (j == 0) | np.asarray(saturated, bool)
        if busy:
            run |= (j % self.busy_stride == 0) if block >= self.quiet_after_blocks else True
        return run

    @property
    def learned_off(self) -> "AnchorConfig":
        """The same filter with every learned correction switched off: plain VQF."""
        import dataclasses

        return dataclasses.replace(self, pull_gain=0.0, centripetal=False, tau_acc_flight_s=0.0, bias_gate_weight=0.0,
                                   bias_deadzone_deg_s=1e9, sigma_net_scale=0.0, gyro_scale=(1.0, 1.0, 1.0),
                                   gyro_selfcal=False, gnss_aid=False, smoother=False,
                                   accel_scale_selfcal=False, rest_relevel_s=0.0, sigma_gap_gain=0.0,
                                   clip_tilt_from_fusion=False, gyro_step_weighting=False)  # fmt: skip


@dataclass
class WindowOutput:
    """The network's outputs for one window (body FRD / NED; SI units)."""

    q_nb_wxyz: np.ndarray  # (4,) tilt (zero yaw)
    sigma_rad: float
    gyr_bias_rad_s: np.ndarray  # (3,)
    vel_m_s: np.ndarray  # (3,) body velocity v̂ (zeros where the model has no such head)
    acc_m_s2: np.ndarray  # (3,) its rate â
    fusion_bias_rad_s: np.ndarray | None = None  # (3,) the older fusion's gyro-bias estimate (pull target "fusion")
    # the GNSS aid holds at this window's end (:mod:`.gnss_aid`): the receiver measured the motion
    # acceleration, already out of the accelerometer, so the flight-speed gate's centripetal term
    # (ω × v̂ + â) stays off; its pull and time constant act as elsewhere (with
    # AnchorConfig.gnss_aid_in_flight and the receiver's ground speed at least GnssAidConfig's
    # max_speed_m_s, ``gnss_fast``; else the whole gate stays shut), as do the other gates
    gnss_aided: bool = False
    gnss_fast: bool = False


def to_sensor(v_b: np.ndarray) -> np.ndarray:
    """Body FRD vectors → VQF's z-up sensor frame."""
    return np.ascontiguousarray(np.asarray(v_b, np.float64) * _FLIP)


def q_nb_from_vqf(q_es: np.ndarray) -> np.ndarray:
    """VQF's sensor → z-up earth quaternion(s) (..., 4) → body FRD → NED."""
    q_es = np.asarray(q_es, np.float64)
    out = np.empty(q_es.shape)
    q_nb_rows(_rows(q_es.reshape(-1, 4)), out.reshape(-1, 4))
    return out


def tilt_pull_quat(q_es, up_s, fraction: float) -> np.ndarray:
    """Earth-frame rotation that turns the filter attitude ``q_es`` by ``fraction`` of the tilt
    between it and a target whose up direction in sensor axes is ``up_s``; about a horizontal
    axis, so the heading is untouched (:func:`.anchor_kernels.tilt_pull_f`)."""
    return np.array(tilt_pull_f(*(float(v) for v in q_es), *(float(v) for v in up_s), float(fraction)))


def _rows(x, ndim: int = 2) -> np.ndarray:
    """``x`` as the compiled kernels take it: float64, C-contiguous, writable, ``ndim`` dimensions
    (one row: a block of one); a copy only when it is not (a record's columns are read-only,
    Fortran-ordered)."""
    x = np.asarray(x, np.float64)
    if x.ndim < ndim:
        x = x.reshape((1,) * (ndim - x.ndim) + x.shape)
    if not (x.flags.c_contiguous and x.flags.writeable):
        x = x.copy()
    return x


class AnchoredVQF:
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
            if c.bias_gate_fusion_deg_s > 0 and w.fusion_bias_rad_s is not None:  # for 2 s on end
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
        k = c.pull_gain * self.gate
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


def speed_gate_allowed(config: AnchorConfig, vehicle: str | None) -> bool:
    """Whether the flight-speed gate may open for ``vehicle`` (a record's ``vehicle_type``, an autopilot's MAV_TYPE
    name or a :mod:`..vehicle_class` class; None: not known): not for the classes ``config.speed_gate_shut_for``
    names (rule 24, session 32)."""
    return vehicle_class(vehicle) not in config.speed_gate_shut_for


def with_fusion_tilt(q_nb: np.ndarray, q_fusion: np.ndarray) -> np.ndarray:
    """Rows of ``q_nb`` (body→NED) given the tilt of ``q_fusion``'s rows on their own heading
    (:attr:`AnchorConfig.clip_tilt_from_fusion`; the smoother's tilt formula). A row whose fusion estimate is
    missing, or whose two down directions are opposite (no shortest turn between them), stays ``q_nb``'s."""
    q_nb = np.ascontiguousarray(np.atleast_2d(q_nb), np.float64)
    out = np.empty_like(q_nb)
    fusion_tilt_rows(q_nb, np.ascontiguousarray(np.atleast_2d(q_fusion), np.float64), out)  # the live step, per row
    return out


def _read_only(x) -> np.ndarray:
    """``x`` C-contiguous and read-only (a view where it is C-contiguous already): a record's columns are read-only, so
    that is the one signature a kernel reading them is compiled for, whoever calls it (a caller's writable array was
    a second compile: tests/test_compiled_signatures.py)."""
    v = np.ascontiguousarray(x).view()
    v.flags.writeable = False
    return v


def _floats(v) -> list:
    """A short vector (array, tuple, list) as Python floats."""
    return np.asarray(v, np.float64).tolist()


def _norm3(v) -> float:
    return math.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2])


def ffill_rows(arr, first=None):
    """Forward-fill NaN rows of ``arr`` in place (from ``first`` before the first finite row)."""
    bad = ~np.all(np.isfinite(arr.reshape(len(arr), -1)), axis=1)
    if not bad.any():
        return
    idx = np.where(~bad, np.arange(len(arr)), -1)
    np.maximum.accumulate(idx, out=idx)
    have = idx >= 0
    arr[bad & have] = arr[idx[bad & have]]
    if first is not None:
        arr[~have] = first


def with_busy_stride(settings, n: int | None, label: str = "this model"):
    """``settings`` running every ``n``-th window of a busy block (after a segment's first
    ``quiet_after_blocks``; every window holding a saturated token still runs): the speed knob of
    ``estimate``/``evaluate``/``bridge --busy-stride`` for flights that keep the network busy (fixed
    wing), at some accuracy (docs/results.md, "Speed"). ``n`` None or 0: unchanged. Only the anchored
    estimator has busy blocks: for the older network-centred fusion, a :class:`ConfigError`."""
    if not n:
        return settings
    if not isinstance(settings, AnchorConfig):
        raise ConfigError(f"--busy-stride {n}: {label} runs the older network-centred fusion, which needs every window")
    return replace(settings, busy_stride=int(n))
