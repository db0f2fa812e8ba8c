"""Load an ONNX policy and check its contract against the robot data and the running code.

``load_policy(path)`` opens the file with onnxruntime (never pickle, never the ``onnx`` package: the robot
computer only has onnxruntime), reads ``custom_metadata_map`` into a ``PolicyMetadata`` and refuses to run,
with a ``PolicyLoadError`` naming the mismatch, when any of these differ:

- the observation schema: the embedded JSON must hash to the embedded fingerprint, and equal the layout that
  this code builds for the task and mode (``ObservationManager.for_task``);
- the joint set (``arms`` / ``arms_neck``) and the canonical joint order (``load_robot(mode)``);
- the action joints, default pose and command names (against the schema);
- the policy period against the runtime's control period (0.02 s unless overridden);
- the gains Kp / Kd against the robot data;
- the graph's I/O: one float32 input ``obs`` of shape ``[batch, obs_size]`` and a float32 output
  ``actions`` of shape ``[batch, n_action_joints]``.

The accepted policy is an ``OnnxPolicy``: ``policy(obs)`` runs one inference and ``policy.q_command(action)``
turns an action into the unclipped joint target ``default + action_scale * action``.

Action clip: the LiteReach env clips every action to [-1, 1] before ``q_cmd`` and feeds the clipped action
back as the ``actions`` observation term. ``OnnxPolicy.action_clip`` carries that bound: the optional
metadata key ``bar.action_clip`` (a JSON number, or null for none) when the file has it, else
``DEFAULT_ACTION_CLIP`` (1.0). The runtime applies it and counts every clipped entry.
"""

from __future__ import annotations

import json
import logging
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from bar_policy.deploy.metadata import MetadataError, PolicyMetadata
from bar_policy.obs.manager import ObservationManager, ObservationSchema
from bar_policy.robot.constants import MODES, RobotSpec, load_robot
from bar_policy.robot.mjcf import PHYSICS_DT

__all__ = [
    "ACTION_CLIP_KEY",
    "DEFAULT_ACTION_CLIP",
    "DEFAULT_CONTROL_DT",
    "OnnxPolicy",
    "PolicyLoadError",
    "load_policy",
    "read_metadata",
]

log = logging.getLogger(__name__)

DEFAULT_CONTROL_DT = 0.02
"""Control (policy) period the runtime expects, s (50 Hz)."""

ACTION_CLIP_KEY = "bar.action_clip"
"""Optional metadata key: symmetric bound applied to raw actions (JSON number > 0, or null for none)."""
DEFAULT_ACTION_CLIP = 1.0
"""Action bound when the file has no ``bar.action_clip`` (the LiteReach contract: actions in [-1, 1])."""

_DT_TOL = 1e-9
"""Tolerance on the policy period, s."""
_GAIN_RTOL = 1e-6
"""Relative tolerance on Kp / Kd and on the default pose (JSON round-trips floats exactly; this is slack)."""
_PICKLE_SUFFIXES = (".pt", ".pth", ".pkl", ".pickle", ".ckpt", ".joblib")


class PolicyLoadError(ValueError):
    """A policy file cannot be run: unreadable, not ONNX, or its contract does not match this robot/code."""


def _refuse(path: Path, msg: str) -> PolicyLoadError:
    return PolicyLoadError(f"refusing policy {str(path)!r}: {msg}")


def _read_bytes(path: Path) -> bytes:
    """The file's bytes, after refusing pickles by suffix and by magic number."""
    if path.suffix.lower() in _PICKLE_SUFFIXES:
        raise _refuse(path, f"{path.suffix} files are pickles; only ONNX files are loaded (export to .onnx)")
    try:
        data = path.read_bytes()
    except OSError as e:
        raise _refuse(path, f"cannot read the file: {e.strerror or e}") from None
    if not data:
        raise _refuse(path, "the file is empty")
    # Pickle protocol 2+ starts with 0x80; torch.save writes a zip archive ("PK").
    if data[:1] == b"\x80" or data[:2] == b"PK":
        raise _refuse(path, "the file is a pickle / torch archive, not ONNX; pickles are never loaded")
    return data


def _session(path: Path, data: bytes, threads: int):  # noqa: ANN202 - onnxruntime.InferenceSession
    import onnxruntime as ort

    opts = ort.SessionOptions()
    opts.intra_op_num_threads = threads
    opts.inter_op_num_threads = 1
    opts.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
    opts.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
    opts.log_severity_level = 3
    try:
        return ort.InferenceSession(data, sess_options=opts, providers=["CPUExecutionProvider"])
    except Exception as e:  # onnxruntime raises its own Fail/InvalidGraph/... types
        first = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
        raise _refuse(path, f"not a loadable ONNX model (corrupted or truncated?): {first}") from None


