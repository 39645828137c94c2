"""Paths on the command line shared by several verbs: the records a verb reads (a folder stands for
the records and logs in it) and the one output per input a verb writes."""

from __future__ import annotations

from pathlib import Path


#: names that are files, not folders: outputs written under one of them would make a folder so named
FILE_SUFFIXES = (".parquet", ".pq", ".csv", ".tlog", ".md", ".html", ".json", ".png")


def check_folder_name(output, needs: str) -> None:
    """A :class:`~..errors.ConfigError` where ``output``, given where a folder is made, is named as a file (it made
    a folder ``est.csv``, a ``report.md/report.md``); ``needs`` says why a folder."""
    from ..errors import ConfigError

    if not Path(output).is_dir() and Path(output).suffix.lower() in FILE_SUFFIXES:
        raise ConfigError(f"-o {output} names a file; {needs}: give a folder name")


def output_paths(logs: list[Path], output: str | None, from_folder: bool = False) -> list[Path]:
    """One output per log: ``-o`` is a file for one log, a folder for several (or where ``from_folder``: the logs
    came from a folder, or from several items, given on the command line, however many it held). A name with a
    file's suffix for a folder is a :class:`~..errors.ConfigError` (it made a folder named ``est.csv``)."""
    if (output is not None and len(logs) == 1 and not from_folder and not Path(output).is_dir()
            and not output.endswith(("/", "\\"))):
        return [Path(output)]
    if output is not None:
        check_folder_name(output, "the outputs of several inputs, or of a folder, go to a folder")
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


#: an output file's name → the format written: Parquet (``.parquet``, ``.pq`` or no suffix) or CSV
TABLE_SUFFIXES = {"": "parquet", ".parquet": "parquet", ".pq": "parquet", ".csv": "csv"}


def output_format(path: Path, verb: str, csv: bool = False) -> str:
    """The format ``path``'s name asks for: ``"parquet"``, or ``"csv"`` where the verb writes CSV (``csv``). Any other
    suffix is a :class:`~..errors.ConfigError` before any work: a file named ``.csv`` (or ``.txt``) holding Parquet
    bytes is of no use to whoever opens it."""
    from ..errors import ConfigError

    fmt = TABLE_SUFFIXES.get(Path(path).suffix.lower())
    if fmt == "parquet" or (fmt == "csv" and csv):
        return fmt
    if csv:
        raise ConfigError(f"-o {path}: {verb} writes Parquet (.parquet) or CSV (.csv), and this name ends in neither")
    raise ConfigError(f"-o {path}: {verb} writes flight records as Parquet: name it .parquet (`tepinn-flight "
                      "estimate -o FILE.csv` writes an estimate as CSV)")  # fmt: skip


def check_suffix(flag: str, path, suffixes: tuple[str, ...], what: str) -> None:
    """A :class:`~..errors.ConfigError` where ``path``'s suffix is none of ``suffixes`` (lower case; ``""``: none):
    a file of one kind under another kind's name is opened by the wrong tool, or replaces a file of that kind."""
    from ..errors import ConfigError

    if Path(path).suffix.lower() not in suffixes:
        named = " or ".join(x for x in suffixes if x)
        raise ConfigError(f"{flag} {path}: writes {what}; name it {named}")


def refuse_overwriting_inputs(outputs, inputs) -> None:
    """A :class:`~..errors.ConfigError` before any work where an output is one of the inputs (``outputs``: pairs of
    the option that names it and its path; ``inputs``: paths): writing it would replace a log or record the run
    reads — ``estimate r.parquet -o r.parquet``, a folder estimated into itself beside its records, ``--tlog``
    naming the source tlog."""
    from ..errors import ConfigError
    from ..record import file_key

    given = {}
    for p in inputs:
        k = file_key(p)
        if k is not None:
            given.setdefault(k, p)
    for flag, out in outputs:
        k = file_key(out)
        if k is not None and k in given:
            raise ConfigError(f"{flag} {out} is the input {given[k]}: writing it would replace it; name another output")


def refuse_same_outputs(outputs) -> None:
    """A :class:`~..errors.ConfigError` before any work where two options name the same output (``outputs``: pairs
    of the option and its path): the one written last would replace the other — ``bridge --tlog s --summary-json s``
    left the session's JSON summary where its telemetry log had been."""
    from ..errors import ConfigError
    from ..record import file_key

    seen: dict = {}
    for flag, out in outputs:
        for k in {Path(out).resolve(), file_key(out)} - {None}:
            if k in seen:
                raise ConfigError(f"{flag} {out} is also {seen[k][0]} {seen[k][1]}: one would replace the other; "
                                  "name two outputs")  # fmt: skip
            seen[k] = (flag, out)


def add_recursive(p) -> None:
    """``-r/--recursive``: a folder stands for what its subfolders hold too (a PX4 SD card's dated folders)."""
    p.add_argument("-r", "--recursive", action="store_true",
                   help="a folder stands for the logs and records in its subfolders too (e.g. a PX4 SD card's log/)")


def collect_records(items: list[str], recursive: bool = False, notes: list[str] | None = None) -> list[Path]:
    """Record paths from the command line: files as given, a folder stands for the flight records and the logs
    in it (told by content: :mod:`tepinn_flight.ingest.inputs`; in its subfolders too where ``recursive``);
    ``notes`` gets a line for each file there named as a log that is none (an empty ``.BIN``)."""
    from ..ingest.inputs import expand

    return expand(items, recursive=recursive, notes=notes)


def read_records(items: list[str], paths: list[Path], notes: list[str]) -> list:
    """The flight records at ``paths`` (from :func:`collect_records` of ``items``; logs ingested on the fly), each
    named after its file. A file named on the command line that cannot be read is a one-line error; one a folder
    brought in is left out with a note in ``notes`` (a log folder holds logs without IMU data, older formats...)."""
    from ..errors import NoImuData, TepinnError
    from ..ingest import load_record
    from ..record import no_imu_reason

    named = {Path(i) for i in items if not Path(i).is_dir()}
    records = []
    for p in paths:
        try:
            rec = load_record(p)
            why = no_imu_reason(rec)
            if why:
                raise NoImuData(f"{why}: nothing to estimate", p)
        except TepinnError as exc:
            if p in named:
                raise
            notes.append(f"{p}: left out ({exc.reason})")
            continue
        rec.meta.setdefault("name", p.stem)
        records.append(rec)
    if not records:  # (the notes are printed after an evaluation, which will not run: say the first here)
        raise TepinnError(f"none of the {len(paths)} records or logs given could be read; {notes[0]}"
                          if notes else "no records given")
    return records
