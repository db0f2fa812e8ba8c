"""The one interface that the sim, mock and real targets implement.

A target owns the joints: it reads their state and applies MIT commands for all of them, in canonical
joint order. The runtime never knows which target it drives.

Timing: a *synchronous* target (the headless sim) advances its own clock when the runtime calls
``advance(dt)``, so it can run faster than real time; an asynchronous target (mock at a fixed rate, the real
bus) lives in wall-clock time and ``advance`` only returns; the runtime's deadline scheduler keeps the rate.

The safe ending: ``safe_stop`` sends damping, then stop, and returns a ``StopReport``: per joint, whether the
damping and the stop frames were answered. The real target knows whether each motor replied; the sim and mock
targets always answer (the default ``safe_stop``).
"""

from __future__ import annotations

import abc
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from bar_policy.robot.mit import MitCommand

__all__ = ["JointState", "StopReport", "Target", "TargetError", "run_metadata_of"]


class TargetError(RuntimeError):
    """A target cannot read or command its joints (lost bus, fault, dead simulator)."""


@dataclass(frozen=True)
class JointState:
    """Measured state of all joints, canonical order. Arrays have shape (num_joints,)."""

    q: np.ndarray
    """Positions, rad."""
    dq: np.ndarray
    """Velocities, rad/s."""
    tau: np.ndarray
    """Measured (or applied) torque, N*m."""
    stamp: float
    """Time the reading was taken, s, on the target's clock (``time.monotonic`` for async targets)."""
    faults: tuple[str, ...] = ()
    """Active fault descriptions reported by the hardware (empty when healthy)."""


@dataclass(frozen=True)
class StopReport:
    """What the safe stop's frames got back, per joint in canonical order."""

    joint_names: tuple[str, ...]
    damping_answered: tuple[bool, ...]
    """True where the joint answered the (last) damping frame."""
    stop_answered: tuple[bool, ...]
    """True where the joint answered the stop frame."""
    detail: str = ""
    """A note for the summary (``"dry run: nothing was enabled"``), empty by default."""

    def __post_init__(self) -> None:
        n = len(self.joint_names)
        if len(self.damping_answered) != n or len(self.stop_answered) != n:
            raise ValueError(f"StopReport needs {n} answers per frame kind")

    @classmethod
    def all_answered(cls, joint_names: Sequence[str], detail: str = "") -> StopReport:
        """Every joint answered both frames (targets that always answer: sim, mock)."""
        n = len(joint_names)
        return cls(tuple(joint_names), (True,) * n, (True,) * n, detail)

    @property
    def no_damping_reply(self) -> tuple[str, ...]:
        """Joints that did not answer the damping frame."""
        return tuple(n for n, ok in zip(self.joint_names, self.damping_answered, strict=True) if not ok)

    @property
    def no_stop_reply(self) -> tuple[str, ...]:
        """Joints that did not answer the stop frame."""
        return tuple(n for n, ok in zip(self.joint_names, self.stop_answered, strict=True) if not ok)

    @property
    def unconfirmed(self) -> tuple[str, ...]:
        """Joints that missed the damping or the stop frame's reply, canonical order."""
        missed = set(self.no_damping_reply) | set(self.no_stop_reply)
        return tuple(n for n in self.joint_names if n in missed)

    @property
    def confirmed(self) -> bool:
        """True when every joint answered both the damping and the stop frames."""
        return not self.unconfirmed

    def summary(self) -> str:
        """``"stop confirmed"`` when every joint answered, else which joints did not answer which frames."""
        if self.confirmed:
            text = f"stop confirmed (damping and stop frames answered by all {len(self.joint_names)} joints)"
        else:
            parts = []
            if self.no_damping_reply:
                parts.append(f"no reply to the damping frames from {list(self.no_damping_reply)}")
            if self.no_stop_reply:
                parts.append(f"no reply to the stop frames from {list(self.no_stop_reply)}")
            text = f"stop NOT confirmed for {list(self.unconfirmed)}: {'; '.join(parts)}"
        return f"{text}; {self.detail}" if self.detail else text

    def to_dict(self) -> dict[str, Any]:
        """JSON form for the run log."""
        return {
            "confirmed": self.confirmed,
            "unconfirmed_joints": list(self.unconfirmed),
            "no_damping_reply": list(self.no_damping_reply),
            "no_stop_reply": list(self.no_stop_reply),
            "detail": self.detail,
        }


class Target(abc.ABC):
    """Read joint state; write MIT commands for all joints."""

    synchronous: bool = False
    """True when ``advance`` steps a simulated clock (no sleeping needed)."""
    applies_commands: bool = True
    """False when written commands never reach the joints (a dry run): the measured state cannot follow
    them, so the torque a command would demand at that state is no fault of the run (``Runtime`` skips the
    saturation rule and logs it once)."""
    measures_torque: bool = True
    """False when ``read_state``'s torque is not what the motors applied (the mock's echo): the hand-load
    fit (``deploy.hand_load``) needs that torque, and the runtime leaves it off on such a target."""

    def __init__(self, joint_names: tuple[str, ...]) -> None:
        self.joint_names = tuple(joint_names)

    @property
    def num_joints(self) -> int:
        """Number of joints the target drives."""
        return len(self.joint_names)

    def start(self) -> None:  # noqa: B027 - optional hook
        """Connect / enable. Called once before the first read."""

    @abc.abstractmethod
    def read_state(self) -> JointState:
        """The latest joint state."""

    @abc.abstractmethod
    def write_command(self, cmd: MitCommand) -> None:
        """Apply one MIT command (fields shape (num_joints,)) to every joint."""

    def advance(self, dt: float) -> None:  # noqa: B027 - asynchronous targets do nothing
        """Let ``dt`` seconds of target time pass (synchronous targets step physics here)."""

    def now(self) -> float:
        """The target's clock, s."""
        import time

        return time.monotonic()

    def safe_stop(
        self, q: np.ndarray | None = None, kd: float = 1.0, *, hold_s: float | None = None
    ) -> StopReport:
        """Damping, then stop: the safe ending; returns which joints answered (here: all of them).

        ``hold_s``: how long the damping is held before the stop frames, s (None: the target's own
        default). Here one damping command is written (a simulated or mock joint set has no stop frames and
        no wall-clock hold). Real hardware overrides it to hold the damping, send stop frames and report the
        motors that did not reply.
        """
        state_q = self.read_state().q if q is None else q
        self.write_command(MitCommand.damping(state_q, kd))
        return StopReport.all_answered(self.joint_names)

    def use_stop_torque(self, tau_ff: Callable[[np.ndarray], np.ndarray] | None) -> None:  # noqa: B027
        """Feed-forward torque for the damping of the target's own safe stop: ``tau_ff(q)``, N*m (n,).

        The runtime hands its gravity compensation (``deploy.gravity``) to the target here, so a stop the
        target runs by itself (the real target after a driver error) damps the same way. Default: unused.
        """

    def run_metadata(self) -> dict[str, Any]:
        """Target settings worth keeping in the run log (JSON values), read when the run ends.

        The real target can report, for example, the CAN watchdog it armed; the default reports nothing.
        """
        return {}

    def close(self) -> None:  # noqa: B027 - optional hook
        """Release resources (buses, viewers). Must be safe to call twice."""

    def __enter__(self) -> Target:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def run_metadata_of(target: Target) -> dict[str, Any]:
    """``target.run_metadata()``, or ``{"error": ...}`` when it raises (a run log is never lost for it)."""
    try:
        return dict(target.run_metadata())
    except Exception as e:
        return {"error": f"{type(e).__name__}: {e}"}
