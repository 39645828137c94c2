"""The GNSS-aided tilt (:mod:`tepinn_flight.model.gnss_aid`): the receiver's acceleration against a
closed form, the heading offset of a 6-D filter recovered so the correction lands in the right body
axes (scipy's rotations as the reference), and the anchored estimate against the truth of a record
whose accelerometer carries a known motion acceleration."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from tepinn_flight.conventions import GRAVITY_M_S2
from tepinn_flight.model.gnss_aid import GnssAidConfig, gnss_evidence, motion_acc_body, motion_acc_ne
from tepinn_flight.quat import quat_normalize
from tepinn_flight.record import FlightRecord, make_frame

RATE_HZ = 200.0
A_MS2 = 3.0  # horizontal acceleration amplitude (a multirotor's figure eight)
W1, W2 = 2 * np.pi / 8.0, 2 * np.pi / 11.0  # its two frequencies (rad/s)


def accelerating_flight(duration_s: float = 120.0, v0_ne=(0.0, 0.0), gnss_rate_hz: float = 5.0, latency_s: float = 0.1,
                        seed: int = 0, gnss: bool = True, periods_s: tuple[float, float] | None = None):  # fmt: skip
    """A record whose accelerometer carries a known horizontal motion acceleration
    ``a = A (sin ω₁t, sin ω₂t)`` on top of gravity (``periods_s``: 2π/ω₁, 2π/ω₂; default those of W1, W2), with a
    slowly turning, gently tilting attitude, an exact gyro (the turn between samples) and a receiver's velocity:
    ``v0 + ∫a`` sampled at ``gnss_rate_hz`` ``latency_s`` late, linear between fixes. Returns (record, true q_nb)."""
    W1, W2 = (globals()["W1"], globals()["W2"]) if periods_s is None else (2 * np.pi / periods_s[0], 2 * np.pi / periods_s[1])
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, duration_s, 1.0 / RATE_HZ)
    yaw = 0.3 * t + 0.5
    pitch = np.radians(4.0) * np.sin(0.7 * t)
    roll = np.radians(5.0) * np.sin(0.5 * t + 1.0)
    r = Rotation.from_euler("ZYX", np.c_[yaw, pitch, roll])  # body FRD → NED
    q_nb = r.as_quat()[:, [3, 0, 1, 2]]
    a_n = np.c_[A_MS2 * np.sin(W1 * t), A_MS2 * np.sin(W2 * t), np.zeros_like(t)]
    g_n = np.array([0.0, 0.0, GRAVITY_M_S2])
    acc_b = r.inv().apply(a_n - g_n) + rng.normal(0, 0.05, (len(t), 3))
    dr = (r[:-1].inv() * r[1:]).as_rotvec() * RATE_HZ  # body rate over each step
    gyr_b = np.vstack([dr, dr[-1:]]) + rng.normal(0, 0.002, (len(t), 3))
    gnss_ne = None
    if gnss:
        t_fix = np.arange(latency_s, duration_s, 1.0 / gnss_rate_hz)
        tm = t_fix - latency_s
        v_fix = np.c_[v0_ne[0] + A_MS2 / W1 * (1 - np.cos(W1 * tm)), v0_ne[1] + A_MS2 / W2 * (1 - np.cos(W2 * tm))]
        gnss_ne = np.c_[np.interp(t, t_fix, v_fix[:, 0], left=np.nan, right=np.nan),
                        np.interp(t, t_fix, v_fix[:, 1], left=np.nan, right=np.nan)]  # fmt: skip
    df = make_frame(t, np.zeros(len(t), np.int32), gyr_b, acc_b, None, q_nb, None, gnss_vel_ne_m_s=gnss_ne)
    meta = {"format_version": 1, "source_file": "synthetic", "source_kind": "synthetic", "imu_rate_hz": RATE_HZ,
            "reference_source": "synthetic-truth"}
    return FlightRecord(df, meta), q_nb


def test_the_receivers_acceleration_is_the_velocity_difference_over_the_smoothing_span():
    rec, _ = accelerating_flight(60.0, latency_s=0.1)
    cfg = GnssAidConfig()
    a = motion_acc_ne(rec.t_s, rec.gnss_vel_ne_m_s, cfg)
    t = rec.t_s
    ok = np.all(np.isfinite(a), axis=1)
    assert ok.mean() > 0.95 and not ok[0]  # no fix yet at the start
    # the fixes are 0.1 s late and the read is 0.1 s later: the closed form of the mean of a over
    # [t − h/2, t + h/2] (h = 1 s), i.e. (v(t + h/2) − v(t − h/2)) / h
    h = cfg.smooth_s
    exact = np.c_[A_MS2 * (np.cos(W1 * (t - h / 2)) - np.cos(W1 * (t + h / 2))) / (W1 * h),
                  A_MS2 * (np.cos(W2 * (t - h / 2)) - np.cos(W2 * (t + h / 2))) / (W2 * h)]  # fmt: skip
    err = np.abs(a[ok] - exact[ok]).max()
    assert err < 0.02, err  # the fixes' linear interpolation only
    # a wrong latency shows: reading 0.1 s too early misses by ~A ω 0.1 s
    early = motion_acc_ne(t, rec.gnss_vel_ne_m_s, dataclasses.replace(cfg, latency_s=0.0))
    assert np.nanmax(np.abs(early[ok] - exact[ok])) > 5 * err


@pytest.mark.parametrize("yaw_offset_deg", [0.0, 73.0, -150.0])
def test_the_correction_lands_in_the_right_body_axes_whatever_the_filters_heading_origin(yaw_offset_deg):
    rec, q_nb = accelerating_flight(90.0)
    # the filter's attitude: the truth with its heading origin turned (a 6-D filter's arbitrary heading)
    off = Rotation.from_euler("Z", np.radians(yaw_offset_deg))
    r_true = Rotation.from_quat(q_nb[:, [1, 2, 3, 0]])
    q_est = (off * r_true).as_quat()[:, [3, 0, 1, 2]]
    a_b, trusted, covered = motion_acc_body(rec.t_s, q_est, rec.acc_m_s2, rec.gnss_vel_ne_m_s, GnssAidConfig())
    assert trusted.mean() > 0.8 and covered.mean() > 0.95
    t = rec.t_s
    h = GnssAidConfig().smooth_s
    a_n = np.c_[A_MS2 * (np.cos(W1 * (t - h / 2)) - np.cos(W1 * (t + h / 2))) / (W1 * h),
                A_MS2 * (np.cos(W2 * (t - h / 2)) - np.cos(W2 * (t + h / 2))) / (W2 * h), np.zeros_like(t)]  # fmt: skip
    expected = r_true.inv().apply(a_n)  # the true motion acceleration (1-s mean) in body axes
    err = np.linalg.norm(a_b[trusted] - expected[trusted], axis=1)
    assert np.sqrt(np.mean(err**2)) < 0.1, np.sqrt(np.mean(err**2))  # of a 3 m/s² acceleration
    assert np.all(a_b[~trusted] == 0.0)


def test_no_correction_where_the_vehicle_hardly_accelerates_or_flies_fast():
    cfg = GnssAidConfig()
    rec, q_nb = accelerating_flight(60.0)
    still = rec.data.copy()
    still[["gnss_vel_n_m_s", "gnss_vel_e_m_s"]] = 1.0  # constant velocity: nothing to read a heading from
    a_b, trusted, covered = motion_acc_body(rec.t_s, q_nb, rec.acc_m_s2, still[["gnss_vel_n_m_s", "gnss_vel_e_m_s"]].to_numpy(), cfg)
    assert covered.mean() > 0.95 and not trusted.any() and not a_b.any()
    fast, _ = accelerating_flight(60.0, v0_ne=(25.0, 0.0))  # above the flight-speed gate: the network's
    a_b, trusted, covered = motion_acc_body(fast.t_s, q_nb, fast.acc_m_s2, fast.gnss_vel_ne_m_s, cfg)
    assert covered.mean() > 0.95 and not trusted.any()


def test_samples_near_a_clipped_gyro_give_no_heading_evidence_but_keep_their_correction():
    # where the gyro clipped (a tumble past its range) the attitude that turns the specific force into
    # the earth frame is wrong: stood for by 20 m/s² along body x for 1 s that the receiver does not
    # show — with 3 m/s² of real motion, enough to turn the heading offset read over the 30 s around it
    # (at 40 m/s² the unguarded aid loses its coherence there and corrects nothing)
    rec, q_nb = accelerating_flight(90.0)
    t, vel = rec.t_s, rec.gnss_vel_ne_m_s
    hit = (t >= 45.0) & (t < 46.0)
    acc = rec.acc_m_s2.copy()
    acc[hit, 0] += 20.0
    h = GnssAidConfig().smooth_s
    a_n = np.c_[A_MS2 * (np.cos(W1 * (t - h / 2)) - np.cos(W1 * (t + h / 2))) / (W1 * h),
                A_MS2 * (np.cos(W2 * (t - h / 2)) - np.cos(W2 * (t + h / 2))) / (W2 * h), np.zeros_like(t)]  # fmt: skip
    expected = Rotation.from_quat(q_nb[:, [1, 2, 3, 0]]).inv().apply(a_n)
    away = (np.abs(t - 45.5) > 2.0) & (np.abs(t - 45.5) < 15.0)  # beyond the averages, within the heading window

    def err_away(a_b, trusted):
        m = away & trusted
        assert m.sum() > 0.8 * away.sum()
        return float(np.sqrt(np.mean(np.sum((a_b[m] - expected[m]) ** 2, axis=1))))

    off = dataclasses.replace(GnssAidConfig(), clip_guard=False)
    unguarded = err_away(*motion_acc_body(t, q_nb, acc, vel, off, hit)[:2])
    a_b, trusted, _ = motion_acc_body(t, q_nb, acc, vel, GnssAidConfig(), hit)
    guarded = err_away(a_b, trusted)
    assert guarded < 0.05 and unguarded > 0.2, (guarded, unguarded)  # m/s² of a 3 m/s² acceleration
    assert trusted[hit].all()  # the correction is not cut there (switching it biases the filter)
    # nothing clipped: the unguarded result, bit for bit
    a0, tr0, _ = motion_acc_body(t, q_nb, acc, vel, off)
    a1, tr1, _ = motion_acc_body(t, q_nb, acc, vel, GnssAidConfig(), np.zeros(len(t), bool))
    np.testing.assert_array_equal(a0, a1)
    np.testing.assert_array_equal(tr0, tr1)


def test_an_accelerometer_marked_clipped_now_and_then_leaves_the_aid_as_it_was():
    # a vibrating multirotor's clip counter (0.1 s marked every 3 s, the accelerometer alone): a first
    # guard that cut the correction there took the training multirotors from 4.1° to 6.7° (session 22)
    from tepinn_flight.model.checkpoint import default_model_path, load_model
    from tepinn_flight.model.estimate import EST_Q_COLS, estimate_anchored

    model, anchor, _ = load_model(default_model_path())
    rec, _ = accelerating_flight(60.0)
    marked = FlightRecord(rec.data.copy(), dict(rec.meta))
    dt = rec.t_s - rec.t_s[0]
    marked.data["clipped"] = (np.mod(dt, 3.0) < 0.1) & (dt > 1.0)
    marked.data["gyr_clipped"] = False  # the reader says which sensor (a record without the column: the gyro)
    cfg = dataclasses.replace(anchor.learned_off, gnss_aid=True)
    a, b = estimate_anchored(model, rec, cfg), estimate_anchored(model, marked, cfg)
    assert a.attrs["gnss_aid"] == b.attrs["gnss_aid"] and a.attrs["gnss_aid"].endswith("; applied")
    np.testing.assert_array_equal(a[EST_Q_COLS].to_numpy(), b[EST_Q_COLS].to_numpy())


def test_the_anchored_estimate_with_the_receiver_gets_much_closer_to_the_truth():
    from tepinn_flight.evaluation.metrics import error_quat_earth, inclination_error_rad
    from tepinn_flight.model.checkpoint import default_model_path, load_model
    from tepinn_flight.model.estimate import EST_Q_COLS, estimate_anchored

    model, anchor, _ = load_model(default_model_path())
    rec, q_true = accelerating_flight(60.0)  # aided/plain 0.03 (0.28° vs 8.5°); 120 s gave the same

    def rmse_deg(e):
        m = rec.t_s >= 10.0
        err = inclination_error_rad(error_quat_earth(e[EST_Q_COLS].to_numpy()[m], q_true[m]))
        return np.degrees(np.sqrt(np.mean(err**2)))

    plain = estimate_anchored(model, rec, dataclasses.replace(anchor.learned_off, gnss_aid=False))
    aided = estimate_anchored(model, rec, dataclasses.replace(anchor.learned_off, gnss_aid=True))
    assert aided.attrs["gnss_aid"].endswith("; applied")
    # VQF leans toward the 3 m/s² (17°) motion acceleration its 3-s low-pass does not average out
    assert rmse_deg(aided) < 0.3 * rmse_deg(plain), (rmse_deg(aided), rmse_deg(plain))
    # a record without a receiver: the estimate is the unaided one, bit for bit, and says why
    bare, _ = accelerating_flight(60.0, gnss=False)
    on = estimate_anchored(model, bare, dataclasses.replace(anchor.learned_off, gnss_aid=True))
    off = estimate_anchored(model, bare, dataclasses.replace(anchor.learned_off, gnss_aid=False))
    np.testing.assert_array_equal(on[EST_Q_COLS].to_numpy(), off[EST_Q_COLS].to_numpy())
    assert on.attrs["gnss_aid"] == "GNSS-aided tilt: no GNSS velocity in the record; not applied"
    assert not anchor.learned_off.gnss_aid  # every correction off is plain VQF


def test_a_checkpoint_written_before_the_gnss_aid_runs_without_it():
    from tepinn_flight.model.anchor import AnchorConfig
    from tepinn_flight.model.checkpoint import anchor_config_from

    old = {"anchor_config": {"enabled": True, "pull_target": "fusion"}, "fusion_config": None}
    assert anchor_config_from(old).gnss_aid is False
    assert AnchorConfig().gnss_aid is True
    # session 14's aid (gnss_aid without gnss_aid_in_flight) loads as it ran
    s14 = {"anchor_config": {"enabled": True, "pull_target": "fusion", "gnss_aid": True}, "fusion_config": None}
    assert anchor_config_from(s14).gnss_aid and not anchor_config_from(s14).gnss_aid_in_flight
    assert AnchorConfig().gnss_aid_in_flight is True


def test_aided_windows_keep_the_flight_gate_in_fast_flight_without_its_centripetal_term():
    # a window 20° tilted whose v̂ says 60 m/s (flight gate 1; pull 0.5 → 10°): unaided it pulls and removes ω × v̂ + â; aided below
    # 20 m/s of ground speed the gate stays shut (the receiver says the vehicle is slow); aided at speed
    # (gnss_fast) it pulls, keeps its 10-s time constant, and the receiver's acceleration replaces ω × v̂ + â
    import math

    from tepinn_flight.model.anchor import AnchorConfig, AnchoredVQF, WindowOutput

    n = 100
    t = np.arange(n) * 0.01
    gyr, acc = np.tile([0.0, 0.0, 0.2], (n, 1)), np.tile([0.0, 0.0, -9.81], (n, 1))
    tilted = np.array([math.cos(math.radians(10)), math.sin(math.radians(10)), 0.0, 0.0])

    def after(cfg, aided, fast):
        f = AnchoredVQF(cfg, 0.01)
        f.update(t, gyr, acc)
        f.correct(WindowOutput(tilted, 0.01, np.zeros(3), np.array([60.0, 0, 0]), np.array([0.0, 1.0, 0]),
                               None, aided, fast))  # fmt: skip
        q = f.update(t[-1:] + 0.01, gyr[:1], acc[:1])[0][0]
        incl = math.degrees(2 * math.acos(min(1.0, math.sqrt(q[0] ** 2 + q[3] ** 2))))
        return incl, f.gate, f.tau_acc, f.vel.tolist(), f.acc_v.tolist()

    cfg = AnchorConfig(pull_gain=0.5)
    incl_u, gate, tau, vel, acc_v = after(cfg, False, False)
    assert gate == 1.0 and tau == 10.0 and vel == [60.0, 0, 0] and acc_v == [0, 1.0, 0]
    incl, gate, tau, vel, acc_v = after(cfg, True, False)
    assert gate == 0.0 and incl < 0.05 and tau == 3.0 and vel == [0, 0, 0] and acc_v == [0, 0, 0]
    incl, gate, tau, vel, acc_v = after(cfg, True, True)
    assert gate == 1.0 and incl == pytest.approx(10.0, abs=0.15) and tau == 10.0 and vel == [0, 0, 0] and acc_v == [0, 0, 0]
    assert incl_u > incl + 0.3  # unaided, ω × v̂ + â (13 m/s² sideways) also leaves the accelerometer VQF sees
    # session 14's aid: aided windows shut the gate whatever the speed
    incl, gate, tau, vel, acc_v = after(dataclasses.replace(cfg, gnss_aid_in_flight=False), True, True)
    assert gate == 0.0 and incl < 0.05 and vel == [0, 0, 0]


def test_the_settings_are_checked():
    from tepinn_flight.errors import ConfigError

    for bad in ({"smooth_s": 0.0}, {"min_coherence": 1.5}, {"passes": 0}, {"latency_s": -0.1}, {"max_speed_m_s": float("nan")},
                {"latency_grid_s": (0.0, -0.05)}, {"latency_min_gain": -0.01}):
        with pytest.raises(ConfigError):
            GnssAidConfig(**bad)


def test_estimate_says_what_the_gnss_aid_did_and_keeps_it_in_the_output(tmp_path, capsys):
    from tepinn_flight.record import write_record

    from .conftest import estimate_says_and_stores

    rec, _ = accelerating_flight(60.0)
    write_record(rec, tmp_path / "fly.parquet")
    # --no-gnss-aid: the estimate the live bridge gives, nothing said or stored about it
    line, on, off = estimate_says_and_stores(tmp_path, capsys, tmp_path / "fly.parquet", "gnss_aid", "--no-gnss-aid",
                                             "GNSS-aided")  # fmt: skip
    assert line.startswith("GNSS-aided tilt: motion acceleration") and line.endswith("; applied")
    assert np.abs(on["q_est_x"].to_numpy() - off["q_est_x"].to_numpy()).max() > 1e-2


@pytest.mark.slow
def test_on_a_real_log_with_a_receiver_the_aid_applies_and_gets_closer_to_the_autopilot(tmp_path):
    # erle (ArduCopter 3.3, 5 Hz GPS, held out): the EKF-class reference uses the GNSS too; VQF leans
    # toward the motion acceleration, the aided estimate much less (1.12° → 0.74°, session 14)
    import json

    from tepinn_flight.cli.main import main
    from tests.conftest import real_log

    out = tmp_path / "rep"
    assert main(["evaluate", str(real_log("erle_pxf_copter_15-12-2014_16.BIN")), "-o", str(out), "-q"]) == 0
    m = json.loads((out / "metrics.json").read_text())
    r = m["records"][0]
    assert r["gnss_aid"]["tepinn"].endswith("; applied")
    # its receiver read as 0.20 s late (rule 37c; ArduPilot's u-blox driver takes a 5/6-series receiver's velocity as
    # 0.22 s late, a 7/M8's as 0.12 s)
    assert "the receiver read as 0.20 s late" in r["gnss_aid"]["tepinn"], r["gnss_aid"]["tepinn"]
    incl = {e: r["results"][e]["inclination_rmse_deg"] for e in ("tepinn", "vqf")}
    assert incl["tepinn"] < 0.8 * incl["vqf"], incl
    assert any("GNSS-aided tilt" in n for n in m["notes"])


@pytest.mark.parametrize("max_speed", [20.0, float("inf")])
def test_the_receiver_s_part_made_apart_gives_the_formula_s_bits(max_speed):
    """:func:`gnss_evidence` made apart and handed to :func:`motion_acc_body` (as every pass, and the helper process,
    do since session 40) gives the same bits as the formula before the split (``tests/gnss_aid_reference.py``): with
    a clipped gyro (the guard), holes in the fixes, fast stretches (the speed margin) and an attitude estimate off the
    truth."""
    from tests import gnss_aid_reference as ref

    rec, q_nb = accelerating_flight(90.0, v0_ne=(14.0, 9.0))  # ground speed crosses 20 m/s
    t, vel = rec.t_s, rec.gnss_vel_ne_m_s.copy()
    vel[(t > 20.0) & (t < 21.5)] = np.nan  # a hole in the fixes
    q = quat_normalize(q_nb + np.random.default_rng(1).normal(0, 0.02, q_nb.shape))
    hit = (t >= 45.0) & (t < 46.0)
    cfg = dataclasses.replace(GnssAidConfig(), max_speed_m_s=max_speed)
    for clipped in (hit, None):
        ev = gnss_evidence(t, vel, cfg, clipped)
        got = motion_acc_body(t, q, rec.acc_m_s2, vel, cfg, clipped, ev)
        want = ref.motion_acc_body(t, q, rec.acc_m_s2, vel, cfg, clipped)
        for g, w in zip(got, want):
            assert np.array_equal(g, w)
        assert 0.03 < want[1].mean() < 0.99  # trusted in part: the masks are exercised


def test_a_record_with_no_acceleration_to_read_skips_the_aid_with_the_formula_s_masks():
    """A receiver showing no acceleration (a hover: constant velocity): :func:`gnss_evidence` says no sample may be
    trusted, and the passes (which then skip the aid's arithmetic) give the formula's masks and a zero correction."""
    from tests import gnss_aid_reference as ref

    rec, q_nb = accelerating_flight(90.0)
    t = rec.t_s
    vel = np.where(np.isfinite(rec.gnss_vel_ne_m_s), 1.5, np.nan) + np.random.default_rng(2).normal(0, 0.01, (len(t), 2))
    cfg = GnssAidConfig()
    ev = gnss_evidence(t, vel, cfg)
    assert not ev.may_trust
    got = motion_acc_body(t, q_nb, rec.acc_m_s2, vel, cfg, None, ev)
    want = ref.motion_acc_body(t, q_nb, rec.acc_m_s2, vel, cfg)
    for g, w in zip(got, want):
        assert np.array_equal(g, w)
    assert want[2].mean() > 0.9 and not want[1].any()  # covered, none trusted
    # the record's own receiver (a figure eight) may be trusted
    assert gnss_evidence(t, rec.gnss_vel_ne_m_s, cfg).may_trust


def test_the_receiver_s_bound_never_misses_a_sample_a_pass_would_trust():
    """:func:`may_trust_any` is a necessary condition of the formula's mask: over a sweep of the least acceleration
    (``min_accel_m_s2``) on a record whose fixes cover ~60 % of each heading window (the bound's ``frac > 0.5``
    matters: a bound without it says "nothing" where the formula trusts), with a clipped gyro and fast stretches,
    wherever the formula trusts a sample the evidence says it may; and the bound does say "nothing" within ~2× of the
    largest setting the formula trusts at (not vacuous)."""
    from tests import gnss_aid_reference as ref

    rec, q_nb = accelerating_flight(120.0, v0_ne=(14.0, 9.0))
    t, vel = rec.t_s, rec.gnss_vel_ne_m_s.copy()
    vel[(t % 10.0) > 6.0] = np.nan  # 6 s of fixes in every 10
    q = quat_normalize(q_nb + np.random.default_rng(1).normal(0, 0.02, q_nb.shape))
    hit = (t >= 45.0) & (t < 46.0)
    trusts, may = [], []
    settings = np.geomspace(0.5, 12.0, 40)
    for m in settings:
        cfg = dataclasses.replace(GnssAidConfig(), min_accel_m_s2=float(m))
        trusts.append(bool(ref.motion_acc_body(t, q, rec.acc_m_s2, vel, cfg, hit)[1].any()))
        may.append(gnss_evidence(t, vel, cfg, hit).may_trust)
    trusts, may = np.array(trusts), np.array(may)
    assert trusts[0] and not trusts[-1]  # the sweep crosses the formula's own threshold
    assert np.all(may[trusts])
    top = settings[trusts].max()
    assert not may[-1] and settings[~may].min() < 2.5 * top


def _with_hole(rec, t0: float, t1: float):
    """``rec`` with no fix between t0 and t1 (ingest leaves NaN across a gap of more than 2.5 fix periods)."""
    data = rec.data.copy()
    hole = (data["t_s"] > t0) & (data["t_s"] < t1)
    data.loc[hole, ["gnss_vel_n_m_s", "gnss_vel_e_m_s"]] = np.nan
    return FlightRecord(data, dict(rec.meta))


def test_a_hole_in_the_fixes_is_bridged_by_its_mean_acceleration_with_no_heading_read_there():
    """Rule 36: inside the fixes' span a hole's correction is the velocity's change across it over its length (the
    bridge's slope, in closed form from the fixes around it); the heading's evidence is read from real fixes only
    (the same mask as without the bridge); without a hole the bridge changes nothing, bit for bit."""
    rec, q_nb = accelerating_flight(90.0)
    holed = _with_hole(rec, 40.0, 43.0)
    t, v = holed.t_s, holed.gnss_vel_ne_m_s
    plain, bridged = GnssAidConfig(), GnssAidConfig(bridge_gaps=True)
    ev0, ev1 = (gnss_evidence(t, v, c) for c in (plain, bridged))
    np.testing.assert_array_equal(ev0.covered, ev1.covered)  # the evidence's mask: real fixes only
    inside = (t > 40.0 + 1.0) & (t < 43.0 - 1.0)  # both ends of the 1-s difference in the hole (and its latency)
    assert not ev0.covered[inside].any() and ev1.corrigible[inside].all()
    ok = np.all(np.isfinite(v), axis=1)
    a, b = np.flatnonzero(ok & (t < 41.0))[-1], np.flatnonzero(ok & (t > 42.0))[0]  # the fixes' last and first samples
    slope = (v[b] - v[a]) / (t[b] - t[a])
    np.testing.assert_allclose(np.c_[ev1.za.real, ev1.za.imag][inside], np.tile(slope, (inside.sum(), 1)), atol=1e-9)
    a_b0, tr0, _ = motion_acc_body(t, q_nb, holed.acc_m_s2, v, plain)
    a_b1, tr1, _ = motion_acc_body(t, q_nb, holed.acc_m_s2, v, bridged)
    assert not tr0[inside].any() and not a_b0[inside].any() and tr1[inside].all()
    assert np.array_equal(tr0, tr1 & ev1.covered) and np.array_equal(a_b0[tr0], a_b1[tr0])  # elsewhere: the same
    # the hole's correction: the bridge's slope in body axes (the filter's heading is the truth's here)
    r = Rotation.from_quat(q_nb[inside][:, [1, 2, 3, 0]])
    np.testing.assert_allclose(a_b1[inside], r.inv().apply(np.c_[np.tile(slope, (inside.sum(), 1)), np.zeros(inside.sum())]),
                               atol=0.05)  # fmt: skip
    for c in (plain, bridged):  # no hole: the same bits
        got = motion_acc_body(rec.t_s, q_nb, rec.acc_m_s2, rec.gnss_vel_ne_m_s, c)
        want = motion_acc_body(rec.t_s, q_nb, rec.acc_m_s2, rec.gnss_vel_ne_m_s, plain)
        for x, y in zip(got, want):
            np.testing.assert_array_equal(x, y)


def test_the_bridge_applies_on_the_vehicle_classes_named_and_brings_an_outage_at_a_peak_back_toward_the_truth():
    """Rule 36b: the anchored estimate bridges the receiver's holes where the log names a vehicle of a class in
    ``bridge_gaps_for``; a 3-s outage where the motion acceleration peaks, left unbridged, leaves that peak in the
    accelerometer while the rest of the manoeuvre is taken out (session 15's bias)."""
    import tepinn_flight.model.estimate as est
    from tepinn_flight.evaluation.metrics import error_quat_earth, inclination_error_rad
    from tepinn_flight.model.checkpoint import default_model_path, load_model
    from tepinn_flight.model.estimate import EST_Q_COLS, aid_settings, estimate_anchored

    model, anchor, _ = load_model(default_model_path())
    policy = GnssAidConfig(bridge_gaps_for=("multirotor",))
    assert GnssAidConfig() == policy  # shipped (rule 36b)
    with pytest.raises(Exception, match="bridge_gaps_for"):
        GnssAidConfig(bridge_gaps_for=("quad",))  # a class, not a vehicle type
    assert aid_settings(anchor, policy, "quadrotor")[0].bridge_gaps
    assert not aid_settings(anchor, policy, "fixed-wing")[0].bridge_gaps and not aid_settings(anchor, policy, None)[0].bridge_gaps
    rec, q_true = accelerating_flight(60.0)
    t = rec.t_s
    mag = np.hypot(A_MS2 * np.sin(W1 * t), A_MS2 * np.sin(W2 * t))
    peak = float(t[(t > 15) & (t < 55)][np.argmax(mag[(t > 15) & (t < 55)])])
    holed = _with_hole(rec, peak - 1.5, peak + 1.5)
    aided = dataclasses.replace(anchor.learned_off, gnss_aid=True)

    def rmse_deg(vehicle: str) -> float:
        r = FlightRecord(holed.data, {**holed.meta, "vehicle_type": vehicle})
        q = estimate_anchored(model, r, aided)[EST_Q_COLS].to_numpy()
        m = t >= 10.0
        return float(np.degrees(np.sqrt(np.mean(inclination_error_rad(error_quat_earth(q[m], q_true[m])) ** 2))))

    orig = est.GnssAidConfig
    try:
        est.GnssAidConfig = lambda: policy
        quad, wing = rmse_deg("quadrotor"), rmse_deg("fixed-wing")
    finally:
        est.GnssAidConfig = orig
    assert quad < 0.8 * wing, (quad, wing)


def _pooled_coherence_slow(rec, q_nb, cfg: GnssAidConfig, lat: float, at: np.ndarray) -> float:
    """The pooled coherence at one latency the obvious way: every sample of ``at`` (where all candidates have fixes),
    a Python loop over the 30-s blocks, the specific force turned by scipy."""
    t = rec.t_s
    f = Rotation.from_quat(q_nb[:, [1, 2, 3, 0]]).apply(np.array(rec.acc_m_s2))[:, :2]
    k = int(round(cfg.smooth_s * RATE_HZ))
    f = np.stack([np.convolve(f[:, i], np.ones(k) / k, mode="same") for i in range(2)], 1)  # centred (k even: ½ sample)
    a = motion_acc_ne(t, rec.gnss_vel_ne_m_s, dataclasses.replace(cfg, latency_s=lat))
    zf, za = (f[at, 0] + 1j * f[at, 1]), (a[at, 0] + 1j * a[at, 1])
    block = np.floor((t[at] - t[0]) / cfg.heading_window_s)
    num = den = 0.0
    for b in np.unique(block):
        m = block == b
        num += abs(np.sum(zf[m] * np.conj(za[m])))
        den += np.sqrt(np.sum(np.abs(zf[m]) ** 2) * np.sum(np.abs(za[m]) ** 2))
    return num / den


@pytest.mark.parametrize("latency_s, read_as, turn_rad", [(0.1, 0.1, 0.0), (0.35, 0.1, 0.0), (0.5, 0.5, 0.0), (0.5, 0.5, 2.0)])
def test_the_receivers_latency_is_read_where_the_pooled_coherence_peaks(latency_s, read_as, turn_rad):
    """Rule 37: on a record whose receiver is ``latency_s`` late, the pooled coherence (against a slow reference at
    every candidate) peaks at that latency; the record's latency is read as it where the peak clears the setting's
    (0.1 s) coherence by ``latency_min_gain`` — on these slow manoeuvres (periods of 8 and 11 s) 0.35 s does not
    (0.014 above), 0.5 s does (0.037). With the filter's heading origin different in each 30-s block (``turn_rad``
    more each block: a 6-D filter's heading drifts, if far more slowly) the pooling over blocks reads the same, where
    one sum over the whole record would not."""
    from tepinn_flight.model.gnss_aid import latency_candidates, latency_scores, read_latency

    rec, q_true = accelerating_flight(90.0, latency_s=latency_s)
    drift = Rotation.from_euler("z", (turn_rad * np.floor(rec.t_s / 30.0))[:, None])  # the filter's frame about down
    q_nb = (drift * Rotation.from_quat(q_true[:, [1, 2, 3, 0]])).as_quat()[:, [3, 0, 1, 2]]
    cfg = GnssAidConfig()
    num, den = latency_scores(rec.t_s, q_nb, rec.acc_m_s2, rec.gnss_vel_ne_m_s, cfg)
    grid = latency_candidates(cfg)
    p = num / den
    assert grid[np.argmax(p)] == pytest.approx(latency_s)
    assert read_latency(num, den, cfg) == pytest.approx(read_as)
    assert read_latency(num, den, dataclasses.replace(cfg, latency_min_gain=0.005)) == pytest.approx(latency_s)
    every = [motion_acc_ne(rec.t_s, rec.gnss_vel_ne_m_s, dataclasses.replace(cfg, latency_s=float(x))) for x in grid]
    ok = np.all([np.all(np.isfinite(a), axis=1) for a in every], axis=0)
    at = np.flatnonzero(ok)[:: int(round(0.02 * RATE_HZ))]
    slow = np.array([_pooled_coherence_slow(rec, q_nb, cfg, float(x), at) for x in grid])
    np.testing.assert_allclose(p, slow, atol=3e-3)  # the decimation's phase and the odd/even centring apart
    assert slow.max() - slow.min() > 0.01  # a peak: the test can tell latencies apart
    if turn_rad:  # one block (the whole record) would not see it: the turns cancel the sum
        one = dataclasses.replace(cfg, heading_window_s=1e9)
        n1, d1 = latency_scores(rec.t_s, q_nb, rec.acc_m_s2, rec.gnss_vel_ne_m_s, one)
        assert (n1 / d1).max() < 0.5 < p.max(), (n1 / d1, p)
    # a gain out of reach leaves the setting; an empty grid reads nothing
    assert read_latency(num, den, dataclasses.replace(cfg, latency_min_gain=10.0)) == cfg.latency_s
    assert read_latency(num[:0], den[:0], dataclasses.replace(cfg, latency_grid_s=())) == cfg.latency_s


def _aided_rmse_deg(latency_s: float, vehicle: str, **flight) -> tuple[float, object]:
    """The physics filter with the GNSS aid (the shipped anchor, learned parts off) on :func:`accelerating_flight` with a
    receiver ``latency_s`` late, logged as ``vehicle`` → (inclination RMSE after 10 s in °, the estimate)."""
    from tepinn_flight.evaluation.metrics import error_quat_earth, inclination_error_rad
    from tepinn_flight.model.checkpoint import default_model_path, load_model
    from tepinn_flight.model.estimate import EST_Q_COLS, estimate_anchored

    model, anchor, _ = load_model(default_model_path())
    rec, q_true = accelerating_flight(60.0, latency_s=latency_s, **flight)
    df = estimate_anchored(model, FlightRecord(rec.data, {**rec.meta, "vehicle_type": vehicle}),
                           dataclasses.replace(anchor.learned_off, gnss_aid=True))  # fmt: skip
    q = df[EST_Q_COLS].to_numpy()
    m = rec.t_s >= 10.0
    return float(np.degrees(np.sqrt(np.mean(inclination_error_rad(error_quat_earth(q[m], q_true[m])) ** 2)))), df


def test_a_late_receiver_read_as_late_brings_a_multirotor_s_estimate_back_toward_the_truth():
    """Rule 37 end to end: a receiver 0.5 s late, taken as 0.1 s late, subtracts an acceleration 0.4 s old; read from
    the record (with the first aided pass's attitude: rule 37b), the anchored estimate's error is halved, and it says
    what it read; a receiver on time is read as on time (the same error as not reading). Rule 37b: read only where the
    log names a vehicle of a class in ``read_latency_for`` (multirotors)."""
    import re

    from tepinn_flight.model.checkpoint import default_model_path, load_model
    from tepinn_flight.model.estimate import aid_settings

    anchor = load_model(default_model_path())[1]
    assert GnssAidConfig().read_latency_for == ("multirotor",)  # shipped (rule 37b)
    with pytest.raises(Exception, match="read_latency_for"):
        GnssAidConfig(read_latency_for=("quad",))  # a class, not a vehicle type
    assert aid_settings(anchor, None, "copter")[0].latency_grid_s == GnssAidConfig().latency_grid_s
    assert aid_settings(anchor, None, "plane")[0].latency_grid_s == () == aid_settings(anchor, None, None)[0].latency_grid_s

    on_time, said_on_time = _aided_rmse_deg(0.1, "quadrotor")
    on_time_as_set, _ = _aided_rmse_deg(0.1, "fixed-wing")
    late_as_set, said_set = _aided_rmse_deg(0.5, "fixed-wing")  # not read: the setting's 0.1 s
    late_read, said = _aided_rmse_deg(0.5, "quadrotor")
    assert late_read < 0.6 * late_as_set, (late_read, late_as_set)
    assert on_time == on_time_as_set and "late" not in said_on_time.attrs["gnss_aid"], on_time
    read = re.search(r"the receiver read as ([0-9.]+) s late", said.attrs["gnss_aid"])
    assert read and 0.45 <= float(read.group(1)) <= 0.65, said.attrs["gnss_aid"]  # with the first aided pass's attitude
    assert "late" not in said_set.attrs["gnss_aid"]


def test_a_receiver_far_later_than_the_setting_is_read_with_the_plain_pass_s_attitude(monkeypatch):
    """Rule 37c: a receiver 0.7 s late on quicker manoeuvres (periods 2.5 and 3.3 s) is trusted nowhere at the setting's
    0.1 s, so there is no aided pass to read with: read with the plain pass's attitude (the grid's end, 0.6 s), the aid
    then applies and the error falls below the unaided one (a fixed wing's log: not read). And a read at which the next
    pass trusts nothing leaves the last pass that did, reported at the setting's latency."""
    import tepinn_flight.model.estimate as est

    quick = {"periods_s": (2.5, 3.3)}
    read, said = _aided_rmse_deg(0.7, "quadrotor", **quick)
    unread, said_unread = _aided_rmse_deg(0.7, "fixed-wing", **quick)
    assert "the receiver read as 0.60 s late); applied" in said.attrs["gnss_aid"], said.attrs["gnss_aid"]
    assert said_unread.attrs["gnss_aid"].endswith("not applied"), said_unread.attrs["gnss_aid"]
    assert read < 0.9 * unread, (read, unread)
    monkeypatch.setattr(est, "record_latency", lambda *a: 1000.0)  # a "read" no fix covers: pass 1 trusts nothing
    _, kept = _aided_rmse_deg(0.1, "quadrotor", **quick)
    assert kept.attrs["gnss_aid"].endswith("; applied") and "late" not in kept.attrs["gnss_aid"], kept.attrs["gnss_aid"]
