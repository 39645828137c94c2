"""Low-level scanner for binary ArduPilot DataFlash logs: FMT records, message boundaries, bulk decode.

A binary DataFlash log is a chain of messages ``A3 95 <id> <body>``; the ``FMT`` messages (id 128)
give each id's total length (header included), name, struct type chars and column names. This
module finds the chain with numpy instead of a Python object per message:

1. :func:`find_formats` locates the ``A3 95 80`` records with ``mmap.find`` (C speed) and
   validates each candidate body (type chars known, length = 3 + struct size, printable name).
2. :func:`scan` walks the file in fixed-size chunks: every ``A3 95`` pair whose id has a format
   is a candidate; a candidate whose successor (offset + length) is the next candidate is
   "regular", and runs of regular candidates are accepted in bulk. Only irregular spots (a false
   ``A3 95`` inside a payload, garbage, unknown ids) are followed one by one in Python, like
   pymavlink's byte-wise resync. Only the offsets of the wanted ids are kept, so memory is the
   output size plus one chunk.
3. :func:`decode_rows` gathers the wanted messages' bytes (in blocks) and views them through a
   packed numpy structured dtype; :func:`scaled` applies pymavlink's multipliers (``c`` ×0.01,
   ``L`` ×1e-7, ...) the same way pymavlink does (division by ``1/mult``), so values are equal.

Type chars follow pymavlink ``DFReader.FORMAT_TO_STRUCT``.
"""

from __future__ import annotations

import mmap
import struct
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

HEAD1, HEAD2 = 0xA3, 0x95
FMT_ID = 0x80
FMT_LEN = 89
_FMT_BODY = struct.Struct("<BB4s16s64s")

#: DataFlash type char -> (numpy dtype, pymavlink multiplier or None).
TYPE_CHARS: dict[str, tuple[str, float | None]] = {
    "a": ("<i2,(32,)", None),  # int16[32]; pymavlink reads it as 64s then array('h')
    "b": ("<i1", None),
    "B": ("<u1", None),
    "g": ("<f2", None),
    "h": ("<i2", None),
    "H": ("<u2", None),
    "i": ("<i4", None),
    "I": ("<u4", None),
    "f": ("<f4", None),
    "d": ("<f8", None),
    "n": ("S4", None),
    "N": ("S16", None),
    "Z": ("S64", None),
    "c": ("<i2", 0.01),
    "C": ("<u2", 0.01),
    "e": ("<i4", 0.01),
    "E": ("<u4", 0.01),
    "L": ("<i4", 1.0e-7),
    "M": ("<i1", None),  # flight mode number
    "q": ("<i8", None),
    "Q": ("<u8", None),
}
STRING_CHARS = frozenset("nNZ")


def _field_dtype(ch: str) -> np.dtype:
    if ch == "a":
        return np.dtype(("<i2", (32,)))
    return np.dtype(TYPE_CHARS[ch][0])


def _null_term(b: bytes) -> str:
    i = b.find(b"\0")
    if i >= 0:
        b = b[:i]
    try:
        return b.decode("utf-8")
    except UnicodeDecodeError:
        return b.decode("ISO-8859-1")


@dataclass(frozen=True)
class MsgFormat:
    """One message definition from an FMT record."""

    type_id: int
    name: str
    length: int  # total bytes including the 3-byte header
    fmt: str  # type chars
    columns: tuple[str, ...]
    offset: int = -1  # file offset (binary) or line number (text) of the FMT record

    @cached_property
    def dtype(self) -> np.dtype:
        """Packed structured dtype of a whole message (3 header bytes as ``_hdr``)."""
        names = ["_hdr"] + list(self.columns)
        formats = [np.dtype("V3")] + [_field_dtype(c) for c in self.fmt]
        return np.dtype({"names": names, "formats": formats})

    def multiplier(self, col: str) -> float | None:
        return TYPE_CHARS[self.fmt[self.columns.index(col)]][1]

    def type_char(self, col: str) -> str:
        return self.fmt[self.columns.index(col)]

    def field_offset(self, col: str) -> int:
        """Byte offset of a column inside the message (header included)."""
        return self.dtype.fields[col][1]


def _unique_columns(cols: list[str], n: int) -> tuple[str, ...]:
    """Exactly ``n`` distinct, non-empty column names (pad or rename; malformed FMTs exist)."""
    out: list[str] = []
    seen: set[str] = set()
    for k in range(n):
        c = cols[k].strip() if k < len(cols) and cols[k].strip() else f"_f{k}"
        base, j = c, 2
        while c in seen or c == "_hdr":
            c, j = f"{base}_{j}", j + 1
        seen.add(c)
        out.append(c)
    return tuple(out)


