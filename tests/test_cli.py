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
    assert code == 2 and "holds no flight records or logs" in err


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



@pytest.mark.parametrize("verb", ["train", "ablate"])
def test_data_takes_several_paths_after_one_flag_and_repeats(verb):
    """``train --init default --data LOG_OR_DIR... -o RUN_DIR`` (the issue's form): several paths after one ``--data``,
    and ``--data`` given again adds to them, in order."""
    from tepinn_flight.cli import main as cli_main

    extra = ["--init", "default"] if verb == "train" else ["--config", "train/ablation.toml"]
    args = cli_main.build_parser().parse_args([verb, *extra, "--data", "a.BIN", "b.ulg", "--data", "logs/", "-o", "r"])
    assert args.data == ["a.BIN", "b.ulg", "logs/"]
    assert args.output == "r"

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


def test_estimate_resume_skips_only_outputs_of_the_same_source_model_and_settings(tmp_path, capsys):
    """``--resume`` (a killed run over a folder goes on): an output is skipped only where it carries the key of
    this source file (name, size, time), model and settings; a touched source, other settings, a damaged output
    or one from before the key are estimated again, and without --resume everything is."""
    import os

    import pyarrow.parquet as pq

    pytest.importorskip("torch")
    from tepinn_flight.model.synthetic import synthetic_record
    from tepinn_flight.record import write_record

    src = tmp_path / "in"
    src.mkdir()
    for seed in (1, 2):
        write_record(synthetic_record(seed=seed, duration_s=12.0, rate_hz=100.0), src / f"s{seed}.parquet")
    out = tmp_path / "out"

    def run(*extra):
        capsys.readouterr()
        assert main(["estimate", str(src), "-o", str(out), *extra]) == 0
        lines = capsys.readouterr().out.splitlines()
        return {ln.split(" -> ")[0].rsplit("/", 1)[-1]: "skipped (--resume)" in ln for ln in lines if " -> " in ln}

    assert run() == {"s1.parquet": False, "s2.parquet": False}
    key = pq.read_schema(out / "s1.parquet").metadata[b"estimate_key"]
    stamp = (out / "s1.parquet").stat().st_mtime_ns
    assert run("--resume") == {"s1.parquet": True, "s2.parquet": True}
    assert (out / "s1.parquet").stat().st_mtime_ns == stamp  # not written again
    st = (src / "s1.parquet").stat()
    os.utime(src / "s1.parquet", ns=(st.st_atime_ns, st.st_mtime_ns + 1_000_000_000))  # the source changed
    assert run("--resume") == {"s1.parquet": False, "s2.parquet": True}
    assert pq.read_schema(out / "s1.parquet").metadata[b"estimate_key"] != key
    assert run("--resume", "--no-smooth") == {"s1.parquet": False, "s2.parquet": False}  # other settings
    (out / "s2.parquet").write_bytes((out / "s2.parquet").read_bytes()[:100])  # damaged (not by us: writes are atomic)
    assert run("--resume", "--no-smooth") == {"s1.parquet": True, "s2.parquet": False}
    assert run("--no-smooth") == {"s1.parquet": False, "s2.parquet": False}
    table = pq.read_table(out / "s1.parquet")  # an output written before outputs carried the key
    meta = {k: v for k, v in table.schema.metadata.items() if k != b"estimate_key"}
    pq.write_table(table.replace_schema_metadata(meta), out / "s1.parquet")
    assert run("--resume", "--no-smooth") == {"s1.parquet": False, "s2.parquet": True}


def test_several_inputs_go_to_a_folder_a_file_named_twice_is_read_once_and_tlog_takes_a_folder(tmp_path, capsys):
    """Several inputs (or a folder) with ``-o`` named as a file are refused (a folder ``est.csv`` was made); one file
    given twice (``a.parquet ./a.parquet``) is estimated once (twice before, into two outputs); ``--tlog DIR`` with
    one record writes DIR/RECORD.tlog (it was refused, naming a ``.parquet`` the user never typed)."""
    import os

    pytest.importorskip("torch")
    from tepinn_flight.model.synthetic import synthetic_record
    from tepinn_flight.record import write_record
    from tepinn_flight.tlog_writer import write_tlog

    rec = synthetic_record(seed=1, duration_s=12.0, rate_hz=100.0)
    write_record(rec, tmp_path / "a.parquet")
    cwd = os.getcwd()
    os.chdir(tmp_path)
    try:
        for out in ("est.csv", "est.parquet", "est.tlog"):
            capsys.readouterr()
            assert main(["estimate", "a.parquet", "./a.parquet", "-o", out, "-q"]) == 2
            assert "names a file" in capsys.readouterr().err and not (tmp_path / out).exists()
        assert main(["estimate", "a.parquet", "./a.parquet", str(tmp_path / "a.parquet"), "-o", "est", "-q",
                     "--no-smooth"]) == 0  # fmt: skip
        assert sorted(p.name for p in (tmp_path / "est").iterdir()) == ["a.parquet"]
    finally:
        os.chdir(cwd)
    log = tmp_path / "f.tlog"
    write_tlog(log, rec)
    (tmp_path / "tl").mkdir()
    assert main(["estimate", str(log), "-o", str(tmp_path / "e.parquet"), "--tlog", str(tmp_path / "tl"), "-q",
                 "--no-smooth"]) == 0  # fmt: skip
    assert [p.name for p in (tmp_path / "tl").iterdir()] == ["f.tlog"]


