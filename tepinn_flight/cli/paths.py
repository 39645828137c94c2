"""Paths on the command line shared by several verbs: the records a verb reads (a folder stands for
the records in it) and the one output per input a verb writes."""

from __future__ import annotations

from pathlib import Path

from ..errors import TepinnError


def output_paths(logs: list[Path], output: str | None) -> list[Path]:
    """One output per log: ``-o`` is a file for one log, a folder for several."""
    if output is not None and len(logs) == 1 and not Path(output).is_dir() and not output.endswith(("/", "\\")):
        return [Path(output)]
    folder = Path(output) if output is not None else Path.cwd()
    names: list[Path] = []
    seen: set[str] = set()
    for log in logs:
        name = log.stem
        if name in seen:
            name = f"{log.stem}_{log.suffix.lstrip('.').lower() or 'log'}"
        k = 2
        base = name
        while name in seen:
            name, k = f"{base}_{k}", k + 1
        seen.add(name)
        names.append(folder / f"{name}.parquet")
    return names


def collect_records(items: list[str]) -> list[Path]:
    """Record paths from the command line: files as given, a folder stands for its ``*.parquet``."""
    out: list[Path] = []
    for it in items:
        p = Path(it)
        if p.is_dir():
            found = sorted(p.glob("*.parquet"))
            if not found:
                raise TepinnError("folder holds no flight records (*.parquet)", p)
            out += found
        elif p.exists():
            out.append(p)
        else:
            raise TepinnError("no such file", p)
    return out
