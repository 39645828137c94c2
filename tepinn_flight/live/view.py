"""The live view: TE-PINN's attitude beside the autopilot's (EKF), drawn by Rerun.

The bridge and the vehicle emulator call :meth:`LiveView.estimate` with each TE-PINN estimate and
:meth:`LiveView.ekf` with each attitude of the autopilot, both on the autopilot's clock (seconds
since boot); nothing here knows about MAVLink or routing. Rerun (``rerun-sdk``, the ``[view]``
extra) is imported only when a view is opened.

Entities (timeline ``autopilot_time``, seconds; angles in degrees, Z-Y-X Euler of ``q_nb_wxyz``):

==================================  ===============================================================
``world``                           the NED earth frame (static: x north, y east, z down)
``world/tepinn``, ``world/ekf``     ``Transform3D``: the body (FRD) in NED, side by side
                                    (``body_offset_m`` west / east of the origin)
``world/<who>/body``                static box and body axes (x forward red, y right green, z down blue)
``attitude/{roll,pitch,heading}/    the traces of both (heading = yaw, ±180°)
{tepinn,ekf}``
``difference/{roll,pitch,heading,   TE-PINN − EKF, the EKF slerped onto each estimate's time
inclination}``                      (:class:`~tepinn_flight.live.inputs.EkfComparator`: the view's
                                    own, or the caller's through :meth:`LiveView.differences`)
==================================  ===============================================================

``--view`` spawns the Rerun viewer (``rerun``, installed with rerun-sdk) and streams to it;
``--rrd FILE`` records the same to ``FILE.part``, renamed to FILE on close (``rerun FILE`` opens it).
"""

from __future__ import annotations

import os
import shutil
import socket
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import ConfigError
from ..quat import quat_to_euler_zyx
from .inputs import EkfComparator

TIMELINE = "autopilot_time"
SOURCES = ("tepinn", "ekf")
ANGLES = ("roll", "pitch", "heading")
DIFFERENCES = ("roll", "pitch", "heading", "inclination")
_COLORS = {"tepinn": (230, 120, 20), "ekf": (40, 120, 230)}
_LABELS = {"tepinn": "TE-PINN", "ekf": "EKF (autopilot)"}
INSTALL_HINT = "pip install 'tepinn-flight[view]' (or pip install 'rerun-sdk>=0.41,<0.42')"


@dataclass(frozen=True)
class ViewConfig:
    spawn: bool = False  # --view: start the Rerun viewer and stream to it
    rrd_path: str | None = None  # --rrd: record to this file
    port: int = 9876  # the spawned viewer's gRPC port
    app_id: str = "tepinn-flight"
    body_offset_m: float = 0.8  # the two bodies this far west / east of the origin
    body_half_size_m: tuple[float, float, float] = (0.5, 0.3, 0.08)  # the box: forward, right, down
    spawn_wait_s: float = 8.0  # how long the viewer may take to listen
    # rows are sent every this many seconds of wall time: often for the eye, seldom to a file alone
    # (each send is a chunk of ~1 KB per entity in the .rrd, 0.1 s made 950 KB of a 6.5 s flight,
    # and ~1.8 ms of CPU: benchmarks/view_cost.py)
    view_flush_s: float = 0.1
    file_flush_s: float = 2.0

    @property
    def enabled(self) -> bool:
        return self.spawn or self.rrd_path is not None


def _rerun(flag: str):
    try:
        import rerun  # noqa: PLC0415
    except ImportError:
        raise ConfigError(f"{flag} needs Rerun, which is not installed: {INSTALL_HINT}") from None
    return rerun


def _viewer_executable() -> str | None:
    """``rerun`` on PATH, else the one installed beside this Python (a venv not activated)."""
    found = shutil.which("rerun")
    if found:
        return found
    beside = Path(sys.executable).with_name("rerun.exe" if os.name == "nt" else "rerun")
    return str(beside) if beside.is_file() else None


def _listening(port: int, wait_s: float) -> bool:
    end = time.monotonic() + wait_s
    while True:
        try:
            with socket.create_connection(("127.0.0.1", port), timeout=0.5):
                return True
        except OSError:
            if time.monotonic() >= end:
                return False
            time.sleep(0.2)


