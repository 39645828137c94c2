"""``AnchoredVQF.update_one`` (the live path, plain floats) gives the numbers of a one-row
``AnchoredVQF.update`` (numpy, the offline path), sample by sample, on a real BROAD trial with the
magnetometer, every gate on (pulls, centripetal correction, bias correction), saturated samples
and holes."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from tepinn_flight.model.anchor import AnchorConfig, AnchoredVQF, WindowOutput
from tests.conftest import broad_trial


@pytest.mark.parametrize("gyro_scale", [(1.0, 1.0, 1.0), (0.99, 1.0, 1.005)])
def test_update_one_equals_a_one_row_update_on_a_real_trial(gyro_scale):
    from tepinn_flight.ingest import load_record

    rec = load_record(broad_trial("broad_06_*.hdf5"))
    n = 6000
    t, gyr, acc, mag = rec.t_s[:n], rec.gyr_rad_s[:n].copy(), rec.acc_m_s2[:n].copy(), rec.mag_ut[:n].copy()
    gyr[1000] = np.nan  # a hole
    acc[2000, 1] = np.inf  # another
    mag[3000:3100] = np.nan  # no magnetometer for a while
    clipped = np.zeros(n, bool)
    clipped[1500:1510] = True
    cfg = dataclasses.replace(AnchorConfig(), speed_lo_m_s=0.0, speed_hi_m_s=1e-3, mode="9d", gyro_scale=gyro_scale)
    rng = np.random.default_rng(0)
    flt = {k: AnchoredVQF(cfg, float(np.median(np.diff(t[:52]))), use_mag=True) for k in ("batch", "one")}
    got = {k: [] for k in flt}
    for i in range(n):
        if i % 11 == 10:  # a window: the gates open, the tilt is pulled, v̂ and â enter; a constant
            # older-fusion bias of 13 °/s (an uncalibrated gyro) latches the bias gate
            w = WindowOutput(np.r_[1.0, rng.normal(0, 0.05, 3)] / np.sqrt(1 + 3 * 0.05**2), 0.05,
                             rng.normal(0, 0.05, 3), rng.normal(0, 20.0, 3), rng.normal(0, 2.0, 3),
                             np.array([0.2, -0.1, 0.05]))  # fmt: skip
            for f in flt.values():
                f.correct(w)
        q6, q9, s, b = flt["batch"].update([t[i]], [gyr[i]], [acc[i]], [mag[i]], [clipped[i]])
        got["batch"].append(np.r_[q6[0], q9[0], s[0], b[0]])
        q6, q9, s, b = flt["one"].update_one(t[i], gyr[i], acc[i], mag[i], clipped[i])
        got["one"].append(np.r_[q6, q9, s, b])
    a, b = np.array(got["batch"]), np.array(got["one"])
    assert np.all(np.isfinite(a))
    np.testing.assert_allclose(b, a, rtol=0, atol=1e-12)
    assert flt["one"].holes == flt["batch"].holes == 2
    assert flt["one"].bias_latched  # the bias gate was exercised too
    plain = AnchoredVQF(cfg.learned_off, flt["one"].ts, use_mag=True).update(t, gyr, acc, mag)
    assert np.abs(plain[0][-1] - a[-1, :4]).max() > 1e-3  # the corrections did act
