"""``sim`` target: C MuJoCo with the same MJCF and the same actuator law as training and the real motors.

Every physics step (2 ms) applies the Robstride firmware model to the latest command through
``data.qfrc_applied``: 16-bit wire quantisation of the five MIT fields, ``tau = Kp (q_cmd - q) +
Kd (dq_cmd - dq) + tau_ff`` at the current q and dq, and the firmware torque cap - i.e.
``firmware_torque(cmd, q, dq, wire_ranges(robot.models), robot.torque_cap)`` - as mujoco_ros2_control's
MujocoSystem does. The command is quantised once when it is written (it is constant until the next write);
the law and the cap are evaluated each step (a test checks the result equals ``firmware_torque`` exactly).

Damping integration (``SimConfig.damping``, as the env's ``ActuatorConfig.damping``): ``explicit``
writes the torque to ``qfrc_applied`` as is; ``implicit`` (the env's default) also sets
``dof_damping = Kd`` on the joints whose torque is below the cap and writes ``tau + Kd dq`` to
``qfrc_applied``: the force at the step's start is still exactly the firmware torque (the passive force
adds ``-Kd dq``), while Euler integrates the damping term implicitly, ``(M + h Kd) dv = h f``, as the MJX
env does.

The scene may hold more than the robot (``scene=``, a task's ``bar_policy.robot.scene.SceneEdit``, the
same one its env uses): the robot's joints are read and written at their addresses (``RobotIndex``), the
scene's other joints move by physics only and start each run at ``qpos0``.

The target is synchronous: ``advance(dt)`` runs ``dt / 0.002`` physics steps and its clock is
``data.time``, so a headless run goes as fast as the CPU allows. Optional: a live viewer
(``mujoco.viewer``, on request only) and headless video through ``mujoco.Renderer`` (needs an OpenGL
context: set ``MUJOCO_GL=egl`` with ``EGL_PLATFORM=surfaceless``, or ``MUJOCO_GL=osmesa``, before mujoco is
imported; ``bar-deploy --video`` does that), written as MP4 when imageio has an ffmpeg backend, else GIF.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from bar_policy.deploy.targets.base import JointState, Target, TargetError
from bar_policy.robot.constants import load_robot
from bar_policy.robot.index import RobotIndex
from bar_policy.robot.mit import MitCommand, mit_torque, quantize, wire_ranges
from bar_policy.robot.scene import PHYSICS_DT, SceneEdit, load_model

__all__ = [
    "SimConfig",
    "SimTarget",
    "VideoRecorder",
    "ffmpeg_available",
    "note_physics_dt",
    "training_damping",
]

log = logging.getLogger(__name__)


@dataclass(frozen=True, kw_only=True)
class SimConfig:
    """Options of the C MuJoCo target."""

    initial_pose: str = "piano_ready"
    """Named pose the joints start in (``RobotSpec.pose``)."""
    quantize_wire: bool = True
    """Apply the 16-bit MIT wire quantisation to commands (as the motors do)."""
    damping: str = "implicit"
    """``implicit`` (the env's default: Kd of unsaturated joints integrated by Euler's implicit damping) or
    ``explicit`` (the whole torque through ``qfrc_applied``)."""
    viewer: bool = False
    """Open a live passive viewer (needs a display)."""
    video_path: str | None = None
    """Write a video of the run here (.mp4, or .gif; .mp4 falls back to .gif without ffmpeg)."""
    video_fps: float = 25.0
    """Video frame rate, frames/s (a frame every ``1 / fps`` s of sim time)."""
    video_size: tuple[int, int] = (240, 320)
    """Video frame (height, width), pixels (at most 480 x 640, the MJCF's offscreen buffer)."""
    camera: str = "front"
    """MJCF camera of the video."""

    def __post_init__(self) -> None:
        if self.damping not in ("implicit", "explicit"):
            raise ValueError(f"SimConfig.damping must be 'implicit' or 'explicit', got {self.damping!r}")
        if not (math.isfinite(self.video_fps) and self.video_fps > 0):
            raise ValueError(f"SimConfig.video_fps must be > 0, got {self.video_fps}")
        h, w = self.video_size
        if not (0 < h <= 480 and 0 < w <= 640):
            raise ValueError(
                f"SimConfig.video_size {self.video_size} must fit the 480 x 640 offscreen buffer"
            )
        if self.video_path is not None and Path(self.video_path).suffix.lower() not in (".mp4", ".gif"):
            raise ValueError(f"video path {self.video_path!r} must end in .mp4 or .gif")


def training_damping(randomization: Mapping[str, Any]) -> str:
    """The damping integration a policy was trained with (``bar.randomization["actuator"]["damping"]``).

    Falls back to ``implicit`` (the env's default) when the record does not say.
    """
    actuator = randomization.get("actuator") if isinstance(randomization, Mapping) else None
    value = actuator.get("damping") if isinstance(actuator, Mapping) else None
    return value if value in ("implicit", "explicit") else "implicit"


def note_physics_dt(physics_dt: float | None) -> None:
    """Log (INFO) that a policy trained at another physics step than the sim target's ``PHYSICS_DT``.

    Information, not a fault: the training presets may step MJX coarser (the gpu preset: 4 ms) and the ship
    gate judges every file on this target's 2 ms. ``physics_dt``: the file's ``bar.physics_dt``, s (None: a
    file that does not say). Only the sim target has a physics step to compare; the real one does not.
    """
    if physics_dt is not None and abs(physics_dt - PHYSICS_DT) > 1e-9:
        log.info("policy was trained with physics dt %g s; the sim target steps %g s", physics_dt, PHYSICS_DT)


def ffmpeg_available() -> bool:
    """True when imageio can write MP4 (the ``imageio-ffmpeg`` backend is installed)."""
    try:
        import imageio_ffmpeg  # noqa: F401
    except ImportError:
        return False
    return True


class VideoRecorder:
    """Offscreen frames of a MuJoCo model streamed to an MP4 (ffmpeg) or GIF file."""

    def __init__(
        self, model: object, path: str | Path, *, fps: float, size: tuple[int, int], camera: str
    ) -> None:
        import mujoco

        path = Path(path)
        if path.suffix.lower() == ".mp4" and not ffmpeg_available():
            new = path.with_suffix(".gif")
            log.warning("no ffmpeg backend for imageio (pip install imageio-ffmpeg): writing %s instead", new)
            path = new
        self.path = path
        self.fps = fps
        self.camera = camera
        try:
            self._renderer = mujoco.Renderer(model, height=size[0], width=size[1])
        except Exception as e:  # mujoco raises FatalError / RuntimeError / OpenGL errors here
            raise TargetError(
                "headless video needs an OpenGL context and none could be created "
                f"({type(e).__name__}: {e}). Set MUJOCO_GL=egl and EGL_PLATFORM=surfaceless (or "
                "MUJOCO_GL=osmesa) before starting, or run without --video."
            ) from None
        self._frames: list[np.ndarray] = []
        self._writer = None
        if path.suffix.lower() == ".mp4":
            import imageio.v2 as iio

            self._writer = iio.get_writer(str(path), fps=fps, macro_block_size=1)
        self.frames_written = 0

    def capture(self, data: object) -> None:
        """Render the current state of ``data`` and append the frame."""
        self._renderer.update_scene(data, camera=self.camera)
        frame = self._renderer.render()
        if self._writer is not None:
            self._writer.append_data(frame)
        else:
            self._frames.append(frame.copy())
        self.frames_written += 1

    def close(self) -> Path:
        """Finish the file; returns its path."""
        if self._writer is not None:
            self._writer.close()
            self._writer = None
        elif self._frames:
            import imageio.v3 as iio3

            iio3.imwrite(self.path, np.stack(self._frames), duration=1000.0 / self.fps, loop=0)
            self._frames = []
        self._renderer.close()
        return self.path


class SimTarget(Target):
    """C MuJoCo simulation of the Lite behind the Target interface (synchronous)."""

    synchronous = True

    def __init__(
        self, mode: str = "arms", config: SimConfig | None = None, *, scene: SceneEdit | None = None
    ) -> None:
        """The robot of ``mode`` in the scene ``scene`` adds to (None: the robot alone)."""
        import mujoco

        self._mj = mujoco
        self.config = config or SimConfig()
        self.robot = load_robot(mode)
        super().__init__(self.robot.joint_names)
        self.model = load_model(mode, scene)
        self.data = mujoco.MjData(self.model)
        if abs(self.model.opt.timestep - PHYSICS_DT) > 1e-12:
            raise TargetError(f"MJCF timestep {self.model.opt.timestep} s, expected {PHYSICS_DT} s")
        self.index = RobotIndex.from_model(self.model, self.joint_names)
        """Addresses of the robot's joints in the scene."""
        qadr, dadr = self.index.qpos, self.index.dof
        n = self.num_joints
        # Slices (views into MjData) when the joints are the first n coordinates in order, as for the robot
        # alone and for scenes whose joints all come after the robot's.
        self._qadr = slice(0, n) if np.array_equal(qadr, np.arange(n)) else qadr
        self._dadr = slice(0, n) if np.array_equal(dadr, np.arange(n)) else dadr
        self._ranges = wire_ranges(self.robot.models)
        self._cap = self.robot.torque_cap
        self._neg_cap = -self._cap
        r = self._ranges
        zero = np.zeros(self.num_joints)
        self._wire_lo = np.stack([-r.p_max, -r.v_max, zero, zero, -r.t_max])
        self._wire_hi = np.stack([r.p_max, r.v_max, r.kp_max, r.kd_max, r.t_max])
        # Cached numpy views of MjData buffers (fixed for the life of ``data``; pybind makes a new wrapper
        # object on every attribute access, which costs microseconds per physics step).
        self._qpos = self.data.qpos
        self._qvel = self.data.qvel
        self._qfrc = self.data.qfrc_applied
        self._dof_damping = self.model.dof_damping
        self._mjcf_damping = self.model.dof_damping[self._dadr].copy()
        self._implicit = self.config.damping == "implicit"
        # Per-step buffers and, when the joints are the first n coordinates (our MJCF), views of MjData.
        n = self.num_joints
        self._views = isinstance(self._qadr, slice) and isinstance(self._dadr, slice)
        if self._views:
            self._q_view = self._qpos[self._qadr]
            self._dq_view = self._qvel[self._dadr]
            self._frc_view = self._qfrc[self._dadr]
            self._damp_view = self._dof_damping[self._dadr]
        self._abs = np.zeros(n)
        self._unsat = np.zeros(n, dtype=bool)
        self._d_law = np.zeros(n)
        self._mjcf_damped = bool(np.any(self._mjcf_damping))
        self._mj_step = mujoco.mj_step
        self._cmd = MitCommand.zero_torque(self.num_joints)
        self._wire_cmd = self._cmd
        self._tau = np.zeros(self.num_joints)
        self._viewer = None
        self._video: VideoRecorder | None = None
        self._next_frame_t = 0.0
        self.video_path: Path | None = None
        """Path of the written video (after ``close``)."""
        self.reset()

    # -- state ---------------------------------------------------------------------------------------
    def reset(self, q: np.ndarray | None = None, dq: np.ndarray | None = None) -> None:
        """Put the joints at ``q`` (default: ``config.initial_pose``), velocity ``dq`` (default 0), t = 0."""
        self._mj.mj_resetData(self.model, self.data)
        q0 = self.robot.pose(self.config.initial_pose) if q is None else np.asarray(q, dtype=np.float64)
        dq0 = np.zeros(self.num_joints) if dq is None else np.asarray(dq, dtype=np.float64)
        if q0.shape != (self.num_joints,) or dq0.shape != (self.num_joints,):
            raise ValueError(f"reset q / dq must have shape ({self.num_joints},)")
        self.data.qpos[self._qadr] = q0
        self.data.qvel[self._dadr] = dq0
        self.data.qfrc_applied[:] = 0.0
        self._mj.mj_forward(self.model, self.data)
        self._cmd = MitCommand.zero_torque(self.num_joints)
        self._wire_cmd = self._cmd
        self._tau = np.zeros(self.num_joints)
        self._next_frame_t = 0.0

    def start(self) -> None:
        """Open the viewer and the video recorder when configured."""
        if self.config.viewer and self._viewer is None:
            import mujoco.viewer

            try:
                self._viewer = mujoco.viewer.launch_passive(self.model, self.data)
            except Exception as e:  # no display, no GLFW
                raise TargetError(f"cannot open the MuJoCo viewer (is there a display?): {e}") from None
        if self.config.video_path and self._video is None:
            c = self.config
            self._video = VideoRecorder(
                self.model, c.video_path, fps=c.video_fps, size=c.video_size, camera=c.camera
            )
            self._next_frame_t = self.data.time

    def read_state(self) -> JointState:
        """q, dq and the torque applied in the last physics step, stamped with sim time."""
        return JointState(
            q=self._qpos[self._qadr].copy(),
            dq=self._qvel[self._dadr].copy(),
            tau=self._tau.copy(),
            stamp=float(self.data.time),
        )

    def now(self) -> float:
        """Simulation time, s."""
        return float(self.data.time)

    # -- commands ------------------------------------------------------------------------------------
    def write_command(self, cmd: MitCommand) -> None:
        """Latch ``cmd`` (each field shape (num_joints,)); it acts from the next physics step on."""
        fields = [np.asarray(f, dtype=np.float64) for f in cmd]
        for name, f in zip(MitCommand._fields, fields, strict=True):
            if f.shape != (self.num_joints,):
                raise TargetError(f"command field {name} has shape {f.shape}, expected ({self.num_joints},)")
        stacked = np.stack(fields)
        if not np.isfinite(stacked).all():
            bad = [n for n, f in zip(MitCommand._fields, fields, strict=True) if not np.isfinite(f).all()]
            raise TargetError(f"command fields {bad} are not finite")
        self._cmd = MitCommand(*fields)
        if self.config.quantize_wire:
            # quantize() on the five fields stacked (5, n): the same elementwise arithmetic as
            # quantize_command, in one call instead of five.
            self._wire_cmd = MitCommand(*quantize(stacked, self._wire_lo, self._wire_hi))
        else:
            self._wire_cmd = self._cmd

    def applied_torque(self) -> np.ndarray:
        """The firmware torque for the latched command at the current state, N*m, shape (num_joints,).

        Equal, bit for bit, to ``firmware_torque(cmd, q, dq, wire_ranges(models), torque_cap)``: the
        command was quantised once in ``write_command``; here the MIT law and the cap are evaluated at the
        current q, dq (``mit_torque`` then the cap as ``min(max(tau, -cap), cap)``, which is what
        ``clip_effort`` computes, without its per-call array-namespace dispatch).
        """
        if self._views:
            q, dq = self._q_view, self._dq_view
        else:
            q, dq = self._qpos[self._qadr], self._qvel[self._dadr]
        tau = mit_torque(self._wire_cmd, q, dq)
        np.maximum(tau, self._neg_cap, out=tau)
        np.minimum(tau, self._cap, out=tau)
        return tau

    def step(self) -> None:
        """One physics step with the MIT law applied through ``qfrc_applied`` (see ``SimConfig.damping``)."""
        tau = self.applied_torque()
        if self._implicit and self._views:
            # d_law = Kd where |tau| < cap else 0; dof_damping = MJCF damping + d_law; qfrc = tau + d_law dq.
            np.abs(tau, out=self._abs)
            np.less(self._abs, self._cap, out=self._unsat)
            np.multiply(self._unsat, self._wire_cmd.kd, out=self._d_law)
            if self._mjcf_damped:
                np.add(self._mjcf_damping, self._d_law, out=self._damp_view)
            else:
                self._damp_view[:] = self._d_law
            np.multiply(self._d_law, self._dq_view, out=self._frc_view)
            self._frc_view += tau
        elif self._implicit:
            d_law = np.where(np.abs(tau) < self._cap, self._wire_cmd.kd, 0.0)
            self._dof_damping[self._dadr] = self._mjcf_damping + d_law
            self._qfrc[self._dadr] = tau + d_law * self._qvel[self._dadr]
        else:
            self._qfrc[self._dadr] = tau
        self._tau = tau
        self._mj_step(self.model, self.data)

    def advance(self, dt: float) -> None:
        """Run ``dt`` seconds of physics (a whole number of 2 ms steps)."""
        n = round(dt / PHYSICS_DT)
        if n < 1 or abs(n * PHYSICS_DT - dt) > 1e-9:
            raise TargetError(f"advance({dt}) is not a whole number of {PHYSICS_DT} s physics steps")
        for _ in range(n):
            self.step()
            if self._video is not None and self.data.time >= self._next_frame_t - 1e-9:
                self._video.capture(self.data)
                self._next_frame_t += 1.0 / self._video.fps
        if self._viewer is not None:
            if not self._viewer.is_running():
                raise TargetError("the viewer window was closed")
            self._viewer.sync()

    def close(self) -> None:
        """Close the viewer and finish the video (safe to call twice)."""
        if self._viewer is not None:
            self._viewer.close()
            self._viewer = None
        if self._video is not None:
            self.video_path = self._video.close()
            self._video = None
            log.info("video written to %s", self.video_path)
