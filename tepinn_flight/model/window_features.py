"""The network's token features computed outside the graph: :meth:`.network.TEPINN.features` for a
trained (frozen) sensor model, compiled with numba, one window per loop pass.

Used by :class:`~.runtime.OnnxRunner`: an export (version 2 on) holds the encoder and the heads
(version 3: their linear layers; :mod:`.head_physics` computes the attitude from them); the physics features — the sensor model, the per-token RK4
rotations and their prefix products, the specific forces and the centripetal matrices turned into
the window's last body frame — are a few hundred tiny tensor operators in a graph (about half of a
batch-1 run in onnxruntime, session 11) and a few microseconds here. Computed in float64 and handed
to the graph in float32; equal to the PyTorch features to float32 round-off (``tests/test_window_features.py``).

The formulas are the network's (``network.py``, ``physics.py``: ``rk4_delta``, ``prefix_products``,
``trust_after_clipping``); rotations are :mod:`..quat_scalar`'s. :class:`SensorValues` carries the
trained sensor model's effective values, which an export stores in its metadata.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np
from numba import njit

from ..conventions import GRAVITY_M_S2
from ..quat_scalar import qmul, qnorm, qrot
from .config import CEN_FEATURE_M_S, ModelConfig


@dataclass(frozen=True)
class SensorValues:
    """A trained sensor model's effective values (after its limits): ``ω_c = (ω − b_g − S_g ω)·(1 + κ·clip)``,
    ``a_c = a − b_a − S_a a``; ``kappa`` None without declipping."""

    b_g: tuple
    S_g: tuple
    b_a: tuple
    S_a: tuple
    kappa: float | None

    def to_json(self) -> dict:
        return {"b_g": list(self.b_g), "S_g": [list(r) for r in self.S_g], "b_a": list(self.b_a),
                "S_a": [list(r) for r in self.S_a], "kappa": self.kappa}  # fmt: skip

    @classmethod
    def from_json(cls, d: dict) -> "SensorValues":
        """From an export's metadata (untrusted: shapes and finiteness are checked, ValueError)."""
        v = cls(tuple(map(float, d["b_g"])), tuple(tuple(map(float, r)) for r in d["S_g"]),
                tuple(map(float, d["b_a"])), tuple(tuple(map(float, r)) for r in d["S_a"]),
                None if d.get("kappa") is None else float(d["kappa"]))  # fmt: skip
        shapes_ok = len(v.b_g) == len(v.b_a) == len(v.S_g) == len(v.S_a) == 3 and all(len(r) == 3 for r in v.S_g + v.S_a)
        values = (*v.b_g, *v.b_a, *sum(v.S_g + v.S_a, ()), 0.0 if v.kappa is None else v.kappa)
        if not shapes_ok or not all(math.isfinite(x) for x in values) or (v.kappa is not None and v.kappa < 0):
            raise ValueError("sensor_model: b_g, b_a need 3 values, S_g, S_a 3×3, κ ≥ 0, all finite")
        return v

    @classmethod
    def identity(cls) -> "SensorValues":
        z3, z33 = (0.0, 0.0, 0.0), ((0.0,) * 3,) * 3
        return cls(z3, z33, z3, z33, None)


def feature_names(config: ModelConfig) -> tuple[str, ...]:
    """The arrays :func:`window_features` returns for ``config``, in the export's input order."""
    names = ["x", "t_rel"]
    if config.physics:
        names += ["v", "u"]
        if config.centripetal:
            names.append("cen")
            if config.centripetal_rate:
                names.append("cen_rate")
    return tuple(names)


