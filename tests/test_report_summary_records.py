"""Which records the summary is over, said the same everywhere (review59): a record with no scored sample is said
to be one (it had been called one "where not every estimator has an estimate"); the per-record figure's bar is the
summary's mean; the tables tag only records the summary leaves out; a 9-D heading is averaged over the records with a
magnetometer; a record's name cannot split a Markdown row; the HTML's wraps break after its decimation; each
estimator's start-up is not timed as a record's cost; `-q` still says which inputs were left out."""

from __future__ import annotations

import copy

import numpy as np
import pytest

from tepinn_flight.evaluation.harness import WARM_ROWS, HarnessConfig, evaluate
from tepinn_flight.evaluation.report import FIGURES, fig_per_record, md_cell, render_markdown
from tepinn_flight.evaluation.plotdata import colour_map
from tepinn_flight.evaluation.suite import baseline_estimators
from tepinn_flight.model.synthetic import synthetic_record
from tepinn_flight.record import MAG_COLS


def _rec(seed, duration_s, name):
    r = synthetic_record(seed=seed, duration_s=duration_s, rate_hz=100.0)
    r.meta["name"] = name
    return r


class _NoEstimateOn:
    """A filter estimator that returns no attitude on the record called ``name`` (NaN rows)."""

    def __init__(self, inner, name):
        self.inner, self.skip = inner, name
        self.name, self.kind, self.causal, self.uses_mag = "blind", inner.kind, True, False

    def estimate(self, rec):
        df = self.inner.estimate(rec)
        if rec.meta.get("name") == self.skip:
            df[[c for c in df.columns if c.startswith("q_est")]] = np.nan
        return df


@pytest.fixture(scope="module")
def two_ok_one_short():
    recs = [_rec(1, 12.0, "a"), _rec(2, 12.0, "b"), _rec(3, 1.5, "short")]  # short: under the 2-s warm-up
    return evaluate(recs, baseline_estimators(), HarnessConfig(warmup_s=2.0), progress=False)


def test_a_record_with_no_scored_sample_is_said_to_be_one(two_ok_one_short):
    res = two_ok_one_short
    by = {r["name"]: r for r in res.records}
    assert not by["short"]["in_summary"] and by["short"]["kept_out"] == "no scored sample"
    assert by["a"]["in_summary"] and by["a"]["kept_out"] == ""
    assert any("no scored sample" in n and "short" in n for n in res.notes)
    assert not any("not every estimator has an estimate" in n for n in res.notes)
    md = render_markdown(res, {k: f"{k}.png" for k in FIGURES})
    assert "## Summary (mean over the 2 records in it, 1 kept out)" in md
    assert "| short (no scored sample, not in the summary) |" in md
    assert "| a |" in md  # (in the summary: no tag)


def _bars(res):
    fig = fig_per_record(res, colour_map(list(res.dataset)), None)
    lines = [c for c in fig.axes[0].collections if c.__class__.__name__ == "LineCollection"]
    return {n: lc.get_segments()[0][0][1] for n, lc in zip(res.dataset, lines)}


def test_the_per_record_bar_is_the_summary_mean_where_one_estimator_has_no_estimate():
    recs = [_rec(1, 12.0, "a"), _rec(2, 12.0, "b"), _rec(4, 12.0, "c")]
    base = baseline_estimators()
    ests = base[:2] + [_NoEstimateOn(base[2], "c")]
    res = evaluate(recs, ests, HarnessConfig(warmup_s=2.0), progress=False)
    c = next(r for r in res.records if r["name"] == "c")
    assert not c["in_summary"] and c["kept_out"] == "not every estimator has an estimate"
    for name, y in _bars(res).items():  # (the bar had averaged record c in for the others)
        assert y == pytest.approx(res.dataset[name]["inclination_rmse_deg"], rel=1e-9), name
    from tepinn_flight.evaluation.plotdata import showcase_records

    captions = {s["name"]: cap for s, cap in showcase_records(res)}  # the time series' captions say it too
    assert "not every estimator has an estimate, not in the summary" in captions["c"]
    assert "not in the summary" not in captions["a"]


def test_where_every_record_is_left_out_the_tables_do_not_say_not_in_the_summary():
    recs = [_rec(1, 12.0, "a"), _rec(2, 12.0, "b")]
    for r in recs:
        r.meta["estimation_ok"] = False  # an IMU too slow: every record left out, the summary over them all
    res = evaluate(recs, baseline_estimators(), HarnessConfig(warmup_s=2.0), progress=False)
    assert all(r["in_summary"] for r in res.records)
    md = render_markdown(res, {k: f"{k}.png" for k in FIGURES})
    assert "not in the summary" not in md.split("## Notes")[0] + md.split("## Records")[1]
    assert "| a | " in md and "no: IMU too slow |" in md


def _with_mag(rec):
    from scipy.spatial.transform import Rotation

    q = rec.q_ref_wxyz
    m_ned = np.array([20.0, 1.0, 45.0])
    r = copy.copy(rec)
    r.data = rec.data.copy()
    r.data[MAG_COLS] = Rotation.from_quat(q[:, [1, 2, 3, 0]]).inv().apply(m_ned)
    return r


