"""Whether a log's reference attitude can be learned from (model/reference_trust.py): it must turn as the
gyro turns and agree with the accelerometer's gravity where the vehicle is quiet."""

from __future__ import annotations

import numpy as np
import pytest

from tepinn_flight.model.reference_trust import (ReferenceTrustConfig, check_reference, gravity_disagreement_deg,
                                                 turn_disagreement_deg_s)  # fmt: skip
from tepinn_flight.quat import quat_angle_between, quat_from_rotvec, quat_mul
from tepinn_flight.record import GYR_COLS, QREF_COLS, FlightRecord
from tests.conftest import real_log
from tests.test_gyro_selfcal import turns_with_rests


def _with(rec: FlightRecord, ref=None, gyr=None) -> FlightRecord:
    """``rec`` with another reference attitude or gyro."""
    data = rec.data.copy()
    if ref is not None:
        data[QREF_COLS] = ref
    if gyr is not None:
        data[GYR_COLS] = gyr
    return FlightRecord(data, dict(rec.meta))


def test_a_true_reference_is_learned_from():
    rec, _ = turns_with_rests(seed=1)  # hand-held-like turns of 120–300° between rests: the reference is the truth
    chk = check_reference(rec)
    assert chk.trusted and chk.turn_share == 0.0 and chk.gravity_deg < 0.5 and chk.quiet_s > 10


def test_a_reference_that_drifts_away_from_the_gyro_is_not():
    """Over the record's last 30 %, the reference turns 20 °/s about the body's y axis on its own (an estimator
    that diverged): the gyro check reads that rate back on those seconds, a share beyond the 20 % it allows.
    (A drift over most of a log would pass for a gyro bias — the check takes the median turn difference out —
    and is left to the gravity check.)"""
    rec, q = turns_with_rests(seed=2)
    t = rec.t_s
    t0 = t[int(0.7 * len(t))]
    drift = np.where(t > t0, t - t0, 0.0) * np.radians(20.0)
    bad = _with(rec, ref=quat_mul(q, quat_from_rotvec(np.outer(drift, [0.0, 1.0, 0.0]))))
    chk = check_reference(bad)
    assert not chk.trusted and 0.25 < chk.turn_share < 0.35
    assert "not trusted" in chk.describe()
    turn = turn_disagreement_deg_s(bad)
    assert np.median(turn[-8:]) == pytest.approx(20.0, abs=1.0) and np.median(turn[:20]) < 1.0  # the drift, read back


def test_a_reference_in_another_frame_is_not():
    """The reference of a board mounted 30° off about x (the same turns, a fixed rotation apart): the gravity check
    sees the tilt at the rests (30° where gravity is across x, less where it is along it)."""
    rec, q = turns_with_rests(seed=3)
    q_off = quat_mul(q, quat_from_rotvec(np.radians([30.0, 0.0, 0.0])))
    chk = check_reference(_with(rec, ref=q_off))
    assert not chk.trusted and 15.0 < chk.gravity_deg <= 30.0
    # ... and a reference of the right frame, turned about the vertical only (another heading), is fine
    q_yaw = quat_mul(quat_from_rotvec(np.radians([0.0, 0.0, 40.0])), q)
    assert check_reference(_with(rec, ref=q_yaw)).trusted


def test_an_uncalibrated_gyro_does_not_make_a_true_reference_untrusted():
    """A gyro reading 15 °/s off on two axes (an uncalibrated consumer part's turn-on bias): the constant bias is
    read from the intervals and taken out before the turns are compared."""
    rec, _ = turns_with_rests(seed=4)
    gyr = rec.gyr_rad_s + np.radians([15.0, -15.0, 0.0])
    raw = turn_disagreement_deg_s(_with(rec, gyr=gyr), interval_s=1.0)
    assert np.median(raw) < 1.0 and check_reference(_with(rec, gyr=gyr)).trusted


def test_missing_reference_rows_are_left_out_not_judged():
    """Rows without a reference — NaN, or zeros as a broken logger writes them — are left out of both checks."""
    rec, q = turns_with_rests(seed=7)
    holed = q.copy()
    holed[::7] = np.nan
    holed[3::7] = 0.0
    chk = check_reference(_with(rec, ref=holed))
    assert chk.trusted and chk.gravity_deg < 0.5 and np.isfinite(chk.gravity_deg) and chk.turn_share < 0.05


