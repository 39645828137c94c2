"""Filter-anchored TE-PINN: a VQF filter does the attitude; the network corrects what VQF cannot know.

The physics filter is VQF (Laidig & Seel 2023): strapdown integration of the gyro, the accelerometer's
gravity low-passed in a quasi-inertial frame, gyro-bias estimation in motion and at rest, and, with a
magnetometer, heading with magnetic-disturbance rejection — the ``vqf`` package's filter, compiled
(:mod:`.vqf_kernel`, the package's C++ to the bit). With every learned correction at zero this module
*is* the ``vqf`` package's VQF, bit for bit (tested).

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
  gyro VQF sees, and its tilt pulls with weight ``bias_gate_weight``. The older fusion's path stays shut on a
  record that names a hand-held IMU (``bias_gate_fusion_shut_for``, rule 31): only VQF's own bias opens it there,
  and there it takes the network's bias out of the gyro without pulling the tilt (``bias_pull_shut_for``, rule 33).

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
σ₀ and c fitted on real files with a trusted reference (and g chosen there, by the fine-tuning). On a record whose
log names a vehicle (not a hand-held IMU, not one not known) the output σ² takes σ_a² too, after the offline
smoothing (``sigma_aircraft_deg``, rule 28: an autopilot-grade IMU's residual errors after its routine calibration,
chosen on simulated flights with the consumer IMU preset; :func:`aircraft_var_rad2`); and where the estimate is
causal (live, ``--no-smooth``) c is ``sigma_acc_gain_aircraft`` on such a record (rule 29: the motion acceleration
the causal filter cannot tell from gravity without the receiver; :func:`acc_gain`).

Frames: VQF works in a z-up sensor frame ``S`` (body FRD turned 180° about x) and a z-up earth
frame; conversions happen only at this module's edges (body FRD / NED outside). The frames and the
per-sample formulas (the samples into ``S``, VQF's outputs out of it with σ, the tilt pull) are in
:mod:`.anchor_kernels`; the filter's steps — a block of samples, a live sample, a window, a whole
segment — are compiled in :mod:`.anchor_steps`, on the filter's state held in float arrays
(:class:`AnchoredVQF` makes them). Offline a segment is one compiled call (session 49: the Python per
window and the round trips of VQF's state were most of a busy flight's time).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Literal

import numpy as np

from ..config import check_choice, check_range
from ..errors import ConfigError
from ..vehicle_class import CLASSES as VEHICLE_CLASSES
from ..vehicle_class import FIXED_WING, MULTIROTOR, OTHER, vehicle_class
from .anchor_kernels import FLIP as _FLIP
from .anchor_kernels import Q_NED_ENU, Q_SENSOR_BODY  # noqa: F401  (VQF's frames; peers import them from here)
from . import anchor_steps as S
from . import vqf_kernel
from .anchor_kernels import fusion_tilt_f  # noqa: F401  (streaming's, imported from here)
from .anchor_kernels import fusion_tilt_rows, q_nb_rows, tilt_pull_f
from .anchor_steps import CLIP_SIGMA_CAP_RAD  # noqa: F401  (σ's saturation term's most; tests read it here)
from .fusion import FusionConfig
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
    # ... and that path (the older fusion's evidence) stays shut on a record whose log names a vehicle of these classes
    # (:mod:`..vehicle_class`; VQF's own bias at its clip still opens the gate there): the network never trained on
    # hand-held motion, so its bias and the older fusion's are out of domain there, as its speed is (rule 24). Session
    # 53's review: a hand-held IMU held tilted 30–55° latched it on calibrated gyros (12 of the 17 seen BROAD trials
    # turned 45° over the per-file bound). Session 54, rule 31; () — any vehicle — before
    bias_gate_fusion_shut_for: tuple[str, ...] = ("handheld",)
    # ... and once latched on a record whose log names a vehicle of these classes, the gate removes the network's bias
    # beyond bias_deadzone_deg_s from the gyro VQF sees but does not pull the tilt toward the network's: the seen BROAD
    # trials with 2 °/s added (the first path latching at VQF's clip) read 2.92° against VQF's 1.49° with the pull,
    # 1.02° without; the bias removal is what helps at large biases (at 10 °/s the whole gate shut read 5.47° against
    # 3.88°: rule 32, not shipped). Session 54, rule 33; () — the pull on any vehicle — before
    bias_pull_shut_for: tuple[str, ...] = ("handheld",)
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
    # σ_a (rule 28, session 50): σ² += σ_a² on a record whose log names a vehicle (multirotor, fixed wing or another
    # vehicle; not a hand-held IMU, not one not known), offline after the smoothing and live: the residual errors of an
    # autopilot-grade IMU after its routine calibration (the gyro's scale in flips, the accelerometer's bias and
    # cross-axis in hover: session 33's oracle), which σ₀ — fitted on the hand-held BROAD trials' lab IMU — does not
    # cover. Chosen by σ's rule on the 36 training flights with the consumer preset
    # (an autopilot log's MPU-6000-class IMU; per-file NEES 2.84, 93.3 % within 3σ without it, 1.94, 97.3 % with it).
    # A fine-tuned model fits σ₀ on the vehicle's own logs and sets it to 0. 0: off (checkpoints before it)
    sigma_aircraft_deg: float = 0.35
    # c_a (rule 29, session 50): where the estimate is causal (the live bridge, `estimate --no-smooth`) on such a record,
    # σ's accelerometer term takes this gain instead of sigma_acc_gain: σ² += (c_a·e)², e the motion acceleration the
    # causal filter cannot tell from gravity without the receiver (the GNSS aid and the smoothing are offline). Chosen by
    # σ's rule on the 36 consumer training flights' live-equivalent estimate: per-file NEES 31.5, 63.3 % within 3σ
    # without it, 1.90, 98.1 % with it. The smoothed estimate keeps sigma_acc_gain (its σ has the disagreement term).
    # A fine-tuned model fits c on its own logs and sets it to 0. 0: sigma_acc_gain everywhere (checkpoints before it)
    sigma_acc_gain_aircraft: float = 0.2
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
        for name in ("speed_gate_shut_for", "bias_gate_fusion_shut_for", "bias_pull_shut_for"):
            given = getattr(self, name)
            shut = (given,) if isinstance(given, str) else tuple(given) if isinstance(given, (list, tuple)) else None
            if shut is None or any(v not in VEHICLE_CLASSES for v in shut):
                raise ConfigError(f"'{name}' must name vehicle classes among {', '.join(VEHICLE_CLASSES)}, got {given!r}")
            object.__setattr__(self, name, shut)
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
                     "sigma_net_scale", "sigma_sampling_gain", "sigma_clip_gain", "sigma_gap_gain", "sigma_gap_hold_s",
                     "sigma_aircraft_deg", "sigma_acc_gain_aircraft"):  # fmt: skip
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
    sample pushed, for the samples after it (causal); :meth:`run_windows` does both over a whole segment.

    The filter is float arrays and the steps are compiled (:mod:`.anchor_steps`, its VQF :mod:`.vqf_kernel`); this
    class makes the arrays from the settings and hands them over."""

    def __init__(self, config: AnchorConfig, ts_s: float, use_mag: bool = False, vehicle: str | None = None,
                 causal: bool = False):  # fmt: skip
        """``vehicle``: what the record says the vehicle is (its ``vehicle_type``; None: nothing) —
        ``config.speed_gate_shut_for`` keeps the flight-speed gate shut for some classes of it; ``causal``: the
        estimate is this filter's own (live, or offline without the smoothing), whose σ takes
        :func:`acc_gain`'s gain for the vehicle."""
        self.cfg = c = config
        self.ts = ts_s = float(ts_s)
        self.use_mag = bool(use_mag)
        # the filter's arrays, views of one buffer (the live step takes it whole): settings, state, VQF's two, scratch
        self.buf = buf = np.zeros(S.N_BUF)
        self.k, self.fs = buf[S.O_K : S.O_F], buf[S.O_F : S.O_CV]
        self.cv, self.sv = buf[S.O_CV : S.O_SV], buf[S.O_SV : S.O_ROWS]
        self.cv[:], self.sv[:] = vqf_kernel.new_filter(ts_s, tauAcc=c.tau_acc_s, biasClip=c.bias_clip_deg_s)
        self.k[:] = _settings(c, ts_s, self.use_mag, speed_gate_allowed(c, vehicle), bias_fusion_gate_allowed(c, vehicle),
                              bias_pull_allowed(c, vehicle))  # fmt: skip
        f = self.fs  # the steps' state beside VQF's
        f[S.F_T_BIAS_OVER] = math.nan  # none
        f[S.F_TAU_ACC] = c.tau_acc_s
        f[S.F_T_CLIP_HIGH] = f[S.F_T_CLIP_LAST] = f[S.F_T_GATED] = -math.inf
        # σ's accelerometer term and constants as sigma_step takes them: (e, α, var0, gain, samp, var_net)
        f[S.F_SP : S.F_SP + 6] = (0.0, min(1.0, ts_s / c.sigma_acc_tau_s), math.radians(c.sigma_floor_deg) ** 2,
                                  acc_gain(c, vehicle, causal), float(c.sigma_sampling_gain) * ts_s * ts_s / 12.0, 0.0)  # fmt: skip
        f[S.F_CLIP_DECAY] = math.exp(-ts_s / c.sigma_clip_tau_s)
        f[S.F_T_PREV] = math.nan  # the previous sample's time (none yet in this segment)
        self.cb = np.empty(64)  # the saturated samples' times still remembered (anchor_steps.clip_room)
        self.relevel_t: list[float] = []  # when the tilt was set from the accelerometer at rest (rest_relevel_s)
        self._out1 = buf[S.O_OUT : S.N_BUF]  # update_one's output
        self._win = np.zeros(S.N_WIN)
        self._no_mag = np.empty((0, 3))

    @property
    def speed_gate(self) -> bool:
        """Whether the flight-speed gate may open (the vehicle's class; the live estimator sets it when the autopilot
        says what the vehicle is)."""
        return bool(self.k[S.K_SPEED_GATE])

    @speed_gate.setter
    def speed_gate(self, allowed: bool) -> None:
        self.k[S.K_SPEED_GATE] = float(bool(allowed))

    @property
    def bias_fusion_gate(self) -> bool:
        """Whether the uncalibrated-gyro gate may open on the older fusion's evidence (the vehicle's class, and the
        setting on; the live estimator sets it when the autopilot says what the vehicle is)."""
        return bool(self.k[S.K_BIAS_GATE_FUSION_ON])

    @bias_fusion_gate.setter
    def bias_fusion_gate(self, allowed: bool) -> None:
        self.k[S.K_BIAS_GATE_FUSION_ON] = float(bool(allowed) and self.cfg.bias_gate_fusion_deg_s > 0)

    @property
    def bias_pull(self) -> bool:
        """Whether the uncalibrated-gyro gate, once latched, pulls the tilt toward the network's (the vehicle's class;
        the live estimator sets it when the autopilot says what the vehicle is)."""
        return bool(self.k[S.K_BIAS_PULL])

    @bias_pull.setter
    def bias_pull(self, allowed: bool) -> None:
        self.k[S.K_BIAS_PULL] = float(bool(allowed))

    def set_acc_gain(self, gain: float) -> None:
        """σ's accelerometer gain from the next sample on (the live estimator, when the autopilot says what the vehicle
        is: :func:`acc_gain`)."""
        self.fs[S.F_SP + 3] = float(gain)

    # what the steps keep, as a reader wants it
    t = property(lambda self: float(self.fs[S.F_T]))
    gate = property(lambda self: float(self.fs[S.F_GATE]))
    gate_parts = property(lambda self: tuple(self.fs[S.F_GATE_PARTS : S.F_GATE_PARTS + 3].tolist()))
    at_rest = property(lambda self: bool(self.fs[S.F_AT_REST]))
    bias_latched = property(lambda self: bool(self.fs[S.F_BIAS_LATCHED]))
    e_clip = property(lambda self: float(self.fs[S.F_E_CLIP]))
    tau_acc = property(lambda self: float(self.fs[S.F_TAU_ACC]))  # VQF's accelerometer time constant now
    vel = property(lambda self: self.fs[S.F_VEL : S.F_VEL + 3].copy())  # the gated v̂ and â removed (body axes)
    acc_v = property(lambda self: self.fs[S.F_ACC_V : S.F_ACC_V + 3].copy())
    var_gap = property(lambda self: float(self.fs[S.F_VAR_GAP]))  # σ²'s gap term, set at each window
    holes = property(lambda self: int(self.fs[S.F_HOLES]))
    still = property(lambda self: self.fs[S.F_STILL : S.F_STILL + 7])  # the still run (anchor_kernels.rest_step)

    def vqf_bias_s(self) -> np.ndarray:
        """VQF's own gyro-bias estimate (rad/s, its sensor frame)."""
        return self.sv[vqf_kernel.S_BIAS : vqf_kernel.S_BIAS + 3].copy()

    def room(self, n: int) -> None:
        """Room in the saturated samples' queue for ``n`` more."""
        if n and not S.clip_room(self.fs, self.cb, n):
            head, count = int(self.fs[S.F_CLIP_HEAD]), int(self.fs[S.F_CLIP_COUNT])
            cb = np.empty(max(2 * len(self.cb), count + n))
            cb[:count] = self.cb[head : head + count]
            self.cb, self.fs[S.F_CLIP_HEAD] = cb, 0.0

    # ------------------------------------------------------------------ samples

    def update(self, t_s, gyr_b, acc_b, mag=None, clipped=None):
        """Rows of samples → (q_nb (n, 4), q_nb_9d (n, 4) or None, sigma (n,), bias_b (n, 3)).
        A non-finite gyro/accelerometer row is a hole, bridged with the last finite sample."""
        t_s = _rows(np.atleast_1d(np.asarray(t_s, np.float64)), 1)
        gyr_b, acc_b = _rows(gyr_b), _rows(acc_b)
        n = len(t_s)
        cl = np.zeros(n, np.bool_) if clipped is None else np.array(np.atleast_1d(clipped), np.bool_)  # (writable: one signature)
        self.room(int(np.count_nonzero(cl)))
        m = self._no_mag
        if self.use_mag:
            m = np.full((n, 3), np.nan) if mag is None else _rows(mag)
        q6, sig, bias = np.empty((n, 4)), np.empty(n), np.empty((n, 3))
        q9 = np.empty((n, 4)) if self.use_mag else q6
        S.update_rows(self.k, self.fs, self.cv, self.sv, self.cb, t_s, gyr_b, acc_b, m, cl, q6, q9, sig, bias)
        return q6, (q9 if self.use_mag else None), sig, bias

    def update_one(self, t_s: float, gyr_b, acc_b, mag=None, clipped: bool = False):
        """:meth:`update` of one sample in plain floats (the live path: numpy's per-call overhead on one row cost 10×
        the arithmetic) → (q_nb, q_nb_9d or None, sigma, bias_b) as tuples and a float; the numbers of a one-row
        :meth:`update` (tested)."""
        gx, gy, gz = gyr_b
        ax, ay, az = acc_b
        mx, my, mz = _NAN3 if mag is None else mag
        if clipped:
            self.room(1)
        S.update_one(self.buf, self.cb, float(t_s), float(gx), float(gy), float(gz), float(ax), float(ay), float(az),
                     float(mx), float(my), float(mz), bool(clipped))  # fmt: skip
        o = self._out1.tolist()
        return (o[0], o[1], o[2], o[3]), ((o[4], o[5], o[6], o[7]) if self.use_mag else None), o[8], (o[9], o[10], o[11])

    # ------------------------------------------------------------------ network windows

    def correct(self, w: WindowOutput) -> None:
        """Apply the network's window made at the last sample pushed (see module doc)."""
        window_vector(w, self._win)
        if S.correct(self.k, self.fs, self.cv, self.sv, self.cb, self._win):
            self.relevel_t.append(self.t)

    def pull(self, d) -> None:
        """Turn the filter's attitude by the earth-frame rotation ``d`` (horizontal axis): its
        inclination quaternion and, with it, its low-passed accelerometer states."""
        dw, dx, dy, dz = _floats(d)
        S.pull(self.sv, dw, dx, dy, dz)

    def run_windows(self, t_s, gyr_b, acc_b, mag, clipped, ends, wins):
        """A whole segment (this filter made for it): its samples, window ``j`` of ``wins`` (:func:`window_rows`)
        applied at the end of sample ``ends[j]`` (offsets in the segment, non-decreasing) → per sample (q_nb (9-D
        with the magnetometer), sigma, bias_b), per window (the gate after it, its parts (W, 3), whether it
        re-levelled the tilt at rest)."""
        t_s = _rows(np.asarray(t_s, np.float64), 1)
        gyr_b, acc_b = _rows(gyr_b), _rows(acc_b)
        n = len(t_s)
        cl = np.zeros(n, np.bool_) if clipped is None else np.array(clipped, np.bool_)  # (writable copies: one signature)
        self.room(int(np.count_nonzero(cl)))
        m = (np.full((n, 3), np.nan) if mag is None else _rows(mag)) if self.use_mag else self._no_mag
        ends = np.array(ends, np.int64)
        nw = len(ends)
        q, sig, bias = np.empty((n, 4)), np.empty(n), np.empty((n, 3))
        gates, parts, relevel = np.empty(nw), np.empty((nw, 3)), np.zeros(nw, np.bool_)
        S.run_segment(self.k, self.fs, self.cv, self.sv, self.cb, t_s, gyr_b, acc_b, m, cl, ends,
                      _rows(wins), q, sig, bias, gates, parts, relevel)  # fmt: skip
        self.relevel_t += [float(t_s[ends[j]]) for j in np.flatnonzero(relevel)]
        return q, sig, bias, gates, parts, relevel


