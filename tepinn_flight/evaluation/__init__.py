"""Evaluation harness: baseline filters, published peers, metrics, the BROAD protocol and reports.

- :mod:`.metrics` — pure metric functions (BROAD's error split, heading alignment, drift, dynamic
  error, bias error, uncertainty calibration, Wilcoxon signed-rank).
- :mod:`.filters` — complementary ("analytical"), Madgwick (corrected / original quirk), MEKF.
- :mod:`.peers` — VQF, offline VQF, RIANN, x-io Fusion.
- :mod:`.estimators` — the common estimator interface (TE-PINN plugs in here).
- :mod:`.harness` — same records, same masks, same warm-up for every estimator.
- :mod:`.report` — Markdown + PNG + metrics.json.
- :mod:`.broad_benchmark` — the BROAD benchmark protocol and the published-Madgwick reproduction check.
"""
