"""Campaigns: many simulated flights (aircraft × maneuver profiles × sensors × turbulence × repeats).

A campaign TOML (``flight_sims/campaigns/*.toml``, :class:`CampaignConfig`) lists groups of flights;
each group is the full product of its lists. Flights are numbered in that order (groups, aircraft,
profiles, sensors, turbulence, repeats) and flight ``i`` gets the seed
``SeedSequence(campaign seed, spawn_key=(i,))`` (its first 32-bit word): the same flights and
bits whatever the worker count or completion order.

Output folder: one record per flight, named ``{i:04d}-{aircraft}-{profile}-{sensor}-{turbulence}
-r{repeat}.parquet`` and written atomically, plus ``campaign.json`` (the resolved definition, its
hash and the flight list). Re-running skips flights whose record exists, so a killed campaign
continues where it stopped; a folder holding a *different* campaign is refused.

Flights run in a pool of worker processes (``forkserver`` where available, else ``spawn``; never
threads: JSBSim is not thread-safe), one JSBSim instance per process. Ctrl-C or SIGTERM terminates
the workers at once; finished records stay, temporaries are removed by the next run.
"""

from __future__ import annotations

import hashlib
import json
import math
import multiprocessing
import os
import re
import sys
import time
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import numpy as np

from ..config import check, from_dict, load_toml, to_dict
from ..errors import ConfigError, TepinnError
from ..record import atomic_write
from ..worker_processes import (quiet_tracker_after_kill, signals_held, start_forkserver, stop_pool, terminate_on_sigterm,
                                worker_init)  # fmt: skip

MANIFEST = "campaign.json"
#: A worker process is replaced after this many flights (bounds any memory growth in JSBSim).
MAX_TASKS_PER_WORKER = 20
RANDOM = "random"  # turbulence drawn from the flight seed / maneuvers chained at random


@dataclass(frozen=True)
class Profile:
    """A named maneuver list, flown in order and cycled; empty: a random chain from the seed."""

    name: str
    maneuvers: tuple[str, ...] = ()

    def __post_init__(self):
        check(bool(re.fullmatch(r"[A-Za-z0-9_.]+", self.name)),
              f"profile name {self.name!r} may only hold letters, digits, '_' and '.'")  # fmt: skip


@dataclass(frozen=True)
class FlightGroup:
    aircraft: tuple[str, ...]
    profiles: tuple[Profile, ...] = (Profile(RANDOM),)
    sensors: tuple[str, ...] = ("consumer",)  # preset names or TOML paths (relative to the campaign file)
    sensor_set: tuple[str, ...] = ()  # key=value overrides applied to every sensor of the group
    turbulence: tuple[str, ...] = (RANDOM,)
    repeats: int = 1
    duration_s: float | None = None  # default: the campaign's
    rate_hz: float | None = None

    def __post_init__(self):
        for name in ("aircraft", "profiles", "sensors", "turbulence"):
            check(len(getattr(self, name)) > 0, f"'{name}' must not be empty")
        check(self.repeats >= 1, f"'repeats' must be >= 1, got {self.repeats}")
        names = [p.name for p in self.profiles]
        check(len(set(names)) == len(names), f"profile names repeat: {names}")


@dataclass(frozen=True)
class CampaignConfig:
    name: str
    seed: int
    groups: tuple[FlightGroup, ...]
    description: str = ""
    duration_s: float = 60.0
    rate_hz: float = 400.0

    def __post_init__(self):
        check(len(self.groups) > 0, "'groups' must not be empty")
        check(self.seed >= 0, f"'seed' must be >= 0, got {self.seed}")
        check(bool(re.fullmatch(r"[A-Za-z0-9_.-]+", self.name)), f"campaign name {self.name!r} is not a plain word")


@dataclass(frozen=True)
class FlightSpec:
    index: int
    aircraft: str
    profile: str
    maneuvers: tuple[str, ...] | None
    sensor: str  # preset name or resolved TOML path
    sensor_set: tuple[str, ...]
    turbulence: str | None
    repeat: int
    duration_s: float
    rate_hz: float
    seed: int
    file: str


def flight_seed(campaign_seed: int, index: int) -> int:
    """Seed of flight ``index``: SeedSequence(campaign_seed, spawn_key=(index,)), first uint32."""
    ss = np.random.SeedSequence(int(campaign_seed), spawn_key=(int(index),))
    return int(ss.generate_state(1, np.uint32)[0])


def load_campaign(path: str | os.PathLike) -> CampaignConfig:
    data = load_toml(path)
    try:
        return from_dict(CampaignConfig, data)
    except ConfigError as exc:
        raise ConfigError(exc.reason, path) from None