_NAN3 = (math.nan, math.nan, math.nan)


def _settings(c: AnchorConfig, ts_s: float, use_mag: bool, speed_gate: bool, bias_fusion_gate: bool,
              bias_pull: bool) -> np.ndarray:  # fmt: skip
    """The steps' settings array (:data:`.anchor_steps.K_*`) of a filter: angles in radians, flags 0/1;
    ``speed_gate`` / ``bias_fusion_gate`` / ``bias_pull``: whether the flight-speed gate and the uncalibrated-gyro
    gate's older-fusion path may open, and whether that gate pulls, for the record's vehicle."""
    k = np.zeros(S.N_K)
    rest_gyr2 = math.radians(c.rest_gyr_deg_s) ** 2
    gscale = c.gyro_scale != (1.0, 1.0, 1.0)
    for slot, v in (
        (S.K_TS, ts_s), (S.K_CENTRIPETAL, c.centripetal), (S.K_SPEED_GATE, speed_gate), (S.K_USE_MAG, use_mag),
        (S.K_CLIP_GATE_MAX, math.radians(c.clip_gate_max_deg_s) if c.clip_gate_max_deg_s > 0 else math.inf),
        (S.K_REST_GYR2, rest_gyr2), (S.K_REST_ACC2, float(c.rest_acc_m_s2) ** 2),
        (S.K_REST_SPIKE2, rest_gyr2 * float(c.rest_spike_factor) ** 2), (S.K_HAS_GSCALE, gscale),
        # an IMU slower than the network learned: every gate stays shut (min_network_rate_hz)
        (S.K_SLOW, c.min_network_rate_hz > 0 and ts_s * c.min_network_rate_hz > 1.0),
        (S.K_STEP_WEIGHTING, c.gyro_step_weighting), (S.K_CLIP_GAIN_DT, float(c.sigma_clip_gain) * ts_s),
        (S.K_REST_RELEVEL_S, c.rest_relevel_s), (S.K_CLIP_HOLD_S, c.clip_hold_s), (S.K_CLIP_MIN_S, c.clip_min_s),
        (S.K_SIGMA_CLIP_TAU_S, c.sigma_clip_tau_s), (S.K_SPEED_LO, c.speed_lo_m_s), (S.K_SPEED_HI, c.speed_hi_m_s),
        (S.K_GNSS_AID_IN_FLIGHT, c.gnss_aid_in_flight), (S.K_BIAS_GATE_WEIGHT, c.bias_gate_weight),
        (S.K_BIAS_LATCH_RAD_S, 0.95 * math.radians(c.bias_clip_deg_s)),
        (S.K_BIAS_GATE_FUSION_ON, c.bias_gate_fusion_deg_s > 0 and bias_fusion_gate),
        (S.K_BIAS_GATE_FUSION_RAD_S, math.radians(c.bias_gate_fusion_deg_s)),
        (S.K_BIAS_GATE_VQF_RAD_S, math.radians(c.bias_gate_vqf_deg_s)),
        (S.K_BIAS_GATE_THRUST_ON, c.bias_gate_thrust_deg > 0),
        (S.K_BIAS_GATE_THRUST_COS, math.cos(math.radians(c.bias_gate_thrust_deg))),
        (S.K_SIGMA_GAP_GAIN, c.sigma_gap_gain), (S.K_SIGMA_GAP_HOLD_S, c.sigma_gap_hold_s),
        (S.K_SIGMA_GAP_BIAS_EVIDENCE, c.sigma_gap_bias_evidence), (S.K_QUIET_BIAS_RAD_S, math.radians(c.quiet_bias_deg_s)),
        (S.K_PULL_GAIN, c.pull_gain), (S.K_TAU_ACC_FLIGHT_S, c.tau_acc_flight_s), (S.K_TAU_ACC_S, c.tau_acc_s),
        (S.K_SIGMA_NET_SCALE, c.sigma_net_scale), (S.K_REST_KEEPS_RUN, c.rest_keeps_run),
        (S.K_BIAS_DEADZONE_RAD_S, math.radians(c.bias_deadzone_deg_s)), (S.K_BIAS_PULL, bias_pull),
    ):  # fmt: skip
        k[slot] = float(v)
    k[S.K_GSCALE : S.K_GSCALE + 3] = c.gyro_scale
    return k


