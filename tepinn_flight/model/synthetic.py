"""Closed-form synthetic IMU flights for model tests and the tiny training config.

A smooth random body rate (sum of sinusoids) is integrated with fine RK4 steps into the true
attitude; the accelerometer reads the specific force ``−g_body + a_lin`` with a smooth random
linear acceleration; gyro bias, white noise and a slow bias walk come from the seed. Exact truth,
no JSBSim — small and fast enough for unit tests.
"""

from __future__ import annotations

import numpy as np

from ..conventions import GRAVITY_M_S2
from ..quat import gravity_body, quat_canonical, quat_from_rotvec, quat_mul, quat_normalize
from ..record import FlightRecord, make_frame


def synthetic_record(seed: int = 0, duration_s: float = 30.0, rate_hz: float = 200.0,
                     max_rate_rad_s: float = 4.0, gyr_bias_rad_s: float = 0.02,
                     gyr_noise_rad_s: float = 0.01, acc_noise_m_s2: float = 0.1,
                     lin_acc_m_s2: float = 2.0) -> FlightRecord:  # fmt: skip
    rng = np.random.default_rng(seed)
    n = int(round(duration_s * rate_hz))
    t = np.arange(n) / rate_hz
    sub = 4  # RK4-free exact integration: constant-rate sub-steps via the exponential map

    def smooth(scale, n_sines=5):
        f = rng.uniform(0.05, 1.0, (n_sines, 3))
        ph = rng.uniform(0, 2 * np.pi, (n_sines, 3))
        amp = rng.normal(size=(n_sines, 3)) * scale / np.sqrt(n_sines)
        def fn(tt):  # noqa: E306
            return (amp[None] * np.sin(2 * np.pi * f[None] * tt[:, None, None] + ph[None])).sum(1)
        return fn

    w_fn = smooth(max_rate_rad_s)
    a_fn = smooth(lin_acc_m_s2)
    w = w_fn(t)
    q = np.empty((n, 4))
    q[0] = quat_normalize(rng.normal(size=4)) if seed % 2 else [1.0, 0, 0, 0]
    h = 1.0 / rate_hz / sub
    for i in range(1, n):
        qi = q[i - 1]
        for s in range(sub):
            tm = t[i - 1] + (s + 0.5) * h
            qi = quat_mul(qi, quat_from_rotvec(w_fn(np.array([tm]))[0] * h))
        q[i] = quat_normalize(qi)
    g_b = gravity_body(q) * GRAVITY_M_S2
    a_lin_n = a_fn(t)
    from ..quat import quat_conj, quat_rotate

    a_lin_b = quat_rotate(quat_conj(q), a_lin_n)
    f_b = -g_b + a_lin_b
    bias0 = rng.normal(size=3) * gyr_bias_rad_s
    walk = np.cumsum(rng.normal(size=(n, 3)), axis=0) * gyr_bias_rad_s * 0.02 / np.sqrt(rate_hz)
    bias = bias0 + walk
    gyr = w + bias + rng.normal(size=(n, 3)) * gyr_noise_rad_s
    acc = f_b + rng.normal(size=(n, 3)) * acc_noise_m_s2
    df = make_frame(t, np.zeros(n, int), gyr, acc, None, quat_canonical(q), None,
                    gyr_bias_rad_s=bias, acc_bias_m_s2=np.zeros((n, 3)))  # fmt: skip
    meta = {"format_version": 1, "source_file": f"synthetic-{seed}", "source_kind": "synthetic",
            "imu_rate_hz": rate_hz, "reference_source": "synthetic-truth", "vehicle_type": "synthetic",
            "seed": seed}  # fmt: skip
    return FlightRecord(df, meta)