def test_estimate_yaw_zero_keeps_the_tilt_and_sets_the_heading_to_zero(tmp_path):
    """``--yaw zero`` with the shipped (filter-anchored) model: it was ignored (the output was the default one, its
    heading VQF's). Now each row has the default output's roll and pitch (scipy's Euler angles) and a heading of 0;
    ``--resume`` tells the two outputs apart."""
    import numpy as np
    import pandas as pd
    from scipy.spatial.transform import Rotation

    pytest.importorskip("torch")
    from tepinn_flight.model.synthetic import synthetic_record
    from tepinn_flight.record import EST_Q_COLS, write_record

    src = tmp_path / "s.parquet"
    write_record(synthetic_record(seed=3, duration_s=12.0, rate_hz=100.0), src)
    assert main(["estimate", str(src), "-o", str(tmp_path / "d.parquet"), "-q"]) == 0
    assert main(["estimate", str(src), "-o", str(tmp_path / "z.parquet"), "-q", "--yaw", "zero"]) == 0
    d, z = (pd.read_parquet(tmp_path / n)[EST_Q_COLS].to_numpy() for n in ("d.parquet", "z.parquet"))
    ed, ez = (Rotation.from_quat(q[:, [1, 2, 3, 0]]).as_euler("ZYX") for q in (d, z))  # yaw, pitch, roll
    assert np.abs(ed[:, 0]).max() > 0.1  # the default output has a heading to take out
    assert np.abs(ez[:, 0]).max() < 1e-9
    np.testing.assert_allclose(ez[:, 1:], ed[:, 1:], atol=1e-9)
    assert main(["estimate", str(src), "-o", str(tmp_path / "d.parquet"), "-q", "--yaw", "zero", "--resume"]) == 0
    np.testing.assert_allclose(pd.read_parquet(tmp_path / "d.parquet")[EST_Q_COLS].to_numpy(), z)  # estimated again


def test_estimates_written_inside_the_folder_are_not_taken_as_records(tmp_path, capsys):
    """``estimate -r DIR -o DIR/est``, then the same with ``--resume``: the folder's scan leaves the estimates it wrote
    there out (it took them as inputs: the second run refused to replace them, so a killed run could not be resumed),
    and ``info -r`` reads the records only."""
    pytest.importorskip("torch")
    from tepinn_flight.model.synthetic import synthetic_record
    from tepinn_flight.record import write_record

    (tmp_path / "sub").mkdir()
    write_record(synthetic_record(seed=1, duration_s=12.0, rate_hz=100.0), tmp_path / "a.parquet")
    write_record(synthetic_record(seed=2, duration_s=12.0, rate_hz=100.0), tmp_path / "sub" / "b.parquet")
    est = tmp_path / "est"
    assert main(["estimate", "-r", str(tmp_path), "-o", str(est), "--no-smooth", "-q"]) == 0
    assert sorted(p.name for p in est.iterdir()) == ["a.parquet", "b.parquet"]
    capsys.readouterr()
    assert main(["estimate", "-r", str(tmp_path), "-o", str(est), "--no-smooth", "--resume"]) == 0
    out = capsys.readouterr().out.splitlines()
    assert len(out) == 2 and all("skipped (--resume)" in ln for ln in out), out
    assert main(["info", "-r", str(tmp_path)]) == 0


def test_estimate_resume_estimates_again_where_an_offline_step_s_own_settings_changed(tmp_path, capsys, monkeypatch):
    """The offline steps' settings are module defaults no checkpoint carries (a rule changes them, as rule 21
    did the accelerometer-scale reading's): the resume key holds them, so an upgrade does not keep stale outputs."""
    import dataclasses

    pytest.importorskip("torch")
    import tepinn_flight.model.accel_scale as acs
    from tepinn_flight.model.synthetic import synthetic_record
    from tepinn_flight.record import write_record

    src = tmp_path / "s1.parquet"
    write_record(synthetic_record(seed=1, duration_s=12.0, rate_hz=100.0), src)
    out = tmp_path / "out"

    def skipped():
        capsys.readouterr()
        assert main(["estimate", str(src), "-o", str(out), "--resume"]) == 0
        return "skipped (--resume)" in capsys.readouterr().out

    assert not skipped() and skipped()
    other = dataclasses.replace(acs.AccelScaleConfig(), noise_floor_factor=2.0)
    monkeypatch.setattr(acs, "AccelScaleConfig", lambda: other)
    assert not skipped() and skipped()