def window_vector(w: WindowOutput, out: np.ndarray) -> np.ndarray:
    """A :class:`WindowOutput` as the steps read it (:data:`.anchor_steps.W_*` slots), into ``out``."""
    out[S.W_Q : S.W_Q + 4] = w.q_nb_wxyz
    out[S.W_SIGMA] = w.sigma_rad
    out[S.W_BIAS : S.W_BIAS + 3] = w.gyr_bias_rad_s
    out[S.W_VEL : S.W_VEL + 3] = w.vel_m_s
    out[S.W_ACC : S.W_ACC + 3] = w.acc_m_s2
    has = w.fusion_bias_rad_s is not None
    out[S.W_FUSION_BIAS : S.W_FUSION_BIAS + 3] = w.fusion_bias_rad_s if has else 0.0
    out[S.W_HAS_FUSION_BIAS], out[S.W_GNSS_AIDED], out[S.W_GNSS_FAST] = has, bool(w.gnss_aided), bool(w.gnss_fast)
    return out


def window_rows(q, sigma, bias, vel, acc_v, fusion_bias, gnss_aided, gnss_fast) -> np.ndarray:
    """Many windows' outputs (rows; ``fusion_bias`` None: none) as :meth:`AnchoredVQF.run_windows` reads them
    (:func:`window_vector` of each)."""
    n = len(sigma)
    out = np.zeros((n, S.N_WIN))
    out[:, S.W_Q : S.W_Q + 4] = q
    out[:, S.W_SIGMA] = sigma
    out[:, S.W_BIAS : S.W_BIAS + 3] = bias
    out[:, S.W_VEL : S.W_VEL + 3] = vel
    out[:, S.W_ACC : S.W_ACC + 3] = acc_v
    if fusion_bias is not None:
        out[:, S.W_FUSION_BIAS : S.W_FUSION_BIAS + 3] = fusion_bias
        out[:, S.W_HAS_FUSION_BIAS] = 1.0
    out[:, S.W_GNSS_AIDED] = gnss_aided
    out[:, S.W_GNSS_FAST] = gnss_fast
    return out


