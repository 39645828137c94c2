"""Signals and checks at a command's edges (review59): a Ctrl-C or SIGTERM while the commands' modules still import
ends in one line and 130 / 143 (a traceback, or a silent kill, before); the bridge stopped by a signal after routing
began exits 130 / 143 as every verb does (it had exited 0), and refuses a model file that is none, and an IMU rate
past reason, before it routes."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import pytest

from tepinn_flight.cli import main as cli_main
from tepinn_flight.errors import ConfigError
from tepinn_flight.worker_processes import Terminated


@pytest.mark.parametrize("exc, code, word", [(KeyboardInterrupt, 130, "interrupted"), (Terminated, 143, "terminated")])
def test_a_signal_while_the_commands_import_is_one_line(monkeypatch, capsys, exc, code, word):
    def build_parser():
        raise exc  # (the signal's exception, raised where the commands' modules import)

    monkeypatch.setattr(cli_main, "build_parser", build_parser)
    assert cli_main.main(["info", "x"]) == code
    assert capsys.readouterr().err == f"tepinn-flight: {word}\n"


def test_the_bridge_refuses_a_model_file_that_is_none_before_routing(tmp_path, capsys):
    bad = tmp_path / "notes.pt"
    bad.write_text("not a model\n")
    code = cli_main.main(["bridge", "--master", "udpin:127.0.0.1:0", "--model", str(bad), "--duration", "3", "-q"])
    err = capsys.readouterr().err
    assert code == 2 and err.startswith("tepinn-flight bridge: error:") and "notes.pt" in err  # (it had routed for the
    # whole --duration and exited 0; a longer one met the model in the worker after 8 s)


@pytest.mark.parametrize("rate", [float("inf"), 1e9, float("nan"), 1e-9, 0.0])
def test_the_bridge_refuses_an_imu_rate_past_reason(rate):
    from tepinn_flight.live.bridge import BridgeConfig

    with pytest.raises(ConfigError, match="request-imu-rate"):
        BridgeConfig(master="udpin:127.0.0.1:0", request_imu_rate_hz=rate)
    BridgeConfig(master="udpin:127.0.0.1:0", request_imu_rate_hz=400.0)  # (a sane one passes)


@pytest.mark.slow
@pytest.mark.parametrize("sig, code", [(signal.SIGINT, 130), (signal.SIGTERM, 143)])
def test_the_bridge_stopped_by_a_signal_while_routing_exits_as_every_verb_does(sig, code):
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    proc = subprocess.Popen([sys.executable, "-m", "tepinn_flight", "bridge", "--master", "udpin:127.0.0.1:0",
                             "--duration", "120", "--status-interval", "1"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)  # fmt: skip
    try:
        end = time.monotonic() + 90
        seen = ""
        while time.monotonic() < end and "estimator ready" not in seen:  # routing, the worker started
            seen += proc.stderr.readline()
        assert "estimator ready" in seen, seen
        proc.send_signal(sig)
        out, err = proc.communicate(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == code, (out, err)
    assert "Traceback" not in err


@pytest.mark.parametrize("sig, code", [(signal.SIGINT, 130), (signal.SIGTERM, 143)])
def test_replay_stopped_by_a_signal_mid_play_exits_as_every_verb_does(tmp_path, sig, code):
    """(review61: replay printed its summary and exited 0, as after the whole log)"""
    from tepinn_flight.model.synthetic import synthetic_record
    from tepinn_flight.record import write_record

    write_record(synthetic_record(seed=1, duration_s=60.0, rate_hz=100.0), tmp_path / "r.parquet")
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    proc = subprocess.Popen([sys.executable, "-m", "tepinn_flight", "replay", str(tmp_path / "r.parquet"), "--to",
                             "udpout:127.0.0.1:9"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)  # fmt: skip
    try:
        seen, end = "", time.monotonic() + 60
        while time.monotonic() < end and "playing" not in seen:
            seen += proc.stderr.readline()
        assert "playing" in seen, seen
        time.sleep(1.0)
        proc.send_signal(sig)
        out, err = proc.communicate(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == code, (out, err)
    assert "replayed" in out and "Traceback" not in err
