"""Text DataFlash logs (``.log``): the :class:`~.dataflash_source.DataflashSource` of ``NAME, v1, ...`` lines.

Lines are classified with numpy and the wanted lines parsed by pandas' C CSV parser (memory ≈ a
few times the file size: text logs are small).
"""

from __future__ import annotations

import csv
import io
import os

import numpy as np
import pandas as pd

from . import dataflash_scan as dfs


class TextSource:
    """Text log: ``NAME, v1, v2, ...`` lines.

    Lines are classified with numpy (line starts, first comma, a key from the ≤ 4-character
    message name), so Python touches only the FMT lines and the wanted messages' lines; numeric
    tables are parsed by pandas' C CSV parser.
    """

    kind = "text"

    def __init__(self, path: str | os.PathLike, wanted_names: set[str], counted_names: set[str] = frozenset()):
        with open(path, "rb") as f:
            self._raw = f.read()
        data = np.frombuffer(self._raw, np.uint8)
        nl = np.flatnonzero(data == 10)
        starts = np.concatenate([[0], nl + 1]).astype(np.int64)
        ends = np.concatenate([nl, [len(data)]]).astype(np.int64)
        self._commas = commas = np.flatnonzero(data == 44)
        ci = np.searchsorted(commas, starts)
        first = commas[np.minimum(ci, max(len(commas) - 1, 0))] if len(commas) else np.full(len(starts), -1)
        has = (ci < len(commas)) & (first < ends)
        keys = np.full(len(starts), -1, np.int64)
        nlen = np.where(has, first - starts, 0)
        okn = has & (nlen >= 1) & (nlen <= 4)
        if okn.any():
            k = np.zeros(int(okn.sum()), np.int64)
            s0, ln = starts[okn], nlen[okn]
            for j in range(4):
                k |= np.where(j < ln, data[np.minimum(s0 + j, len(data) - 1)].astype(np.int64), 0) << (8 * j)
            keys[okn] = k | (ln << 32)
        self._starts, self._first, self._ends, self._keys = starts, first, ends, keys

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
        unknown = len(kb) - known - blank
        self._rows = {
            name: np.flatnonzero(keys == k)
            for name, k in self._name_keys.items()
            if name in wanted_names or name in counted_names
        }
        self._cache: dict[str, np.ndarray] = {}
        self.corrupt_frames = bad_fmt
        self.skipped_frames = unknown
        self.notes = []
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

    def _numeric(self, name: str) -> np.ndarray:
        """``(n, ncols)`` float64 of one message's lines; strings and malformed rows are NaN."""
        if name in self._cache:
            return self._cache[name]
        mf = self.formats[name]
        k = len(mf.fmt)
        rows = self._rows.get(name, np.zeros(0, np.int64))
        out = np.full((len(rows), k), np.nan)
        if len(rows) and k:
            a, e = self._first[rows] + 1, self._ends[rows]
            n_commas = np.searchsorted(self._commas, e) - np.searchsorted(self._commas, a)
            good = n_commas == k - 1
            if not good.all():
                self.corrupt_frames += int((~good).sum())
                self.notes.append(f"{int((~good).sum())} {name} line(s) with a wrong number of fields skipped")
            raw = self._raw
            joined = b"\n".join([raw[x:y] for x, y in zip(a[good].tolist(), e[good].tolist())])
            num = [c for c, ch in enumerate(mf.fmt) if ch not in dfs.STRING_CHARS and ch != "a"]
            if good.any() and num:
                out[np.ix_(good, num)] = _parse_csv(joined, k, num, int(good.sum()))
        self._cache[name] = out
        return out

    def instance_column(self, name: str, col: str) -> np.ndarray:
        return self._numeric(name)[:, self.formats[name].columns.index(col)]

    def instance_counts(self, name: str, col: str) -> dict[int, int]:
        v, n = np.unique(self.instance_column(name, col), return_counts=True)
        return {int(a): int(b) for a, b in zip(v, n) if np.isfinite(a)}

    def table(self, name: str, cols: tuple[str, ...], rows: np.ndarray | None = None) -> np.ndarray:
        arr = self._numeric(name)
        mf = self.formats[name]
        idx = [mf.columns.index(c) for c in cols]
        return arr[:, idx] if rows is None else arr[np.ix_(rows, idx)]

    def strings(self, name: str, col: str) -> list[str]:
        mf = self.formats.get(name)
        if mf is None or col not in mf.columns:
            return []
        i = mf.columns.index(col)
        last = i == len(mf.columns) - 1
        out = []
        for r in self._rows.get(name, []):
            parts = self._line(r, self._first[r] + 1).split(",", i if last else i + 1)
            out.append(parts[i].strip() if len(parts) > i else "")
        return out


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