def test_estimate_to_csv_reads_back_as_the_parquet_output_and_other_names_are_refused(tmp_path, capsys):
    """``-o FILE.csv`` writes the estimate as CSV (it wrote Parquet bytes under that name before): read back, the
    same columns and the same float64s as the Parquet output (NaN: ``tests/test_csv_table.py``). A name ending in
    neither is refused before any work, as is ``--resume`` with a CSV (it has no key); ``ingest`` and ``simulate``
    write records as Parquet only, ``--tlog`` a .tlog. An estimate given where a record is asked for is named as one."""
    import numpy as np
    import pandas as pd

    pytest.importorskip("torch")
    from tepinn_flight.model.synthetic import synthetic_record
    from tepinn_flight.record import write_record

    src = tmp_path / "s1.parquet"
    write_record(synthetic_record(seed=1, duration_s=12.0, rate_hz=100.0), src)
    assert main(["estimate", str(src), "-o", str(tmp_path / "e.parquet"), "--no-smooth", "-q"]) == 0
    assert main(["estimate", str(src), "-o", str(tmp_path / "e.CSV"), "--no-smooth", "-q"]) == 0
    want = pd.read_parquet(tmp_path / "e.parquet")
    assert (tmp_path / "e.CSV").read_bytes()[:4] != b"PAR1"
    got = pd.read_csv(tmp_path / "e.CSV")
    assert list(got.columns) == list(want.columns) and len(got) == len(want)
    for c in want.columns:
        assert np.array_equal(got[c].to_numpy(np.float64), want[c].to_numpy(np.float64), equal_nan=True), c
    capsys.readouterr()
    for argv, what in ((["estimate", str(src), "-o", str(tmp_path / "e.txt")], "ends in neither"),
                       (["info", str(tmp_path / "e.parquet")], "an estimate written by `tepinn-flight estimate`"),
                       (["estimate", str(src), "-o", str(tmp_path / "g.parquet"), "--tlog", str(tmp_path / "g.parquet")],
                        "name it .tlog"),
                       (["estimate", str(src), "-o", str(tmp_path / "f.csv"), "--resume"], "--resume"),
                       (["ingest", str(src), "-o", str(tmp_path / "r.csv")], "flight records as Parquet"),
                       (["simulate", "--aircraft", "F450", "--duration", "2", "-o", str(tmp_path / "f.csv")],
                        "flight records as Parquet")):  # fmt: skip
        assert main(argv) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and what in err[0] and err[0].startswith(f"tepinn-flight {argv[0]}: error:"), err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["e.CSV", "e.parquet", "s1.parquet"]


def test_no_output_replaces_an_input(tmp_path, capsys):
    """An output that is one of the run's inputs is refused (one line, exit 2) and every input is left as it was:
    ``estimate r.parquet -o r.parquet`` and ``--tlog`` naming the log (both replaced them before), a folder
    estimated into itself beside its records, ``--tlog`` naming the source tlog found next to a record (refused
    for that record), ``ingest`` onto its input."""
    import hashlib
    import shutil

    pytest.importorskip("torch")
    log = tmp_path / "sub.tlog"
    shutil.copy(real_log("ardusub_small.tlog"), log)
    rec = tmp_path / "sub.parquet"
    assert main(["ingest", str(log), "-o", str(rec), "-q"]) == 0

    def digests():
        return {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in (log, rec)}

    before = digests()
    cases = ((["estimate", str(rec), "-o", str(rec)], f"-o {rec} is the input"),
             (["estimate", str(log), "-o", str(tmp_path / "e1.parquet"), "--tlog", str(log)],
              f"--tlog {log} is the input"),
             (["estimate", str(tmp_path), "-o", str(tmp_path)], "is the input"),
             (["estimate", str(rec), "-o", str(tmp_path / "e2.parquet"), "--tlog", str(tmp_path / "." / "sub.tlog")],
              "is the source tlog"),
             (["ingest", str(rec), "-o", str(rec)], "is the input"))  # fmt: skip
    for argv, what in cases:
        capsys.readouterr()
        assert main([*argv, "-q"]) == 2, argv
        err = [ln for ln in capsys.readouterr().err.splitlines() if ": warning: " not in ln]
        assert len(err) == 1 and what in err[0] and "would replace it" in err[0], (argv, err)
        assert digests() == before, argv
    assert not (tmp_path / "e1.parquet").exists()  # refused before any work (the source next to a record: after)