def _spawn_viewer(rr, cfg: ViewConfig) -> str:
    """Start the viewer; its gRPC URL. ConfigError (one line) when it cannot be started."""
    if sys.platform.startswith("linux") and not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
        raise ConfigError("--view: no display here (DISPLAY and WAYLAND_DISPLAY are unset) for the Rerun viewer; "
                          "record with --rrd FILE and open it elsewhere with: rerun FILE")  # fmt: skip
    exe = _viewer_executable()
    if exe is None:
        raise ConfigError(f"--view: the Rerun viewer (rerun) is not on PATH; {INSTALL_HINT}")
    try:
        rr.sinks.spawn(port=cfg.port, connect=False, executable_path=exe, hide_welcome_screen=True)
    except Exception as exc:  # noqa: BLE001 - whatever Rerun raises, one line
        first = (str(exc).strip().splitlines() or [type(exc).__name__])[0]
        raise ConfigError(f"--view: could not start the Rerun viewer ({first})") from None
    if not _listening(cfg.port, cfg.spawn_wait_s):
        raise ConfigError(f"--view: the Rerun viewer did not start listening on port {cfg.port} "
                          "(see its messages above); record with --rrd FILE instead")  # fmt: skip
    return f"rerun+http://127.0.0.1:{cfg.port}/proxy"


def _blueprint(rrb):
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Spatial3DView(origin="world", name="attitude (NED)"),
            rrb.Vertical(*(rrb.TimeSeriesView(origin=f"attitude/{a}", name=f"{a} (deg)") for a in ANGLES),
                         rrb.TimeSeriesView(origin="difference", name="TE-PINN - EKF (deg)")),  # fmt: skip
            column_shares=[2, 3],
        ),
        collapse_panels=True,
    )


