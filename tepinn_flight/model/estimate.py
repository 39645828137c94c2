"""Offline estimation over whole records: batched sliding windows, then the causal pass — the
filter-anchored VQF (:func:`estimate_anchored`, the shipped model; on request followed by the tilt
smoothing of its ungated stretches) or the older network-centred fusion (:func:`estimate_record`
with a :class:`FusionConfig`).

``model`` is a :class:`~.network.TEPINN` (run in PyTorch) or any :class:`~.runtime.NetworkRunner`
(e.g. :class:`~.runtime.OnnxRunner`: no torch needed)."""

from __future__ import annotations

import math
import threading
from collections import deque
from contextlib import ExitStack
from dataclasses import replace
from typing import TYPE_CHECKING

import numpy as np
import pandas as pd

from ..errors import TepinnError
from ..record import ACC_COLS, EST_BIAS_COLS, EST_Q_COLS, FlightRecord, segment_slices
from ..record_gaps import GAP_PERIODS, bridge_gaps, segment_period_s
from ..vehicle_class import vehicle_class
from .anchor import (AnchorConfig, AnchoredVQF, _rows, aircraft_var_rad2, bias_gate_limits, ffill_rows, q_nb_from_vqf,
                     speed_gate_allowed, to_sensor, window_rows, with_aircraft_sigma, with_fusion_tilt)  # fmt: skip
from .anchor_kernels import step_weights
from .beside import MAX_WAIT_S_PER_SAMPLE, WAIT_S_PER_SAMPLE, Beside, BesideFailed, worth_it
from .fusion import FusionConfig, FusionRun, feedback_bias
from .accel_scale import AccelScale, read_accel_scale
from .gnss_aid import GnssAidConfig, gnss_evidence, latency_scores, motion_acc_body, read_latency, summarize
from .gyro_selfcal import GyroSelfCal, self_calibrate
from .runtime import as_runner
from .smoother import SmootherConfig, smooth
from .tokens import tokenize, tokenize_record

if TYPE_CHECKING:
    from .network import TEPINN

#: What the anchored estimate reads from the whole record (offline only): each one line in the
#: result's ``attrs`` under this key, ending with "; applied" where it changed the estimate
OFFLINE_STEPS = ("accel_scale_selfcal", "gyro_selfcal", "gnss_aid", "smoother")
#: what an anchored estimate reports in its ``attrs`` (one line each; ``estimate`` prints and stores them,
#: ``evaluate`` keeps them per record): the offline steps, the re-levelling at rest after a saturation and
#: where the network's gates acted (elsewhere the estimate is VQF's on the inputs the steps gave it)
REPORTED_STEPS = (*OFFLINE_STEPS, "rest_relevel", "network_gates", "speed_gate", "bias_gate")
#: the anchored filter's gates, in :attr:`.anchor.AnchoredVQF.gate_parts`' order, as a user reads them
GATE_NAMES = ("flight speed", "gyro saturation", "uncalibrated gyro")


def network_on_windows(model: TEPINN, tok, ends: np.ndarray, gyr_offset: np.ndarray | None = None,
                       batch_size: int = 256):  # fmt: skip
    """(q (W, 4), sigma (W,), bias (W, 3)) of the windows ending at token indices ``ends``;
    ``gyr_offset`` (W, 3) rad/s is subtracted from every gyro token of each window (bias feedback)
    and added back to its bias output."""
    out = network_outputs(model, tok, ends, gyr_offset, batch_size)
    return out["q"], out["sigma"], out["bias"]


def network_outputs(model: TEPINN, tok, ends: np.ndarray, gyr_offset: np.ndarray | None = None,
                    batch_size: int = 256) -> dict:  # fmt: skip
    """The network's outputs for the windows ending at token indices ``ends``: ``q`` (W, 4),
    ``sigma`` (W,), ``bias`` (W, 3) and the transport-theorem head's body velocity ``vel`` and its
    rate ``acc_v`` (W, 3; zeros for a model without that head)."""
    runner = as_runner(model)
    c = runner.config
    qs, ss, bs, vs, avs = [], [], [], [], []
    for a in range(0, len(ends), batch_size):
        e = ends[a : a + batch_size]
        idx = e[:, None] + np.arange(-c.window_tokens + 1, 1)[None, :]
        t = tok.t_s[idx]
        gyr = np.nan_to_num(tok.gyr[idx])  # the windows' tokens only (the whole record per call: O(calls × length))
        g = gyr if gyr_offset is None else gyr - gyr_offset[a : a + batch_size, None, :]
        out = runner.run(g, np.nan_to_num(tok.acc[idx]), tok.count[idx], t - t[:, -1:], tok.dt_s[idx],
                         np.nan_to_num(tok.mag[idx]), tok.clip[idx])  # fmt: skip
        qs.append(out["q"])
        ss.append(out["sigma"])
        bs.append(out["bias"])
        vs.append(out["vel"])
        avs.append(out["acc_v"])
    if not qs:
        z3 = np.zeros((0, 3))
        return {"q": np.zeros((0, 4)), "sigma": np.zeros(0), "bias": z3, "vel": z3, "acc_v": z3}
    bias = np.concatenate(bs)
    if gyr_offset is not None:
        bias = bias + gyr_offset
    return {"q": np.concatenate(qs), "sigma": np.concatenate(ss), "bias": bias, "vel": np.concatenate(vs),
            "acc_v": np.concatenate(avs)}  # fmt: skip


def window_estimates(model: TEPINN, rec: FlightRecord, batch_size: int = 256):
    """Network estimates at every token that ends a full window (on the raw gyro).

    Returns (sample_index (W,), q (W, 4), sigma (W,), bias (W, 3)) — sample_index is the record row
    of each window's last sample, the time the estimate belongs to.
    """
    tok = tokenize_record(rec, model.config.token_rate_hz)
    ends = tok.windows_ending(model.config.window_tokens)
    q, s, b = network_on_windows(model, tok, ends, batch_size=batch_size)
    return tok.last_index[ends], q, s, b


