"""MAVLink endpoints for the bridge and the emulator, opened through pymavlink's ``mavlink_connection``.

Endpoint forms (``mavlink.md`` §2: always say which way a UDP socket goes):

=========================  ===================================================================
``udpin:HOST:PORT``        bind and listen; replies go to every peer heard from in the last 10 s
``udpout:HOST:PORT``       send to HOST:PORT; replies arrive on the same socket
``tcp:HOST:PORT``          connect (reconnected every second while the peer is away)
``tcpin:HOST:PORT``        listen for one TCP client (a new client may connect after it leaves)
``DEVICE[,BAUD]``          a serial port, e.g. ``/dev/ttyACM0,115200`` (default 115200 baud)
=========================  ===================================================================

A bare ``udp:`` is refused (pymavlink and MAVProxy read it in opposite directions).

:class:`Link` reads raw bytes (non-blocking, after ``select``), parses them with the link's own
pymavlink parser (CRC-checked, robust: garbage comes back as ``BAD_DATA``) and writes raw frames.
UDP datagrams are parsed independently: a frame cut at the end of a datagram is garbage, and must
not swallow the start of the next datagram. Forwarding uses ``msg.get_msgbuf()``: the original
bytes, with the original system/component ids, sequence number and signature.
"""

from __future__ import annotations

import errno
import os
import re
import socket

from ..errors import ConfigError
from . import mavutil

FORMS = "udpin:HOST:PORT, udpout:HOST:PORT, tcp:HOST:PORT, tcpin:HOST:PORT or a serial DEVICE[,BAUD]"
_NET = ("udpin", "udpout", "tcp", "tcpin")
READ_SIZE = 65536
RECONNECT_S = 1.0
CONNECT_TIMEOUT_S = 0.5
#: a ``udpin:`` endpoint stops sending to a peer silent this long (s) — a ground station restarted from another port,
#: a laptop whose address changed — but keeps the last one it heard (pymavlink's ``udp_timeout``); before session 53
#: every peer ever heard got every frame for ever
UDP_PEER_TIMEOUT_S = 10.0
#: UDP socket buffers asked for: a burst (a flood of 7000 datagrams in 5 s lost ~10 % of the valid
#: frames in the kernel with the default ~208 KiB) or a scheduling stall of the bridge must fit.
#: Linux caps SO_RCVBUF at ``net.core.rmem_max``; SO_RCVBUFFORCE (privileged) is tried first, and
#: the size granted is kept in ``Link.rcvbuf_bytes`` (the bridge says when it is short).
SOCKET_BUFFER_BYTES = 4 << 20


class EndpointError(ConfigError):
    """A command-line endpoint that is malformed or cannot be opened."""


def parse_endpoint(spec: str) -> tuple[str, str, int]:
    """(kind, host or device, port or baud) of an endpoint string; EndpointError when malformed."""
    s = (spec or "").strip()
    if not s:
        raise EndpointError(f"empty endpoint (use {FORMS})")
    head, _, rest = s.partition(":")
    if head == "udp":
        raise EndpointError(f"{s!r}: say udpin:{rest} (listen) or udpout:{rest} (send to) instead of udp:")
    if head in _NET:
        m = re.fullmatch(r"(\[[^\]]+\]|[^:]+):(\d+)", rest)
        if not m:
            raise EndpointError(f"{s!r}: expected {head}:HOST:PORT")
        host, port = m.group(1).strip("[]"), int(m.group(2))
        lo = 0 if head in ("udpin", "tcpin") else 1
        if not lo <= port <= 65535:
            raise EndpointError(f"{s!r}: port {port} out of range")
        return head, host, port
    if ":" in s and not re.match(r"^[A-Za-z]:\\", s):
        raise EndpointError(f"{s!r}: unknown endpoint (use {FORMS})")
    dev, _, baud = s.partition(",")
    if baud:
        if not baud.isdigit() or int(baud) <= 0:
            raise EndpointError(f"{s!r}: bad baud rate {baud!r}")
    return "serial", dev, int(baud or 115200)


def size_socket_buffers(sock, nbytes: int) -> int | None:
    """Ask for ``nbytes`` of receive and send buffer (SO_RCVBUFFORCE first, which ignores
    ``net.core.rmem_max`` where the process may; else SO_RCVBUF, capped by it). Returns the receive
    buffer granted as getsockopt reports it (Linux: twice the usable bytes), None if unknown."""
    force = getattr(socket, "SO_RCVBUFFORCE", None)
    done = False
    if force is not None:
        try:
            sock.setsockopt(socket.SOL_SOCKET, force, nbytes)
            done = True
        except OSError:
            pass
    for opt in ((socket.SO_SNDBUF,) if done else (socket.SO_RCVBUF, socket.SO_SNDBUF)):
        try:
            sock.setsockopt(socket.SOL_SOCKET, opt, nbytes)
        except OSError:
            pass
    try:
        return int(sock.getsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF))
    except OSError:
        return None


