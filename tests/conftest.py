"""Shared fixtures: where the real logs live, and skips with a reason when they are absent."""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
SHARED = Path(os.environ.get("TEPINN_SHARED", REPO.parent / "shared"))
REAL_LOGS = SHARED / "real-logs"
BROAD = SHARED / "broad"


def _session_folder(tmp_path_factory) -> Path:
    """A folder of this test session that every xdist worker shares (the workers' base folders' parent)."""
    base = tmp_path_factory.getbasetemp()  # (a worker's is <the session's>/popen-gwN; a pytest started inside a
    # worker inherits PYTEST_XDIST_WORKER but not that folder: it keeps its own, review65)
    return base.parent if os.environ.get("PYTEST_XDIST_WORKER") and base.name.startswith("popen-") else base


_FIRST_RUN_JSON = "first-run.json"
_FIRST_FLIGHTS_JSON = "first-flights.json"
_RUNTIME_VENV_JSON = "runtime-venv.json"


def _never_compiled(dispatchers) -> bool:
    """Whether none of these loops is in this checkout's numba cache (a fresh clone); a loop compiled as its module is
    imported (given its signature) does not count."""
    try:
        return all(not os.path.exists(d._cache._cache_file._index_path) for d in dispatchers if not d.signatures)
    except AttributeError:  # another numba's internals
        return False


def _estimator_warm_up(shared: Path, want_venv: bool) -> None:
    """The estimator's loops: on this checkout's empty cache, the first run that ``tests/test_first_run_compile.py``
    checks (its output kept for that test), then the warm-up the commands run (two processes at once)."""
    from tepinn_flight import jit_warmup

    if os.environ.get("NUMBA_CACHE_DIR") is None and _never_compiled(jit_warmup._dispatchers()):
        from tests.test_first_run_compile import first_run

        folder = shared / "first-run"
        folder.mkdir(exist_ok=True)
        try:
            run = first_run(folder)
        except Exception as e:  # (said by the test that reads it; the warm-up below still runs)
            run = {"returncode": -1, "stdout": "", "stderr": f"the session's first run failed: {e!r}", "paths": [],
                   "cache": None}  # fmt: skip
        (shared / _FIRST_RUN_JSON).write_text(json.dumps(run))
    jit_warmup.warm_up()


def _simulation_and_filters_warm_up(shared: Path, want_venv: bool) -> None:
    """The simulation's loops: on this checkout's empty cache, the first flights that
    ``tests/test_quad_flight_kernel.py`` checks (their output kept for that test), then the campaign's preload; and the
    baseline filters ``evaluate`` runs. None of these loops is the estimator's (so the estimator's first run, beside
    it, still finds its own cold). On the empty cache then also the runtime extra's venv that
    ``tests/test_onnx_runtime.py`` runs (``tests/runtime_venv.py``) where that test is to run (``want_venv``): the
    estimator's first run takes the longer."""
    from tepinn_flight.sim import quad_flight_kernel

    fresh = os.environ.get("NUMBA_CACHE_DIR") is None and _never_compiled([quad_flight_kernel.fly_quad])
    if fresh:
        from tests.test_quad_flight_kernel import first_flights

        try:
            run = first_flights(shared / "first-flights.parquet")
        except Exception as e:
            run = {"returncode": -1, "stdout": "", "stderr": f"the session's first flights failed: {e!r}", "cache": None}
        (shared / _FIRST_FLIGHTS_JSON).write_text(json.dumps(run))
    import tepinn_flight.sim.preload  # noqa: F401  (the simulation's loops, as a campaign's forkserver loads them)
    from tepinn_flight import jit_warmup

    jit_warmup.warm_filters()
    if fresh and want_venv:  # a fresh clone: this worker would wait for the estimator's first run; it builds the venv
        from tests.runtime_venv import build_runtime_venv

        try:
            built = build_runtime_venv(shared / "runtime")
        except Exception as e:  # (said by the test that reads it)
            built = {"skip": None, "venv": None, "returncode": -1, "stderr": f"the session's venv build failed: {e!r}"}
        (shared / _RUNTIME_VENV_JSON).write_text(json.dumps(built))


