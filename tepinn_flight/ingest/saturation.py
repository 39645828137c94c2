"""When an IMU sample counts as clipped: one rule for every reader and the live bridge.

A sample is at its range when an axis reaches ``CLIP_FRACTION`` of the full scale it can show —
the sensor's (ArduPilot and PX4 configure ±2000 °/s and ±16 g) or, for MAVLink's int16 messages
(``RAW_IMU``, ``SCALED_IMU*``: mrad/s), the field's own limit, ±32.767 rad/s (1877 °/s), which a
2000 °/s gyro passes first. ArduPilot's logged IMU is a low-passed snapshot, so a saturated sensor
shows slightly below full scale: hence 98 %, not 100 %.

The gyro's saturation is kept apart (a record's ``gyr_clipped``): only it makes the integrated rate
wrong; an accelerometer at its range is marked ``clipped`` alone.
"""

from __future__ import annotations

import numpy as np

from ..conventions import DEG_TO_RAD, GRAVITY_M_S2, MRAD_S_TO_RAD_S

GYRO_FULL_SCALE_RAD_S = 2000.0 * DEG_TO_RAD
ACCEL_FULL_SCALE_M_S2 = 16.0 * GRAVITY_M_S2
CLIP_FRACTION = 0.98
#: the largest rate an int16 mrad/s field (RAW_IMU, SCALED_IMU*) can carry
INT16_MRAD_S_LIMIT_RAD_S = 32767 * MRAD_S_TO_RAD_S


def gyro_full_scale_rad_s(message: str | None = None) -> float:
    """The largest rate a sample of ``message`` can show (the sensor's range, or an int16 MAVLink
    field's limit where that is lower; None: a log's float rates, the sensor's range)."""
    if message is None or message == "HIGHRES_IMU":
        return GYRO_FULL_SCALE_RAD_S
    return min(GYRO_FULL_SCALE_RAD_S, INT16_MRAD_S_LIMIT_RAD_S)


def gyro_saturated(gyr_rad_s: np.ndarray, full_scale_rad_s: float = GYRO_FULL_SCALE_RAD_S) -> np.ndarray:
    """(N,) rows with a gyro axis at ≥ ``CLIP_FRACTION`` of ``full_scale_rad_s``."""
    return (np.abs(np.asarray(gyr_rad_s, np.float64)) >= CLIP_FRACTION * full_scale_rad_s).any(axis=1)


#: a clipping bit a log sets per raw sample (PX4's ``gyro_clipping``) counts as the gyro's saturation where the logged
#: rate has an axis at this share of the full scale or more (rule 35, session 61)
CREDIBLE_CLIP_FRACTION = 0.5


def credible_gyro_clipping(gyr_rad_s: np.ndarray, bits: np.ndarray,
                           full_scale_rad_s: float = GYRO_FULL_SCALE_RAD_S) -> np.ndarray:  # fmt: skip
    """(N,) the rows of ``bits`` — a log's own per-raw-sample gyro clipping flags — where the logged rate shows a
    saturation: an axis at ≥ ``CREDIBLE_CLIP_FRACTION`` of ``full_scale_rad_s``. A raw sample clipped inside an
    interval whose logged mean rate is under half the range (a vibration spike at kHz) is a short part of it and loses
    a small part of its rotation: no saturation handling is due there (review61: such bits had opened the saturation
    gate, a hand-held trial 0.27° → 3.80°)."""
    g = np.abs(np.asarray(gyr_rad_s, np.float64))
    with np.errstate(invalid="ignore"):
        shows = np.nan_to_num(g, nan=0.0).max(axis=1) >= CREDIBLE_CLIP_FRACTION * full_scale_rad_s
    return np.asarray(bits, bool) & shows


def accel_saturated(acc_m_s2: np.ndarray) -> np.ndarray:
    """(N,) rows with an accelerometer axis at ≥ ``CLIP_FRACTION`` of ±16 g."""
    return (np.abs(np.asarray(acc_m_s2, np.float64)) >= CLIP_FRACTION * ACCEL_FULL_SCALE_M_S2).any(axis=1)


def saturated_f(gyr_rad_s, acc_m_s2, full_scale_rad_s: float) -> tuple[bool, bool]:
    """(clipped, gyr_clipped) of one sample in plain floats (the live bridge): the rows' rules above."""
    lim = CLIP_FRACTION * full_scale_rad_s
    g = any(abs(v) >= lim for v in gyr_rad_s)
    a = any(abs(v) >= CLIP_FRACTION * ACCEL_FULL_SCALE_M_S2 for v in acc_m_s2)
    return g or a, g