def window_features(config: ModelConfig, sensor: SensorValues, gyr, acc, count, t_rel, dt, mag=None, clip=None) -> dict:
    """Windows (B, K, …) as :meth:`.network.TEPINN.forward` takes them → float32 feature arrays:
    ``x`` (B, K, n_inputs) before normalisation, ``t_rel`` (B, K), and with physics ``v`` (B, K, 3)
    in g, ``u`` (B, K), with the centripetal term ``cen`` (B, K, 3, 3) and ``cen_rate``."""
    f64 = lambda a: np.ascontiguousarray(a, np.float64)  # noqa: E731
    gyr, acc, count, t_rel, dt = f64(gyr), f64(acc), f64(count), f64(t_rel), f64(dt)
    b, k = count.shape
    clip = np.zeros((b, k)) if clip is None else f64(clip)
    if gyr.shape != (b, k, 3) or acc.shape != (b, k, 3) or t_rel.shape != (b, k) or dt.shape != (b, k) or clip.shape != (b, k):
        # (the compiled loop does not check its indices)
        raise ValueError(f"windows of mismatched shapes: gyr {gyr.shape}, acc {acc.shape}, count {count.shape}, "
                         f"t_rel {t_rel.shape}, dt {dt.shape}, clip {clip.shape}")  # fmt: skip
    use_mag = bool(config.use_mag)
    mag = f64(np.nan_to_num(mag)) if use_mag and mag is not None else np.zeros((b, k, 3))
    if mag.shape != (b, k, 3):
        raise ValueError(f"windows of mismatched shapes: mag {mag.shape}, count {count.shape}")
    x = np.empty((b, k, config.n_inputs), np.float32)
    v = np.empty((b, k, 3), np.float32)
    u = np.empty((b, k), np.float32)
    cen = np.empty((b, k, 3, 3), np.float32)
    cen_rate = np.empty((b, k, 3, 3), np.float32)
    b_g, s_g, b_a, s_a, kappa = _sensor_arrays(sensor)
    _features(gyr, acc, count, t_rel, dt, clip, mag, b_g, s_g, b_a, s_a, kappa, bool(config.physics),
              bool(config.clip_aware), bool(config.centripetal), bool(config.centripetal_rate), use_mag, GRAVITY_M_S2,
              CEN_FEATURE_M_S, x, v, u, cen, cen_rate)  # fmt: skip
    out = {"x": x, "t_rel": t_rel.astype(np.float32), "v": v, "u": u, "cen": cen, "cen_rate": cen_rate}
    return {n: out[n] for n in feature_names(config)}


@functools.lru_cache(maxsize=8)
def _sensor_arrays(sensor: SensorValues) -> tuple:
    """(b_g, S_g, b_a, S_a as float64 arrays, κ or −1 without declipping), once per sensor model
    (the live path calls :func:`window_features` once per token)."""
    arrays = tuple(np.array(v, np.float64) for v in (sensor.b_g, sensor.S_g, sensor.b_a, sensor.S_a))
    for a in arrays:
        a.setflags(write=False)
    return (*arrays, -1.0 if sensor.kappa is None else float(sensor.kappa))


@njit(cache=True)
def rk4_delta_f(wx, wy, wz, dt):
    """:func:`.physics.rk4_delta` of one token: the RK4 step from the identity, renormalised."""
    vx, vy, vz = 0.5 * dt * wx, 0.5 * dt * wy, 0.5 * dt * wz
    p2 = vx * vx + vy * vy + vz * vz
    s = 1.0 - p2 / 6.0
    return qnorm(1.0 - 0.5 * p2 + p2 * p2 / 24.0, s * vx, s * vy, s * vz)


