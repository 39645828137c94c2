"""Vectorised walker over MAVLink telemetry-log records: selected message ids into numpy arrays.

A tlog is a repetition of ``[uint64 big-endian receive time, µs][MAVLink frame]``. A frame is

* v1: ``FE len seq sysid compid msgid`` + payload + CRC16 (little endian);
* v2: ``FD len incompat compat seq sysid compid msgid(3 bytes LE)`` + payload + CRC16
  (+ a 13-byte signature when ``incompat & 0x01``); trailing zero bytes of the payload are cut.

The CRC is CRC-16/MCRF4XX (X.25) over everything after the start byte, then the message's
``CRC_EXTRA`` byte. pymavlink's dialect (``all``, the one ``mavutil`` uses) gives ``CRC_EXTRA``,
the little-endian wire layout (``unpacker.format``) and the field names in wire order
(``ordered_fieldnames``) of each message; nothing else of pymavlink runs here.

How the scan works, chunk by chunk (the file is read in fixed-size chunks of 512 kB, so memory is
the chunk plus the decoded output; no Python object per frame):

1. Every byte position ``i`` with a start byte at ``i + 8`` is a candidate record; its header
   gives the record length, hence where the next record should begin.
2. Candidates with a known message id, allowed incompat flags and a complete frame are
   CRC-checked if the next record's start byte is where it should be (or the file ends there)
   or, failing that, their receive timestamp lies within a day of the chunk's typical one (a
   frame before junk). Steps 1–2 are one compiled loop, :func:`.mavlink_sync.good_frames`.
3. Frames whose CRC matches are the *good* frames; a good frame inside an earlier one is
   dropped. Only the wanted message ids are decoded: payloads are zero-padded to the full
   length (MAVLink 2 truncation) and viewed as a numpy structured array.
4. Bytes between good frames (junk, CRC-failed frames, frames of ids the dialect does not know,
   an incomplete last record) are walked record by record, which gives the counts (a gap that
   is exactly one record, the usual CRC failure, is counted in bulk).

Versus pymavlink (``mavutil.mavlink_connection(tlog)``, a ``mavmmaplog``): on the shared tlogs the
decoded messages equal its ``recv_match(type=[...])`` output value for value (a test).
``corrupt_frames`` counts structurally valid frames (start byte, a length that lands on the next
record, allowed flags) with a known id whose CRC fails: pymavlink's ``BAD_DATA`` "invalid MAVLink
CRC" (4 in ``ardusub_small.tlog``, 1967 in ``ardusub_2023-04-18_11-03-34.tlog``: the same numbers).
pymavlink also emits a ``BAD_DATA`` per run of junk bytes ("Bad prefix"; 140 in
``uavlv_pr437_flight_logs.tlog``): we count those bytes as ``junk_bytes`` (2565 there), not as
frames. Its sequential parser also loses 5 HEARTBEATs in that junk prefix (and decodes 3 false
``UNKNOWN_*`` frames); its indexed ``recv_match(type=...)`` and this scan find them. Frames of ids
the dialect does not know (pymavlink's ``UNKNOWN_*``) are ``unknown_frames``.
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass, field
from functools import lru_cache
from typing import Iterable

import numpy as np

from ..mavlink_dialect import dialect
from .mavlink_sync import HDR_V1, HDR_V2, SIG_LEN, STX_V1, STX_V2, TS_LEN, crc_slices, good_frames

#: Longest record: timestamp + v2 header + 255 payload + CRC + signature.
MAX_RECORD = TS_LEN + HDR_V2 + 255 + 2 + SIG_LEN
#: Look-ahead kept after a chunk: a record starting in the chunk plus the next record's header.
_PAD = 2 * MAX_RECORD
DEFAULT_CHUNK_BYTES = 512 << 10
#: Receive timestamps of real records lie within this of the chunk's median (µs).
_TS_WINDOW_US = 86_400 * 1_000_000
_MAX_ID = 1 << 16  # dialect ids are below this (all: max 60053)


def _crc_table() -> np.ndarray:
    x = np.arange(256, dtype=np.uint32)
    tmp = (x ^ (x << 4)) & 0xFF
    return (((tmp << 8) ^ (tmp << 3) ^ (tmp >> 4)) & 0xFFFF).astype(np.uint16)


_CRC_TABLE = _crc_table()


def x25_crc(data: bytes, crc: int = 0xFFFF) -> int:
    """CRC-16/MCRF4XX of ``data`` (the scalar reference, for tests)."""
    for b in data:
        crc = (crc >> 8) ^ int(_CRC_TABLE[(crc ^ b) & 0xFF])
    return crc


_STRUCT_TO_NUMPY = {
    "B": "u1", "b": "i1", "H": "<u2", "h": "<i2", "I": "<u4", "i": "<i4",
    "Q": "<u8", "q": "<i8", "f": "<f4", "d": "<f8", "c": "S1",
}  # fmt: skip


@dataclass(frozen=True)
class MsgLayout:
    """Wire layout of one message id, from the dialect."""

    msgid: int
    name: str
    crc_extra: int
    size: int  # full payload length, extensions included
    dtype: np.dtype  # packed little-endian structured dtype, fields in wire order


@lru_cache(maxsize=None)
def layout(name: str) -> MsgLayout:
    """Layout of the message called ``name`` (e.g. ``"RAW_IMU"``); KeyError if unknown."""
    mav = dialect()
    msgid = getattr(mav, f"MAVLINK_MSG_ID_{name}")
    cls = mav.mavlink_map[msgid]
    tokens = re.findall(r"(\d*)([a-zA-Z?])", cls.unpacker.format.lstrip("<>=!@"))
    if len(tokens) != len(cls.ordered_fieldnames):
        raise ValueError(f"cannot map the struct format of {name} to its fields")
    fields = []
    for (count, code), fname in zip(tokens, cls.ordered_fieldnames):
        n = int(count) if count else 1
        if code == "s":
            fields.append((fname, f"S{n}"))
        elif n > 1:
            fields.append((fname, _STRUCT_TO_NUMPY[code], (n,)))
        else:
            fields.append((fname, _STRUCT_TO_NUMPY[code]))
    dt = np.dtype(fields)
    if dt.itemsize != cls.unpacker.size:
        raise ValueError(f"layout size mismatch for {name}")
    return MsgLayout(msgid, cls.msgname, int(cls.crc_extra), int(cls.unpacker.size), dt)


@lru_cache(maxsize=1)
def _id_tables():
    """(known, crc_extra) lookup tables indexed by message id (< 65536)."""
    mav = dialect()
    known = np.zeros(_MAX_ID, bool)
    extra = np.zeros(_MAX_ID, np.uint16)
    for mid, cls in mav.mavlink_map.items():
        if mid < _MAX_ID:
            known[mid] = True
            extra[mid] = cls.crc_extra
    return known, extra


@dataclass
class Frames:
    """The good frames of one message id, in file order."""

    name: str
    offset: np.ndarray  # (n,) int64, file offset of the record (its receive timestamp)
    sysid: np.ndarray  # (n,) uint8
    compid: np.ndarray  # (n,) uint8
    fields: np.ndarray  # (n,) structured, field names as in pymavlink


@dataclass
class ScanResult:
    frames: dict[str, Frames]
    good_frames: int = 0
    corrupt_frames: int = 0
    unknown_frames: int = 0
    junk_bytes: int = 0
    truncated_bytes: int = 0
    file_size: int = 0
    #: good frames per (sysid, compid)
    sources: dict[tuple[int, int], int] = field(default_factory=dict)


_CRC_SLICES = crc_slices(_CRC_TABLE)


class _Acc:
    """Per-message accumulation of decoded chunks (of every field, or of ``keep``'s only: memory)."""

    def __init__(self, lay: MsgLayout, keep: tuple[str, ...] | None = None):
        self.lay = lay
        self.keep = keep
        self.dtype = lay.dtype if keep is None else np.dtype([(f, lay.dtype.fields[f][0]) for f in keep])
        self.parts: list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]] = []

    def add(self, buf, rec, pstart, plen, sysid, compid, base):
        lay = self.lay
        n = len(rec)
        if n == 0:
            return
        mat = np.lib.stride_tricks.sliding_window_view(buf, lay.size)[pstart]  # (n, size) copy
        short = np.flatnonzero(plen < lay.size)
        if len(short):  # v2 zero truncation (and short v1 frames): pad with zeros
            cols = np.arange(lay.size)
            part = mat[short]
            part[cols[None, :] >= plen[short, None]] = 0
            mat[short] = part
        rows = mat.view(lay.dtype).reshape(n)
        if self.keep is not None:  # the fields asked for, packed (the chunk's full rows are dropped)
            full, rows = rows, np.empty(n, self.dtype)
            for f in self.keep:
                rows[f] = full[f]
        self.parts.append((rec.astype(np.int64) + base, sysid.copy(), compid.copy(), rows))

    def result(self) -> Frames:
        if not self.parts:
            z = np.zeros(0, np.int64)
            return Frames(self.lay.name, z, z.astype(np.uint8), z.astype(np.uint8), np.zeros(0, self.dtype))
        # filled part by part, each part dropped once copied: memory is the result plus one part
        n = sum(len(p[0]) for p in self.parts)
        out = Frames(self.lay.name, np.empty(n, np.int64), np.empty(n, np.uint8), np.empty(n, np.uint8),
                     np.empty(n, self.dtype))  # fmt: skip
        k = 0
        self.parts.reverse()
        while self.parts:
            o, s, c, f = self.parts.pop()
            out.offset[k : k + len(o)], out.sysid[k : k + len(o)], out.compid[k : k + len(o)] = o, s, c
            out.fields[k : k + len(o)] = f
            k += len(o)
        return out


