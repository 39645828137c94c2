"""``tepinn-flight evaluate``: the report renders with every figure, metrics.json, TE-PINN plugged in."""

from __future__ import annotations

import json
import re
import sys

import numpy as np
import pytest

from tepinn_flight.cli.main import main
from tepinn_flight.evaluation.names import display_name
from tepinn_flight.evaluation.report import FIGURES, colour_map


@pytest.fixture(scope="module")
def records_dir(tmp_path_factory):
    from tepinn_flight.model.synthetic import synthetic_record
    from tepinn_flight.record import write_record

    d = tmp_path_factory.mktemp("records")
    for seed in (1, 2, 3):
        rec = synthetic_record(seed=seed, duration_s=12.0, rate_hz=100.0)
        rec.meta["name"] = f"syn{seed}"
        write_record(rec, d / f"syn{seed}.parquet")
    return d


@pytest.fixture(scope="module")
def tiny_checkpoint(tmp_path_factory):
    torch = pytest.importorskip("torch")
    from tepinn_flight.model.checkpoint import save_checkpoint
    from tepinn_flight.model.config import ModelConfig
    from tepinn_flight.model.fusion import FusionConfig
    from tepinn_flight.model.network import TEPINN

    torch.manual_seed(0)
    model = TEPINN(ModelConfig(window_tokens=24, d_model=16, n_heads=2, n_layers=1, d_ff=32)).eval()
    path = tmp_path_factory.mktemp("ckpt") / "tiny.pt"
    save_checkpoint(path, model, FusionConfig())
    return path


def _is_png(path) -> bool:
    import matplotlib.image as mpimg

    with open(path, "rb") as f:
        if f.read(8) != b"\x89PNG\r\n\x1a\n":
            return False
    img = mpimg.imread(path)
    return img.ndim == 3 and img.shape[0] > 100 and img.shape[1] > 100 and float(np.std(img)) > 0.01


@pytest.mark.slow
def test_report_renders_with_all_figures(records_dir, tiny_checkpoint, tmp_path, monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, "riann", None)  # pretend a peer's package is missing: graceful fallback
    out = tmp_path / "report"
    code = main(["evaluate", str(records_dir), "--report", str(out), "--model", str(tiny_checkpoint),
                 "--noise-sweep", "--noise-levels", "0,4", "--warmup-s", "3", "-q"])  # fmt: skip
    assert code == 0, capsys.readouterr().err
    md = (out / "report.md").read_text()
    for key, name in FIGURES.items():
        assert _is_png(out / name), key
        assert f"]({name})" in md, key
    assert "RIANN skipped: package 'riann' is not installed" in md
    page = (out / "report.html").read_text()
    assert "](report.html)" in md and "Plotly.newPlot" in page and '"name":"TE-PINN"' in page
    data = json.loads((out / "metrics.json").read_text())
    names = {e["name"]: e for e in data["estimators"]}
    assert names["tepinn"]["kind"] == "learned" and {"complementary", "madgwick", "ekf", "vqf"} <= set(names)
    assert "riann" not in names
    # metrics.json agrees with the per-record values it summarises
    incl = [r["results"]["ekf"]["inclination_rmse_deg"] for r in data["records"]]
    assert data["dataset"]["ekf"]["inclination_rmse_deg"] == pytest.approx(np.mean(incl))
    assert len(data["records"]) == 3
    # simulated records carry the true bias: the EKF's bias error is scored, and its σ calibration
    assert data["dataset"]["ekf"]["gyr_bias_rms_deg_s"] is not None
    assert "nees" in data["dataset"]["ekf"]["uncertainty"]
    cmp_ = data["comparisons"][0]
    assert cmp_["a"] == "tepinn" and cmp_["n"] == 3 and 0 < cmp_["pvalue_two_sided"] <= 1
    # noise sweep: level 0 adds nothing, so it repeats the main evaluation exactly
    assert data["noise_sweep"]["levels"] == [0.0, 4.0]
    for n in names:
        assert data["noise_sweep"]["inclination_rmse_deg"][n][0] == pytest.approx(data["dataset"][n]["inclination_rmse_deg"])
    # the summary table lists every estimator once, by the name people write, never by its bare id
    table = md.split("## Summary")[1].split("##")[0]
    for n in names:
        assert len(re.findall(rf"^\| {re.escape(display_name(n))} \|", table, flags=re.M)) == 1
    row_labels = {m.group(1) for m in re.finditer(r"^\| ([^|]+?) \|", md, flags=re.M)}
    assert {"TE-PINN", "VQF", "offline VQF", "EKF", "Madgwick"} <= row_labels
    assert not {"tepinn", "vqf", "offline-vqf", "ekf", "madgwick"} & row_labels
    assert "| A | B (best other) |" in md and re.search(r"^\| TE-PINN \| \S", md.split("## Paired")[1], flags=re.M)