def _word(s: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.]+", "_", s)


def _sensor_ref(sensor: str, base: Path | None) -> str:
    if sensor.endswith(".toml") or "/" in sensor or os.sep in sensor:
        p = Path(sensor)
        return str(p if p.is_absolute() or base is None else (base / p).resolve())
    return sensor


def expand(cfg: CampaignConfig, base: Path | None = None) -> list[FlightSpec]:
    """All flights of the campaign, in index order (no validation of names)."""
    out: list[FlightSpec] = []
    for g in cfg.groups:
        for ac in g.aircraft:
            for prof in g.profiles:
                for sensor in g.sensors:
                    for turb in g.turbulence:
                        for rep in range(g.repeats):
                            i = len(out)
                            ref = _sensor_ref(sensor, base)
                            sname = Path(sensor).stem if ref != sensor else sensor
                            out.append(FlightSpec(
                                index=i, aircraft=ac, profile=prof.name,
                                maneuvers=tuple(prof.maneuvers) or None, sensor=ref, sensor_set=tuple(g.sensor_set),
                                turbulence=None if turb == RANDOM else turb, repeat=rep,
                                duration_s=float(g.duration_s if g.duration_s is not None else cfg.duration_s),
                                rate_hz=float(g.rate_hz if g.rate_hz is not None else cfg.rate_hz),
                                seed=flight_seed(cfg.seed, i),
                                file=f"{i:04d}-{_word(ac)}-{_word(prof.name)}-{_word(sname)}-{_word(turb)}-r{rep}.parquet",
                            ))  # fmt: skip
    return out


def validate(cfg: CampaignConfig, flights: list[FlightSpec]) -> dict[str, dict]:
    """Check every name before any work; returns the resolved sensor parameters per (sensor, overrides)."""
    from . import flight as fl
    from .sensors import decimation_factor, load_sensor_config
    from .simulate import check_flight_args

    known_turb = list(getattr(fl, "TURBULENCE", {}))  # (in the table's order: a set's differed from run to run)
    resolved: dict[str, dict] = {}
    checked: set = set()
    for f in flights:
        where = f"flight {f.index} ({f.file})"
        key = (f.aircraft, f.maneuvers, f.turbulence, f.duration_s, f.rate_hz)
        if key not in checked:
            checked.add(key)
            if f.aircraft not in fl.AIRCRAFT:
                raise ConfigError(f"unknown aircraft {f.aircraft!r} (known: {', '.join(fl.AIRCRAFT)})")
            if f.maneuvers:
                names = fl.maneuver_names(f.aircraft)
                bad = [m for m in f.maneuvers if m not in names]
                if bad:
                    raise ConfigError(f"unknown maneuver {bad[0]!r} for {f.aircraft} (known: {', '.join(names)})")
            if f.turbulence is not None and known_turb and f.turbulence not in known_turb:
                raise ConfigError(f"unknown turbulence {f.turbulence!r} (known: {RANDOM}, {', '.join(known_turb)})")
            lo, hi = getattr(fl, "MIN_RATE_HZ", 0.0), getattr(fl, "MAX_RATE_HZ", math.inf)
            if not lo <= f.rate_hz <= hi:  # (first: a rate out of range had been told to fly shorter flights)
                raise ConfigError(f"rate must be within {lo:g}..{hi:g} Hz, got {f.rate_hz:g}")
            try:
                check_flight_args(f.duration_s, f.rate_hz, f.seed)
            except ConfigError as exc:
                raise ConfigError(f"{where}: {exc.reason}") from None
        skey = json.dumps([f.sensor, list(f.sensor_set)])
        if skey not in resolved:
            resolved[skey] = load_sensor_config(f.sensor, list(f.sensor_set)).to_dict()
        rate = resolved[skey].get("rate_hz")
        if rate is not None and (skey, f.rate_hz) not in checked:  # (found per flight before: after the good ones flew)
            checked.add((skey, f.rate_hz))
            try:
                decimation_factor(f.rate_hz, float(rate))
            except ConfigError as exc:
                raise ConfigError(f"{where}: {exc.reason}") from None
    return resolved


# --------------------------------------------------------------------------- running


