"""The motor-vibration model (sim/vibration.py): its compiled arithmetic against the former numpy array
expressions, bit for bit, and the boxcar's sinc where a rotor stands still."""

import numpy as np
import pytest

from tepinn_flight.sim.vibration import motor_vibration

from .vibration_reference import motor_vibration as reference


@pytest.mark.parametrize("seed", range(4))
def test_the_former_array_expressions_bit_for_bit(seed):
    """Rotor speeds of 2-6 motors (some standing still, where the boxcar's sinc is 1), per-sample gains,
    rates from 50 to 1000 Hz: the same acc and gyr to the last bit, and the same draws used."""
    rng = np.random.default_rng(seed)
    n, m = int(rng.integers(1, 3000)), int(rng.integers(2, 7))
    rotor_hz = rng.uniform(0.0, 400.0, (n, m)) * (rng.random((n, m)) < 0.9)
    gain = rng.choice([1.0, 3.5, 0.0], n)
    dt = 1.0 / float(rng.choice([50.0, 400.0, 1000.0]))
    a_rng, b_rng = np.random.default_rng(100 + seed), np.random.default_rng(100 + seed)
    acc, gyr, info = motor_vibration(rotor_hz, gain, dt, a_rng)
    acc_ref, gyr_ref = reference(rotor_hz, gain, dt, b_rng)
    assert acc.tobytes() == acc_ref.tobytes() and gyr.tobytes() == gyr_ref.tobytes()
    assert a_rng.random() == b_rng.random()  # the generators left in the same state
    assert info["acc_rms_m_s2"] > 0.0


def test_a_standing_rotor_adds_nothing_and_a_lone_harmonic_is_a_sinc_weighted_sine():
    """One motor at a constant speed f: each harmonic's acc is a sine of amplitude a_k sinc(k f dt) (the
    boxcar over a sample); a motor standing still adds exactly zero."""
    n, dt, f = 4000, 1.0 / 400.0, 37.0
    rotor_hz = np.column_stack([np.full(n, f), np.zeros(n)])
    acc, gyr, _ = motor_vibration(rotor_hz, np.ones(n), dt, np.random.default_rng(3))
    spec = np.abs(np.fft.rfft(acc[:, 0])) / (n / 2)
    freqs = np.fft.rfftfreq(n, dt)
    peaks = sorted(freqs[np.argsort(spec)[-2:]])
    assert peaks == pytest.approx([f, 2 * f], abs=0.2)
    still = motor_vibration(np.zeros((n, 2)), np.ones(n), dt, np.random.default_rng(3))
    assert not still[0].any() and not still[1].any()
