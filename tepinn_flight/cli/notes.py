"""A command's progress notes on standard error, printed so that they do not break its progress bar."""

from __future__ import annotations

import sys
from collections.abc import Callable


def note_printer(verb: str, quiet: bool) -> Callable[[str], None] | None:
    """``say(line)`` printing ``tepinn-flight VERB: note: line`` above any progress bar (None where ``quiet``)."""
    if quiet:
        return None
    from tqdm import tqdm

    return lambda line: tqdm.write(f"tepinn-flight {verb}: note: {line}", file=sys.stderr)


def run_noting_compiles(verb: str, args, body: Callable) -> int:
    """``body(args)`` with a one-line note when numba compiles the package's loops (the first run after installing:
    :mod:`..jit_notice`), unless ``args.quiet``."""
    from ..jit_notice import compile_notice

    with compile_notice(note_printer(verb, args.quiet)):
        return body(args)