@dataclass
class CampaignResult:
    total: int
    computed: int = 0
    skipped: int = 0
    failed: list[tuple[str, str]] = field(default_factory=list)
    wall_s: float = 0.0
    flight_s: float = 0.0  # sum of per-flight times (CPU-side work)

    def failure_causes(self) -> str:
        """Each distinct error of the failed flights with how many failed with it, most frequent first,
        in one line (a missing JSBSim installation fails every flight the same way: one cause, not 120)."""
        n: dict[str, int] = {}
        for _, err in self.failed:
            n[err] = n.get(err, 0) + 1
        return "; ".join(f"{err} ({k} flight{'s' if k > 1 else ''})" for err, k in sorted(n.items(), key=lambda kv: -kv[1]))


def _fly_one(spec: dict, out_dir: str) -> tuple[int, str | None, float, str]:
    """Worker: simulate one flight and write its record atomically. Never raises."""
    t0 = time.perf_counter()
    try:
        from ..record import write_record
        from .simulate import simulate_record

        rec = simulate_record(
            spec["aircraft"], spec["duration_s"], spec["rate_hz"], spec["seed"], sensor=spec["sensor"],
            sensor_overrides=list(spec["sensor_set"]),
            maneuvers=list(spec["maneuvers"]) if spec["maneuvers"] else None, turbulence=spec["turbulence"],
        )  # fmt: skip
        rec.meta["campaign_flight"] = {k: spec[k] for k in ("index", "profile", "repeat", "file")}
        write_record(rec, Path(out_dir) / spec["file"])
        return spec["index"], None, time.perf_counter() - t0, str(rec.meta.get("termination"))
    except TepinnError as exc:
        return spec["index"], str(exc), time.perf_counter() - t0, "error"
    except Exception as exc:  # a bug or a JSBSim failure: report it, keep the campaign going
        first = (str(exc).strip().splitlines() or [""])[0]
        return spec["index"], f"{type(exc).__name__}: {first}", time.perf_counter() - t0, "error"


def _fly_one_packed(args):
    return _fly_one(*args)


def _mp_context():
    methods = multiprocessing.get_all_start_methods()
    ctx = multiprocessing.get_context("forkserver" if "forkserver" in methods else "spawn")
    if ctx.get_start_method() == "forkserver":
        ctx.set_forkserver_preload(["tepinn_flight.sim.preload"])
    return ctx


#: Sensor settings added after campaigns were first flown, with the value that flies every flight as before: a
#: folder flown before they existed holds the same flights where they keep that value (session 29's lost samples).
SENSOR_FIELDS_ADDED = {"lost_fraction": 0.0, "stamp_jitter_s": 0.0}


def _digest(definition: dict) -> str:
    return hashlib.sha256(json.dumps(definition, sort_keys=True, default=str).encode()).hexdigest()


def _relative_digest(definition: dict, base: Path | None) -> str:
    """The digest of ``definition`` with the sensor files under the campaign file's folder (``base``) named relative
    to it: a campaign moved with its sensor files keeps its digest (session 53: the absolute path in it had refused
    the resume). (The paths sit inside the resolved sensors' JSON keys too: replaced in the text.)"""
    text = json.dumps(definition, sort_keys=True, default=str)
    if base is not None:
        text = text.replace(str(Path(base).resolve()) + os.sep, "./")
    return hashlib.sha256(text.encode()).hexdigest()


def _manifest(cfg: CampaignConfig, flights: list[FlightSpec], sensors: dict, base: Path | None = None) -> dict:
    definition = {"campaign": to_dict(cfg), "sensors_resolved": sensors,
                  "flights": [[f.file, f.seed, f.sensor] for f in flights]}  # fmt: skip
    absolute = _digest(definition)  # (what earlier versions wrote: a folder they made resumes)
    digest = _relative_digest(definition, base)
    # the same definition as written before SENSOR_FIELDS_ADDED existed, where each keeps its neutral value
    older = {k: {f: v for f, v in s.items() if not (f in SENSOR_FIELDS_ADDED and v == SENSOR_FIELDS_ADDED[f])}
             if isinstance(s, dict) else s for k, s in sensors.items()}  # fmt: skip
    same_as = sorted({digest, absolute, _digest({**definition, "sensors_resolved": older})})
    return {
        "name": cfg.name,
        "description": cfg.description,
        "seed": cfg.seed,
        "definition_sha256": digest,
        "same_as_sha256": same_as,  # digests of folders written by earlier versions that hold these very flights
        "definition": definition["campaign"],
        "sensors_resolved": sensors,
        "flights": [asdict(f) for f in flights],
    }