def read_metadata(path: str | Path) -> PolicyMetadata:
    """Read and parse a policy file's metadata without checking it against the robot.

    Raises:
        PolicyLoadError: unreadable file, not ONNX, or missing / malformed metadata keys.
    """
    path = Path(path)
    sess = _session(path, _read_bytes(path), threads=1)
    return _metadata(path, sess)


def _action_clip(path: Path, sess: object) -> float | None:
    props = sess.get_modelmeta().custom_metadata_map  # type: ignore[attr-defined]
    if ACTION_CLIP_KEY not in props:
        return DEFAULT_ACTION_CLIP
    try:
        value = json.loads(props[ACTION_CLIP_KEY])
    except json.JSONDecodeError as e:
        raise _refuse(path, f"metadata key {ACTION_CLIP_KEY!r} is not valid JSON: {e}") from None
    if value is None:
        return None
    if (
        isinstance(value, bool)
        or not isinstance(value, int | float)
        or not (math.isfinite(value) and value > 0)
    ):
        raise _refuse(path, f"metadata key {ACTION_CLIP_KEY!r} must be a number > 0 or null, got {value!r}")
    return float(value)


def _metadata(path: Path, sess: object) -> PolicyMetadata:
    props = dict(sess.get_modelmeta().custom_metadata_map)  # type: ignore[attr-defined]
    if not props:
        raise _refuse(
            path, "the file has no metadata; export it with bar_policy (every bar.* key is required)"
        )
    try:
        return PolicyMetadata.from_props(props)
    except MetadataError as e:
        raise _refuse(path, str(e)) from e


def _diff_joints(label: str, got: tuple[str, ...], want: tuple[str, ...]) -> str | None:
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


def _diff_values(
    label: str, unit: str, names: tuple[str, ...], got: np.ndarray, want: np.ndarray
) -> str | None:
    bad = ~np.isclose(got, want, rtol=_GAIN_RTOL, atol=1e-9)
    if not bad.any():
        return None
    items = ", ".join(f"{names[i]}: policy {got[i]:g}, robot {want[i]:g}" for i in np.flatnonzero(bad))
    return f"{label} ({unit}) differ from the robot data: {items}"


def _io_shape_ok(shape: list, size: int) -> bool:
    """``[batch, size]`` where batch is symbolic, unknown or 1."""
    if len(shape) != 2:
        return False
    batch, n = shape
    batch_ok = not isinstance(batch, int) or batch in (1, -1) or batch is None
    return batch_ok and n == size