def speed_gate_allowed(config: AnchorConfig, vehicle: str | None) -> bool:
    """Whether the flight-speed gate may open for ``vehicle`` (a record's ``vehicle_type``, an autopilot's MAV_TYPE
    name or a :mod:`..vehicle_class` class; None: not known): not for the classes ``config.speed_gate_shut_for``
    names (rule 24, session 32)."""
    return vehicle_class(vehicle) not in config.speed_gate_shut_for


def bias_fusion_gate_allowed(config: AnchorConfig, vehicle: str | None) -> bool:
    """Whether the uncalibrated-gyro gate may open on the older fusion's evidence for ``vehicle`` (as
    :func:`speed_gate_allowed` takes it): not for the classes ``config.bias_gate_fusion_shut_for`` names (rule 31,
    session 54); VQF's own bias at its clip opens it on any vehicle."""
    return vehicle_class(vehicle) not in config.bias_gate_fusion_shut_for


def bias_gate_limits(config: AnchorConfig, vehicle: str | None) -> list[str]:
    """What the uncalibrated-gyro gate does not do on a record of ``vehicle`` (rules 31, 33), as a user reads it
    (``estimate``'s ``bias_gate`` line, ``info``'s vehicle line); empty where it acts as on any vehicle."""
    if config.bias_gate_weight <= 0:
        return []
    said = []
    if config.bias_gate_fusion_deg_s > 0 and not bias_fusion_gate_allowed(config, vehicle):
        said.append("opens only on VQF's own bias estimate")
    if not bias_pull_allowed(config, vehicle):
        said.append("takes the network's bias out of the gyro without pulling the tilt")
    return said