def make_format(type_id: int, name: str, length: int, fmt: str, columns: str, offset: int = -1) -> MsgFormat | None:
    """A validated :class:`MsgFormat`, or None if the definition is not self-consistent."""
    if not name or not all(32 < ord(ch) < 127 for ch in name):
        return None
    if any(ch not in TYPE_CHARS for ch in fmt):
        return None
    cols = [] if columns.strip() == "" else columns.split(",")
    mf = MsgFormat(type_id, name, length, fmt, _unique_columns(cols, len(fmt)), offset)
    if mf.dtype.itemsize != length:  # the dtype includes the 3 header bytes
        return None
    return mf


@dataclass
class FormatTable:
    """All valid FMT definitions of a log, keyed by message id (first definition wins)."""

    by_id: dict[int, MsgFormat]
    redefined: list[str] = field(default_factory=list)  # notes on conflicting redefinitions
    fmt_offsets: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))

    @property
    def by_name(self) -> dict[str, MsgFormat]:
        return {f.name: f for f in self.by_id.values()}

    def lengths(self) -> np.ndarray:
        """Message length per id (0 = unknown id)."""
        out = np.zeros(256, np.int64)
        for i, f in self.by_id.items():
            out[i] = f.length
        return out


def find_formats(mm, exclude: set[int] | None = None) -> FormatTable:
    """Every plausible FMT record in the file (``exclude``: offsets known not to be messages)."""
    fmt_cols = ("Type", "Length", "Name", "Format", "Columns")
    by_id: dict[int, MsgFormat] = {FMT_ID: MsgFormat(FMT_ID, "FMT", FMT_LEN, "BBnNZ", fmt_cols)}
    redefined: list[str] = []
    offsets: list[int] = []
    size = len(mm)
    pat = bytes([HEAD1, HEAD2, FMT_ID])
    pos = mm.find(pat, 0)
    while pos >= 0 and pos + FMT_LEN <= size:
        if exclude is None or pos not in exclude:
            tid, length, name, fmt, cols = _FMT_BODY.unpack_from(mm, pos + 3)
            mf = make_format(tid, _null_term(name), length, _null_term(fmt), _null_term(cols), pos)
            if mf is not None and (tid != FMT_ID or mf.name == "FMT"):
                offsets.append(pos)
                old = by_id.get(tid)
                if old is None or (tid == FMT_ID and old.offset < 0):
                    by_id[tid] = mf
                elif (old.name, old.length, old.fmt) != (mf.name, mf.length, mf.fmt):
                    redefined.append(
                        f"message id {tid} redefined at byte {pos} ({old.name}/{old.fmt} -> {mf.name}/{mf.fmt}); "
                        "the first definition is used"
                    )
        pos = mm.find(pat, pos + 1)
    return FormatTable(by_id, redefined, np.asarray(offsets, np.int64))


@dataclass
class ScanResult:
    """Where the wanted messages are, and what did not parse."""

    offsets: dict[int, np.ndarray]  # message id -> file offsets (file order), wanted ids only
    counts: np.ndarray  # (256,) messages per id on the chain
    corrupt_regions: int = 0  # places where the chain broke on garbage (bytes skipped to resync)
    unknown_id_headers: int = 0  # chain breaks on a header whose id has no FMT
    skipped_bytes: int = 0  # bytes skipped while resyncing (not counting the tail)
    truncated_tail_bytes: int = 0  # bytes after the last complete message
    data_end: int = 0  # offset just after the last complete message
    instance_counts: dict[int, np.ndarray] = field(default_factory=dict)  # id -> rows per instance value


