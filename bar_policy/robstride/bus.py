"""One Robstride CAN interface: an injected ``can.BusABC`` plus the motors on it (style.md item 15).

``RobstrideBus`` works in *joint* coordinates: it applies ``joint = direction * (raw - homing_offset)`` to
feedback and the inverse to commands, so its callers never see motor frames. Every exchange is a *round*:
one frame per motor out, one type-2 reply per motor back before a deadline. Late or unsolicited frames
are drained and inspected before the next round, so a type-21 fault frame or a stranger on the bus is
never dropped silently, and a late reply is never mistaken for a fresh one. The activation-time checks and
cap writes (scan match, model plausibility, torque/current caps) are functions in ``activation``
(over a bus; this module does not import it).

Its values (``MotorConfig``, ``BusReading``) and deadlines (``DEFAULT_REPLY_TIMEOUT``: one round) are in
``bus_types``; the activation's stop checks and retries (``retry``) are ``startup.StartupControl``.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Sequence

import can
import numpy as np

from bar_policy.robot.mit import wire_ranges
from bar_policy.robstride import protocol as proto
from bar_policy.robstride.bus_params import BusParams
from bar_policy.robstride.bus_types import (
    DEFAULT_PARAM_TIMEOUT,
    DEFAULT_REPLY_TIMEOUT,
    BusReading,
    MotorConfig,
)
from bar_policy.robstride.can_record import CanRecorder
from bar_policy.robstride.canbus import down_hint
from bar_policy.robstride.errors import FaultError, OperationError, TimeoutError, UnexpectedDeviceError
from bar_policy.robstride.startup import StartupControl

__all__ = ["RobstrideBus"]

log = logging.getLogger(__name__)

_SEND_RETRIES = 20
_SEND_RETRY_SLEEP = 0.0002
_QUEUED_AFTER_DEADLINE = 64
"""``await_reply`` reads at most this many frames already queued past its deadline (bounded by chatter)."""


class RobstrideBus(BusParams):
    """The motors on one CAN interface, over an injected ``can.BusABC``.

    A context manager; ``shutdown()`` closes the CAN bus (it never sends frames: stopping motors is the
    caller's explicit decision, see ``stop``). ``scan``, ``read_param`` and ``write_param`` come from
    ``BusParams`` (``bus_params``).
    """

    def __init__(
        self,
        bus: can.BusABC,
        motors: Sequence[MotorConfig],
        *,
        interface: str = "can0",
        host_id: int = proto.HOST_ID,
        reply_timeout: float = DEFAULT_REPLY_TIMEOUT,
    ) -> None:
        ids = [m.can_id for m in motors]
        if len(set(ids)) != len(ids):
            raise ValueError(f"{interface}: duplicate CAN ids in {ids}")
        if reply_timeout <= 0:
            raise ValueError(f"reply_timeout must be > 0 s, got {reply_timeout}")
        self.bus = bus
        self.motors = tuple(motors)
        self.interface = interface
        self.host_id = host_id
        self.reply_timeout = reply_timeout
        self.param_timeout = max(DEFAULT_PARAM_TIMEOUT, reply_timeout)
        """Deadline of one parameter read or write, s: 50 ms, or the round deadline when that is longer."""
        self.ids = tuple(ids)
        self.models = {m.can_id: m.model for m in motors}
        self._index = {m.can_id: i for i, m in enumerate(motors)}
        self._ranges = wire_ranges([m.model for m in motors])
        self._bounds = proto.field_bounds(self._ranges)
        self._direction = np.array([m.direction for m in motors], dtype=np.float64)
        self.offsets = np.array([m.homing_offset for m in motors], dtype=np.float64)
        """Homing offsets, rad (settable for calibration tools)."""
        self.clamps = proto.ClampCounter()
        """Deliberately clamped MIT fields, counted per field and id."""
        self.ignored_frames = 0
        """Frames that were not valid replies (garbage, other hosts' requests), counted."""
        self.late_frames = 0
        """Replies that arrived after their round's deadline."""
        self._logged_clamps: set[tuple[int, str]] = set()
        self._closed = False
        self._pending_unexpected: set[int] = set()
        self._pending_faultwords: dict[int, int] = {}
        self._pending_faultbits: dict[int, int] = {}
        self.last_reading = self.empty_reading()
        """The most recent reading of this bus (NaN where replies were missing)."""
        self.recorder: CanRecorder | None = None
        """Where every frame sent and received is recorded (``record_to``); None: nowhere."""
        self._record_channel = 0
        self.retry: StartupControl | None = None
        """Set by ``RobstrideGroup.activate`` while it runs: ``request`` (parameter reads and writes) then
        retries a missing reply (``StartupControl.attempt``); None otherwise (tools, the control path)."""

    # ----------------------------------------------------------------------------------------------
    # lifecycle
    def __enter__(self) -> RobstrideBus:
        return self

    def __exit__(self, *exc: object) -> None:
        self.shutdown()

    def shutdown(self) -> None:
        """Close the CAN bus. Safe to call twice."""
        if not self._closed:
            self._closed = True
            self.bus.shutdown()

    def record_to(self, recorder: CanRecorder | None) -> None:
        """Record every frame this bus sends and receives from now on (None stops recording here)."""
        self._record_channel = 0 if recorder is None else recorder.channel(self.interface)
        self.recorder = recorder

    def name_of(self, can_id: int) -> str:
        """Joint name of a motor id (or ``id N``)."""
        i = self._index.get(can_id)
        return self.motors[i].name if i is not None else f"id {can_id}"

    # ----------------------------------------------------------------------------------------------
    # raw I/O
    def send(self, frame: proto.Frame) -> None:
        """Send one extended frame, retrying briefly on a full TX queue (ENOBUFS).

        An interface that is down or gone fails at once, with the command that brings it up.
        """
        msg = can.Message(arbitration_id=frame[0], data=frame[1], is_extended_id=True)
        for attempt in range(_SEND_RETRIES):
            try:
                self.bus.send(msg)
                if self.recorder is not None:
                    self.recorder.record(msg, self._record_channel, is_rx=False)
                return
            except can.CanOperationError as exc:
                hint = down_hint(exc.error_code, self.interface)
                if hint is not None:
                    raise OperationError(f"{self.interface}: cannot send: {hint}") from exc
                if attempt == _SEND_RETRIES - 1:
                    raise OperationError(f"{self.interface}: cannot send {frame!r}: {exc}") from exc
                time.sleep(_SEND_RETRY_SLEEP)

    def _recv(self, timeout: float) -> proto.Reply | bool | None:
        """One reply, None on timeout, False for an ignored (undecodable) frame."""
        try:
            msg = self.bus.recv(timeout=max(timeout, 0.0))
        except can.CanError as exc:  # interface down, socket error
            hint = down_hint(getattr(exc, "error_code", None), self.interface)
            raise OperationError(f"{self.interface}: receive failed: {hint or exc}") from exc
        if msg is None:
            return None
        if self.recorder is not None:
            self.recorder.record(msg, self._record_channel, is_rx=True)
        if msg.is_error_frame or msg.is_remote_frame:
            self.ignored_frames += 1
            return False
        try:
            return proto.decode_reply(
                msg.arbitration_id, msg.data, is_extended_id=msg.is_extended_id, models=self.models
            )
        except proto.FrameError as exc:
            self.ignored_frames += 1
            if self.ignored_frames <= 10 or self.ignored_frames % 1000 == 0:
                log.warning("%s: ignored frame (%d so far): %s", self.interface, self.ignored_frames, exc)
            return False

    def request(
        self, frame: proto.Frame, match: Callable[[proto.Reply], bool], timeout: float
    ) -> proto.Reply:
        """Send one frame; return the first reply ``match`` accepts, ``TimeoutError`` at the deadline.

        While ``retry`` is set, a missing reply is retried as it says (the frame is sent again).
        """
        if self.retry is not None:
            return self.retry.attempt(
                f"{self.interface} parameter exchange", lambda: self._request_once(frame, match, timeout)
            )
        return self._request_once(frame, match, timeout)

    def _request_once(
        self, frame: proto.Frame, match: Callable[[proto.Reply], bool], timeout: float
    ) -> proto.Reply:
        self.drain()
        self.send(frame)
        deadline = time.perf_counter() + timeout
        while (remaining := deadline - time.perf_counter()) > 0:
            reply = self._recv(remaining)
            if reply is None:
                break
            if reply is not False and match(reply):
                return reply
        raise TimeoutError(
            f"{self.interface}: no reply to {frame!r} within {timeout * 1e3:.1f} ms",
            missing=(frame[0] & 0xFF,),
            interface=self.interface,
        )

    def drain(self) -> list[proto.Reply]:
        """Read every frame already queued (non-blocking); returns the decoded ones."""
        out = []
        while (reply := self._recv(0.0)) is not None:
            if reply is not False:
                out.append(reply)
        return out

    # ----------------------------------------------------------------------------------------------
    # rounds
    def send_round(self, frames: Sequence[proto.Frame]) -> float:
        """Drain stale frames, send one frame per motor; returns the deadline (``perf_counter``)."""
        self._pending_unexpected = set()
        self._pending_faultwords = {}
        self._pending_faultbits = {}
        for reply in self.drain():
            self._note(reply, None)
        for frame in frames:
            self.send(frame)
        return time.perf_counter() + self.reply_timeout

    def _note(self, reply: proto.Reply, got: dict[int, proto.Feedback] | None) -> None:
        motor_id = reply.motor_id
        if motor_id not in self._index:
            if not isinstance(reply, proto.ActiveReport):
                self._pending_unexpected.add(motor_id)
            return
        if isinstance(reply, proto.FaultReport):
            if reply.fault_word:
                self._pending_faultwords[motor_id] = reply.fault_word
        elif isinstance(reply, proto.Feedback):
            if got is None:  # a late reply drained before a new round: count it, keep its fault bits
                self.late_frames += 1
                if reply.faults:
                    self._pending_faultbits[motor_id] = reply.faults
            else:
                got[motor_id] = reply

    def collect_round(self, deadline: float, *, strict: bool = True) -> BusReading:
        """Collect one type-2 reply per motor until ``deadline`` (``perf_counter``).

        Raises (when ``strict``), in this order of precedence: ``UnexpectedDeviceError`` (a sender that is not
        one of this bus's motors), ``FaultError`` (fault bits or a type-21 frame), ``TimeoutError`` (missing
        replies, naming the ids). The reading is stored in ``last_reading`` before raising.
        """
        got: dict[int, proto.Feedback] = {}
        n = len(self.ids)
        while len(got) < n and (remaining := deadline - time.perf_counter()) > 0:
            reply = self._recv(remaining)
            if reply is None:
                break
            if reply is not False:
                self._note(reply, got)
        # Frames already queued count even when this thread was descheduled past the deadline (a loaded
        # host): the deadline bounds the wait, it does not discard replies that did arrive.
        while len(got) < n and (reply := self._recv(0.0)) is not None:
            if reply is not False:
                self._note(reply, got)
        reading = self._reading(got)
        self.last_reading = reading
        if not strict:
            return reading
        if self._pending_unexpected:
            ids = sorted(self._pending_unexpected)
            raise UnexpectedDeviceError(
                f"{self.interface}: frames from unexpected CAN ids {ids}; expected only {list(self.ids)}",
                can_ids=ids,
                interface=self.interface,
            )
        bits = dict(self._pending_faultbits)
        bits.update({i: int(f.faults) for i, f in got.items() if f.faults})
        words = self._pending_faultwords
        if bits or words:
            desc = "; ".join(
                f"{self.name_of(i)} (id {i}): "
                + ", ".join(proto.fault_names(bits.get(i, 0)) + proto.fault_word_names(words.get(i, 0)))
                for i in sorted(set(bits) | set(words))
            )
            raise FaultError(
                f"{self.interface}: motor fault: {desc}",
                faults=bits,
                fault_words=words,
                interface=self.interface,
            )
        missing = [i for i in self.ids if i not in got]
        if missing:
            raise TimeoutError(
                f"{self.interface}: no reply within {self.reply_timeout * 1e3:.1f} ms from "
                f"{[(i, self.name_of(i)) for i in missing]}",
                missing=missing,
                interface=self.interface,
            )
        return reading

    def send_stop(self, motor_id: int, *, clear_faults: bool = False) -> float:
        """Drain what is queued (an earlier reply is no answer to this stop), send one stop frame.

        Returns the deadline of its reply (``perf_counter``), for ``await_reply``.
        """
        for reply in self.drain():
            self._note(reply, None)
        self.send(proto.stop_frame(motor_id, clear_faults=clear_faults, host_id=self.host_id))
        return time.perf_counter() + self.reply_timeout

    def await_reply(self, motor_id: int, deadline: float) -> proto.Feedback | None:
        """The first type-2 reply carrying ``motor_id`` until ``deadline`` (``perf_counter``); None if none.

        A reply carrying another id is not this motor's answer: it is noted (late or unexpected) and the
        wait goes on. Frames queued by the deadline still count (a descheduled host, as in
        ``collect_round``), at most ``_QUEUED_AFTER_DEADLINE`` of them.
        """
        queued = 0
        while True:
            remaining = deadline - time.perf_counter()
            if remaining <= 0:
                queued += 1
                if queued > _QUEUED_AFTER_DEADLINE:
                    return None
            reply = self._recv(max(remaining, 0.0))
            if reply is None:
                return None
            if reply is False:
                continue
            if isinstance(reply, proto.Feedback) and reply.motor_id == motor_id:
                return reply
            self._note(reply, None)

    def empty_reading(self) -> BusReading:
        """A reading with no replies (NaN, mode -1)."""
        return self._reading({})

    def _reading(self, got: dict[int, proto.Feedback]) -> BusReading:
        n = len(self.ids)
        raw = np.full((4, n), np.nan)
        mode = np.full(n, -1, dtype=np.int64)
        faults = np.zeros(n, dtype=np.int64)
        for motor_id, fb in got.items():
            i = self._index[motor_id]
            raw[:, i] = (fb.position, fb.velocity, fb.torque, fb.temperature)
            mode[i], faults[i] = fb.mode, fb.faults
        d = self._direction
        return BusReading(
            q=d * (raw[0] - self.offsets),
            dq=d * raw[1],
            tau=d * raw[2],
            temperature=raw[3],
            mode=mode,
            faults=faults,
            stamp=time.monotonic(),
        )

    def mit_frames(
        self, q: np.ndarray, dq: np.ndarray, kp: np.ndarray, kd: np.ndarray, tau: np.ndarray
    ) -> list[proto.Frame]:
        """Encode joint-frame MIT commands (each shape (num_motors,)) into one frame per motor.

        Applies ``raw = direction * q + homing_offset`` (velocity and torque: direction only), clamps
        deliberately and counts the clamps in ``clamps`` (logging the first clamp of each id and field).
        """
        d = self._direction
        values = np.empty((5, len(self.ids)))
        values[0] = q
        values[1] = dq
        values[2] = kp
        values[3] = kd
        values[4] = tau
        values[[0, 1, 4]] *= d  # velocity and torque: direction only; position: also the offset
        values[0] += self.offsets
        frames, clamped = proto.encode_mit_batch(self.ids, self._ranges, values, bounds=self._bounds)
        if clamped.any():
            for f, j in np.argwhere(clamped):
                can_id, fname = self.ids[j], proto.MIT_FIELDS[f]
                self.clamps.add(can_id, (fname,))
                if (can_id, fname) not in self._logged_clamps:
                    self._logged_clamps.add((can_id, fname))
                    log.warning(
                        "%s: clamped MIT %s=%g of %s (id %d) to its wire range (counted in .clamps)",
                        self.interface,
                        fname,
                        values[f, j],
                        self.name_of(can_id),
                        can_id,
                    )
        return frames

    def exchange(self, frames: Sequence[proto.Frame], *, strict: bool = True) -> BusReading:
        """``send_round`` then ``collect_round``."""
        return self.collect_round(self.send_round(frames), strict=strict)

    def enable_frames(self) -> list[proto.Frame]:
        """Type-3 enable frames for every motor."""
        return [proto.enable_frame(i, self.host_id) for i in self.ids]

    def stop_frames(self, *, clear_faults: bool = False) -> list[proto.Frame]:
        """Type-4 stop frames for every motor (byte0 = 1 when ``clear_faults``)."""
        return [proto.stop_frame(i, clear_faults=clear_faults, host_id=self.host_id) for i in self.ids]
