"""Which scored records the summary leaves out, and why: a record whose IMU is too slow for windowed estimation
(below 20 Hz, :func:`~tepinn_flight.record.estimation_ok`) or whose reference attitude fails the trust check
(:mod:`~tepinn_flight.model.reference_trust`) is scored like the others and listed apart, but kept out of the
summary means, the rate bins and the paired comparison (``evaluation/harness.py``; the reports say so). So is a
record with no scored sample, or one where not every estimator has an estimate (each mean over the same records):
:func:`kept_out` gives the reason the harness recorded."""

from __future__ import annotations

#: what the reports say of the records kept out of the summary
LEFT_OUT_NOTE = ("Scored for reference only and kept out of the summary means, the rate bins and the paired comparison: "
                 "an IMU too slow for windowed estimation (ingest flags it below 20 Hz, typical of telemetry links), or "
                 "a reference attitude that fails the trust check (it turns unlike the gyro or points away from the "
                 "accelerometer's gravity: an autopilot estimator that diverged), where every estimator's error "
                 "measures the reference's failure; also a record with no scored sample (shorter than the warm-up, or "
                 "no reference after it) or one where not every estimator has an estimate (so that each mean is over "
                 "the same records).")  # fmt: skip


def left_out(r: dict) -> str:
    """Why a scored record (an entry of ``EvalResult.records``) is kept out of the summary — "IMU too slow" or
    "reference not trusted" — or "" where it is in it (results written before the trust check counted are in)."""
    if not r.get("estimation_ok", True):
        return "IMU too slow"
    if not r.get("reference_trusted", True):
        return "reference not trusted"
    return ""


def kept_out(r: dict) -> str:
    """Why a scored record is not in the summary means — :func:`left_out`'s reasons, "no scored sample" or "not every
    estimator has an estimate" — or "" where it is in them (``in_summary``; where every record is left out the
    summary is over them all). Results written before the harness recorded it: :func:`left_out`."""
    if "in_summary" not in r:
        return left_out(r)
    return "" if r["in_summary"] else (r.get("kept_out") or left_out(r) or "not in the summary")


def summary_heading(records: list[dict]) -> str:
    """The summary's heading (report.md and report.html), saying how many records its means are over and how many
    are kept out; where every record in it fails :func:`left_out`'s checks (the harness then averages over them all
    rather than show no summary), that it is no meaningful comparison."""
    inside = [r for r in records if not kept_out(r)]
    m, kept = len(inside), len(records) - len(inside)
    apart = f", {kept} kept out" if kept else ""
    if not inside:
        return f"Summary (no record in it{apart})"
    if all(left_out(r) for r in inside):
        over = f"all {m} records in it, though none passes" if m != 1 else "the one record in it, though it fails"
        return f"Summary (over {over}: an IMU too slow or a reference not trusted; not a meaningful comparison{apart})"
    if kept:
        return f"Summary (mean over the {m} record{'s' if m != 1 else ''} in it{apart})"
    return f"Summary (mean over {f'the {m} records' if m != 1 else 'the one record'})"