def bias_pull_allowed(config: AnchorConfig, vehicle: str | None) -> bool:
    """Whether the uncalibrated-gyro gate, once latched, pulls the tilt toward the network's for ``vehicle`` (as
    :func:`speed_gate_allowed` takes it): not for the classes ``config.bias_pull_shut_for`` names (rule 33, session
    54); its bias removal acts on any vehicle."""
    return vehicle_class(vehicle) not in config.bias_pull_shut_for


#: the vehicle classes whose σ takes :attr:`AnchorConfig.sigma_aircraft_deg` (rule 28)
AIRCRAFT_SIGMA_CLASSES = (MULTIROTOR, FIXED_WING, OTHER)


def takes_aircraft_terms(vehicle: str | None) -> bool:
    """Whether a record of ``vehicle`` (a record's ``vehicle_type``, an autopilot's MAV_TYPE name or a
    :mod:`..vehicle_class` class) takes σ's aircraft terms (rules 28, 29): its class is one of
    :data:`AIRCRAFT_SIGMA_CLASSES` (not a hand-held IMU, not a vehicle not known)."""
    return vehicle_class(vehicle) in AIRCRAFT_SIGMA_CLASSES


def aircraft_var_rad2(config: AnchorConfig, vehicle: str | None) -> float:
    """What σ² takes on a record of ``vehicle``: σ_a² (``config.sigma_aircraft_deg``) where it
    :func:`takes_aircraft_terms`, else 0."""
    if config.sigma_aircraft_deg <= 0 or not takes_aircraft_terms(vehicle):
        return 0.0
    return math.radians(config.sigma_aircraft_deg) ** 2