def scan_tlog(
    path: str | os.PathLike, names: Iterable[str], chunk_bytes: int = DEFAULT_CHUNK_BYTES,
    keep_fields: dict[str, tuple[str, ...]] | None = None,
) -> ScanResult:
    """Decode the good frames of the messages ``names`` from the tlog at ``path``; ``keep_fields``: for the
    messages it names, only those fields are kept (in that order, packed: the rest is never stored)."""
    known_tab, extra_tab = _id_tables()
    keep_fields = keep_fields or {}
    lays = {}
    for nm in names:
        lay = layout(nm)
        lays[lay.msgid] = lay
        missing = [f for f in keep_fields.get(nm, ()) if f not in lay.dtype.names]
        if missing:
            raise KeyError(f"{nm} has no field(s) {', '.join(missing)}")
    accs = {mid: _Acc(lay, keep_fields.get(lay.name)) for mid, lay in lays.items()}
    wanted = np.zeros(_MAX_ID, bool)
    wanted[list(lays)] = True

    chunk_bytes = max(int(chunk_bytes), 4 * MAX_RECORD)
    size = os.path.getsize(path)
    res = ScanResult(frames={}, file_size=size)
    src_counts = np.zeros(256 * 256, np.int64)
    covered = 0  # file offset up to which bytes belong to accepted good frames or known gaps
    buf = np.zeros(chunk_bytes + _PAD + 32, np.uint8)  # zero tail: header reads past m stay inside

    with open(path, "rb") as f:
        a = 0
        while a < size:
            f.seek(a)
            m = f.readinto(memoryview(buf)[: chunk_bytes + _PAD])
            buf[m:] = 0
            n_starts = min(chunk_bytes, m)  # record starts handled in this chunk: [a, a + n_starts)
            last = a + chunk_bytes >= size
            # 1.-2. candidates, plausibility and CRC: the compiled frame sync (i: record starts in buf)
            h_lo, h_hi = TS_LEN + max(0, covered - a), TS_LEN + n_starts
            n_max = int(np.count_nonzero(buf[h_lo:h_hi] >= STX_V2)) if h_hi > h_lo else 0
            i, msgid = good_frames(buf, m, h_lo, h_hi, n_max, a, size,
                                   known_tab, extra_tab, _CRC_TABLE, _CRC_SLICES, _MAX_ID, float(_TS_WINDOW_US))  # fmt: skip
            h = i + TS_LEN
            v2 = np.take(buf, h) == STX_V2
            ln = np.take(buf, h + 1).astype(np.int64)
            inc = np.take(buf, h + 2) * v2
            hdr = np.where(v2, HDR_V2, HDR_V1)
            nxt = i + TS_LEN + hdr + ln + 2 + (inc & 1) * SIG_LEN
            good = np.arange(len(i))
            # 3. good frames must not overlap (a frame inside another one is not a record)
            g_start = i[good] + a
            g_end = nxt[good] + a
            keep = _non_overlapping(g_start, g_end, covered)
            good = good[keep]
            g_start, g_end = g_start[keep], g_end[keep]
            if len(good):
                prev_end = np.concatenate([[covered], g_end[:-1]])
                gap = g_start > prev_end
                g0, g1 = _single_record_gaps(buf, a, prev_end[gap], g_start[gap], res)
                _walk_gaps(f, zip(g0.tolist(), g1.tolist()), size, res)
                covered = int(g_end[-1])
            res.good_frames += len(good)
            hg = h[good] + np.where(v2[good], 5, 3)
            sysid = np.take(buf, hg)
            compid = np.take(buf, hg + 1)
            key, n_key = np.unique(sysid.astype(np.int64) * 256 + compid, return_counts=True)
            src_counts[key] += n_key
            # 4. decode the wanted ids (good frames have ids below _MAX_ID)
            gid = msgid[good]
            sel = np.flatnonzero(np.take(wanted, gid))
            if len(sel):
                for mid in np.unique(gid[sel]).tolist():
                    s = sel[gid[sel] == mid]
                    g = good[s]
                    accs[mid].add(buf, i[g], i[g] + TS_LEN + hdr[g], ln[g], sysid[s], compid[s], a)
            if last:
                break
            a += chunk_bytes
        if covered < size:
            _walk_gaps(f, [(covered, size)], size, res)
    res.frames = {}
    while accs:  # one message's parts at a time
        acc = accs.pop(next(iter(accs)))
        res.frames[acc.lay.name] = acc.result()
        del acc
    nz = np.flatnonzero(src_counts)
    res.sources = {(int(k) // 256, int(k) % 256): int(src_counts[k]) for k in nz}
    return res


def _non_overlapping(start: np.ndarray, end: np.ndarray, covered: int) -> np.ndarray:
    """Mask of frames that do not start inside an earlier kept frame (file order)."""
    keep = start >= covered
    while True:
        e = np.where(keep, end, 0)
        prev = np.maximum.accumulate(np.concatenate([[covered], e[:-1]])) if len(e) else e
        new = keep & (start >= prev)
        if np.array_equal(new, keep):
            return keep
        keep = new


def _single_record_gaps(buf, a, g0, g1, res):
    """Count the gaps that are exactly one record (a CRC-failed frame, an unknown id), all at once.

    The commonest gap is one damaged frame between two good ones; :func:`_walk_gaps` would find
    the same record first and classify it the same way (its start byte at ``g0 + 8``, its length
    landing on ``g1``). Only gaps inside the chunk in ``buf`` (file offset ``a``) are looked at;
    the others are returned, for :func:`_walk_gaps`.
    """
    inside = g0 >= a
    p = g0[inside] - a
    stx = np.take(buf, p + TS_LEN)
    v2 = stx == STX_V2
    is_stx = v2 | (stx == STX_V1)
    ln = np.take(buf, p + TS_LEN + 1).astype(np.int64)
    inc = np.take(buf, p + TS_LEN + 2) * v2
    id2 = (
        np.take(buf, p + TS_LEN + 7).astype(np.int64)
        | (np.take(buf, p + TS_LEN + 8).astype(np.int64) << 8)
        | (np.take(buf, p + TS_LEN + 9).astype(np.int64) << 16)
    )
    msgid = np.where(v2, id2, np.take(buf, p + TS_LEN + 5))
    rl = TS_LEN + np.where(v2, HDR_V2, HDR_V1) + ln + 2 + (inc & 1) * SIG_LEN
    one = is_stx & (rl == g1[inside] - g0[inside])
    known_tab, _ = _id_tables()
    unknown = one & ((inc & 0xFE) == 0) & ~((msgid < _MAX_ID) & np.take(known_tab, msgid & 0xFFFF))
    res.unknown_frames += int(unknown.sum())
    res.corrupt_frames += int(one.sum() - unknown.sum())
    rest = np.ones(len(g0), bool)
    rest[np.flatnonzero(inside)[one]] = False
    return g0[rest], g1[rest]


_GAP_WINDOW = 4 << 20


def _walk_gaps(f, gaps: Iterable[tuple[int, int]], size: int, res: ScanResult) -> None:
    """Classify the bytes between good frames: bad-CRC frames, unknown ids, junk, a cut tail.

    A frame in a gap must end exactly where the next record (or the gap) begins; the rest is
    junk. Long gaps are read in windows, so memory stays bounded.
    """
    known_tab, _ = _id_tables()
    for g0, g1 in gaps:
        o = g0  # absolute: bytes before o are classified
        for w0 in range(g0, g1, _GAP_WINDOW):
            w1 = min(g1, w0 + _GAP_WINDOW)
            if o >= w1:
                continue
            f.seek(w0)
            data = f.read(w1 - w0 + 2 * MAX_RECORD)
            arr = np.frombuffer(data, np.uint8)
            win = arr[TS_LEN : w1 - w0 + TS_LEN]
            for p in (np.flatnonzero((win == STX_V1) | (win == STX_V2)) + w0).tolist():
                if p < o:
                    continue
                rl, msgid, flags_ok = _record_header(data, p - w0)
                end = p + rl if rl else None
                fits = end is not None and end <= g1
                if fits and end < g1:
                    q = end - w0 + TS_LEN
                    fits = q < len(data) and data[q] in (STX_V1, STX_V2)
                if fits:
                    res.junk_bytes += p - o
                    if flags_ok and not (msgid < _MAX_ID and known_tab[msgid]):
                        res.unknown_frames += 1
                    else:
                        res.corrupt_frames += 1  # CRC failed (or invalid incompat flags)
                    o = end
                elif g1 == size and (end is None or end > size):
                    res.junk_bytes += p - o
                    res.truncated_bytes += size - p  # a record cut by the end of the file
                    o = size
                    break
        res.junk_bytes += max(0, g1 - o)


def _record_header(data: bytes, p: int) -> tuple[int, int, bool]:
    """(record length, msgid, incompat flags allowed) of the record at ``p``; length 0 if cut."""
    s = p + TS_LEN
    if s + 2 > len(data):
        return 0, -1, False
    if data[s] == STX_V2:
        if s + HDR_V2 > len(data):
            return 0, -1, False
        inc = data[s + 2]
        msgid = data[s + 7] | (data[s + 8] << 8) | (data[s + 9] << 16)
        return TS_LEN + HDR_V2 + data[s + 1] + 2 + (SIG_LEN if inc & 1 else 0), msgid, (inc & 0xFE) == 0
    if s + HDR_V1 > len(data):
        return 0, -1, False
    return TS_LEN + HDR_V1 + data[s + 1] + 2, data[s + 5], True
