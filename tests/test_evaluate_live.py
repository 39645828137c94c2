"""`evaluate --live` adds TE-PINN as the bridge runs it (review61: `--no-smooth` had been called "the bridge's" while
the record's GNSS aid and gyro self-calibration still applied; review62: an offline estimate with those steps off still
read the accelerometer's scale from the whole record, where the bridge reads it from its first quiet seconds). The
live column is the streaming estimator pushed every sample; checked here against the offline anchored estimator with
every offline step off (an independent path: its own compiled segment loop), σ included; and on a board whose
accelerometer reads 0.8 g at rest — where the two paths rightly differ — against the live tests' own push loop
(``tests/live_run.py``: the vehicle and the clipping flags passed as the bridge passes them), more than 0.5° from the
offline estimate with those steps off."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

pytest.importorskip("torch")

from tepinn_flight.cli.main import main  # noqa: E402
from tepinn_flight.evaluation.estimators import TepinnEstimator  # noqa: E402
from tepinn_flight.model.checkpoint import default_model_path  # noqa: E402
from tepinn_flight.record import EST_Q_COLS  # noqa: E402


@pytest.fixture(scope="module")
def f450(tmp_path_factory):
    from tepinn_flight.record import write_record
    from tepinn_flight.sim.simulate import simulate_record

    rec = simulate_record("F450", 25.0, rate_hz=100.0, seed=11)
    path = tmp_path_factory.mktemp("live") / "f450.parquet"
    write_record(rec, path)
    return rec, path


@pytest.fixture(scope="module")
def shipped():
    return TepinnEstimator.from_checkpoint(default_model_path(), "tepinn", "torch")


def _angle_deg(a, b):
    return np.degrees(2 * np.arccos(np.clip(np.abs(np.sum(a * b, 1)), 0, 1)))


def test_the_live_column_is_the_offline_estimate_with_every_offline_step_off(f450, shipped):
    rec, _ = f450
    assert rec.meta.get("vehicle_type")  # (the vehicle reaches σ's aircraft term in both paths)
    live = shipped.live()
    assert live.name == "tepinn-live" and live.causal and not shipped.causal and live.live() is None
    got = live.estimate(rec)
    causal = TepinnEstimator(shipped.model, dataclasses.replace(shipped.fusion, smoother=False, gnss_aid=False,
                                                                gyro_selfcal=False, accel_scale_selfcal=False))  # fmt: skip
    want = causal.estimate(rec)
    ok = np.all(np.isfinite(got[EST_Q_COLS].to_numpy()), 1)
    assert ok.sum() > 0.9 * len(rec)
    # live, the first estimate waits for the segment's period (its first 51 steps); from then on both have one
    first = int(np.argmax(ok))
    assert first <= 51 and ok[first:].all() and np.all(np.isfinite(want[EST_Q_COLS].to_numpy()[first:]))
    assert np.max(_angle_deg(got[EST_Q_COLS].to_numpy()[ok], want[EST_Q_COLS].to_numpy()[ok])) < 1e-3
    np.testing.assert_allclose(got["sigma_rad"].to_numpy()[ok], want["sigma_rad"].to_numpy()[ok], rtol=1e-4, atol=1e-7)
    # the unsmoothed column still carries the offline GNSS aid: on this flight it is not the bridge's
    plain = shipped.unsmoothed().estimate(rec)
    assert "applied" in plain.attrs.get("gnss_aid", "")
    assert np.percentile(_angle_deg(got[EST_Q_COLS].to_numpy()[ok], plain[EST_Q_COLS].to_numpy()[ok]), 90) > 0.1


def test_the_live_column_reads_a_low_accelerometer_as_the_bridge_does(shipped):
    """A 15-s rest, then a fixed-wing flight whose gates act, on a board reading 0.8 g: the bridge reads the scale
    after its first quiet seconds, offline reads it from the whole record and applies it from the first sample
    (review62: the live column had been the offline one, up to 2.3° from the bridge's here). The live column is the
    streaming estimator's, sample for sample (``tests/live_run.py``, the loop the live tests use, with the vehicle)."""
    import pandas as pd

    from tepinn_flight.conventions import GRAVITY_M_S2
    from tepinn_flight.record import ACC_COLS, GYR_COLS, FlightRecord
    from tepinn_flight.sim.simulate import simulate_record
    from tests.live_run import live_run

    rec = simulate_record("c172x", 25.0, rate_hz=100.0, seed=3)
    d, n0, rng = rec.data, 1500, np.random.default_rng(0)
    rest = pd.DataFrame({c: np.repeat(d[c].iloc[:1].to_numpy(), n0) for c in d.columns})
    rest["t_s"] = np.arange(n0) * 0.01
    rest[GYR_COLS] = rng.normal(0, 0.003, (n0, 3))
    a0 = d[ACC_COLS].iloc[0].to_numpy()
    rest[ACC_COLS] = a0 / np.linalg.norm(a0) * GRAVITY_M_S2 + rng.normal(0, 0.05, (n0, 3))
    rest[[c for c in d.columns if c.startswith("gnss_")]] = np.nan
    flight = d.copy()
    flight["t_s"] += n0 * 0.01
    data = pd.concat([rest, flight], ignore_index=True)
    data[ACC_COLS] = data[ACC_COLS].to_numpy() * 0.8
    low = FlightRecord(data, dict(rec.meta))
    got = shipped.live().estimate(low)[EST_Q_COLS].to_numpy()
    want, _ = live_run(shipped.model, shipped.fusion, low, vehicle=low.meta.get("vehicle_type"))
    np.testing.assert_array_equal(np.isfinite(got), np.isfinite(want))
    ok = np.all(np.isfinite(got), 1)
    assert ok.sum() > 0.9 * len(low) and np.max(_angle_deg(got[ok], want[ok])) < 1e-4
    # the offline steps turned off is not the same: its scale applies from the first sample
    base = dataclasses.replace(shipped.fusion, smoother=False, gnss_aid=False, gyro_selfcal=False)
    off = TepinnEstimator(shipped.model, base).estimate(low)[EST_Q_COLS].to_numpy()
    assert np.max(_angle_deg(got[ok], off[ok])) > 0.5, np.max(_angle_deg(got[ok], off[ok]))


def test_evaluate_live_adds_the_column_named_as_the_bridges(f450, tmp_path):
    _, path = f450
    out = tmp_path / "r"
    assert main(["evaluate", str(path), "-o", str(out), "--no-peers", "--live", "--no-smooth", "-q",
                 "--runtime", "torch"]) == 0  # fmt: skip
    info = {e["name"]: e for e in json.loads((out / "metrics.json").read_text())["estimators"]}
    assert "tepinn-live" in info and "tepinn-nosmooth" in info and "lstm-live" not in info
    assert info["tepinn-live"]["causal"] is True and info["tepinn"]["causal"] is False
    assert "TE-PINN, live (the bridge's)" in (out / "report.md").read_text()


def test_evaluate_live_says_when_a_model_is_already_the_bridges(f450, tmp_path, capsys):
    import torch

    _, path = f450
    ck = torch.load(default_model_path(), weights_only=True)
    ck["anchor_config"].update(smoother=False, gnss_aid=False, gyro_selfcal=False, accel_scale_selfcal=False)
    torch.save(ck, tmp_path / "causal.pt")
    ck["anchor_config"].update(mode="9d")
    torch.save(ck, tmp_path / "nine.pt")
    capsys.readouterr()
    for model, why in (("causal.pt", "it has no offline step"), ("nine.pt", "it is 9-D")):
        out = tmp_path / f"report_{model}"
        assert main(["evaluate", str(path), "-o", str(out), "--no-peers", "--live", "-q", "--runtime", "torch",
                     "--model", str(tmp_path / model)]) == 0  # fmt: skip
        assert f": {why}" in capsys.readouterr().err
        names = [e["name"] for e in json.loads((out / "metrics.json").read_text())["estimators"]]
        assert not any(n.endswith("-live") for n in names)
