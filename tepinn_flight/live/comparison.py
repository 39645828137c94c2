"""The live comparison: TE-PINN's estimates against the autopilot's own attitude (its EKF).

The autopilot's ATTITUDE_QUATERNION is used, else its ATTITUDE (ignored while an
ATTITUDE_QUATERNION came in the last 2 s); attitudes whose time is not newer than the newest one
taken are dropped and counted (``imu.ekf_dropped``). Each estimate is paired with the EKF at its
time (:class:`~tepinn_flight.live.inputs.EkfComparator`: slerped between the bracketing EKF
samples); the inclination differences go into a histogram (``ekf_difference_deg`` in the summary),
the latest difference into the diagnostics and the status line. Each difference is also held against the estimate's
own σ at that time (the per-axis σ of its 2-D tilt error; the inclination difference is that error's length): the
share within 3σ and the mean NEES (d/σ)² against the autopilot (``within_3sigma``, ``nees`` in the summary; a
calibrated σ gives 98.9 % and 2 against the truth — against an EKF the EKF's own error counts too). A live view
(:mod:`~tepinn_flight.live.view`), when there is one, gets every EKF attitude, every estimate and
every difference.

ArduPilot reports the vehicle's attitude, the level trim ``AHRS_TRIM_X/Y`` away from the IMU board's
frame that TE-PINN estimates in (:mod:`tepinn_flight.ingest.ahrs_trim`): once the trim is known —
from the PARAM_VALUEs of a ground station's parameter download, or the bridge's own request — the
EKF's attitude is turned into the board's frame before the difference (``ahrs_trim_rad`` in the
summary), as ``ingest`` turns a log's reference.
"""

from __future__ import annotations

import math
from collections import deque

import numpy as np

from ..ingest.ahrs_trim import TRIM_PARAMS, usable_trim, vehicle_to_board
from .inputs import EkfComparator, ekf_attitude, mavlink_text
from .sample_order import DUPLICATE, STALE, SampleOrder
from .status import angle_histogram

#: ATTITUDE is ignored this long after an ATTITUDE_QUATERNION
QUATERNION_HOLD_S = 2.0
#: the latest difference goes into an estimate's diagnostics when it is this close in time
DIAG_DIFF_AGE_S = 0.5


class LiveComparison:
    def __init__(self, view=None):
        self.view = view
        self.order = SampleOrder()
        self.src_seen: dict[str, float] = {}
        self.cmp = EkfComparator()
        self.hist = angle_histogram()
        self.last = None  # (t_s, droll, dpitch, dincl, dheading) of the latest difference
        self.params: dict[str, float] = {}  # the autopilot's AHRS_TRIM_X/Y, as they come
        self.trim = None  # (x, y) rad once known and non-zero
        # (t_s, σ rad) of the estimates not yet paired with the EKF: no more than the comparator keeps waiting
        self.sigmas: deque = deque(maxlen=self.cmp.pending.maxlen)
        self.n_sigma = 0  # differences held against a finite σ
        self.n_within_3sigma = 0
        self.nees_sum = 0.0

    def on_param(self, m) -> None:
        """A PARAM_VALUE of an ArduPilot autopilot: its level trim."""
        name = mavlink_text(m.param_id)
        if name in TRIM_PARAMS and math.isfinite(float(m.param_value)):
            self.params[name] = float(m.param_value)
            self.trim = usable_trim(*(self.params.get(n) for n in TRIM_PARAMS))

    def on_ekf(self, m, name: str, t_in: float) -> None:
        """The autopilot's ATTITUDE_QUATERNION or ATTITUDE."""
        self.src_seen[name] = t_in
        if name == "ATTITUDE" and t_in - self.src_seen.get("ATTITUDE_QUATERNION", -1e9) < QUATERNION_HOLD_S:
            return  # ATTITUDE_QUATERNION is there: use it alone
        a = ekf_attitude(m)
        if a is None:
            return
        if self.order.accept(a[0], t_in) in (DUPLICATE, STALE):
            return
        if self.trim is not None:  # the vehicle's attitude → the IMU board's
            a = (a[0], a[1], tuple(vehicle_to_board(np.array([a[2]]), *self.trim)[0].tolist()))
        if self.view is not None:
            self.view.ekf(a[0], a[2])
        for d in self.cmp.add_ekf(a[0], a[2]):
            self._diff(d)

    def on_estimate(self, t_s: float, q_nb_wxyz, sigma_rad: float | None = None) -> None:
        """An estimate and, where given, its σ (rad)."""
        if self.view is not None:
            self.view.estimate(t_s, q_nb_wxyz)
        if sigma_rad is not None:
            if self.sigmas and t_s < self.sigmas[-1][0]:  # the estimates' clock started again (a reboot): the σs
                self.sigmas.clear()  # before it pair with nothing now, and would stand in front of the new ones
            self.sigmas.append((t_s, float(sigma_rad)))
        for d in self.cmp.add_estimate(t_s, q_nb_wxyz):
            self._diff(d)

    def _sigma_at(self, t_s: float) -> float | None:
        """The σ given with the estimate at ``t_s`` (the differences come in the estimates' order; those left out of
        the pairing are passed over)."""
        while self.sigmas and self.sigmas[0][0] < t_s:
            self.sigmas.popleft()
        if self.sigmas and self.sigmas[0][0] == t_s:
            return self.sigmas.popleft()[1]
        return None

    def _diff(self, d) -> None:
        self.hist.add(d[3])
        self.last = d
        s = self._sigma_at(d[0])
        if s is not None and math.isfinite(s) and s > 0 and math.isfinite(d[3]):
            r = d[3] / s
            self.n_sigma += 1
            self.n_within_3sigma += r <= 3.0
            self.nees_sum += r * r
        if self.view is not None:
            self.view.differences([d])

    def diff_near(self, t_s: float):
        """(droll, dpitch, dincl, dheading) in rad of the latest difference when it is near
        ``t_s``, else None (for the estimate's diagnostics)."""
        if self.last is not None and abs(self.last[0] - t_s) < DIAG_DIFF_AGE_S:
            return self.last[1:]
        return None

    def status(self) -> str:
        if self.last is None:
            return "dIncl -"
        return f"dIncl {math.degrees(self.last[3]):.2f} deg dHead {math.degrees(self.last[4]):.1f} deg"

    def summary(self) -> dict:
        dif = self.hist.summary(math.degrees(1.0), 3)
        if self.hist.count:
            dif["rms"] = round(math.degrees(self.hist.rms()), 3)
        if self.n_sigma:  # the estimate's σ against the autopilot's attitude
            dif["within_3sigma"] = round(self.n_within_3sigma / self.n_sigma, 4)
            dif["nees"] = round(self.nees_sum / self.n_sigma, 3)
        dif["ahrs_trim_rad"] = list(self.trim) if self.trim is not None else None
        return dif
