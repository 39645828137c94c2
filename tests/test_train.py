"""Training infrastructure: CLI end to end, strict config, determinism, resume after a kill, DDP,
split by flight, early stopping and the time limit.

Everything runs on tiny recipes (train/tiny.toml with ``--set`` overrides: d_model 8, 12-token
windows, 3-step epochs on three 5-s closed-form synthetic flights) and on one torch thread, so runs
are bitwise reproducible; subprocesses are used only where the process boundary is the point (the
console script, a real SIGKILL, torchrun).
"""

from __future__ import annotations

import dataclasses

import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from tepinn_flight.model.fusion import FusionConfig
import pandas as pd
import pytest
import torch

from tepinn_flight.cli.main import main
from tepinn_flight.errors import ConfigError
from tepinn_flight.model import train as T
from tepinn_flight.model.checkpoint import load_model, read_checkpoint
from tepinn_flight.model.dataset import build_bank, make_batch
from tepinn_flight.model.losses import TEPINNLoss
from tepinn_flight.model.network import TEPINN
from tepinn_flight.model.synthetic import synthetic_record
from tepinn_flight.record import GYR_BIAS_COLS, FlightRecord, write_record

REPO = Path(__file__).resolve().parents[1]
TINY = REPO / "train" / "tiny.toml"
SMALL = [
    "model.d_model=8", "model.d_ff=16", "model.window_tokens=12",
    "data.synthetic_flights=3", "data.synthetic_duration_s=5.0", "data.max_val_windows=64",
    "optim.batch_size=8", "optim.steps_per_epoch=3",
]  # fmt: skip
N_EPOCHS = 6  # the reference run for determinism and resume


def small_cfg(*extra: str) -> T.TrainConfig:
    return T.load_train_config(TINY, [*SMALL, *extra])


def sets(*extra: str) -> list[str]:
    out = []
    for s in [*SMALL, *extra]:
        out += ["--set", s]
    return out


def quiet_train(cfg: T.TrainConfig, out: Path, **kw) -> dict:
    return T.train(cfg, out, config_base=TINY.parent, progress=False, log=lambda *a: None, **kw)


def weights(path: Path) -> dict[str, torch.Tensor]:
    ck = read_checkpoint(path)
    return {**ck["state_dict"], **{f"loss.{k}": v for k, v in ck["loss_state"].items()}} if "loss_state" in ck else ck["state_dict"]


def max_abs_diff(a: dict, b: dict) -> float:
    assert a.keys() == b.keys()
    return max(float((a[k].double() - b[k].double()).abs().max()) for k in a)


def metric_epochs(run: Path) -> list[int]:
    return [json.loads(line)["epoch"] for line in (run / "metrics.jsonl").read_text().splitlines()]


def env1() -> dict:
    env = dict(os.environ, OMP_NUM_THREADS="1", MKL_NUM_THREADS="1")
    env.pop("TEPINN_DEBUG", None)
    return env


def one_line_error(capsys, rc: int) -> str:
    err = capsys.readouterr().err.strip()
    assert rc == 2, err
    lines = err.splitlines()
    assert len(lines) == 1 and lines[0].startswith("tepinn-flight train: error:"), err
    return lines[0]


@pytest.fixture(autouse=True)
def one_thread():
    n = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(n)


@pytest.fixture(scope="module")
def ref_run(tmp_path_factory) -> Path:
    """An uninterrupted N-epoch run (in-process, one thread)."""
    n = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        out = tmp_path_factory.mktemp("ref") / "run"
        res = quiet_train(small_cfg(f"optim.epochs={N_EPOCHS}", "optim.early_stop_patience=100"), out)
    finally:
        torch.set_num_threads(n)
    assert res["epochs"] == N_EPOCHS and res["stop_reason"] == "epochs"
    return out


# ---------------------------------------------------------------------- 1. CLI end to end


@pytest.mark.slow
def test_cli_train_then_estimate_end_to_end(tmp_path):
    exe = shutil.which("tepinn-flight", path=str(Path(sys.executable).parent)) or shutil.which("tepinn-flight")
    assert exe, "console script tepinn-flight not installed"
    run = tmp_path / "RUN"
    p = subprocess.run([exe, "train", "--config", str(TINY), "-o", str(run), "--threads", "1", *sets("optim.epochs=2")],
                       capture_output=True, text=True, env=env1(), timeout=300)  # fmt: skip
    assert p.returncode == 0, p.stderr[-2000:]
    assert "step/s" in p.stderr or "s/step" in p.stderr, "no progress bar without -q"
    for name in ("metrics.jsonl", "last.pt", "best.pt", "model.pt", "config.json"):
        assert (run / name).is_file(), name
    assert not list(run.glob("*.tmp")) and not list(run.glob(".*.tmp"))
    assert metric_epochs(run) == [1, 2]
    for line in (run / "metrics.jsonl").read_text().splitlines():
        assert np.isfinite(json.loads(line)["val_tilt_rmse_deg"])
    cfg = json.loads((run / "config.json").read_text())
    assert cfg["model"]["d_model"] == 8 and cfg["optim"]["epochs"] == 2 and cfg["data"]["synthetic_flights"] == 3
    model, fusion, ck = load_model(run / "model.pt")  # torch.load(weights_only=True) inside
    assert model.config.d_model == 8 and model.config.window_tokens == 12
    assert max_abs_diff(model.state_dict(), read_checkpoint(run / "best.pt")["state_dict"]) == 0

    # estimate on a fresh synthetic record written with write_record
    rec = synthetic_record(seed=77, duration_s=3.0)
    src, dst = tmp_path / "rec.parquet", tmp_path / "est.parquet"
    write_record(rec, src)
    assert main(["estimate", "--model", str(run / "model.pt"), str(src), "-o", str(dst), "-q", "--threads", "1"]) == 0
    est = pd.read_parquet(dst)
    assert len(est) == len(rec)
    np.testing.assert_array_equal(est["t_s"].to_numpy(), rec.t_s)
    q = est[["q_est_w", "q_est_x", "q_est_y", "q_est_z"]].to_numpy()
    fin = np.all(np.isfinite(q), axis=1)
    np.testing.assert_allclose(np.linalg.norm(q[fin], axis=1), 1.0, atol=1e-6)
    # the recipe's [anchor] (default: on): model.pt runs the filter-anchored estimator, which
    # estimates from a segment's first sample (VQF) — the network's windows correct it later
    from tepinn_flight.model.anchor import AnchorConfig

    assert isinstance(fusion, AnchorConfig) and fusion.fusion_config == FusionConfig(**ck["fusion_config"])
    assert fin.all()


