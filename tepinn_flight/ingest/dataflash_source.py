"""What the DataFlash stream rules need from a log, whichever its encoding.

:mod:`.dataflash` (IMU/MAG/reference selection, clipping, boot epochs) is written once against
this small interface; :mod:`.dataflash_binary` and :mod:`.dataflash_text` implement it. Message
formats (:class:`~.dataflash_scan.MsgFormat`) are shared by both encodings.
"""

from __future__ import annotations

from typing import Protocol

import numpy as np

from .dataflash_scan import MsgFormat

#: Columns that number the instance of a multi-instance message (``IMU[I]``, ``XKQ[C]``...).
INSTANCE_COLS = ("I", "C", "IMU")
#: Rows decoded at a time (keeps the raw rows' memory constant).
DECODE_BLOCK_ROWS = 1 << 15


def instance_col(mf: MsgFormat) -> str | None:
    """The integer instance column of a message format, if it has one."""
    for c in INSTANCE_COLS:
        if c in mf.columns and mf.type_char(c) in "BbHhIi":
            return c
    return None


class DataflashSource(Protocol):
    """A parsed DataFlash log: formats by name, rows per message, decoded tables on demand."""

    kind: str  # "binary" or "text"
    formats: dict[str, MsgFormat]  # message name -> format (FMT itself excluded)
    counts: dict[str, int]  # message name -> rows in the log
    banner: str  # first non-empty text before the FMT lines (text logs), else ""
    corrupt_frames: int
    skipped_frames: int
    notes: list[str]

    def count(self, name: str) -> int:
        """Rows of one message (0 if absent)."""

    def order(self, name: str) -> np.ndarray:
        """File position of each row (increasing): merges streams in file order."""

    def instance_column(self, name: str, col: str) -> np.ndarray:
        """One column of every row as float64 (the instance numbers)."""

    def instance_counts(self, name: str, col: str) -> dict[int, int]:
        """Rows per instance value."""

    def table(self, name: str, cols: tuple[str, ...], rows: np.ndarray | None = None) -> np.ndarray:
        """``(n, len(cols))`` float64 of the rows (all, or the row indices ``rows``), SI as logged."""

    def strings(self, name: str, col: str) -> list[str]:
        """A string column of every row."""
