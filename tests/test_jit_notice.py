"""The one-line notice while numba compiles the package's loops (first run after installing): said once when
something compiles, not when the loops load from the cache, not for other packages' functions, not in quiet mode
(for ``estimate``: ``tests/test_first_run_compile.py``, with the first run's other checks; for
``simulate``: ``tests/test_quad_flight_kernel.py``, with its loop's signature count). Each case runs in a fresh
process with its own ``NUMBA_CACHE_DIR`` (numba reads it at import), so the cache state is known."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap

from tepinn_flight.jit_notice import COMPILE_NOTICE

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

_PROBE = textwrap.dedent("""
    import numpy as np
    from numba import njit
    from tepinn_flight.jit_notice import compile_notice
    from tepinn_flight.small_linalg import symmetrize

    @njit
    def not_ours(x):
        return x + 1

    lines = []
    with compile_notice(lines.append):
        not_ours(1.0)  # compiled, but not one of tepinn_flight's loops
        print("after other", len(lines))
        symmetrize(np.ones((2, 2)))
        symmetrize(np.ones((3, 3)))  # the same signature: nothing new compiled
        symmetrize(np.ones((2, 2), np.float32))  # a second compile: still one notice
    symmetrize(np.ones((2, 2), np.int64))  # outside the block: silent
    print("lines", len(lines))
    print(lines[0] if lines else "")
""")


def _run(code_or_args, cache, module=False):
    env = {**os.environ, "NUMBA_CACHE_DIR": str(cache), "PYTHONPATH": REPO}
    env.pop("NUMBA_DISABLE_JIT", None)
    cmd = [sys.executable, "-m", "tepinn_flight", *code_or_args] if module else [sys.executable, "-c", code_or_args]
    p = subprocess.run(cmd, capture_output=True, text=True, env=env, cwd=REPO, timeout=600)
    return p


def test_notice_once_on_compile_and_not_on_a_cache_load(tmp_path):
    first = _run(_PROBE, tmp_path / "cache")
    assert first.returncode == 0, first.stderr
    out = first.stdout.splitlines()
    assert out[0] == "after other 0"  # another package's function compiling is not announced
    assert out[1] == "lines 1"
    assert out[2] == COMPILE_NOTICE
    again = _run(_PROBE, tmp_path / "cache")  # the same cache: every signature loads, nothing compiles
    assert again.returncode == 0, again.stderr
    assert again.stdout.splitlines()[1] == "lines 0"


def test_a_campaign_announces_the_compile_its_workers_do(monkeypatch, tmp_path, capsys):
    """The campaign's workers compile in their forkserver, which this process cannot watch: where the simulation's
    loop is not in numba's cache the command says so before the flights start, and not where it is."""
    from types import SimpleNamespace

    from tepinn_flight import jit_warmup
    from tepinn_flight.cli import simulate_cmd
    from tepinn_flight.sim import campaign

    said = []
    monkeypatch.setattr(campaign, "run_campaign", lambda *a, **k: said.append("ran") or SimpleNamespace(
        failed=[], total=0, computed=0, skipped=0, wall_s=0.0, flight_s=0.0))  # fmt: skip
    args = SimpleNamespace(list=False, campaign="c.toml", output=str(tmp_path / "out"), workers=1, quiet=False, seed=None,
                           **{n: None for n in simulate_cmd._SINGLE_ONLY})  # fmt: skip
    for is_cold in (True, False):
        monkeypatch.setattr(jit_warmup, "cold", lambda d, c=is_cold: c)
        assert simulate_cmd.run(args) == 0
        err = capsys.readouterr().err
        assert (COMPILE_NOTICE in err) == is_cold, err
    assert said == ["ran", "ran"]
