"""A log that ends in a crash: TE-PINN (shipped) beside VQF after a tumble, an impact and a rest upside down.

The issue's independent set holds an ArduCopter log ending in a crash, and none of our files does. This
appends a synthetic crash to simulated F450 flights (consumer IMU: a ±2000 °/s gyro, ±16 g
accelerometer; fresh flights from the given seeds, or records given on the command line): the motors
stop and the vehicle falls for 0.8 s, tumbling about a body axis at ``--rate`` °/s through ``--turn``
degrees (past the gyro's range when the rate is above 1960 °/s: those samples clipped and marked as a
reader marks them) while the airframe shakes (30 m/s² RMS); a 50-ms impact takes its velocity (the
receiver's last horizontal velocity and the fall's) to zero, the accelerometer reading that
deceleration up to its range; then it lies still upside down (or on its side) for 6 s. The receiver
reports the same motion (5 Hz, 0.1 s late). The truth is the integrated true rate. Printed per flight
and case, for TE-PINN and VQF 6-D, inclination RMSE before the crash (after a 5 s warm-up), over the
crash and the rest after it, and TE-PINN's median σ there, and TE-PINN with its GNSS aid off; at the
record's rate and decimated to 25 Hz (the training's averaging ``decimate``: the 25 Hz ArduCopter log
of the issue).

Session 21's version dropped the receiver's velocity to zero at the crash's start, which no
accelerometer showed: its "TE-PINN behind VQF after a tumble within the range" (12.5 vs 9.5°) was that
inconsistency. With one motion for both sensors (session 22, seeds 101–103) TE-PINN is ahead after a
tumble within the range (0.33–0.98° against VQF's 0.86–3.73°: the GNSS aid); what the crash did to the
seconds before it — the tumble's clipped samples turned the aid's heading offset over its 30-s window,
seed 102 1.06° → 2.21° before the crash — is gone since the aid leaves samples whose gyro clipped out
of its evidence (``GnssAidConfig.clip_guard``). After a tumble past the range TE-PINN was behind VQF on 2 of 3
flights (55.96 vs 51.60°, 45.65 vs 30.43° at 400 Hz): the saturation gate pulled toward the network's
tilt through the rest while its windows still held the tumble. Since session 23 the gate shuts 0.5 s into
the rest with the tilt set to the accelerometer's (``AnchorConfig.rest_relevel_s``): at rest from 1 s after
the impact 0.42–7.63° against VQF's 20–33°; over the whole crash still behind on 2 of 3 (43.52 vs 30.43°,
37.26 vs 30.01°: the tumble itself, where the gate pulls toward windows holding a free fall). Session 25's offline
smoothing (the default): over the crash and the 6 s after 6.99° against VQF's 21.02°, worse on none; a first version
ran VQF backward through the clipped tumble and spoiled the 5 s before it (before the crash 3.96–6.29° against VQF's
3.12–6.44°): the smoothing's runs now end before a clipped sample there (0.59–1.77°). Session 26: after the
re-levelling at rest the smoothed tilt had kept 17° of the tumble for 3 s (the whole stretch's forward pass crossed
the reset; σ at its floor, whole-file NEES 30–36): the runs now never cross a re-levelling either (rule 13).

    python benchmarks/crash_probe.py [--seeds 101 102 103] [--rate 2400 --turn 540] [--gyro-noise 2] [RECORD ...]
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

import numpy as np
import pandas as pd

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from tepinn_flight.evaluation.estimators import TepinnEstimator  # noqa: E402
from tepinn_flight.evaluation.metrics import error_quat_earth, inclination_error_rad  # noqa: E402
from tepinn_flight.evaluation.peers import make_peer  # noqa: E402
from tepinn_flight.ingest.saturation import ACCEL_FULL_SCALE_M_S2, CLIP_FRACTION, GYRO_FULL_SCALE_RAD_S  # noqa: E402
from tepinn_flight.model.checkpoint import default_model_path  # noqa: E402
from tepinn_flight.model.tokens import decimate_record  # noqa: E402
from tepinn_flight.quat import quat_conj, quat_from_rotvec, quat_mul, quat_rotate  # noqa: E402
from tepinn_flight.record import FlightRecord, read_record  # noqa: E402

G = 9.81


def _fixes_after(t_s, vel_ne, t_new, v_true_ne, rate_hz, latency_s, rng, noise_m_s=0.05):
    """The receiver's horizontal velocity on the samples from the record's last fix on: a fix every
    ``1 / rate_hz`` s reporting the true velocity ``latency_s`` earlier plus noise, linear between fixes on
    the IMU samples (as the simulator and ``ingest`` put them there). ``v_true_ne(t)`` is the true velocity."""
    ok = np.all(np.isfinite(vel_ne), axis=1)
    i_last = int(np.flatnonzero(ok)[-1])
    t_last = float(t_s[i_last])
    t_fix = np.arange(t_last + 1.0 / rate_hz, t_new[-1] + 1e-9, 1.0 / rate_hz)
    v_fix = v_true_ne(t_fix - latency_s) + rng.normal(0.0, noise_m_s, (len(t_fix), 2))
    tk = np.concatenate([[t_last], t_fix])
    vk = np.concatenate([vel_ne[i_last][None], v_fix])
    t_all = np.concatenate([t_s[i_last:], t_new])
    return i_last, np.stack([np.interp(t_all, tk, vk[:, k], right=np.nan) for k in range(2)], 1)


def with_crash(rec: FlightRecord, rate_dps: float, turn_deg: float, axis=(0.0, 1.0, 0.0), fall_s: float = 0.8,
               rest_s: float = 6.0, seed: int = 0) -> tuple[FlightRecord, float]:  # fmt: skip
    """``rec`` with the crash appended → (the record, the time the crash starts).

    Physically consistent, so that every estimator reads one motion: the motors stop and the vehicle
    falls freely for ``fall_s`` (the specific force is the airframe's shaking alone), tumbling about
    ``axis`` at ``rate_dps`` until it has turned ``turn_deg``; it keeps the horizontal velocity the
    receiver last reported and gains G·fall_s downward; a 50-ms impact takes that velocity to zero
    (the accelerometer reads the deceleration, clipped at its range); then it rests. The receiver
    (the record's rate, 5 Hz where it does not say, 0.1 s latency) reports the same velocity."""
    rng = np.random.default_rng(seed)
    d = rec.data
    t0, dt = float(d.t_s.iloc[-1]), float(np.median(np.diff(d.t_s)))
    q = rec.q_ref_wxyz[-1].copy()
    w = np.radians(rate_dps) * np.asarray(axis, float)
    n_turn = max(1, int(round(np.radians(turn_deg) / np.radians(rate_dps) / dt)))
    n_fall = max(n_turn, int(round(fall_s / dt)))
    n_hit = max(1, int(round(0.05 / dt)))
    has_gnss = {"gnss_vel_n_m_s", "gnss_vel_e_m_s"} <= set(d.columns)
    vel_ne = d[["gnss_vel_n_m_s", "gnss_vel_e_m_s"]].to_numpy(float) if has_gnss else None
    has_gnss = has_gnss and int(np.all(np.isfinite(vel_ne), axis=1).sum()) > 0
    v = np.zeros(3)
    if has_gnss:
        v[:2] = vel_ne[np.all(np.isfinite(vel_ne), axis=1)][-1]
    g_n = np.array([0.0, 0.0, G])
    rows, v_hist = [], []
    a_hit = None
    for i in range(n_fall + n_hit + int(rest_s / dt)):
        turning = i < n_turn
        if turning:
            q = quat_mul(q, quat_from_rotvec(w * dt))
            q = q / np.linalg.norm(q)
        if i < n_fall:  # free fall: no specific force but the shaking
            a_n = g_n
        elif i < n_fall + n_hit:
            a_hit = -v / ((n_fall + n_hit - i) * dt) if a_hit is None else a_hit  # constant deceleration to rest
            a_n = a_hit
        else:
            a_n = np.zeros(3)
        v = v + a_n * dt
        if i == n_fall + n_hit - 1:
            v = np.zeros(3)
        v_hist.append(v[:2].copy())
        f = quat_rotate(quat_conj(q), a_n - g_n)  # specific force, body axes
        if i < n_fall:
            f = f + rng.normal(0.0, 30.0, 3)
        gyr = np.clip((w if turning else 0.0) + rng.normal(0.0, 0.003, 3), -GYRO_FULL_SCALE_RAD_S, GYRO_FULL_SCALE_RAD_S)
        f = np.clip(f + rng.normal(0.0, 0.05, 3), -ACCEL_FULL_SCALE_M_S2, ACCEL_FULL_SCALE_M_S2)
        g_clip = bool(np.any(np.abs(gyr) >= CLIP_FRACTION * GYRO_FULL_SCALE_RAD_S))
        a_clip = bool(np.any(np.abs(f) >= CLIP_FRACTION * ACCEL_FULL_SCALE_M_S2))
        rows.append([t0 + (i + 1) * dt, *gyr, *f, *q, g_clip or a_clip, g_clip])
    cols = ["t_s", "gyr_x_rad_s", "gyr_y_rad_s", "gyr_z_rad_s", "acc_x_m_s2", "acc_y_m_s2", "acc_z_m_s2",
            "q_ref_w", "q_ref_x", "q_ref_y", "q_ref_z", "clipped", "gyr_clipped"]  # fmt: skip
    extra = pd.DataFrame(rows, columns=cols)
    for c in d.columns:
        if c not in extra:  # the segment and validity go on; a magnetometer reads nothing
            extra[c] = d[c].iloc[-1] if c in ("segment", "valid") else np.nan
    out = pd.concat([d, extra[list(d.columns)]], ignore_index=True)
    if has_gnss:
        t_new = extra.t_s.to_numpy()
        v_tab = np.concatenate([[vel_ne[np.all(np.isfinite(vel_ne), axis=1)][-1]], np.array(v_hist)])
        t_tab = np.concatenate([[t0], t_new])
        true_ne = lambda t: np.stack([np.interp(t, t_tab, v_tab[:, k]) for k in range(2)], 1)  # noqa: E731
        rate = float(rec.meta.get("gnss_rate_hz") or 5.0)
        i_last, v_new = _fixes_after(d.t_s.to_numpy(), vel_ne, t_new, true_ne, rate, 0.1, rng)
        out.loc[i_last:, ["gnss_vel_n_m_s", "gnss_vel_e_m_s"]] = v_new
    return FlightRecord(out, dict(rec.meta)), t0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("records", nargs="*", help="records to append the crash to (default: simulated flights)")
    ap.add_argument("--seeds", type=int, nargs="+", default=[101, 102, 103], help="F450 consumer flights, 60 s")
    ap.add_argument("--rate", type=float, nargs="+", default=[2400.0, 1500.0], help="tumble rates, deg/s")
    ap.add_argument("--turn", type=float, nargs="+", default=[540.0, 90.0], help="tumble angles (with --rate), deg")
    ap.add_argument("--gyro-noise", type=float, default=0.0,
                    help="white noise added to the whole record's gyro after the crash is appended, deg/s RMS per sample "
                         "and axis (a noisy gyro: the re-levelling at rest reads a still gyro)")  # fmt: skip
    args = ap.parse_args(argv)
    if len(args.rate) != len(args.turn):
        ap.error("--rate and --turn pair up: give as many of each")
    if args.records:
        flights = [(Path(p).name, read_record(p)) for p in args.records]
    else:
        from tepinn_flight.sim.simulate import simulate_record

        flights = [(f"F450 consumer seed {s}", simulate_record("F450", 60.0, 400.0, s, "consumer")) for s in args.seeds]
    tp = TepinnEstimator.from_checkpoint(default_model_path(), "tepinn")
    tp_no_aid = TepinnEstimator.from_checkpoint(default_model_path(), "tepinn")
    tp_no_aid.fusion = dataclasses.replace(tp_no_aid.fusion, gnss_aid=False)
    vqf = make_peer("vqf", [])
    print("inclination RMSE (deg): before the crash | the crash and the 6 s after | the rest from 1 s after the impact"
          " | TE-PINN's median sigma after")
    rows = []
    for name, base in flights:
        for rate, turn in zip(args.rate, args.turn):
            rec0, t0 = with_crash(base, rate, turn)
            if args.gyro_noise > 0:
                noisy = rec0.data.copy()
                g = rec0.gyr_rad_s + np.radians(args.gyro_noise) * np.random.default_rng(7).standard_normal((len(rec0), 3))
                noisy[["gyr_x_rad_s", "gyr_y_rad_s", "gyr_z_rad_s"]] = g
                rec0 = FlightRecord(noisy, dict(rec0.meta))
            for fac in (1, 16):
                rec = rec0 if fac == 1 else decimate_record(rec0, fac)
                hz = 1.0 / float(np.median(np.diff(rec.t_s)))
                before = (rec.t_s > rec.t_s[0] + 5.0) & (rec.t_s <= t0)
                after = rec.t_s > t0
                rest = rec.t_s > t0 + 0.85 + 1.0  # the fall (0.8 s) and the impact (0.05 s), then 1 s
                out = {}
                for label, est in (("TE-PINN", tp), ("no aid", tp_no_aid), ("VQF", vqf)):
                    df = est.estimate(rec)
                    q = df[["q_est_w", "q_est_x", "q_est_y", "q_est_z"]].to_numpy()
                    e = np.degrees(inclination_error_rad(error_quat_earth(q, rec.q_ref_wxyz)))
                    out[label] = tuple(float(np.sqrt(np.mean(e[m] ** 2))) for m in (before, after, rest))
                    if label == "TE-PINN":
                        sig = float(np.degrees(np.median(df["sigma_rad"].to_numpy()[after])))
                rows.append((out["TE-PINN"][1], out["VQF"][1], out["TE-PINN"][2], out["VQF"][2]))
                print(f"  {name:24s} {rate:5.0f} deg/s through {turn:4.0f} deg, {hz:4.0f} Hz: "
                      f"TE-PINN {out['TE-PINN'][0]:5.2f} | {out['TE-PINN'][1]:6.2f} | {out['TE-PINN'][2]:6.2f} | sigma {sig:5.2f}   "
                      f"(no GNSS aid {out['no aid'][1]:6.2f})   VQF {out['VQF'][0]:5.2f} | {out['VQF'][1]:6.2f} | {out['VQF'][2]:6.2f}")  # fmt: skip
    a = np.array(rows)
    print(f"after the crash, mean over {len(a)} cases: TE-PINN {a[:, 0].mean():.2f} deg, VQF {a[:, 1].mean():.2f} deg "
          f"(ratio {a[:, 0].mean() / a[:, 1].mean():.2f}); TE-PINN worse on {int(np.sum(a[:, 0] > a[:, 1]))}; at rest from 1 s "
          f"after the impact: TE-PINN {a[:, 2].mean():.2f} deg, VQF {a[:, 3].mean():.2f} deg, TE-PINN worse on "
          f"{int(np.sum(a[:, 2] > a[:, 3]))}")  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
