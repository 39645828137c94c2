"""A `tcp:` ground station gone from the network (its SYNs unanswered) must not hold the bridge's one loop
(session 53): the link is reopened only once a non-blocking connect polled from the loop finds the peer answering;
before, pymavlink's blocking connect held every link's frames and the estimates for its timeout each second
(p99 forwarding 4 → 492 ms, `/work/review53/live`). Unanswered SYNs are made locally by a listener whose accept
queue is full (Linux drops the SYN)."""

from __future__ import annotations

import socket
import sys

import pytest

from tepinn_flight.live.router import EndpointError, Link

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="a full accept queue drops SYNs on Linux")


def _listener(port: int = 0, backlog: int = 1) -> socket.socket:
    s = socket.socket()
    s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    s.bind(("127.0.0.1", port))
    s.listen(backlog)
    return s


def test_a_peer_that_does_not_answer_is_polled_not_waited_for():
    srv = _listener()
    port = srv.getsockname()[1]
    link = Link(f"tcp:127.0.0.1:{port}", "out")
    conn, _ = srv.accept()
    opened = []

    def fake_open():
        opened.append(True)
        raise EndpointError("(the test's stand-in for pymavlink's blocking connect)")

    link._open = fake_open
    conn.close()
    srv.close()
    link.down = True  # the peer went away
    blk = _listener(port, 0)  # its port now drops SYNs: a full accept queue
    fillers = []
    for _ in range(3):
        f = socket.socket()
        f.setblocking(False)
        f.connect_ex(("127.0.0.1", port))
        fillers.append(f)
    try:
        for k in range(40):  # 4 s of the bridge's loop
            assert link.maintain(10.0 + 0.1 * k) is False
        assert opened == []  # never the blocking open while the peer does not answer
        blk.close()
        for f in fillers:
            f.close()
        back = _listener(port, 8)  # the ground station is back
        for k in range(30):
            link.maintain(20.0 + 0.1 * k)
            if opened:
                break
        assert opened  # reopened once it answers
        back.close()
    finally:
        link.close()
