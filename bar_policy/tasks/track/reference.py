"""The track task's command source: ``--motion NAME|PATH`` streams a clip's reference with lookahead.

The reference is built exactly as the MJX env builds it (``env.py``), from the same code:
``shared.ReferenceTable.build`` (the clip resampled to the control rate, tracked-body poses and 6-D
orientations by C MuJoCo forward kinematics of the same MJCF), then each tick
``reference_inputs(table, lookahead_frames(frame, last, K))``: the next K = ``lookahead_steps`` frames,
frames past the clip's end repeating its last (the past-the-end hold).

Schedule (``MotionReference``; the runtime follows it through the ``CommandSource`` hooks):

- the start-up HOLD ramps to the clip's first frame (``hold_pose``), not to the policy's default pose;
- POLICY starts the clip at phase 0 (``begin``): at run time t the phase is
  ``j = round((t - t_policy) / control_dt)`` and the current frame ``f = min(j, last)``; the observation
  holds frames ``f + 1 .. f + K`` (the targets of the next K ticks), as the env's does after j steps from
  frame 0. The phase follows the target clock, so a tick that overran skips frames instead of lagging;
- at phase ``last`` (plus ``tail_s``) the clip is over (``finished``): the runtime enters HOLD at the
  last frame (``end_pose``) with the policy's gains, holds it ``RuntimeConfig.end_hold`` s and ends the run
  as completed through the normal safe ending.

``--motion`` takes a library name (a gesture such as ``wave``, or a clip set member
``random-s<seed>-<index>``; ``motion.library_clip``) or a clip file (``.npz`` by ``motion.load_clip``,
``.csv`` by ``motion.load_csv``; ``--motion-rate HZ`` for a CSV without a ``time`` column) with all the
loader's refusals (joint limits, speed, joint set, hash). The run log records the reference each tick
(``ref_q``, ``ref_frame``), which ``bar-deploy plot`` overlays.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from bar_policy.motion.clip import Clip, ClipError, load_clip, load_csv
from bar_policy.motion.library import library_clip
from bar_policy.tasks.interfaces import CommandSource, OptionError
from bar_policy.tasks.track.shared import COMMAND_TERMS, ReferenceTable, lookahead_frames, reference_inputs

if TYPE_CHECKING:
    from bar_policy.robot.kinematics import Kinematics
    from bar_policy.tasks.episodes import Policy

__all__ = ["MotionReference", "load_motion", "reference_for"]

_CLIP_SUFFIXES = (".npz", ".csv")


def load_motion(spec: str, mode: str = "arms", rate_hz: float | None = None) -> Clip:
    """The clip ``--motion spec`` names: a clip file (``.npz`` / ``.csv``) or a library clip name.

    Args:
        spec: a path ending in ``.npz`` or ``.csv``, or a library name (``wave``, ``random-s1-003``).
        mode: the policy's joint set (the clip must hold exactly its joints).
        rate_hz: frame rate of a CSV clip without a ``time`` column, Hz.

    Raises:
        ClipError: a file the clip loader refuses (limits, speed, joint set, hash), or a missing file.
        ValueError: an unknown library name (the message lists the gestures and the member pattern).
    """
    path = Path(spec)
    if path.suffix.lower() in _CLIP_SUFFIXES:
        if not path.is_file():
            raise ClipError(f"no clip file {spec!r}")
        if path.suffix.lower() == ".csv":
            return load_csv(path, mode, rate_hz=rate_hz)
        if rate_hz is not None:
            raise ClipError(f"{spec}: an NPZ clip states its rate; --motion-rate is for CSV clips only")
        return load_clip(path, mode)
    if rate_hz is not None:
        raise ClipError(f"--motion-rate is for CSV clip files; {spec!r} is a library clip at 50 Hz")
    return library_clip(spec, mode=mode)


class MotionReference(CommandSource):
    """A clip's reference with lookahead, one tick at a time (see the module docstring)."""

    task = "track"
    # the payload rows of the robustness suite pass with it (docs/robustness.md, "Hand-load compensation")
    hand_load = "estimate"

    def __init__(
        self,
        clip: Clip,
        names: tuple[str, ...],
        *,
        body_names: tuple[str, ...],
        lookahead_steps: int,
        control_dt: float,
        tail_s: float = 0.0,
        kinematics: Kinematics | None = None,
    ) -> None:
        """Build the reference table of ``clip`` (C MuJoCo kinematics; a 30 s clip takes ~0.1 s).

        Args:
            clip: the motion (any rate; resampled to the control rate as in training).
            names: the command terms of the policy's layout (a subset of the three ``motion_*`` terms).
            body_names: the layout's tracked bodies.
            lookahead_steps: the layout's K.
            control_dt: control period, s.
            tail_s: after the last frame, keep the policy on the held last frame this long before
                ``finished`` (0: hand over to HOLD as soon as the clip is over), s.
            kinematics: C MuJoCo kinematics of the clip's mode (built when None).
        """
        unknown = [n for n in names if n not in COMMAND_TERMS]
        if unknown:
            raise ValueError(f"a motion reference cannot feed {unknown}; it feeds {COMMAND_TERMS}")
        if lookahead_steps < 1:
            raise ValueError(f"lookahead_steps must be >= 1, got {lookahead_steps}")
        if not tail_s >= 0:
            raise ValueError(f"tail_s must be >= 0 s, got {tail_s}")
        self.clip = clip
        self.names = tuple(names)
        self.lookahead_steps = int(lookahead_steps)
        self.control_dt = float(control_dt)
        self.table = ReferenceTable.build([clip], body_names, rate_hz=1.0 / control_dt, kinematics=kinematics)
        """The clip's frames at the control rate with their kinematics (``tasks.track.shared``)."""
        self.last = self.table.num_frames - 1
        """Index of the clip's last frame."""
        self.tail_ticks = round(tail_s / control_dt)
        self._t0: float | None = None
        self._frame = 0

    # -- phase ---------------------------------------------------------------------------------------
    def phase(self, t: float) -> int:
        """Ticks since POLICY began at run time ``t`` (0 before it began)."""
        if self._t0 is None:
            return 0
        return max(math.floor((t - self._t0) / self.control_dt + 0.5), 0)

    def __call__(self, t: float) -> dict[str, np.ndarray]:
        """The lookahead terms at run time ``t``: frames ``min(f + k, last)``, k = 1..K (f: current frame)."""
        f = min(self.phase(t), self.last)
        self._frame = f
        idx = lookahead_frames(np.int64(f), np.int64(self.last), self.lookahead_steps)
        tb = self.table
        values = reference_inputs(tb.joint_pos, tb.body_pos, tb.body_ori, idx)
        return {n: values[n] for n in self.names}

    # -- schedule ------------------------------------------------------------------------------------
    @property
    def hold_pose(self) -> np.ndarray:
        """The clip's first frame, rad (the start-up HOLD ramps there)."""
        return self.table.joint_pos[0].astype(np.float64)

    @property
    def end_pose(self) -> np.ndarray:
        """The clip's last frame, rad (HOLD holds it once the clip is over)."""
        return self.table.joint_pos[self.last].astype(np.float64)

    def begin(self, t: float) -> None:
        """Phase 0 at run time ``t`` (the first POLICY tick)."""
        self._t0 = t

    def target_q(self) -> np.ndarray:
        """The frame the current tick's command targets, ``min(f + 1, last)`` (the env's), rad."""
        return self.table.joint_pos[min(self._frame + 1, self.last)].astype(np.float64)

    def finished(self, t: float) -> str | None:
        """The completion reason once the phase reaches the last frame (+ ``tail_s``), else None."""
        if self._t0 is None or self.phase(t) < self.last + self.tail_ticks:
            return None
        return (
            f"motion {self.clip.name!r} complete ({self.table.num_frames} frames, "
            f"{self.last * self.control_dt:.2f} s)"
        )

    # -- logging -------------------------------------------------------------------------------------
    @property
    def log_fields(self) -> dict[str, tuple[tuple[int, ...], type]]:
        """``ref_q`` (n,) rad and ``ref_frame`` () int32: where the robot should be at the tick."""
        return {"ref_q": ((self.table.joint_pos.shape[1],), np.float64), "ref_frame": ((), np.int32)}

    def record(self) -> dict[str, Any]:
        """The current frame of the last call and its joint positions."""
        return {"ref_q": self.table.joint_pos[self._frame], "ref_frame": self._frame}

    def metadata(self) -> dict[str, Any]:
        """The clip (name, hash, rate, frames) and the lookahead, for the run log."""
        return {
            "task": self.task,
            "describe": self.describe(),
            "clip": self.clip.name,
            "clip_content_hash": self.clip.content_hash,
            "clip_rate_hz": self.clip.rate_hz,
            "frames": self.table.num_frames,
            "control_rate_hz": 1.0 / self.control_dt,
            "lookahead_steps": self.lookahead_steps,
            "body_names": list(self.table.body_names),
            "tail_s": self.tail_ticks * self.control_dt,
        }

    def describe(self) -> str:
        """One line for logs."""
        return (
            f"motion({self.clip.name}, {self.table.num_frames} frames at {1 / self.control_dt:g} Hz, "
            f"{self.last * self.control_dt:.2f} s, lookahead {self.lookahead_steps})"
        )