def estimate_record(model: TEPINN, rec: FlightRecord, fusion: FusionConfig | AnchorConfig | None = None,
                    batch_size: int = 256, windows=None, smoother: SmootherConfig | None = None) -> pd.DataFrame:  # fmt: skip
    """One output row per record row: ``t_s``, ``q_est_*`` (body→NED), ``sigma_rad``,
    ``gyr_bias_est_*``. An :class:`AnchorConfig` runs :func:`estimate_anchored`; with a
    :class:`FusionConfig`, NaN until the first window of a segment is full. ``windows`` takes the
    result of :func:`window_estimates` when it is already at hand (fusion tuning; with bias feedback,
    a block whose fed-back offset is zero takes its windows from there, equal up to the float32
    rounding of a different batch, and the others are made again).

    With bias feedback (``fusion.bias_feedback_windows`` = L > 0) the windows of a segment are made
    in blocks of L: block b sees the gyro minus the fusion's bias right after the last estimate of
    block b − 1 was applied (soft-thresholded, :func:`~.fusion.feedback_bias`) — what the live
    estimator has at hand when it makes them.

    Short logging dropouts are bridged (:func:`~tepinn_flight.record_gaps.bridge_gaps`: the
    estimator propagates through them instead of restarting); the rows returned are the record's
    own. Precomputed ``windows`` must come from a record without such gaps. ``smoother``: the offline
    smoothing's settings where an :class:`AnchorConfig` smooths (default: the shipped ones)."""
    if windows is None:
        br = bridge_gaps(rec)
        if br.record is not rec:  # gaps filled, or segments cut where the rate rose
            return br.original(estimate_record(model, br.record, fusion, batch_size, smoother=smoother))
    if isinstance(fusion, AnchorConfig):
        return estimate_anchored(model, rec, fusion, batch_size, smoother=smoother)
    fusion = fusion or FusionConfig()
    feedback = fusion.bias_feedback_windows
    if feedback > 0:
        tok = tokenize_record(rec, model.config.token_rate_hz)
        ends = tok.windows_ending(model.config.window_tokens)
        idx = tok.last_index[ends]
        if windows is not None:
            q, sigma, bias = windows[1:]
    else:
        idx, q, sigma, bias = windows if windows is not None else window_estimates(model, rec, batch_size)
    n = len(rec)
    q_out = np.full((n, 4), np.nan)
    s_out = np.full(n, np.nan)
    b_out = np.full((n, 3), np.nan)
    seg = rec.segment
    t = rec.t_s
    gyr = rec.gyr_rad_s
    clipped = rec.clipped
    for sl in segment_slices(seg):
        a, b = sl.start, sl.stop
        m = (idx >= a) & (idx < b)
        run = FusionRun(t[a:b], gyr[a:b], fusion, clipped[a:b])
        if feedback > 0:
            e_seg, i_seg, pos = ends[m], idx[m] - a, np.flatnonzero(m)
            for s0 in range(0, len(e_seg), feedback):
                blk = slice(s0, s0 + feedback)
                off = feedback_bias(fusion, run.fusion.bias)
                if windows is not None and not any(off):
                    p = pos[blk]
                    run.add(i_seg[blk], q[p], sigma[p], bias[p])
                else:
                    fb = np.tile(off, (len(e_seg[blk]), 1))
                    run.add(i_seg[blk], *network_on_windows(model, tok, e_seg[blk], fb, batch_size))
                run.advance(int(i_seg[blk][-1]) + 2)  # through the sample that applies the block's last
        else:
            run.add(idx[m] - a, q[m], sigma[m], bias[m])
        run.advance(b - a)
        q_out[a:b], s_out[a:b], b_out[a:b] = run.q, run.sigma, run.bias
    return _frame(t, q_out, s_out, b_out)


def bridge_holes(rec: FlightRecord) -> tuple[FlightRecord, int]:
    """``rec`` with every non-finite gyro/accelerometer sample replaced by the last finite one (a
    hole, bridged as the live estimator does), and how many there were."""
    gyr, acc = rec.gyr_rad_s, rec.acc_m_s2
    bad = ~(np.all(np.isfinite(gyr), 1) & np.all(np.isfinite(acc), 1))
    if not bad.any():
        return rec, 0
    gyr, acc = gyr.copy(), acc.copy()
    gyr[bad] = np.nan
    acc[bad] = np.nan
    ffill_rows(gyr, np.zeros(3))
    ffill_rows(acc, np.zeros(3))
    data = rec.data.copy()
    data[["gyr_x_rad_s", "gyr_y_rad_s", "gyr_z_rad_s"]] = gyr
    data[["acc_x_m_s2", "acc_y_m_s2", "acc_z_m_s2"]] = acc
    return FlightRecord(data, dict(rec.meta)), int(bad.sum())


def prepared(rec: FlightRecord, anchor: AnchorConfig | None) -> tuple[FlightRecord, AccelScale | None]:
    """``rec`` as the anchored estimator reads it: holes bridged (:func:`bridge_holes`) and, with
    ``anchor.accel_scale_selfcal``, the accelerometer divided by the scale the record itself shows
    where it is clearly not 1 (:mod:`.accel_scale`, over the whole record) → (record, what was found;
    None: not asked)."""
    rec, _ = bridge_holes(rec)
    if anchor is None or not anchor.accel_scale_selfcal:
        return rec, None
    found = read_accel_scale(rec.t_s, rec.gyr_rad_s, rec.acc_m_s2)
    if found.applied:
        data = rec.data.copy()
        data[list(ACC_COLS)] = rec.acc_m_s2 / found.scale
        rec = FlightRecord(data, dict(rec.meta))
    return rec, found


