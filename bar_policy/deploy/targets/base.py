"""The one interface that the sim, mock and real targets implement.

A target owns the joints: it reads their state and applies MIT commands for all of them, in canonical
joint order. The runtime never knows which target it drives.

Timing: a *synchronous* target (the headless sim) advances its own clock when the runtime calls
``advance(dt)``, so it can run faster than real time; an asynchronous target (mock at a fixed rate, the real
bus) lives in wall-clock time and ``advance`` only returns; the runtime's deadline scheduler keeps the rate.
"""

from __future__ import annotations

import abc
from dataclasses import dataclass
from typing import Any

import numpy as np

from bar_policy.robot.mit import MitCommand

__all__ = ["JointState", "Target", "TargetError", "run_metadata_of"]


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


class Target(abc.ABC):
    """Read joint state; write MIT commands for all joints."""

    synchronous: bool = False
    """True when ``advance`` steps a simulated clock (no sleeping needed)."""

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

    def safe_stop(self, q: np.ndarray | None = None, kd: float = 1.0) -> None:
        """Damping, then stop: the safe ending. Real hardware overrides it to also send stop frames."""
        state_q = self.read_state().q if q is None else q
        self.write_command(MitCommand.damping(state_q, kd))

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
