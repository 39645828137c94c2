"""Human-readable renderings of :func:`tepinn_flight.record_stats.summarize`."""

from __future__ import annotations

import math


def _hz(v) -> str:
    return "n/a" if v is None else f"{v:.1f} Hz"


def _share(v) -> str:
    """A share of the IMU samples as `info` and `ingest` both print it (`ingest` had rounded 99.7 % to "100%")."""
    return f"{100 * v:.1f}%"


def record_summary_line(rec) -> str:
    m = rec.meta
    s = f"{len(rec)} samples, IMU {_hz(m.get('imu_rate_hz'))}, reference {m.get('reference_source')}"
    s += f" ({_share(m.get('reference_coverage', 0))} covered), {m.get('segments')} segment(s)"
    if not m.get("estimation_ok", True):
        s += " [IMU rate too low for estimation]"
    return s


def _vehicle(vehicle_type) -> str:
    """The log's vehicle and its class (:mod:`..vehicle_class`), with what the shipped estimator does with it."""
    from ..model.anchor import AnchorConfig, bias_gate_limits, speed_gate_allowed
    from ..vehicle_class import UNKNOWN, vehicle_class

    cls = vehicle_class(vehicle_type)
    if cls == UNKNOWN:
        return f"{vehicle_type or 'unknown'} (not named: TE-PINN's gates as for any vehicle)"
    shipped = AnchorConfig()
    gate = "may open" if speed_gate_allowed(shipped, vehicle_type) else "stays shut"
    said = bias_gate_limits(shipped, vehicle_type)
    bias = f", its uncalibrated-gyro gate {' and '.join(said)}" if said else ""
    return f"{vehicle_type} (class {cls}: TE-PINN's flight-speed gate {gate}{bias})"


def render_info(path, s: dict) -> str:
    lines = [f"{path}"]
    add = lambda k, v: lines.append(f"  {k:<20} {v}")  # noqa: E731
    add("format", s.get("format"))
    add("vehicle", _vehicle(s.get("vehicle_type")))
    add("autopilot/firmware", f"{s.get('autopilot')} / {s.get('firmware')}")
    sim = s.get("simulated")
    if sim:
        flown = sim.get("maneuvers") or []
        shown = ", ".join(flown[:8]) + (f", ... ({len(flown)} in all)" if len(flown) > 8 else "")
        add("simulated", f"{sim.get('aircraft')}, seed {sim.get('seed')}, sensor {sim.get('sensor_preset')}, turbulence "
            f"{sim.get('turbulence')}, {sim.get('termination')}" + (f"; maneuvers {shown}" if flown else ""))
    bridged_s = sum(g["gap_s"] for g in s.get("gaps", []) if g.get("bridged"))
    add("duration", f"{s.get('duration_s', 0):.1f} s in segments"
        + (f", {bridged_s:.1f} s more across the dropouts the estimators bridge" if bridged_s >= 0.05 else "")
        + f" (span {s.get('span_s', 0):.1f} s)")  # fmt: skip
    clock = s.get("log_clock_s")
    if clock:
        field = s.get("imu_time_field") or "the log's own time"
        boots = s.get("boot_epochs") or 1
        add("log clock", f"{clock[0]:.3f} s to {clock[1]:.3f} s ({field}: estimate's t_log_s; t = 0 is the first sample"
            + (f"; {boots} boots: it restarts at each)" if boots > 1 else ")"))
    add("samples", s.get("samples"))
    inst = s.get("imu_instances") or []
    if inst:
        for i in inst:
            add(f"IMU {i.get('instance')}", f"{i.get('name', '')} {i.get('samples', '?')} samples, {_hz(i.get('rate_hz'))}")
    add("IMU used", f"instance {s.get('imu_instance')} at {_hz(s.get('imu_rate_hz'))}"
        + ("" if s.get("estimation_ok", True) else "  ** too slow for windowed estimation **"))
    add("reference", f"{s.get('reference_source')} at {_hz(s.get('reference_rate_hz'))}, "
        f"covers {_share(s.get('reference_coverage', 0))} of IMU samples")
    chk = s.get("reference_check")
    if chk:
        add("reference check", chk["line"].removeprefix("reference attitude: "))
    trim = s.get("level_trim_rad")
    if trim:
        add("level trim", f"AHRS_TRIM_X/Y {math.degrees(trim[0]):.2f}°, {math.degrees(trim[1]):.2f}°: the estimates and the "
            "reference above are the IMU board's attitude; ArduPilot's ATT / ATTITUDE (and a ground station) show the "
            "vehicle's, turned by this trim")  # fmt: skip
    gaps = s.get("gaps", [])
    nb = s.get("bridged_gaps", 0)
    add("segments", f"{s.get('segments')} ({len(gaps)} break(s)"
        + (f", {nb} dropout(s) <= {1000 * s.get('max_bridged_gap_s', 0):.0f} ms bridged by the estimators)" if nb else ")"))
    slow = s.get("slower_stretches") or []
    inside = set()
    for r in slow:  # a lower logging rate: every step a break by the nominal period (one line, not one per break)
        add("", f"IMU at {r['rate_hz']:.1f} Hz from t={r['from_s']:.3f} s to {r['to_s']:.3f} s: each of its "
            f"{r['steps']} steps a break (bridged: filled at {_hz(s.get('imu_rate_hz'))} by the estimators)")  # fmt: skip
        inside.update(range(r["first_break"], r["first_break"] + r["steps"]))
    rest = [g for i, g in enumerate(gaps) if i not in inside]
    for g in rest[:10]:
        add("", f"break at t={g['at_s']:.3f} s, step {g['gap_s']:+.3f} s" + ("  (bridged)" if g.get("bridged") else ""))
    if len(rest) > 10:
        add("", f"... and {len(rest) - 10} more")
    if s.get("steps"):
        lost, n = s.get("lost_steps", 0), s["steps"]
        add("sample steps", f"{lost} of {n} ({100 * lost / n:.2f} %) of about two periods (a sample lost; the gyro is "
            f"integrated over each step's time), jitter {100 * s.get('step_jitter', 0):.1f} % of the period (σ)")  # fmt: skip
    noise = [f"{what} {s[k]:.3f} {unit}" for what, k, unit in (("accelerometer", "acc_noise_m_s2", "m/s²"),
                                                              ("gyro", "gyr_noise_deg_s", "°/s")) if s.get(k) is not None]  # fmt: skip
    if noise:  # (each needs a second's finite samples in one segment)
        add("sample noise", ", ".join(noise) + " per sample and axis (from second differences, median over 1-s windows; "
            "a vibrating frame shows here, fast motion adds)")  # fmt: skip
    add("max angular rate", f"{s.get('max_rate_deg_s', 0):.0f} deg/s (per axis {s.get('max_axis_rate_deg_s')})")
    clip = s.get("clipped_samples")
    if "gyr_clipped_samples" in s:
        clip = f"{clip} (gyro {s['gyr_clipped_samples']}: only those open the saturation gate)"
    add("clipped samples", clip)
    add("magnetometer", "yes" if s.get("has_mag") else "no")
    g = s.get("gnss")
    add("GNSS velocity", "no (the GNSS-aided tilt does not apply)" if not g else
        f"{g['source']} at {_hz(g['rate_hz'])}, covers {_share(g['coverage'])} of IMU samples, "
        f"ground speed up to {g['max_speed_m_s']:.1f} m/s")  # fmt: skip
    if "valid_fraction" in s:
        add("valid (scored)", f"{100 * s['valid_fraction']:.1f}% of samples")
    add("corrupt frames", s.get("corrupt_frames"))
    add("skipped frames", s.get("skipped_frames"))
    if s.get("duplicate_samples_dropped"):  # (review60: dropped unsaid)
        add("duplicate samples", f"{s['duplicate_samples_dropped']} dropped (a time stamp logged twice: the first kept)")
    for n in s.get("notes", []):
        add("note", n)
    return "\n".join(lines)



