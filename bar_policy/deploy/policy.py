"""Load an ONNX policy and check its contract against the robot data and the running code.

``load_policy(path)`` opens the file with onnxruntime (never pickle, never the ``onnx`` package: the robot
computer only has onnxruntime), reads ``custom_metadata_map`` into a ``PolicyMetadata`` (either dialect, see
``deploy.metadata``) and refuses to run, with a ``PolicyLoadError`` naming the mismatch, when any of these
differ:

- ``bar`` files: the observation schema: the embedded JSON must hash to the embedded fingerprint, and equal
  the layout that this code builds for the task and mode (``ObservationManager.for_task``);
- HC-only files: every term of ``observation_names`` and ``command_names`` must be one the runtime can feed
  (``hc_policy.supported_terms()``: the reach command terms and the state / action terms the runtime
  computes); the schema is built from those names (HC's built-in meaning: ``joint_pos = (q - default) * 1``,
  ``joint_vel`` raw, ``actions`` = the previous action, every scale 1, no clip), whatever the ``task_type``;
- the joint set (``arms`` / ``arms_neck``) and the canonical joint order (``load_robot(mode)``; an HC-only
  file's joint set is the mode whose joints its ``joint_names`` lists, in canonical order);
- the action joints, default pose and command names (against the schema);
- the policy period against the runtime's control period (0.02 s unless overridden);
- the gains Kp / Kd: ``bar`` files against the robot data; HC-only files within each motor's MIT wire range
  (the file's gains are used);
- the graph's I/O: one float32 input ``obs`` of shape ``[batch, obs_size]`` and a float32 output
  ``actions`` of shape ``[batch, n_action_joints]``;
- the network's action on the default observation (``default_observation``: at rest in the default pose,
  upright, zero commands) must be finite (``check_default_output``): a network that answers NaN there is
  refused at load, not on its first POLICY tick.

The accepted policy is an ``OnnxPolicy``: ``policy(obs)`` runs one inference and ``policy.q_command(action)``
turns an action into the unclipped joint target ``default + action_scale * action`` for the joints the
policy drives; joints it does not drive are pinned at 0 rad with the file's Kp / Kd, as Humanoid Control
holds them (lite-model.md 2.1). ``policy.hold_pose`` (that target at action 0) is where the HOLD ramp goes
unless the task's command source names another pose (a motion clip's first frame). ``policy.task`` is the
deploy task (``deploy.tasks``) that builds its command source and evaluation.

The file itself (bytes, session, metadata, graph I/O) is ``deploy.onnx_file``; the HC-only dialect is
``deploy.hc_policy``; the refusal messages are ``deploy.contract``.

Action clip: the LiteReach env clips every action to [-1, 1] before ``q_cmd`` and feeds the clipped action
back as the ``actions`` observation term. ``OnnxPolicy.action_clip`` carries that bound: the optional
metadata key ``bar.action_clip`` (a JSON number, or null for none) when the file has it, else
``DEFAULT_ACTION_CLIP`` (1.0); an HC-only file gets no action clip (Humanoid Control applies none). The
runtime applies it and counts every clipped entry.
"""

from __future__ import annotations

import dataclasses
import logging
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from bar_policy._files import shorten
from bar_policy.deploy.contract import PolicyLoadError, diff_joints, diff_values, refuse
from bar_policy.deploy.hc_policy import HC_TERM_CLIP, check_hc_gains, complete_hc, supported_terms
from bar_policy.deploy.inputs import RUNTIME_INPUTS
from bar_policy.deploy.metadata import PolicyMetadata
from bar_policy.deploy.onnx_file import (
    ACTION_CLIP_KEY,
    DEFAULT_ACTION_CLIP,
    action_clip,
    check_io,
    metadata,
    read_bytes,
    session,
)
from bar_policy.deploy.safety import DEFAULT_REACH_MARGIN, check_action_scale
from bar_policy.obs.manager import ObservationManager, ObservationSchema
from bar_policy.obs.robot_layout import ERROR_EMA_TERM, with_error_ema
from bar_policy.robot.constants import MODES, RobotSpec, load_robot
from bar_policy.robot.gains import profile_gains

__all__ = [
    "ACTION_CLIP_KEY",
    "DEFAULT_ACTION_CLIP",
    "DEFAULT_CONTROL_DT",
    "HC_TERM_CLIP",
    "RUNTIME_INPUTS",
    "OnnxPolicy",
    "PolicyLoadError",
    "action_reach_problems",
    "check_default_output",
    "default_observation",
    "deploy_task",
    "load_policy",
    "read_metadata",
    "supported_terms",
]

log = logging.getLogger(__name__)

DEFAULT_CONTROL_DT = 0.02
"""Control (policy) period the runtime expects, s (50 Hz)."""