# ---------------------------------------------------------------------- 2. strict config


@pytest.mark.parametrize(
    "toml_extra, overrides, key",
    [
        ("[optim]\nepochs = 1\nlearning_rate = 0.1\n", [], "optim.learning_rate"),
        ("[modle]\nd_model = 8\n", [], "modle"),
        ("[optim]\nepochs = 'many'\n", [], "optim.epochs"),
        ("", ["optim.fooo=1"], "optim.fooo"),
        ("", ["optim.epochs=1.5"], "optim.epochs"),
        ("", ["model.d_model=true"], "model.d_model"),
        ("", ["data.gyro_bias_aug_prob=1.5"], "gyro_bias_aug_prob"),
    ],
)
def test_strict_config_one_line_error(tmp_path, capsys, toml_extra, overrides, key):
    if toml_extra.startswith("[optim]"):  # replace tiny's [optim] table (the last one) with ours
        text = TINY.read_text().partition("[optim]")[0] + toml_extra
    else:
        text = TINY.read_text() + "\n" + toml_extra
    cfg = tmp_path / "recipe.toml"
    cfg.write_text(text)
    out = tmp_path / "run"
    argv = ["train", "--config", str(cfg), "-o", str(out), "-q"]
    for s in overrides:
        argv += ["--set", s]
    line = one_line_error(capsys, main(argv))
    assert f"'{key}'" in line, line
    assert not out.exists(), "nothing may be written on a config error"


def test_minutes_with_a_recipe_is_refused_not_ignored(tmp_path, capsys):
    """``--minutes`` (the fine-tuning's time limit) beside ``--config`` was taken and ignored: the recipe ran its own
    length. One line naming the recipe's setting, nothing written."""
    out = tmp_path / "run"
    line = one_line_error(capsys, main(["train", "--config", str(TINY), "-o", str(out), "-q", "--minutes", "2"]))
    assert "--set optim.max_minutes=2" in line, line
    assert not out.exists()


def test_bad_data_folder_is_a_one_line_error(tmp_path, capsys):
    out = tmp_path / "run"
    line = one_line_error(capsys, main(["train", "--config", str(TINY), "-o", str(out), "-q", "--data", str(tmp_path / "nope")]))
    assert "not found" in line and "nope" in line
    empty = tmp_path / "empty"
    empty.mkdir()
    line = one_line_error(capsys, main(["train", "--config", str(TINY), "-o", str(out), "-q", "--data", str(empty)]))
    assert "no flight records" in line and "empty" in line
    bad = tmp_path / "bad"
    bad.mkdir()
    (bad / "x.parquet").write_bytes(b"this is not parquet")
    one_line_error(capsys, main(["train", "--config", str(TINY), "-o", str(out), "-q", "--data", str(bad)]))
    slow = tmp_path / "slow"  # a 10 Hz record: no usable windows
    r = synthetic_record(seed=3, duration_s=4.0, rate_hz=10.0)
    write_record(FlightRecord(r.data, {**r.meta, "imu_rate_hz": 10.0}), slow / "slow.parquet")
    line = one_line_error(capsys, main(["train", "--config", str(TINY), "-o", str(out), "-q", "--data", str(slow),
                                        "--set", "data.synthetic_flights=0"]))  # fmt: skip
    assert "no usable windows" in line


@pytest.mark.parametrize(
    "override, key, allowed",
    [
        ("optim.batch_size=0", "batch_size", "[1,"),  # trained NaN losses and wrote model.pt
        ("optim.epochs=-1", "epochs", "[1,"),  # wrote an untrained model.pt
        ("data.synthetic_duration_s=-12", "synthetic_duration_s", "(0,"),  # internal error + empty folder
        ("optim.steps_per_epoch=0", "steps_per_epoch", "[1,"),
        ("optim.lr=-0.1", "lr", "[0,"),
        ("optim.grad_clip=0", "grad_clip", "> 0"),
        ("optim.early_stop_patience=0", "early_stop_patience", "[1,"),
        ("optim.max_minutes=-1", "max_minutes", ">= 0"),
        ("optim.warmup_steps=-5", "warmup_steps", "[0,"),
        ("optim.weight_decay=nan", "weight_decay", "finite"),
        ("data.val_fraction=1.0", "val_fraction", "[0, 1)"),
        ("data.rate_factors=[1, 0]", "rate_factors[1]", "[1,"),
        ("data.max_val_windows=0", "max_val_windows", "[1,"),
        ("data.synthetic_flights=-1", "synthetic_flights", "[0,"),
        ("data.campaign_workers=-2", "campaign_workers", "[0,"),
        ("model.token_rate_hz=inf", "token_rate_hz", "finite"),
        ("model.n_heads=0", "n_heads", "[1,"),
        ("model.pe_min_wavelength_s=0", "pe_min_wavelength_s", "> 0"),
        ("model.pe_max_wavelength_s=0.01", "pe_max_wavelength_s", ">= 0.04"),
        ("loss.lambda_acc=-1", "lambda_acc", "[0,"),
        ("loss.acc_cauchy_rad=0", "acc_cauchy_rad", "(0,"),
        ("loss.gyro_pair_tokens=0", "gyro_pair_tokens", "[1,"),
        ("loss.gyro_pair_tokens=24", "gyro_pair_tokens", "< model.window_tokens"),
        ("calibration.feedback_windows=0", "feedback_windows", "[1,"),
        ("calibration.feedback_deadzones_deg_s=[-1.0]", "feedback_deadzones_deg_s[0]", "[0,"),
        ("fusion.bias_time_constant_s=0", "bias_time_constant_s", "> 0"),
        ("fusion.process_noise_rad2_s=-1e-4", "process_noise_rad2_s", ">= 0"),
        ("seed=-1", "seed", "[0,"),
    ],
)
def test_out_of_range_config_is_a_one_line_error(tmp_path, capsys, override, key, allowed):
    out = tmp_path / "run"
    line = one_line_error(capsys, main(["train", "--config", str(TINY), "-o", str(out), "-q", "--set", override]))
    assert f"'{key}'" in line and allowed in line, line
    assert not out.exists(), "nothing may be written on a config error"