@pytest.mark.parametrize("name, shown", [
    ("tepinn", "TE-PINN"), ("lstm", "LSTM"), ("vqf", "VQF"), ("vqf-9d", "VQF 9-D"), ("offline-vqf", "offline VQF"),
    ("offline-vqf-9d", "offline VQF 9-D"), ("ekf", "EKF"), ("ekf-9d", "EKF 9-D"), ("madgwick", "Madgwick"),
    ("riann", "RIANN"), ("fusion", "Fusion"), ("fusion-9d", "Fusion 9-D"), ("complementary", "complementary"),
    ("complementary-9d", "complementary 9-D"), ("madgwick-original-9d-beta0.12", "Madgwick (original) 9-D, β = 0.12"),
    ("tepinn-nophysics", "TE-PINN without physics"), ("tepinn-noadaptive", "TE-PINN without adaptive weighting"),
    ("tepinn-run2", "TE-PINN (run2)"), ("tepinn-stride6", "TE-PINN, busy stride 6"), ("no-physics", "no physics"),
    ("something-else", "something-else"), ("tepinn-live", "TE-PINN, live (the bridge's)"),
    ("tepinn-run3-live", "TE-PINN (run3), live (the bridge's)"), ("tepinn-nosmooth", "TE-PINN, not smoothed"),
    ("tepinn-smooth", "TE-PINN, smoothed offline"), ("else-live", "else-live"),
])  # fmt: skip
def test_display_names(name, shown):
    assert display_name(name) == shown


def test_broad_table_uses_display_names():
    from tepinn_flight.evaluation.broad_benchmark import format_broad

    row = {"mode": "6-D", "causal": True, "kind": "peer", "total_rmse_deg": 2.0, "heading_rmse_deg": 1.5,
           "inclination_rmse_deg": 1.0, "us_per_sample": 3.0}  # fmt: skip
    text = format_broad({"check": {"reason": "none"}, "trials": ["t1"], "folder": "x", "trusted": True, "notes": [],
                         "summary": {"offline-vqf": row, "tepinn": dict(row, kind="learned")}})  # fmt: skip
    lines = text.splitlines()
    assert any(ln.startswith("offline VQF ") for ln in lines) and any(ln.startswith("TE-PINN ") for ln in lines)
    assert not any(ln.startswith(("offline-vqf ", "tepinn ")) for ln in lines)


def test_paper_colours():
    c = colour_map(["tepinn", "complementary", "lstm", "vqf", "ekf", "complementary-9d"])
    assert (c["tepinn"], c["complementary"], c["lstm"]) == ("green", "red", "blue")
    assert len({c["vqf"], c["ekf"], "green", "red", "blue", "black"}) == 6


def test_evaluate_bad_input_one_line(tmp_path, capsys):
    bad = tmp_path / "x.parquet"
    bad.write_bytes(b"PAR1 not really")
    code = main(["evaluate", str(bad), "--report", str(tmp_path / "r"), "-q", "--no-model"])
    err = capsys.readouterr().err
    assert code == 2 and len(err.strip().splitlines()) == 1 and "x.parquet" in err
    assert not (tmp_path / "r" / "report.md").exists()


