"""Motor vibration of multirotors, added to the truth specific force and body rate.

JSBSim models a rigid airframe, so rotor imbalance and blade-pass vibration are added after the
flight as a truth-level disturbance (documented in ``flight_sims/README.md``). For each motor and
for its 1x (imbalance) and 2x (blade-pass, two blades) harmonics we add a sinusoid whose phase
follows the logged rotor speed, whose amplitude grows with the square of the rotor speed, and
whose direction in body axes is drawn from the seed. Samples are box-car averages over the sample
interval (what a delta-angle / delta-velocity IMU integrates), which removes aliasing at multiples
of the sample rate, so the integrated vibration stays bounded. The vibration's own attitude
oscillation (amplitude < 1e-4 rad) is not added to ``q_nb``.
"""

from __future__ import annotations

import numpy as np
from numba import njit


def _unit(rng: np.random.Generator, z_weight: float) -> np.ndarray:
    v = rng.normal(size=3)
    v[2] *= z_weight
    return v / np.linalg.norm(v)


#: the harmonics: (multiple of the rotor speed, weight of body z in its direction, amplitude share)
HARMONICS = ((1, 0.3, 1.0), (2, 2.0, 0.6))


@njit(cache=True)
def _sine_arguments(rotor_hz, phase0, dt_s, harmonic, offset):
    """Per motor and harmonic (rows in the order motor, then harmonic): the boxcar's ``pi f dt`` (``np.sinc``'s
    argument, its zeros replaced by ``eps`` as numpy does) and the phase at the sample's midpoint."""
    n, m = rotor_hz.shape
    k = len(harmonic)
    y = np.empty((m * k, n))
    z = np.empty((m * k, n))
    eps = np.finfo(np.float64).eps
    for i in range(m):
        for h in range(k):
            c = i * k + h
            for j in range(n):
                f = harmonic[h] * rotor_hz[j, i]
                x = np.pi * (f * dt_s)
                y[c, j] = x if x != 0.0 else eps
                z[c, j] = harmonic[h] * phase0[j, i] + offset[c] - np.pi * f * dt_s
    return y, z


@njit(cache=True)
def _accumulate(rotor_hz, gain, ref_hz, y, sin_y, sin_z, acc_amp, gyr_amp, share, acc_u, acc_dir, gyr_u, gyr_dir, k):
    """Sum of every motor's and harmonic's ``gain (f/f_ref)² sinc(f dt) sin(phase)`` along its drawn directions:
    (acc, gyr). The products in numpy's order, so the sums are the same bits as the array expressions."""
    n, m = rotor_hz.shape
    acc = np.zeros((n, 3))
    gyr = np.zeros((n, 3))
    for c in range(m * k):
        i = c // k
        for j in range(n):
            r = rotor_hz[j, i] / ref_hz
            s = gain[j] * (r * r) * (sin_y[c, j] / y[c, j]) * sin_z[c, j]
            a = s * acc_amp * share[c] * acc_u[c]
            g = s * gyr_amp * share[c] * gyr_u[c]
            for d in range(3):
                acc[j, d] += a * acc_dir[c, d]
                gyr[j, d] += g * gyr_dir[c, d]
    return acc, gyr


def motor_vibration(rotor_hz: np.ndarray, gain: np.ndarray, dt_s: float,
                    rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, dict]:
    """(acc (N, 3) m/s^2, gyr (N, 3) rad/s, description) for rotor speeds ``rotor_hz`` (N, M)."""
    rotor_hz = np.ascontiguousarray(rotor_hz, dtype=float)
    gain = np.ascontiguousarray(gain, dtype=float)
    n, m = rotor_hz.shape
    ref_hz = max(float(np.median(rotor_hz)), 1.0)  # amplitudes are given at the typical rotor speed
    acc_amp = float(rng.uniform(0.3, 1.5))  # m/s^2 per motor and harmonic at ref speed
    gyr_amp = float(rng.uniform(0.004, 0.02))  # rad/s
    # each motor's and harmonic's random phase offset, amplitudes and directions (drawn in this order)
    k = len(HARMONICS)
    offset, share, acc_u, gyr_u = np.empty(m * k), np.empty(m * k), np.empty(m * k), np.empty(m * k)
    acc_dir, gyr_dir = np.empty((m * k, 3)), np.empty((m * k, 3))
    for i in range(m):
        for h, (_, z_weight, h_share) in enumerate(HARMONICS):
            c = i * k + h
            share[c] = h_share
            offset[c] = rng.uniform(0.0, 2.0 * np.pi)
            acc_u[c] = rng.uniform(0.5, 1.0)
            acc_dir[c] = _unit(rng, z_weight)
            gyr_u[c] = rng.uniform(0.5, 1.0)
            gyr_dir[c] = _unit(rng, 1.0)
    # phase = 2*pi*integral(f dt); the box-car average of sin over [t - dt, t] is
    # sinc(f dt) * sin(phase(t) - pi f dt)
    phase0 = np.ascontiguousarray(2.0 * np.pi * (np.cumsum(rotor_hz, axis=0) - 0.5 * rotor_hz) * dt_s)
    harmonic = np.array([float(h) for h, _, _ in HARMONICS])
    y, z = _sine_arguments(rotor_hz, phase0, float(dt_s), harmonic, offset)
    acc, gyr = _accumulate(rotor_hz, gain, ref_hz, y, np.sin(y), np.sin(z), acc_amp, gyr_amp, share, acc_u, acc_dir,
                           gyr_u, gyr_dir, k)  # fmt: skip
    info = {
        "model": "rotor 1x and 2x harmonics, amplitude ~ rpm^2, box-car sampled, added to acc/gyr truth",
        "acc_amp_m_s2_per_motor_harmonic": acc_amp,
        "gyr_amp_rad_s_per_motor_harmonic": gyr_amp,
        "reference_rotor_hz": ref_hz,
        "acc_rms_m_s2": float(np.sqrt(np.mean(acc**2) * 3)) if n else 0.0,
        "gyr_rms_rad_s": float(np.sqrt(np.mean(gyr**2) * 3)) if n else 0.0,
    }
    return acc, gyr, info