def recipe_with(table: str, line: str) -> str:
    """train/tiny.toml with ``line`` added to ``[table]`` (the table appended where tiny has none)."""
    text = TINY.read_text()
    head = f"[{table}]\n"
    return text.replace(head, head + line + "\n") if head in text else text + f"\n{head}{line}\n"


@pytest.mark.parametrize(
    "table, line, expect",
    [
        ("loss", "base_cauchy_rad = -0.1", "'base_cauchy_rad' must be finite and in [0, 10], got -0.1"),
        ("loss", "lambda_base = inf", "'lambda_base' must be finite and in [0, 1000000], got inf"),
        ("loss", "skip_clipped = true", "unknown key 'loss.skip_clipped'"),  # removed (measured worse)
        ("model", 'encoder = "gru"', "'model.encoder' must be one of 'transformer', 'lstm', 'mlp', got 'gru'"),
        ("model", "physics = false", "centripetal needs physics = true"),  # the defaults are TE-PINN's
        ("anchor", 'mode = "7d"', "'anchor.mode' must be one of '6d', '9d', 'auto', got '7d'"),
        ("anchor", 'pull_target = "fusion"', "unknown key 'anchor.pull_target'"),  # removed (measured worse)
        ("anchor", "pull_gain = 1.5", "'pull_gain' must be finite and in [0, 1], got 1.5"),
        ("anchor", "tau_acc_s = nan", "'tau_acc_s' must be finite and > 0, got nan"),
        ("anchor", "speed_hi_m_s = 10.0", "'speed_hi_m_s' must be finite and > 20, got 10.0"),
        ("anchor", "sigma_floor_deg = -0.1", "'sigma_floor_deg' must be finite and >= 0, got -0.1"),
    ],
)
def test_bad_recipe_values_are_one_line_errors(tmp_path, capsys, table, line, expect):
    """``train --config bad.toml``: each bad value is refused in one line naming the key and what
    it may be; nothing is written."""
    bad = tmp_path / "bad.toml"
    bad.write_text(recipe_with(table, line))
    out = tmp_path / "run"
    err = one_line_error(capsys, main(["train", "--config", str(bad), "-o", str(out), "-q"]))
    assert expect in err and str(bad) in err, err
    assert not out.exists()


def test_bad_recipe_value_through_the_console_script(tmp_path):
    """The same through ``python -m tepinn_flight`` (the console script's code): one line, exit 2."""
    bad = tmp_path / "bad.toml"
    bad.write_text(recipe_with("anchor", 'mode = "7d"'))
    env = {k: v for k, v in os.environ.items() if k != "TEPINN_DEBUG"}
    p = subprocess.run([sys.executable, "-m", "tepinn_flight", "train", "--config", str(bad), "-o", str(tmp_path / "run")],
                       capture_output=True, text=True, env=env, timeout=300)  # fmt: skip
    assert p.returncode == 2 and p.stderr.count("\n") == 1 and "'anchor.mode' must be one of" in p.stderr, p.stderr


def test_estimator_configs_built_in_code_are_checked_too():
    """Not only TOML: a config built in code (or from a checkpoint's dict) is checked the same way."""
    from tepinn_flight.model.anchor import AnchorConfig
    from tepinn_flight.model.config import ModelConfig
    from tepinn_flight.model.losses import LossConfig

    for make, key in ((lambda: AnchorConfig(mode="7d"), "'mode'"), (lambda: AnchorConfig(pull_gain=float("nan")), "'pull_gain'"),
                      (lambda: ModelConfig(encoder="gru"), "'encoder'"), (lambda: LossConfig(acc_norm_tol_g=0.0), "'acc_norm_tol_g'")):  # fmt: skip
        with pytest.raises(ConfigError, match=key):
            make()


def test_recipes_in_range():
    for recipe in sorted((REPO / "train").glob("*.toml")):
        T.load_train_config(recipe)  # every shipped recipe stays valid


def test_no_windows_leaves_no_run_folder(tmp_path, capsys):
    out = tmp_path / "run"  # flights shorter than one window: found after the folder was made
    line = one_line_error(capsys, main(["train", "--config", str(TINY), "-o", str(out), "-q",
                                        "--set", "data.synthetic_duration_s=0.3"]))  # fmt: skip
    assert "no usable windows" in line
    assert not out.exists(), sorted(p.name for p in out.iterdir())


# ---------------------------------------------------------------------- 3. determinism, 6. split