def test_tuning_refuses_test_records(records_dir, tmp_path, capsys):
    rec = str(records_dir / "syn1.parquet")
    code = main(["evaluate", rec, "--report", str(tmp_path / "r"), "--tune-ekf-on", rec, "-q", "--no-model"])
    assert code == 2 and "never tune on test data" in capsys.readouterr().err
    import shutil  # a copy of the evaluated record under another name is the same test data (it got through)

    shutil.copy(rec, tmp_path / "copy.parquet")
    code = main(["evaluate", rec, "--report", str(tmp_path / "r"), "--tune-ekf-on", str(tmp_path / "copy.parquet"),
                 "-q", "--no-model"])  # fmt: skip
    assert code == 2 and "never tune on test data" in capsys.readouterr().err
    assert not (tmp_path / "r").exists()


@pytest.mark.parametrize("flag", ["-o", "--output", "--report"])
def test_evaluate_output_option_and_alias(flag):
    from tepinn_flight.cli.main import build_parser

    args = build_parser().parse_args(["evaluate", "rec.parquet", flag, "outdir"])
    assert args.output == "outdir"


def test_evaluate_writes_into_o_dir(records_dir, tmp_path, capsys):
    out = tmp_path / "o"
    code = main(["evaluate", str(records_dir / "syn1.parquet"), "-o", str(out), "-q", "--no-model", "--no-peers",
                 "--warmup-s", "2"])  # fmt: skip
    assert code == 0, capsys.readouterr().err
    assert (out / "report.md").exists() and (out / "metrics.json").exists()


# ----------------------------------------------------------------------------- interactive report, figure data


def _minmax_reference(y, max_points):
    """Slow and obvious: per bucket, the first smallest and first largest finite value and the first NaN."""
    n = len(y)
    if n <= max_points:
        return list(range(n))
    nb = max_points // 3
    keep = set()
    for b in range(nb):
        lo, hi = n * b // nb, n * (b + 1) // nb
        finite = [i for i in range(lo, hi) if not np.isnan(y[i])]
        nans = [i for i in range(lo, hi) if np.isnan(y[i])]
        if finite:
            keep.add(min(finite, key=lambda i: (y[i], i)))
            keep.add(min(finite, key=lambda i: (-y[i], i)))
        if nans:
            keep.add(nans[0])
    return sorted(keep)


@pytest.mark.parametrize("n, max_points, seed", [(10, 30, 0), (1000, 30, 1), (1001, 31, 2), (5000, 400, 3), (4001, 4000, 4),
                                                  (777, 9, 5), (20000, 4000, 6)])  # fmt: skip