def _first_line(exc: BaseException) -> str:
    text = getattr(exc, "strerror", None) or str(exc) or type(exc).__name__
    return (str(text).strip().splitlines() or [type(exc).__name__])[0]


def _stream_closed(sock) -> bool:
    """Whether a stream socket's peer has closed it (a peek reads its end of file) rather than having sent nothing yet."""
    if sock is None:
        return False
    try:
        return sock.recv(1, socket.MSG_PEEK | socket.MSG_DONTWAIT) == b""
    except (BlockingIOError, InterruptedError):
        return False
    except OSError:
        return True


class Link:
    """One endpoint: raw reads, per-link parsing, raw writes, counters, reconnection."""

    def __init__(self, spec: str, role: str, source_system: int = 255, source_component: int = 0):
        self.spec = spec
        self.role = role
        self.kind, self.host, self.port = parse_endpoint(spec)
        self._src = (source_system, source_component)
        self.rx_bytes = 0
        self.rx_msgs = 0
        self.tx_bytes = 0
        self.write_errors = 0
        self.read_errors = 0
        self.bad_frames = 0
        self.bad_bytes = 0
        self.rcvbuf_bytes = None  # UDP: the receive buffer the kernel granted (getsockopt)
        self.down = False
        self.next_reconnect = 0.0
        self._opening = None  # tcp, while the peer is away: the reconnecting thread's {"done", "conn"}
        self._dest = None
        if self.kind in ("udpout", "tcp"):
            try:
                info = socket.getaddrinfo(self.host, self.port, socket.AF_INET, socket.SOCK_DGRAM)
                self._dest = info[0][4]
            except OSError as exc:
                raise EndpointError(f"{role} {spec}: cannot resolve {self.host!r} ({_first_line(exc)})") from None
        if self.kind == "serial" and not os.path.exists(self.host) and self.host.startswith("/"):
            raise EndpointError(f"{role} {spec}: no such serial device {self.host}")
        self.conn = self._open()

    def _open(self, bounded: bool = True):
        """The endpoint opened through pymavlink; ``bounded``: a ``tcp:`` connect waits at most
        :data:`CONNECT_TIMEOUT_S` (a process-wide socket default, set around it: not from a thread)."""
        mu = mavutil()
        if self.kind == "serial":
            device, kw = self.host, {"baud": self.port}
        else:
            device, kw = f"{self.kind}:{self.host}:{self.port}", {}
        if self.kind == "tcp":
            kw.update(retries=0, autoreconnect=False)
        if self.kind == "udpin":  # a peer not heard from for this long is sent nothing more (one is always kept)
            kw.update(udp_timeout=UDP_PEER_TIMEOUT_S)
        old_timeout = socket.getdefaulttimeout()
        try:
            if self.kind == "tcp" and bounded:  # pymavlink connects blocking: bound how long a dead peer stalls us
                socket.setdefaulttimeout(CONNECT_TIMEOUT_S)
            conn = mu.mavlink_connection(device, source_system=self._src[0], source_component=self._src[1], **kw)
        except ImportError as exc:
            raise EndpointError(f"cannot open {self.role} {self.spec}: serial ports need pyserial "
                                f"(pip install pyserial; {_first_line(exc)})") from None  # fmt: skip
        except Exception as exc:  # OSError, serial.SerialException, ValueError ...
            raise EndpointError(f"cannot open {self.role} {self.spec}: {_first_line(exc)}") from None
        finally:
            socket.setdefaulttimeout(old_timeout)
        conn.mav.robust_parsing = True
        if self.kind in ("udpin", "udpout"):
            self.rcvbuf_bytes = size_socket_buffers(conn.port, SOCKET_BUFFER_BYTES)
        return conn

    # ------------------------------------------------------------------ reading
    def fileno(self) -> int | None:
        if self.down:
            return None
        fd = getattr(self.conn, "fd", None)
        return fd if isinstance(fd, int) and fd >= 0 else None

    def local_port(self) -> int | None:
        """The bound port of a UDP/TCP socket (useful with port 0)."""
        sock = getattr(self.conn, "listen", None) or getattr(self.conn, "port", None)
        try:
            return sock.getsockname()[1]
        except (AttributeError, OSError):
            return None

    def read(self) -> bytes:
        """Whatever is waiting (b"" if nothing); marks a dead stream link down."""
        if self.down:
            return b""
        c = self.conn
        try:
            if self.kind == "tcpin" and c.port is None:
                c.recv(0)  # accept a waiting client (pymavlink switches fd to it)
                return b""
            data = c.recv(READ_SIZE)
        except OSError as exc:
            if getattr(exc, "errno", None) in (errno.EAGAIN, errno.EWOULDBLOCK, errno.ECONNREFUSED):
                return b""
            self.read_errors += 1
            self._lost()
            return b""
        except Exception:  # serial.SerialException and friends
            self.read_errors += 1
            self._lost()
            return b""
        if not data:
            if self.kind in ("tcp", "tcpin") and _stream_closed(c.port):
                self._lost()  # the peer closed the stream
            # (else nothing is waiting: pymavlink's tcp recv turns EAGAIN into b"", pyserial's read with no data
            # returns b"" and raises where the device is gone; review59: a replay that read its link until empty
            # took a quiet moment for a closed peer and stopped with EBADF on the socket it had closed)
            return b""
        data = bytes(data) if not isinstance(data, bytes) else data
        self.rx_bytes += len(data)
        return data

    def parse(self, data: bytes) -> list:
        """Messages in ``data`` (good frames, BAD_DATA counted and dropped)."""
        mav = self.conn.mav
        try:
            msgs = mav.parse_buffer(data) or []
        except Exception:  # robust parsing returns BAD_DATA; anything else is a parser failure
            msgs = []
            self.bad_frames += 1
            self.bad_bytes += len(data)
            self._reset_parser()
        out = []
        for m in msgs:
            if m.get_type() == "BAD_DATA":
                self.bad_frames += 1
                self.bad_bytes += len(getattr(m, "data", b"") or b"")
            else:
                out.append(m)
        if self.kind in ("udpin", "udpout") and mav.buf_len() > 0:
            self.bad_frames += 1  # a frame cut at the end of a datagram
            self.bad_bytes += mav.buf_len()
            self._reset_parser()
        self.rx_msgs += len(out)
        return out

    def _reset_parser(self) -> None:
        mav = self.conn.mav
        mav.buf = bytearray()
        mav.buf_index = 0
        mav.expected_length = mavutil().mavlink.HEADER_LEN_V1 + 2
        mav.have_prefix_error = False

    # ------------------------------------------------------------------ writing
    def write(self, buf: bytes) -> bool:
        if self.down or not buf:
            return False
        c = self.conn
        try:
            if self.kind == "udpin" and not c.clients:
                return False  # nobody to send to yet
            if self.kind == "tcpin" and c.port is None:
                return False
            if self.kind == "udpout":
                c.port.sendto(buf, self._dest)  # what mavudp.write does, without swallowing errors
            elif self.kind == "tcp":
                c.port.sendall(buf)
            else:
                c.write(buf)
        except OSError as exc:
            self.write_errors += 1
            if getattr(exc, "errno", None) in (errno.ECONNRESET, errno.EPIPE) and self.kind in ("tcp", "tcpin"):
                self._lost()
            return False
        except Exception:
            self.write_errors += 1
            return False
        self.tx_bytes += len(buf)
        return True

    # ------------------------------------------------------------------ link loss
    def _lost(self) -> None:
        c = self.conn
        if self.kind == "tcpin":
            try:
                if c.port is not None:
                    c.port.close()
            except OSError:
                pass
            c.port = None
            c.fd = c.listen.fileno()
            return
        self.down = True
        self.next_reconnect = 0.0
        try:
            c.close()
        except Exception:
            pass

    def maintain(self, now: float) -> bool:
        """Reopen a lost TCP/serial link (once per second). True when it came back. A ``tcp:`` peer is connected to in
        a thread (:meth:`_open_beside`): pymavlink connects blocking, and a host gone from the network held the
        bridge's one loop — every other link's frames and the estimates — for the connect's timeout each second
        (session 53: p99 forwarding 4 → 492 ms)."""
        if not self.down:
            return False
        if self.kind == "tcp":
            return self._open_beside(now)
        if now < self.next_reconnect:
            return False
        self.next_reconnect = now + RECONNECT_S
        try:
            self.conn = self._open()
        except EndpointError:
            return False
        self.down = False
        return True

    def _open_beside(self, now: float) -> bool:
        """The ``tcp:`` reconnection: a thread makes the connection (once per :data:`RECONNECT_S` at most, one at a
        time); True on the call that finds it made."""
        import threading

        box = self._opening
        if box is None:
            if now < self.next_reconnect:
                return False
            self.next_reconnect = now + RECONNECT_S
            box = self._opening = {"done": threading.Event()}

            def connect():
                try:
                    box["conn"] = self._open(bounded=False)  # (no process-wide socket timeout from a thread)
                except EndpointError:
                    pass
                finally:
                    box["done"].set()

            threading.Thread(target=connect, name=f"tepinn-reconnect-{self.role}", daemon=True).start()
            return False
        if not box["done"].is_set():
            return False
        self._opening = None
        if "conn" not in box:
            return False
        self.conn = box["conn"]
        self.down = False
        return True

    def close(self) -> None:
        box, self._opening = self._opening, None
        if box is not None and box.get("conn") is not None:  # a reconnection that finished after the link's end
            try:
                box["conn"].close()
            except Exception:
                pass
        try:
            self.conn.close()
        except Exception:
            pass
