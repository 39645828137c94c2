"""Records that ingest flags "IMU rate too low for estimation", and records whose reference attitude fails the trust
check, are scored but kept out of the evaluation's headline; the report lists them apart and its Records table says
why (real logs)."""

from __future__ import annotations

import numpy as np
import pytest

from tests.conftest import real_log


@pytest.fixture(scope="module")
def slow_and_fast(tmp_path_factory):
    from tepinn_flight.evaluation.harness import HarnessConfig, evaluate
    from tepinn_flight.evaluation.peers import VqfEstimator
    from tepinn_flight.evaluation.suite import baseline_estimators
    from tepinn_flight.ingest import ingest_log

    slow = ingest_log(real_log("uavlv_vtol.tlog"))  # 4.2 Hz telemetry
    fast = ingest_log(real_log("ardusub_small.BIN"))  # 25 Hz onboard log
    diverged = ingest_log(real_log("aplogan_nan.log"))  # 50 Hz, its autopilot's attitude diverged
    assert slow.meta["estimation_ok"] is False and fast.meta["estimation_ok"] is True
    assert diverged.meta["estimation_ok"] is True
    ests = [VqfEstimator(), *baseline_estimators()[::2]]  # (complementary, and the EKF: it gives σ)
    res = evaluate([slow, fast, diverged], ests, HarnessConfig(warmup_s=2.0), progress=False)
    return res, ests


def test_the_headline_is_over_the_records_fast_enough(slow_and_fast):
    res, ests = slow_and_fast
    by = {r["name"]: r for r in res.records}
    slow, fast = by["uavlv_vtol"], by["ardusub_small"]
    assert slow["estimation_ok"] is False and fast["estimation_ok"] is True
    assert slow["imu_rate_hz"] == pytest.approx(4.2, abs=0.1) and fast["imu_rate_hz"] == pytest.approx(25.0, abs=0.1)
    for e in ests:
        d = res.dataset[e.name]
        assert d["n_records"] == 1
        assert d["inclination_rmse_deg"] == pytest.approx(fast["results"][e.name]["inclination_rmse_deg"], rel=1e-12)
        # and it is not the mean over them (the slow record and the diverged reference do differ)
        for other in (slow, by["aplogan_nan"]):
            both = np.mean([other["results"][e.name]["inclination_rmse_deg"], fast["results"][e.name]["inclination_rmse_deg"]])
            assert abs(both - d["inclination_rmse_deg"]) > 1e-6
    assert any("too slow" in n and "uavlv_vtol" in n for n in res.notes)
    assert by["aplogan_nan"]["reference_trusted"] is False and fast["reference_trusted"] is True
    assert any("fails the trust check" in n and "aplogan_nan" in n and "kept out" in n for n in res.notes)


def test_the_report_lists_them_apart(slow_and_fast, tmp_path):
    from tepinn_flight.evaluation.report import render_markdown, FIGURES
    from tepinn_flight.evaluation.report_html import render_html

    res, _ = slow_and_fast
    md = render_markdown(res, FIGURES)
    records = md.split("## Records\n", 1)[1].split("\n## ", 1)[0]
    assert "| record | kind | IMU rate [Hz] | reference | estimation OK |" in records
    row = next(line for line in records.splitlines() if line.startswith("| uavlv_vtol "))
    assert "| 4.2 |" in row and "| ATTITUDE |" in row and "no: IMU too slow" in row
    assert "| yes |" in next(line for line in records.splitlines() if line.startswith("| ardusub_small "))
    row = next(line for line in records.splitlines() if line.startswith("| aplogan_nan "))
    assert "yes: reference not trusted, not in the summary" in row
    apart = md.split("## Records not in the summary", 1)[1].split("\n## ", 1)[0]
    assert "| uavlv_vtol | IMU too slow |" in apart and "| aplogan_nan | reference not trusted |" in apart
    assert "ardusub_small" not in apart
    assert "## Summary (mean over the 1 record in it, 2 kept out)" in md
    page = render_html(res)
    assert "Records not in the summary" in page and "reference not trusted" in page
    assert "estimation OK" in page and "no: IMU too slow, not in the summary" in page


