"""Reliability: bad output paths and option values are one-line errors (exit code 2), atomic
writes clean up after killed writers, corrupt logs never yield impossible values."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from tepinn_flight.cli.main import main
from tepinn_flight.errors import OutputError
from tepinn_flight.record import atomic_write, check_output, write_record

REPO = Path(__file__).resolve().parents[1]


def cli(argv: list[str]) -> int:
    """``main(argv)``, with argparse's usage errors (SystemExit) as their exit code."""
    try:
        return main(argv)
    except SystemExit as exc:
        return int(exc.code)


def one_line_error(capsys, rc: int, command: str) -> str:
    err = capsys.readouterr().err.strip()
    assert rc == 2, err
    lines = err.splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"tepinn-flight {command}: error:"), err
    assert "internal error" not in err and "Traceback" not in err
    return lines[0]


@pytest.fixture
def record(tmp_path) -> Path:
    from tepinn_flight.model.synthetic import synthetic_record

    p = tmp_path / "rec.parquet"
    write_record(synthetic_record(seed=1, duration_s=6.0), p)
    return p


@pytest.fixture
def a_file(tmp_path) -> Path:
    p = tmp_path / "somefile.txt"
    p.write_text("not a folder\n")
    return p


# ---------------------------------------------------------------------- unwritable outputs


def _bad_outputs(a_file: Path) -> list[tuple[str, str]]:
    return [(str(a_file / "x.parquet"), "is a file, not a folder"), ("/proc/x.parquet", "cannot write")]


def test_ingest_unwritable_output(tmp_path, capsys, record, a_file):
    from tests.conftest import real_log

    log = real_log("ardusub_small.BIN")
    for out, reason in _bad_outputs(a_file):
        line = one_line_error(capsys, cli(["ingest", "-q", str(log), "-o", out]), "ingest")
        assert out in line and reason in line, line


def test_estimate_unwritable_output(capsys, record, a_file):
    for out, reason in _bad_outputs(a_file):
        line = one_line_error(capsys, cli(["estimate", "-q", str(record), "-o", out]), "estimate")
        assert out in line and reason in line, line


@pytest.mark.parametrize("value", ["-3", "x"])
def test_estimate_bad_threads(capsys, record, tmp_path, value):
    line = one_line_error(capsys, cli(["estimate", "-q", str(record), "-o", str(tmp_path / "e.parquet"),
                                        "--threads", value]), "estimate")  # fmt: skip
    assert "--threads" in line
    assert not (tmp_path / "e.parquet").exists()


def test_simulate_unwritable_output(capsys, tmp_path, a_file):
    for out, reason in _bad_outputs(a_file):  # refused before the flight is flown
        line = one_line_error(capsys, cli(["simulate", "-q", "--aircraft", "F450", "--duration", "2", "-o", out]), "simulate")
        assert out in line and reason in line, line
    tlog = str(a_file / "x.tlog")
    line = one_line_error(capsys, cli(["simulate", "-q", "--aircraft", "F450", "--duration", "2",
                                        "-o", str(tmp_path / "s.parquet"), "--tlog", tlog]), "simulate")  # fmt: skip
    assert tlog in line and not (tmp_path / "s.parquet").exists()
    camp = REPO / "flight_sims" / "campaigns" / "mixed.toml"
    line = one_line_error(capsys, cli(["simulate", "-q", "--campaign", str(camp), "-o", str(a_file / "c")]), "simulate")
    assert "is a file, not a folder" in line
    line = one_line_error(capsys, cli(["simulate", "-q", "--campaign", str(camp), "-o", str(tmp_path / "c"),
                                        "--workers", "-1"]), "simulate")  # fmt: skip
    assert "--workers" in line


def test_evaluate_unwritable_report(capsys, record, a_file):
    for out, reason in [(str(a_file / "rep"), "is a file, not a folder"), ("/proc/rep", "cannot write"),
                        (str(a_file), "not a folder")]:  # fmt: skip
        line = one_line_error(capsys, cli(["evaluate", "-q", str(record), "--no-model", "--no-peers", "--report", out]),
                              "evaluate")  # fmt: skip
        assert out in line and reason in line, line


