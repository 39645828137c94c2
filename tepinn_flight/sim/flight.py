"""Fly one simulated flight in JSBSim and return its noise-free truth.

``fly(aircraft, duration_s, rate_hz, seed, maneuvers, turbulence)`` builds the aircraft, draws a
site (latitude, terrain height, Earth magnetic field, wind) and a chain of maneuvers from the seed,
steps JSBSim at ``rate_hz`` with our controller in the loop, and logs per step:

* attitude ``q_nb_wxyz`` from JSBSim's Euler angles (3-2-1, relative to local NED);
* body rates ``velocities/{p,q,r}i-rad_sec`` (inertial: what a gyro senses, Earth rate included);
* specific force at the CG, ``forces/fb{x,y,z}-total-lbs / inertia/mass-slugs`` (all non-gravity
  forces over mass, body FRD);
* position (tangent-plane NED from the start point, from ECEF) and NED velocity.

Everything is read after ``run()``: JSBSim integrates first (FGPropagate is the first model of a
step) and evaluates the forces afterwards, so sample k holds the state at t_k and the forces at
that same state; the next step integrates them (velocity with Adams-Bashforth 2, which a test
checks to 1e-3 m/s^2). The attitude is integrated by JSBSim with Buss' second-order method so it
matches the logged rates (see :mod:`tepinn_flight.sim.jsbsim_env`). A flight that would hit the
ground or produce a non-finite number stops cleanly: the trajectory is cut to its valid part and
``meta["termination"]`` says why.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

import numpy as np

from tepinn_flight.errors import ConfigError
from tepinn_flight.quat import quat_from_euler_zyx
from tepinn_flight.sim.jsbsim_env import FT_TO_M, jsbsim_version, open_fdm
from tepinn_flight.sim.jsbsim_native import Stepper
from tepinn_flight.sim.maneuvers import Sequencer, validate_names
from tepinn_flight.sim.quad_flight_kernel import FINISHED, STOPPED
from tepinn_flight.sim.truth import TruthTrajectory
from tepinn_flight.sim.vibration import motor_vibration

MIN_RATE_HZ = 50.0
MAX_RATE_HZ = 4000.0
MIN_SIM_HZ = 400.0  # below this output rate JSBSim takes several steps per logged sample
N_COLUMNS = 20  # logged per sample: Euler angles, rates, ECEF, NED velocity, 4 extras, forces, mass
WARMUP_S = 1.0  # controller settles before logging starts (motors spun up, trim transients gone)
#: what the controllers' ``step(state)`` takes: read by fly() with the truth after a run() that a
#: control update follows (the same numbers the controller would read: property reads saved)
STATE_PATHS = ("attitude/phi-rad", "attitude/theta-rad", "attitude/psi-rad", "velocities/pi-rad_sec",
               "velocities/qi-rad_sec", "velocities/ri-rad_sec", "position/h-agl-ft", "velocities/v-north-fps",
               "velocities/v-east-fps", "velocities/v-down-fps")  # fmt: skip
#: the logged row's first 16 and last 4 columns (the vehicle's 4 extra properties go between)
TRUTH_PATHS = ("attitude/phi-rad", "attitude/theta-rad", "attitude/psi-rad", "velocities/pi-rad_sec",
               "velocities/qi-rad_sec", "velocities/ri-rad_sec", "position/ecef-x-ft", "position/ecef-y-ft",
               "position/ecef-z-ft", "velocities/v-north-fps", "velocities/v-east-fps",
               "velocities/v-down-fps")  # fmt: skip
TRUTH_PATHS_END = ("forces/fbx-total-lbs", "forces/fby-total-lbs", "forces/fbz-total-lbs", "inertia/mass-slugs")
#: read after each logged step before the row; a flight ends where it is not above the vehicle's floor
AGL_PATH = "position/h-agl-ft"
#: STATE_PATHS from the row: its columns, and where the height goes in
STATE_COLS = tuple(TRUTH_PATHS.index(p) for p in STATE_PATHS if p != AGL_PATH)
STATE_H_AT = STATE_PATHS.index(AGL_PATH)

#: MIL-F-8785C (Dryden) turbulence presets: wind speed at 20 ft AGL (ft/s) and severity index
TURBULENCE = {
    "none": (0.0, 0),
    "light": (25.0, 3),
    "moderate": (50.0, 4),
    "severe": (75.0, 6),
}


@dataclass(frozen=True)
class AircraftSpec:
    name: str
    vehicle_type: str  # "fixed-wing" or "multirotor"
    description: str
    build: Callable[[], object]  # -> vehicle (QuadVehicle / FixedWingVehicle)
    library: Callable[[], tuple[dict, type, dict]]  # -> (maneuvers, recovery class, weights)


def _quad(params_name: str):
    def build():
        from tepinn_flight.sim import multirotor

        return multirotor.QuadVehicle(getattr(multirotor, params_name))

    return build


def _quad_library():
    from tepinn_flight.sim import multirotor_maneuvers as mm

    return mm.LIBRARY, mm.Recovery, mm.WEIGHTS


def _fixed_wing(params_name: str):
    def build():
        from tepinn_flight.sim import fixed_wing

        return fixed_wing.FixedWingVehicle(getattr(fixed_wing, params_name))

    return build


def _fixed_wing_library():
    from tepinn_flight.sim import fixed_wing_maneuvers as fm

    return fm.LIBRARY, fm.Recovery, fm.WEIGHTS


AIRCRAFT: dict[str, AircraftSpec] = {
    "c172x": AircraftSpec("c172x", "fixed-wing", "Cessna 172 (JSBSim c172x), trimmed, our autopilot",
                          _fixed_wing("C172X"), _fixed_wing_library),
    "F450": AircraftSpec("F450", "multirotor", "DJI F450 quad (JSBSim), SCAS bypassed, our controller",
                         _quad("F450"), _quad_library),
    "agile_quad": AircraftSpec("agile_quad", "multirotor",
                               "agile 0.8 kg X quad (flight_sims/aircraft, external_reactions)",
                               _quad("AGILE_QUAD"), _quad_library),
}


def _spec(aircraft: str) -> AircraftSpec:
    spec = AIRCRAFT.get(aircraft)
    if spec is None:
        raise ConfigError(f"unknown aircraft {aircraft!r} (known: {', '.join(AIRCRAFT)})")
    return spec


def maneuver_names(aircraft: str) -> list[str]:
    """The maneuvers ``fly`` can chain for this aircraft."""
    library, _, _ = _spec(aircraft).library()
    return sorted(library)


def _site(rng: np.random.Generator) -> dict:
    """Latitude, longitude, terrain height and a dipole-like Earth magnetic field (NED, uT)."""
    lat = float(rng.uniform(-55.0, 65.0))
    lon = float(rng.uniform(-180.0, 180.0))
    elev = float(rng.uniform(0.0, 500.0))
    b0 = float(rng.uniform(25.0, 33.0))  # equatorial field strength
    mag_lat = math.radians(float(np.clip(lat + rng.uniform(-12.0, 12.0), -85.0, 85.0)))
    decl = math.radians(float(rng.uniform(-20.0, 20.0)))
    h = b0 * math.cos(mag_lat)
    z = 2.0 * b0 * math.sin(mag_lat)
    mag = np.array([h * math.cos(decl), h * math.sin(decl), z])
    return {"lat_deg": lat, "lon_deg": lon, "elevation_m": elev, "mag_earth_ut": mag,
            "declination_deg": math.degrees(decl),
            "inclination_deg": math.degrees(math.atan2(z, h))}


def _validate(aircraft, duration_s, rate_hz, seed, turbulence) -> AircraftSpec:
    spec = _spec(aircraft)
    try:
        duration_s = float(duration_s)
        rate_hz = float(rate_hz)
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"duration and rate must be numbers ({exc})") from exc
    if not math.isfinite(duration_s) or duration_s <= 0.0:
        raise ConfigError(f"duration must be > 0 s, got {duration_s}")
    if not math.isfinite(rate_hz) or rate_hz <= 0.0:
        raise ConfigError(f"rate must be > 0 Hz, got {rate_hz}")
    if not MIN_RATE_HZ <= rate_hz <= MAX_RATE_HZ:
        raise ConfigError(f"rate must be within {MIN_RATE_HZ:g}..{MAX_RATE_HZ:g} Hz, got {rate_hz:g}")
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ConfigError(f"seed must be a non-negative integer, got {seed!r}")
    if turbulence is not None and turbulence not in TURBULENCE:
        raise ConfigError(f"unknown turbulence {turbulence!r} (known: {', '.join(TURBULENCE)})")
    return spec


def _ecef_to_ned(ecef: np.ndarray, lat_rad: float, lon_rad: float) -> np.ndarray:
    sl, cl = math.sin(lat_rad), math.cos(lat_rad)
    so, co = math.sin(lon_rad), math.cos(lon_rad)
    r = np.array([[-sl * co, -sl * so, cl], [-so, co, 0.0], [-cl * co, -cl * so, -sl]])
    d = ecef - ecef[0]
    return d @ r.T


def fly(aircraft: str, duration_s: float, rate_hz: float = 400.0, seed: int = 0,
        maneuvers: list[str] | None = None, turbulence: str | None = None, *,
        vibration: bool = True) -> TruthTrajectory:
    """Simulate one flight; see the module docstring. Same seed -> bit-identical arrays.

    ``maneuvers``: None chains random maneuvers from the vehicle's library; a list is flown in
    order and cycled. ``turbulence``: None draws a level from the seed, else one of
    :data:`TURBULENCE`. ``vibration`` (multirotors): add motor vibration to acc/gyr truth.
    """
    spec = _validate(aircraft, duration_s, rate_hz, seed, turbulence)
    library, recovery_cls, weights = spec.library()
    names = validate_names(library, maneuvers, aircraft)
    duration_s, rate_hz = float(duration_s), float(rate_hz)
    dt = 1.0 / rate_hz
    sub = max(1, math.ceil(MIN_SIM_HZ / rate_hz - 1e-9))  # JSBSim steps per logged sample
    dt_sim = dt / sub
    n_steps = int(round(duration_s * rate_hz))
    if n_steps < 1:
        raise ConfigError(f"duration {duration_s} s is shorter than one sample at {rate_hz:g} Hz")
    ss = np.random.SeedSequence(int(seed))
    rng_site, rng_vehicle, rng_man, rng_vib = (np.random.default_rng(s) for s in ss.spawn(4))
    site = _site(rng_site)
    if turbulence is None:
        turbulence = str(rng_site.choice(["none", "light", "moderate"], p=[0.3, 0.4, 0.3]))
    wind_max = 8.0 if spec.vehicle_type == "fixed-wing" else 5.0
    wind_speed = float(rng_site.uniform(0.0, wind_max))
    wind_dir = float(rng_site.uniform(0.0, 2.0 * math.pi))
    vehicle = spec.build()

    loaded = {}
    with open_fdm(vehicle.model, dt_sim, own_aircraft=vehicle.own_aircraft, lean=getattr(vehicle, "lean", None),
                  info=loaded) as fdm:  # fmt: skip
        fdm["simulation/randomseed"] = int(rng_site.integers(0, 2**31 - 1))
        # the controller runs at about vehicle.control_hz (zero-order hold between updates)
        div = max(1, int(round(rate_hz * sub / vehicle.control_hz)))
        ctl = vehicle.start(fdm, site, rng_vehicle, div * dt_sim)
        # atmosphere: steady wind (blowing towards wind_dir) and Dryden turbulence
        fdm["atmosphere/wind-north-fps"] = wind_speed * math.cos(wind_dir) / FT_TO_M
        fdm["atmosphere/wind-east-fps"] = wind_speed * math.sin(wind_dir) / FT_TO_M
        ws, sev = TURBULENCE[turbulence]
        if ws > 0.0:
            fdm["atmosphere/turb-type"] = 3
            fdm["atmosphere/turbulence/milspec/windspeed_at_20ft_AGL-fps"] = ws
            fdm["atmosphere/turbulence/milspec/severity"] = sev
        ctl.turbulence_baseline = (ws, sev)  # maneuvers that change turbulence restore this
        # JSBSim's steps and the truth's reads: compiled calls into JSBSim's C++ where the binding allows
        # (jsbsim_native; the same numbers through the binding elsewhere)
        min_agl_ft = vehicle.min_agl_m / FT_TO_M
        row_paths = [*TRUTH_PATHS, *vehicle.log_paths, *TRUTH_PATHS_END]
        if len(row_paths) != N_COLUMNS:
            raise ValueError("a vehicle logs exactly 4 extra properties")
        steps = Stepper(fdm, AGL_PATH, row_paths, sub, min_agl_ft, n_steps, STATE_COLS, STATE_H_AT,
                        extra_paths=getattr(ctl, "native_paths", ()))
        # warm-up (not logged): the controller settles on the start condition
        ctl_step = ctl.step
        n_warm = int(round(WARMUP_S * rate_hz * sub))
        for k in range(0, n_warm, div):
            ctl_step()
            steps.run(min(div, n_warm - k))
        ctl.read_state()
        start_agl_m = ctl.agl_m
        seq = Sequencer(library, recovery_cls, names, rng_man, weights)
        seq.start(ctl, 0.0)
        seq_update = seq.update
        lat0 = fdm["position/lat-geod-rad"]
        lon0 = fdm["position/long-gc-rad"]
        n_sim = n_steps * sub
        stop = -1  # the step at which the height floor ended the flight
        # a compiled loop of control updates and steps (a quad whose JSBSim is called natively), or Python's
        runner = ctl.native_runner(steps, n_sim, div, dt_sim) if hasattr(ctl, "native_runner") else None
        if runner is not None:
            i, skip_law = 0, False
            while True:  # back in Python where a maneuver finished or needs the random generator
                i, code = runner(i, skip_law, seq.current.v)
                if code == FINISHED or code == STOPPED:
                    stop = i if code == STOPPED else -1
                    break
                t = i * dt_sim
                if seq.current.resolve(ctl, t, code):
                    seq.advance(ctl, t)
                skip_law = True  # the control update at step i goes on without the law, which ran
        else:
            state = None  # the controller's inputs when the step before a control update read them
            logged = steps.logged
            for i in range(0, n_sim, div):  # a control update, then the JSBSim steps until the next
                seq_update(ctl, i * dt_sim)
                ctl_step(state)
                n = min(div, n_sim - i)
                stop = logged(i, n)
                if stop >= 0:  # also stops on a non-finite height; other columns: below
                    break
                # after run(), the state and the forces belong to the same instant (JSBSim runs FGPropagate first
                # in each step and the force models after it); a control update after a logged row takes its numbers
                state = steps.state() if (i + n) % sub == 0 else None
        termination = "completed"
        if stop >= 0:
            termination = (f"stopped at t={stop // sub * dt:.3f} s: "
                           + ("ground proximity" if math.isfinite(steps.h) else "non-finite state"))
        arr = steps.rows()
        t_end = len(arr) * dt
        seq.close(ctl, t_end)

    ok = np.all(np.isfinite(arr), axis=1)
    if not ok.all():  # cut at the first non-finite row
        cut = int(np.argmin(ok))
        arr = arr[:cut]
        termination = f"stopped at t={cut * dt:.3f} s: non-finite state"
    n = arr.shape[0]
    if n == 0:
        raise ConfigError(f"{aircraft}: the simulation produced no valid sample ({termination})")
    q = np.asarray(quat_from_euler_zyx(arr[:, 0], arr[:, 1], arr[:, 2]), dtype=np.float64)
    gyr = np.ascontiguousarray(arr[:, 3:6])
    pos = _ecef_to_ned(arr[:, 6:9] * FT_TO_M, lat0, lon0)
    vel = arr[:, 9:12] * FT_TO_M
    acc = arr[:, 16:19] / arr[:, 19:20] * FT_TO_M  # specific force: lbf / slug = ft/s^2
    extras = arr[:, 12:16]
    segments = [(float(a), float(min(b, n * dt)), name) for a, b, name in seq.segments if a < n * dt]
    gains = seq.gains[: len(segments)]
    vib_info = None
    if vibration and spec.vehicle_type == "multirotor":
        gain = np.ones(n)
        t_s = np.arange(n) * dt
        for (a, b, _), gn in zip(segments, gains):
            gain[(t_s >= a) & (t_s < b)] = gn
        acc_v, gyr_v, vib_info = motor_vibration(vehicle.rotor_hz(extras), gain, dt, rng_vib)
        acc = acc + acc_v
        gyr = gyr + gyr_v
    meta = {
        "aircraft": aircraft,
        "vehicle_type": spec.vehicle_type,
        "seed": int(seed),
        "rate_hz": rate_hz,
        "duration_s": duration_s,
        "jsbsim_version": jsbsim_version(),
        "jsbsim_model": loaded.get("jsbsim_model", vehicle.model),
        "termination": termination,
        "site": {k: (v.tolist() if isinstance(v, np.ndarray) else v) for k, v in site.items()},
        "turbulence": turbulence,
        "wind_ned_m_s": [wind_speed * math.cos(wind_dir), wind_speed * math.sin(wind_dir), 0.0],
        "vibration": vib_info,
        "gyro_truth": "inertial body rate (includes Earth rate)",
        "acc_truth": "specific force at the CG (non-gravity forces / mass)",
        "attitude_integrator": "Buss 2nd order",
        "start_agl_m": float(start_agl_m),
        "warmup_s": WARMUP_S,
        "control_hz": rate_hz * sub / div,
        "jsbsim_rate_hz": rate_hz * sub,
        "maneuver_requested": list(names) if names is not None else None,
    }
    return TruthTrajectory(
        t_s=np.arange(n, dtype=np.float64) * dt,
        q_nb_wxyz=np.ascontiguousarray(q),
        gyr_true_rad_s=np.ascontiguousarray(gyr),
        acc_true_m_s2=np.ascontiguousarray(acc),
        mag_earth_ut=np.asarray(site["mag_earth_ut"], dtype=np.float64),
        pos_ned_m=np.ascontiguousarray(pos),
        vel_ned_m_s=np.ascontiguousarray(vel),
        maneuvers=segments,
        meta=meta,
    )
