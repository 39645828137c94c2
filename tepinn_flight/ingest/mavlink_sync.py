"""Frame sync of one tlog chunk, compiled (numba): which candidate records are good MAVLink frames.

Steps 1–2 of :mod:`.mavlink_scan` (its docstring states the rules) as one sequential loop per
chunk instead of a dozen candidate-sized numpy temporaries: memory is the good frames' few
integers, and each frame's CRC is one pass over its bytes.

For every byte position ``h`` in ``[h_lo, h_hi)`` of ``buf`` holding a start byte (``FD``/``FE``),
the record starts at ``i = h - 8``; it is a good frame when

* it is *checkable*: complete inside the ``m`` valid bytes, allowed incompat flags, a message id
  the dialect knows;
* it is *plausible*: the next record's start byte sits where this record ends (or the file ends
  there), or else its receive timestamp lies within ``ts_window_us`` of the median receive
  timestamp of every ``step``-th chained candidate (step = max(1, chained // 257));
* its CRC-16/MCRF4XX over the frame after the start byte, then the id's ``CRC_EXTRA``, equals the
  two bytes after the payload.

Good frames are returned in file order; overlaps between them are resolved by the caller.
"""

from __future__ import annotations

import numpy as np
from numba import njit

#: MAVLink wire constants (a tlog record is an 8-byte receive timestamp, then the frame).
TS_LEN = 8
HDR_V1 = 6
HDR_V2 = 10
SIG_LEN = 13
STX_V1 = 0xFE
STX_V2 = 0xFD


def crc_slices(crc_table: np.ndarray) -> np.ndarray:
    """(4, 256) uint16 tables that advance the CRC-16/MCRF4XX register by four bytes at once.

    The CRC is linear: over bytes b0..b3 from register c it is ``adv32(c ^ (b0 | b1 << 8)) ^
    adv16(b2 | b3 << 8)``, where ``adv16``/``adv32`` run 16/32 zero bits through the register;
    each is the XOR of one table entry per byte of its argument.
    """
    t8 = crc_table.astype(np.uint32)

    def adv(x, nbits):
        for _ in range(nbits // 8):
            x = (x >> 8) ^ t8[x & 0xFF]
        return x

    v = np.arange(256, dtype=np.uint32)
    return np.stack([adv(v, 32), adv(v << 8, 32), adv(v, 16), adv(v << 8, 16)]).astype(np.uint16)


@njit(cache=True, inline="always")
def _header(buf, h):
    """(record length, message id, incompat flags, header length) of the frame whose start byte is at h."""
    if buf[h] == STX_V2:
        inc = np.int64(buf[h + 2])
        msgid = np.int64(buf[h + 7]) | (np.int64(buf[h + 8]) << 8) | (np.int64(buf[h + 9]) << 16)
        hdr = HDR_V2
    else:
        inc = np.int64(0)
        msgid = np.int64(buf[h + 5])
        hdr = HDR_V1
    rl = TS_LEN + hdr + np.int64(buf[h + 1]) + 2 + (inc & 1) * SIG_LEN
    return rl, msgid, inc, hdr


@njit(cache=True, inline="always")
def _chained(buf, i, rl, a, size):
    nxt = i + rl
    q = min(nxt + TS_LEN, buf.shape[0] - 1)
    return buf[q] == STX_V1 or buf[q] == STX_V2 or a + nxt == size


@njit(cache=True, inline="always")
def _receive_ts(buf, i):
    v = np.uint64(0)
    for k in range(TS_LEN):
        v = (v << np.uint64(8)) | np.uint64(buf[i + k])
    return np.float64(v)


@njit(cache=True)
def _median(x):
    """``np.median`` of a short float64 array without NaNs (the same value: the middle element, or the
    mean ``(a + b) / 2`` of the two middle ones), by an insertion sort of a copy: numba's
    ``np.median`` costs more compile time (a selection algorithm) than this whole file otherwise."""
    v = x.copy()
    n = v.shape[0]
    for i in range(1, n):
        key = v[i]
        j = i - 1
        while j >= 0 and v[j] > key:
            v[j + 1] = v[j]
            j -= 1
        v[j + 1] = key
    h = n >> 1
    if n & 1:
        return v[h]
    return (v[h - 1] + v[h]) / 2


@njit(cache=True)
def good_frames(buf, m, h_lo, h_hi, n_max, a, size, known, extra, crc_table, slices, max_id, ts_window_us):
    """Record starts (in ``buf``) and message ids of the good frames whose start byte is in [h_lo, h_hi).

    ``n_max``: at least the number of start bytes in the range (``count_nonzero(buf[h_lo:h_hi] >= 0xFD)``).
    ``crc_table``: the byte-wise CRC table; ``slices``: :func:`crc_slices` of it (four bytes a step).
    """
    n_stx = n_max
    # pass 1: every candidate, with its chained flag (chained ones give the timestamp median)
    cand = np.empty(n_stx, np.int64)  # start-byte position, negated when not chained
    n = 0
    n_chain = 0
    for h in range(h_lo, h_hi):
        if buf[h] == STX_V1 or buf[h] == STX_V2:
            rl, msgid, inc, hdr = _header(buf, h)
            if _chained(buf, h - TS_LEN, rl, a, size):
                cand[n] = h
                n_chain += 1
            else:
                cand[n] = -h
            n += 1
    med = 0.0
    if n_chain > 0:
        step = max(1, n_chain // 257)
        ts = np.empty((n_chain + step - 1) // step, np.float64)
        k = 0
        c = 0
        for j in range(n):
            if cand[j] > 0:
                if c % step == 0:
                    ts[k] = _receive_ts(buf, cand[j] - TS_LEN)
                    k += 1
                c += 1
        med = _median(ts)
    # pass 2: checkable and plausible candidates → CRC
    starts = np.empty(n, np.int64)
    ids = np.empty(n, np.int64)
    n_good = 0
    for j in range(n):
        h = abs(cand[j])
        i = h - TS_LEN
        rl, msgid, inc, hdr = _header(buf, h)
        if i + rl > m or (inc & 0xFE) != 0 or msgid >= max_id or not known[msgid]:
            continue
        if cand[j] < 0:
            if n_chain == 0 or not abs(_receive_ts(buf, i) - med) < ts_window_us:
                continue
        end = h + hdr + np.int64(buf[h + 1])  # first CRC byte
        crc = np.int64(0xFFFF)
        p = h + 1
        while p + 3 < end:  # slicing by 4: four independent lookups per step
            y = crc ^ (np.int64(buf[p]) | (np.int64(buf[p + 1]) << 8))
            crc = np.int64(slices[0, y & 0xFF] ^ slices[1, y >> 8]
                           ^ slices[2, buf[p + 2]] ^ slices[3, buf[p + 3]])  # fmt: skip
            p += 4
        while p < end:
            crc = (crc >> 8) ^ np.int64(crc_table[(crc ^ np.int64(buf[p])) & 0xFF])
            p += 1
        crc = (crc >> 8) ^ np.int64(crc_table[(crc ^ np.int64(extra[msgid])) & 0xFF])
        if crc == (np.int64(buf[end]) | (np.int64(buf[end + 1]) << 8)):
            starts[n_good] = i
            ids[n_good] = msgid
            n_good += 1
    return starts[:n_good], ids[:n_good]