_DT_TOL = 1e-9
"""Tolerance on the policy period, s."""


def read_metadata(path: str | Path) -> PolicyMetadata:
    """Read and parse a policy file's metadata without checking it against the robot.

    Raises:
        PolicyLoadError: unreadable file, not ONNX, or missing / malformed metadata keys.
    """
    path = Path(path)
    meta = metadata(path, session(path, read_bytes(path), threads=1))
    return complete_hc(path, meta) if meta.dialect == "hc" else meta


def deploy_task(meta: PolicyMetadata) -> str:
    """The deploy task of a (completed) policy's metadata: ``bar.task``, or an HC-only file's implied one."""
    if meta.dialect == "bar":
        return meta.task
    from bar_policy.deploy.task_registry import implied_task

    return implied_task([t.name for t in ObservationSchema.from_json(meta.obs_schema).terms])


@dataclass(frozen=True)
class OnnxPolicy:
    """An ONNX policy whose contract matched the robot and the running code.

    Attributes are arrays over the canonical joints (shape ``(num_joints,)``) unless noted.
    """

    path: Path
    """The file it was loaded from."""
    metadata: PolicyMetadata
    """The parsed metadata."""
    robot: RobotSpec
    """Robot joint set the policy runs on."""
    obs_manager: ObservationManager
    """The running code's observation layout (equal to the file's)."""
    session: object
    """The onnxruntime InferenceSession."""
    action_index: np.ndarray
    """Canonical index of each action joint, shape ``(n_actions,)``, int."""
    default_joint_pos: np.ndarray
    """Default pose, rad."""
    action_scale: np.ndarray
    """rad per unit action, shape ``(n_actions,)``."""
    kp: np.ndarray
    """Kp, N*m/rad (from the metadata; equal to the robot data)."""
    kd: np.ndarray
    """Kd, N*m*s/rad."""
    action_clip: float | None = DEFAULT_ACTION_CLIP
    """Raw actions are clipped to +-this before use (None: not clipped)."""
    task: str = "reach"
    """Deploy task (``deploy.tasks``): ``bar.task``, or what an HC-only file's terms imply."""

    @property
    def n_actions(self) -> int:
        """Number of action joints."""
        return len(self.action_index)

    @property
    def policy_dt(self) -> float:
        """Policy period, s."""
        return self.metadata.policy_dt

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        """One inference.

        Args:
            obs: observation, shape ``(obs_size,)`` (any float dtype; cast to float32).

        Returns:
            Raw action, float32, shape ``(n_actions,)``.
        """
        x = np.asarray(obs, dtype=np.float32).reshape(1, -1)
        return self.session.run(["actions"], {"obs": x})[0][0]  # type: ignore[attr-defined]

    @property
    def hold_pose(self) -> np.ndarray:
        """``q_command`` at action 0: default pose on driven joints, 0 on the others, rad (HOLD target)."""
        return self.q_command(np.zeros(self.n_actions))

    def q_command(self, action: np.ndarray) -> np.ndarray:
        """Joint targets ``default + action_scale * action`` (action semantics ``delta_from_default``).

        Joints the policy does not drive are pinned at 0 rad (with the file's Kp / Kd), as Humanoid Control
        holds them. Not clipped: the safety layer clips to the joint limits and counts it.

        Args:
            action: raw action, shape ``(n_actions,)``.

        Returns:
            q_cmd, rad, float64, shape ``(num_joints,)``.
        """
        q = np.zeros_like(self.default_joint_pos)
        idx = self.action_index
        q[idx] = self.default_joint_pos[idx] + self.action_scale * np.asarray(action, dtype=np.float64)
        return q