@njit(cache=True)
def _features(gyr, acc, count, t_rel, dt, clip, mag, b_g, s_g, b_a, s_a, kappa, physics, clip_aware, centripetal,
              centripetal_rate, use_mag, g, cen_scale, x, v, u, cen, cen_rate):  # fmt: skip
    nb, k = count.shape
    wc = np.empty((k, 3))
    ac = np.empty((k, 3))
    pe = np.empty((k, 4))  # P_j: body(t_j) → body(t_0) at token ends
    pm = np.empty((k, 4))  # at token midpoints
    for b in range(nb):
        for j in range(k):
            for i in range(3):
                wc[j, i] = gyr[b, j, i]
                ac[j, i] = acc[b, j, i]
            if physics:
                for i in range(3):
                    wc[j, i] = gyr[b, j, i] - b_g[i] - (gyr[b, j, 0] * s_g[i, 0] + gyr[b, j, 1] * s_g[i, 1] + gyr[b, j, 2] * s_g[i, 2])
                    ac[j, i] = acc[b, j, i] - b_a[i] - (acc[b, j, 0] * s_a[i, 0] + acc[b, j, 1] * s_a[i, 1] + acc[b, j, 2] * s_a[i, 2])
                if kappa >= 0.0:
                    f = 1.0 + kappa * clip[b, j]
                    for i in range(3):
                        wc[j, i] *= f
            for i in range(3):
                x[b, j, i] = wc[j, i]
                x[b, j, 3 + i] = ac[j, i] / g
            x[b, j, 6] = math.log1p(count[b, j])
            x[b, j, 7] = clip[b, j]
        col = 8
        if physics:
            pe[0, 0], pe[0, 1], pe[0, 2], pe[0, 3] = 1.0, 0.0, 0.0, 0.0
            pm[0, 0], pm[0, 1], pm[0, 2], pm[0, 3] = 1.0, 0.0, 0.0, 0.0
            for j in range(1, k):
                d = rk4_delta_f(wc[j, 0], wc[j, 1], wc[j, 2], dt[b, j])
                pe[j, 0], pe[j, 1], pe[j, 2], pe[j, 3] = qmul(pe[j - 1, 0], pe[j - 1, 1], pe[j - 1, 2], pe[j - 1, 3], d[0], d[1], d[2], d[3])
                h = rk4_delta_f(wc[j, 0], wc[j, 1], wc[j, 2], 0.5 * dt[b, j])
                pm[j, 0], pm[j, 1], pm[j, 2], pm[j, 3] = qmul(pe[j - 1, 0], pe[j - 1, 1], pe[j - 1, 2], pe[j - 1, 3], h[0], h[1], h[2], h[3])
            lw, lx, ly, lz = pe[k - 1, 0], -pe[k - 1, 1], -pe[k - 1, 2], -pe[k - 1, 3]  # P_K*
            after = 0.0
            for j in range(k - 1, -1, -1):
                tw, tx, ty, tz = qmul(lw, lx, ly, lz, pm[j, 0], pm[j, 1], pm[j, 2], pm[j, 3])  # body(t_j mid) → body(t_K)
                r = qrot(tw, tx, ty, tz, ac[j, 0], ac[j, 1], ac[j, 2])
                for i in range(3):
                    v[b, j, i] = r[i] / g
                    x[b, j, col + i] = r[i] / g
                after += clip[b, j]
                u[b, j] = 1.0 if (not clip_aware or after <= 0.0 or j == k - 1) else 0.0
                c = col + 3
                if clip_aware:
                    x[b, j, c] = u[b, j]
                    c += 1
                if centripetal:
                    t_mid = t_rel[b, j] if j == 0 else t_rel[b, j] - 0.5 * dt[b, j]
                    for e in range(3):
                        ex, ey, ez = (1.0 if e == 0 else 0.0), (1.0 if e == 1 else 0.0), (1.0 if e == 2 else 0.0)
                        cx = wc[j, 1] * ez - wc[j, 2] * ey  # ω_c,j × e_k
                        cy = wc[j, 2] * ex - wc[j, 0] * ez
                        cz = wc[j, 0] * ey - wc[j, 1] * ex
                        r = qrot(tw, tx, ty, tz, cx, cy, cz)
                        re = qrot(tw, tx, ty, tz, ex, ey, ez)
                        for i in range(3):
                            cen[b, j, e, i] = r[i] / g
                            x[b, j, c + 3 * e + i] = cen_scale * (r[i] / g)
                            cen_rate[b, j, e, i] = t_mid * (r[i] / g) + re[i] / g
            col += 3 + (1 if clip_aware else 0) + (9 if centripetal else 0)
        if use_mag:
            for j in range(k):
                for i in range(3):
                    x[b, j, col + i] = mag[b, j, i] / 50.0
