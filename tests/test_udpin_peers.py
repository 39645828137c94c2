"""A `udpin:` endpoint sends to the peers heard from lately, not to every address that ever sent to it (session 53:
a ground station restarted 20 times had 20 addresses each getting every frame, for ever)."""

from __future__ import annotations

import socket
import time

import tepinn_flight.live.router as router
from tepinn_flight.live.router import Link


def _peer():
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind(("127.0.0.1", 0))
    s.settimeout(0.5)
    return s


def test_a_peer_silent_past_the_timeout_is_sent_nothing_more(monkeypatch):
    monkeypatch.setattr(router, "UDP_PEER_TIMEOUT_S", 0.3)
    probe = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    probe.bind(("127.0.0.1", 0))
    port = probe.getsockname()[1]
    probe.close()
    link = Link(f"udpin:127.0.0.1:{port}", "out")
    old, new = _peer(), _peer()
    try:
        old.sendto(b"\xfd hello", ("127.0.0.1", port))
        time.sleep(0.05)
        link.read()
        assert link.write(b"frame-1")
        assert old.recv(64) == b"frame-1"
        time.sleep(0.5)  # the old peer falls silent past the timeout; a new one speaks
        new.sendto(b"\xfd hello", ("127.0.0.1", port))
        time.sleep(0.05)
        link.read()
        assert link.write(b"frame-2")
        assert new.recv(64) == b"frame-2"
        old.settimeout(0.2)
        try:
            got = old.recv(64)
        except TimeoutError:
            got = None
        assert got is None  # the silent one gets nothing more
        assert len(link.conn.clients) == 1
    finally:
        link.close()
        old.close()
        new.close()