def acc_gain(config: AnchorConfig, vehicle: str | None, causal: bool) -> float:
    """σ's accelerometer gain c for a record of ``vehicle``: ``config.sigma_acc_gain_aircraft`` where the estimate is
    ``causal``, the vehicle :func:`takes_aircraft_terms` (rule 29) and that gain is set, else ``config.sigma_acc_gain``."""
    if causal and config.sigma_acc_gain_aircraft > 0 and takes_aircraft_terms(vehicle):
        return float(config.sigma_acc_gain_aircraft)
    return float(config.sigma_acc_gain)


def with_aircraft_sigma(sigma_rad: np.ndarray, var_rad2: float) -> np.ndarray:
    """σ with :func:`aircraft_var_rad2`'s ``var_rad2`` added to σ² (the live step adds it sample by sample the
    same way: ``sqrt(σ·σ + v)``)."""
    if not var_rad2:
        return sigma_rad
    s = np.asarray(sigma_rad, np.float64)
    return np.sqrt(s * s + var_rad2)


def with_fusion_tilt(q_nb: np.ndarray, q_fusion: np.ndarray) -> np.ndarray:
    """Rows of ``q_nb`` (body→NED) given the tilt of ``q_fusion``'s rows on their own heading
    (:attr:`AnchorConfig.clip_tilt_from_fusion`; the smoother's tilt formula). A row whose fusion estimate is
    missing, or whose two down directions are opposite (no shortest turn between them), stays ``q_nb``'s."""
    q_nb = np.ascontiguousarray(np.atleast_2d(q_nb), np.float64)
    out = np.empty_like(q_nb)
    fusion_tilt_rows(q_nb, np.ascontiguousarray(np.atleast_2d(q_fusion), np.float64), out)  # the live step, per row
    return out


def _floats(v) -> list:
    """A short vector (array, tuple, list) as Python floats."""
    return np.asarray(v, np.float64).tolist()


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