def test_minmax_indices_against_reference(n, max_points, seed):
    from tepinn_flight.evaluation.plotdata import minmax_indices

    rng = np.random.default_rng(seed)
    y = np.cumsum(rng.normal(size=n))
    y[rng.integers(0, n, size=n // 50)] = 5e3  # spikes that must survive
    y[rng.integers(0, n, size=n // 40)] = np.nan  # scattered gaps
    if n > 200:
        y[n // 3 : n // 3 + n // 10] = np.nan  # a long gap: whole NaN buckets
    y[rng.integers(0, n, size=n // 30)] = 0.0  # ties
    got = minmax_indices(y, max_points)
    assert got.tolist() == _minmax_reference(y, max_points)
    assert len(got) <= max(n if n <= max_points else 0, max_points)
    assert np.nanmax(y[got]) == np.nanmax(y) and np.nanmin(y[got]) == np.nanmin(y)


def test_break_wraps():
    from tepinn_flight.evaluation.plotdata import break_wraps

    t = np.arange(6.0)
    y = np.array([170.0, 178.0, -178.0, -170.0, -179.0, 179.0])
    t2, y2 = break_wraps(t, y)
    assert len(y2) == 8 and np.isnan(y2[2]) and np.isnan(y2[6]) and t2[2] == 1.5 and t2[6] == 4.5
    seg = np.split(y2, np.flatnonzero(np.isnan(y2)))
    assert all(np.all(np.abs(np.diff(s[np.isfinite(s)])) < 180) for s in seg)


def test_fixed_colours_per_method():
    import matplotlib.colors as mc

    a = colour_map(["tepinn", "madgwick", "ekf", "vqf", "offline-vqf", "riann", "fusion", "complementary"])
    b = colour_map(["offline-vqf", "ekf"])  # the same colour whatever else was evaluated
    assert a["ekf"] == b["ekf"] and a["offline-vqf"] == b["offline-vqf"]
    rgb = {k: np.array(mc.to_rgb(v)) for k, v in a.items()}
    keys = list(rgb)
    for i, k in enumerate(keys):
        for j in keys[i + 1 :]:
            assert np.abs(rgb[k] - rgb[j]).sum() > 0.35, (k, j)
    two = colour_map(["tepinn", "tepinn-run2", "ekf", "ekf-9d"])
    assert two["tepinn"] == "green" and two["tepinn-run2"] != "green" and two["ekf-9d"] == two["ekf"]


@pytest.fixture(scope="module")
def baseline_result(records_dir):
    from tepinn_flight.evaluation.harness import HarnessConfig, evaluate
    from tepinn_flight.evaluation.suite import baseline_estimators, peer_estimators
    from tepinn_flight.record import read_record

    recs = [read_record(p) for p in sorted(records_dir.glob("*.parquet"))]
    ests = baseline_estimators() + [e for e in peer_estimators(notes=[]) if e.name in ("vqf", "offline-vqf")]
    return evaluate(recs, ests, HarnessConfig(warmup_s=2.0), progress=False)


def _plotly_figures(text):
    """The (data, layout) of every Plotly.newPlot call in an HTML page."""
    dec = json.JSONDecoder()
    out = []
    for m in re.finditer(r'Plotly\.newPlot\(\s*"[^"]+",\s*', text):
        data, end = dec.raw_decode(text, m.end())
        layout, _ = dec.raw_decode(text, end + text[end:].index("{"))
        out.append((data, layout))
    return out


def test_html_report_holds_every_record_trace_and_peak(baseline_result):
    from tepinn_flight.evaluation.report_html import render_html
    from tepinn_flight.quat import quat_to_euler_zyx

    text = render_html(baseline_result, max_points=300)
    assert '<script src="http' not in text and "plotly.js" in text.lower()  # plotly.js embedded: works offline
    figs = _plotly_figures(text)
    assert len(figs) == len(baseline_result.series) == 3
    want = {"reference"} | {display_name(n) for n in baseline_result.dataset}
    assert {"EKF", "offline VQF", "VQF", "Madgwick", "complementary"} <= want
    for (data, _), s in zip(figs, baseline_result.series):
        assert {tr["name"] for tr in data} == want
        assert all(len(tr["x"]) == len(tr["y"]) <= 300 + 3 for tr in data)  # decimated (wrap breaks add a few)
        assert len(s["t_s"]) > 300
        ref = [tr for tr in data if tr["name"] == "reference"]
        assert len(ref) == 3  # roll, pitch, heading
        pitch = np.degrees(quat_to_euler_zyx(s["q_ref"])[1])
        ys = np.array([np.nan if v is None else v for v in ref[1]["y"]])
        assert np.nanmax(ys) == pytest.approx(pitch.max(), abs=1e-3) and np.nanmin(ys) == pytest.approx(pitch.min(), abs=1e-3)
        # the inclination error of every estimator is there (4th panel)
        assert sum(tr["yaxis"] == "y4" for tr in data) == len(baseline_result.dataset)
    for r in baseline_result.records:
        assert f"<td>{r['name']}</td>" in text
    assert "<td>samples</td>" in text


def _browser():
    import shutil

    for exe in ("chromium", "chromium-browser", "google-chrome", "chrome"):
        if shutil.which(exe):
            return shutil.which(exe)
    pytest.skip("no headless browser installed (chromium / google-chrome not on PATH); "
                "`apt-get install chromium` to run the browser test of report.html")  # fmt: skip


def test_html_report_renders_in_a_browser(baseline_result, tmp_path):
    import subprocess

    from tepinn_flight.evaluation.report_html import write_html

    exe = _browser()
    page = write_html(baseline_result, tmp_path / "report.html", max_points=1000)
    cmd = [exe, "--headless", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage", "--virtual-time-budget=20000",
           f"--user-data-dir={tmp_path / 'profile'}", "--dump-dom", page.resolve().as_uri()]  # fmt: skip
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=180)
    dom = proc.stdout
    assert proc.returncode == 0 and dom, proc.stderr[-2000:]
    # plotly drew every figure: its SVG layers and the legend with the names people write
    assert dom.count('class="main-svg"') >= len(baseline_result.series)
    for i in range(len(baseline_result.series)):
        assert f'id="fig{i}"' in dom
    legend = set(re.findall(r'class="legendtext"[^>]*>([^<]+)<', dom))
    assert {"reference", "EKF", "offline VQF", "VQF"} <= legend
    assert dom.count('class="scatterlayer') >= len(baseline_result.series)
    assert len(re.findall(r'class="js-line" d="M', dom)) > 10  # the curves themselves were drawn


# ----------------------------------------------------------------------------- PNG figures


def _fake_result(rmse):
    """A minimal EvalResult-like object: records with TE-PINN and VQF inclination RMSEs."""
    from types import SimpleNamespace

    series = [{"name": n, "t_s": np.arange(5.0), "mask": np.ones(5, bool), "q_ref": np.tile([1.0, 0, 0, 0], (5, 1)), "est": {}}
              for n in rmse]  # fmt: skip
    records = [{"name": n, "results": {"tepinn": {"inclination_rmse_deg": a}, "vqf": {"inclination_rmse_deg": b}}}
               for n, (a, b) in rmse.items()]  # fmt: skip
    ds = {k: {"inclination_rmse_deg": float(np.mean([v[i] for v in rmse.values()]))} for i, k in enumerate(("tepinn", "vqf"))}
    est = [{"name": "tepinn", "kind": "learned"}, {"name": "vqf", "kind": "peer"}]
    return SimpleNamespace(series=series, records=records, dataset=ds, estimators=est)


def test_time_series_show_best_and_worst_record_relative_to_vqf():
    from tepinn_flight.evaluation.plotdata import showcase_records

    # alphabetically first "a" and the smallest absolute error "b" are neither best nor worst relative to VQF
    res = _fake_result({"a": (2.0, 2.0), "b": (0.5, 0.4), "c": (3.0, 6.0), "d": (4.0, 2.0), "e": (1.0, 1.0)})
    shown = showcase_records(res)
    assert [s["name"] for s, _ in shown] == ["c", "d"]
    assert "best" in shown[0][1] and "0.50× VQF" in shown[0][1] and "worst" in shown[1][1] and "2.00× VQF" in shown[1][1]
    few = showcase_records(_fake_result({"a": (2.0, 2.0), "b": (0.5, 0.4)}))
    assert [s["name"] for s, _ in few] == ["a", "b"]  # few records: every one


def test_euler_figure_every_record_and_no_wrap_jumps(baseline_result):
    from tepinn_flight.evaluation.report import fig_euler

    fig = fig_euler(baseline_result, colour_map(list(baseline_result.dataset)))
    axes = np.array(fig.axes).reshape(3, -1)
    assert axes.shape[1] == 3  # 3 records: one column each
    assert {ax.get_title().split("\n")[0] for ax in axes[0]} == {s["name"] for s in baseline_result.series}
    breaks = 0
    for ax in list(axes[0]) + list(axes[2]):  # roll, yaw
        for line in ax.get_lines():
            y = np.asarray(line.get_ydata(), np.float64)
            breaks += int(np.isnan(y).sum())
            fin = np.isfinite(y[1:]) & np.isfinite(y[:-1])
            assert np.all(np.abs(np.diff(y))[fin] < 180), line.get_label()
    assert breaks > 0  # these flights do wrap: the lines are broken there
    import matplotlib.pyplot as plt

    plt.close(fig)


def test_per_record_dots_labelled_and_rate_bins_counted(baseline_result):
    import matplotlib.pyplot as plt

    from tepinn_flight.evaluation.report import fig_error_vs_rate, fig_per_record

    colours = colour_map(list(baseline_result.dataset))
    fig = fig_per_record(baseline_result, colours)
    texts = [t.get_text() for t in fig.axes[0].texts]
    for r in baseline_result.records:
        assert texts.count(r["name"]) == len(baseline_result.dataset)
    plt.close(fig)
    fig = fig_error_vs_rate(baseline_result, colours)
    ticks = [t.get_text() for t in fig.axes[0].get_xticklabels()]
    counts = baseline_result.dataset["ekf"]["dynamic_error_n"]
    assert sum(counts) > 0 and ticks and all(f"n = {n}" in tk for tk, n in zip(ticks, counts))
    plt.close(fig)


def test_a_report_stopped_half_way_leaves_no_report_md_and_no_earlier_figure_stays(baseline_result, tmp_path, monkeypatch):
    """``report.md`` marks a complete report. Writing into a folder that holds an earlier one took its figures apart
    one by one and left its ``report.md`` (describing other records) until the end: a run stopped half way left the
    old Markdown beside new figures, and an earlier ``--noise-sweep`` figure stayed for good."""
    import tepinn_flight.evaluation.report as rep

    out = tmp_path / "rep"
    out.mkdir()  # an earlier report (its files as a finished run leaves them; written here, not rendered: seconds)
    (out / "report.md").write_text("# an earlier report, of other records\n")
    (out / "metrics.json").write_text("{}")
    (out / rep.FIGURES["euler"]).write_bytes(b"an earlier run's figure")
    (out / rep.FIGURES["error_vs_noise"]).write_bytes(b"an earlier run's noise sweep")

    def stopped(*a, **k):
        raise KeyboardInterrupt

    monkeypatch.setitem(rep.write_report.__globals__, "fig_euler", stopped)
    with pytest.raises(KeyboardInterrupt):
        rep.write_report(baseline_result, out)
    left = {p.name for p in out.iterdir()}
    assert not left & {"report.md", "metrics.json", rep.FIGURES["error_vs_noise"], rep.FIGURES["euler"]}, left
    monkeypatch.undo()
    rep.write_report(baseline_result, out)
    assert (out / "report.md").exists() and not (out / rep.FIGURES["error_vs_noise"]).exists()


def test_a_difference_in_the_rounding_noise_is_a_tie_not_a_win():
    """TE-PINN "beat" offline VQF 1/1 on a trial by 6e-12° (the same estimate). A record counts for A only by more
    than WIN_MARGIN_DEG; closer is a tie; a clear margin still counts."""
    from types import SimpleNamespace

    from tepinn_flight.evaluation.harness import WIN_MARGIN_DEG, compare_learned

    def run(pairs):
        recs = [{"results": {"tepinn": {"inclination_rmse_deg": a}, "vqf": {"inclination_rmse_deg": b}}} for a, b in pairs]
        ests = [SimpleNamespace(name="tepinn", kind="learned"), SimpleNamespace(name="vqf", kind="peer")]
        ds = {"tepinn": {"inclination_rmse_deg": np.mean([a for a, _ in pairs])},
              "vqf": {"inclination_rmse_deg": np.mean([b for _, b in pairs])}}
        return compare_learned(recs, ests, ds)[0]

    c = run([(0.75, 0.75 + 6e-12), (0.5, 0.5 + WIN_MARGIN_DEG / 2), (0.4, 0.4 + 3 * WIN_MARGIN_DEG), (0.9, 0.5)])
    assert (c["wins_a"], c["ties"], c["n_records"]) == (1, 2, 4)


def test_riann_gets_no_heading_figures_and_the_records_table_gives_the_log_clock(tmp_path):
    """RIANN tracks no heading: its 89.8° heading RMSE and 2483 °/min drift stood beside the others' as if they
    compared. A DataFlash record's row gives the log's clock at the figures' t = 0 (erle: TimeMS 51.686 s)."""
    from tests.conftest import real_log
    from tepinn_flight.evaluation.harness import HarnessConfig, evaluate
    from tepinn_flight.evaluation.report import render_markdown
    from tepinn_flight.evaluation.suite import peer_estimators
    from tepinn_flight.ingest import ingest_log

    rec = ingest_log(real_log("erle_pxf_copter_15-12-2014_16.BIN"))
    ests = [e for e in peer_estimators(notes=[]) if e.name in ("vqf", "riann")]
    if len(ests) < 2:
        pytest.skip("riann or vqf not installed")
    res = evaluate([rec], ests, HarnessConfig(warmup_s=5.0), progress=False)
    assert res.dataset["riann"]["heading_rmse_deg"] is None and res.dataset["riann"]["heading_drift_abs_deg_per_min"] is None
    assert res.dataset["riann"]["inclination_rmse_deg"] is not None and res.dataset["vqf"]["heading_rmse_deg"] is not None
    assert res.records[0]["log_clock_at_t0_s"] == pytest.approx(51.686, abs=1e-9)
    md = render_markdown(res, {k: f"{k}.png" for k in FIGURES})
    row = next(ln for ln in md.splitlines() if ln.startswith("| erle"))
    assert "| 51.686 |" in row
    head = next(ln for ln in md.splitlines() if ln.startswith("| estimator | kind"))
    riann = next(ln for ln in md.splitlines() if ln.startswith(f"| {display_name('riann')} |"))
    cells = [c.strip() for c in riann.strip("|").split("|")]
    cols = [c.strip() for c in head.strip("|").split("|")]
    assert cells[cols.index("heading [°]")] == "–" and cells[cols.index("median of records")] != "–"


def test_tepinn_is_drawn_on_top_and_the_plotted_quaternion_keeps_its_sign_where_the_reference_is_missing(baseline_result):
    import matplotlib.pyplot as plt

    from tepinn_flight.evaluation.report import _hemisphere_ref, fig_inclination_error

    ref = np.array([[np.nan] * 4, [0.0, 1.0, 0.0, 0.0], [np.nan] * 4, [1.0, 0.0, 0.0, 0.0], [np.nan] * 4])
    np.testing.assert_array_equal(_hemisphere_ref(ref), [[0, 1, 0, 0], [0, 1, 0, 0], [0, 1, 0, 0], [1, 0, 0, 0], [1, 0, 0, 0]])
    series = [dict(s) for s in baseline_result.series]
    s0 = series[0]
    s0["est"] = {"tepinn": s0["est"]["vqf"], **s0["est"]}  # TE-PINN first in the dict: still drawn last
    from types import SimpleNamespace

    res = SimpleNamespace(**{**vars(baseline_result), "series": series})
    fig = fig_inclination_error(res, colour_map(["tepinn", *baseline_result.dataset]))
    lines = fig.axes[0].get_lines()
    top = max(lines, key=lambda ln: ln.get_zorder())
    assert top.get_label() == display_name("tepinn") and lines[-1].get_label() == display_name("tepinn")
    plt.close(fig)


def test_labels_of_records_with_nearly_the_same_rmse_do_not_print_over_each_other():
    from tepinn_flight.evaluation.report import _label_sides

    vals = np.array([1.00, 1.01, 1.02, 2.0, 3.0])
    got = dict(_label_sides(vals, range(5), log_scale=False, span=2.0))
    assert got == {0: 1, 1: -1, 3: 1, 4: 1}  # the second close one to the left, the third left out
    same = dict(_label_sides(np.full(4, 0.75), range(4), log_scale=False, span=0.0))
    assert sorted(same.values()) == [-1, 1]
    logs = dict(_label_sides(np.array([0.1, 0.101, 10.0]), range(3), log_scale=True, span=2.0))
    assert logs == {0: 1, 1: -1, 2: 1}


def test_sigma_is_given_pooled_and_per_record_averaged():
    """`evaluate` printed NEES 1.88 / 94.7 % on the six held-out drone logs (pooled over samples) where the README
    quotes 1.16 / 97.7 % (per file averaged), without saying which. Both are given now."""
    from types import SimpleNamespace

    from tepinn_flight.evaluation.harness import aggregate

    def rec(nees, in3, n):
        u = {"n": n, "nees": nees, "coverage_1sigma": 0.4, "coverage_2sigma": 0.8, "coverage_3sigma": in3, "spearman": 0.1}
        return {"results": {"tepinn": {"inclination_rmse_deg": 1.0, "uncertainty": u, "seconds": 1.0, "coverage": 1.0}},
                "n_samples": n}

    rs = [rec(0.1, 1.0, 100), rec(4.0, 0.88, 900)]
    d = aggregate(rs, [SimpleNamespace(name="tepinn")], 1)["tepinn"]["uncertainty"]
    assert d["nees"] == pytest.approx(0.1 * 0.1 + 4.0 * 0.9) and d["nees_per_record_mean"] == pytest.approx(2.05)
    assert d["coverage_3sigma_per_record_mean"] == pytest.approx(0.94)
