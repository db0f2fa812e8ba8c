"""Raw CAN traffic to a file CAN tools open (BLF, ASC), with python-can's own writers.

``CanRecorder(path)`` opens ``can.Logger(path)`` (the suffix picks the format: ``.blf`` Vector binary
logging, ``.asc`` Vector ASCII; CANalyzer, CANoe, asammdf, SavvyCAN and python-can's ``can.LogReader``
read them). ``RobstrideBus`` hands it every frame it sends and every frame it receives, each with the
bus's channel number (1, 2, ... in the order the buses were attached), the direction (``is_rx``) and a
wall-clock timestamp (s since the epoch; received frames keep the interface's own). One lock serialises
the buses' writes, so any thread may record.
"""

from __future__ import annotations

import logging
import threading
import time
from pathlib import Path

import can

__all__ = ["CanRecorder"]

log = logging.getLogger(__name__)


class CanRecorder:
    """One CAN log file for several buses; ``record`` from any thread, ``stop`` once at the end."""

    def __init__(self, path: str | Path) -> None:
        """Open the file (``.blf`` or ``.asc``; ``ValueError`` for another suffix)."""
        self.path = Path(path)
        if self.path.suffix.lower() not in (".blf", ".asc"):
            raise ValueError(f"CAN log {str(self.path)!r}: give a .blf or .asc file")
        self._writer = can.Logger(str(self.path))
        self._lock = threading.Lock()
        self._channels: dict[str, int] = {}
        self.frames = 0
        """Frames written so far."""
        self.stopped = False

    def channel(self, interface: str) -> int:
        """The file's channel number of a bus (1-based, in order of first use)."""
        with self._lock:
            return self._channels.setdefault(interface, len(self._channels) + 1)

    def record(self, msg: can.Message, channel: int, *, is_rx: bool) -> None:
        """Write one frame as seen on ``channel`` (a copy: the caller's message is left as it is)."""
        stamp = msg.timestamp if is_rx and msg.timestamp else time.time()
        frame = can.Message(
            timestamp=stamp,
            arbitration_id=msg.arbitration_id,
            is_extended_id=msg.is_extended_id,
            is_remote_frame=msg.is_remote_frame,
            is_error_frame=msg.is_error_frame,
            dlc=msg.dlc,
            data=bytes(msg.data),
            channel=channel,
            is_rx=is_rx,
        )
        with self._lock:
            if self.stopped:
                return
            self._writer.on_message_received(frame)
            self.frames += 1

    def stop(self) -> None:
        """Flush and close the file (idempotent)."""
        with self._lock:
            if self.stopped:
                return
            self.stopped = True
            self._writer.stop()
        log.info("CAN traffic: %d frames written to %s", self.frames, self.path)
