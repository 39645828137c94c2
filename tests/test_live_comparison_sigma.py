"""The live comparison holds each difference to the autopilot against the estimate's own σ (session 50): the share
within 3σ and the mean NEES (d/σ)², counted only where a σ came with the estimate, the σ of that estimate (not of
a neighbour) even where estimates are passed over by the pairing."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from tepinn_flight.live.comparison import LiveComparison
from tepinn_flight.live.status import format_summary


def _run(estimates):
    """EKF ATTITUDE level at 10 Hz; ``estimates``: (t, tilt about x in rad, σ or None)."""
    from pymavlink.dialects.v20 import all as m2

    c = LiveComparison()
    ekf_t = np.arange(0.0, 3.05, 0.1)
    k = 0
    for t_e in ekf_t:
        c.on_ekf(m2.MAVLink_attitude_message(int(round(t_e * 1000)), 0.0, 0.0, 0.0, 0, 0, 0), "ATTITUDE", float(t_e))
        while k < len(estimates) and estimates[k][0] <= t_e:
            t, tilt, s = estimates[k]
            q = Rotation.from_rotvec([tilt, 0.0, 0.0]).as_quat(scalar_first=True)
            c.on_estimate(t, tuple(q), s)
            k += 1
    return c


def test_the_share_within_3_sigma_and_the_nees_are_the_estimates_own():
    rng = np.random.default_rng(3)
    n = 120
    t = 0.2 + np.arange(n) * 0.02  # estimates at 50 Hz from 0.2 s, inside the EKF's span
    sig = rng.uniform(0.002, 0.02, n)
    ratio = rng.uniform(0.0, 5.0, n)  # |difference| / σ, kept away from 3 by the draw below
    ratio[np.abs(ratio - 3.0) < 0.05] = 2.0
    tilt = ratio * sig * np.where(rng.random(n) < 0.5, -1, 1)
    given = rng.random(n) < 0.8  # some estimates come without σ
    est = [(float(t[i]), float(tilt[i]), float(sig[i]) if given[i] else None) for i in range(n)]
    s = _run(est).summary()
    assert s["n"] == n  # every estimate paired
    want_in = np.mean(ratio[given] <= 3.0)
    want_nees = np.mean(ratio[given] ** 2)
    assert s["within_3sigma"] == pytest.approx(want_in, abs=1e-4)
    assert s["nees"] == pytest.approx(want_nees, rel=1e-3)
    line = format_summary({"ekf_difference_deg": s, "estimates": {"count": n}})
    assert f"within 3σ {100 * want_in:.1f} %" in line


def test_estimates_before_the_autopilots_first_attitude_do_not_shift_the_sigmas():
    """Estimates the pairing leaves out (before the EKF's first attitude) must not hand their σ to later ones."""
    est = [(-0.5, 0.5, 1e-6), (-0.3, 0.5, 1e-6)]  # huge ratio if wrongly used
    est += [(0.2 + 0.1 * i, 0.001, 0.01) for i in range(10)]  # ratio 0.1 each
    s = _run(est).summary()
    assert s["n"] == 10
    assert s["within_3sigma"] == 1.0
    assert s["nees"] == pytest.approx(0.01, rel=1e-3)


def test_no_sigma_no_figures():
    s = _run([(0.2 + 0.1 * i, 0.001, None) for i in range(5)]).summary()
    assert s["n"] == 5 and "nees" not in s and "within_3sigma" not in s
    assert math.isfinite(s["mean"])


def test_after_a_reboot_the_differences_are_still_held_against_their_sigma():
    """The autopilot reboots (its clock and the estimates' start again near 0): the σs given before can pair with
    nothing now, and must not stand in front of the new ones."""
    from pymavlink.dialects.v20 import all as m2

    c = LiveComparison()
    for i in range(20):  # 50 s ... 52 s: estimates 0.001 rad off level, σ 0.01 (ratio 0.1), EKF at 10 Hz
        t = 50.0 + 0.1 * i
        c.on_ekf(m2.MAVLink_attitude_message(int(t * 1000), 0.0, 0.0, 0.0, 0, 0, 0), "ATTITUDE", 100.0 + 0.1 * i)
        c.on_estimate(t + 0.05, tuple(Rotation.from_rotvec([0.001, 0, 0]).as_quat(scalar_first=True)), 0.01)
    c.on_estimate(53.0, tuple(Rotation.from_rotvec([0.001, 0, 0]).as_quat(scalar_first=True)), 0.01)  # never paired
    before, paired = c.n_sigma, c.hist.count
    assert before == paired == 19
    for i in range(20):  # after the reboot (the arrival clock goes on): 1 s ... 3 s, ratio 4 (outside 3σ)
        t = 1.0 + 0.1 * i
        c.on_ekf(m2.MAVLink_attitude_message(int(t * 1000), 0.0, 0.0, 0.0, 0, 0, 0), "ATTITUDE", 103.0 + 0.1 * i)
        c.on_estimate(t + 0.05, tuple(Rotation.from_rotvec([0.04, 0, 0]).as_quat(scalar_first=True)), 0.01)
    assert c.hist.count - paired >= 14  # paired again once the reboot is confirmed (5 attitudes)
    assert c.n_sigma - before == c.hist.count - paired  # and each new difference against its own σ
    assert c.n_within_3sigma == before  # none of them within 3σ


def test_without_the_autopilots_attitude_the_sigmas_kept_stay_bounded():
    """A bridge running for hours where the autopilot sends no attitude: the σs waiting for a pairing are bounded as
    the comparator's own pending estimates are."""
    c = LiveComparison()
    q = tuple(Rotation.identity().as_quat(scalar_first=True))
    for i in range(5000):
        c.on_estimate(0.02 * i, q, 0.01)
    assert len(c.sigmas) <= c.cmp.pending.maxlen
