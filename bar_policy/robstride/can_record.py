"""Raw CAN traffic to a file CAN tools open (BLF, ASC), with python-can's own writers.

``CanRecorder(path)`` opens ``can.Logger(path)`` (the suffix picks the format: ``.blf`` Vector binary
logging, ``.asc`` Vector ASCII; CANalyzer, CANoe, asammdf, SavvyCAN and python-can's ``can.LogReader``
read them). ``RobstrideBus`` hands it every frame it sends and every frame it receives, each with the
bus's channel number (1, 2, ... in the order the buses were attached), the direction (``is_rx``) and a
wall-clock timestamp (s since the epoch; received frames keep the interface's own). Any thread may record:
frames are queued and written by the recorder's own thread.
"""

from __future__ import annotations

import logging
import queue
import threading
import time
from pathlib import Path

import can

__all__ = ["CanRecorder"]

log = logging.getLogger(__name__)


class CanRecorder:
    """One CAN log file for several buses; ``record`` from any thread, ``stop`` once at the end.

    ``record`` only queues the frame (a fraction of a microsecond on the control path); a background thread
    copies it with its channel and direction and hands it to python-can's writer, which compresses and
    writes the file (BLF: zlib blocks of 128 kB, milliseconds each, never on the control path).
    """

    def __init__(self, path: str | Path) -> None:
        """Open the file (``.blf`` or ``.asc``; ``ValueError`` for another suffix) and start the writer."""
        self.path = Path(path)
        if self.path.suffix.lower() not in (".blf", ".asc"):
            raise ValueError(f"CAN log {str(self.path)!r}: give a .blf or .asc file")
        self._writer = can.Logger(str(self.path))
        self._lock = threading.Lock()
        self._channels: dict[str, int] = {}
        self._queue: queue.SimpleQueue[tuple[can.Message, int, bool, float] | None] = queue.SimpleQueue()
        self.frames = 0
        """Frames written so far."""
        self.errors = 0
        """Frames the writer failed to write (the first error is logged)."""
        self.stopped = False
        self._thread = threading.Thread(target=self._write_loop, name="can-record", daemon=True)
        self._thread.start()

    def channel(self, interface: str) -> int:
        """The file's channel number of a bus (1-based, in order of first use)."""
        with self._lock:
            return self._channels.setdefault(interface, len(self._channels) + 1)

    def record(self, msg: can.Message, channel: int, *, is_rx: bool) -> None:
        """Queue one frame as seen on ``channel`` (the message must not change afterwards; it is copied)."""
        if not self.stopped:
            self._queue.put((msg, channel, is_rx, time.time()))

    def _write_loop(self) -> None:
        while (item := self._queue.get()) is not None:
            msg, channel, is_rx, now = item
            frame = can.Message(
                timestamp=msg.timestamp if is_rx and msg.timestamp else now,
                arbitration_id=msg.arbitration_id,
                is_extended_id=msg.is_extended_id,
                is_remote_frame=msg.is_remote_frame,
                is_error_frame=msg.is_error_frame,
                dlc=msg.dlc,
                data=bytes(msg.data),
                channel=channel,
                is_rx=is_rx,
            )
            try:
                self._writer.on_message_received(frame)
                self.frames += 1
            except (OSError, ValueError) as e:
                if not self.errors:
                    log.error("CAN log %s: cannot write a frame: %s (further errors counted)", self.path, e)
                self.errors += 1

    def stop(self) -> None:
        """Write the queued frames, then flush and close the file (idempotent)."""
        with self._lock:
            if self.stopped:
                return
            self.stopped = True
        self._queue.put(None)
        self._thread.join()
        self._writer.stop()
        log.info("CAN traffic: %d frames written to %s", self.frames, self.path)