def _check_io(path: Path, sess: object, obs_size: int, n_actions: int) -> None:
    inputs = sess.get_inputs()  # type: ignore[attr-defined]
    outputs = sess.get_outputs()  # type: ignore[attr-defined]
    if len(inputs) != 1 or inputs[0].name != "obs":
        raise _refuse(
            path, f"the graph must have exactly one input named 'obs'; it has {[i.name for i in inputs]}"
        )
    out = [o for o in outputs if o.name == "actions"]
    if not out:
        raise _refuse(path, f"the graph has no output named 'actions'; outputs: {[o.name for o in outputs]}")
    for label, node, size in (("input 'obs'", inputs[0], obs_size), ("output 'actions'", out[0], n_actions)):
        if node.type != "tensor(float)":
            raise _refuse(path, f"{label} has type {node.type}; float32 (tensor(float)) is required")
        if not _io_shape_ok(list(node.shape), size):
            raise _refuse(path, f"{label} has shape {list(node.shape)}; expected [batch, {size}]")


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

    def q_command(self, action: np.ndarray) -> np.ndarray:
        """Joint targets ``default + action_scale * action`` (action semantics ``delta_from_default``).

        Joints the policy does not drive stay at the default pose. Not clipped: the safety layer clips to
        the joint limits and counts it.

        Args:
            action: raw action, shape ``(n_actions,)``.

        Returns:
            q_cmd, rad, float64, shape ``(num_joints,)``.
        """
        q = self.default_joint_pos.copy()
        q[self.action_index] += self.action_scale * np.asarray(action, dtype=np.float64)
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
    sess = _session(path, _read_bytes(path), threads)
    meta = _metadata(path, sess)

    # Joint set and task.
    if meta.mode not in MODES:
        raise _refuse(path, f"unknown joint set (mode) {meta.mode!r}; valid: {list(MODES)}")
    if mode is not None and meta.mode != mode:
        raise _refuse(
            path,
            f"joint set mismatch: the policy is for mode {meta.mode!r} "
            f"({len(meta.joint_names)} joints), the robot runs mode {mode!r} "
            f"({load_robot(mode).num_joints} joints)",
        )
    if task is not None and meta.task != task:
        raise _refuse(path, f"task mismatch: the policy is for task {meta.task!r}, the runtime runs {task!r}")
    robot = load_robot(meta.mode)
    if meta.robot != robot.robot:
        raise _refuse(
            path, f"robot mismatch: the policy is for {meta.robot!r}, this code drives {robot.robot!r}"
        )
    msg = _diff_joints("joint names", meta.joint_names, robot.joint_names)
    if msg:
        raise _refuse(path, msg)

    # Observation schema: self-consistent, and equal to the running code's layout.
    try:
        schema = ObservationSchema.from_json(meta.obs_schema)
    except ValueError as e:
        raise _refuse(path, f"embedded observation schema is invalid: {e}") from None
    if schema.fingerprint != meta.obs_fingerprint:
        raise _refuse(
            path,
            f"observation fingerprint {meta.obs_fingerprint} does not match the embedded schema "
            f"(which hashes to {schema.fingerprint}); the file was edited or corrupted",
        )
    try:
        om = ObservationManager.for_task(meta.task, meta.mode)
    except ValueError as e:
        raise _refuse(path, str(e)) from None
    if schema.fingerprint != om.fingerprint or schema != om.schema:
        theirs, ours = schema.to_dict(), om.schema.to_dict()
        keys = sorted(k for k in set(theirs) | set(ours) if theirs.get(k) != ours.get(k))
        raise _refuse(
            path,
            f"observation schema fingerprint {schema.fingerprint} ({schema.name} v{schema.version}) differs "
            f"from the running code's {om.fingerprint} ({om.schema.name} v{om.schema.version}); "
            f"differing fields: {keys}",
        )

    # Action joints, default pose and commands (against the schema).
    if meta.action_joint_names != schema.action_joint_names:
        raise _refuse(
            path,
            f"action joints {list(meta.action_joint_names)} differ from the schema's "
            f"{list(schema.action_joint_names)}",
        )
    default = np.asarray(meta.default_joint_pos)
    msg = _diff_values(
        "default joint positions", "rad", robot.joint_names, default, np.asarray(schema.default_joint_pos)
    )
    if msg:
        raise _refuse(path, msg)
    if meta.command_names != om.command_names:
        raise _refuse(
            path,
            f"command names {list(meta.command_names)} differ from the layout's {list(om.command_names)}",
        )

    # Timing.
    if not math.isclose(meta.policy_dt, control_dt, rel_tol=0.0, abs_tol=_DT_TOL):
        raise _refuse(
            path,
            f"policy dt {meta.policy_dt} s differs from the runtime's control dt {control_dt} s "
            f"({1 / meta.policy_dt:g} Hz vs {1 / control_dt:g} Hz)",
        )
    if not math.isclose(meta.physics_dt, PHYSICS_DT, rel_tol=0.0, abs_tol=_DT_TOL):
        log.warning(
            "policy was trained with physics dt %g s; the sim target steps %g s", meta.physics_dt, PHYSICS_DT
        )

    # Gains.
    kp, kd = np.asarray(meta.joint_stiffness), np.asarray(meta.joint_damping)
    for label, unit, got, want in (("Kp", "N*m/rad", kp, robot.kp), ("Kd", "N*m*s/rad", kd, robot.kd)):
        msg = _diff_values(label, unit, robot.joint_names, got, want)
        if msg:
            raise _refuse(path, msg)

    # Graph I/O, then one dry inference to be sure the shapes hold at run time.
    n_act = len(meta.action_joint_names)
    _check_io(path, sess, om.size, n_act)
    try:
        out = sess.run(["actions"], {"obs": np.zeros((1, om.size), np.float32)})[0]
    except Exception as e:  # onnxruntime's own exception types
        raise _refuse(path, f"a test inference on a zero observation failed: {e}") from None
    if out.dtype != np.float32 or out.shape != (1, n_act):
        raise _refuse(
            path, f"a test inference returned {out.dtype} {out.shape}; expected float32 (1, {n_act})"
        )

    return OnnxPolicy(
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
        action_clip=_action_clip(path, sess),
    )