def test_the_uncertainty_figure_pools_the_summary_records_only(slow_and_fast):
    """The σ-vs-error figure beside the summary's σ table takes that table's records only (session 53: a record kept
    out for its untrusted reference had made σ look 20× over-confident there)."""
    from tepinn_flight.evaluation.report import pooled_sigma_samples

    res, ests = slow_and_fast
    in_sum = [r["in_summary"] for r in res.records]
    assert in_sum == [r["name"] == "ardusub_small" for r in res.records]
    with_sigma = [e.name for e in ests if any(s["est"][e.name].get("sigma") is not None for s in res.series)]
    assert with_sigma  # (an estimator of the fixture gives σ)
    for name in with_sigma:
        sig, err = pooled_sigma_samples(res, name)
        i = in_sum.index(True)
        e = res.series[i]["est"][name]
        m = res.series[i]["mask"] & np.isfinite(e["sigma"]) & np.all(np.isfinite(e["tilt_err"]), axis=1)
        np.testing.assert_array_equal(sig, e["sigma"][m])
        np.testing.assert_array_equal(err, np.sum(e["tilt_err"][m] ** 2, axis=1))


def test_a_summary_over_records_that_all_fail_says_so_even_quiet(tmp_path, capsys):
    """Where every record is kept out (a folder of telemetry tlogs), the summary is over them all: its heading says so
    and that it is no meaningful comparison, and `evaluate -q` still says it (review61: averaged without a word)."""
    from tepinn_flight.cli.main import main
    from tepinn_flight.evaluation.harness import ALL_LEFT_OUT_NOTE

    out = tmp_path / "r"
    assert main(["evaluate", str(real_log("uavlv_vtol.tlog")), "-o", str(out), "--no-model", "--no-peers", "-q"]) == 0
    said = capsys.readouterr()
    assert f"note: {ALL_LEFT_OUT_NOTE}" in said.err and "every one failing the rate or reference check" in said.out
    md = (out / "report.md").read_text()
    assert "## Summary (over the one record in it, though it fails: an IMU too slow or a reference not trusted; not a " in md
    assert "not a meaningful comparison" in (out / "report.html").read_text()
    # and quiet with a record that passes: no such note
    assert main(["evaluate", str(real_log("ardusub_small.BIN")), str(real_log("uavlv_vtol.tlog")), "-o",
                 str(tmp_path / "s"), "--no-model", "--no-peers", "-q"]) == 0  # fmt: skip
    assert ALL_LEFT_OUT_NOTE not in capsys.readouterr().err


def test_the_summary_heading_counts_what_it_is_over():
    """Every case of the heading (review62: where every record failed and one more was unscored, the heading had
    dropped the warning; with every record kept out it read "the 0 records in it")."""
    from tepinn_flight.evaluation.left_out import summary_heading

    ok = {"estimation_ok": True, "reference_trusted": True, "in_summary": True, "kept_out": ""}
    slow = {"estimation_ok": False, "reference_trusted": True, "in_summary": True, "kept_out": ""}
    unscored = {"estimation_ok": False, "reference_trusted": True, "in_summary": False, "kept_out": "no scored sample"}
    apart = {"estimation_ok": False, "reference_trusted": True, "in_summary": False, "kept_out": ""}
    assert summary_heading([ok, ok]) == "Summary (mean over the 2 records)"
    assert summary_heading([ok]) == "Summary (mean over the one record)"
    assert summary_heading([ok, apart, apart]) == "Summary (mean over the 1 record in it, 2 kept out)"
    assert summary_heading([slow, slow]).startswith("Summary (over all 2 records in it, though none passes")
    h = summary_heading([slow, unscored])
    assert h.startswith("Summary (over the one record in it, though it fails") and h.endswith("comparison, 1 kept out)")
    assert summary_heading([unscored, unscored]) == "Summary (no record in it, 2 kept out)"