def _prepare_dir(out_dir: Path, manifest: dict) -> None:
    if out_dir.exists() and not out_dir.is_dir():
        raise ConfigError("campaign output must be a folder", out_dir)
    mpath = out_dir / MANIFEST
    if mpath.exists():
        try:
            old = json.loads(mpath.read_text())
        except (OSError, ValueError):
            raise ConfigError(f"unreadable {MANIFEST}; delete it or use another folder", out_dir) from None
        if old.get("definition_sha256") not in manifest["same_as_sha256"]:
            raise ConfigError(
                f"holds a different campaign ({old.get('name')!r}, other definition or sensor presets); "
                "use another folder or delete it", out_dir,
            )  # fmt: skip
    elif out_dir.is_dir() and any(p.suffix == ".parquet" for p in out_dir.iterdir()):
        raise ConfigError(f"holds records but no {MANIFEST}: not a campaign folder; use another folder", out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    for tmp in out_dir.glob(".*.tmp"):  # left by a killed run (atomic_write's temporaries)
        tmp.unlink(missing_ok=True)
    text = json.dumps(manifest, indent=1, default=str)
    atomic_write(mpath, lambda p: Path(p).write_text(text))


def _readable_record(path: Path) -> bool:
    """Whether a campaign's output file is a whole flight record: its Parquet footer and our metadata read (a file
    cut short or emptied has neither)."""
    from ..record import parquet_meta

    meta = parquet_meta(path)
    return meta is not None and "format_version" in meta


def run_campaign(
    path: str | os.PathLike,
    out_dir: str | os.PathLike,
    workers: int | None = None,
    progress: bool = True,
    log=None,
    seed: int | None = None,
) -> CampaignResult:
    """Run (or resume) the campaign at ``path`` into ``out_dir``; see the module doc. ``seed``: the campaign's seed
    replaced (``simulate --campaign --seed``: the same flights drawn anew, as an independent check flies them)."""
    if workers is not None and workers < 1:
        raise ConfigError(f"--workers must be >= 1, got {workers}")
    path = Path(path)
    cfg = load_campaign(path)
    if seed is not None:
        cfg = replace(cfg, seed=int(seed))
    flights = expand(cfg, base=path.parent)
    sensors = validate(cfg, flights)
    out = Path(out_dir)
    _prepare_dir(out, _manifest(cfg, flights, sensors, base=path.parent))
    log = log or (lambda s: sys.stderr.write(s + "\n"))
    pending = [f for f in flights if not (out / f.file).exists()]
    damaged = [f for f in flights if f not in pending and not _readable_record(out / f.file)]
    if damaged:  # (review60: a record cut by a copy or a crash had been counted done for good)
        names = ", ".join(f.file for f in damaged[:3]) + (", ..." if len(damaged) > 3 else "")
        log(f"note: {len(damaged)} record(s) in {out} cannot be read (cut or damaged): flown again ({names})")
        pending = [f for f in flights if f in damaged or f in pending]
    res = CampaignResult(total=len(flights), skipped=len(flights) - len(pending))
    n_workers = min(workers or os.cpu_count() or 1, max(len(pending), 1))
    t0 = time.perf_counter()
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=len(flights), initial=res.skipped, unit="flight", desc=cfg.name, file=sys.stderr,
                   dynamic_ncols=True, leave=False)  # fmt: skip
    by_index = {f.index: f for f in flights}

    def done(index, err, secs, _termination):
        res.flight_s += secs
        if err is None:
            res.computed += 1
        else:
            if all(e != err for _, e in res.failed):  # each cause once, with the first flight it stopped
                (bar.write if bar else log)(f"flight {by_index[index].file}: {err}")
            res.failed.append((by_index[index].file, err))
        if bar:
            bar.update(1)

    try:
        specs = [(asdict(f), str(out)) for f in pending]
        if n_workers == 1:
            for s in specs:
                done(*_fly_one(*s))
        elif specs:
            with terminate_on_sigterm():
                pool = None
                stopping = True
                try:
                    quiet_tracker_after_kill()
                    with signals_held():  # (a signal while the pool starts: raised once it has, and it is stopped)
                        ctx = _mp_context()
                        start_forkserver(ctx)
                        pool = ctx.Pool(n_workers, initializer=worker_init, initargs=(os.getpid(),),
                                        maxtasksperchild=MAX_TASKS_PER_WORKER)  # fmt: skip
                    for result in pool.imap_unordered(_fly_one_packed, specs):
                        done(*result)
                    pool.close()
                    stopping = False
                finally:  # Ctrl-C / SIGTERM: the workers stopped now (finished records stay), out of a second one's reach
                    stop_pool(pool, stopping)
    finally:
        if bar:
            bar.close()
        res.wall_s = time.perf_counter() - t0
    return res
