"""The live estimator pushed every sample of a record, as the bridge feeds it: one home for the tests' loop."""

from __future__ import annotations

import numpy as np

from tepinn_flight.model.streaming import StreamingEstimator


def live_run(model, cfg, rec, vehicle: str | None = None, live: StreamingEstimator | None = None
             ) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """``StreamingEstimator(model, cfg, vehicle)`` pushed every sample of ``rec`` (no magnetometer; its clipping
    flags) → ((n, 4) its estimates, NaN where none; the sample index each network window ended at). ``live``: a new
    estimator made by the caller, pushed instead (to read its counters afterwards)."""
    live = StreamingEstimator(model, cfg, vehicle=vehicle) if live is None else live
    q_live = np.full((len(rec), 4), np.nan)
    ran = []
    # (the record's columns taken once: each of its properties makes a new array from the frame, ~0.3 ms a call)
    t, gyr, acc, clipped, gyr_clipped = rec.t_s, rec.gyr_rad_s, rec.acc_m_s2, rec.clipped, rec.gyr_clipped
    for i in range(len(rec)):
        e = live.push(t[i], gyr[i], acc[i], None, bool(clipped[i]), bool(gyr_clipped[i]))
        if e.model_ran:
            ran.append(i - 1)  # a window is made when the next token's first sample arrives
        if e.q_nb_wxyz is not None:
            q_live[i] = e.q_nb_wxyz
    return q_live, np.asarray(ran, np.int64)