@pytest.mark.slow
def test_estimate_workers_give_the_one_process_estimates_and_go_on_past_a_bad_record(tmp_path, capsys):
    """``--workers 2``: the same outputs as one process (to 1e-6: a worker runs the network on one thread),
    the records' lines in their order, and a bad record one error line (exit 2) while the others are written."""
    import numpy as np
    import pandas as pd

    from tepinn_flight.model.synthetic import synthetic_record
    from tepinn_flight.record import write_record

    names = []
    for seed in (1, 2, 3):
        write_record(synthetic_record(seed=seed, duration_s=40.0, rate_hz=100.0), tmp_path / f"syn{seed}.parquet")
        names.append(f"syn{seed}.parquet")
    (tmp_path / "bad.parquet").write_bytes(b"not a record at all")
    recs = [str(tmp_path / n) for n in ("syn1.parquet", "bad.parquet", "syn2.parquet", "syn3.parquet")]
    assert main(["estimate", *recs[:1], *recs[2:], "-o", str(tmp_path / "one")]) == 0
    capsys.readouterr()
    assert main(["estimate", *recs, "-o", str(tmp_path / "two"), "--workers", "2"]) == 2
    cap = capsys.readouterr()
    errors = [ln for ln in cap.err.splitlines() if "error" in ln]
    assert len(errors) == 1 and "bad.parquet" in errors[0], cap.err
    said = [ln.split(" -> ")[0] for ln in cap.out.splitlines() if " -> " in ln]
    assert said == [recs[0], recs[2], recs[3]]  # in the order given
    assert not (tmp_path / "two" / "bad.parquet").exists()
    for n in names:
        a, b = pd.read_parquet(tmp_path / "one" / n), pd.read_parquet(tmp_path / "two" / n)
        assert list(a.columns) == list(b.columns) and len(a) == len(b) == 4000
        np.testing.assert_allclose(b.to_numpy(), a.to_numpy(), rtol=0, atol=1e-6)


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


# ----------------------------------------------------------------------------- one real run of each verb
# Small real inputs: the Erle copter log (ArduPilot DataFlash, 50 Hz) cut to its first 26 s, a short
# simulated flight, the shipped model; each result checked against something the verb did not make.

N_CROP = 1300  # rows of the Erle record kept (the pinned rows 0 and 1266 inside)


@pytest.fixture(scope="module")
def erle(tmp_path_factory):
    """``ingest`` of the real Erle log (the verb's real run), and that record cut to N_CROP rows."""
    from tepinn_flight.ingest import ingest_log
    from tepinn_flight.record import FlightRecord, read_record, write_record

    log = real_log("erle_pxf_copter_15-12-2014_16.BIN")
    d = tmp_path_factory.mktemp("erle")
    assert main(["ingest", str(log), "-o", str(d / "full.parquet"), "-q"]) == 0
    full = read_record(d / "full.parquet")
    crop = FlightRecord(full.data.iloc[:N_CROP].reset_index(drop=True), dict(full.meta))
    write_record(crop, d / "crop.parquet")
    return {"log": log, "dir": d, "full": full, "crop": d / "crop.parquet", "direct": ingest_log(log)}


def test_ingest_real_log(erle):
    """The record ``ingest`` wrote is the log as the library reads it: 7600 IMU samples at 50 Hz,
    the autopilot's attitude as the reference, unit quaternions."""
    import numpy as np

    rec, direct = erle["full"], erle["direct"]
    assert len(rec) == 7600 and rec.meta["imu_rate_hz"] == pytest.approx(50.0, abs=0.1)
    np.testing.assert_array_equal(rec.gyr_rad_s, direct.gyr_rad_s)
    np.testing.assert_array_equal(rec.q_ref_wxyz, direct.q_ref_wxyz)
    np.testing.assert_allclose(np.linalg.norm(rec.q_ref_wxyz, axis=1), 1.0, atol=1e-6)


def test_info_real_record_and_log(erle, capsys):
    assert main(["info", str(erle["crop"]), str(erle["log"])]) == 0
    out = capsys.readouterr().out
    assert f"samples              {N_CROP}" in out and "samples              7600" in out  # the cut record, the log
    assert "ArduCopter V3.3-dev" in out and "50.0 Hz" in out


