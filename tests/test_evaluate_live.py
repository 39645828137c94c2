"""`evaluate --live` adds TE-PINN as the bridge runs it (review61: `--no-smooth` had been called "the bridge's" while
the record's GNSS aid and gyro self-calibration still applied). Checked against the streaming estimator the bridge
itself runs, sample by sample, on a simulated quad flight where the GNSS aid acts offline."""

from __future__ import annotations

import json

import numpy as np
import pytest

pytest.importorskip("torch")

from tepinn_flight.cli.main import main  # noqa: E402
from tepinn_flight.evaluation.estimators import TepinnEstimator  # noqa: E402
from tepinn_flight.model.checkpoint import default_model_path  # noqa: E402

Q = ["q_est_w", "q_est_x", "q_est_y", "q_est_z"]


@pytest.fixture(scope="module")
def f450(tmp_path_factory):
    from tepinn_flight.record import write_record
    from tepinn_flight.sim.simulate import simulate_record

    rec = simulate_record("F450", 40.0, rate_hz=100.0, seed=11)
    path = tmp_path_factory.mktemp("live") / "f450.parquet"
    write_record(rec, path)
    return rec, path


def _streamed(est, rec):
    from tepinn_flight.model.streaming import StreamingEstimator

    se = StreamingEstimator(est.model, est.fusion)
    out = np.full((len(rec), 4), np.nan)
    for i, (t, g, a, c) in enumerate(zip(rec.t_s, rec.gyr_rad_s, rec.acc_m_s2, rec.clipped)):
        e = se.push(t, g, a, None, c)
        if e is not None and e.q_nb_wxyz is not None:
            out[i] = e.q_nb_wxyz
    return out


def test_the_live_variant_is_what_the_bridge_gives_and_the_unsmoothed_one_is_not(f450):
    rec, _ = f450
    shipped = TepinnEstimator.from_checkpoint(default_model_path(), "tepinn", "torch")
    live, nosmooth = shipped.live(), shipped.unsmoothed()
    assert live.name == "tepinn-live" and not (live.fusion.smoother or live.fusion.gnss_aid or live.fusion.gyro_selfcal)
    assert live.fusion.accel_scale_selfcal == shipped.fusion.accel_scale_selfcal  # (the bridge tracks it as it goes)
    streamed = _streamed(live, rec)
    offline = live.estimate(rec)[Q].to_numpy()
    unsmoothed = nosmooth.estimate(rec)[Q].to_numpy()
    ok = np.all(np.isfinite(streamed), 1) & np.all(np.isfinite(offline), 1)
    assert ok.sum() > 0.9 * len(rec)

    def angle_deg(a, b):
        return np.degrees(2 * np.arccos(np.clip(np.abs(np.sum(a * b, 1)), 0, 1)))

    assert np.max(angle_deg(streamed[ok], offline[ok])) < 0.05
    # the unsmoothed column still carries the offline GNSS aid: on this flight it differs from the bridge's
    assert "applied" in nosmooth.estimate(rec).attrs.get("gnss_aid", "")
    assert np.percentile(angle_deg(streamed[ok], unsmoothed[ok]), 90) > 0.1
    # a model with nothing offline on has no live variant apart from itself
    assert live.live() is None


def test_evaluate_live_adds_the_column_named_as_the_bridges(f450, tmp_path):
    _, path = f450
    out = tmp_path / "r"
    assert main(["evaluate", str(path), "-o", str(out), "--no-peers", "--live", "--no-smooth", "-q",
                 "--runtime", "torch"]) == 0  # fmt: skip
    names = [e["name"] for e in json.loads((out / "metrics.json").read_text())["estimators"]]
    assert "tepinn-live" in names and "tepinn-nosmooth" in names and "lstm-live" not in names
    assert "TE-PINN, live (the bridge's)" in (out / "report.md").read_text()


def test_evaluate_live_says_when_a_model_is_already_the_bridges(f450, tmp_path, capsys):
    import torch

    _, path = f450
    ck = torch.load(default_model_path(), weights_only=True)
    ck["anchor_config"].update(smoother=False, gnss_aid=False, gyro_selfcal=False)
    torch.save(ck, tmp_path / "causal.pt")
    out = tmp_path / "r"
    capsys.readouterr()
    assert main(["evaluate", str(path), "-o", str(out), "--no-peers", "--live", "-q", "--runtime", "torch",
                 "--model", str(tmp_path / "causal.pt")]) == 0  # fmt: skip
    assert "--live: no model here has an offline step the bridge lacks" in capsys.readouterr().err
    names = [e["name"] for e in json.loads((out / "metrics.json").read_text())["estimators"]]
    assert not any(n.endswith("-live") for n in names)
