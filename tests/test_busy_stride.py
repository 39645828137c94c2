"""``--busy-stride N`` on ``estimate``, ``evaluate`` and ``bridge``: the anchored estimator's speed knob
(``AnchorConfig.busy_stride``) from the command line. ``estimate`` gives exactly the estimate of the
setting (and not the shipped one), ``evaluate`` adds the strided model beside the shipped one, the
bridge's worker runs it, and a model without busy blocks (the older network-centred fusion) is
refused with one line. That live and offline run the same windows at a stride is tested in
``test_anchor.py``."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest

from tepinn_flight.cli.main import main
from tepinn_flight.errors import ConfigError
from tepinn_flight.model.anchor import AnchorConfig, with_busy_stride
from tepinn_flight.model.checkpoint import default_lstm_path, default_model_path, load_model
from tepinn_flight.model.estimate import anchored_windows, estimate_record
from tepinn_flight.model.finetune import inclination_rmse_deg
from tepinn_flight.model.runtime import default_onnx_path, load_runner
from tepinn_flight.model.synthetic import synthetic_record
from tepinn_flight.record import write_record

Q = ["q_est_w", "q_est_x", "q_est_y", "q_est_z"]


@pytest.fixture(scope="module")
def record(tmp_path_factory):
    # 24 s at 100 Hz with a 5.7 °/s gyro bias: blocks stay busy after the 10 s start-up (522 -> 391
    # windows at a stride of 2 with the shipped settings) and the uncalibrated-gyro gate opens, so the
    # windows reach the estimate (at the synthetic default of 1.1 °/s no gate opens: VQF's output at any
    # stride). Turning at up to ~1 rad/s from level: the synthetic default (4 rad/s, every orientation)
    # leaves the network's domain, where the gate no longer takes the older fusion's evidence (session 16)
    rec = synthetic_record(seed=2, duration_s=24.0, rate_hz=100.0, gyr_bias_rad_s=0.1, max_rate_rad_s=1.0)
    path = tmp_path_factory.mktemp("stride") / "syn.parquet"
    write_record(rec, path)
    return rec, path


def test_with_busy_stride_sets_the_stride_and_refuses_the_older_fusion():
    _, shipped, _ = load_model(default_model_path())
    assert isinstance(shipped, AnchorConfig) and shipped.busy_stride == 1
    assert with_busy_stride(shipped, 0) is shipped and with_busy_stride(shipped, None) is shipped
    s4 = with_busy_stride(shipped, 4)
    assert s4.busy_stride == 4 and s4.pull_gain == shipped.pull_gain and s4.quiet_blocks == shipped.quiet_blocks
    _, lstm_fusion, _ = load_model(default_lstm_path())  # the LSTM baseline runs the older fusion
    with pytest.raises(ConfigError, match="--busy-stride 2: lstm_default.pt runs the older network-centred fusion"):
        with_busy_stride(lstm_fusion, 2, "lstm_default.pt")


def test_estimate_busy_stride_is_the_setting_and_runs_fewer_windows(record, tmp_path, capsys):
    rec, path = record
    runner, settings, _ = load_runner(default_onnx_path(), "onnx")
    every, _ = anchored_windows(runner, rec, fusion=settings.fusion_config, anchor=settings)
    strided, _ = anchored_windows(runner, rec, fusion=settings.fusion_config, anchor=with_busy_stride(settings, 2))
    assert len(strided) < len(every) - 30  # the record has busy blocks after the start-up
    assert main(["estimate", str(path), "-o", str(tmp_path / "s2.parquet"), "-q", "--busy-stride", "2"]) == 0, capsys.readouterr().err
    assert main(["estimate", str(path), "-o", str(tmp_path / "s1.parquet"), "-q"]) == 0, capsys.readouterr().err
    got2 = pd.read_parquet(tmp_path / "s2.parquet")[Q].to_numpy()
    got1 = pd.read_parquet(tmp_path / "s1.parquet")[Q].to_numpy()
    want2 = estimate_record(runner, rec, with_busy_stride(settings, 2))[Q].to_numpy()
    want1 = estimate_record(runner, rec, settings)[Q].to_numpy()
    np.testing.assert_allclose(got2, want2, rtol=0, atol=1e-12)
    np.testing.assert_allclose(got1, want1, rtol=0, atol=1e-12)
    assert np.nanmax(np.abs(got2 - got1)) > 1e-6  # the knob changes the estimate: it reached the estimator


def test_estimate_busy_stride_bad_values_and_models_are_one_line(record, tmp_path, capsys):
    _, path = record
    with pytest.raises(SystemExit) as ex:
        main(["estimate", str(path), "-o", str(tmp_path / "x.parquet"), "--busy-stride", "0"])
    assert ex.value.code == 2
    assert "--busy-stride: must be an integer >= 1" in capsys.readouterr().err
    code = main(["estimate", str(path), "-o", str(tmp_path / "y.parquet"), "--busy-stride", "3", "--model", str(default_lstm_path())])
    err = capsys.readouterr().err
    assert code == 2 and "runs the older network-centred fusion" in err and "Traceback" not in err
    assert len(err.strip().splitlines()) == 1 and not (tmp_path / "y.parquet").exists()


@pytest.mark.slow
def test_evaluate_busy_stride_adds_the_strided_model(record, tmp_path, capsys):
    _, path = record
    out = tmp_path / "rep"
    code = main(["evaluate", str(path), "-o", str(out), "--no-peers", "--busy-stride", "3", "-q"])
    assert code == 0, capsys.readouterr().err
    ds = json.loads((out / "metrics.json").read_text())["dataset"]
    # the strided model's score is that of the setting, computed here without evaluate's harness
    rec, _ = record
    runner, settings, _ = load_runner(default_onnx_path(), "onnx")
    want = inclination_rmse_deg(rec, estimate_record(runner, rec, with_busy_stride(settings, 3)))
    # (to 1e-4°: the network in float32, batched otherwise by the harness; the stride itself moves it > 1e-3°)
    assert ds["tepinn-stride3"]["inclination_rmse_deg"] == pytest.approx(want, abs=1e-4)
    assert abs(ds["tepinn-stride3"]["inclination_rmse_deg"] - ds["tepinn"]["inclination_rmse_deg"]) > 1e-3
    assert "TE-PINN, busy stride 3" in (out / "report.md").read_text()


def test_bridge_worker_runs_the_stride_and_the_config_checks_it():
    from tepinn_flight.live.bridge import BridgeConfig
    from tepinn_flight.live.worker import model_estimator_factory

    est = model_estimator_factory(str(default_onnx_path()), "onnx", "", 5)()
    assert est.anchor_cfg.busy_stride == 5
    assert model_estimator_factory(str(default_onnx_path()), "onnx")().anchor_cfg.busy_stride == 1
    with pytest.raises(ConfigError, match="older network-centred fusion"):
        model_estimator_factory(str(default_lstm_path()), "torch", "", 2)()
    with pytest.raises(ConfigError, match="busy_stride"):
        BridgeConfig(master="udpin:127.0.0.1:14550", busy_stride=-1)


def test_the_offline_rule_on_arrays_is_the_live_rule_window_by_window():
    """``runs_windows`` (offline, a block's windows at once) decides as ``runs_window`` (live, one window) for every
    block, window, busy and saturated case, strides 1 and 6."""
    import dataclasses

    for stride in (1, 6):
        cfg = dataclasses.replace(AnchorConfig(), busy_stride=stride)
        j = np.arange(25)
        for block in (0, cfg.quiet_after_blocks - 1, cfg.quiet_after_blocks, 40):
            for busy in (False, True):
                sat = np.random.default_rng(block + 7 * busy).random(25) < 0.3
                want = [cfg.runs_window(block, int(k), busy, bool(s)) for k, s in zip(j, sat)]
                got = cfg.runs_windows(block, j, busy, sat)
                assert got.dtype == bool and got.tolist() == want


def test_the_windows_made_ahead_in_a_thread_are_the_one_call_s_bits_and_errors_reach_the_reader(record):
    """The quiet blocks' first windows, made a batch at a time in a thread ahead of the blocks (``_Ahead``), are those
    one ``network_outputs`` call makes (the same batches), row by row across batch edges; a failing network call
    raises where its row is read."""
    import threading

    from tepinn_flight.model import estimate as E
    from tepinn_flight.model.tokens import tokenize_record

    model, _, _ = load_model(default_model_path())
    tok = tokenize_record(record[0], model.config.token_rate_hz)
    ends = tok.windows_ending(model.config.window_tokens)[::3][:20]
    assert len(ends) == 20
    whole = E.network_outputs(model, tok, ends, None, 7)
    ahead = E._Ahead(model, tok, ends, 7, threading.Lock())
    try:
        for i in range(len(ends)):
            row = ahead.row(i)
            assert set(row) == set(whole)
            for k in whole:
                assert np.array_equal(row[k], whole[k][i : i + 1]), (i, k)
    finally:
        ahead.close()

    from tepinn_flight.model.runtime import NetworkRunner

    class Broken(NetworkRunner):
        config = model.config

        def run(self, *a):
            raise RuntimeError("network down")

    bad = E._Ahead(Broken(), tok, ends, 7, threading.Lock())
    try:
        with pytest.raises(RuntimeError, match="network down"):
            bad.row(0)
    finally:
        bad.close()