@pytest.mark.slow
def test_estimate_real_record_equals_the_pinned_estimates(erle, tmp_path):
    """The shipped model through the verb: the pinned attitudes of tests/test_pinned_estimates.py (the
    estimator without the GNSS aid and the smoothing is causal, so the cut record gives the full log's estimates), and
    σ in closed form where no gate acts (session 17's σ: σ₀² + (|ω|·Δt)²/12, c = 0, and since session 50 the aircraft
    term σ_a²; the pins hold the σ before them). The pins hold VQF fed each sample over one fixed period: the shipped checkpoint with
    ``gyro_step_weighting`` off (session 29; erle's millisecond stamps step by 19-21 ms), as a user's
    ``--model`` would carry it."""
    import math

    import numpy as np
    import pandas as pd
    import torch

    from tepinn_flight.model.checkpoint import default_model_path, read_checkpoint
    from tepinn_flight.model.streaming import TS_STEPS
    from tepinn_flight.record import read_record
    from tests.test_pinned_estimates import PINNED

    ck = read_checkpoint(default_model_path())
    ck["anchor_config"]["gyro_step_weighting"] = False
    sigma_a_deg = ck["anchor_config"]["sigma_aircraft_deg"]  # σ's aircraft term (session 50): erle names a copter
    assert sigma_a_deg > 0
    ck["anchor_config"]["sigma_acc_gain_aircraft"] = 0.0  # the causal motion term (rule 29) off: σ in closed form
    torch.save(ck, tmp_path / "unweighted.pt")
    out = tmp_path / "est.parquet"
    assert main(["estimate", str(erle["crop"]), "-o", str(out), "-q", "--no-gnss-aid", "--no-smooth",
                 "--model", str(tmp_path / "unweighted.pt")]) == 0  # fmt: skip
    est = pd.read_parquet(out)
    assert len(est) == N_CROP
    rec = read_record(erle["crop"])
    for row in (r for r in PINNED if r < N_CROP):
        q_pin, _ = PINNED[row]
        np.testing.assert_allclose(est.loc[row, ["q_est_w", "q_est_x", "q_est_y", "q_est_z"]].to_numpy(float), q_pin,
                                   rtol=0, atol=1e-9)  # fmt: skip
        seg_t = rec.t_s[rec.segment == rec.segment[row]]
        ts = float(np.median(np.diff(seg_t[: TS_STEPS + 1])))  # the filter's sample period
        want = math.sqrt(math.radians(0.45) ** 2 + float(np.sum(rec.gyr_rad_s[row] ** 2)) * ts**2 / 12
                         + math.radians(sigma_a_deg) ** 2)  # fmt: skip
        assert est.loc[row, "sigma_rad"] == pytest.approx(want, rel=1e-9)


@pytest.mark.slow
def test_evaluate_real_record_matches_an_independent_inclination_error(erle, tmp_path):
    """The report's TE-PINN inclination RMSE is the angle between the estimated and the reference
    gravity directions (scipy rotations) over the samples after the 5 s warm-up."""
    import json

    import numpy as np
    import pandas as pd
    from scipy.spatial.transform import Rotation

    from tepinn_flight.record import read_record

    assert main(["estimate", str(erle["crop"]), "-o", str(tmp_path / "est.parquet"), "-q"]) == 0
    assert main(["evaluate", str(erle["crop"]), "-o", str(tmp_path / "rep"), "--no-peers", "-q"]) == 0
    assert (tmp_path / "rep" / "report.md").exists() and (tmp_path / "rep" / "report.html").exists()
    metrics = json.loads((tmp_path / "rep" / "metrics.json").read_text())
    got = metrics["records"][0]["results"]["tepinn"]["inclination_rmse_deg"]
    rec = read_record(erle["crop"])
    q_est = pd.read_parquet(tmp_path / "est.parquet")[["q_est_w", "q_est_x", "q_est_y", "q_est_z"]].to_numpy()
    m = rec.t_s - rec.t_s[0] >= 5.0
    down = [Rotation.from_quat(q[m][:, [1, 2, 3, 0]]).inv().apply([0.0, 0.0, 1.0]) for q in (q_est, rec.q_ref_wxyz)]
    angle = np.arccos(np.clip(np.sum(down[0] * down[1], axis=1), -1.0, 1.0))
    assert got == pytest.approx(np.degrees(np.sqrt(np.mean(angle**2))), rel=1e-6)


@pytest.mark.slow
def test_simulate_a_short_flight(tmp_path, capsys):
    """JSBSim F450, 3 s at 200 Hz: the gyro agrees with rates differentiated from the true attitude."""
    import numpy as np

    from tepinn_flight.record import read_record
    from tests.consistency import rate_consistency

    out = tmp_path / "f450.parquet"
    assert main(["simulate", "--aircraft", "F450", "--duration", "3", "--rate", "200", "--seed", "3",
                 "--sensor", "tactical", "--sensor-set", "gyro.range_deg_s=2000", "-o", str(out), "-q"]) == 0  # fmt: skip
    rec = read_record(out)
    assert len(rec) == 600 and rec.meta["reference_source"] == "jsbsim-truth"
    rc = rate_consistency(rec)
    assert np.all(rc.corr[rc.moving] > 0.99)


