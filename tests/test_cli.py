"""The command line: help, one-line errors with exit code 2, no output left behind, light imports."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

from tepinn_flight.cli.main import main
from tests.conftest import real_log


def run_cli(*args, cwd=None):
    """Run ``python -m tepinn_flight`` in a subprocess; returns (code, stdout, stderr)."""
    env = {k: v for k, v in os.environ.items() if k != "TEPINN_DEBUG"}
    p = subprocess.run([sys.executable, "-m", "tepinn_flight", *args], capture_output=True, text=True,
                       cwd=cwd, env=env, timeout=300)  # fmt: skip
    return p.returncode, p.stdout, p.stderr


def test_help_lists_subcommands():
    code, out, _ = run_cli("--help")
    assert code == 0
    for cmd in ("ingest", "info"):
        assert cmd in out


@pytest.mark.parametrize(
    "content, reason",
    [
        (b"", "empty file"),
        (os.urandom(4096), "not a ULog, DataFlash"),
        (b"time,gyr_x\n0.0,1.0\n" * 50, "not a ULog, DataFlash"),
    ],
    ids=["empty", "random-bytes", "csv"],
)
@pytest.mark.parametrize("command", ["ingest", "info"])
def test_bad_input_one_line_exit_2_nothing_written(tmp_path, content, reason, command):
    bad = tmp_path / "bad.bin"
    bad.write_bytes(content)
    out = tmp_path / "out"
    out.mkdir()
    args = [command, str(bad)] + (["-o", str(out / "x.parquet")] if command == "ingest" else [])
    code, stdout, stderr = run_cli(*args)
    assert code == 2
    lines = stderr.strip().splitlines()
    assert len(lines) == 1, stderr
    assert str(bad) in lines[0] and reason in lines[0]
    assert "Traceback" not in stderr
    assert list(out.iterdir()) == []


def test_missing_file_and_directory(tmp_path):
    code, _, err = run_cli("ingest", str(tmp_path / "nope.tlog"), "-o", str(tmp_path / "x.parquet"))
    assert code == 2 and "no such file" in err and len(err.strip().splitlines()) == 1
    code, _, err = run_cli("info", str(tmp_path))
    assert code == 2 and "directory" in err


def test_usage_error_is_one_line():
    code, _, err = run_cli("ingest")
    assert code == 2 and "error" in err and "Traceback" not in err


def test_ingest_and_info_do_not_import_torch_or_jsbsim(tmp_path):
    log = real_log("erle_pxf_copter_15-12-2014_16.BIN")
    code = (
        "import sys\n"
        "from tepinn_flight.cli.main import main\n"
        f"rc1 = main(['ingest', {str(log)!r}, '-q', '-o', {str(tmp_path / 'r.parquet')!r}])\n"
        f"rc2 = main(['info', {str(tmp_path / 'r.parquet')!r}, {str(log)!r}])\n"
        "print('RC', rc1, rc2)\n"
        "print('HEAVY', sorted(m for m in ('torch', 'jsbsim') if m in sys.modules))\n"
    )
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert "RC 0 0" in p.stdout, p.stderr
    assert "HEAVY []" in p.stdout


def test_main_returns_2_on_tepinn_error(tmp_path, capsys):
    bad = tmp_path / "x.log"
    bad.write_bytes(b"\x00" * 100)
    assert main(["info", str(bad)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1


# ----------------------------------------------------------------------------- parser hygiene

VERBS = [c for c, _ in __import__("tepinn_flight.cli.main", fromlist=["COMMANDS"]).COMMANDS]


def test_every_command_module_imports_and_every_verb_is_in_the_parser():
    """A command whose module fails to import must fail here, not vanish from the CLI."""
    import importlib

    from tepinn_flight.cli import main as cli_main

    for _, module in cli_main.COMMANDS:
        importlib.import_module(f"tepinn_flight.cli.{module}")  # an ImportError fails the test loudly
    parser = cli_main.build_parser()
    assert cli_main.UNAVAILABLE == {}
    assert cli_main.command_names(parser) == VERBS


@pytest.mark.parametrize("verb", VERBS)
def test_every_verb_has_working_help(verb, capsys):
    with pytest.raises(SystemExit) as exc:
        main([verb, "--help"])
    assert exc.value.code == 0
    out = capsys.readouterr().out
    assert out.startswith(f"usage: tepinn-flight {verb}") and "UNAVAILABLE" not in out


def test_help_via_the_module_entry_point():
    code, out, err = run_cli("estimate", "--help")
    assert code == 0 and out.startswith("usage: tepinn-flight estimate") and "--model" in out, err


@pytest.mark.parametrize(
    "argv, bad",
    [
        (["estimate", "rec.parquet", "-o", "x.parquet", "--mod", "9d"], "--mod"),  # --mode or --model: neither taken
        (["evaluate", "rec.parquet", "--report", "r", "--warm", "3"], "--warm"),  # --warmup-s
        (["benchmark", "broad", "dir", "--no-mod"], "--no-mod"),  # nested sub-parser: --no-model
        (["--vers"], "--vers"),  # the main parser: --version
    ],
    ids=["estimate", "evaluate", "benchmark-broad", "main"],
)
def test_abbreviated_options_are_refused(argv, bad, capsys):
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert "unrecognized arguments" in err and bad in err and len(err.strip().splitlines()) == 1


def test_a_command_whose_module_fails_to_import_stays_listed_and_fails_loudly(monkeypatch, capsys):
    from tepinn_flight.cli import main as cli_main

    monkeypatch.setattr(cli_main, "COMMANDS", cli_main.COMMANDS + [("ghost", "ghost_cmd_does_not_exist")])
    monkeypatch.delenv("TEPINN_DEBUG", raising=False)
    parser = cli_main.build_parser()
    assert "ghost" in cli_main.command_names(parser) and "ghost" in cli_main.UNAVAILABLE
    assert "ghost" in parser.format_help() and "UNAVAILABLE" in parser.format_help()
    assert main(["ghost", "anything", "--at-all"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "tepinn-flight ghost: error: command unavailable" in err and "ModuleNotFoundError" in err
    monkeypatch.setenv("TEPINN_DEBUG", "1")
    with pytest.raises(ImportError):
        cli_main.build_parser()


def test_estimate_warns_once_when_the_imu_is_too_slow(tmp_path, capsys):
    pytest.importorskip("torch")
    from tepinn_flight.model.synthetic import synthetic_record
    from tepinn_flight.record import write_record

    rec = synthetic_record(seed=1, duration_s=12.0, rate_hz=100.0)
    write_record(rec, tmp_path / "ok.parquet")
    rec.meta.update(estimation_ok=False, imu_rate_hz=10.0)
    write_record(rec, tmp_path / "slow.parquet")
    for name, warned in (("ok", False), ("slow", True)):
        code = main(["estimate", str(tmp_path / f"{name}.parquet"), "-o", str(tmp_path / f"{name}-est.parquet"), "-q"])
        err = capsys.readouterr().err
        assert code == 0 and (tmp_path / f"{name}-est.parquet").exists(), err
        lines = [ln for ln in err.splitlines() if "warning" in ln]
        assert len(lines) == (1 if warned else 0), err
        if warned:
            assert "slow.parquet" in lines[0] and "10.0 Hz" in lines[0] and "too slow" in lines[0]


def test_info_accepts_a_folder_like_evaluate(tmp_path, capsys):
    import json

    from tepinn_flight.model.synthetic import synthetic_record
    from tepinn_flight.record import write_record

    for seed in (1, 2):
        write_record(synthetic_record(seed=seed, duration_s=5.0, rate_hz=100.0), tmp_path / f"syn{seed}.parquet")
    (tmp_path / "notes.txt").write_text("not a record")
    assert main(["info", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert str(tmp_path / "syn1.parquet") in out and str(tmp_path / "syn2.parquet") in out and "notes.txt" not in out
    assert main(["info", str(tmp_path), "--json"]) == 0
    assert sorted(json.loads(capsys.readouterr().out)) == [str(tmp_path / "syn1.parquet"), str(tmp_path / "syn2.parquet")]
