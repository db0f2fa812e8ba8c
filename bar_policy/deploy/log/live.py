"""``bar-deploy --live``: the run log's channels served on localhost to the Foxglove app (Foxglove SDK).

``LiveServer`` starts the Foxglove SDK's WebSocket server on the loopback interface only (``127.0.0.1``:
nothing outside the machine can connect; from another machine, forward the port over SSH). The run log's
writer (``mcap_write.McapRunWriter``) advertises every channel it writes (same topic, schema and encoding)
and sends every message it writes to the file to the server too, stamped with the same log time. In the
Foxglove app: *Open connection* -> *Foxglove WebSocket* -> ``ws://localhost:8765``.
"""

from __future__ import annotations

import logging
from typing import Any

__all__ = ["LIVE_HOST", "LIVE_PORT", "LiveError", "LiveServer"]

log = logging.getLogger(__name__)

LIVE_HOST = "127.0.0.1"
"""The only interface the live server binds to (loopback)."""
LIVE_PORT = 8765
"""Default port (the Foxglove app's default for a Foxglove WebSocket connection)."""


class LiveError(ValueError):
    """The live server cannot start (the port is taken, ...)."""


class LiveServer:
    """A Foxglove WebSocket server on ``127.0.0.1`` with its own channels (its own SDK context)."""

    def __init__(self, port: int = LIVE_PORT, *, name: str = "bar-deploy") -> None:
        """Start serving.

        Args:
            port: TCP port on 127.0.0.1 (0: any free port; ``port`` then holds the one chosen).
            name: server name shown by the Foxglove app.

        Raises:
            LiveError: the server could not start (naming the port and the reason).
        """
        if not 0 <= port <= 65535:
            raise LiveError(f"live port must be in 0..65535, got {port}")
        import foxglove

        self._foxglove = foxglove
        self._context = foxglove.Context()  # channels here go to this server only (no global sinks)
        try:
            self._server = foxglove.start_server(name=name, host=LIVE_HOST, port=port, context=self._context)
        except Exception as e:  # the SDK raises its own error types (port in use: an OS error inside)
            raise LiveError(f"cannot serve on {LIVE_HOST}:{port}: {e}") from None
        self.port = int(self._server.port)
        """The port served (the one chosen when ``port`` was 0)."""
        self._channels: dict[str, Any] = {}
        self.stopped = False
        log.info("live view: ws://localhost:%d (Foxglove app: open connection, WebSocket)", self.port)

    @property
    def url(self) -> str:
        """The WebSocket URL to open in the Foxglove app."""
        return f"ws://localhost:{self.port}"

    def add_channel(
        self, topic: str, schema: tuple[str, str, bytes], message_encoding: str, metadata: dict[str, str]
    ) -> None:
        """Advertise ``topic`` with an MCAP schema ``(name, encoding, data)`` and message encoding."""
        name, encoding, data = schema
        self._channels[topic] = self._foxglove.Channel(
            topic,
            schema=self._foxglove.Schema(name=name, encoding=encoding, data=data),
            message_encoding=message_encoding,
            context=self._context,
            metadata=dict(metadata),
        )

    def publish(self, topic: str, data: bytes, log_time_ns: int) -> None:
        """Send one message (the bytes written to the file) to the connected clients."""
        channel = self._channels.get(topic)
        if channel is not None and not self.stopped:
            channel.log(data, log_time=int(log_time_ns))

    def stop(self) -> None:
        """Close the channels and stop the server (idempotent)."""
        if self.stopped:
            return
        self.stopped = True
        for channel in self._channels.values():
            channel.close()
        self._server.stop()