@pytest.mark.slow
def test_train_tiny_recipe(tmp_path):
    """train/tiny.toml made smaller: model.pt is written, loads, and is the recipe's model."""
    from pathlib import Path

    from tepinn_flight.model.checkpoint import load_model
    from tepinn_flight.model.train_config import load_train_config

    tiny = Path(__file__).resolve().parents[1] / "train" / "tiny.toml"
    sets = ["model.d_model=8", "model.d_ff=16", "model.window_tokens=12", "data.synthetic_flights=3",
            "data.synthetic_duration_s=5.0", "optim.batch_size=8", "optim.steps_per_epoch=2", "optim.epochs=1"]  # fmt: skip
    argv = ["train", "--config", str(tiny), "-o", str(tmp_path / "run"), "-q"]
    for s in sets:
        argv += ["--set", s]
    assert main(argv) == 0
    model, _, ck = load_model(tmp_path / "run" / "model.pt")
    assert model.config == load_train_config(tiny, sets).model and ck["metrics"]["epoch"] == 1


@pytest.mark.slow
def test_export_the_shipped_model(tmp_path):
    """The ONNX graph carries the checkpoint's configs and gives the network's outputs."""
    import json

    import numpy as np
    import onnxruntime as ort
    import torch

    from tepinn_flight.model.checkpoint import default_model_path, load_model

    out = tmp_path / "m.onnx"
    assert main(["export", "-o", str(out), "-q"]) == 0
    sess = ort.InferenceSession(str(out), providers=["CPUExecutionProvider"])
    model, _, ck = load_model(default_model_path())
    assert json.loads(sess.get_modelmeta().custom_metadata_map["model_config"]) == ck["model_config"]
    k, rng = model.config.window_tokens, np.random.default_rng(0)
    feed = {"gyr": rng.normal(0, 0.5, (2, k, 3)), "acc": rng.normal(0, 1, (2, k, 3)) + [0, 0, -9.81],
            "count": np.full((2, k), 8.0), "t_rel": np.tile((np.arange(k) - k + 1) * 0.04, (2, 1)),
            "dt": np.full((2, k), 0.04), "mag": np.zeros((2, k, 3)), "clip": np.zeros((2, k))}  # fmt: skip
    from tepinn_flight.model.export import sensor_values
    from tepinn_flight.model.window_features import window_features

    # the graph takes the windows' features, computed outside it with the trained sensor model, and ends at the
    # heads' linear layers: the attitude is computed from its outputs and the features (the physics head)
    from tepinn_flight.model.head_physics import window_attitude

    features = window_features(model.config, sensor_values(model), *(feed[n] for n in ("gyr", "acc", "count", "t_rel", "dt", "mag", "clip")))
    names = [i.name for i in sess.get_inputs()]
    outs = [o.name for o in sess.get_outputs()]
    graph = dict(zip(outs, sess.run(outs, {n: features[n] for n in names})))
    q_onnx = window_attitude(model.config, graph, features)
    with torch.inference_mode():
        q_torch = model(*[torch.as_tensor(feed[n], dtype=torch.float32) for n in
                          ("gyr", "acc", "count", "t_rel", "dt", "mag", "clip")])["q"].numpy()  # fmt: skip
    np.testing.assert_allclose(np.abs(np.sum(q_onnx * q_torch, axis=1)), 1.0, atol=1e-5)


def test_replay_a_small_tlog(tmp_path):
    """Every frame of the tlog arrives at the UDP endpoint, unchanged and in order."""
    import time

    from tepinn_flight.model.synthetic import synthetic_record
    from tepinn_flight.tlog_writer import write_tlog
    from tests.test_replay import UdpListener, tlog_records

    path = tmp_path / "s.tlog"
    write_tlog(path, synthetic_record(seed=2, duration_s=1.0, rate_hz=100.0))
    lis = UdpListener()
    try:
        assert main(["replay", str(path), "--to", f"udpout:127.0.0.1:{lis.port}", "--speed", "4", "-q"]) == 0
        time.sleep(0.3)
    finally:
        lis.close()
    assert [d for _, d in lis.datagrams] == [fr for _, fr in tlog_records(path)]


