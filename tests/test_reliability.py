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