@pytest.mark.slow
def test_same_seed_same_weights_bitwise(ref_run, tmp_path):
    again = tmp_path / "again"
    quiet_train(small_cfg(f"optim.epochs={N_EPOCHS}", "optim.early_stop_patience=100"), again)
    assert max_abs_diff(weights(ref_run / "last.pt"), weights(again / "last.pt")) == 0.0
    assert max_abs_diff(weights(ref_run / "model.pt"), weights(again / "model.pt")) == 0.0
    assert (ref_run / "metrics.jsonl").read_text().splitlines()[-1].split('"elapsed_s"')[0] == \
        (again / "metrics.jsonl").read_text().splitlines()[-1].split('"elapsed_s"')[0]  # fmt: skip
    other = tmp_path / "seed1"  # and the seed matters (the test could fail)
    quiet_train(small_cfg("optim.epochs=1", "seed=1"), other)
    w1 = read_checkpoint(other / "last.pt")["state_dict"]
    w0 = read_checkpoint(ref_run / "last.pt")["state_dict"]
    assert max_abs_diff(w0, w1) > 1e-3


def test_validation_split_is_by_flight(ref_run):
    for name in ("last.pt", "model.pt"):
        tr = read_checkpoint(ref_run / name)["training"]
        train_f, val_f = set(tr["train_flights"]), set(tr["val_flights"])
        assert len(train_f) == len(tr["train_flights"]) == 2 and len(val_f) == len(tr["val_flights"]) == 1
        assert not train_f & val_f
        assert train_f | val_f == {f"synthetic-{i}" for i in range(3)}
    # the recorded window counts are those of the flights named (recomputed independently)
    cfg = small_cfg()
    recs = {f"synthetic-{i}": synthetic_record(seed=i, duration_s=5.0) for i in range(3)}
    vb = build_bank([recs[f] for f in tr["val_flights"]], cfg.model, (1,), cfg.loss.gyro_pair_tokens)
    tb = build_bank([recs[f] for f in tr["train_flights"]], cfg.model, cfg.data.rate_factors, cfg.loss.gyro_pair_tokens)
    assert tr["val_windows"] == min(len(vb), cfg.data.max_val_windows) and tr["train_windows"] == len(tb)


# ---------------------------------------------------------------------- 4. resume


@pytest.mark.slow
def test_resume_after_stop_equals_uninterrupted(ref_run, tmp_path, capsys):
    run = tmp_path / "run"
    quiet_train(small_cfg("optim.epochs=2", "optim.early_stop_patience=100"), run)
    assert metric_epochs(run) == [1, 2]
    # without --resume the folder is refused (one line, exit 2), and left as it was
    before = (run / "last.pt").read_bytes()
    argv = ["train", "--config", str(TINY), "-o", str(run), "-q", "--threads", "1",
            *sets(f"optim.epochs={N_EPOCHS}", "optim.early_stop_patience=100")]  # fmt: skip
    assert "already holds a run" in one_line_error(capsys, main(argv))
    assert (run / "last.pt").read_bytes() == before
    assert main([*argv, "--resume"]) == 0
    assert "resumed from epoch 2" in capsys.readouterr().out
    assert max_abs_diff(weights(ref_run / "last.pt"), weights(run / "last.pt")) == 0.0
    assert max_abs_diff(weights(ref_run / "model.pt"), weights(run / "model.pt")) == 0.0
    assert metric_epochs(run) == list(range(1, N_EPOCHS + 1))


@pytest.mark.slow
def test_crash_while_writing_a_checkpoint_keeps_the_last_one(ref_run, tmp_path, monkeypatch):
    """A crash inside the 3rd write of last.pt (a half-written file): last.pt still holds epoch 2."""
    run = tmp_path / "run"
    real_save, calls = torch.save, []

    def flaky_save(obj, f, *a, **k):
        if Path(f).name.startswith(".last.pt."):
            calls.append(f)
            if len(calls) == 3:
                Path(f).write_bytes(b"PK\x03\x04 half a checkpoint")
                raise KeyboardInterrupt  # like a kill in the middle of the write
        return real_save(obj, f, *a, **k)

    monkeypatch.setattr(torch, "save", flaky_save)
    cfg = small_cfg(f"optim.epochs={N_EPOCHS}", "optim.early_stop_patience=100")
    with pytest.raises(KeyboardInterrupt):
        quiet_train(cfg, run)
    monkeypatch.setattr(torch, "save", real_save)
    assert read_checkpoint(run / "last.pt")["epoch"] == 2
    assert not list(run.glob(".*.tmp")), "the failed temp file is removed"
    assert metric_epochs(run) == [1, 2], "metrics.jsonl only names checkpointed epochs"
    # a kill between saving last.pt and appending its metrics line: the line is restored on resume
    lines = (run / "metrics.jsonl").read_text().splitlines()
    (run / "metrics.jsonl").write_text(lines[0] + "\n")
    quiet_train(cfg, run, resume=True)
    assert max_abs_diff(weights(ref_run / "last.pt"), weights(run / "last.pt")) == 0.0
    assert metric_epochs(run) == list(range(1, N_EPOCHS + 1))