@pytest.mark.slow
def test_ablate_two_variants_on_a_tiny_recipe(erle, tmp_path):
    """Two variants trained from train/tiny.toml, evaluated on the real record: one table row each."""
    import json
    from pathlib import Path

    from tepinn_flight.model.checkpoint import read_checkpoint

    tiny = Path(__file__).resolve().parents[1] / "train" / "tiny.toml"
    argv = ["ablate", "--config", str(tiny), "-o", str(tmp_path / "abl"), "--eval", str(erle["crop"]),
            "--variants", "full,no-uncertainty", "-q"]  # fmt: skip
    for s in ("model.d_model=8", "model.d_ff=16", "model.window_tokens=12", "data.synthetic_flights=3",
              "data.synthetic_duration_s=5.0", "optim.batch_size=8", "optim.steps_per_epoch=2", "optim.epochs=1"):
        argv += ["--set", s]
    assert main(argv) == 0
    rows = {r["variant"]: r for r in json.loads((tmp_path / "abl" / "ablation.json").read_text())}
    assert list(rows) == ["full", "no-uncertainty", "vqf"] and rows["full"]["vs_full"] == 1.0
    cfgs = {v: read_checkpoint(tmp_path / "abl" / v / "model.pt")["model_config"] for v in ("full", "no-uncertainty")}
    assert cfgs["full"]["uncertainty"] is True and cfgs["no-uncertainty"]["uncertainty"] is False  # trained as named
    table = (tmp_path / "abl" / "ablation.md").read_text()
    assert "evaluated on 1 held-out flights" in table and table.count("\n| ") == 1 + 3  # header + 3 rows


@pytest.mark.slow
def test_benchmark_broad_one_trial(capsys):
    """BROAD trial 01: the harness reproduces BROAD's published Madgwick errors on it (the verb's
    own check against the published numbers; exit 3 if it did not). Scoring every estimator on a
    trial takes minutes: tests/test_broad_benchmark.py."""
    from tests.conftest import broad_trial

    trial = broad_trial("broad_01_*.hdf5")
    code = main(["benchmark", "broad", str(trial.parent), "--pattern", trial.name, "--check-only", "-q"])
    out = capsys.readouterr().out
    assert code == 0 and "01" in out, out


@pytest.mark.slow
def test_demo_short(tmp_path):
    """The demo's report: simulated flights, TE-PINN and the baselines, a report with figures."""
    import json

    out = tmp_path / "demo"
    assert main(["demo", "-o", str(out), "--duration", "12", "--rate", "100", "-q"]) == 0
    metrics = json.loads((out / "metrics.json").read_text())
    assert "tepinn" in metrics["dataset"] and (out / "report.md").exists()


def test_option_values_that_misbehaved_are_refused_in_one_line(tmp_path, capsys):
    """``export --opset`` below 1 (0 silently wrote 17) or one torch cannot write (an internal error before), ``-o``
    under a file, ``estimate --tlog-rate inf`` (a tlog with one estimate) and ``evaluate`` with a warm-up longer
    than the record (an empty report, exit 0, numpy's warnings), ``--source-log`` for a record not from a tlog (the
    estimate was written first), EKF tuning on records with nothing to score (its first grid point reported as
    tuned), ``replay --speed inf``, ``simulate`` with ``--tlog`` naming the record: one line each, exit 2, nothing
    written."""
    pytest.importorskip("torch")
    (tmp_path / "afile").write_text("x")
    src = tmp_path / "s.parquet"
    from tepinn_flight.model.synthetic import synthetic_record
    from tepinn_flight.record import write_record

    write_record(synthetic_record(seed=1, duration_s=6.0, rate_hz=100.0), src)
    short = tmp_path / "short.parquet"  # (EKF tuning on it: nothing after the warm-up; "tuned" was reported before)
    write_record(synthetic_record(seed=2, duration_s=5.0, rate_hz=100.0), short)
    cases = ((["export", "-o", str(tmp_path / "m.onnx"), "--opset", "0"], "positive"),
             (["export", "-o", str(tmp_path / "m.onnx"), "--opset", "7"], "torch cannot export the network at this opset"),
             (["export", "-o", str(tmp_path / "afile" / "m.onnx")], "is a file, not a folder"),
             (["estimate", str(src), "-o", str(tmp_path / "e.parquet"), "--tlog", str(tmp_path / "e.tlog"),
               "--tlog-rate", "inf"], "--tlog-rate"),
             (["evaluate", str(src), "-o", str(tmp_path / "rep"), "--no-peers", "--warmup-s", "1e9"],
              "no sample left to score"),
             (["estimate", str(src), "-o", str(tmp_path / "e.parquet"), "--tlog", str(tmp_path / "e.tlog"),
               "--source-log", str(src)], "was not ingested from a tlog"),
             (["evaluate", str(src), "-o", str(tmp_path / "report.md")], "evaluate writes a report folder"),
             (["evaluate", str(src), "-o", str(tmp_path / "rep"), "--no-model", "--no-peers", "--warmup-s", "5.5",
               "--tune-ekf-on", str(short)], "EKF tuning: no sample left to score"),
             (["replay", str(src), "--to", "udpout:127.0.0.1:14999", "--speed", "inf"], "--speed"),
             (["simulate", "--aircraft", "F450", "--duration", "2", "-o", str(tmp_path / "f"), "--tlog",
               str(tmp_path / "f")], "the tlog would replace the record"))  # fmt: skip
    for argv, words in cases:
        capsys.readouterr()
        assert main([*argv, "-q"]) == 2, argv
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and words in err[0] and ": error: " in err[0], (argv, err)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["afile", "s.parquet", "short.parquet"]


