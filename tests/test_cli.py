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


def test_the_verbs_are_the_command_modules():
    """The parser's verbs, read from the parser, are exactly the ``cli/*_cmd.py`` modules: a module
    dropped from COMMANDS (a lost command) or a verb without its module fails here."""
    from pathlib import Path

    from tepinn_flight.cli import main as cli_main

    modules = sorted(p.stem for p in (Path(cli_main.__file__).parent).glob("*_cmd.py"))
    verbs = cli_main.command_names(cli_main.build_parser())
    assert sorted(f"{v}_cmd" for v in verbs) == modules
    assert [m for _, m in cli_main.COMMANDS] == [f"{v}_cmd" for v in verbs]


def _break_import(monkeypatch, module: str):
    """Make ``cli/<module>.py`` fail to import as a bug in it would (ImportError from inside it)."""
    import importlib

    from tepinn_flight.cli import main as cli_main

    real = importlib.import_module

    def fake(name, *a, **kw):
        if name == f"tepinn_flight.cli.{module}":
            raise ImportError(f"cannot import name 'gone' from 'tepinn_flight.{module}'")
        return real(name, *a, **kw)

    monkeypatch.setattr(cli_main.importlib, "import_module", fake)
    monkeypatch.delenv("TEPINN_DEBUG", raising=False)


@pytest.mark.parametrize("argv", [["info", "--help"], ["info", "x.bin"], ["info"]], ids=["help", "run", "bare"])
def test_a_verb_whose_module_fails_to_import_fails_loudly(monkeypatch, capsys, argv):
    """A broken verb module is neither hidden nor given a usage text: the verb, --help included,
    fails with exit 1 and one line naming the module and the import error; the other verbs work."""
    from tepinn_flight.cli import main as cli_main

    _break_import(monkeypatch, "info_cmd")
    parser = cli_main.build_parser()
    assert "info" in cli_main.command_names(parser) and "BROKEN" in parser.format_help()
    assert main(argv) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("tepinn-flight info: internal error:"), err
    assert "cli/info_cmd.py failed to import" in err and "ImportError" in err and "gone" in err
    with pytest.raises(SystemExit) as exc:  # its neighbours are unaffected
        main(["ingest", "--help"])
    assert exc.value.code == 0
    monkeypatch.setenv("TEPINN_DEBUG", "1")
    with pytest.raises(ImportError):
        cli_main.build_parser()


def test_a_broken_verb_fails_the_help_check(monkeypatch, capsys):
    """The check every verb's --help gets above fails for a broken module (it cannot pass by
    printing a stand-in usage text)."""
    _break_import(monkeypatch, "export_cmd")
    with pytest.raises((AssertionError, pytest.fail.Exception)):  # "DID NOT RAISE SystemExit": main returned 1
        test_every_verb_has_working_help("export", capsys)


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
