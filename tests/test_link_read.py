"""``Link.read`` on a stream link: nothing waiting is not a closed peer (review59: `replay --to tcp:` read its link
until empty, took the quiet moment after a reply for a peer gone, closed the socket and stopped with EBADF), and a
peer that did close is still seen."""

from __future__ import annotations

import socket
import threading
import time

from tepinn_flight.live.router import Link


def _server(hold_s: float, reply: bytes):
    srv = socket.socket()
    srv.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    srv.bind(("127.0.0.1", 0))
    srv.listen(1)
    done = threading.Event()

    def serve():
        c, _ = srv.accept()
        time.sleep(0.2)
        c.sendall(reply)
        done.wait(hold_s)
        c.close()
        srv.close()

    threading.Thread(target=serve, daemon=True).start()
    return srv.getsockname()[1], done


def _read_until(link: Link, n: int, timeout_s: float = 3.0) -> bytes:
    got, t0 = b"", time.monotonic()
    while len(got) < n and time.monotonic() - t0 < timeout_s:
        got += link.read()
        time.sleep(0.01)
    return got


def test_a_quiet_tcp_peer_is_not_taken_for_a_closed_one():
    port, done = _server(5.0, b"\xfd" + bytes(20))
    link = Link(f"tcp:127.0.0.1:{port}", "--to")
    try:
        assert len(_read_until(link, 21)) == 21
        assert link.read() == b"" and link.read() == b""  # nothing waiting: twice, as a drain reads
        assert not link.down  # (the old read marked it down here and closed the socket)
        assert link.fileno() is not None
    finally:
        done.set()
        link.close()


def test_a_tcp_peer_that_closes_is_seen():
    port, done = _server(0.0, b"\xfd" + bytes(20))
    link = Link(f"tcp:127.0.0.1:{port}", "--to")
    try:
        assert len(_read_until(link, 21)) == 21
        t0 = time.monotonic()
        while not link.down and time.monotonic() - t0 < 3.0:
            link.read()
            time.sleep(0.02)
        assert link.down  # the peer's end of file
    finally:
        link.close()