def load_policy(
    path: str | Path,
    *,
    control_dt: float = DEFAULT_CONTROL_DT,
    mode: str | None = None,
    task: str | None = None,
    threads: int = 1,
) -> OnnxPolicy:
    """Load an ONNX policy after checking its whole contract.

    Args:
        path: the ``.onnx`` file.
        control_dt: the runtime's control period, s; the file's ``policy_dt`` must equal it.
        mode: joint set the robot runs (``arms`` / ``arms_neck``); None accepts the file's mode.
        task: task the runtime runs; None accepts the file's task.
        threads: onnxruntime intra-op threads (1 is fastest for small MLPs).

    Raises:
        PolicyLoadError: with a message naming the mismatch (see the module docstring for the list).
    """
    path = Path(path)
    sess = session(path, read_bytes(path), threads)
    meta = metadata(path, sess)
    if meta.dialect == "hc":
        meta = complete_hc(path, meta)

    # Joint set and task.
    if meta.mode not in MODES:
        raise refuse(path, f"unknown joint set (mode) {shorten(repr(meta.mode))}; valid: {list(MODES)}")
    if mode is not None and meta.mode != mode:
        theirs, ours = load_robot(meta.mode), load_robot(mode)
        extra = [n for n in theirs.joint_names if n not in ours.joint_names]
        missing = [n for n in ours.joint_names if n not in theirs.joint_names]
        parts = [f"it adds {extra}"] if extra else []
        parts += [f"it lacks {missing}"] if missing else []
        listed = ""
        if len(meta.joint_names) != theirs.num_joints:
            listed = (
                f"; its joint_names list {len(meta.joint_names)} joints, not {theirs.num_joints}: the file "
                "is inconsistent, re-export it"
            )
        raise refuse(
            path,
            f"joint set mismatch: the policy drives mode {meta.mode!r} ({theirs.num_joints} joints), this "
            f"run drives mode {mode!r} ({ours.num_joints} joints; {', '.join(parts)}); give --mode "
            f"{meta.mode} to run it on that joint set, or a policy trained for {mode!r}{listed}",
        )
    if task is not None and deploy_task(meta) != task:
        raise refuse(
            path, f"task mismatch: the policy is for task {deploy_task(meta)!r}, the runtime runs {task!r}"
        )
    robot = load_robot(meta.mode)
    if meta.robot != robot.robot:
        raise refuse(
            path,
            f"robot mismatch: the policy is for {shorten(repr(meta.robot))}, this code drives "
            f"{robot.robot!r}",
        )
    msg = diff_joints("joint names", meta.joint_names, robot.joint_names)
    if msg:
        raise refuse(path, msg)

    # Observation schema: self-consistent, and equal to the running code's layout.
    try:
        schema = ObservationSchema.from_json(meta.obs_schema)
    except (ValueError, TypeError, KeyError, AttributeError, IndexError) as e:  # any malformed schema
        raise refuse(path, f"embedded observation schema is invalid: {shorten(e, 500)}") from None
    if schema.fingerprint != meta.obs_fingerprint:
        raise refuse(
            path,
            f"observation fingerprint {meta.obs_fingerprint} does not match the embedded schema "
            f"(which hashes to {schema.fingerprint}); the file was edited or corrupted",
        )
    if meta.dialect == "hc":
        om = ObservationManager(schema)  # built from the file's HC keys: no code layout to compare with
    else:
        try:
            om = ObservationManager.for_task(meta.task, meta.mode)
        except ValueError as e:  # an unknown task: its name is echoed, cut
            raise refuse(path, shorten(str(e), 500)) from None
        if ERROR_EMA_TERM in {t.name for t in schema.terms}:  # the task's opt-in next version
            om = ObservationManager(with_error_ema(om.schema))
    if schema.fingerprint != om.fingerprint or schema != om.schema:
        theirs, ours = schema.to_dict(), om.schema.to_dict()
        keys = sorted(k for k in set(theirs) | set(ours) if theirs.get(k) != ours.get(k))
        raise refuse(
            path,
            f"observation schema fingerprint {schema.fingerprint} ({schema.name} v{schema.version}) differs "
            f"from the running code's {om.fingerprint} ({om.schema.name} v{om.schema.version}); "
            f"differing fields: {keys}",
        )

    # Action joints, default pose and commands (against the schema).
    if meta.action_joint_names != schema.action_joint_names:
        raise refuse(
            path,
            f"action joints {list(meta.action_joint_names)} differ from the schema's "
            f"{list(schema.action_joint_names)}",
        )
    default = np.asarray(meta.default_joint_pos)
    msg = diff_values(
        "default joint positions", "rad", robot.joint_names, default, np.asarray(schema.default_joint_pos)
    )
    if msg:
        raise refuse(path, msg)
    if meta.command_names != om.command_names:
        raise refuse(
            path,
            f"command names {list(meta.command_names)} differ from the layout's {list(om.command_names)}",
        )

    # Timing.
    if not math.isclose(meta.policy_dt, control_dt, rel_tol=0.0, abs_tol=_DT_TOL):
        raise refuse(
            path,
            f"policy dt {meta.policy_dt} s differs from the runtime's control dt {control_dt} s "
            f"({1 / meta.policy_dt:g} Hz vs {1 / control_dt:g} Hz)",
        )

    # Gains: a bar file's must be the robot data's for its profile (bar.gains); an HC-only file's are used
    # as they are (in range).
    kp, kd = np.asarray(meta.joint_stiffness), np.asarray(meta.joint_damping)
    if meta.dialect == "hc":
        check_hc_gains(path, meta, robot)
    else:
        want_kp, want_kd = profile_gains(robot, meta.gains)
        of = "" if meta.gains == "robot" else f" (gain profile {meta.gains!r}, bar.gains)"
        for label, unit, got, want in (("Kp", "N*m/rad", kp, want_kp), ("Kd", "N*m*s/rad", kd, want_kd)):
            msg = diff_values(label + of, unit, robot.joint_names, got, want)
            if msg:
                raise refuse(path, msg)
    undriven = [n for n in robot.joint_names if n not in meta.action_joint_names]
    if undriven:
        log.info("joints the policy does not drive, pinned at 0 rad with the file's Kp/Kd: %s", undriven)

    # Graph I/O, then one dry inference to be sure the shapes hold at run time.
    check_io(path, sess, om.size, len(meta.action_joint_names))

    policy = OnnxPolicy(
        path=path,
        metadata=meta,
        robot=robot,
        obs_manager=om,
        session=sess,
        action_index=np.array([robot.index(n) for n in meta.action_joint_names], dtype=np.int64),
        default_joint_pos=default.astype(np.float64),
        action_scale=np.asarray(meta.action_scale, dtype=np.float64),
        kp=kp.astype(np.float64),
        kd=kd.astype(np.float64),
        # HC-only files: no clip, as Humanoid Control runs them (q_cmd is still clipped to the limits).
        action_clip=action_clip(path, sess) if meta.dialect == "bar" else None,
        task=deploy_task(meta),
    )
    check_default_output(policy)
    # Action scale against the joint ranges (the runtime checks again with its configured margin).
    problems = action_reach_problems(policy)
    if problems and policy.action_clip is not None and policy.action_clip > 1.0:
        at_one = dataclasses.replace(policy, action_clip=1.0)
        if not action_reach_problems(at_one):  # the scale is fine over +-1: the clip's bound is what reaches
            raise refuse(
                path,
                f"metadata key {ACTION_CLIP_KEY!r} = {policy.action_clip:.4g} lets the actions reach beyond "
                f"the joint ranges ({len(problems)} of {policy.n_actions} joints; the action_scale is fine "
                f"over +-1): {shorten(problems[0], 300)}. Export the clip the policy was trained with (the "
                "LiteReach env clips to +-1)",
            )
    if problems:
        raise refuse(path, shorten(f"action_scale beyond the joint ranges: {'; '.join(problems)}", 1000))
    return policy