def reference_for(
    policy: Policy, clip: Clip, *, tail_s: float = 0.0, kinematics: Kinematics | None = None
) -> MotionReference:
    """The ``MotionReference`` of ``clip`` for a tracking policy's layout (bodies, K, command terms).

    Raises:
        OptionError: the layout's tracked bodies or lookahead differ from the file's HC keys, or the clip's
            joint set is not the policy's.
    """
    schema = policy.obs_manager.schema
    meta = policy.metadata
    if tuple(meta.body_names) != tuple(schema.body_names) or meta.lookahead_steps != schema.lookahead_steps:
        raise OptionError(
            f"policy {policy.path}: HC keys body_names {list(meta.body_names)} / lookahead_steps "
            f"{meta.lookahead_steps} differ from its observation layout's {list(schema.body_names)} / "
            f"{schema.lookahead_steps}"
        )
    if clip.joint_names != policy.robot.joint_names:
        raise OptionError(
            f"clip {clip.name!r} is not for the policy's joint set (mode {policy.robot.mode!r})"
        )
    return MotionReference(
        clip,
        policy.obs_manager.command_names,
        body_names=schema.body_names,
        lookahead_steps=schema.lookahead_steps,
        control_dt=policy.policy_dt,
        tail_s=tail_s,
        kinematics=kinematics,
    )
