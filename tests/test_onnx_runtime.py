"""ONNX export and the network runners: onnxruntime gives torch's outputs, and the estimate and
live paths run without torch."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from tests.conftest import REPO, real_log

torch = pytest.importorskip("torch")
pytest.importorskip("onnx")
pytest.importorskip("onnxruntime")

from tepinn_flight.model.checkpoint import default_model_path, load_model  # noqa: E402
from tepinn_flight.model.runtime import (  # noqa: E402
    OUTPUTS, OnnxRunner, TorchRunner, default_onnx_path, load_runner, read_onnx_metadata,
)  # fmt: skip

ERLE = "erle_pxf_copter_15-12-2014_16.BIN"
#: q, σ, bias to 1e-5 absolute; the velocity head's outputs are in m/s (×30) and m/s² (×5):
#: 1e-5 of the head's own units
ATOL = {"q": 1e-5, "sigma": 1e-5, "bias": 1e-5, "vel": 30 * 1e-5, "acc_v": 5 * 1e-5}


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    from tepinn_flight.cli.main import main

    path = tmp_path_factory.mktemp("onnx") / "model.onnx"
    assert main(["export", "-o", str(path), "-q"]) == 0
    return path


def _assert_close(a: dict, b: dict):
    for k in OUTPUTS:
        np.testing.assert_allclose(a[k], b[k], rtol=0, atol=ATOL[k], err_msg=k)


def _random_windows(config, batch, seed):
    from tepinn_flight.model.export import example_inputs

    return [v.numpy().astype(np.float64) for v in example_inputs(config, batch, seed)]


def test_export_metadata_and_settings_match_the_checkpoint(exported):
    model, settings, ckpt = load_model(default_model_path())
    meta = read_onnx_metadata(exported)
    assert meta["format"] == "tepinn-flight-onnx" and meta["version"] == 3 and meta["opset"] == 17
    assert meta["model_config"] == ckpt["model_config"]
    as_json = lambda d: json.loads(json.dumps(d))  # noqa: E731  (JSON metadata: tuples come back as lists)
    assert meta["anchor_config"] == as_json(ckpt["anchor_config"]) and meta["fusion_config"] == as_json(ckpt["fusion_config"])
    assert meta["conventions"] == ckpt["conventions"]
    from tepinn_flight import __version__

    assert meta["exported_by"] == f"tepinn-flight {__version__}"  # (review60: the deployed file did not say)
    assert meta.get("tepinn_flight_version") == ckpt.get("tepinn_flight_version")
    runner, settings_onnx, _ = load_runner(exported, "auto")
    assert isinstance(runner, OnnxRunner) and settings_onnx == settings
    assert runner.config == model.config
    # dynamic batch axis, window length fixed by the config
    for i in runner.session.get_inputs():
        assert isinstance(i.shape[0], str) and i.shape[1] == model.config.window_tokens, (i.name, i.shape)


@pytest.mark.parametrize("batch,seed", [(1, 0), (7, 1), (300, 2)])
def test_onnx_equals_torch_on_random_windows(exported, batch, seed):
    model, _, _ = load_model(default_model_path())
    x = _random_windows(model.config, batch, seed)
    _assert_close(OnnxRunner(exported).run(*x), TorchRunner(model).run(*x))


def test_a_batch_in_slices_on_threads_equals_one_run(exported):
    # with n threads a batch runs as n slices side by side: each window's outputs as in one run (to
    # float32 round-off), in the batch's order (a slice out of place would be far off)
    model, _, _ = load_model(default_model_path())
    x = _random_windows(model.config, 11, 3)
    one, three = OnnxRunner(exported, threads=1), OnnxRunner(exported, threads=3)
    assert (one.workers, three.workers) == (1, 3)
    a, b = one.run(*x), three.run(*x)
    for k in OUTPUTS:
        np.testing.assert_allclose(b[k], a[k], rtol=0, atol=1e-6, err_msg=k)
    y = [v[::-1].copy() for v in x]  # the windows reversed give the outputs reversed
    assert np.abs(three.run(*y)["q"][::-1] - a["q"]).max() < 1e-6 < np.abs(three.run(*y)["q"] - a["q"]).max()


@pytest.mark.parametrize("threads", [1, 2])
def test_a_large_batch_runs_in_chunks_equal_to_one_window_at_a_time(exported, threads):
    # a batch larger than CHUNK_WINDOWS (per thread) runs CHUNK_WINDOWS windows at a time: each window's outputs
    # as its own run's (float32 round-off), in the batch's order
    from tepinn_flight.model import runtime

    model, _, _ = load_model(default_model_path())
    b = 2 * runtime.CHUNK_WINDOWS * threads + 5
    x = _random_windows(model.config, b, 7)
    runner, single = OnnxRunner(exported, threads=threads), OnnxRunner(exported, threads=1)
    calls = []
    run = runner.session.run
    runner.session = type("Counted", (), {"run": lambda self, names, feed: calls.append(len(feed["x"])) or run(names, feed)})()
    a = runner.run(*x)
    assert max(calls) == runtime.CHUNK_WINDOWS and sum(calls) == b and len(calls) >= 3 * threads
    for i in range(b):
        one = single.run(*(v[i : i + 1] for v in x))
        for k in OUTPUTS:
            np.testing.assert_allclose(a[k][i], one[k][0], rtol=0, atol=1e-6, err_msg=f"{k} window {i}")


def test_runs_through_the_kept_binding_equal_fresh_sessions_and_leave_earlier_outputs_alone(exported):
    # one thread: runs of one shape reuse their binding (inputs copied into its buffers, outputs read from
    # buffers bound once); each run's outputs are those of a fresh session's own run, bit for bit, and a new
    # shape binds anew. An output handed out earlier is not overwritten by a later run
    model, _, _ = load_model(default_model_path())
    kept, fresh = OnnxRunner(exported, threads=1), OnnxRunner(exported, threads=1)
    xs = [_random_windows(model.config, b, seed) for b, seed in ((1, 10), (1, 11), (3, 12), (1, 13))]
    first = kept.run(*xs[0])
    q_first = first["q"].copy()
    for x in xs:
        a = kept.run(*x)
        fresh._io.__dict__.clear()  # a binding made for this run alone
        b = fresh.run(*x)
        for k in OUTPUTS:
            np.testing.assert_array_equal(a[k], b[k], err_msg=k)
    np.testing.assert_array_equal(first["q"], q_first)
    assert np.abs(kept.run(*xs[1])["q"] - q_first).max() > 1e-4  # other windows, other outputs


@pytest.mark.parametrize("which", ["tepinn", "lstm"])
def test_shipped_onnx_is_the_shipped_checkpoint(which):
    """assets/tepinn_default.onnx and lstm_default.onnx (run by default, and where torch is absent) are kept in sync
    with their .pt."""
    from tepinn_flight.model.checkpoint import default_lstm_path
    from tepinn_flight.model.runtime import export_in_sync

    pt = default_model_path() if which == "tepinn" else default_lstm_path()
    model, settings, ckpt = load_model(pt)
    assert export_in_sync(pt) == pt.with_suffix(".onnx")
    runner, settings_onnx, meta = load_runner(pt.with_suffix(".onnx"), "onnx")
    assert settings_onnx == settings and meta["model_config"] == ckpt["model_config"]
    x = _random_windows(model.config, 16, 5)
    _assert_close(runner.run(*x), TorchRunner(model).run(*x))


def test_torch_runtime_refuses_an_onnx_file(exported):
    from tepinn_flight.errors import ConfigError

    with pytest.raises(ConfigError, match="onnx runtime"):
        load_runner(exported, "torch")


@pytest.fixture(scope="module")
def erle():
    from tepinn_flight.ingest import ingest_log

    return ingest_log(real_log(ERLE))


@pytest.mark.slow
def test_real_windows_and_estimate_anchored_onnx_equals_torch(exported, erle):
    from tepinn_flight.model.estimate import anchored_windows, estimate_anchored

    model, settings, _ = load_model(default_model_path())
    onnx_runner, onnx_settings, _ = load_runner(exported, "onnx")
    assert onnx_settings == settings
    idx_t, out_t = anchored_windows(model, erle)
    idx_o, out_o = anchored_windows(onnx_runner, erle)
    assert len(idx_t) > 1000 and np.array_equal(idx_t, idx_o)
    _assert_close(out_o, out_t)
    a = estimate_anchored(model, erle, settings, windows=(idx_t, out_t))
    b = estimate_anchored(onnx_runner, erle, onnx_settings, windows=(idx_o, out_o))
    assert a["q_est_w"].notna().mean() > 0.9
    np.testing.assert_allclose(b.to_numpy(), a.to_numpy(), rtol=0, atol=1e-5, equal_nan=True)


def test_streaming_onnx_equals_torch(exported, erle):
    from tepinn_flight.model.streaming import StreamingEstimator

    model, settings, _ = load_model(default_model_path())
    runner, _, _ = load_runner(exported, "onnx")
    live_t = StreamingEstimator(model, settings)
    live_o = StreamingEstimator(runner, settings)
    n = min(len(erle), 1200)
    ran = 0
    for i in range(n):
        args = (erle.t_s[i], erle.gyr_rad_s[i], erle.acc_m_s2[i], None, bool(erle.clipped[i]))
        et, eo = live_t.push(*args), live_o.push(*args)
        assert et.model_ran == eo.model_ran
        ran += et.model_ran
        assert (et.q_nb_wxyz is None) == (eo.q_nb_wxyz is None)
        if et.q_nb_wxyz is not None:
            np.testing.assert_allclose(eo.q_nb_wxyz, et.q_nb_wxyz, atol=1e-5)
            np.testing.assert_allclose(eo.gyr_bias_rad_s, et.gyr_bias_rad_s, atol=1e-5)
            assert eo.sigma_rad == pytest.approx(et.sigma_rad, abs=1e-5)
    assert ran > 10


#: blocks `import torch` in a subprocess: the runtime path must not need it
NO_TORCH = textwrap.dedent("""
    import importlib.abc, sys
    class _NoTorch(importlib.abc.MetaPathFinder):
        def find_spec(self, name, path=None, target=None):
            if name == "torch" or name.startswith("torch."):
                raise ImportError("torch blocked by the test")
    sys.meta_path.insert(0, _NoTorch())
    import importlib.util
    importlib.util.find_spec = (lambda f: (lambda name, *a: None if name.split(".")[0] == "torch" else f(name, *a)))(importlib.util.find_spec)