def test_train_unwritable_output(capsys, a_file):
    out = a_file / "run"
    line = one_line_error(capsys, cli(["train", "-q", "--config", str(REPO / "train" / "tiny.toml"), "-o", str(out)]), "train")
    assert "is a file, not a folder" in line


def test_atomic_write_errors_are_output_errors(tmp_path, a_file):
    with pytest.raises(OutputError, match="is a file, not a folder"):
        atomic_write(a_file / "sub" / "x.txt", lambda tmp: Path(tmp).write_text("x"))

    def disk_full(tmp):
        raise OSError(28, "No space left on device")

    with pytest.raises(OutputError, match="No space left"):
        atomic_write(tmp_path / "y.txt", disk_full)
    assert list(tmp_path.glob(".y.txt*")) == [] and not (tmp_path / "y.txt").exists()
    with pytest.raises(OutputError, match="is a folder"):
        check_output(tmp_path)


def test_killed_write_temporaries_are_cleaned(tmp_path):
    """A hidden temporary left by a killed atomic write is removed by the next write of the same
    output; one of a writer that still runs, and other outputs' temporaries, are left alone."""
    import subprocess
    import sys

    out = tmp_path / "x.parquet"
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)
    dead_pid = int(dead.stdout)  # a process that has exited
    stale = tmp_path / f".x.parquet.{dead_pid}.abcd1234.tmp"
    stale.write_bytes(b"half a file")
    old_style = tmp_path / ".x.parquet.k3j2h1g0.tmp"  # written before temporaries carried a pid
    old_style.write_bytes(b"half")
    os.utime(old_style, (0, 0))
    live = tmp_path / f".x.parquet.{os.getppid()}.efgh5678.tmp"  # a writer that still runs
    live.write_bytes(b"in progress")
    other = tmp_path / f".y.parquet.{dead_pid}.abcd1234.tmp"
    other.write_bytes(b"another output's")
    atomic_write(out, lambda tmp: Path(tmp).write_text("done"))
    assert out.read_text() == "done"
    assert not stale.exists() and not old_style.exists()
    assert live.exists() and other.exists()


# ---------------------------------------------------------------------- impossible values


def flip_bytes(src: Path, dst: Path, fraction: float, seed: int) -> Path:
    """A copy of ``src`` with ``fraction`` of its bytes replaced by random ones (seeded)."""
    import numpy as np

    b = np.frombuffer(src.read_bytes(), np.uint8).copy()
    rng = np.random.default_rng(seed)
    idx = rng.choice(len(b), max(1, int(fraction * len(b))), replace=False)
    b[idx] = rng.integers(0, 256, len(idx), dtype=np.uint8)
    dst.write_bytes(b.tobytes())
    return dst


def assert_plausible(rec) -> None:
    import numpy as np

    from tepinn_flight.ingest import assemble as A

    g, a, m, t = rec.gyr_rad_s, rec.acc_m_s2, rec.mag_ut, rec.t_s
    assert np.all(np.isfinite(g)) and np.all(np.isfinite(a)) and np.all(np.isfinite(t))
    assert np.abs(g).max() <= A.MAX_GYRO_RAD_S and np.abs(a).max() <= A.MAX_ACC_M_S2
    mf = m[np.isfinite(m)]
    assert mf.size == 0 or np.abs(mf).max() <= A.MAX_MAG_UT
    q = rec.q_ref_wxyz
    qf = q[np.all(np.isfinite(q), axis=1)]
    assert qf.size == 0 or np.abs(np.linalg.norm(qf, axis=1) - 1).max() <= A.MAX_QUAT_NORM_ERR


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_byte_flipped_dataflash_has_no_impossible_values(tmp_path, seed):
    from tepinn_flight.errors import TepinnError
    from tepinn_flight.ingest import ingest_log
    from tests.conftest import real_log

    src = real_log("erle_pxf_copter_15-12-2014_16.BIN")
    clean = ingest_log(src)
    bad = flip_bytes(src, tmp_path / "flipped.BIN", 0.005, seed)
    try:
        rec = ingest_log(bad)
    except TepinnError:
        pytest.skip("this corruption hit the log's FMT records: a one-line error, nothing to check")
    assert_plausible(rec)
    # the flipped log spans the clean log's time, not 1e13 s, and is not split into hundreds of boots
    assert rec.t_s.max() <= clean.t_s.max() * 1.05 + 1.0
    assert rec.meta["boot_epochs"] <= 3
    n = rec.meta["implausible_samples_dropped"]
    assert n > 0 and rec.meta["corrupt_frames"] >= n
    assert any("dropped as corrupt" in s for s in rec.meta["notes"])


