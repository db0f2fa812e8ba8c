"""Refusing a policy file: the error type and the messages that compare a file's values with the robot's.

Every check of ``deploy.policy`` (and of the HC-only dialect, ``deploy.hc_policy``) ends in a
``PolicyLoadError`` whose message starts with ``refusing policy '<path>':`` and names the mismatch.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from bar_policy._files import InputError

__all__ = ["GAIN_RTOL", "PolicyLoadError", "diff_joints", "diff_values", "refuse"]

GAIN_RTOL = 1e-6
"""Relative tolerance on Kp / Kd and on the default pose (JSON round-trips floats exactly; this is slack)."""


class PolicyLoadError(InputError):
    """A policy file cannot be run: unreadable, not ONNX, or its contract does not match this robot/code."""


def refuse(path: Path, msg: str) -> PolicyLoadError:
    """The error for ``path`` with ``msg`` (to raise)."""
    return PolicyLoadError(f"refusing policy {str(path)!r}: {msg}")


def diff_joints(label: str, got: tuple[str, ...], want: tuple[str, ...]) -> str | None:
    """A message describing how ``got`` differs from ``want`` (set first, then order), or None."""
    if got == want:
        return None
    extra = [n for n in got if n not in want]
    missing = [n for n in want if n not in got]
    if extra or missing or len(got) != len(want):
        return (
            f"{label} differ from the robot's: policy has {len(got)} joints, robot {len(want)}; "
            f"not on the robot: {extra}; missing from the policy: {missing}"
        )
    first = next(i for i, (a, b) in enumerate(zip(got, want, strict=True)) if a != b)
    return (
        f"{label} order differs from the canonical order at index {first}: policy {got[first]!r}, "
        f"robot {want[first]!r} (policy order {list(got)})"
    )


def diff_values(
    label: str, unit: str, names: tuple[str, ...], got: np.ndarray, want: np.ndarray
) -> str | None:
    """A message listing the entries of ``got`` that differ from ``want`` (``GAIN_RTOL``), or None."""
    bad = ~np.isclose(got, want, rtol=GAIN_RTOL, atol=1e-9)
    if not bad.any():
        return None
    items = ", ".join(f"{names[i]}: policy {got[i]:g}, robot {want[i]:g}" for i in np.flatnonzero(bad))
    return f"{label} ({unit}) differ from the robot data: {items}"