def anchored_windows(model: TEPINN, rec: FlightRecord, batch_size: int = 256, fusion: FusionConfig | None = None,
                     anchor: AnchorConfig | None = None):  # fmt: skip
    """(sample_index (W,), outputs dict) of the windows :func:`estimate_anchored` applies.
    With ``fusion`` (the pull target ``"fusion"``), the older network-centred fusion runs alongside:
    the windows are made as its bias feedback makes them and ``outputs["q_target"]`` is its
    estimate at each window's last sample (before that window is applied: causal). With ``anchor``'s
    quiet blocks on, a quiet block runs only its first window and those holding a saturated token
    (:meth:`AnchorConfig.block_busy`; the live estimator decides the same way). The record is read as
    :func:`prepared` makes it for ``anchor``."""
    rec, _ = prepared(rec, anchor)
    tok = tokenize_record(rec, model.config.token_rate_hz)
    ends = tok.windows_ending(model.config.window_tokens)
    idx = tok.last_index[ends]
    if fusion is None:
        return idx, network_outputs(model, tok, ends, batch_size=batch_size)
    quiet = anchor.quiet_in(fusion) if anchor is not None else 0
    clip_win = _clip_in_window(tok, ends, as_runner(model).config.window_tokens) if quiet else None
    n = len(rec)
    q_old = np.full((n, 4), np.nan)
    b_old = np.full((n, 3), np.nan)
    parts, chosen = [], []
    t, gyr, clipped = rec.t_s, rec.gyr_rad_s, rec.clipped
    lock = threading.Lock()  # one network call at a time (the thread ahead, the blocks' own)
    speed_gate = anchor is None or speed_gate_allowed(anchor, rec.meta.get("vehicle_type"))  # |v̂| read (rule 26)
    reads_speed = bool(quiet) and anchor.reads_speed(speed_gate)  # else no block reads |v̂|: not computed
    for sl in segment_slices(rec.segment):
        a, b = sl.start, sl.stop
        pos = np.flatnonzero((idx >= a) & (idx < b))
        e_seg, i_seg = ends[pos], idx[pos] - a
        run = FusionRun(t[a:b], gyr[a:b], fusion, clipped[a:b])
        step = fusion.bias_feedback_windows or max(len(e_seg), 1)
        first = None
        if quiet:  # the blocks' first windows with no feedback, batched (used where the feedback is zero), made a
            # batch at a time in a thread ahead of the blocks that read them
            first = _Ahead(model, tok, e_seg[::step], batch_size, lock)
            v_blocks = deque(maxlen=anchor.quiet_memory_blocks)  # the largest |v̂| of each recent block
        try:
            for bi, s0 in enumerate(range(0, len(e_seg), step)):
                sel = np.arange(s0, min(s0 + step, len(e_seg)))
                off = feedback_bias(fusion, run.fusion.bias) if fusion.bias_feedback_windows else None
                if quiet:
                    if off is not None and any(off):
                        with lock:
                            o = network_outputs(model, tok, e_seg[s0 : s0 + 1], np.atleast_2d(off), batch_size)
                    else:
                        o = first.row(bi)
                    rest = sel[1:]
                    speed = max(float(np.linalg.norm(o["vel"][0])), max(v_blocks, default=0.0)) if reads_speed else 0.0
                    busy = anchor.block_busy(bi, speed, run.fusion.bias, speed_gate)
                    rest = rest[anchor.runs_windows(bi, rest - s0, busy, clip_win[pos[rest]])]
                    if len(rest):
                        fb = None if off is None else np.tile(off, (len(rest), 1))
                        with lock:
                            o2 = network_outputs(model, tok, e_seg[rest], fb, batch_size)
                        o = {k: np.concatenate([o[k], o2[k]]) for k in o}
                    sel = np.concatenate(([s0], rest))
                    if reads_speed:
                        v_blocks.append(float(np.linalg.norm(o["vel"], axis=1).max()))
                else:
                    fb = None if off is None else np.tile(off, (len(sel), 1))
                    o = network_outputs(model, tok, e_seg[sel], fb, batch_size)
                parts.append(o)
                chosen.append(pos[sel])
                run.add(i_seg[sel], o["q"], o["sigma"], o["bias"])
                run.advance(int(i_seg[sel][-1]) + 2)
        finally:
            if first is not None:
                first.close()
        run.advance(b - a)
        q_old[a:b] = run.q
        b_old[a:b] = run.bias
    if parts:
        out = {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}
        idx = idx[np.concatenate(chosen)]
    else:
        out = network_outputs(model, tok, ends[:0], batch_size=batch_size)
        idx = idx[:0]
    target = q_old[idx]
    bad = ~np.all(np.isfinite(target), axis=1)
    target[bad] = out["q"][bad]
    out["q_target"] = target
    out["bias_target"] = np.nan_to_num(b_old[idx])  # its gyro-bias estimate then (uncalibrated-gyro evidence)
    out["q_fusion"] = q_old  # per sample (not per window): its estimate at every sample, causal (NaN: none)
    return idx, out