def scan(
    buf: np.ndarray,
    lengths: np.ndarray,
    wanted: set[int] | list[int],
    chunk_bytes: int = 1 << 22,
    start: int = 0,
    instance_bytes: dict[int, int] | None = None,
) -> ScanResult:
    """Walk the message chain of ``buf`` (uint8 view of the file) and collect wanted offsets.

    ``instance_bytes`` maps message ids to the byte offset (inside the message) of a one-byte
    instance field; the scan then counts rows per instance value for those ids without keeping
    their offsets (``ScanResult.instance_counts``).

    Memory: one chunk of temporaries plus 8 bytes per wanted message.
    """
    instance_bytes = dict(instance_bytes or {})
    size = int(buf.shape[0])
    lengths = np.asarray(lengths, np.int64)
    want = np.zeros(256, bool)
    want[list(wanted)] = True
    counts = np.zeros(256, np.int64)
    w_off: dict[int, list[np.ndarray]] = {int(i): [] for i in np.flatnonzero(want)}
    res = ScanResult({}, counts)
    res.instance_counts = {i: np.zeros(256, np.int64) for i in instance_bytes}
    pos = start
    pending: tuple[int, bool] | None = None  # (break offset, unknown-id header) not yet resolved

    def _break(at: int) -> tuple[int, bool]:
        unknown = at + 2 < size and buf[at] == HEAD1 and buf[at + 1] == HEAD2
        return at, bool(unknown)

    def _resolve(pend: tuple[int, bool], found_at: int) -> None:
        res.skipped_bytes += found_at - pend[0]
        if pend[1]:
            res.unknown_id_headers += 1
        else:
            res.corrupt_regions += 1

    while pos < size:
        end = min(pos + chunk_bytes, size)
        a = buf[pos : min(end + 2, size)]
        if len(a) < 3:
            break
        h = np.flatnonzero(a[: min(end - pos, len(a) - 2)] == HEAD1)
        h = h[a[h + 1] == HEAD2]
        ids = a[h + 2]
        L = lengths[ids]
        off = h.astype(np.int64) + pos
        ok = (L > 0) & (off + L <= size)
        off, ids, L = off[ok], ids[ok], L[ok]
        n = len(off)
        if n == 0:
            if pending is None:
                pending = _break(pos)
            pos = end
            continue
        if off[0] != pos and pending is None:
            pending = _break(pos)
        if pending is not None:
            _resolve(pending, int(off[0]))
            pending = None
        nxt = off + L
        j = np.searchsorted(off, nxt)
        exact = (j < n) & (off[np.minimum(j, n - 1)] == nxt)
        regular = exact & (j == np.arange(1, n + 1))
        irregular = np.flatnonzero(~regular)  # never empty: the last candidate is irregular
        starts: list[int] = []
        stops: list[int] = []
        k = 0
        while True:
            r = int(irregular[np.searchsorted(irregular, k)])
            starts.append(k)
            stops.append(r + 1)
            nx = int(nxt[r])
            if nx >= end:
                pos = nx
                break
            if exact[r]:
                k = int(j[r])  # candidates in between were false headers inside message r
                continue
            # nothing at the expected offset: garbage or an unknown id; resync at the next header
            brk = _break(nx)
            if j[r] >= n:
                pending = brk
                pos = end
                break
            k = int(j[r])
            _resolve(brk, int(off[k]))
        mark = np.zeros(n + 1, np.int32)
        np.add.at(mark, np.asarray(starts), 1)
        np.add.at(mark, np.asarray(stops), -1)
        keep = np.cumsum(mark[:-1]) > 0
        s_off, s_id = off[keep], ids[keep]
        counts += np.bincount(s_id, minlength=256)
        present = np.flatnonzero(np.bincount(s_id, minlength=256))
        for i in present:
            i = int(i)
            if i in w_off or i in instance_bytes:
                o_i = s_off[s_id == i]
                if i in w_off:
                    w_off[i].append(o_i)
                if i in instance_bytes:
                    res.instance_counts[i] += np.bincount(buf[o_i + instance_bytes[i]], minlength=256)
    if pending is not None:
        res.truncated_tail_bytes = size - pending[0]
        res.data_end = pending[0]
    else:
        res.data_end = min(pos, size)
        res.truncated_tail_bytes = max(0, size - pos)
    for i, parts in w_off.items():
        res.offsets[i] = np.concatenate(parts) if parts else np.zeros(0, np.int64)
    return res


def _gather(buf: np.ndarray, offsets: np.ndarray, start: int, width: int) -> np.ndarray:
    """``(n, width)`` uint8: bytes ``[o + start, o + start + width)`` for each offset.

    Fancy indexing on a sliding-window view copies just the selected rows (no (n, width) index
    array).
    """
    win = np.lib.stride_tricks.sliding_window_view(buf[start:], width)
    return win[offsets]


def decode_rows(buf: np.ndarray, mf: MsgFormat, offsets: np.ndarray) -> np.ndarray:
    """Raw (unscaled) rows of one message type as a structured array."""
    rows = _gather(buf, np.asarray(offsets, np.int64), 0, mf.length)
    return rows.reshape(-1).view(mf.dtype)


def decode_column(buf: np.ndarray, mf: MsgFormat, offsets: np.ndarray, col: str) -> np.ndarray:
    """Raw values of one column only (e.g. an instance byte), without gathering whole rows."""
    dt = mf.dtype.fields[col][0]
    raw = _gather(buf, np.asarray(offsets, np.int64), mf.field_offset(col), dt.itemsize)
    return raw.reshape(-1).view(dt) if dt.shape == () else raw.view(dt.base).reshape(len(offsets), *dt.shape)


def scaled(values: np.ndarray, mult: float | None) -> np.ndarray:
    """float64 values with pymavlink's multiplier applied exactly as pymavlink does."""
    with np.errstate(invalid="ignore"):  # a corrupt row's bytes may be NaN/inf: dropped later, not a warning
        v = np.asarray(values).astype(np.float64)
    if mult is None:
        return v
    if 0.0 < mult < 1.0:
        return v / (1 / mult)
    return v * mult


def open_buffer(path) -> tuple[mmap.mmap | None, np.ndarray]:
    """Read-only mmap of the file and a uint8 numpy view (empty files give an empty array)."""
    with open(path, "rb") as f:
        f.seek(0, 2)
        if f.tell() == 0:
            return None, np.zeros(0, np.uint8)
        mm = mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ)
    return mm, np.frombuffer(mm, np.uint8)
