"""The GNSS aid's per-segment formula as it stood before session 40 split the receiver's part out of it
(:func:`tepinn_flight.model.gnss_aid.gnss_evidence`, made once per record and on a long record by the helper process):
kept here, word for word, so that ``tests/test_gnss_aid.py`` can check the split gives the same bits."""

from __future__ import annotations

import numpy as np

from tepinn_flight.model.gnss_aid import GnssAidConfig, _centred_mean, motion_acc_ne, rotate_rows


def motion_acc_body(t_s, q_nb_wxyz, acc_b, vel_ne_m_s, cfg: GnssAidConfig, gyr_clipped=None):
    """The motion acceleration in body axes (N, 3) to take out of the accelerometer, for one segment
    estimated as ``q_nb_wxyz`` (any heading origin), and the per-sample mask where it is applied.
    ``gyr_clipped``: the samples where the gyro read its range (:attr:`GnssAidConfig.clip_guard`;
    None: none did)."""
    n = len(t_s)
    if n < 3:
        return np.zeros((n, 3)), np.zeros(n, bool), np.zeros(n, bool)
    dt = float(np.median(np.diff(t_s)))
    k = max(1, int(round(cfg.smooth_s / dt)))
    a_ne = motion_acc_ne(t_s, vel_ne_m_s, cfg)
    covered = np.all(np.isfinite(a_ne), axis=1)
    rows = (np.require(x, np.float64, "CW") for x in (q_nb_wxyz, acc_b))  # the kernels' one signature
    f_ne = _centred_mean(rotate_rows(*rows)[:, :2], k)  # specific force in the filter's earth frame
    zf = f_ne[:, 0] + 1j * f_ne[:, 1]
    za = a_ne[:, 0] + 1j * a_ne[:, 1]
    usable = covered & np.isfinite(zf)  # where a correction can be made
    use = usable  # where the heading's evidence is read
    if cfg.clip_guard and gyr_clipped is not None and np.any(gyr_clipped):
        m_clip = k + 2 * int(round(cfg.latency_s / dt))  # the averages' span, the fixes' latency on each side
        use = use & ~(_centred_mean(np.asarray(gyr_clipped, float), m_clip) > 0)
    w = max(1, int(round(cfg.heading_window_s / dt)))
    c = _centred_mean(np.where(use, zf * np.conj(za), 0), w)
    pf = _centred_mean(np.where(use, np.abs(zf) ** 2, 0.0), w)
    pa = _centred_mean(np.where(use, np.abs(za) ** 2, 0.0), w)
    frac = _centred_mean(use.astype(float), w)
    with np.errstate(invalid="ignore", divide="ignore"):
        coh = np.abs(c) / np.sqrt(pf * pa)
        rms_a = np.sqrt(pa / np.maximum(frac, 1e-12))
    trusted = usable & (frac > 0.5) & (coh >= cfg.min_coherence) & (rms_a >= cfg.min_accel_m_s2)
    rot = np.exp(1j * np.angle(c))
    za_e = rot * za  # the GNSS acceleration in the filter's earth frame
    speed = np.hypot(vel_ne_m_s[:, 0], vel_ne_m_s[:, 1])
    wild = ~(speed < cfg.max_speed_m_s)  # NaN (no fix): only where covered, below
    m = max(1, int(round(2 * cfg.margin_s / dt)) + 1)
    near_wild = _centred_mean((wild & covered).astype(float), m) > 0
    trusted &= ~near_wild
    a_n = np.zeros((n, 3))
    za_t = za_e[trusted]
    za_t = za_t * np.minimum(1.0, cfg.max_accel_m_s2 / np.maximum(np.abs(za_t), 1e-12))
    a_n[trusted, 0] = za_t.real
    a_n[trusted, 1] = za_t.imag
    q_conj = q_nb_wxyz * np.array([1.0, -1.0, -1.0, -1.0])
    return rotate_rows(np.require(q_conj, np.float64, "CW"), a_n), trusted, covered  # zero where not trusted