class _Ahead:
    """:func:`network_outputs` of the windows ending at ``ends`` (no feedback), made a batch of ``batch_size`` at a
    time in a thread ahead of the caller, who reads them in order with :meth:`row`: the network releases the GIL, so
    the blocks' Python runs meanwhile. The same batches as one call would make: the same bits."""

    def __init__(self, model, tok, ends: np.ndarray, batch_size: int, lock: threading.Lock):
        from concurrent.futures import ThreadPoolExecutor

        def one(e):
            with lock:
                return network_outputs(model, tok, e, None, batch_size)

        self._bs = batch_size
        self._pool = ThreadPoolExecutor(1, thread_name_prefix="tepinn-windows")
        self._parts = [self._pool.submit(one, ends[k : k + batch_size]) for k in range(0, len(ends), batch_size)]

    def row(self, i: int) -> dict:
        """The outputs of the ``i``-th window (each a (1, ...) array)."""
        part = self._parts[i // self._bs].result()
        j = i % self._bs
        return {k: v[j : j + 1] for k, v in part.items()}

    def close(self) -> None:
        """Stop making batches not yet begun (those of blocks an error left unread)."""
        self._pool.shutdown(wait=True, cancel_futures=True)


def _clip_in_window(tok, ends: np.ndarray, window_tokens: int) -> np.ndarray:
    """(W,) whether the window ending at each token of ``ends`` holds a token with a saturated sample."""
    c = np.r_[0, np.cumsum(tok.clip > 0)]
    return c[ends + 1] - c[np.maximum(ends - window_tokens + 1, 0)] > 0


class MissingMagnetometer(TepinnError):
    """9-D asked for on a record without a magnetometer."""


def wants_mag(anchor: AnchorConfig, rec: FlightRecord) -> bool:
    """9-D for ``mode = 9d``, and for ``auto`` when the record carries a magnetometer."""
    if anchor.mode == "6d":
        return False
    has = bool(np.any(np.all(np.isfinite(rec.mag_ut), axis=1)))
    if anchor.mode == "9d" and not has:
        raise MissingMagnetometer("9-D mode needs a magnetometer and this record has none (use --mode 6d or auto)")
    return has


def estimate_anchored(model: TEPINN, rec: FlightRecord, anchor: AnchorConfig | None = None,
                      batch_size: int = 256, windows=None, smoother: SmootherConfig | None = None) -> pd.DataFrame:  # fmt: skip
    """The filter-anchored estimate (:mod:`.anchor`): one row per record row, ``t_s``, ``q_est_*``
    (body→NED; 9-D heading where ``wants_mag``), ``sigma_rad``, ``gyr_bias_est_*``. Estimates start
    at a segment's first sample (VQF); the network's windows apply from the sample after their last
    one; with ``anchor.clip_tilt_from_fusion``, while the saturation gate is on, the tilt is the older fusion's
    (its per-sample estimate, ``windows``' ``"q_fusion"``) on the filter's heading. ``windows`` takes
    :func:`anchored_windows`' result when already at hand. Non-finite IMU
    samples are holes, bridged with the last finite sample. With ``anchor.accel_scale_selfcal`` the
    accelerometer is first divided by its scale where the record shows one clearly not 1
    (:func:`prepared`; read over the whole record — the live estimator reads it causally):
    ``attrs["accel_scale_selfcal"]``. With ``anchor.gyro_selfcal`` the gyro's
    scale is first read from the record (:func:`self_calibrated`; offline only), and what was found
    is in the result's ``attrs["gyro_selfcal"]``. With ``anchor.gnss_aid`` and a record carrying GNSS
    velocity, the motion acceleration it shows is then taken out of the accelerometer and the filter
    run again (:func:`gnss_aided_acc`; offline only): ``attrs["gnss_aid"]``. With ``anchor.smoother``
    the tilt of every long enough stretch where no gate acts is then VQF's run forward and backward
    on the same inputs (:mod:`.smoother`; offline only, its settings ``smoother``, default the
    shipped ones): ``attrs["smoother"]``. On a long record (:func:`.beside.worth_it`) the self-calibration, the GNSS
    aid's evidence from the receiver and the smoothing's runs over whole segments are made in a helper process beside
    the anchored pass (:func:`_beside_work`;
    on a record whose receiver changed the accelerometer, by a second helper beside the last pass, :func:`_aided_work`;
    the same bits as made here, which they are where the helper is not done in time)."""
    anchor = anchor or AnchorConfig()
    rec, acal = prepared(rec, anchor)
    with ExitStack() as helpers:  # leaving stops any helper still running
        side = helpers.enter_context(Beside(_beside_work(anchor, rec))) if worth_it(len(rec)) else None
        return _estimate_anchored(model, rec, anchor, acal, batch_size, windows, smoother, side, helpers)


def _beside_work(anchor: AnchorConfig, rec: FlightRecord):
    """What a helper process (:mod:`.beside`) does for :func:`estimate_anchored` on a long record while the
    anchored pass runs: the gyro's self-calibration, then (with the smoothing on) VQF forward and backward over each
    whole segment — the run the smoothing asks for wherever no gate acts in a segment → yields ``(anchor, cal)``, then
    ``{(start, stop): q_nb}``; on a record with a receiver's velocity, between the two, the GNSS aid's evidence from the
    receiver alone (:func:`gnss_evidences`, session 40). On such a record those runs are on the accelerometer as read,
    and used only where the GNSS aid then leaves it as it is (session 39: a PX4 log's hour, where it does, 137–162 k →
    175–206 k samples/s); where the aid changes it, this helper is stopped and a second one makes them on the new one."""

    def work():
        cal = self_calibrated(anchor, rec)
        yield cal
        if reads_gnss(anchor, rec):  # the GNSS aid's evidence from the receiver alone (session 40)
            yield gnss_evidences(rec, aid_settings(anchor, vehicle=rec.meta.get("vehicle_type"))[0])
        done = {}
        if anchor.smoother:
            done = segment_runs(cal[0], rec.t_s, np.ascontiguousarray(rec.gyr_rad_s), np.ascontiguousarray(rec.acc_m_s2),
                                rec.segment)  # fmt: skip
        yield done

    return work


def segment_runs(anchor: AnchorConfig, t, gyr, acc, seg) -> dict:
    """:func:`offline_vqf` over each whole segment (of two samples or more) → ``{(start, stop): q_nb}``: what the
    smoothing asks for wherever no gate acts in a segment."""
    return {(sl.start, sl.stop): offline_vqf(anchor, t[sl], gyr[sl], acc[sl])
            for sl in segment_slices(seg) if sl.stop - sl.start >= 2}  # fmt: skip


def _aided_work(anchor: AnchorConfig, t, gyr, acc_aided, seg):
    """What a second helper process does on a long record whose receiver changed the accelerometer, beside the last
    anchored pass: the smoothing's runs over whole segments on that accelerometer (:func:`segment_runs`)."""

    def work():
        yield segment_runs(anchor, t, gyr, acc_aided, seg)

    return work


def _estimate_anchored(model, rec, anchor, acal, batch_size, windows, smoother, side, helpers: ExitStack):
    """:func:`estimate_anchored` on the record as :func:`prepared` made it; ``side``: a helper process running
    :func:`_beside_work` (None: everything here). Where the receiver's velocity changes the accelerometer, a second
    helper (:func:`_aided_work`, entered into ``helpers``) makes the smoothing's runs on the new one beside the last
    anchored pass."""
    aided = None
    if side is None:
        anchor, cal = self_calibrated(anchor, rec)
    if windows is None:  # on the record as prepared: its accelerometer scale is not read a second time (the
        # windows read nothing the gyro's self-calibration sets: they may be made before it is known)
        windows = anchored_windows(model, rec, batch_size, anchor.fusion_config or FusionConfig(),
                                   replace(anchor, accel_scale_selfcal=False))  # fmt: skip
    if side is not None:
        try:
            anchor, cal = side.take(WAIT_S_PER_SAMPLE * len(rec), MAX_WAIT_S_PER_SAMPLE * len(rec))
        except BesideFailed:
            side = None
            anchor, cal = self_calibrated(anchor, rec)
    idx, out = windows
    use_mag = wants_mag(anchor, rec)
    # row-major once: the passes hand the filter a window's rows at a time, and a column-major
    # slice would be copied for the compiled kernels at every window
    t, gyr, acc, mag = rec.t_s, *(np.ascontiguousarray(x) for x in (rec.gyr_rad_s, rec.acc_m_s2, rec.mag_ut))
    cols = (t, gyr, acc, mag, rec.gyr_clipped)  # read from the frame once (each property access copies); the
    # saturation gate opens on the gyro's clipping alone
    vehicle = rec.meta.get("vehicle_type")  # what the log says the vehicle is (AnchorConfig.speed_gate_shut_for)
    q_out, s_out, b_out, gate, relevel_t, relevel_i, gates_open, clip_gate = _anchored_pass(anchor, rec.segment, cols,
                                                                                             idx, out, use_mag, vehicle)  # fmt: skip
    aid = None
    if anchor.gnss_aid:
        evidence = None
        if side is not None and reads_gnss(anchor, rec):
            try:
                evidence = side.take(WAIT_S_PER_SAMPLE * len(rec), MAX_WAIT_S_PER_SAMPLE * len(rec))
            except BesideFailed:
                side = None
        aid, acc_aided, out_aided = gnss_aided_acc(rec, q_out, anchor, idx, out, cols, use_mag, evidence=evidence)
        if acc_aided is not None:
            cols = (t, gyr, acc_aided, mag, cols[4])
            if side is not None and anchor.smoother:  # a long record: the smoothing's runs beside the last pass
                side.close()  # its runs are on the accelerometer as read: not wanted now, nor its core
                side = None
                aided = helpers.enter_context(Beside(_aided_work(anchor, t, gyr, acc_aided, rec.segment)))
            q_out, s_out, b_out, gate, relevel_t, relevel_i, gates_open, clip_gate = _anchored_pass(
                anchor, rec.segment, cols, idx, out_aided, use_mag, vehicle)  # fmt: skip
    q_fusion = out.get("q_fusion")
    if anchor.clip_tilt_from_fusion and q_fusion is not None and np.any(clip_gate > 0):
        on = clip_gate > 0  # the saturation gate (as the filter held it): the older fusion's tilt, the filter's heading
        q_out[on] = with_fusion_tilt(q_out[on], q_fusion[on])
    done = None
    if anchor.smoother:
        scale = np.asarray(anchor.gyro_scale, np.float64)
        ready = {}  # a helper's runs over whole segments, on the accelerometer the last pass read (as the record read
        # it: the first helper's; aided by the receiver: the second's)
        helper = side if cols[2] is acc else aided
        if helper is not None:
            try:
                ready = helper.take(WAIT_S_PER_SAMPLE * len(t), MAX_WAIT_S_PER_SAMPLE * len(t))
            except BesideFailed:
                pass

        def offline(sl, extra=None):  # extra: rates added to the filter's gyro (a clipping's missed turn)
            if extra is None and (sl.start, sl.stop) in ready:
                return ready[(sl.start, sl.stop)]
            g = gyr[sl] if extra is None else gyr[sl] + extra[sl] / scale
            return offline_vqf(anchor, t[sl], g, cols[2][sl])

        clips = cols[4] is not None and bool(np.any(cols[4]))  # the clip-turn fit's inputs only where the gyro clipped
        q_out, s_out, done = smooth(t, q_out, s_out, gate, rec.segment, smoother or SmootherConfig(), offline, cols[4],
                                    relevel_i, imu=(gyr * scale, cols[2], b_out) if clips else None,
                                    gyr_rad_s=gyr, acc_m_s2=acc)  # fmt: skip
    s_out = with_aircraft_sigma(s_out, aircraft_var_rad2(anchor, vehicle))  # rule 28: an aircraft's IMU
    df = _frame(t, q_out, s_out, b_out)
    for key, found in (("accel_scale_selfcal", acal), ("gyro_selfcal", cal), ("gnss_aid", aid), ("smoother", done)):
        if found is not None:
            df.attrs[key] = found.describe()
    if relevel_t:
        df.attrs["rest_relevel"] = describe_relevels(relevel_t)
    steps = np.zeros(len(t))
    for sl in segment_slices(rec.segment):
        steps[sl] = _sample_steps(t[sl])
    df.attrs["network_gates"] = describe_gates(gates_open, float(steps[gate > 0].sum()), float(steps.sum()))
    if not speed_gate_allowed(anchor, vehicle):  # why the flight-speed gate never opened here (rule 24)
        df.attrs["speed_gate"] = f"flight-speed gate: not used on a {vehicle_class(vehicle)} log (it names a {vehicle})"
    limits = bias_gate_limits(anchor, vehicle)  # what the uncalibrated-gyro gate does not do here (rules 31, 33)
    if limits:
        df.attrs["bias_gate"] = (f"uncalibrated-gyro gate: {' and '.join(limits)} on a {vehicle_class(vehicle)} log "
                                 f"(it names a {vehicle})")  # fmt: skip
    return df


def describe_gates(gates_open: dict, open_s: float, span_s: float) -> str:
    """One line for a user: how long each of the network's gates was open (``{name: (seconds, first
    time)}``, :func:`_anchored_pass`), any of them ``open_s`` of the record's ``span_s`` seconds; where
    none was, the estimate is VQF's (on the inputs the offline steps gave it)."""
    acted = {k: v for k, v in gates_open.items() if v[0] > 0}
    if not acted:
        return "network gates: shut throughout (the network corrected nothing); not applied"
    parts = ", ".join(f"{k} {s:.1f} s from t = {t0:.1f} s" for k, (s, t0) in acted.items())
    share = f"{100 * open_s / span_s:.1f} % of the record" if span_s > 0 else "the record"
    return f"network gates open on {share} ({parts}); applied"


def gates_acted(lines: dict) -> str:
    """One line over several records (``{record name: its network_gates line}``): where the gates acted."""
    acted = [f"{k} ({v.split('(', 1)[1].rsplit(')', 1)[0]})" for k, v in lines.items() if v.endswith("; applied")]
    if not acted:
        return f"network gates shut on all {len(lines)} record(s) (the network corrected nothing)"
    return (f"network gates acted on {len(acted)} of {len(lines)} record(s), elsewhere the network corrected nothing: "
            f"{'; '.join(acted[:5])}{'; ...' if len(acted) > 5 else ''}")


def _sample_steps(t: np.ndarray) -> np.ndarray:
    """(n,) each sample's time until the next one of its segment ``t`` (the last one's: the median step)."""
    dt = np.diff(t)
    return np.r_[dt, np.median(dt) if dt.size else 0.0]


def describe_relevels(times_s: list[float]) -> str:
    """One line for a user: where the tilt was set from the accelerometer at rest after a saturation."""
    shown = ", ".join(f"{t:.1f}" for t in times_s[:5]) + (", ..." if len(times_s) > 5 else "")
    return (f"gyro saturation then rest: tilt set from the accelerometer {len(times_s)}× (t = {shown} s; "
            "rest_relevel_s); applied")


def offline_vqf(anchor: AnchorConfig, t_s, gyr_b, acc_b) -> np.ndarray:
    """``vqf.offlineVQF`` (forward and backward, acausal) on one run of samples with the anchored
    filter's settings (its accelerometer time constant, bias limit and gyro scale; its sampling
    time as the live estimator takes it; each gyro sample over its own step where the filter does so,
    ``gyro_step_weighting``) → its 6-D attitude, body→NED, per sample."""
    import vqf

    ts = segment_period_s(t_s, 0.01)
    g = np.asarray(gyr_b, np.float64) * np.asarray(anchor.gyro_scale)
    if anchor.gyro_step_weighting:  # each sample over its own step, as the anchored filter integrates it
        w = np.empty(len(g))
        if step_weights(np.asarray(t_s, np.float64), math.nan, ts, GAP_PERIODS, w):
            g = g * w[:, None]
    params = {"tauAcc": float(anchor.tau_acc_s), "biasClip": float(anchor.bias_clip_deg_s)}
    res = vqf.offlineVQF(to_sensor(g), to_sensor(acc_b), None, ts, params)
    return q_nb_from_vqf(res["quat6D"])


def _anchored_pass(anchor: AnchorConfig, seg, cols, idx, out, use_mag, vehicle: str | None = None):
    """One run of the anchored filter over every segment with the network's windows ``(idx, out)``
    applied at their last samples → (q_nb, sigma, bias, gate) per sample and the times the tilt was
    re-levelled at rest (:attr:`.anchor.AnchoredVQF.relevel_t`), the first sample estimated after each of those
    re-levellings and, per gate (:data:`GATE_NAMES`), the
    seconds it was open and when it first opened (``{name: (s, t)}``), and the saturation gate's part per sample
    (its pull weight, :attr:`.anchor.AnchoredVQF.gate_parts`); the gate (the largest of the
    filter's gates, 0 where the estimate is VQF's) is each window's from the sample after it. ``vehicle``: the
    record's ``vehicle_type`` (:class:`.anchor.AnchoredVQF`)."""
    t = cols[0]
    if cols[4] is not None and not cols[4].any():  # no sample clipped: the filter need not look for one, window by window
        cols = (*cols[:4], None)
    q_pull = out.get("q_target", out["q"])
    b_fus = out.get("bias_target")
    aided = out.get("gnss_aided", np.zeros(len(idx), bool))
    fast = out.get("gnss_fast", np.zeros(len(idx), bool))
    n = len(t)
    q_out = np.full((n, 4), np.nan)
    s_out = np.full(n, np.nan)
    b_out = np.full((n, 3), np.nan)
    gate = np.zeros(n)
    clip_gate = np.zeros(n)
    relevel_t, relevel_i = [], []
    open_s, first_t = np.zeros(len(GATE_NAMES)), np.full(len(GATE_NAMES), np.inf)
    wins = window_rows(q_pull, out["sigma"], out["bias"], out["vel"], out["acc_v"], b_fus, aided, fast)
    tc, gc, ac = _rows(t, 1), _rows(cols[1]), _rows(cols[2])  # (C arrays once for every segment)
    mc = _rows(cols[3]) if use_mag else None
    for sl in segment_slices(seg):
        a, b = sl.start, sl.stop
        flt = AnchoredVQF(anchor, segment_period_s(t[a:b], 0.01), use_mag, vehicle,  # (as the live estimator)
                          causal=not anchor.smoother)  # σ's gain where nothing smooths (rule 29)
        js = np.flatnonzero((idx >= a) & (idx < b))
        ends = np.asarray(idx, np.int64)[js] - a  # each window at its last sample, for the samples after it
        q_out[a:b], s_out[a:b], b_out[a:b], gates, parts, relevel = flt.run_windows(
            tc[a:b], gc[a:b], ac[a:b], None if mc is None else mc[a:b], None if cols[4] is None else cols[4][a:b], ends,
            wins[js])  # fmt: skip
        starts = ends + 1  # each window's gate holds from the sample after it to the next one's
        relevel_i += (starts[relevel] + a).tolist()  # the windows that re-levelled the tilt, from the sample after
        if len(starts):
            gate[a:b] = _piecewise(starts, gates, b - a)
            clip_gate[a:b] = _piecewise(starts, parts[:, 1], b - a)
            _add_open_time(t[a:b], starts, parts > 0, open_s, first_t)
        relevel_t += flt.relevel_t
    gates_open = {name: (float(s), float(t0)) for name, s, t0 in zip(GATE_NAMES, open_s, first_t)}
    return q_out, s_out, b_out, gate, relevel_t, relevel_i, gates_open, clip_gate


def _add_open_time(t: np.ndarray, starts: np.ndarray, is_open: np.ndarray, open_s: np.ndarray, first_t: np.ndarray) -> None:
    """Add to ``open_s`` (per gate) the time the windows of one segment held each gate open — window k's
    gates hold from its sample ``starts[k]`` to the next window's (the segment's end after the last; the
    samples' own spacing, the last sample's taken as the median) — and lower ``first_t`` to when each opened."""
    n = len(t)
    cum = np.r_[0.0, np.cumsum(_sample_steps(t))]
    s0 = np.minimum(starts, n)
    s1 = np.r_[s0[1:], n]
    held = cum[s1] - cum[s0]  # (W,) seconds each window's gates hold
    open_s += held @ is_open
    for g in range(is_open.shape[1]):
        k = np.flatnonzero(is_open[:, g] & (s1 > s0))  # a window whose successor starts at the same sample never held
        if k.size:
            first_t[g] = min(first_t[g], float(t[s0[k[0]]]))


def _piecewise(starts: np.ndarray, values: np.ndarray, n: int) -> np.ndarray:
    """(n,) ``values[k]`` from ``starts[k]`` (non-decreasing offsets) up to the next start, 0 before
    the first; a later value at the same start wins (as successive writes would)."""
    k = np.searchsorted(starts, np.arange(n), side="right") - 1
    return np.where(k >= 0, values[np.maximum(k, 0)], 0.0)


def aid_settings(anchor: AnchorConfig, cfg: GnssAidConfig | None = None, vehicle: str | None = None) -> tuple[GnssAidConfig, float]:
    """The GNSS aid's settings as the anchored estimator runs it on a record of ``vehicle`` (its log's
    ``vehicle_type``) — ``cfg``, default the shipped ones; no speed limit with ``anchor.gnss_aid_in_flight``; the
    receiver's holes bridged where the vehicle's class is in ``cfg.bridge_gaps_for``; its latency read from the
    record only where the class is in ``cfg.read_latency_for`` (elsewhere no ``latency_grid_s``) — and the ground speed
    from which the flight-speed gate acts beside it."""
    cfg = cfg or GnssAidConfig()
    if not cfg.bridge_gaps and cfg.bridge_gaps_for and vehicle_class(vehicle) in cfg.bridge_gaps_for:
        cfg = replace(cfg, bridge_gaps=True)
    if cfg.latency_grid_s and vehicle_class(vehicle) not in cfg.read_latency_for:
        cfg = replace(cfg, latency_grid_s=())
    fast_m_s = cfg.max_speed_m_s
    if anchor.gnss_aid_in_flight:
        cfg = replace(cfg, max_speed_m_s=float("inf"))
    return cfg, fast_m_s


def reads_gnss(anchor: AnchorConfig, rec: FlightRecord) -> bool:
    """Whether the GNSS aid reads ``rec``'s receiver (asked for, and the record has its velocity)."""
    return bool(anchor.gnss_aid) and rec.gnss_vel_ne_m_s is not None


def gnss_evidences(rec: FlightRecord, cfg: GnssAidConfig) -> dict:
    """:func:`.gnss_aid.gnss_evidence` of each segment of ``rec`` (its receiver's velocity and its gyro's clipping)
    → ``{(start, stop): GnssEvidence or None}``: what every pass of :func:`gnss_aided_acc` reads without the attitude."""
    t, vel, clipped = rec.t_s, rec.gnss_vel_ne_m_s, rec.gyr_clipped
    return {(sl.start, sl.stop): gnss_evidence(t[sl], vel[sl], cfg, clipped[sl]) for sl in segment_slices(rec.segment)}


def gnss_aided_acc(rec: FlightRecord, q_nb: np.ndarray, anchor: AnchorConfig, idx, out, cols, use_mag: bool,
                   cfg: GnssAidConfig | None = None, evidence: dict | None = None):  # fmt: skip
    """The accelerometer (``cols[2]``) with the motion acceleration the record's GNSS velocity shows
    taken out (:mod:`.gnss_aid`), from the estimate ``q_nb`` and ``cfg.passes`` rounds of
    re-estimation → (the :class:`GnssAid` found, the aided accelerometer or None where it does not
    apply, the windows' outputs for the aided filter: each window marked where the aid holds at its
    end, :class:`.anchor.WindowOutput`'s ``gnss_aided``). ``evidence``: :func:`gnss_evidences` of the record with
    these settings where already made (a helper process's); else made here, once for all the passes."""
    cfg, fast_m_s = aid_settings(anchor, cfg, rec.meta.get("vehicle_type"))  # at fast_m_s and above, the flight-speed gate acts beside the aid
    t, acc = cols[0], cols[2]
    vel = rec.gnss_vel_ne_m_s
    n = len(acc)
    none = np.zeros(n, bool)
    if vel is None:
        return summarize(none, none, np.zeros((n, 3)), None, cfg), None, out
    seg = rec.segment
    gyr_clipped = cols[4]  # the gyro's clipping, as the passes read it
    at = np.asarray(idx, np.int64)
    fast = np.hypot(vel[at, 0], vel[at, 1]) >= fast_m_s  # the windows' ends (NaN: no fix, not fast)
    found = (none, none, np.zeros((n, 3)))  # the masks and correction of the last pass that applied
    found_latency = None  # the latency read that that correction was made at (None: the setting's)
    aided, out_aided = None, out
    ev = evidence if evidence is not None else gnss_evidences(rec, cfg)  # the receiver's part: the same every pass

    def correction(q_nb, cfg, ev):
        a_b, trusted, covered = np.zeros((n, 3)), none.copy(), none.copy()
        for sl in segment_slices(seg):
            a_b[sl], trusted[sl], covered[sl] = motion_acc_body(t[sl], q_nb[sl], acc[sl], vel[sl], cfg, gyr_clipped[sl],
                                                                ev[(sl.start, sl.stop)])  # fmt: skip
        return a_b, trusted, covered

    # rule 37: the receiver's latency read from the record where it is not the setting's (None: not read). With the
    # first aided pass's attitude (37b: the plain pass's tilt follows the slow acceleration and reads late; so with
    # ``passes`` 1 nothing is read there); where the setting's latency lets nothing be trusted, with the plain pass's
    # (37c: a receiver far later than the setting), and not read again after. A pass at the latency read that trusts
    # nothing leaves the last pass that did, and the summary its latency
    latency = None

    def read_with(q_nb, cfg, ev):  # → the settings, the latency read (None: the setting's) and the evidence at it
        read = record_latency(t, q_nb, acc, vel, seg, cfg, ev)
        if read == cfg.latency_s:
            return cfg, None, ev
        cfg = replace(cfg, latency_s=read)
        return cfg, read, gnss_evidences(rec, cfg)

    for p in range(cfg.passes):
        a_b, trusted, covered = correction(q_nb, cfg, ev)
        if p == 0 and not trusted.any():
            cfg, latency, ev = read_with(q_nb, cfg, ev)
            if latency is not None:
                a_b, trusted, covered = correction(q_nb, cfg, ev)
        if not trusted.any():
            if aided is None:  # nothing applies: say why from this pass's masks
                found = (trusted, covered, a_b)
            break
        found, found_latency = (trusted, covered, a_b), latency
        aided = acc - a_b
        out_aided = dict(out, gnss_aided=trusted[at], gnss_fast=fast)
        if p + 1 < cfg.passes:
            q_nb = _anchored_pass(anchor, seg, (t, cols[1], aided, cols[3], cols[4]), idx, out_aided, use_mag,
                                  rec.meta.get("vehicle_type"))[0]  # fmt: skip
            if p == 0 and latency is None:
                cfg, latency, ev = read_with(q_nb, cfg, ev)
    trusted, covered, a_b = found
    return replace(summarize(trusted, covered, a_b, vel, cfg), latency_s=found_latency), aided, out_aided


def record_latency(t, q_nb, acc, vel, seg, cfg: GnssAidConfig, evidence: dict) -> float:
    """The receiver's latency of a record (rule 37, :func:`.gnss_aid.read_latency`) from its segments whose receiver
    evidence may be trusted at all (``evidence``: :func:`gnss_evidences`'), read with the estimate ``q_nb`` on the
    accelerometer ``acc``; ``cfg.latency_s`` where none may be (or ``cfg.latency_grid_s`` is empty)."""
    if not cfg.latency_grid_s:
        return cfg.latency_s
    num = den = None
    for sl in segment_slices(seg):
        e = evidence[(sl.start, sl.stop)]
        if e is None or not e.may_trust:
            continue
        a, b = latency_scores(t[sl], q_nb[sl], acc[sl], vel[sl], cfg, e.clip_ok)
        num, den = (a, b) if num is None else (num + a, den + b)
    return cfg.latency_s if num is None else read_latency(num, den, cfg)


def self_calibrated(anchor: AnchorConfig, rec: FlightRecord) -> tuple[AnchorConfig, GyroSelfCal | None]:
    """``anchor`` with the gyro scale the record itself shows (:mod:`.gyro_selfcal`, read on the gyro
    as logged) where ``anchor.gyro_selfcal`` and the evidence say so — it then replaces any
    ``gyro_scale`` a fine-tuning fitted for the vehicle: this record's own evidence is the more
    specific — and what was found (None: not asked)."""
    if not anchor.gyro_selfcal:
        return anchor, None
    cal = self_calibrate(rec.t_s, rec.gyr_rad_s, rec.acc_m_s2, rec.segment, rec.gyr_clipped)
    if cal.applied:
        anchor = replace(anchor, gyro_scale=cal.scale)
    return anchor, cal


def _frame(t, q, s, b) -> pd.DataFrame:
    df = pd.DataFrame({"t_s": t})
    for i, c in enumerate(EST_Q_COLS):
        df[c] = q[:, i]
    df["sigma_rad"] = s
    for i, c in enumerate(EST_BIAS_COLS):
        df[c] = b[:, i]
    return df
