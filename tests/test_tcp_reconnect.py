"""A `tcp:` ground station gone from the network (its connect hanging) must not hold the bridge's one loop (session 53):
the link is reconnected by a thread, and the loop's calls return at once while it waits; before, pymavlink's blocking
connect held every link's frames and the estimates for its timeout each second (p99 forwarding 4 → 492 ms,
`/work/review53/live`)."""

from __future__ import annotations

import socket
import threading

from tepinn_flight.live.router import Link


def test_a_hanging_connect_is_waited_for_beside_the_loop_not_in_it():
    srv = socket.socket()
    srv.bind(("127.0.0.1", 0))
    srv.listen(1)
    port = srv.getsockname()[1]
    link = Link(f"tcp:127.0.0.1:{port}", "out")
    conn, _ = srv.accept()
    release, calls = threading.Event(), []
    real_open = link._open

    def hanging_open(**kw):  # the peer does not answer until released
        calls.append(threading.current_thread() is threading.main_thread())
        assert release.wait(10), "never released"
        return real_open(**kw)

    link._open = hanging_open
    conn.close()
    link.down = True  # the peer went away
    try:
        for k in range(40):  # 4 s of the bridge's loop, none of it waiting for the connect
            assert link.maintain(10.0 + 0.1 * k) is False
        assert calls == [False]  # one connect at a time, in a thread
        release.set()  # the ground station answers
        came_back = False
        for k in range(200):
            if link.maintain(20.0 + 0.1 * k):
                came_back = True
                break
            threading.Event().wait(0.01)
        assert came_back and not link.down
        c2, _ = srv.accept()
        assert link.write(b"frame")
        c2.settimeout(2)
        assert c2.recv(16) == b"frame"
        c2.close()
    finally:
        release.set()
        link.close()
        srv.close()
