"""Discovery and parameters of one bus: ``scan`` (type 0), ``read_param`` (17), ``write_param`` (18).

Activation-time exchanges (one request, one reply), not the control path: ``RobstrideBus`` (``bus``) inherits
them from ``BusParams`` and provides the raw I/O they run on (``send``, ``request``, ``drain``, ``_recv``).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable

from bar_policy.robstride import protocol as proto
from bar_policy.robstride.errors import OperationError

__all__ = ["BusParams"]


class BusParams:
    """Scan and parameter exchanges over the raw I/O of the class that inherits them (``RobstrideBus``)."""

    interface: str
    host_id: int
    param_timeout: float
    send: Callable[[proto.Frame], None]
    request: Callable[[proto.Frame, Callable[[proto.Reply], bool], float], proto.Reply]
    drain: Callable[[], list[proto.Reply]]
    _recv: Callable[[float], proto.Reply | bool | None]

    def scan(
        self, ids: Iterable[int] = range(1, 128), *, timeout: float = 0.05, batch: int = 8
    ) -> dict[int, bytes]:
        """Ask every id in ``ids`` for its device id (type 0); returns responder id -> 64-bit MCU id.

        Read-only. Queries go out ``batch`` at a time so a short SocketCAN TX queue does not overflow.
        """
        self.drain()
        found: dict[int, bytes] = {}
        id_list = list(ids)

        def collect(until: float) -> None:
            while (remaining := until - time.perf_counter()) > 0:
                reply = self._recv(remaining)
                if reply is None:
                    return
                if isinstance(reply, proto.DeviceIdReply):
                    found[reply.motor_id] = reply.uid

        for k in range(0, len(id_list), batch):
            for can_id in id_list[k : k + batch]:
                self.send(proto.get_id_frame(can_id, self.host_id))
            collect(time.perf_counter() + 0.002)
        collect(time.perf_counter() + timeout)
        return dict(sorted(found.items()))

    def read_param(
        self, can_id: int, index: int, *, dtype: str | None = None, timeout: float | None = None
    ) -> float | int:
        """Read a parameter (type 17); ``OperationError`` when the motor reports failure.

        The deadline is ``timeout``, or ``param_timeout`` when None.
        """
        frame = proto.read_param_frame(can_id, index, self.host_id)
        reply = self.request(
            frame,
            lambda r: isinstance(r, proto.ParamReply) and r.motor_id == can_id and r.index == index,
            self.param_timeout if timeout is None else timeout,
        )
        if not isinstance(reply, proto.ParamReply):  # pragma: no cover - guaranteed by the match
            raise OperationError(f"unexpected reply {reply!r}")
        if reply.status != 0:
            raise OperationError(
                f"{self.interface}: id {can_id} refused to read parameter {index:#06x} "
                f"(status {reply.status})"
            )
        return reply.value(dtype)

    def write_param(
        self,
        can_id: int,
        index: int,
        value: float | int,
        *,
        dtype: str | None = None,
        timeout: float | None = None,
    ) -> None:
        """Write a parameter (type 18, volatile) and wait for the motor's type-2 acknowledgement.

        The deadline is ``timeout``, or ``param_timeout`` when None.
        """
        frame = proto.write_param_frame(can_id, index, value, dtype=dtype, host_id=self.host_id)
        self.request(
            frame,
            lambda r: isinstance(r, proto.Feedback) and r.motor_id == can_id,
            self.param_timeout if timeout is None else timeout,
        )