def test_log_with_nothing_plausible_is_one_error(tmp_path):
    import numpy as np

    from tepinn_flight.errors import NoImuData
    from tepinn_flight.ingest.assemble import build_record
    from tepinn_flight.ingest.streams import ImuStream, RawLog

    t = np.arange(100) * 0.01
    raw = RawLog(ImuStream(t, np.full((100, 3), 1e27), np.zeros((100, 3))), meta={"source_kind": "dataflash"})
    with pytest.raises(NoImuData, match="no plausible IMU samples") as e:
        build_record(raw, tmp_path / "x.bin")
    assert "\n" not in str(e.value)


# ---------------------------------------------------------------------- fuzz


FUZZ_LOGS = ["ardusub_small.BIN", "pyulog_sample_appended_multiple.ulg", "dkla_fs-batt.log"]
FUZZ_BUDGET_S = 20.0


def _mutations(data: bytes, seed: int):
    """Seeded damaged copies: bytes flipped anywhere or only past the first fifth (the data, not
    the format definitions a ULog/DataFlash log starts with), truncated, truncated + flipped."""
    import numpy as np

    rng = np.random.default_rng(seed)
    b = np.frombuffer(data, np.uint8)

    def flipped(fraction, start=0):
        c = b.copy()
        idx = start + rng.choice(len(c) - start, max(1, int(fraction * (len(c) - start))), replace=False)
        c[idx] = rng.integers(0, 256, len(idx), dtype=np.uint8)
        return c.tobytes()

    yield "flip-2%", flipped(0.02)
    yield "flip-data-0.5%", flipped(0.005, len(b) // 5)
    yield "truncated", data[: int(rng.integers(len(data) // 4, len(data)))]
    cut = flipped(0.002, len(b) // 5)
    yield "truncated+flip", cut[: int(rng.integers(len(cut) // 2, len(cut)))]


def test_fuzz_ingest_estimate_exit_0_or_2_and_plausible_records(tmp_path, capsys):
    """Damaged real logs through the CLI (in-process): exit code 0 or 2 only, never a traceback
    or an internal error, and every written record holds finite, physically possible values."""
    import time

    import numpy as np
    import pandas as pd

    from tepinn_flight.record import read_record
    from tests.conftest import REAL_LOGS

    logs = [REAL_LOGS / n for n in FUZZ_LOGS if (REAL_LOGS / n).exists()]
    if not logs:
        pytest.skip(f"no shared real logs in {REAL_LOGS} (set TEPINN_SHARED)")
    t_end = time.monotonic() + FUZZ_BUDGET_S
    cases = ok = 0
    todo = [(log, seed) for seed in range(3) for log in logs]  # every log once before any twice
    for log, seed in todo:
        for name, data in _mutations(log.read_bytes(), seed=100 * seed + logs.index(log)):
            if time.monotonic() > t_end:
                break
            case = f"{log.name}/seed {seed}/{name}"
            stem = f"{logs.index(log)}_{seed}_{name}"
            bad = tmp_path / f"{stem}{log.suffix}"
            bad.write_bytes(data)
            rec_path = tmp_path / f"{stem}.parquet"
            rc = cli(["ingest", "-q", str(bad), "-o", str(rec_path)])
            err = capsys.readouterr().err
            assert rc in (0, 2), f"{case}: ingest exit {rc}: {err}"
            assert "Traceback" not in err and "internal error" not in err, f"{case}: {err}"
            cases += 1
            ok += rc == 0
            if rc != 0:
                assert len(err.strip().splitlines()) == 1, f"{case}: {err}"
                assert not rec_path.exists()
                continue
            rec = read_record(rec_path)
            assert_plausible(rec)
            est_path = tmp_path / f"{stem}_est.parquet"
            rc = cli(["estimate", "-q", "--threads", "1", str(rec_path), "-o", str(est_path)])
            err = capsys.readouterr().err
            assert rc in (0, 2), f"{case}: estimate exit {rc}: {err}"
            assert "Traceback" not in err and "internal error" not in err, f"{case}: {err}"
            if rc == 0:
                est = pd.read_parquet(est_path)
                q = est[["q_est_w", "q_est_x", "q_est_y", "q_est_z"]].to_numpy(float)
                q = q[np.all(np.isfinite(q), axis=1)]
                assert q.size == 0 or np.abs(np.linalg.norm(q, axis=1) - 1).max() < 1e-3, case
    assert cases >= len(logs) and ok > 0, (cases, ok)


# ---------------------------------------------------------------------- smaller items


def test_checkpoint_with_python_objects_is_refused_without_torchs_unsafe_advice(tmp_path, capsys, record):
    import torch

    from tepinn_flight.model.checkpoint import CheckpointError, read_checkpoint

    bad = tmp_path / "objects.pt"
    torch.save({"thing": _Unsafe()}, bad)  # a pickled object of a class: loading it runs code
    with pytest.raises(CheckpointError) as e:
        read_checkpoint(bad)
    msg = str(e.value)
    assert "weights_only" not in msg and "\x1b[" not in msg and "\n" not in msg
    assert "not a readable checkpoint" in msg and "Python objects" in msg and "_Unsafe" in msg
    line = one_line_error(capsys, cli(["estimate", "-q", str(record), "-o", str(tmp_path / "e.parquet"),
                                       "--model", str(bad)]), "estimate")  # fmt: skip
    assert "weights_only" not in line
    garbage = tmp_path / "garbage.pt"
    garbage.write_bytes(record.read_bytes())  # a parquet file, not a checkpoint
    with pytest.raises(CheckpointError, match="not a readable checkpoint") as e:
        read_checkpoint(garbage)
    assert "weights_only" not in str(e.value)


class _Unsafe:
    pass


def test_truncated_ulog_gets_a_truncation_note(tmp_path):
    from tepinn_flight.ingest import ingest_log
    from tests.conftest import real_log

    src = real_log("pyulog_sample_px4_events.ulg")
    full = ingest_log(src)
    said = "the log ends inside a message (the logger stopped mid-write or the file was cut)"
    assert not any(said in n for n in full.meta["notes"])
    b = src.read_bytes()
    cut = tmp_path / "cut.ulg"
    cut.write_bytes(b[: int(len(b) * 0.77)])
    rec = ingest_log(cut)
    assert any(said in n for n in rec.meta["notes"]), rec.meta["notes"]
    assert 0 < len(rec) < len(full)


def _session_pids(sid: int) -> list[int]:
    """Live processes (not zombies) of a session, from /proc."""
    import os

    out = []
    for d in os.listdir("/proc"):
        if not d.isdigit():
            continue
        try:
            with open(f"/proc/{d}/stat") as f:
                st = f.read()
        except OSError:
            continue
        fields = st[st.rindex(")") + 2 :].split()
        if int(fields[3]) == sid and fields[0] != "Z":  # fields: state ppid pgrp session ...
            out.append(int(d))
    return out


def _session_ends(sid: int, timeout_s: float = 15.0) -> bool:
    """Whether every process of the session has ended within ``timeout_s``."""
    import time

    deadline = time.monotonic() + timeout_s
    while _session_pids(sid) and time.monotonic() < deadline:
        time.sleep(0.2)
    return not _session_pids(sid)


def _kill_session(sid: int) -> None:
    """SIGKILL to whatever of the session is left (a failed test leaves no process behind)."""
    import signal

    for pid in _session_pids(sid):
        os.kill(pid, signal.SIGKILL)


@pytest.mark.slow
@pytest.mark.parametrize("flight_s, repeats, reap", [(1800.0, 2, False), (20.0, 400, True)])
def test_kill_9_of_a_campaign_takes_its_workers_with_it_quietly(tmp_path, flight_s, repeats, reap):
    """kill -9 of a 2-worker campaign: its worker processes die too instead of flying their flights to the end (they
    used to run on for the rest of their flights), also while the killed process is a zombie its parent has not
    reaped yet (``kill(pid, 0)`` succeeds on one: the workers flew on); and nothing reaches the terminal after it —
    workers that finished a flight in the watchdog's half second printed the pool's ``BrokenPipeError`` tracebacks
    handing it back, and the resource tracker a warning about the pool's semaphores."""
    import os
    import signal
    import subprocess
    import sys
    import time

    if not sys.platform.startswith("linux"):
        pytest.skip("parent-death signal is Linux-only")
    camp = tmp_path / "c.toml"
    camp.write_text(f'name = "k"\nseed = 1\nduration_s = {flight_s}\nrate_hz = 400.0\n[[groups]]\naircraft = ["F450"]\n'
                    f'profiles = [{{ name = "random" }}]\nsensors = ["consumer"]\nturbulence = ["none"]\nrepeats = {repeats}\n')
    err_path = tmp_path / "stderr.txt"
    with open(err_path, "w") as err:
        proc = subprocess.Popen([sys.executable, "-m", "tepinn_flight", "simulate", "--campaign", str(camp), "-o",
                                 str(tmp_path / "out"), "--workers", "2", "--quiet"], start_new_session=True,
                                stdout=subprocess.DEVNULL, stderr=err)  # fmt: skip
    try:
        deadline = time.monotonic() + 60
        while len(_session_pids(proc.pid)) < 5 and time.monotonic() < deadline:  # main, tracker, forkserver, 2 workers
            time.sleep(0.2)
        assert len(_session_pids(proc.pid)) >= 5, "the campaign did not start its workers"
        out = tmp_path / "out"
        while reap and len(list(out.glob("*.parquet"))) < 4 and time.monotonic() < deadline:
            time.sleep(0.05)  # flights are being handed back
        time.sleep(0.2 if reap else 1.0)  # the workers are flying
        os.kill(proc.pid, signal.SIGKILL)
        if reap:
            proc.wait()
        assert _session_ends(proc.pid), "worker processes outlived the killed campaign"
        proc.wait()
        time.sleep(0.5)  # (the tracker's last words, if any)
    finally:
        _kill_session(proc.pid)
    if reap:
        assert len(list((tmp_path / "out").glob("*.parquet"))) < repeats, "it finished before the kill: the test saw nothing"
    text = err_path.read_text()
    assert "Traceback" not in text and "BrokenPipe" not in text and "leaked" not in text, text[-2000:]


@pytest.mark.slow
def test_sigterm_of_estimate_with_workers_stops_them_and_leaves_no_partial_file(tmp_path):
    """SIGTERM (what timeout, systemd and schedulers send) to ``estimate --workers 2``: it says so and exits 143, its
    workers and the pool's helpers end with it (they were left orphaned, waiting on the pool's lock, holding the
    caller's pipe open), no temporary is left, and ``--resume`` then finishes the folder."""
    import os
    import signal
    import subprocess
    import sys
    import time

    from tepinn_flight.model.synthetic import synthetic_record

    if not sys.platform.startswith("linux"):
        pytest.skip("reads the session's processes from /proc")
    src, out = tmp_path / "in", tmp_path / "out"
    src.mkdir()
    for seed in range(4):
        write_record(synthetic_record(seed=seed, duration_s=30.0, rate_hz=100.0), src / f"s{seed}.parquet")
    cmd = [sys.executable, "-m", "tepinn_flight", "estimate", str(src), "-o", str(out), "--workers", "2", "-q"]
    proc = subprocess.Popen(cmd, start_new_session=True, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 120
        while len(_session_pids(proc.pid)) < 5 and time.monotonic() < deadline:  # main, tracker, forkserver, 2 workers
            time.sleep(0.1)
        assert len(_session_pids(proc.pid)) >= 5, "the estimate did not start its workers"
        os.kill(proc.pid, signal.SIGTERM)
        _, err = proc.communicate(timeout=60)  # (returns once every process holding the pipes has ended)
        assert proc.returncode == 143 and err.strip().endswith("tepinn-flight estimate: terminated"), err
        assert _session_ends(proc.pid), "worker processes outlived the terminated estimate"
    finally:
        _kill_session(proc.pid)
    assert not (out.exists() and list(out.glob(".*"))), "a temporary was left"
    done = len(list(out.glob("*.parquet"))) if out.exists() else 0
    assert done < 4, "it finished before the signal: the test saw nothing"
    r = subprocess.run([*cmd, "--resume"], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0 and len(list(out.glob("*.parquet"))) == 4, r.stderr


def test_sigterm_in_a_command_removes_its_temporary_and_exits_143(tmp_path, capsys, monkeypatch):
    """SIGTERM while an output is being written: the temporary is removed (it stayed, hidden, before), the output
    is not made, and the command says it was terminated, exit 143; the handler before is put back."""
    import signal

    import tepinn_flight.record as rec_mod

    before = signal.getsignal(signal.SIGTERM)
    real = rec_mod.atomic_write

    def write_then_signal(path, write_fn):
        def fn(tmp):
            write_fn(tmp)
            assert Path(tmp).exists()
            os.kill(os.getpid(), signal.SIGTERM)  # (delivered here: the main thread is running Python)

        real(path, fn)

    from tepinn_flight.model.synthetic import synthetic_record

    src = tmp_path / "a.parquet"
    write_record(synthetic_record(seed=1, duration_s=6.0), src)
    out = tmp_path / "out"
    monkeypatch.setattr("tepinn_flight.record.atomic_write", write_then_signal)
    capsys.readouterr()
    rc = cli(["estimate", str(src), "-o", str(out / "e.parquet"), "--no-smooth"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 143 and err[-1] == "tepinn-flight estimate: terminated", err
    assert not list(out.iterdir()), "the temporary or a partial output stayed"
    assert signal.getsignal(signal.SIGTERM) is before


def test_atomic_write_keeps_a_link_and_writes_into_a_pipe_without_replacing_either(tmp_path):
    """``-o`` naming a symbolic link replaces its target and keeps the link; naming a FIFO (or a device, such as
    /dev/null) writes into it and leaves it a FIFO, even where the writer deletes its path on failure as
    pyarrow's ``write_table`` does (a rename onto it, before, made it a plain file; pyarrow removed /dev/full)."""
    import stat
    import threading

    import pyarrow.parquet as pq

    from tepinn_flight.model.synthetic import synthetic_record

    rec = synthetic_record(seed=1, duration_s=3.0)
    target = tmp_path / "real.parquet"
    target.write_text("old")
    link = tmp_path / "link.parquet"
    link.symlink_to(target.name)
    write_record(rec, link)
    assert link.is_symlink() and pq.read_table(target).num_rows == len(rec)

    fifo = tmp_path / "pipe"
    os.mkfifo(fifo)
    got = []
    reader = threading.Thread(target=lambda: got.append(Path(fifo).read_bytes()), daemon=True)
    reader.start()
    write_record(rec, fifo)
    reader.join(30)
    assert stat.S_ISFIFO(os.stat(fifo).st_mode) and got and got[0][:4] == b"PAR1"
    (tmp_path / "copy.parquet").write_bytes(got[0])
    assert pq.read_table(tmp_path / "copy.parquet").num_rows == len(rec)

    def fails_like_pyarrow(p):
        Path(p).write_bytes(b"x")
        os.remove(p)
        raise OSError(28, "No space left on device")

    with pytest.raises(OSError):
        atomic_write(fifo, fails_like_pyarrow)
    assert stat.S_ISFIFO(os.stat(fifo).st_mode)


def test_a_signal_while_a_pool_starts_is_raised_once_it_has():
    """``signals_held``: a SIGTERM or Ctrl-C that comes while a pool starts (whose ``__init__`` cleans up after an
    Exception, not after a KeyboardInterrupt: a resumed campaign terminated then hung) is raised when the block has
    ended, as Terminated or KeyboardInterrupt, and the handlers before are put back."""
    import signal

    from tepinn_flight.worker_processes import Terminated, signals_held, terminate_on_sigterm

    before = signal.getsignal(signal.SIGTERM), signal.getsignal(signal.SIGINT)
    ran_to_the_end = []
    with terminate_on_sigterm(), pytest.raises(Terminated):
        with signals_held():
            os.kill(os.getpid(), signal.SIGTERM)
            os.kill(os.getpid(), signal.SIGINT)
            ran_to_the_end.append(True)
    assert ran_to_the_end == [True]
    with pytest.raises(KeyboardInterrupt) as exc:
        with signals_held():
            os.kill(os.getpid(), signal.SIGINT)
    assert not isinstance(exc.value, Terminated)
    assert (signal.getsignal(signal.SIGTERM), signal.getsignal(signal.SIGINT)) == before


#: in a fresh interpreter (no resource tracker, no forkserver yet): a pool's start under ``signals_held``, then the
#: forkserver's signal mask, then a Ctrl-C sent to the process while the block runs
_POOL_START = """
import multiprocessing, multiprocessing.forkserver as fs, os, signal, sys
from tepinn_flight.worker_processes import signals_held, start_forkserver
if __name__ == "__main__":
    ctx = multiprocessing.get_context("forkserver")
    try:
        with signals_held():
            start_forkserver(ctx)
            pool = ctx.Pool(1)
            os.kill(os.getpid(), signal.SIGINT)
            fields = dict(l.split(":", 1) for l in open(f"/proc/{fs._forkserver._forkserver_pid}/status"))
            unblocked = signal.SIGINT not in signal.pthread_sigmask(signal.SIG_BLOCK, set())
            print("unblocked", unblocked, "forkserver_blocks", bool(int(fields["SigBlk"], 16) & (1 << (signal.SIGINT - 1))))
    except KeyboardInterrupt:
        print("raised after the block")
    pool.terminate()
    pool.join()
"""


#: a pool of workers busy for a minute; a second Ctrl-C arrives as its terminate begins (as `timeout`'s does: it signals
#: the command, then its whole process group); `stop_pool` must still stop the workers and return
_SECOND_CTRL_C = """
import multiprocessing, os, signal, time
from tepinn_flight.worker_processes import stop_pool, worker_init
if __name__ == "__main__":
    pool = multiprocessing.get_context("fork").Pool(2, initializer=worker_init, initargs=(os.getpid(),))
    pool.map_async(time.sleep, [60, 60])
    time.sleep(0.5)
    real = pool.terminate
    def terminate():
        os.kill(os.getpid(), signal.SIGINT)  # the second Ctrl-C, as the stopping begins
        time.sleep(0.05)
        real()
    pool.terminate = terminate
    t0 = time.monotonic()
    try:
        raise KeyboardInterrupt  # the first
    except KeyboardInterrupt:
        stop_pool(pool, stopping=True)
    print("stopped", round(time.monotonic() - t0) < 10)
"""


def test_a_second_ctrl_c_does_not_stop_a_pools_stopping():
    """Interrupted campaigns hung 3 times in 5 under `timeout -s INT` (session 58): the second SIGINT stopped
    `Pool.terminate` before it killed the workers, and the `join` after it waited for them for ever. `stop_pool`
    terminates and joins out of a signal's reach."""
    import subprocess
    import sys

    out = subprocess.run([sys.executable, "-c", _SECOND_CTRL_C], capture_output=True, text=True, timeout=120)
    assert out.stdout.split() == ["stopped", "True"], out
    assert "Traceback" not in out.stderr, out.stderr


def test_a_pools_forkserver_starts_with_ctrl_c_blocked():
    """A terminal's Ctrl-C goes to the whole process group: the campaign's forkserver, which ignores it only once it
    has imported its preload (seconds), had died of one there with a traceback and the pool's start with an
    ``EOFError`` (exit 1; session 58's review). ``start_forkserver`` spawns it with Ctrl-C blocked, which it
    inherits (after the resource tracker's start, which unblocks it around its own), and unblocks it in the main
    process at once; the Ctrl-C that came is raised once ``signals_held``'s block ends."""
    import subprocess
    import sys

    if not hasattr(__import__("signal"), "pthread_sigmask") or not Path("/proc/self/status").exists():
        pytest.skip("needs pthread_sigmask and /proc (Linux)")
    out = subprocess.run([sys.executable, "-c", _POOL_START], capture_output=True, text=True, timeout=120)
    assert out.stdout.split() == ["unblocked", "True", "forkserver_blocks", "True", "raised", "after", "the", "block"], out
    assert "Traceback" not in out.stderr, out.stderr