def test_too_little_to_judge_keeps_the_log():
    rec, _ = turns_with_rests(seed=5, n_turns=1)
    cfg = ReferenceTrustConfig(min_intervals=10_000, min_quiet_s=10_000.0)
    chk = check_reference(rec, cfg)
    assert chk.trusted and chk.turn_share is None and chk.gravity_deg is None
    angles, quiet_s = gravity_disagreement_deg(rec)
    assert quiet_s > 0 and len(angles) > 0


def test_real_logs_a_diverged_reference_and_a_good_one():
    """The shared ArduPilot log whose attitude pitches to 100° in 5 s while its gyro turns a few degrees a second
    (fine-tuning on it took a validation error from 0.43° to 0.79°), and the ArduCopter log the fine-tuning test
    learns from."""
    from tepinn_flight.ingest import ingest_log

    bad = check_reference(ingest_log(real_log("aplogan_nan.log")))
    good = check_reference(ingest_log(real_log("erle_pxf_copter_15-12-2014_16.BIN")))
    assert not bad.trusted and bad.turn_share > 0.2
    assert good.trusted and good.turn_share < 0.05 and good.gravity_deg < 2.0


def test_info_says_whether_a_logs_reference_is_the_imus_attitude(capsys):
    """`info` on a raw log: a line for the reference check, and the figures in --json."""
    import json

    from tepinn_flight.cli.main import main

    bad, good = real_log("aplogan_nan.log"), real_log("erle_pxf_copter_15-12-2014_16.BIN")
    assert main(["info", str(bad)]) == 0
    line = next(x for x in capsys.readouterr().out.splitlines() if x.strip().startswith("reference check"))
    assert "turns unlike the gyro (by > 10 °/s) on 31 % of 13 1-s intervals" in line and line.rstrip().endswith(
        "another frame)") and "not trusted" in line  # fmt: skip
    assert main(["info", str(good), "--json"]) == 0
    chk = json.loads(capsys.readouterr().out)[str(good)]["reference_check"]
    assert chk["trusted"] and chk["turn_share"] < 0.05 and chk["intervals"] > 100 and chk["gravity_deg"] < 2.0


def _shifted(q: np.ndarray, n: int) -> np.ndarray:
    """The reference ``n`` samples late (negative: early), the rows it leaves without one NaN."""
    out = np.roll(q, n, axis=0)
    out[slice(0, n) if n > 0 else slice(n, None)] = np.nan
    return out


@pytest.mark.parametrize("lag_s", [0.5, -0.3, 0.12, 0.05])
def test_a_reference_off_the_imus_time_is_read_back_and_refused_past_a_tenth_of_a_second(lag_s):
    """The turns' own reference moved later or earlier (a logger's clock, a stamp taken on receipt): the shift at
    which its body rate best matches the gyro's is read back to a few milliseconds; past 0.1 s it is not trusted
    (learned from, it would teach the network to lag)."""
    rec, q = turns_with_rests(seed=1)  # 100 Hz
    chk = check_reference(_with(rec, ref=_shifted(q, int(round(lag_s / 0.01)))))
    # to within half the record's 10-ms step: these turns hold each gyro sample over its step, which the check's
    # trapezoid reads as the rate at its instant (a simulation's or a real IMU's samples are instants: ~0 there)
    assert chk.lag_s == pytest.approx(lag_s, abs=0.006)
    assert chk.trusted == (abs(lag_s) <= 0.1)
    if not chk.trusted:
        assert "off the IMU's time" in chk.describe() and ("behind" if lag_s > 0 else "ahead of") in chk.describe()
    assert chk.frame_deg < 1.0  # a late reference is still the IMU's frame


