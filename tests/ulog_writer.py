"""A minimal ULog writer (file header, formats, subscriptions, data, dropouts: what pyulog reads) for crafted PX4
logs in tests (session 53). Pure struct packing of the format's documented messages."""

from __future__ import annotations

import struct

import numpy as np

_TYPES = {"uint64_t": "Q", "int64_t": "q", "uint32_t": "I", "int32_t": "i", "uint16_t": "H", "int16_t": "h",
          "uint8_t": "B", "int8_t": "b", "float": "f", "double": "d", "bool": "?", "char": "c"}  # fmt: skip

#: sensor_combined as PX4 v1.9-v1.14 log it (the accelerometer's clipping field, none for the gyro)
SENSOR_COMBINED_V1_14 = [("float[3]", "gyro_rad"), ("uint32_t", "gyro_integral_dt"),
                         ("int32_t", "accelerometer_timestamp_relative"), ("float[3]", "accelerometer_m_s2"),
                         ("uint32_t", "accelerometer_integral_dt"), ("uint8_t", "accelerometer_clipping")]  # fmt: skip

#: sensor_combined as PX4 v1.15 on log it (per-axis clipping bits for both sensors)
SENSOR_COMBINED_V1_15 = [*SENSOR_COMBINED_V1_14, ("uint8_t", "gyro_clipping")]


class ULogWriter:
    def __init__(self, t0_us: int = 0):
        self.buf = bytearray(b"ULog\x01\x12\x35\x01" + struct.pack("<Q", t0_us))
        self.buf += self._msg(b"B", bytes(40))  # flag bits: no incompatible flags, no appended data
        self.formats: dict[str, str] = {}
        self.subs: dict[tuple[str, int], int] = {}

    @staticmethod
    def _msg(kind: bytes, payload: bytes) -> bytes:
        return struct.pack("<HB", len(payload), ord(kind)) + payload

    def fmt(self, name: str, fields: list[tuple[str, str]]) -> None:
        """A message format: ``fields`` (type, name) after the ``timestamp`` the format begins with."""
        fields = [("uint64_t", "timestamp"), *fields]
        self.buf += self._msg(b"F", (name + ":" + "".join(f"{t} {n};" for t, n in fields)).encode())
        st = "<"
        for t, _ in fields:
            base, _, cnt = t.rstrip("]").partition("[")
            st += (cnt or "") + _TYPES[base]
        self.formats[name] = st

    def subscribe(self, name: str, multi_id: int = 0) -> None:
        self.subs[(name, multi_id)] = mid = len(self.subs)
        self.buf += self._msg(b"A", struct.pack("<BH", multi_id, mid) + name.encode())

    def data(self, name: str, multi_id: int, *vals) -> None:
        flat = []
        for v in vals:
            flat += list(v) if isinstance(v, (list, tuple, np.ndarray)) else [v]
        self.buf += self._msg(b"D", struct.pack("<H", self.subs[(name, multi_id)]) + struct.pack(self.formats[name], *flat))

    def dropout(self, ms: int) -> None:
        self.buf += self._msg(b"O", struct.pack("<H", ms))

    def write(self, path):
        with open(path, "wb") as f:
            f.write(bytes(self.buf))
        return path