@pytest.mark.slow
def test_sigkill_then_resume_equals_uninterrupted(ref_run, tmp_path, capsys):
    run = tmp_path / "run"
    args = ["train", "--config", str(TINY), "-o", str(run), "-q", "--threads", "1",
            *sets(f"optim.epochs={N_EPOCHS}", "optim.early_stop_patience=100")]  # fmt: skip
    proc = subprocess.Popen([sys.executable, "-m", "tepinn_flight", *args], stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE, env=env1())  # fmt: skip
    try:
        t0 = time.monotonic()
        while not (run / "last.pt").exists() and proc.poll() is None and time.monotonic() - t0 < 240:
            time.sleep(0.005)
        os.kill(proc.pid, signal.SIGKILL)
    finally:
        proc.wait(30)
    assert proc.returncode == -signal.SIGKILL, f"the run ended before the kill: {proc.stderr.read()[-1000:]!r}"
    ck = read_checkpoint(run / "last.pt")  # never half-written: always loadable
    assert 1 <= ck["epoch"] < N_EPOCHS
    assert not (run / "model.pt").exists()
    # temp files a kill may leave are never taken for checkpoints
    assert all(p.name.startswith(".") and p.suffix == ".tmp" for p in run.iterdir() if p.name not in
               {"last.pt", "best.pt", "metrics.jsonl", "config.json"})  # fmt: skip
    assert main([*args, "--resume"]) == 0
    assert max_abs_diff(weights(ref_run / "last.pt"), weights(run / "last.pt")) == 0.0
    assert max_abs_diff(weights(ref_run / "model.pt"), weights(run / "model.pt")) == 0.0
    assert metric_epochs(run) == list(range(1, N_EPOCHS + 1))


# ---------------------------------------------------------------------- 5. DDP


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.mark.slow
def test_ddp_two_processes_match_one(tmp_path):
    """torchrun, gloo, 2 CPU processes vs 1 process with the same global batch. The data mixes
    flights with a known gyro bias (synthetic) and one without (like a real log), so L_bias is a
    masked mean whose per-rank shares must hold equal numbers of bias windows."""
    extra = ("optim.epochs=2", "optim.early_stop_patience=100", "data.gyro_bias_aug_deg_s=3.0")  # augmentation dealt too
    data = tmp_path / "data"
    r = synthetic_record(seed=5, duration_s=5.0)
    write_record(FlightRecord(r.data.drop(columns=GYR_BIAS_COLS), {**r.meta, "source_file": "no-bias-5"}), data / "nb.parquet")
    one = tmp_path / "one"
    quiet_train(small_cfg(*extra), one, data_dirs=[data])
    assert "no-bias-5" in read_checkpoint(one / "last.pt")["training"]["train_flights"]
    two = tmp_path / "two"
    for attempt in range(2):  # the free port can be taken between finding it and torchrun's bind (tests run beside)
        port = _free_port()
        env = dict(env1(), MASTER_ADDR="127.0.0.1", MASTER_PORT=str(port))
        cmd = [sys.executable, "-m", "torch.distributed.run", "--nproc_per_node=2", "--master_addr=127.0.0.1",
               f"--master_port={port}", "-m", "tepinn_flight", "train", "--config", str(TINY), "-o", str(two),
               "--data", str(data), "-q", "--threads", "1", *sets(*extra)]  # fmt: skip
        p = subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=300)
        if p.returncode == 0 or not any(s in p.stderr for s in ("EADDRINUSE", "Address already in use")):
            break
        shutil.rmtree(two, ignore_errors=True)
    assert p.returncode == 0, (p.stdout[-1500:], p.stderr[-3000:])
    assert read_checkpoint(two / "last.pt")["training"]["world_size"] == 2
    a, b = weights(one / "last.pt"), weights(two / "last.pt")
    diff = max_abs_diff(a, b)
    assert diff < 1e-4, diff  # float reduction order differs; without the global loss-weight init: ~4e-3
    assert max_abs_diff({"l": a["loss.log_vars"]}, {"l": b["loss.log_vars"]}) < 1e-4
    assert metric_epochs(two) == [1, 2]
    m1 = [json.loads(x) for x in (one / "metrics.jsonl").read_text().splitlines()]
    m2 = [json.loads(x) for x in (two / "metrics.jsonl").read_text().splitlines()]
    for r1, r2 in zip(m1, m2):
        assert r2["val_tilt_rmse_deg"] == pytest.approx(r1["val_tilt_rmse_deg"], abs=1e-2)
        assert r2["L_data"] == pytest.approx(r1["L_data"], rel=1e-3)  # averaged over both ranks


def _mixed_bias_bank():
    """Two flights, one with a known gyro bias and one without (like sim + real logs)."""
    cfg = small_cfg()
    r0 = synthetic_record(seed=0, duration_s=4.0)
    r1 = synthetic_record(seed=1, duration_s=4.0)
    df = r1.data.copy()
    df[GYR_BIAS_COLS] = np.nan
    bank = build_bank([r0, FlightRecord(df, r1.meta)], cfg.model, (1,), cfg.loss.gyro_pair_tokens)
    return cfg, bank


