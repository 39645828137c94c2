"""Text DataFlash logs (``.log``): the :class:`~.dataflash_source.DataflashSource` of ``NAME, v1, ...`` lines.

The file is mapped, its lines and their commas found in one compiled pass (:mod:`.dataflash_text_kernels`),
classified with numpy, and the wanted lines' columns parsed by pandas' C CSV parser, each column once, when first
asked for (memory ≈ a few times the file size: text logs are small).
"""

from __future__ import annotations

import csv
import io
import mmap
import os

import numpy as np
import pandas as pd

from . import dataflash_scan as dfs
from .dataflash_text_kernels import NEWLINE, field_bounds, line_table


class TextSource:
    """Text log: ``NAME, v1, v2, ...`` lines.

    Lines are classified by a key from their ≤ 4-character message name (before the first comma), so
    Python touches only the FMT lines and the wanted messages' lines; numeric columns are parsed by
    pandas' C CSV parser.
    """

    kind = "text"

    def __init__(self, path: str | os.PathLike, wanted_names: set[str], counted_names: set[str] = frozenset()):
        with open(path, "rb") as f:  # mapped, not copied (a text log of tens of MB: its pages come from the cache)
            size = os.fstat(f.fileno()).st_size
            self._raw = mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ) if size else b""
        data = np.frombuffer(self._raw, np.uint8)
        n_lines = int(np.count_nonzero(data == NEWLINE)) + 1
        starts, ends, first, n_commas = (np.empty(n_lines, np.int64) for _ in range(4))
        line_table(data, starts, ends, first, n_commas)  # one compiled pass: lines, first commas, commas per line
        has = first >= 0
        keys = np.full(len(starts), -1, np.int64)
        nlen = np.where(has, first - starts, 0)
        okn = has & (nlen >= 1) & (nlen <= 4)
        # a last line without its line end is a log cut in it: its last field may be cut mid-number ("186.16" read
        # as "1", with the right number of fields), so it is not read (review60: a reference yaw swung 140°)
        cut = bool(len(data)) and data[-1] != NEWLINE and len(data) - starts[-1] > 1  # (1 byte: a blank line)
        if cut:
            okn[-1] = False
        if okn.any():
            k = np.zeros(int(okn.sum()), np.int64)
            s0, ln = starts[okn], nlen[okn]
            for j in range(4):
                k |= np.where(j < ln, data[np.minimum(s0 + j, len(data) - 1)].astype(np.int64), 0) << (8 * j)
            keys[okn] = k | (ln << 32)
        self._starts, self._first, self._ends, self._keys = starts, first, ends, keys
        self._n_commas = n_commas  # per line: its commas, the message name's included

        fmt_key = _name_key("FMT")
        self.formats: dict[str, dfs.MsgFormat] = {}
        bad_fmt = 0
        fmt_lines = np.flatnonzero(keys == fmt_key)
        for i in fmt_lines:
            mf = self._parse_fmt(self._line(i, first[i] + 1), int(starts[i]))
            if mf is None:
                bad_fmt += 1
            elif mf.name != "FMT" and mf.name not in self.formats:
                self.formats[mf.name] = mf
        body_from = int(fmt_lines[0]) if len(fmt_lines) else len(starts)
        banner = [self._line(i, starts[i]).strip() for i in range(min(body_from, 20))]
        self.banner = next((b for b in banner if b), "")
        kb = keys[body_from:]
        u, n = np.unique(kb, return_counts=True)
        by_key = dict(zip(u.tolist(), n.tolist()))
        self._name_keys = {name: _name_key(name) for name in self.formats}
        self.counts = {name: by_key[k] for name, k in self._name_keys.items() if k in by_key}
        known = sum(self.counts.values()) + by_key.get(fmt_key, 0)
        blank = int(np.sum((ends[body_from:] - starts[body_from:]) <= 1))  # empty or a lone '\r'
        unknown = len(kb) - known - blank - int(cut and len(starts) - 1 >= body_from)  # (the cut line: said apart)
        self._rows = {
            name: np.flatnonzero(keys == k)
            for name, k in self._name_keys.items()
            if name in wanted_names or name in counted_names
        }
        self._cache: dict[tuple[str, int], np.ndarray] = {}  # (message, column) -> its values per line
        self._joined: dict[str, tuple[np.ndarray, bytes]] = {}
        self._str_cache: dict[tuple[str, str], list[str]] = {}
        self.corrupt_frames = bad_fmt
        self.skipped_frames = unknown
        self.notes = []
        if cut:
            self.notes.append("the log ends inside a line (cut while written, or copied in part): its last line is "
                              "not read")  # fmt: skip
        if unknown:
            self.notes.append(f"{unknown} line(s) with no FMT definition skipped")
        if bad_fmt:
            self.notes.append(f"{bad_fmt} malformed FMT line(s) skipped")

    def _line(self, i: int, start: int) -> str:
        return self._raw[start : self._ends[i]].decode("utf-8", "replace").rstrip("\r")

    @staticmethod
    def _parse_fmt(rest: str, pos: int) -> dfs.MsgFormat | None:
        parts = [p.strip() for p in rest.split(",")]
        if len(parts) < 4:
            return None
        try:
            tid, length = int(parts[0]), int(parts[1])
        except ValueError:
            return None
        return dfs.make_format(tid, parts[2], length, parts[3], ",".join(parts[4:]), pos)

    def count(self, name: str) -> int:
        return self.counts.get(name, 0)

    def order(self, name: str) -> np.ndarray:
        rows = self._rows.get(name)
        return np.zeros(0, np.int64) if rows is None else self._starts[rows]

    def _lines(self, name: str) -> tuple[np.ndarray, bytes]:
        """(which of the message's lines have its number of fields, those lines joined by newlines), made once per
        message; a line with another number of fields is counted and said once."""
        got = self._joined.get(name)
        if got is None:
            k = len(self.formats[name].fmt)
            rows = self._rows.get(name, np.zeros(0, np.int64))
            good = np.zeros(len(rows), bool)
            joined = b""
            if len(rows) and k:
                a, e = self._first[rows] + 1, self._ends[rows]
                good = self._n_commas[rows] == k  # the name's comma and one before each later field
                if not good.all():
                    self.corrupt_frames += int((~good).sum())
                    self.notes.append(f"{int((~good).sum())} {name} line(s) with a wrong number of fields skipped")
                raw = self._raw
                joined = b"\n".join([raw[x:y] for x, y in zip(a[good].tolist(), e[good].tolist())])
            got = self._joined[name] = (good, joined)
        return got

    def _columns(self, name: str, idx: list[int]) -> np.ndarray:
        """``(n, len(idx))`` float64 of those columns of the message's lines; strings and malformed lines NaN.
        Each column is parsed once, when first asked for (pandas' C parser reads only the columns it is given)."""
        mf = self.formats[name]
        k = len(mf.fmt)
        todo = [j for j in dict.fromkeys(idx) if (name, j) not in self._cache]
        if todo:
            good, joined = self._lines(name)
            num = [j for j in todo if mf.fmt[j] not in dfs.STRING_CHARS and mf.fmt[j] != "a"]
            cols = {j: np.full(len(good), np.nan) for j in todo}
            if good.any() and num:
                parsed = _parse_csv(joined, k, num, int(good.sum()))
                for c, j in enumerate(num):
                    cols[j][good] = parsed[:, c]
            for j in todo:
                self._cache[(name, j)] = cols[j]
        n = len(self._rows.get(name, ()))
        return np.column_stack([self._cache[(name, j)] for j in idx]) if idx else np.zeros((n, 0))

    def instance_column(self, name: str, col: str) -> np.ndarray:
        return self._columns(name, [self.formats[name].columns.index(col)])[:, 0]

    def instance_counts(self, name: str, col: str) -> dict[int, int]:
        v, n = np.unique(self.instance_column(name, col), return_counts=True)
        return {int(a): int(b) for a, b in zip(v, n) if np.isfinite(a)}

    def table(self, name: str, cols: tuple[str, ...], rows: np.ndarray | None = None) -> np.ndarray:
        mf = self.formats[name]
        arr = self._columns(name, [mf.columns.index(c) for c in cols])
        return arr if rows is None else arr[rows]

    def strings(self, name: str, col: str) -> list[str]:
        """One column of a message's lines as text (a copy of a list made once per column: a log's PARM
        names are asked for once per parameter read, and each pass is a Python loop over its lines)."""
        mf = self.formats.get(name)
        if mf is None or col not in mf.columns:
            return []
        got = self._str_cache.get((name, col))
        if got is None:
            got = self._column_text(np.asarray(self._rows.get(name, np.zeros(0, np.int64))), mf.columns.index(col),
                                    mf.columns.index(col) == len(mf.columns) - 1)  # fmt: skip
            self._str_cache[(name, col)] = got
        return list(got)

    def _column_text(self, rows: np.ndarray, i: int, last: bool) -> list[str]:
        """Field ``i`` (after the message name) of the lines ``rows``, stripped; the last field runs to the line's
        end (commas and all); a line with fewer fields gives "". Its bounds: a compiled walk of each line."""
        if len(rows) == 0:
            return []
        start, end = np.empty(len(rows), np.int64), np.empty(len(rows), np.int64)
        field_bounds(np.frombuffer(self._raw, np.uint8), self._first[rows], self._ends[rows], i, last, start, end)
        raw = self._raw
        return [raw[a:b].decode("utf-8", "replace").strip() for a, b in zip(start.tolist(), end.tolist())]


