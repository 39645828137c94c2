"""Published peer estimators: VQF, offline VQF, RIANN, x-io Fusion (regular dependencies).

Each peer is imported only when used; a missing or broken package still gives ``None`` plus a
one-line note, never a crash. Frame conventions are resolved once here (never per record):

- The peers expect a **z-up sensor frame** in which the accelerometer at rest reads +g along z. Our
  body frame is FRD (at rest, level: acc z ≈ −9.81), so we feed them the sensor frame
  ``S = body turned 180° about x``: ``v_S = (x, −y, −z)_B`` (BROAD's own sensor axes, see
  :mod:`tepinn_flight.ingest.broad`), ``q_SB = (0, 1, 0, 0)``.
- VQF and RIANN output sensor → ENU (z up; in 6-D the heading origin is arbitrary), so
  ``q_NB = q_NE ⊗ q_ES ⊗ q_SB`` with ``q_NE = (0, √½, √½, 0)``.
- Fusion (``imufusion``) runs in its NWU convention, deg/s and g units:
  ``q_NB = q_{NED←NWU} ⊗ q_{NWU←S} ⊗ q_SB`` with ``q_{NED←NWU} = (0, 1, 0, 0)``. (With its ENU
  convention the output is off by a constant −90° heading; NWU avoids that.)
"""

from __future__ import annotations

import os

import numpy as np
import pandas as pd

from ..conventions import GRAVITY_M_S2
from ..quat import quat_mul, quat_normalize
from ..model.anchor import _FLIP, Q_NED_ENU, Q_SENSOR_BODY  # the frames VQF works in: one home
from ..model.anchor import to_sensor as body_to_zup_sensor  # body FRD → the z-up sensor frame S
from ..record import FlightRecord, segment_slices
from .estimators import estimate_frame, record_mag
from .names import display_name


Q_NED_NWU = np.array([0.0, 1.0, 0.0, 0.0])  # 180° about x


def q_nb_from_earth_sensor(q_es: np.ndarray, q_ned_earth: np.ndarray) -> np.ndarray:
    """``q_NB = q_{NED←E} ⊗ q_ES ⊗ q_SB`` for a peer output q_ES (sensor → its earth frame E)."""
    q_es = np.asarray(q_es, np.float64)
    shape = q_es.shape
    return quat_normalize(quat_mul(np.broadcast_to(q_ned_earth, shape), quat_mul(q_es, np.broadcast_to(Q_SENSOR_BODY, shape))))


def _rate(t: np.ndarray) -> float:
    d = np.diff(t)
    d = d[np.isfinite(d) & (d > 0)]
    return 1.0 / float(np.median(d)) if d.size else 100.0


class _PeerBase:
    kind = "peer"
    causal = True
    uses_mag = False
    tracks_heading = True

    def estimate(self, record: FlightRecord) -> pd.DataFrame:
        n = len(record)
        q = np.full((n, 4), np.nan)
        bias = None
        gyr, acc, t = record.gyr_rad_s, record.acc_m_s2, record.t_s
        mag = record_mag(record) if self.uses_mag else None
        for sl in segment_slices(record.segment):
            g = body_to_zup_sensor(np.nan_to_num(gyr[sl]))
            a = body_to_zup_sensor(np.nan_to_num(acc[sl]))
            m = None if mag is None else body_to_zup_sensor(np.nan_to_num(mag[sl]))
            q_s, b_s = self._run(g, a, m, 1.0 / _rate(t[sl]) if sl.stop - sl.start > 1 else 0.01)
            q[sl] = q_nb_from_earth_sensor(q_s, self.q_ned_earth)
            if b_s is not None:
                bias = np.full((n, 3), np.nan) if bias is None else bias
                bias[sl] = b_s * _FLIP  # back to body axes
        return estimate_frame(t, q, None, bias)


class VqfEstimator(_PeerBase):
    """VQF (Laidig & Seel 2023), online ``VQF(Ts).updateBatch`` or acausal ``offlineVQF``."""

    q_ned_earth = Q_NED_ENU

    def __init__(self, offline: bool = False, use_mag: bool = False, params: dict | None = None):
        import vqf  # noqa: F401  (ImportError -> skipped by the caller)

        self.offline = offline
        self.uses_mag = use_mag
        self.causal = not offline
        self.params = dict(params or {})
        self.name = ("offline-vqf" if offline else "vqf") + ("-9d" if use_mag else "")

    def _run(self, g, a, m, ts):
        import vqf

        if self.offline:
            out = vqf.offlineVQF(g, a, m, ts, self.params or None)
        else:
            out = vqf.VQF(ts, **self.params).updateBatch(g, a, m)
        # (a record without a magnetometer runs 6-D here too, as the harness's note says: VQF gives no 9-D then)
        return (out["quat9D"] if self.uses_mag and m is not None else out["quat6D"]), out["bias"]


