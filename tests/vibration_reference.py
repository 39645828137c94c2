"""The motor-vibration model as numpy array expressions, as it was before its arithmetic was compiled
(session 48): ``tests/test_sim_vibration.py`` holds :func:`tepinn_flight.sim.vibration.motor_vibration`
to it, bit for bit."""

import numpy as np


def _unit(rng: np.random.Generator, z_weight: float) -> np.ndarray:
    v = rng.normal(size=3)
    v[2] *= z_weight
    return v / np.linalg.norm(v)


def motor_vibration(rotor_hz: np.ndarray, gain: np.ndarray, dt_s: float,
                    rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, dict]:
    """(acc (N, 3) m/s^2, gyr (N, 3) rad/s, description) for rotor speeds ``rotor_hz`` (N, M)."""
    rotor_hz = np.asarray(rotor_hz, dtype=float)
    n, m = rotor_hz.shape
    ref_hz = max(float(np.median(rotor_hz)), 1.0)  # amplitudes are given at the typical rotor speed
    acc_amp = float(rng.uniform(0.3, 1.5))  # m/s^2 per motor and harmonic at ref speed
    gyr_amp = float(rng.uniform(0.004, 0.02))  # rad/s
    acc = np.zeros((n, 3))
    gyr = np.zeros((n, 3))
    # phase = 2*pi*integral(f dt); the box-car average of sin over [t - dt, t] is
    # sinc(f dt) * sin(phase(t) - pi f dt)
    phase0 = 2.0 * np.pi * (np.cumsum(rotor_hz, axis=0) - 0.5 * rotor_hz) * dt_s
    for i in range(m):
        for harmonic, z_weight, share in ((1, 0.3, 1.0), (2, 2.0, 0.6)):
            f = harmonic * rotor_hz[:, i]
            ph = harmonic * phase0[:, i] + rng.uniform(0.0, 2.0 * np.pi)
            scale = gain * (rotor_hz[:, i] / ref_hz) ** 2 * np.sinc(f * dt_s)
            s = scale * np.sin(ph - np.pi * f * dt_s)
            acc += np.outer(s * acc_amp * share * rng.uniform(0.5, 1.0), _unit(rng, z_weight))
            gyr += np.outer(s * gyr_amp * share * rng.uniform(0.5, 1.0), _unit(rng, 1.0))
    return acc, gyr