@pytest.mark.parametrize("deg", [90.0, 180.0, 35.0])
def test_a_board_turned_about_the_vertical_is_read_back_as_another_frame(deg):
    """The reference of a board mounted turned about its z axis (q ⊗ R_z): the rotation that carries the reference's
    body rates onto the gyro's is R_z itself — its angle read back to a degree — and past 20° it is not trusted."""
    rec, q = turns_with_rests(seed=3)
    chk = check_reference(_with(rec, ref=quat_mul(q, quat_from_rotvec(np.radians([0.0, 0.0, deg])))))
    assert chk.frame_deg == pytest.approx(deg, abs=1.0) and abs(chk.lag_s) < 0.005
    assert not chk.trusted and "another mounting" in chk.describe()


def test_the_frame_is_the_least_squares_rotation_scipy_finds():
    """Independent reference: scipy's ``Rotation.align_vectors`` on the same rate pairs gives the same rotation
    angle as the check's own SVD, for a board turned about a skew axis."""
    from scipy.spatial.transform import Rotation

    from tepinn_flight.model.reference_trust import _centred, rates_on_grid

    rec, q = turns_with_rests(seed=6)
    off = np.radians([20.0, -30.0, 40.0])
    turned = _with(rec, ref=quat_mul(q, quat_from_rotvec(off)))
    segs, _ = rates_on_grid(turned, 0.02)
    g, r = (np.concatenate([_centred(s[k]) for s in segs]) for k in (0, 1))
    m = np.isfinite(g).all(axis=1) & np.isfinite(r).all(axis=1)
    rot, _ = Rotation.align_vectors(g[m], r[m])
    chk = check_reference(turned)
    assert chk.frame_deg == pytest.approx(np.degrees(rot.magnitude()), abs=0.05)
    assert chk.frame_deg == pytest.approx(np.degrees(np.linalg.norm(off)), abs=1.0)


def test_turns_about_one_axis_or_no_motion_leave_timing_and_frame_unjudged():
    """Turns about z alone leave a rotation about z unknown (the frame is not judged; the timing still is), a
    record at rest has no rates to match (neither), and a telemetry-rate IMU is too coarse to time."""
    rec, q = turns_with_rests(seed=1)
    t = rec.t_s
    yaw = np.radians(60.0) * np.sin(0.7 * t)
    q_z = quat_from_rotvec(np.outer(yaw, [0.0, 0.0, 1.0]))
    gyr = np.zeros((len(t), 3))
    gyr[:, 2] = np.radians(60.0) * 0.7 * np.cos(0.7 * t)
    chk = check_reference(_with(rec, ref=quat_mul(q_z, quat_from_rotvec(np.radians([0.0, 0.0, 90.0]))), gyr=gyr))
    assert chk.frame_deg is None and abs(chk.lag_s) < 0.01
    still = _with(rec, ref=np.tile([1.0, 0.0, 0.0, 0.0], (len(t), 1)), gyr=np.zeros((len(t), 3)))
    assert check_reference(still).lag_s is None and check_reference(still).frame_deg is None
    from tepinn_flight.ingest import ingest_log

    slow = check_reference(ingest_log(real_log("ardusub_2023-04-18_11-03-34.tlog")))  # its IMU at 2 Hz
    assert slow.lag_s is None and slow.frame_deg is None


def test_a_real_flight_turned_or_late_is_refused_where_the_older_checks_let_it_pass():
    """erle's ArduCopter flight: as recorded its reference is within 0.03 s and 3° of the gyro; turned 90° about the
    vertical or 0.5 s late it passed the turn and gravity checks (the flight is too gentle for them: session 53's
    review) and now fails on the frame and the timing, each read back."""
    from tepinn_flight.ingest import ingest_log

    rec = ingest_log(real_log("erle_pxf_copter_15-12-2014_16.BIN"))
    q = rec.q_ref_wxyz
    ok = check_reference(rec)
    assert ok.trusted and abs(ok.lag_s) < 0.03 and ok.frame_deg < 3.0
    turned = check_reference(_with(rec, ref=quat_mul(q, quat_from_rotvec(np.radians([0.0, 0.0, 90.0])))))
    assert turned.turn_share <= 0.2 and turned.gravity_deg <= 10.0  # what the older checks see: nothing wrong
    assert not turned.trusted and turned.frame_deg == pytest.approx(90.0, abs=3.0)
    late = check_reference(_with(rec, ref=_shifted(q, 25)))  # 50 Hz: 0.5 s
    assert late.turn_share <= 0.2 and late.gravity_deg <= 10.0
    assert not late.trusted and late.lag_s == pytest.approx(0.5 + ok.lag_s, abs=0.01)