def test_deal_to_ranks_gives_equal_bias_shares():
    cfg, bank = _mixed_bias_bank()
    rng = np.random.default_rng(0)
    for _ in range(20):
        ends = rng.choice(bank.ends, 12, replace=False)
        has = np.all(np.isfinite(bank.bias[ends]), axis=1)
        for world in (1, 2, 3, 4):
            shares = [T.deal_to_ranks(ends, has, r, world) for r in range(world)]
            assert sorted(np.concatenate(shares).tolist()) == sorted(ends.tolist())
            assert {len(s) for s in shares} == {12 // world}
            nb = [int(np.all(np.isfinite(bank.bias[s]), axis=1).sum()) for s in shares]
            assert max(nb) - min(nb) <= 1


@pytest.mark.parametrize("n_bias", [4, 3])
def test_mean_of_share_gradients_is_the_global_batch_gradient(n_bias):
    """What DDP computes (the average of the ranks' gradients) equals one process on the whole
    batch, with a masked L_bias (windows without a known bias; an even and an odd count of bias
    windows) and pairs for L_gyro; also for a split that puts every bias window on one rank."""
    cfg, bank = _mixed_bias_bank()
    torch.manual_seed(0)
    model = TEPINN(cfg.model).double()
    loss = TEPINNLoss(dataclasses.replace(cfg.loss, base_cauchy_rad=0.1), model.body).double()  # every term
    pair, k = cfg.loss.gyro_pair_tokens, cfg.model.window_tokens
    pool = bank.ends[bank.prev_ok]
    rec = bank.record_of_end[bank.prev_ok]
    rng = np.random.default_rng(1)
    ends = np.concatenate([rng.choice(pool[rec == 0], n_bias, replace=False),
                           rng.choice(pool[rec == 1], 8 - n_bias, replace=False)])  # fmt: skip
    rng.shuffle(ends)
    has = np.all(np.isfinite(bank.bias[ends]), axis=1)
    assert has.sum() == n_bias

    def batches(e):
        return (make_batch(bank, e, k, cfg.model.correction_layer, dtype=torch.float64),
                make_batch(bank, e - pair, k, cfg.model.correction_layer, dtype=torch.float64))  # fmt: skip

    def grad(step, e):
        model.zero_grad(), loss.zero_grad()
        total, _ = step(*batches(e), n_bias)
        total.backward()
        return torch.cat([p.grad.flatten() if p.grad is not None else torch.zeros(p.numel(), dtype=p.dtype)
                          for p in step.parameters()])  # fmt: skip

    one, two = T.TrainStep(model, loss, world=1), T.TrainStep(model, loss, world=2)
    with torch.no_grad():
        one(*batches(ends))  # adaptive weights from the global batch (what TrainStep arranges under DDP)
    assert bool(loss.initialised.all())
    g_all = grad(one, ends)
    dealt = [T.deal_to_ranks(ends, has, r, 2) for r in (0, 1)]
    srt = ends[np.argsort(~has, kind="stable")]
    lopsided = [srt[:4], srt[4:]]  # every bias window on rank 0
    for shares in (dealt, lopsided):
        g_ddp = 0.5 * (grad(two, shares[0]) + grad(two, shares[1]))
        torch.testing.assert_close(g_ddp, g_all, rtol=1e-9, atol=1e-12)
    # without the per-rank weighting of L_bias the lopsided split is another step (the test can fail)
    g_naive = 0.5 * (grad(one, lopsided[0]) + grad(one, lopsided[1]))
    assert float((g_naive - g_all).abs().max()) > 1e-3 * float(g_all.abs().max())


# ---------------------------------------------------------------------- 7. early stop, time limit, -q


def test_early_stop_on_a_run_that_cannot_improve(tmp_path, capsys):
    run = tmp_path / "run"
    argv = ["train", "--config", str(TINY), "-o", str(run), "-q", "--threads", "1",
            *sets("optim.epochs=20", "optim.lr=0.0", "optim.lr_physics=0.0", "optim.early_stop_patience=1",
                  "optim.max_minutes=30.0")]  # fmt: skip
    assert main(argv) == 0
    cap = capsys.readouterr()
    assert "early stop" in cap.out
    assert "step/s" not in cap.err and "%|" not in cap.err, "-q: no progress bar"
    m = [json.loads(x) for x in (run / "metrics.jsonl").read_text().splitlines()]
    assert [r["epoch"] for r in m] == [1, 2]
    assert m[0]["val_tilt_rmse_deg"] == m[1]["val_tilt_rmse_deg"]  # lr = 0: nothing moves
    assert read_checkpoint(run / "last.pt")["stale"] == 1


@pytest.mark.slow
def test_time_limit_stops_at_an_epoch_end(tmp_path):
    said = []
    res = T.train(small_cfg("optim.epochs=50", "optim.max_minutes=1e-5", "optim.early_stop_patience=100"), tmp_path / "run",
                  config_base=TINY.parent, progress=False, log=said.append)  # fmt: skip
    assert res["stop_reason"] == "time_limit" and res["epochs"] == 1
    # it says how far the budget got, and how to train longer (a slower machine trains fewer epochs within it)
    assert any("time limit" in x and "after 1 of 50 epochs" in x and "optim.max_minutes" in x for x in said), said
    assert metric_epochs(tmp_path / "run") == [1]
    assert (tmp_path / "run" / "model.pt").is_file()
    res = quiet_train(small_cfg("optim.epochs=2", "optim.max_minutes=30.0", "optim.early_stop_patience=100"), tmp_path / "r2")
    assert res["stop_reason"] == "epochs" and res["epochs"] == 2


def test_optional_training_data_is_used_when_present_and_skipped_when_missing(tmp_path, capsys):
    """`optional_records`: a real log (not a record) is ingested like `tepinn-flight ingest`
    would; a pattern that matches nothing is skipped with a note instead of failing."""
    from tepinn_flight.ingest import ingest_log
    from tepinn_flight.model.train_config import DataConfig, TrainConfig
    from tepinn_flight.model.train_data import load_records

    repo = Path(__file__).resolve().parents[1]
    cfg = TrainConfig(data=DataConfig(optional_records=("logs/*.tlog", "no-such-folder/*.hdf5")))
    recs = load_records(cfg, base=repo, progress=False)
    assert "optional training data skipped" in capsys.readouterr().err
    direct = ingest_log(repo / "logs" / "sample_f450_flips.tlog")
    assert len(recs) == 1 and len(recs[0]) == len(direct)
    np.testing.assert_array_equal(recs[0].gyr_rad_s, direct.gyr_rad_s)
    with pytest.raises(ConfigError):  # the same missing pattern as required data is an error
        load_records(TrainConfig(data=DataConfig(records=("no-such-folder/*.hdf5",))), base=repo, progress=False)


def test_device_choice(tmp_path, capsys):
    """`--device auto` trains on the CPU of a machine without CUDA; `--device cuda` there is a
    one-line error before anything is written."""
    assert T.resolve_device("cpu") == torch.device("cpu")
    assert T.resolve_device("auto") == torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if torch.cuda.is_available():
        pytest.skip("this machine has a CUDA GPU: the no-GPU error cannot be shown here")
    out = tmp_path / "run"
    line = one_line_error(capsys, main(["train", "--config", str(TINY), "-o", str(out), "-q", "--device", "cuda"]))
    assert "no CUDA GPU" in line and not out.exists()


def test_gyro_bias_augmentation_equals_a_record_with_that_bias():
    """Adding a bias to a batch is the same as recording the flight with a gyro that has it."""
    cfg = small_cfg()
    r = synthetic_record(seed=2, duration_s=6.0)
    b = np.radians([4.0, -7.0, 2.5])
    df = r.data.copy()
    df[["gyr_x_rad_s", "gyr_y_rad_s", "gyr_z_rad_s"]] += b
    df[GYR_BIAS_COLS] += b
    k = cfg.model.window_tokens
    banks = [build_bank([x], cfg.model, (1,), cfg.loss.gyro_pair_tokens) for x in (r, FlightRecord(df, r.meta))]
    ends = banks[0].ends[::7]
    aug = T.add_gyro_bias(make_batch(banks[0], ends, k, True, dtype=torch.float64), np.tile(b, (len(ends), 1)))
    ref = make_batch(banks[1], ends, k, True, dtype=torch.float64)
    for key in ("gyr", "bias_true", "acc", "q_ref"):
        torch.testing.assert_close(aug[key], ref[key], rtol=0, atol=1e-9)
    rng = np.random.default_rng(0)
    draws = T.gyro_bias_augmentation(rng, 4000, 5.0, 0.5)
    on = np.any(draws != 0, axis=1)
    assert abs(on.mean() - 0.5) < 0.03 and abs(np.degrees(draws[on].std()) - 5.0) < 0.2


def test_scale_augmentation_equals_a_record_with_those_scale_errors():
    """Scaling a batch's token means is the same as recording the flight with those scale errors,
    and the draws have the configured share and ranges."""
    cfg = small_cfg()
    r = synthetic_record(seed=3, duration_s=6.0)
    sg, sa = np.array([1.02, 0.97, 1.01]), np.array([0.81, 0.83, 0.80])
    df = r.data.copy()
    df[["gyr_x_rad_s", "gyr_y_rad_s", "gyr_z_rad_s"]] *= sg
    df[["acc_x_m_s2", "acc_y_m_s2", "acc_z_m_s2"]] *= sa
    k = cfg.model.window_tokens
    banks = [build_bank([x], cfg.model, (1,), cfg.loss.gyro_pair_tokens) for x in (r, FlightRecord(df, r.meta))]
    ends = banks[0].ends[::7]
    n = len(ends)
    aug = T.scale_sensors(make_batch(banks[0], ends, k, True, dtype=torch.float64), np.tile(sg, (n, 1)), np.tile(sa, (n, 1)))
    ref = make_batch(banks[1], ends, k, True, dtype=torch.float64)
    for key in ("gyr", "acc", "q_ref", "bias_true"):
        torch.testing.assert_close(aug[key], ref[key], rtol=0, atol=1e-9)
    g, a = T.scale_augmentation(np.random.default_rng(0), 4000, 0.2, 0.03, 0.5)
    on = np.any(a != 1.0, axis=1)
    assert abs(on.mean() - 0.5) < 0.03 and np.all(g[~on] == 1.0)
    common = a[on].mean(axis=1)
    assert 0.77 < common.min() < 0.8 and 1.2 < common.max() < 1.23  # ±20 % common, ±3 % per axis
    assert np.all(np.abs(g - 1) <= 0.03) and np.abs(g[on] - 1).max() > 0.029


def test_heldout_split_files_are_never_training_data(tmp_path, capsys):
    """Every file the split's [heldout] lists is left out, whatever glob picks it up; others stay."""
    from tepinn_flight.model.train_data import drop_heldout

    split = tmp_path / "split.toml"
    split.write_text('[heldout]\nreal_logs = ["a.BIN"]\nbroad = ["t_03.hdf5"]\n[seen]\nbroad = ["t_01.hdf5"]\n')
    paths = [tmp_path / n for n in ("a.BIN", "t_01.hdf5", "t_03.hdf5", "x.parquet")]
    assert drop_heldout(paths, split) == [paths[1], paths[3]]
    assert "2 held-out file(s)" in capsys.readouterr().err
    bad = tmp_path / "bad.toml"
    bad.write_text("[heldout\n")
    with pytest.raises(ConfigError, match="heldout_split"):
        drop_heldout(paths, bad)
    # the shipped recipes name the repository's split, and it holds out real drone logs
    import tomllib

    for recipe in ("default.toml", "lstm.toml"):
        cfg = tomllib.loads((REPO / "train" / recipe).read_text())
        held = tomllib.loads((REPO / "train" / cfg["data"]["heldout_split"]).read_text())["heldout"]
        assert held["real_logs"]


@pytest.mark.slow
def test_training_says_where_the_network_gates_act_on_its_real_validation_files(tmp_path):
    """A network out of its domain can open a gate on real motion (session 24): at the end of training the
    estimator is run on the real validation files (not the simulated ones) and says where its gates acted —
    what `estimate` with the written model says of the same file."""
    from tepinn_flight.ingest import ingest_log
    from tepinn_flight.model.estimate import estimate_anchored, gates_acted
    from tepinn_flight.model.train import train
    from tepinn_flight.model.train_config import load_train_config

    repo = Path(__file__).resolve().parents[1]
    tlog = repo / "logs" / "sample_f450_flips.tlog"
    cfg = load_train_config(TINY, ["optim.epochs=1", "optim.steps_per_epoch=3", "data.synthetic_flights=2",
                                   "data.val_fraction=0.5", f'data.optional_records=["{tlog}"]'])  # fmt: skip
    said = []
    res = train(cfg, tmp_path / "run", progress=False, log=said.append)
    val = json.loads((tmp_path / "run" / "config.json").read_text())
    lines = res.get("real_val_network_gates")
    assert lines is not None and list(lines) == ["sample_f450_flips.tlog"], (lines, val)
    model, anchor, _ = load_model(tmp_path / "run" / "model.pt")
    assert lines["sample_f450_flips.tlog"] == estimate_anchored(model, ingest_log(tlog), anchor).attrs["network_gates"]
    assert said[-1] == f"on the real validation files: {gates_acted(lines)}"


@pytest.mark.parametrize("existed", [False, True])
def test_a_run_stopped_in_its_first_epoch_leaves_no_run_folder_it_made(tmp_path, monkeypatch, existed):
    """Ctrl-C (or SIGTERM, which the CLI turns into the same) before the first checkpoint: nothing of the run is
    left — a folder this run made is removed, one the user made stays, emptied of the run's config and metrics
    (session 60: they had stayed behind)."""
    cfg = T.load_train_config(TINY)
    out = tmp_path / "run" if existed else tmp_path / "deep" / "er" / "run"  # (review60: deep/er was left behind)
    if existed:
        out.mkdir()

    def stopped(*a, **k):
        raise KeyboardInterrupt

    monkeypatch.setattr(T, "validate", stopped)
    with pytest.raises(KeyboardInterrupt):
        T.train(cfg, out, progress=False, log=lambda m: None)
    assert out.exists() == existed and (not existed or not any(out.iterdir()))
    assert existed or not (tmp_path / "deep").exists()


@pytest.mark.parametrize("epoch_s,left_s,done", [(10.0, 95.0, 3), (10.0, 5.0, 3), (7.5, 30.0, 1), (1.0, 1e6, 2),
                                                 (10.0, -4.0, 5), (0.0, 10.0, 2)])
def test_the_progress_bars_end_is_where_the_time_limit_stops_the_run(epoch_s, left_s, done):
    """`epochs_within` against the training loop's rule run forward one epoch at a time: after each epoch the run
    stops where the next one (as long as the last) would end past the limit, and never after the recipe's epochs."""
    optim = T.OptimConfig(epochs=40, max_minutes=1.0)
    n, t = done, 0.0
    while n < optim.epochs and not (t + epoch_s > left_s) and epoch_s > 0:
        n, t = n + 1, t + epoch_s
    expected = optim.epochs if epoch_s == 0 else n
    assert T.epochs_within(optim, done, epoch_s, left_s) == expected


@pytest.mark.slow
def test_a_resume_takes_only_the_recipe_that_started_the_run_and_ends_as_a_finished_run_did(tmp_path):
    """`--resume` with another recipe — another seed, learning rate — is refused in one line naming the keys (review60:
    the last epochs trained on other flights, and config.json claimed the new recipe made it all); how long it trains
    may change. A run that had stopped early is resumed as it ended: no epoch more (review60: one more, its line
    added)."""
    import torch as _torch

    run = tmp_path / "run"
    quiet_train(small_cfg("optim.epochs=2", "optim.early_stop_patience=100"), run)
    before = (run / "config.json").read_text()
    with pytest.raises(ConfigError, match=r"cannot resume .* with another recipe \(optim\.lr 0\.001 -> 0\.01; seed 0 -> 7\)"):
        quiet_train(small_cfg("optim.epochs=3", "optim.early_stop_patience=100", "seed=7", "optim.lr=0.01"), run,
                    resume=True)  # fmt: skip
    assert (run / "config.json").read_text() == before and metric_epochs(run) == [1, 2]
    # stopped early: the checkpoint's count of epochs without improvement at the patience
    ck = _torch.load(run / "last.pt", weights_only=False)
    ck["stale"] = 100
    _torch.save(ck, run / "last.pt")
    res = quiet_train(small_cfg("optim.epochs=4", "optim.early_stop_patience=100"), run, resume=True)
    assert res["stop_reason"] == "early_stop" and metric_epochs(run) == [1, 2]


def test_a_recipe_cannot_ask_for_a_batch_past_memory():
    """A batch of 10^6 windows had been accepted and taken 24 GB before the OOM killer (review60)."""
    with pytest.raises(ConfigError, match="batch_size"):
        small_cfg("optim.batch_size=1000000")
    from tepinn_flight.model.train_config import MAX_BATCH

    assert small_cfg(f"optim.batch_size={MAX_BATCH}").optim.batch_size == MAX_BATCH


def test_estimate_says_a_training_checkpoint_runs_uncalibrated(ref_run, tmp_path, capsys):
    """`estimate --model RUN/best.pt` (or last.pt) runs the network-centred fusion uncalibrated: said in a note, and
    not of RUN/model.pt (review60: the two compared as if one estimator)."""
    from tepinn_flight.record import write_record

    write_record(synthetic_record(seed=9, duration_s=5.0), tmp_path / "r.parquet")
    for name, noted in (("best.pt", True), ("last.pt", True), ("model.pt", False)):
        assert main(["estimate", str(tmp_path / "r.parquet"), "--model", str(ref_run / name), "--runtime", "torch",
                     "-o", str(tmp_path / f"e_{name}.parquet")]) == 0  # fmt: skip
        err = capsys.readouterr().err
        assert ("is a checkpoint a training run writes as it goes" in err) == noted, (name, err)