class RiannEstimator(_PeerBase):
    """RIANN (Weber et al. 2021): pretrained GRU, 6-D attitude only (heading undefined)."""

    q_ned_earth = Q_NED_ENU
    tracks_heading = False  # its heading is not a heading: the report leaves its heading figures out

    def __init__(self):
        import riann

        path = os.path.join(os.path.dirname(riann.__file__), "riann.onnx")  # riann 0.2.0 cannot find it itself
        self.model = riann.RIANN(path)
        self.name = "riann"

    def _run(self, g, a, m, ts):
        return quat_normalize(np.asarray(self.model.predict(a, g, 1.0 / ts), np.float64)), None  # acc first


class FusionEstimator(_PeerBase):
    """x-io Fusion (``imufusion``): Python loop over ``Ahrs.update``; deg/s and g units.

    Settings of x-io's own advanced example (gain 0.5, gyroscope range 2000 °/s, acceleration and
    magnetic rejection 10°, rejection timeout 5 s) plus its ``Bias`` module (stationary periods).
    ``AhrsSettings()`` defaults instead switch rejection off, which fails on fast translations. The price in agile
    flight: once a flip has taken its tilt away, an accelerometer that keeps leaving the 10° gate now and then keeps
    its recovery from triggering, and it can stay tens of degrees off (the demo's F450: 49.5° inclination RMSE, 7.5°
    with rejection off; session 44) — Fusion as x-io configures it, not as tuned for a drone.
    """

    q_ned_earth = Q_NED_NWU

    def __init__(self, use_mag: bool = False, gain: float = 0.5, bias_correction: bool = True,
                 gyroscope_range_deg_s: float = 2000.0, rejection_deg: float = 10.0, rejection_timeout_s: float = 5.0):  # fmt: skip
        import imufusion  # noqa: F401

        self.uses_mag = use_mag
        self.gain = gain
        self.bias_correction = bias_correction
        self.gyroscope_range_deg_s = gyroscope_range_deg_s
        self.rejection_deg = rejection_deg
        self.rejection_timeout_s = rejection_timeout_s
        self.name = "fusion" + ("-9d" if use_mag else "")

    def _run(self, g, a, m, ts):
        import imufusion

        rate = 1.0 / ts
        ahrs = imufusion.Ahrs()
        ahrs.set_settings(imufusion.AhrsSettings(
            convention=imufusion.CONVENTION_NWU, gain=self.gain, gyroscope_range=self.gyroscope_range_deg_s,
            acceleration_rejection=self.rejection_deg, magnetic_rejection=self.rejection_deg,
            rejection_timeout=int(round(self.rejection_timeout_s * rate)), sample_rate=int(round(rate))))  # fmt: skip
        bias = None
        if self.bias_correction:
            bias = imufusion.Bias()
            bias.set_settings(imufusion.BiasSettings(sample_rate=int(round(rate))))
        g_deg = np.degrees(g)
        a_g = a / GRAVITY_M_S2
        n = len(g)
        q = np.empty((n, 4))
        b = np.zeros((n, 3))
        for i in range(n):
            gi = g_deg[i]
            if bias is not None:
                gc = bias.update(gi)
                b[i] = gi - gc
                gi = gc
            if m is not None:
                ahrs.update(gi, a_g[i], m[i])
            else:
                ahrs.update_no_magnetometer(gi, a_g[i])
            q[i] = ahrs.get_quaternion()
        return q, np.radians(b) if bias is not None else None


#: name -> (package it needs, constructor) of every peer the harness knows.
PEERS = {
    "vqf": ("vqf", lambda: VqfEstimator()),
    "vqf-9d": ("vqf", lambda: VqfEstimator(use_mag=True)),
    "offline-vqf": ("vqf", lambda: VqfEstimator(offline=True)),
    "offline-vqf-9d": ("vqf", lambda: VqfEstimator(offline=True, use_mag=True)),
    "riann": ("riann", lambda: RiannEstimator()),
    "fusion": ("imufusion", lambda: FusionEstimator()),
    "fusion-9d": ("imufusion", lambda: FusionEstimator(use_mag=True)),
}


def make_peer(name: str, notes: list | None = None):
    """The peer ``name`` or None with a note when its package is not installed (or fails to load)."""
    package, ctor = PEERS[name]
    try:
        return ctor()
    except ImportError as exc:
        msg = (f"{display_name(name)} skipped: package '{package}' is not installed "
               f"(pip install {package}) [{type(exc).__name__}: {exc}]")  # fmt: skip
    except Exception as exc:  # a broken install must not stop the evaluation
        msg = f"{display_name(name)} skipped: '{package}' failed to load ({type(exc).__name__}: {exc})"
    if notes is not None:
        notes.append(msg)
    return None


def available_peers(names=("vqf", "offline-vqf", "riann", "fusion"), notes: list | None = None) -> list:
    return [p for p in (make_peer(n, notes) for n in names) if p is not None]


__all__ = ["VqfEstimator", "RiannEstimator", "FusionEstimator", "make_peer", "available_peers", "PEERS",
           "body_to_zup_sensor", "q_nb_from_earth_sensor"]