def render_model_info(d: dict) -> str:
    """``info MODEL``'s text: :func:`~tepinn_flight.model.describe.describe_model`'s dict."""
    lines = [d["file"]]
    add = lambda k, v: lines.append(f"  {k:<20} {v}")  # noqa: E731
    add("kind", f"{d['kind']} ({d['format']})" + (f", read from {d['read_from']}" if d.get("read_from") else ""))
    made = [f"written by tepinn-flight {d['written_by']}" if d.get("written_by") else "",
            f"exported by {d['exported_by']}" if d.get("exported_by") else "",
            f"opset {d['opset']}" if d.get("opset") is not None else "",
            f"from {d['source']}" if d.get("source") else ""]  # (review61: without exported_by, opset and source unsaid)
    if any(made):
        add("made", "; ".join(m for m in made if m))
    n = d["network"]
    add("network", f"{n['variant']}: {n['encoder']}, {n['n_layers']} layer(s) of width {n['d_model']}"
        + (f", {n['n_heads']} heads" if n["encoder"] == "transformer" else "")
        + f"; windows of {n['window_tokens']} tokens at {n['token_rate_hz']:g} Hz ({n['window_s']:g} s)"
        + (", magnetometer in" if n["magnetometer"] else "")
        + (f"; {n['parameters']:,} parameters" if "parameters" in n else ""))  # fmt: skip
    e = dict(d["estimator"])
    kind, note = e.pop("kind"), e.pop("note", None)
    add("estimator", kind + (": " + ", ".join(f"{k}={_setting(v)}" for k, v in e.items()) if e else ""))
    if note:
        add("", f"note: {note}")
    t = d.get("training") or {}
    if t:
        parts = [f"{t['train_files']} training and {t.get('val_files', 0)} validation files" if "train_files" in t else "",
                 f"IMU rates {'/'.join(f'{r:g}' for r in t['imu_rates_hz'])} Hz" if t.get("imu_rates_hz") else "",
                 f"seed {t['seed']}" if "seed" in t else "",
                 # (the epoch whose figures the file holds — the best for model.pt / best.pt, the last for last.pt —
                 # not how many ran: review61, review62)
                 f"figures from epoch {t['epoch']}" if "epoch" in t else "",
                 f"{t['elapsed_s'] / 60:.1f} min in by then" if "elapsed_s" in t else ""]  # fmt: skip
        add("training", ", ".join(p for p in parts if p) or "-")
        val = [f"network {t['val_tilt_rmse_deg']:.2f}°" if "val_tilt_rmse_deg" in t else "",
               f"NEES {t['val_nees']:.2f}" if "val_nees" in t else "",
               f"fused {t['fusion_val_tilt_rmse_mean_deg']:.2f}°" if "fusion_val_tilt_rmse_mean_deg" in t else ""]  # fmt: skip
        if any(val):
            add("validation", ", ".join(v for v in val if v) + " (tilt RMSE on its validation files, as trained)")
    if d.get("notes"):
        add("notes", d["notes"])
    add("beside it", d["beside"])
    return "\n".join(lines)


def _setting(v) -> str:
    if isinstance(v, (list, tuple)):
        return "/".join(map(str, v)) or "none"
    return f"{v:g}" if isinstance(v, float) else str(v)