class LiveView:
    """Logs estimates and EKF attitudes to a Rerun recording stream (see the module doc).

    Rows are buffered and sent as columns (``send_columns``, one per entity) every ``flush_s`` of
    wall time: a send costs about what one ``log`` of a single row does, so the cost is per send,
    not per row (``benchmarks/view_cost.py``: ~1.8 ms of CPU per flush of all entities)."""

    def __init__(self, rec, cfg: ViewConfig = ViewConfig(), rrd_part: Path | None = None, compare: bool = True,
                 flush_s: float = 0.1, clock=time.monotonic):  # fmt: skip
        import rerun as rr  # noqa: PLC0415

        self.rr = rr
        self.rec = rec
        self.cfg = cfg
        self.flush_s = flush_s
        self.clock = clock
        self._rrd_part = rrd_part
        self.cmp = EkfComparator() if compare else None  # else the caller passes its own differences()
        self.logged = {"tepinn": 0, "ekf": 0, "difference": 0}
        self._rows = {"tepinn": [], "ekf": [], "difference": []}
        self._next_flush = clock() + flush_s
        self._static()

    def _static(self) -> None:
        rr, rec, c = self.rr, self.rec, self.cfg
        rec.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_DOWN, static=True)
        axes = [[2 * c.body_half_size_m[0], 0, 0], [0, 2 * c.body_half_size_m[1], 0], [0, 0, 4 * c.body_half_size_m[2]]]
        for who in SOURCES:
            rec.log(f"world/{who}/body", rr.Boxes3D(half_sizes=[c.body_half_size_m], colors=[_COLORS[who]],
                                                   labels=[_LABELS[who]]), static=True)  # fmt: skip
            rec.log(f"world/{who}/body/axes", rr.Arrows3D(vectors=axes, colors=[(220, 40, 40), (40, 180, 40), (40, 40, 220)]),
                    static=True)  # fmt: skip
            for a in ANGLES:
                rec.log(f"attitude/{a}/{who}", rr.SeriesLines(names=_LABELS[who], colors=_COLORS[who]), static=True)
        for d in DIFFERENCES:
            rec.log(f"difference/{d}", rr.SeriesLines(names=d), static=True)

    def estimate(self, t_s: float, q_nb_wxyz) -> None:
        """A TE-PINN estimate at ``t_s`` (the autopilot's clock, s)."""
        self._rows["tepinn"].append((float(t_s), *(float(v) for v in q_nb_wxyz)))
        if self.cmp is not None:
            self._rows["difference"].extend(self.cmp.add_estimate(t_s, q_nb_wxyz))
        self._maybe_flush()

    def ekf(self, t_s: float, q_nb_wxyz) -> None:
        """The autopilot's attitude at ``t_s`` (s since boot)."""
        self._rows["ekf"].append((float(t_s), *(float(v) for v in q_nb_wxyz)))
        if self.cmp is not None:
            self._rows["difference"].extend(self.cmp.add_ekf(t_s, q_nb_wxyz))
        self._maybe_flush()

    def differences(self, diffs) -> None:
        """(t_s, roll, pitch, inclination, heading) differences in rad, as
        :class:`~tepinn_flight.live.inputs.EkfComparator` gives them (a view opened with
        ``compare=False``: the caller runs the comparison already)."""
        self._rows["difference"].extend(diffs)

    def _maybe_flush(self) -> None:
        now = self.clock()
        if now >= self._next_flush:
            self._next_flush = now + self.flush_s
            self.flush()

    def flush(self) -> None:
        """Send the buffered rows."""
        rr, rec = self.rr, self.rec
        for who in SOURCES:
            rows = self._rows[who]
            if not rows:
                continue
            self._rows[who] = []
            a = np.asarray(rows, dtype=np.float64)
            index = [rr.TimeColumn(TIMELINE, duration=a[:, 0])]
            q = a[:, 1:5]
            side = -1.0 if who == "tepinn" else 1.0
            offset = np.tile([0.0, side * self.cfg.body_offset_m, 0.0], (len(a), 1))
            rec.send_columns(f"world/{who}", indexes=index,
                             columns=rr.Transform3D.columns(translation=offset, quaternion=q[:, [1, 2, 3, 0]]))  # fmt: skip
            for name, v in zip(ANGLES, quat_to_euler_zyx(q)):
                rec.send_columns(f"attitude/{name}/{who}", indexes=index, columns=rr.Scalars.columns(scalars=np.degrees(v)))
            self.logged[who] += len(a)
        rows = self._rows["difference"]
        if rows:
            self._rows["difference"] = []
            a = np.asarray(rows, dtype=np.float64)  # t, droll, dpitch, dincl, dheading
            index = [rr.TimeColumn(TIMELINE, duration=a[:, 0])]
            for name, col in zip(DIFFERENCES, (1, 2, 4, 3)):
                rec.send_columns(f"difference/{name}", indexes=index, columns=rr.Scalars.columns(scalars=np.degrees(a[:, col])))
            self.logged["difference"] += len(a)

    def close(self) -> None:
        """Send what is buffered, flush; a recording is renamed from ``FILE.part`` to FILE."""
        try:
            self.flush()
            self.rec.flush(timeout_sec=10.0)
        finally:
            self.rec.disconnect()
        if self._rrd_part is not None:
            os.replace(self._rrd_part, self.cfg.rrd_path)
            self._rrd_part = None


    def discard(self) -> None:
        """Stop without keeping a recording (the run failed before it started)."""
        try:
            self.rec.disconnect()
        finally:
            if self._rrd_part is not None:
                self._rrd_part.unlink(missing_ok=True)
                self._rrd_part = None


def open_view(cfg: ViewConfig, compare: bool = True) -> LiveView | None:
    """The view ``cfg`` asks for (None when neither ``--view`` nor ``--rrd``); ConfigError, one
    line, when Rerun is missing, the viewer cannot start or the file cannot be written.
    ``compare=False``: the caller feeds :meth:`LiveView.differences` from its own comparator."""
    if not cfg.enabled:
        return None
    flag = "--view" if cfg.spawn else "--rrd"
    rr = _rerun(flag)
    import rerun.blueprint as rrb  # noqa: PLC0415

    part = None
    sinks = [rr.GrpcSink(_spawn_viewer(rr, cfg))] if cfg.spawn else []
    if cfg.rrd_path is not None:
        path = Path(cfg.rrd_path)
        if not path.parent.exists():
            raise ConfigError(f"--rrd {cfg.rrd_path}: folder {path.parent} does not exist")
        part = path.with_name(path.name + ".part")
        try:
            part.touch()
        except OSError as exc:
            raise ConfigError(f"--rrd {cfg.rrd_path}: cannot write ({exc.strerror or exc})") from None
        sinks.append(rr.FileSink(str(part)))
    rec = rr.RecordingStream(cfg.app_id)
    rec.set_sinks(*sinks, default_blueprint=_blueprint(rrb))
    return LiveView(rec, cfg, part, compare=compare, flush_s=cfg.view_flush_s if cfg.spawn else cfg.file_flush_s)
