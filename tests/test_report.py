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
    ("tepinn-run2", "TE-PINN (run2)"), ("no-physics", "no physics"), ("something-else", "something-else"),
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
