"""The live estimator pushed every sample of a record, as the bridge feeds it: one home for the tests' loop."""

from __future__ import annotations

import numpy as np

from tepinn_flight.model.streaming import StreamingEstimator


def live_run(model, cfg, rec, vehicle: str | None = None) -> tuple[np.ndarray, np.ndarray]:
    """``StreamingEstimator(model, cfg, vehicle)`` pushed every sample of ``rec`` (no magnetometer; its clipping
    flags) → ((n, 4) its estimates, NaN where none; the sample index each network window ended at)."""
    live = StreamingEstimator(model, cfg, vehicle=vehicle)
    q_live = np.full((len(rec), 4), np.nan)
    ran = []
    for i in range(len(rec)):
        e = live.push(rec.t_s[i], rec.gyr_rad_s[i], rec.acc_m_s2[i], None, bool(rec.clipped[i]), bool(rec.gyr_clipped[i]))
        if e.model_ran:
            ran.append(i - 1)  # a window is made when the next token's first sample arrives
        if e.q_nb_wxyz is not None:
            q_live[i] = e.q_nb_wxyz
    return q_live, np.asarray(ran, np.int64)
