"""The live estimator's per-sample work in one compiled call (:class:`.streaming.StreamingEstimator`'s usual push).

A push that applies no network window — every push but those where a token closes and its window runs — adds the
sample to the open token, steps the older fusion (the pulls' target) and the anchored filter, and takes the older
fusion's tilt while the saturation gate holds. Each of those was a compiled call already; the Python between them
(argument checks, tuples, property reads) was most of a quiet record's cost per sample (session 51). :func:`live_sample`
makes the same calls, in the same order, on the same buffers: the same numbers to the bit (tested against the
push that calls them one by one from Python, which still runs where a window applies or the filter is not yet made).

The open token is one float array (:data:`TOK_*`): sums of the gyro, accelerometer and magnetometer, the
magnetometer's count, the sample count, the clipped count and the last sample's time.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from . import anchor_steps as S
from .anchor_kernels import fusion_tilt_f
from .fusion import _O_OUT as _FUS_OUT
from .fusion import _step_live

# the open token's slots
TOK_G, TOK_A, TOK_M, TOK_M_N, TOK_N, TOK_CLIP, TOK_T_LAST = 0, 3, 6, 9, 10, 11, 12
N_TOK = 13

# live_sample's output slots: the estimate's q (4), σ, bias (3); whether q is finite; the older fusion's step:
# whether it gave an attitude, its q (4) and bias (3)
OUT_Q, OUT_SIGMA, OUT_BIAS, OUT_Q_OK, OUT_FUS_OK, OUT_FUS_Q, OUT_FUS_BIAS = 0, 4, 5, 8, 9, 10, 14
N_OUT = 17

_GATE_SAT = S.O_F + S.F_GATE_PARTS + 1  # the anchored filter's saturation gate, in its buffer


def new_token() -> np.ndarray:
    """An empty token."""
    tok = np.zeros(N_TOK)
    tok[TOK_T_LAST] = math.nan
    return tok


@njit(cache=True)
def token_add(tok, t, gx, gy, gz, ax, ay, az, mx, my, mz, clipped):
    """The sample into the open token (the magnetometer where all three axes are finite)."""
    tok[TOK_G] += gx
    tok[TOK_G + 1] += gy
    tok[TOK_G + 2] += gz
    tok[TOK_A] += ax
    tok[TOK_A + 1] += ay
    tok[TOK_A + 2] += az
    if math.isfinite(mx) and math.isfinite(my) and math.isfinite(mz):
        tok[TOK_M] += mx
        tok[TOK_M + 1] += my
        tok[TOK_M + 2] += mz
        tok[TOK_M_N] += 1.0
    tok[TOK_N] += 1.0
    if clipped:
        tok[TOK_CLIP] += 1.0
    tok[TOK_T_LAST] = t


@njit(cache=True)
def live_sample(tok, fus, anch, cb, t, gx, gy, gz, ax, ay, az, mx, my, mz, clipped, gyr_clipped, no_window, use_mag,
                clip_tilt, sigma_add, out):  # fmt: skip
    """One sample whose push applies no window: into the token, the older fusion's step (``fus``:
    :class:`.fusion.AttitudeFusion`'s buffer; ``no_window`` is False — a typed argument, not a constant: the step is
    then the one the Python push calls, not a second compile of it), the anchored filter's (``anch``, ``cb``:
    :class:`.anchor.AnchoredVQF`'s; with ``gyr_clipped`` the caller has made room in ``cb``), its 9-D attitude with
    ``use_mag``, the older fusion's tilt while the saturation gate holds (``clip_tilt``) and σ² + ``sigma_add`` (σ's
    aircraft term) → ``out`` (:data:`OUT_*`)."""
    token_add(tok, t, gx, gy, gz, ax, ay, az, mx, my, mz, clipped)
    fus_ok = _step_live(fus, t, gx, gy, gz, clipped, no_window, 0.0)
    S.update_one(anch, cb, t, gx, gy, gz, ax, ay, az, mx, my, mz, gyr_clipped)
    o = S.O_OUT + (4 if use_mag else 0)
    qw, qx, qy, qz = anch[o], anch[o + 1], anch[o + 2], anch[o + 3]
    f = _FUS_OUT  # the older fusion's output: q (4), σ, bias (3)
    q_ok = math.isfinite(qw + qx + qy + qz)
    if q_ok and anch[_GATE_SAT] > 0 and clip_tilt and fus_ok:
        qw, qx, qy, qz = fusion_tilt_f(qw, qx, qy, qz, fus[f], fus[f + 1], fus[f + 2], fus[f + 3])
    sig = anch[S.O_OUT + 8]
    if sigma_add != 0.0:
        sig = math.sqrt(sig * sig + sigma_add)
    out[OUT_Q], out[OUT_Q + 1], out[OUT_Q + 2], out[OUT_Q + 3] = qw, qx, qy, qz
    out[OUT_SIGMA] = sig
    for i in range(3):
        out[OUT_BIAS + i] = anch[S.O_OUT + 9 + i]
        out[OUT_FUS_BIAS + i] = fus[f + 5 + i]
    for i in range(4):
        out[OUT_FUS_Q + i] = fus[f + i]
    out[OUT_Q_OK] = 1.0 if q_ok else 0.0
    out[OUT_FUS_OK] = 1.0 if fus_ok else 0.0
