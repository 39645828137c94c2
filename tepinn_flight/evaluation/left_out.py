"""Which scored records the summary leaves out, and why: a record whose IMU is too slow for windowed estimation
(below 20 Hz, :func:`~tepinn_flight.record.estimation_ok`) or whose reference attitude fails the trust check
(:mod:`~tepinn_flight.model.reference_trust`) is scored like the others and listed apart, but kept out of the
summary means, the rate bins and the paired comparison (``evaluation/harness.py``; the reports say so)."""

from __future__ import annotations

#: what the reports say of the records kept out of the summary
LEFT_OUT_NOTE = ("Scored for reference only and kept out of the summary means, the rate bins and the paired comparison: "
                 "an IMU too slow for windowed estimation (ingest flags it below 20 Hz, typical of telemetry links), or "
                 "a reference attitude that fails the trust check (it turns unlike the gyro or points away from the "
                 "accelerometer's gravity: an autopilot estimator that diverged), where every estimator's error "
                 "measures the reference's failure.")  # fmt: skip


def left_out(r: dict) -> str:
    """Why a scored record (an entry of ``EvalResult.records``) is kept out of the summary — "IMU too slow" or
    "reference not trusted" — or "" where it is in it (results written before the trust check counted are in)."""
    if not r.get("estimation_ok", True):
        return "IMU too slow"
    if not r.get("reference_trusted", True):
        return "reference not trusted"
    return ""
