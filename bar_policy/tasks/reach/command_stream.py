"""``stream:stdin`` / ``stream:udp:PORT``: live reach targets as JSON lines (``commands.py``)."""

from __future__ import annotations

import queue
import socket
import threading
from collections.abc import Mapping
from typing import IO

import numpy as np

from bar_policy._files import loads_json, shorten
from bar_policy.tasks.reach.shared import ReachTargetConfig
from bar_policy.tasks.reach.sources import CommandError, ReachSource, _vector, log

__all__ = ["StreamCommands"]


class StreamCommands(ReachSource):
    """Live targets from JSON lines on stdin or UDP datagrams on 127.0.0.1 (a background reader thread)."""

    def __init__(
        self,
        names: tuple[str, ...],
        initial: Mapping[str, np.ndarray],
        *,
        stdin: IO[str] | None = None,
        udp_port: int | None = None,
        workspace: ReachTargetConfig | None = None,
    ) -> None:
        super().__init__(names, workspace)
        if (stdin is None) == (udp_port is None):
            raise CommandError("a stream source reads either stdin or a UDP port")
        self._current = {n: _vector(n, initial[n], "initial command") for n in self.names}
        self._queue: queue.SimpleQueue[str] = queue.SimpleQueue()
        self.bad_messages = 0
        """Messages rejected (malformed JSON, wrong keys or sizes, non-finite)."""
        self.messages = 0
        """Messages accepted."""
        self._stop = threading.Event()
        self._sock: socket.socket | None = None
        if udp_port is not None:
            if not 0 <= udp_port < 65536:
                raise CommandError(f"UDP port must be in 0..65535 (0: any free port), got {udp_port}")
            sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            try:
                sock.bind(("127.0.0.1", udp_port))  # loopback only, never another address
            except OSError as e:
                sock.close()
                raise CommandError(f"cannot bind UDP 127.0.0.1:{udp_port}: {e.strerror or e}") from None
            sock.settimeout(0.1)
            self._sock = sock
            self.port = sock.getsockname()[1]
            target = self._read_udp
        else:
            self._stdin = stdin
            target = self._read_stdin
        self._thread = threading.Thread(target=target, name="bar-deploy-commands", daemon=True)
        self._thread.start()

    def _read_stdin(self) -> None:
        assert self._stdin is not None
        for line in self._stdin:
            if self._stop.is_set():
                break
            if line.strip():
                self._queue.put(line)

    def _read_udp(self) -> None:
        assert self._sock is not None
        while not self._stop.is_set():
            try:
                data = self._sock.recv(65536)
            except TimeoutError:
                continue
            except OSError:
                break
            for line in data.decode("utf-8", errors="replace").splitlines():
                if line.strip():
                    self._queue.put(line)

    def _apply(self, line: str) -> None:
        try:
            msg = loads_json(line, "message", CommandError)
            if not isinstance(msg, dict):
                raise CommandError(f"expected a JSON object, got {type(msg).__name__}")
            unknown = sorted(set(msg) - set(self.names) - {"t"})
            known = [n for n in self.names if n in msg]
            if unknown or not known:
                raise CommandError(f"keys must be among {list(self.names)}; got {shorten(sorted(msg))}")
            update = {n: _vector(n, msg[n], "stream message") for n in known}
        except CommandError as e:
            self.bad_messages += 1
            log.warning(
                "ignored command message %r: %s (%d bad so far)", line.strip()[:200], e, self.bad_messages
            )
            return
        self._current.update(update)
        self.messages += 1

    def _values(self, t: float) -> dict[str, np.ndarray]:
        while True:
            try:
                line = self._queue.get_nowait()
            except queue.Empty:
                break
            self._apply(line)
        return {n: v.copy() for n, v in self._current.items()}

    def describe(self) -> str:
        """One line for logs."""
        return f"stream(udp 127.0.0.1:{self.port})" if self._sock else "stream(stdin)"

    def close(self) -> None:
        """Stop the reader thread and close the socket."""
        self._stop.set()
        if self._sock is not None:
            self._sock.close()
            self._sock = None