def test_a_flight_too_long_to_hold_in_memory_is_refused_before_any_work(tmp_path, capsys):
    """``simulate --duration 1e6`` ran for an hour growing its rows until the machine killed it: a flight is
    made in memory, so one of more than MAX_FLIGHT_SAMPLES is one line and exit 2, alone or in a campaign."""
    from tepinn_flight.cli.main import main
    from tepinn_flight.sim.simulate import MAX_FLIGHT_SAMPLES

    out = tmp_path / "f.parquet"
    assert main(["simulate", "--aircraft", "F450", "--duration", "1e6", "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert "400,000,000 samples" in err and f"{MAX_FLIGHT_SAMPLES:,}" in err and not out.exists()
    camp = tmp_path / "c.toml"
    camp.write_text('name = "long"\nseed = 1\nduration_s = 30000.0\nrate_hz = 1000.0\n'
                    '[[groups]]\naircraft = ["F450"]\nprofiles = [{ name = "random" }]\n')
    assert main(["simulate", "--campaign", str(camp), "-o", str(tmp_path / "camp")]) == 2
    assert "30,000,000 samples" in capsys.readouterr().err
    assert not list((tmp_path / "camp").glob("**/*.parquet"))  # nothing flown
    # the bound itself is a legal flight: 10 M samples at 400 Hz pass the check (not flown here)
    from tepinn_flight.sim.simulate import check_flight_args

    check_flight_args(MAX_FLIGHT_SAMPLES / 400.0, 400.0, 0)


def test_model_default_names_the_shipped_model_in_every_verb(tmp_path, capsys):
    """`train --init default` took "default" for the shipped model; `evaluate --model default` said "no such
    checkpoint". Every verb's --model now does the same, with the shipped model's figures."""
    pytest.importorskip("torch")
    import pandas as pd

    from tepinn_flight.cli.main import main
    from tepinn_flight.model.synthetic import synthetic_record
    from tepinn_flight.record import write_record

    src = tmp_path / "s.parquet"
    write_record(synthetic_record(seed=2, duration_s=8.0, rate_hz=100.0), src)
    assert main(["estimate", str(src), "-o", str(tmp_path / "a.parquet"), "-q"]) == 0
    assert main(["estimate", str(src), "-o", str(tmp_path / "b.parquet"), "--model", "default", "-q"]) == 0
    a, b = pd.read_parquet(tmp_path / "a.parquet"), pd.read_parquet(tmp_path / "b.parquet")
    assert a.equals(b)
    assert main(["evaluate", str(src), "-o", str(tmp_path / "rep"), "--model", "default", "--no-peers", "-q"]) == 0


def test_a_log_through_a_pipe_is_one_clear_line(capsys):
    """A log is read from its start more than once: a pipe (`info <(cat f.tlog)`) is refused as such, in one line
    (session 53: it had been "not a … tlog"; a FIFO with no writer hung the command)."""
    head = real_log("ardusub_small.tlog").read_bytes()[:8192]
    r, w = os.pipe()
    try:
        os.write(w, head)
        os.close(w)
        assert main(["info", f"/dev/fd/{r}"]) == 2
    finally:
        os.close(r)
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "a pipe or a device, not a file" in err


def test_export_at_an_opset_it_cannot_write_prints_one_line_not_torchs_graph(tmp_path, capfd):
    """Below the network's opsets torch's exporter printed the whole graph (176 lines, from C++: past Python's
    streams) before our one-line error; outside torch's own range (7–23 for this torch) it is refused before any
    export. At the file descriptors: one line, exit 2, no file."""
    pytest.importorskip("torch")
    for opset, words in (("8", "torch cannot export the network at this opset"), ("99", "this torch exports opsets")):
        capfd.readouterr()
        assert main(["export", "-o", str(tmp_path / "m.onnx"), "--opset", opset]) == 2
        out, err = capfd.readouterr()
        assert out == "" and len(err.strip().splitlines()) == 1 and words in err, err[-500:]
        assert not (tmp_path / "m.onnx").exists()