def test_a_nine_d_heading_is_averaged_over_the_records_with_a_magnetometer():
    recs = [_with_mag(_rec(1, 12.0, "a")), _rec(2, 12.0, "nomag")]
    ests = [e for e in baseline_estimators(with_mag=True) if e.uses_mag]
    res = evaluate(recs, ests, HarnessConfig(warmup_s=2.0), progress=False)
    assert any("no magnetometer" in n for n in res.notes)
    for e in ests:
        per = {r["name"]: r["results"][e.name]["heading_rmse_deg"] for r in res.records}
        assert abs(per["nomag"] - per["a"]) > 0.1  # (so a mean over both would differ)
        assert res.dataset[e.name]["heading_rmse_deg"] == pytest.approx(per["a"])
        assert res.dataset[e.name]["inclination_rmse_deg"] == pytest.approx(
            np.mean([r["results"][e.name]["inclination_rmse_deg"] for r in res.records]))  # (tilt: over both)


def test_a_record_name_cannot_split_a_markdown_row():
    assert md_cell("pipe|name") == "pipe\\|name" and md_cell("tag<i>x&y") == "tag&lt;i&gt;x&amp;y"
    recs = [_rec(1, 12.0, "pipe|name"), _rec(2, 12.0, "b")]
    res = evaluate(recs, baseline_estimators(), HarnessConfig(warmup_s=2.0), progress=False)
    lines = render_markdown(res, {k: f"{k}.png" for k in FIGURES}).splitlines()
    cells = lambda ln: len(ln.replace("\\|", "").strip("|").split("|"))  # noqa: E731 - GFM: \| is no separator
    rows = [i for i, ln in enumerate(lines) if ln.startswith("| pipe")]
    assert len(rows) >= 2  # the Records and the Per-record tables
    for i in rows:
        head = next(lines[j - 1] for j in range(i, 0, -1) if lines[j].startswith("|---"))
        assert cells(lines[i]) == cells(head), (lines[i], head)


def test_the_html_breaks_its_wraps_after_decimating():
    from tepinn_flight.evaluation.report_html import _trace_xy

    t = np.arange(0, 600, 0.01)
    yaw = (np.degrees(np.radians(900.0) * t) + 180.0) % 360.0 - 180.0  # 10 min spinning at 900 °/s
    x, y = _trace_xy(t, yaw, True, 4000)
    y = np.array([np.nan if v is None else v for v in y])
    jumps = np.abs(np.diff(y))
    assert np.nansum(jumps > 180.0) == 0  # (1271 segments drew across ±180° before)
    assert len(x) <= 4000 + 1500 and np.isnan(y).sum() > 100


def test_each_estimator_is_warmed_before_it_is_timed():
    calls = []

    class Counting:
        name, kind, causal, uses_mag = "counting", "filter", True, False

        def __init__(self, inner):
            self.inner = inner

        def estimate(self, rec):
            calls.append(len(rec))
            return self.inner.estimate(rec)

    recs = [_rec(1, 60.0, "a"), _rec(2, 12.0, "b")]
    evaluate(recs, [Counting(baseline_estimators()[0])], HarnessConfig(warmup_s=2.0), progress=False)
    assert calls == [WARM_ROWS, 6000, 1200]  # the first, untimed, on the first record's first rows


def test_quiet_evaluate_still_says_which_inputs_were_left_out(tmp_path, capsys):
    from tepinn_flight.cli.main import main
    from tepinn_flight.record import write_record

    d = tmp_path / "logs"
    d.mkdir()
    write_record(_rec(1, 12.0, "a"), d / "a.parquet")
    (d / "bad.BIN").write_bytes(b"\x00" * 64)
    code = main(["evaluate", str(d), "-o", str(tmp_path / "rep"), "--no-model", "--no-peers", "--warmup-s", "2", "-q"])
    err = capsys.readouterr().err
    assert code == 0 and "bad.BIN: left out" in err


def test_where_the_summarys_records_have_no_scored_sample_they_are_listed_apart_too(tmp_path, capsys):
    """A record too short for the warm-up beside one with an IMU too slow (scored, listed apart): the short record is
    listed apart as one with no scored sample — it had been the whole summary, a table of dashes, and the command's
    line had ended at its colon (review60)."""
    from tepinn_flight.cli.main import main
    from tepinn_flight.record import write_record

    slow = synthetic_record(seed=1, duration_s=12.0, rate_hz=10.0)  # under 20 Hz: scored by the filters, listed apart
    short = _rec(2, 1.5, "short")
    res = evaluate([slow, short], baseline_estimators(), HarnessConfig(warmup_s=2.0), progress=False)
    by = {r["name"]: r for r in res.records}
    assert by["short"]["kept_out"] == "no scored sample" and not any(r["in_summary"] for r in res.records)
    assert all(d["inclination_rmse_deg"] is None for d in res.dataset.values())
    d = tmp_path / "recs"
    d.mkdir()
    write_record(slow, d / "slow.parquet")
    write_record(short, d / "short.parquet")
    assert main(["evaluate", str(d), "-o", str(tmp_path / "rep"), "--no-model", "--no-peers", "--warmup-s", "2", "-q"]) == 0
    line = capsys.readouterr().out.splitlines()[0]
    assert "mean over the 0 records in the summary; 2 listed apart: " in line and "no scored sample (1)" in line, line
    assert line.endswith("none: no record in the summary (each record's figures are in the report)"), line
