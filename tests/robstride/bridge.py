"""Loopback bridge between a subprocess and this process's python-can ``virtual`` channels (tests only).

python-can's ``virtual`` bus lives inside one process, so a driver in a real subprocess (killed with SIGKILL,
or sent SIGTERM) cannot reach the in-process emulator directly, and ``udp_multicast`` would leave the
machine. Instead the subprocess uses python-can's own socketcand client
(``can.interfaces.socketcand.SocketCanDaemonBus``) and ``SocketcandBridge``, in the test process, speaks
the server side of socketcand's raw mode on 127.0.0.1 and forwards every frame between the TCP connection
and a ``virtual`` channel. ``install_client()`` (in the subprocess) makes ``can.Bus(interface="virtual")``
open such a client, so the product code runs unchanged.

Protocol subset (socketcand raw mode): server ``< hi >``; client ``< open CH >`` -> ``< ok >``; client
``< rawmode >`` -> ``< ok >``; then client ``< send ID DLC B0 B1 .. >`` and server
``< frame ID SECONDS HEXDATA >`` (ID: 8 hex digits for an extended id).
"""

from __future__ import annotations

import os
import socket
import threading
from collections.abc import Mapping

import can
from can.interfaces.socketcand.socketcand import SocketCanDaemonBus

PORT_ENV = "BAR_TEST_BRIDGE_PORT"


class SocketcandBridge:
    """socketcand server on 127.0.0.1: client channel name -> in-process ``virtual`` channel."""

    def __init__(self, channels: Mapping[str, str]) -> None:
        self.channels = dict(channels)
        self._server = socket.create_server(("127.0.0.1", 0))
        self._server.settimeout(0.1)
        self.port = self._server.getsockname()[1]
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self.sessions_ended = 0
        """Client connections that ended (closed, reset or killed)."""
        self._spawn(self._accept)

    def _spawn(self, target, *args) -> None:
        t = threading.Thread(target=target, args=args, daemon=True)
        self._threads.append(t)
        t.start()

    def _accept(self) -> None:
        while not self._stop.is_set():
            try:
                conn, _ = self._server.accept()
            except TimeoutError:
                continue
            except OSError:
                return
            self._spawn(self._session, conn)

    def _session(self, conn: socket.socket) -> None:
        conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        conn.settimeout(0.1)
        buf = b""
        bus = None
        pumping = threading.Event()
        try:
            conn.sendall(b"< hi >")
            while not self._stop.is_set():
                try:
                    chunk = conn.recv(4096)
                except TimeoutError:
                    continue
                if not chunk:
                    break  # the client is gone (closed or killed): forward nothing more
                buf += chunk
                while b">" in buf:
                    raw, buf = buf.split(b">", 1)
                    words = raw.decode("ascii").strip().lstrip("<").split()
                    if words[:1] == ["open"]:
                        bus = can.Bus(interface="virtual", channel=self.channels.get(words[1], words[1]))
                        conn.sendall(b"< ok >")
                    elif words[:1] == ["rawmode"]:
                        conn.sendall(b"< ok >")
                    elif words[:1] == ["send"] and bus is not None:
                        ident, dlc = words[1], int(words[2], 16)
                        data = bytes(int(b, 16) for b in words[3 : 3 + dlc])
                        ext = len(ident) > 3
                        msg = can.Message(arbitration_id=int(ident, 16), data=data, is_extended_id=ext)
                        if not pumping.is_set():  # the handshake is over: frames may flow back now
                            pumping.set()
                            self._spawn(self._pump, bus, conn)
                        bus.send(msg)
        except OSError:
            pass
        finally:
            self.sessions_ended += 1
            pumping.set()
            if bus is not None:
                bus.shutdown()
            conn.close()

    def _pump(self, bus: can.BusABC, conn: socket.socket) -> None:
        while not self._stop.is_set():
            try:
                msg = bus.recv(timeout=0.05)
            except (can.CanError, AttributeError):  # the session closed the bus
                return
            if msg is None:
                continue
            ident = f"{msg.arbitration_id:08X}" if msg.is_extended_id else f"{msg.arbitration_id:03X}"
            try:
                conn.sendall(f"< frame {ident} {msg.timestamp:.6f} {bytes(msg.data).hex()} >".encode())
            except OSError:
                return

    def close(self) -> None:
        self._stop.set()
        self._server.close()
        for t in self._threads:
            t.join(timeout=1.0)

    def __enter__(self) -> SocketcandBridge:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class BridgedBus(SocketCanDaemonBus):
    """python-can's socketcand client, pointed at the bridge whose port is in ``$BAR_TEST_BRIDGE_PORT``."""

    def __init__(self, channel: str, **kwargs) -> None:
        kwargs.pop("receive_own_messages", None)
        super().__init__(channel=channel, host="127.0.0.1", port=int(os.environ[PORT_ENV]), tcp_tune=True)


def install_client() -> None:
    """In the subprocess: make ``can.Bus(interface="virtual", channel=X)`` a ``BridgedBus``."""
    from can.interfaces import BACKENDS

    BACKENDS["virtual"] = (__name__, "BridgedBus")