def test_a_fixed_wings_gentle_turns_are_not_taken_for_gravity():
    """A simulated c172x (true attitude as reference, GNSS receiver): quiet by the rate and the accelerometer's
    norm, its gentle coordinated turns (0.05–0.1 rad/s at ~50 m/s) lean the accelerometer by their bank, and the
    gravity check refused the truth itself (11.8° over 2 s) — a third of twelve such flights. The averaged rate times
    the GNSS speed now keeps those out: the truth passes; without a GNSS speed a fixed wing's quiet is not judged;
    and a reference truly turned 30° is still refused on a flight with straight, steady stretches."""
    from dataclasses import replace

    from tepinn_flight.record import GNSS_VEL_COLS
    from tepinn_flight.sim.simulate import simulate_record

    rec = simulate_record("c172x", 120.0, 400.0, 2)
    before = check_reference(rec, replace(ReferenceTrustConfig(), max_turn_acc_m_s2=float("inf")))
    assert not before.trusted and before.gravity_deg > 10.0
    assert check_reference(rec).trusted
    no_gnss = FlightRecord(rec.data.drop(columns=GNSS_VEL_COLS), dict(rec.meta))
    assert gravity_disagreement_deg(no_gnss)[1] == 0.0  # a fixed wing without a speed: no quiet taken
    straight = simulate_record("c172x", 120.0, 400.0, 7)
    ok = check_reference(straight)
    assert ok.trusted and ok.quiet_s >= 10.0 and ok.gravity_deg < 6.0
    off = check_reference(_with(straight, ref=quat_mul(straight.q_ref_wxyz, quat_from_rotvec(np.radians([30.0, 0, 0])))))
    assert not off.trusted and off.gravity_deg > 20.0


