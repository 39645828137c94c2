"""The transparent router inside the bridge: frames between the autopilot and the ground stations.

* **master → outs**: every good frame from the autopilot is written to every out unchanged
  (``get_msgbuf()``: ids, sequence, signature kept); the frames of one read go out together.
* **outs → master**: every good frame from a ground station goes to the autopilot unchanged.
* frames from the bridge's own (sysid, compid) are dropped wherever they come in (echoes in some
  topologies); garbage and CRC failures are counted and dropped by the links. A message id the
  dialect does not know cannot be CRC-checked (no CRC_EXTRA), so garbage often parses as one: such
  a frame is forwarded only when its (system, component) has sent a CRC-checked frame on the same
  link before (custom-dialect messages of a real autopilot, gimbal or companion keep flowing), else
  dropped and counted (``unknown_dropped``).
* the bridge's own messages go out through :meth:`Forwarder.send_own`; everything routed or sent
  is written to the session log (:mod:`~tepinn_flight.live.session_tlog`) when there is one.

The endpoints themselves (opening, parsing, reconnecting) are :mod:`~tepinn_flight.live.router`.
"""

from __future__ import annotations

import sys
import time

from .router import Link
from .session_tlog import SessionTlog
from .status import RateMeter, latency_histogram

#: The routing counters, in the order the exit summary lists them.
COUNTS = ("from_master", "forwarded_to_outs", "from_outs", "forwarded_to_master", "sent_own", "own_echoes",
          "unknown_dropped")  # fmt: skip


class Forwarder:
    """The master link, the out links and the session log; raw frames between them."""

    def __init__(self, master: str, outs: tuple[str, ...], tlog_path: str | None, clock=time.monotonic):
        self.clock = clock
        self.links: list[Link] = []
        try:
            self.master = Link(master, "master")
            self.links.append(self.master)
            self.outs = []
            for spec in outs:
                link = Link(spec, "out")
                self.outs.append(link)
                self.links.append(link)
            self.tlog = SessionTlog(tlog_path) if tlog_path else None
        except BaseException:
            self.close_links()
            raise
        self.n = dict.fromkeys(COUNTS, 0)
        self.known_sources: dict[int, set] = {}  # id(link) -> (sysid, compid) seen with CRC-checked frames
        self.fwd_hist = latency_histogram()
        self.fwd_rate = RateMeter(2.0)

    # ------------------------------------------------------------------ filtering
    def _vouched(self, link: Link, m) -> bool:
        """False for a frame of an unknown message id from a source not seen with a CRC-checked
        frame on this link (garbage that happens to parse); True otherwise, noting known sources."""
        known = self.known_sources.setdefault(id(link), set())
        buf = m.get_msgbuf()
        src = (buf[5], buf[6]) if buf[0] == 0xFD else (buf[3], buf[4])
        if m.get_type().startswith("UNKNOWN"):
            if src in known:
                return True
            self.n["unknown_dropped"] += 1
            return False
        if len(known) < 4096:
            known.add(src)
        return True

    def _keep(self, link: Link, msgs, own) -> list:
        """The messages to route: not our own echoes (``own`` = our (sysid, compid), or None before
        the autopilot is known), not unvouched unknown ids."""
        keep = []
        for m in msgs:
            if own is not None and m.get_srcComponent() == own[1] and m.get_srcSystem() == own[0]:
                self.n["own_echoes"] += 1
            elif self._vouched(link, m):
                keep.append(m)
        return keep

    # ------------------------------------------------------------------ traffic
    def from_master(self, own) -> tuple[list, float]:
        """Read the master, forward what is kept to every out; (the kept messages, read time)."""
        data = self.master.read()
        t_in = self.clock()
        if not data:
            return [], t_in
        keep = self._keep(self.master, self.master.parse(data), own)
        if not keep:
            return [], t_in
        frames = [bytes(m.get_msgbuf()) for m in keep]
        out = b"".join(frames)
        for o in self.outs:
            if o.write(out):
                self.n["forwarded_to_outs"] += len(frames)
        self.fwd_hist.add(self.clock() - t_in)
        self.n["from_master"] += len(frames)
        self.fwd_rate.tick(t_in)
        if self.tlog is not None:
            self.tlog.write(frames, time.time())
        return keep, t_in

    def from_out(self, link: Link, own) -> None:
        """Read a ground station's link, forward what is kept to the master."""
        data = link.read()
        if not data:
            return
        msgs = self._keep(link, link.parse(data), own)
        if not msgs:
            return
        frames = [bytes(m.get_msgbuf()) for m in msgs]
        self.n["from_outs"] += len(frames)
        if self.master.write(b"".join(frames)):
            self.n["forwarded_to_master"] += len(frames)
        if self.tlog is not None:
            self.tlog.write(frames, time.time())

    def send_own(self, enc, msgs, to_outs: bool = True, to_master: bool = False) -> list[bytes]:
        """Our messages, packed by ``enc``, to the outs and/or the master."""
        frames = [enc.pack(m) for m in msgs]
        buf = b"".join(frames)
        if to_outs:
            for o in self.outs:
                o.write(buf)
        if to_master:
            self.master.write(buf)
        self.n["sent_own"] += len(frames)
        if self.tlog is not None:
            self.tlog.write(frames, time.time())
        return frames

    # ------------------------------------------------------------------ upkeep
    def reconnect(self, now: float) -> list[Link]:
        """The links that came back (TCP/serial, reopened once per second)."""
        return [link for link in self.links if link.maintain(now)]

    def fds(self) -> dict[int, Link]:
        fds = {}
        for link in self.links:
            fd = link.fileno()
            if fd is not None:
                fds[fd] = link
        return fds

    def close(self) -> None:
        """Close the session log (renamed into place) and the links."""
        if self.tlog is not None:
            try:
                self.tlog.close()
            except OSError as exc:  # the session is in FILE.part: said where (review60: lost without a word)
                sys.stderr.write(f"tepinn-flight bridge: warning: the session tlog could not be put in place as "
                                 f"{self.tlog.path} ({exc.strerror or exc}): it is in {self.tlog.tmp}\n")  # fmt: skip
        self.close_links()

    def close_links(self) -> None:
        for link in self.links:
            link.close()

    # ------------------------------------------------------------------ reporting
    @property
    def bad_frames(self) -> int:
        return sum(link.bad_frames for link in self.links)

    def link_counts(self) -> dict:
        return {"bad_frames": self.bad_frames, "bad_bytes": sum(link.bad_bytes for link in self.links),
                "write_errors": sum(link.write_errors for link in self.links)}  # fmt: skip