""")


def test_estimate_and_live_worker_run_without_torch(tmp_path, exported):
    from tepinn_flight.record import write_record
    from tepinn_flight.sim.simulate import simulate_record

    rec = simulate_record("F450", 6.0, rate_hz=200.0, seed=1)
    write_record(rec, tmp_path / "r.parquet")
    code = NO_TORCH + textwrap.dedent(f"""
        from tepinn_flight.cli.main import main
        rc1 = main(["estimate", "-q", "--model", {str(exported)!r}, {str(tmp_path / 'r.parquet')!r}, "-o", {str(tmp_path / 'e.parquet')!r}])
        rc2 = main(["estimate", "-q", {str(tmp_path / 'r.parquet')!r}, "-o", {str(tmp_path / 'd.parquet')!r}])  # shipped model: its .onnx
        from tepinn_flight.live.worker import model_estimator_factory
        import tepinn_flight.live.bridge
        est = model_estimator_factory({str(exported)!r})()
        from tepinn_flight.record import read_record
        r = read_record({str(tmp_path / 'r.parquet')!r})
        n = sum(est.push(r.t_s[i], r.gyr_rad_s[i], r.acc_m_s2[i]).q_nb_wxyz is not None for i in range(len(r)))
        print("RC", rc1, rc2, "N", n, "TORCH", "torch" in sys.modules)
    """)
    env = {k: v for k, v in os.environ.items() if k != "TEPINN_DEBUG"}
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300, env=env, cwd=REPO)
    assert "RC 0 0" in p.stdout and "TORCH False" in p.stdout, p.stdout + p.stderr
    n = int(p.stdout.split("N ")[1].split()[0])
    assert n > len(rec) // 2
    import pandas as pd

    from tepinn_flight.model.estimate import estimate_record

    model, settings, _ = load_model(default_model_path())
    ref = estimate_record(model, rec, settings)
    for name in ("e.parquet", "d.parquet"):
        got = pd.read_parquet(tmp_path / name)
        np.testing.assert_allclose(got.to_numpy(), ref.to_numpy(), rtol=0, atol=1e-5, equal_nan=True)


@pytest.mark.slow
def test_fresh_venv_runtime_extra_without_torch(tmp_path, exported, monkeypatch, runtime_venv_of_session):
    """`pip install ".[runtime]"` into a plain venv: no torch; `estimate --runtime onnx` works there and gives the torch
    path's estimates, `evaluate` scores the shipped models' exports, the installed live modules import, and the bridge run by that venv's Python works end to end (replay → the venv's bridge on the .onnx → listener: every
    autopilot frame forwarded, estimates on the 50 Hz grid, equal to the torch StreamingEstimator's on the same
    samples). Where pip cannot reach the package index it is skipped; the live estimator without torch is still tested
    in-process (test_estimate_and_live_worker_run_without_torch). The venv is the session's where its warm-up built it
    (a fresh clone: ``tests/runtime_venv.py``), else built here."""
    from tests.runtime_venv import build_runtime_venv

    built = runtime_venv_of_session or build_runtime_venv(tmp_path / "runtime")
    if built["skip"]:
        pytest.skip(f"pip cannot reach the package index ({built['skip']})")
    assert built["returncode"] == 0, built["stderr"]
    venv = Path(built["venv"])
    py = venv / "bin" / "python"
    p = subprocess.run([str(py), "-c", "import torch"], capture_output=True, text=True)
    assert p.returncode != 0 and "No module named 'torch'" in p.stderr
    # a companion computer's autopilot is on a serial port: the extra brings pyserial (review60: it did not)
    assert subprocess.run([str(py), "-c", "import serial"], capture_output=True).returncode == 0
    from tepinn_flight.record import write_record
    from tepinn_flight.sim.simulate import simulate_record

    rec = simulate_record("F450", 5.0, rate_hz=200.0, seed=2)
    write_record(rec, tmp_path / "r.parquet")
    # numba's compilation off in the venv (NUMBA_DISABLE_JIT, its debugging switch: the loops run as Python): the
    # compile of a first run is ~60 s of CI's time, and is tested on its own (tests/test_first_run_compile.py)
    exe = venv / "bin" / "tepinn-flight"
    monkeypatch.setenv("NUMBA_DISABLE_JIT", "1")  # for the venv's commands
    p = subprocess.run([str(exe), "estimate", "--runtime", "onnx", "--model", str(exported), str(tmp_path / "r.parquet"),
                        "-o", str(tmp_path / "e.parquet")], capture_output=True, text=True, timeout=300, cwd=tmp_path)  # fmt: skip
    assert p.returncode == 0, p.stderr
    p2 = subprocess.run([str(exe), "estimate", "--runtime", "torch", str(tmp_path / "r.parquet"), "-o", str(tmp_path / "x.parquet")],
                        capture_output=True, text=True, timeout=300, cwd=tmp_path)  # fmt: skip
    assert p2.returncode == 2 and "needs PyTorch" in p2.stderr
    # evaluate there: the shipped TE-PINN and LSTM from their exports beside the filters (issue 17: evaluate too)
    p3 = subprocess.run([str(exe), "evaluate", str(tmp_path / "r.parquet"), "-o", str(tmp_path / "rep"), "--no-peers", "-q",
                         "--warmup-s", "1"], capture_output=True, text=True, timeout=300, cwd=tmp_path)  # fmt: skip
    assert p3.returncode == 0, p3.stderr
    ran = {e["name"]: e.get("runtime") for e in json.loads((tmp_path / "rep" / "metrics.json").read_text())["estimators"]}
    assert ran["tepinn"] == ran["lstm"] == "onnx" and "ekf" in ran, ran
    import pandas as pd

    from tepinn_flight.model.estimate import estimate_record

    model, settings, _ = load_model(default_model_path())
    ref = estimate_record(model, rec, settings)
    got = pd.read_parquet(tmp_path / "e.parquet")
    np.testing.assert_allclose(got.to_numpy(), ref.to_numpy(), rtol=0, atol=1e-5, equal_nan=True)
    # the bridge, run by the venv's Python without torch (its worker process on onnxruntime), compiled: a live
    # estimator running as Python would not keep up with 400 Hz on a loaded machine. So it is this checkout's bridge
    # (PYTHONPATH), whose loops numba's cache holds; the installed copy's live modules are imported here first
    p = subprocess.run([str(py), "-c", "import importlib, pkgutil, tepinn_flight.live as L; print(L.__file__); "
                        "[importlib.import_module(m.name) for m in pkgutil.iter_modules(L.__path__, L.__name__ + '.')]"],
                       capture_output=True, text=True, timeout=300, cwd=tmp_path)  # fmt: skip
    assert p.returncode == 0 and p.stdout.startswith(str(venv)), p.stdout + p.stderr
    from tests.test_bridge import _check_chain, _offline_estimates, _run_chain, _sim_tlog

    monkeypatch.delenv("NUMBA_DISABLE_JIT")
    monkeypatch.setenv("PYTHONPATH", str(REPO))
    chain = tmp_path / "chain"
    chain.mkdir()
    _, tlog = _sim_tlog(chain, 6.0, 400.0)
    lis, summary, _ = _run_chain(chain, exported, tlog, speed=1.0, bridge_cli=[str(py), "-m", "tepinn_flight"])
    aq, ms = _check_chain(lis, tlog, summary)
    ref = _offline_estimates(default_model_path(), tlog)  # torch
    q_live = np.array([[m.q1, m.q2, m.q3, m.q4] for m in aq])
    np.testing.assert_allclose(q_live, np.array([ref[int(k)] for k in ms]), atol=1e-5)
    assert summary["estimates"]["errors"] == 0


def test_auto_runs_a_checkpoint_with_its_export_in_sync_in_onnxruntime(tmp_path):
    """`auto`: a checkpoint runs the export beside it only while that export was made from exactly
    that file (the shipped model: its export ships beside it); alone, or with a stale export beside
    it, PyTorch; an explicit choice wins."""
    import shutil

    import torch

    from tepinn_flight.model.runtime import OnnxRunner, TorchRunner, export_in_sync, resolve_runtime

    assert export_in_sync(default_model_path()) == default_onnx_path()
    assert resolve_runtime(default_model_path(), "auto") == "onnx"
    assert isinstance(load_runner(default_model_path())[0], OnnxRunner)
    assert isinstance(load_runner(default_model_path(), "torch")[0], TorchRunner)
    mine = tmp_path / "mine.pt"
    shutil.copy(default_model_path(), mine)
    assert resolve_runtime(mine, "auto") == "torch"  # no export beside it
    shutil.copy(default_onnx_path(), tmp_path / "mine.onnx")
    assert resolve_runtime(mine, "auto") == "onnx"  # the same bytes as the shipped pair
    assert isinstance(load_runner(mine)[0], OnnxRunner)
    ck = torch.load(mine, weights_only=True)
    ck["metrics"] = {"note": "retrained"}  # another checkpoint now, the export beside it is stale
    torch.save(ck, mine)
    assert export_in_sync(mine) is None and resolve_runtime(mine, "auto") == "torch"


def test_verbs_that_need_torch_say_so_in_a_torch_less_install(tmp_path):
    """With torch absent as it is from the [runtime] install (No module named 'torch'): `train` says in one line that it
    needs PyTorch, exit 2 (review60: "internal error", exit 1); `evaluate` scores the shipped TE-PINN and LSTM from
    their exports in onnxruntime beside the filters (session 60 had left TE-PINN out; it had failed as a whole before),
    `evaluate --runtime torch` is refused in one line, exit 2, and `info` describes the shipped checkpoint from its
    export."""
    from tepinn_flight.model.synthetic import synthetic_record
    from tepinn_flight.record import write_record

    write_record(synthetic_record(seed=1, duration_s=12.0, rate_hz=100.0), tmp_path / "r.parquet")
    code = textwrap.dedent(f"""
        import importlib.abc, sys
        class _Absent(importlib.abc.MetaPathFinder):
            def find_spec(self, name, path=None, target=None):
                if name == "torch" or name.startswith("torch."):
                    raise ModuleNotFoundError(f"No module named {{name!r}}", name=name)
        sys.meta_path.insert(0, _Absent())
        import importlib.util  # (and not found, as find_spec says of a module that is not installed)
        importlib.util.find_spec = (lambda f: (lambda name, *a: None if name.split(".")[0] == "torch" else f(name, *a)))(importlib.util.find_spec)
        from tepinn_flight.cli.main import main
        rc1 = main(["train", "--config", {str(REPO / 'train' / 'tiny.toml')!r}, "-o", {str(tmp_path / 'run')!r}, "-q"])
        rc2 = main(["evaluate", {str(tmp_path / 'r.parquet')!r}, "-o", {str(tmp_path / 'rep')!r}, "--no-peers", "-q",
                    "--warmup-s", "2"])
        rc3 = main(["evaluate", {str(tmp_path / 'r.parquet')!r}, "-o", {str(tmp_path / 'rep2')!r}, "--no-peers", "-q",
                    "--runtime", "torch"])
        from tepinn_flight.model.checkpoint import default_model_path
        rc4 = main(["info", str(default_model_path())])  # a checkpoint: read from its export in sync beside it
        print("RC", rc1, rc2, rc3, rc4, "TORCH", "torch" in sys.modules)
    """)
    env = {k: v for k, v in os.environ.items() if k != "TEPINN_DEBUG"}
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300, env=env, cwd=tmp_path)
    assert "RC 2 0 2 0 TORCH False" in p.stdout, p.stdout + p.stderr
    assert "read from tepinn_default.onnx (in sync beside it; PyTorch is not installed)" in p.stdout
    lines = [ln for ln in p.stderr.splitlines() if ln.startswith("tepinn-flight train:")]
    assert len(lines) == 1 and "error: this needs PyTorch, which this install does not have" in lines[0], p.stderr
    assert "internal error" not in p.stderr and not (tmp_path / "run").exists()
    ran = {e["name"]: e.get("runtime") for e in json.loads((tmp_path / "rep" / "metrics.json").read_text())["estimators"]}
    assert ran["tepinn"] == "onnx" and ran["lstm"] == "onnx" and "ekf" in ran
    lines = [ln for ln in p.stderr.splitlines() if ln.startswith("tepinn-flight evaluate:")]
    assert len(lines) == 1 and "--runtime torch needs PyTorch" in lines[0] and not (tmp_path / "rep2").exists(), p.stderr