def test_align_reference_moves_a_late_turned_reference_back_onto_the_imus_time_and_axes():
    """A reference 0.4 s late and of a board turned 90° about z: moved by the lag its check reads and turned back by
    the frame rotation it fits, it is the true attitude again (to the slerp's and the fit's error) and passes; a
    trusted reference is returned as it is, and one refused for another reason (diverged) is left alone."""
    from tepinn_flight.model.reference_trust import align_reference, aligned_if_refused
    from tepinn_flight.quat import quat_angle_between

    rec, q = turns_with_rests(seed=2)
    bad = _with(rec, ref=_shifted(quat_mul(q, quat_from_rotvec(np.radians([0.0, 0.0, 90.0]))), 40))
    chk = check_reference(bad)
    moved, shift, turn = align_reference(bad, chk)
    assert shift == pytest.approx(0.4, abs=0.006) and turn == pytest.approx(90.0, abs=0.5)
    e = np.degrees(quat_angle_between(moved.q_ref_wxyz, q))
    assert np.nanmedian(e) < 0.3 and np.nanpercentile(e, 95) < 1.0 and np.isfinite(e).mean() > 0.85
    assert check_reference(moved).trusted and moved.meta["reference_aligned"]["shift_s"] == shift
    same, what = aligned_if_refused(rec)
    assert same is rec and what is None
    t = rec.t_s
    drift = np.where(t > t[len(t) // 2], t - t[len(t) // 2], 0.0) * np.radians(25.0)
    diverged = _with(rec, ref=quat_mul(q, quat_from_rotvec(np.outer(drift, [1.0, 0.0, 0.0]))))
    kept, what = aligned_if_refused(diverged)
    assert kept is diverged and (what is None or "still not trusted" in what)


def test_evaluate_align_reference_scores_against_the_moved_reference_and_says_so(tmp_path, capsys):
    """`evaluate --align-reference` on a record whose reference is 0.4 s late: scored against the moved reference
    (in the summary, trusted), a note saying what was moved; without the option the record fails the check and
    every estimator's error is the lag's."""
    import json

    from tepinn_flight.cli.main import main
    from tepinn_flight.record import write_record

    rec, q = turns_with_rests(seed=8)
    path = tmp_path / "late.parquet"
    write_record(_with(rec, ref=_shifted(q, 40)), path)
    runs = {}
    for flag in ([], ["--align-reference"]):
        out = tmp_path / ("ev" + "".join(flag))
        assert main(["evaluate", str(path), "-o", str(out), "--no-model", "--no-peers", "-q", *flag]) == 0
        capsys.readouterr()
        runs[bool(flag)] = (json.loads((out / "metrics.json").read_text())["records"][0], (out / "report.md").read_text())
    (before, _), (after, page) = runs[False], runs[True]
    assert not before["reference_trusted"] and after["reference_trusted"]
    assert "late: reference moved 0.40" in page and "s earlier" in page
    err = {k: [v["inclination_rmse_deg"] for v in r[0]["results"].values()] for k, r in runs.items()}
    assert max(err[True]) < 0.5 * min(err[False])


def test_gravity_tilt_reads_a_small_lean_of_the_reference_from_the_rests():
    """The rate-fitted turn leans by the IMU's own axis errors (half a degree on BROAD's tapping trial); at the record's
    rests the accelerometer reads gravity alone, and `gravity_tilt` reads the lean back: a reference leaning 2° about x
    and 1° about y comes back level to 0.05°. Without a rest (every sample turning) it reads nothing."""
    from tepinn_flight.model.reference_trust import gravity_tilt
    from tepinn_flight.quat import quat_angle_between

    rec, q = turns_with_rests(seed=5)
    lean = np.radians([2.0, 1.0, 0.0])
    leaning = quat_mul(q, quat_from_rotvec(np.tile(lean, (len(q), 1))))
    phi = gravity_tilt(rec, leaning, ReferenceTrustConfig())
    back = quat_mul(leaning, quat_from_rotvec(np.tile(phi, (len(q), 1))))
    assert np.degrees(np.nanmax(quat_angle_between(back, q))) < 0.05
    spinning = _with(rec, gyr=rec.gyr_rad_s + np.radians([0.0, 0.0, 5.0]))  # 5 °/s on z throughout: never at rest
    assert gravity_tilt(spinning, leaning, ReferenceTrustConfig()) is None


def test_a_reference_stored_on_its_own_rows_of_a_faster_imu_is_still_checked():
    """A reference on every 4th row only (a 25-Hz motion capture in a 100-Hz record, NaN between), those rows off the
    1-s interval edges and the 20-ms grid's sample pairs: it is read between its own rows, so a reference 0.4 s late
    and turned 90° is still refused — it had been 'trusted' with every check unjudged — and a true one still passes.
    A hole of its own (2 s without a row) stays one."""
    from tepinn_flight.model.reference_trust import reference_at

    rec, q = turns_with_rests(seed=2)
    sparse = np.full_like(q, np.nan)
    sparse[1::4] = q[1::4]
    chk = check_reference(_with(rec, ref=sparse))
    assert chk.trusted and abs(chk.lag_s) < 0.006 and chk.frame_deg < 1.0 and chk.turn_share == 0.0
    bad = _shifted(quat_mul(q, quat_from_rotvec(np.radians([0.0, 0.0, 90.0]))), 40)
    sparse_bad = np.full_like(q, np.nan)
    sparse_bad[1::4] = bad[1::4]
    chk = check_reference(_with(rec, ref=sparse_bad))
    assert not chk.trusted and chk.lag_s == pytest.approx(0.4, abs=0.006) and chk.frame_deg == pytest.approx(90.0, abs=1.0)
    # ... and `--align-reference` reads it the same way: its moved copy is the truth again (it had been NaN throughout)
    from tepinn_flight.model.reference_trust import aligned_if_refused

    moved, what = aligned_if_refused(_with(rec, ref=sparse_bad))
    e = np.degrees(quat_angle_between(moved.q_ref_wxyz, q))
    assert "moved 0.4" in what and np.nanmedian(e) < 0.3 and np.isfinite(e).mean() > 0.85
    t = rec.t_s
    holed = sparse.copy()
    holed[(t > 10.0) & (t < 12.0)] = np.nan
    q_at, known = reference_at(t, holed, np.array([9.0, 11.0, 13.0]))
    assert known.tolist() == [True, False, True]
    assert np.degrees(quat_angle_between(q_at[[0, 2]], q[[900, 1300]])).max() < 0.5


def test_a_20_hz_imu_is_timed_whatever_its_stamps_round_to():
    """At 20 Hz the grid's step is the IMU's period, 0.05 s, exactly the limit under which timing is judged; stamps
    from 250 s make the median period 0.05000000000001 s, which had switched the timing and frame checks off (a
    reference turned 90° then passed on a gentle flight). The same record from 0 s and from 250 s reads the same."""
    from tepinn_flight.model.reference_trust import rate_alignment

    rec, q = turns_with_rests(seed=3, rate_hz=20.0)
    data = rec.data.copy()
    data["t_s"] = 250.0 + np.arange(len(data)) * 0.05
    late = FlightRecord(data, dict(rec.meta))
    assert np.median(np.diff(late.t_s)) > 0.05  # (the rounding this is about)
    a, b = rate_alignment(rec), rate_alignment(late)
    assert a.lag_s is not None and b.lag_s == pytest.approx(a.lag_s, abs=1e-6)
    assert b.frame_deg == pytest.approx(a.frame_deg, abs=1e-6)


def test_an_accelerometer_reading_zeros_at_rest_is_not_read_as_gravity():
    """A dropout written as zeros on a rest: no direction to read gravity from. Those samples are left out (a
    division by zero had printed a RuntimeWarning and made the angle NaN: refused while the line said 'trusted');
    the verdict and its line come from one rule."""
    import warnings

    rec, q = turns_with_rests(seed=4)
    data = rec.data.copy()
    data.loc[rec.t_s < 3.0, ["acc_x_m_s2", "acc_y_m_s2", "acc_z_m_s2"]] = 0.0
    zeros = FlightRecord(data, dict(rec.meta))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        chk = check_reference(zeros)
    assert chk.trusted and np.isfinite(chk.gravity_deg) and chk.gravity_deg < 0.5
    assert chk.describe().endswith("; trusted")


def test_a_lag_past_the_search_is_said_to_be_at_least_its_edge_and_not_moved_by():
    """A reference 1.3 s late: the best shift within ±1 s lies at the edge, so the lag is at least 1 s (said so), and
    ``align_reference`` does not move it by that edge (the true lag is not known)."""
    from tepinn_flight.model.reference_trust import align_reference

    rec, q = turns_with_rests(seed=1)
    chk = check_reference(_with(rec, ref=_shifted(q, 130)))
    assert not chk.trusted and not chk.lag_bracketed and chk.lag_s == pytest.approx(1.0)
    assert "at least 1.000 s behind" in chk.describe()
    assert align_reference(_with(rec, ref=_shifted(q, 130)), chk)[1] == 0.0
    assert check_reference(_with(rec, ref=_shifted(q, 30))).lag_bracketed


def test_the_line_says_why_timing_was_not_judged():
    rec, q = turns_with_rests(seed=1)
    t = rec.t_s
    still = _with(rec, ref=np.tile([1.0, 0.0, 0.0, 0.0], (len(t), 1)), gyr=np.zeros((len(t), 3)))
    assert "timing: not judged (too little motion)" in check_reference(still).describe()
    from tepinn_flight.ingest import ingest_log

    slow = check_reference(ingest_log(real_log("ardusub_2023-04-18_11-03-34.tlog")))  # its IMU at 2 Hz
    assert "an IMU at 2 Hz, under 20 Hz" in slow.describe()
    _, other = turns_with_rests(seed=10)  # the reference of other turns (about other axes, by other angles)
    n = min(len(q), len(other))
    unlike = _with(FlightRecord(rec.data.iloc[:n].reset_index(drop=True), dict(rec.meta)), ref=other[:n])
    assert "timing: not judged (the rates correlate at best 0." in check_reference(unlike).describe()


def test_align_reference_moves_a_lag_the_turn_check_refused_under_the_timing_limit():
    """A reference 60 ms late on fast turns: under the timing check's 0.1 s but the turns over 1-s intervals disagree
    on more than a fifth of them, so it is refused; ``--align-reference`` moves it by the measured lag (past 40 ms:
    beyond the measurement's noise) and then it passes. 20 ms is left alone."""
    from tepinn_flight.model.reference_trust import aligned_if_refused

    from tepinn_flight.model.gyro_selfcal import attitude_at
    from tepinn_flight.quat import gravity_body
    from tepinn_flight.record import ACC_COLS

    rec, q = turns_with_rests(seed=2)
    # the same turns three times as far (up to ~700 °/s): the attitude integrated from the tripled rate, the
    # accelerometer reading its gravity
    t = rec.t_s
    gyr3 = rec.gyr_rad_s * 3.0
    q3 = np.zeros((len(t), 4))
    attitude_at(np.ascontiguousarray(gyr3), np.r_[np.diff(t), 0.0], 1.0, 1.0, 1.0, 0.0, 0.0, 0.0,
                np.arange(len(t), dtype=np.int64), q3, np.zeros((len(t), 3, 3)))  # fmt: skip
    q3 = quat_mul(np.tile(q[0], (len(t), 1)), q3)
    data = rec.data.copy()
    data[GYR_COLS] = gyr3
    data[ACC_COLS] = -9.81 * gravity_body(q3)
    fast = FlightRecord(data, dict(rec.meta))
    assert check_reference(_with(fast, ref=q3)).trusted
    late = _with(fast, ref=_shifted(q3, 6))
    chk = check_reference(late)
    assert chk.lag_s == pytest.approx(0.06, abs=0.006) and not chk.trusted and "intervals" in chk.describe()
    moved, what = aligned_if_refused(late)
    assert moved is not late and "s earlier" in what and check_reference(moved).trusted
    assert aligned_if_refused(_with(fast, ref=_shifted(q3, 2)))[1] is None


def test_the_rate_grid_masks_a_cell_whose_integral_reads_a_bad_sample():
    """A cell's gyro integral reads the samples from the one at or before its start to the one after its end: a NaN
    there (or a clipped sample) masks the cell. At 60 Hz a NaN right after a cell's last sample had been integrated
    as zero in an unmasked cell (0.375 rad/s read for 0.5)."""
    from tepinn_flight.model.reference_trust import rates_on_grid
    from tepinn_flight.record import make_frame

    n, w = 600, np.array([0.5, -0.3, 0.2])
    t = np.arange(n) / 60.0
    q = quat_from_rotvec(np.outer(t, w))
    for row in range(8, 20):
        gyr = np.tile(w, (n, 1))
        gyr[row] = np.nan
        acc = np.tile([0.0, 0.0, -9.81], (n, 1))
        rec = FlightRecord(make_frame(t, np.zeros(n, np.int32), gyr, acc, q_ref_wxyz=q),
                           {"source_kind": "synthetic", "source_file": "x", "vehicle_type": "synthetic",
                            "reference_source": "synthetic-truth"})  # fmt: skip
        (g, r), = rates_on_grid(rec, 0.02)[0]
        ok = np.isfinite(g).all(axis=1)
        assert ok.sum() > 0.9 * len(g) and np.abs(g[ok] - w).max() < 1e-9, row


def test_a_reference_no_part_of_which_could_be_checked_is_said_to_be_unjudged():
    """A record of 1.5 s: too short for the gyro's intervals, the quiet gravity and the timing — its check says so
    instead of "trusted" (review60: `info` called it trusted), and it still refuses nothing; a longer one is judged."""
    from tepinn_flight.model.reference_trust import check_reference
    from tepinn_flight.model.synthetic import synthetic_record

    short = check_reference(synthetic_record(seed=4, duration_s=1.5, rate_hz=100.0))
    assert short.trusted and not short.judged
    assert short.describe().endswith("; not judged: nothing to check it by (kept, as trusted)"), short.describe()
    long = check_reference(synthetic_record(seed=4, duration_s=60.0, rate_hz=100.0))
    assert long.judged and long.describe().endswith("; trusted"), long.describe()