def _parse_csv(data: bytes, ncols: int, numeric: list[int], n_lines: int) -> np.ndarray:
    """Numeric columns of ``n_lines`` comma-separated lines via pandas' C parser; bad cells become NaN. Bytes that
    are no text are read as Latin-1 (which decodes every byte), so a corrupted byte spoils its cell, not the log;
    where corruption made the parser see another number of lines (a stray carriage return or quote), the lines
    are split here, one by one."""
    kw = dict(header=None, names=list(range(ncols)), usecols=numeric, skipinitialspace=True, engine="c",
              encoding="latin-1", quoting=csv.QUOTE_NONE)
    try:
        table = pd.read_csv(io.BytesIO(data), dtype=np.float64, **kw)
    except ValueError:
        table = pd.read_csv(io.BytesIO(data), dtype=object, **kw)
        table = table.apply(lambda c: pd.to_numeric(c.astype(str).str.strip(), errors="coerce"))
    if len(table) == n_lines:
        return table[numeric].to_numpy(np.float64)
    out = np.full((n_lines, len(numeric)), np.nan)
    for r, line in enumerate(data.split(b"\n")[:n_lines]):
        cells = line.decode("latin-1").split(",")
        for j, c in enumerate(numeric):
            try:
                out[r, j] = float(cells[c])
            except (IndexError, ValueError):
                pass
    return out


def _name_key(name: str) -> int:
    """The integer key of a ≤ 4-character message name used by :class:`TextSource`."""
    b = name.encode("ascii", "replace")[:4]
    return int.from_bytes(b, "little") | (len(b) << 32)

