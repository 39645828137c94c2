"""Binary DataFlash logs (``.bin``): the :class:`~.dataflash_source.DataflashSource` of a mmap.

Formats come from the FMT records, the message chain is found and the wanted messages decoded in
bulk by :mod:`.dataflash_scan` (mmap, numpy; memory ≈ output size plus one scan chunk).
"""

from __future__ import annotations

import os

import numpy as np

from ..errors import CorruptLog
from . import dataflash_scan as dfs
from .dataflash_source import DECODE_BLOCK_ROWS, instance_col


class BinarySource:
    """Binary log: formats from FMT records, rows decoded in bulk from the mmap."""

    kind = "binary"

    def __init__(self, path: str | os.PathLike, wanted_names: set[str], counted_names: set[str]):
        self._mm, self.buf = dfs.open_buffer(path)
        if self._mm is None:
            raise CorruptLog("empty file")
        table = dfs.find_formats(self._mm)
        res = None
        for _ in range(3):  # a false FMT inside a payload is dropped and the chain rescanned
            names = table.by_name
            ids = {dfs.FMT_ID} | {names[n].type_id for n in wanted_names if n in names}
            inst = {}
            for n in counted_names - wanted_names:  # count rows per instance without keeping offsets
                col = instance_col(names[n]) if n in names else None
                if col is not None and names[n].dtype.fields[col][0].itemsize == 1:
                    inst[names[n].type_id] = names[n].field_offset(col)
                elif col is not None:  # a wider instance field: keep the offsets and decode it
                    ids.add(names[n].type_id)
            res = dfs.scan(self.buf, table.lengths(), ids, instance_bytes=inst)
            false_fmt = set(table.fmt_offsets.tolist()) - set(res.offsets[dfs.FMT_ID].tolist())
            if not false_fmt:
                break
            table = dfs.find_formats(self._mm, exclude=false_fmt)
        self.formats = {f.name: f for f in table.by_id.values() if f.type_id != dfs.FMT_ID}
        self._offsets = {table.by_id[i].name: o for i, o in res.offsets.items() if i in table.by_id}
        self.counts = {table.by_id[i].name: int(c) for i, c in enumerate(res.counts) if c and i in table.by_id}
        self._inst_counts = {table.by_id[i].name: c for i, c in res.instance_counts.items()}
        self.corrupt_frames = res.corrupt_regions
        self.skipped_frames = res.unknown_id_headers + (1 if res.truncated_tail_bytes else 0)
        self.notes = list(table.redefined)
        if res.corrupt_regions:
            self.notes.append(
                f"{res.corrupt_regions} corrupt region(s), {res.skipped_bytes} bytes skipped to resynchronise"
            )
        if res.unknown_id_headers:
            self.notes.append(f"{res.unknown_id_headers} message header(s) with an id that has no FMT skipped")
        if res.truncated_tail_bytes:
            self.notes.append(f"truncated tail: the last {res.truncated_tail_bytes} bytes hold no complete message (a "
                              "log cut while written, or bytes that are no log after it)")  # (review60: 3 MB "a message")
        self.banner = ""

    def count(self, name: str) -> int:
        return self.counts.get(name, 0)

    def order(self, name: str) -> np.ndarray:
        return self._offsets.get(name, np.zeros(0, np.int64))

    def instance_column(self, name: str, col: str) -> np.ndarray:
        mf = self.formats[name]
        return dfs.scaled(dfs.decode_column(self.buf, mf, self.order(name), col), mf.multiplier(col))

    def instance_counts(self, name: str, col: str) -> dict[int, int]:
        c = self._inst_counts.get(name)
        if c is not None:
            return {int(i): int(c[i]) for i in np.flatnonzero(c)}
        v, n = np.unique(self.instance_column(name, col), return_counts=True)
        return {int(a): int(b) for a, b in zip(v, n) if np.isfinite(a)}

    def table(self, name: str, cols: tuple[str, ...], rows: np.ndarray | None = None) -> np.ndarray:
        mf = self.formats[name]
        offs = self.order(name) if rows is None else self.order(name)[rows]
        out = np.empty((len(offs), len(cols)))
        for i in range(0, len(offs), DECODE_BLOCK_ROWS):  # blocks keep the raw rows' memory constant
            raw = dfs.decode_rows(self.buf, mf, offs[i : i + DECODE_BLOCK_ROWS])
            for k, c in enumerate(cols):
                out[i : i + DECODE_BLOCK_ROWS, k] = dfs.scaled(raw[c], mf.multiplier(c))
        return out

    def strings(self, name: str, col: str) -> list[str]:
        mf = self.formats.get(name)
        if mf is None or self.count(name) == 0 or col not in mf.columns or mf.type_char(col) not in dfs.STRING_CHARS:
            return []
        raw = dfs.decode_rows(self.buf, mf, self.order(name))[col]
        return [dfs._null_term(bytes(b)) for b in raw]
