"""Shared fixtures: where the real logs live, and skips with a reason when they are absent."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
SHARED = Path(os.environ.get("TEPINN_SHARED", REPO.parent / "shared"))
REAL_LOGS = SHARED / "real-logs"
BROAD = SHARED / "broad"


def _session_folder(tmp_path_factory) -> Path:
    """A folder of this test session that every xdist worker shares (the workers' base folders' parent)."""
    base = tmp_path_factory.getbasetemp()
    return base.parent if os.environ.get("PYTEST_XDIST_WORKER") else base


_FIRST_RUN_JSON = "first-run.json"


def _cache_empty(jit_warmup) -> bool:
    """Whether none of the loops the warm-up compiles is in this checkout's numba cache (a fresh clone); a loop
    compiled as its module is imported (given its signature) does not count."""
    try:
        return all(not os.path.exists(d._cache._cache_file._index_path) for d in jit_warmup._dispatchers(filters=True)
                   if not d.signatures)  # fmt: skip
    except AttributeError:  # another numba's internals
        return False


@pytest.fixture(scope="session", autouse=True)
def _loops_compiled_once(tmp_path_factory):
    """numba's cache for this checkout filled before the first test (a fresh clone's is empty) by the warm-up the
    commands run (``tepinn_flight/jit_warmup.py``: two processes at once) and the simulation's preload, by one xdist
    worker at a time: the other waits, then finds the cache warm. Otherwise each worker compiled the same loops as its
    tests first needed them (a test paid ~40-60 s in CI that takes ~6 s on a warm cache). Where the cache is empty (a
    fresh clone, as in CI) the warm-up is the first run that ``tests/test_first_run_compile.py`` checks, its output
    kept for that test: one cold compile in CI instead of two (~80 s of a worker). Other tests of the cold cache use
    their own ``NUMBA_CACHE_DIR``."""
    if os.environ.get("NUMBA_DISABLE_JIT", "0") not in ("", "0"):
        return
    try:
        import fcntl
    except ImportError:  # not POSIX: each worker compiles as its tests need
        return
    from tepinn_flight import jit_warmup

    shared = _session_folder(tmp_path_factory)
    with open(tmp_path_factory.getbasetemp().parent / "numba-warm-up.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # (released as the file closes)
        if os.environ.get("NUMBA_CACHE_DIR") is None and _cache_empty(jit_warmup):
            import json

            from tests.test_first_run_compile import first_run

            folder = shared / "first-run"
            folder.mkdir(exist_ok=True)
            try:
                run = first_run(folder)
            except Exception as e:  # (said by the test that reads it; the warm-up below still runs)
                run = {"returncode": -1, "stdout": "", "stderr": f"the session's first run failed: {e!r}", "paths": [],
                       "cache": None}  # fmt: skip
            (shared / _FIRST_RUN_JSON).write_text(json.dumps(run))
        jit_warmup.warm_up(filters=True)
        import tepinn_flight.sim.preload  # noqa: F401  (the simulation's loops, as a campaign's forkserver loads them)


@pytest.fixture
def first_run_of_session(tmp_path_factory):
    """The first run the session's warm-up made on this checkout's empty cache (its exit status, output, records), or
    None where the cache was not empty (the test then makes its own)."""
    import json

    f = _session_folder(tmp_path_factory) / _FIRST_RUN_JSON
    return json.loads(f.read_text()) if f.exists() else None


def real_log(name: str) -> Path:
    """Path of a shared real log, or skip the test with a clear reason."""
    p = REAL_LOGS / name
    if not p.exists():
        pytest.skip(f"real log {name} not available (expected in {REAL_LOGS}; set TEPINN_SHARED)")
    return p


def broad_trial(pattern: str = "broad_01_*.hdf5") -> Path:
    hits = sorted(BROAD.glob(pattern))
    if not hits:
        pytest.skip(f"BROAD trial {pattern} not available (expected in {BROAD}; set TEPINN_SHARED)")
    return hits[0]


def estimate_says_and_stores(tmp_path, capsys, record_path, key: str, off_flag: str, phrase: str):
    """``estimate`` on ``record_path``: the offline step's line (stored under ``key`` in the output's
    metadata) is printed; with ``off_flag`` nothing about it (``phrase``) is printed or stored.
    → (the line, the estimate's frame, the frame with ``off_flag``)."""
    import pyarrow.parquet as pq

    from tepinn_flight.cli.main import main

    on_path, off_path = tmp_path / "est.parquet", tmp_path / "off.parquet"
    assert main(["estimate", str(record_path), "-o", str(on_path)]) == 0
    out = capsys.readouterr().out
    line = pq.read_schema(on_path).metadata[key.encode()].decode()
    assert line in out
    assert main(["estimate", str(record_path), "-o", str(off_path), off_flag]) == 0
    assert phrase not in capsys.readouterr().out
    assert key.encode() not in (pq.read_schema(off_path).metadata or {})
    return line, pq.read_table(on_path).to_pandas(), pq.read_table(off_path).to_pandas()