#: the session's two warm-ups, each the job of the first xdist worker free to take it (a file lock, and a file saying
#: it is done); one process alone runs them in this order (the estimator's first run flies a record: the simulation's
#: loop would be warm before its own first flights)
_WARM_UPS = (("simulation", _simulation_and_filters_warm_up), ("estimator", _estimator_warm_up))


@pytest.fixture(scope="session", autouse=True)
def _loops_compiled_once(tmp_path_factory, request):
    """numba's cache for this checkout filled before the first test (a fresh clone's is empty): the estimator's loops
    by the warm-up the commands run (``tepinn_flight/jit_warmup.py``), the simulation's and the baseline filters' by
    their preloads. The two warm-ups run side by side, one per xdist worker (the first run's estimate keeps one core
    busy for most of its minute: the other had waited for it, then compiled the rest alone); a worker then waits for the
    other's before its first test. Otherwise each worker compiled the same loops as its tests first needed them (a test
    paid ~40-60 s in CI that takes ~6 s on a warm cache). Where the cache is empty (a fresh clone, as in CI) the
    warm-ups are the first runs that ``tests/test_first_run_compile.py`` and ``tests/test_quad_flight_kernel.py`` check,
    their outputs kept for those tests: one cold compile in CI instead of two. Other tests of the cold cache use their
    own ``NUMBA_CACHE_DIR``."""
    if os.environ.get("NUMBA_DISABLE_JIT", "0") not in ("", "0"):
        return
    try:
        import fcntl
    except ImportError:  # not POSIX: each worker compiles as its tests need
        return
    shared = _session_folder(tmp_path_factory)  # (this session's: its locks and the jobs' done marks)
    want_venv = any(item.name.startswith("test_fresh_venv_runtime_extra") for item in request.session.items)

    def run(name, job, wait: bool) -> None:
        with open(shared / f"numba-warm-up-{name}.lock", "w") as lock:
            try:
                fcntl.flock(lock, fcntl.LOCK_EX | (0 if wait else fcntl.LOCK_NB))  # (released as the file closes)
            except BlockingIOError:  # the other worker's job now: waited for below
                return
            done = shared / f"numba-warm-up-{name}.done"
            if not done.exists():
                try:
                    job(shared, want_venv)
                finally:
                    done.touch()

    for name, job in _WARM_UPS:  # the first job free, then the other's end (or the job itself, where none took it)
        run(name, job, wait=False)
    for name, job in _WARM_UPS:
        run(name, job, wait=True)


def _session_result(tmp_path_factory, name: str):
    """A warm-up's result this session kept for a test (its JSON), or None where it made none."""
    f = _session_folder(tmp_path_factory) / name
    return json.loads(f.read_text()) if f.exists() else None


@pytest.fixture
def first_run_of_session(tmp_path_factory):
    """The first run the session's warm-up made on this checkout's empty cache (its exit status, output, records), or
    None where the cache was not empty (the test then makes its own)."""
    return _session_result(tmp_path_factory, _FIRST_RUN_JSON)


@pytest.fixture
def first_flights_of_session(tmp_path_factory):
    """The first flights the session's warm-up flew on this checkout's empty cache (``first_flights``' output), or None
    where the cache was not empty (the test then flies its own)."""
    return _session_result(tmp_path_factory, _FIRST_FLIGHTS_JSON)


@pytest.fixture
def runtime_venv_of_session(tmp_path_factory):
    """The runtime extra's venv the session's warm-up built (``tests/runtime_venv.py``'s result), or None where it
    built none (the test then builds its own)."""
    return _session_result(tmp_path_factory, _RUNTIME_VENV_JSON)


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
