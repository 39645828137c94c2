"""Which autopilot the bridge serves, and whether it is still there.

The autopilot is the component 1 whose HEARTBEAT names a real autopilot (not
``MAV_AUTOPILOT_INVALID``): the first one seen, or the ``--sysid`` given. Its messages count as
"seen" once its HEARTBEAT has said which autopilot it is (RAW_IMU units depend on it); silent for
``autopilot_timeout_s`` it is "lost" (forwarding goes on) until it is heard again. Its latest
``time_boot_ms`` (with the wall time it came) carries the boot clock to IMU messages stamped in UNIX
time. The bridge's own messages are encoded as (its sysid, our compid) once it is known.
"""

from __future__ import annotations

from . import dialect
from .messages import Encoder

MAV_AUTOPILOT_INVALID = 8
#: The messages of another system that are counted as ``other_sources``.
WATCHED = ("HIGHRES_IMU", "RAW_IMU", "SCALED_IMU", "ATTITUDE", "ATTITUDE_QUATERNION")


class AutopilotTracker:
    def __init__(self, sysid: int | None, compid: int, note):
        self.compid = compid
        self.note = note
        self.m = dialect()
        self.enc: Encoder | None = None
        self.sysid: int | None = sysid
        self.autopilot: int | None = None
        self.type: int | None = None
        self.first_seen: float | None = None
        self.last_seen: float | None = None
        self.lost = False
        self.lost_count = 0
        self.last_boot = None  # (time_boot_ms, monotonic) of the autopilot's latest message with one
        self.other_sources = 0

    @property
    def own(self) -> tuple[int, int] | None:
        """Our (sysid, compid) once the autopilot is known, else None."""
        return None if self.enc is None else (self.enc.sysid, self.compid)

    def heartbeat(self, m, sid: int, t_in: float) -> bool:
        """A component-1 HEARTBEAT; True when it is the autopilot's (it was seen)."""
        if m.autopilot == MAV_AUTOPILOT_INVALID:
            return False
        if self.sysid is None:
            self.sysid = sid
        if sid != self.sysid:
            self.other_sources += 1
            return False
        self.autopilot, self.type = int(m.autopilot), int(m.type)
        if self.enc is None or self.enc.sysid != sid:
            self.enc = Encoder(sid, self.compid)
            self.note(f"tepinn-flight bridge: autopilot system {sid} found ({self.name()})")
        return True

    def message(self, name: str, sid: int, t_in: float, time_boot_ms) -> bool:
        """Another component-1 message: True when it is the autopilot's and its HEARTBEAT came
        (then it counts as seen and its ``time_boot_ms`` carries the boot clock on)."""
        if self.sysid is None or sid != self.sysid:
            if name in WATCHED:
                self.other_sources += 1
            return False
        if self.autopilot is None:
            return False  # wait for its HEARTBEAT (RAW_IMU units depend on the autopilot)
        tb = time_boot_ms
        if tb is not None and (self.last_boot is None or int(tb) >= self.last_boot[0] or t_in - self.last_boot[1] > 1.0):
            self.last_boot = (int(tb), t_in)  # a stale copy does not set the clock back; a reboot does within 1 s
        return True

    def seen(self, t_in: float) -> bool:
        """Note the autopilot heard at ``t_in``; True when it came back after being lost."""
        back = False
        if self.first_seen is None:
            self.first_seen = t_in
        if self.lost:
            self.lost = False
            self.first_seen = t_in
            back = True
            self.note(f"tepinn-flight bridge: autopilot system {self.sysid} is back")
        self.last_seen = t_in
        return back

    def check_lost(self, now: float, timeout_s: float) -> None:
        if self.last_seen is not None and not self.lost and now - self.last_seen > timeout_s:
            self.lost = True
            self.lost_count += 1
            self.note(f"tepinn-flight bridge: autopilot system {self.sysid} silent for "
                      f"{timeout_s:.0f} s (forwarding goes on)")  # fmt: skip

    def boot_ms_at(self, t_in: float) -> int | None:
        """The autopilot's boot clock (ms) at wall time ``t_in``, carried on from its latest
        ``time_boot_ms``; None before any."""
        if self.last_boot is None:
            return None
        return self.last_boot[0] + int(round((t_in - self.last_boot[1]) * 1e3))

    # ------------------------------------------------------------------ names
    def name(self) -> str:
        e = self.m.enums.get("MAV_AUTOPILOT", {}).get(self.autopilot)
        return e.name.removeprefix("MAV_AUTOPILOT_").lower() if e else str(self.autopilot)

    def type_name(self):
        if self.type is None:
            return None
        e = self.m.enums.get("MAV_TYPE", {}).get(self.type)
        return e.name.removeprefix("MAV_TYPE_").lower() if e else str(self.type)

    def summary(self) -> dict:
        return {
            "sysid": self.sysid if self.enc is not None else None,
            "autopilot": self.name() if self.autopilot is not None else None,
            "vehicle_type": self.type_name(),
            "lost": self.lost_count,
        }