def default_observation(om: ObservationManager) -> np.ndarray:
    """The observation of the robot at rest in its default pose: what the policy sees as POLICY begins.

    Every term's input is zero except ``joint_pos`` (the default pose, so 0 after its offset),
    ``projected_gravity`` (0, 0, -1: upright) and ``imu_quaternion`` (1, 0, 0, 0: identity). Shape
    ``(om.size,)``, float32.
    """
    upright = {"projected_gravity": (0.0, 0.0, -1.0), "imu_quaternion": (1.0, 0.0, 0.0, 0.0)}
    inputs = {}
    for t in om.schema.terms:
        x = np.zeros(t.size, np.float32)
        if t.name == "joint_pos":
            x = np.asarray(om.schema.default_joint_pos, np.float32)
        elif t.name in upright and t.size == len(upright[t.name]):
            x = np.asarray(upright[t.name], np.float32)
        inputs[t.name] = x
    return np.asarray(om.compute(inputs), np.float32)


def check_default_output(policy: OnnxPolicy) -> None:
    """Refuse (``PolicyLoadError``) a policy whose action on ``default_observation`` is not finite.

    Such a network (NaN weights, a broken normalisation) would fault on its first POLICY tick; at load the
    user learns it before anything moves. The message names the action joints and their values.
    """
    action = np.asarray(policy(default_observation(policy.obs_manager)), np.float64)
    bad = np.flatnonzero(~np.isfinite(action))
    if bad.size:
        names = [policy.metadata.action_joint_names[i] for i in bad]
        values = ", ".join(f"{n} {action[i]}" for n, i in zip(names, bad, strict=True))
        raise refuse(
            policy.path,
            shorten(
                f"the network's action on the default observation (robot at rest in the default pose, "
                f"upright, zero commands) is not finite for {len(bad)} of {action.size} joints ({values}); "
                "the weights or the input normalisation are broken: re-export the policy",
                1000,
            ),
        )


def action_reach_problems(policy: OnnxPolicy, margin: float = DEFAULT_REACH_MARGIN) -> list[str]:
    """``safety.check_action_scale`` of a loaded policy: one problem per joint reaching too far (empty: none).

    ``default +- action_scale x bound`` (bound = the action clip, else 1 action unit) against each action
    joint's range widened by ``margin`` rad.
    """
    robot, idx = policy.robot, policy.action_index
    return check_action_scale(
        np.asarray(policy.default_joint_pos, dtype=np.float64)[idx],
        policy.action_scale,
        robot.lower[idx],
        robot.upper[idx],
        [robot.joint_names[i] for i in idx],
        bound=1.0 if policy.action_clip is None else float(policy.action_clip),
        margin=margin,
    )
