"""Compiled passes over a text DataFlash log's bytes (:mod:`.dataflash_text`): its lines and their commas in one
pass, and the bounds of one field on chosen lines. numpy's whole-file forms (a 20-MB log: two comparisons of every
byte, every comma's position kept, two sorted searches) cost more than the CSV parsing itself."""

from __future__ import annotations

import numpy as np
from numba import njit

NEWLINE, COMMA = 10, 44


@njit(cache=True)
def line_table(data, starts, ends, first, commas):
    """Fill, per line (split at newlines; the text after the last one is a line too): its first byte, its end (the
    newline's position, or the data's end), its first comma (−1: none) and how many commas it holds. The arrays hold
    at least (newlines + 1) rows; returns the number of lines."""
    line = 0
    start = 0
    f = -1
    nc = 0
    for i in range(len(data)):
        c = data[i]
        if c == COMMA:
            if f < 0:
                f = i
            nc += 1
        elif c == NEWLINE:
            starts[line] = start
            ends[line] = i
            first[line] = f
            commas[line] = nc
            line += 1
            start = i + 1
            f = -1
            nc = 0
    starts[line] = start
    ends[line] = len(data)
    first[line] = f
    commas[line] = nc
    return line + 1


@njit(cache=True)
def field_bounds(data, first, ends, i, last, lo, hi):
    """Bounds [lo, hi) of field ``i`` (counted after the message name, which ends at the comma ``first``) on each line;
    the last field (``last``) runs to the line's end, commas and all; a line with fewer fields: an empty field at its
    end."""
    for r in range(len(first)):
        p = first[r] + 1
        e = ends[r]
        k = 0
        while k < i and p <= e:  # past i commas
            while p < e and data[p] != COMMA:
                p += 1
            if p >= e:
                p = e + 1  # no such field
                break
            p += 1
            k += 1
        if p > e:
            lo[r] = e
            hi[r] = e
            continue
        lo[r] = p
        if last:
            hi[r] = e
        else:
            q = p
            while q < e and data[q] != COMMA:
                q += 1
            hi[r] = q
