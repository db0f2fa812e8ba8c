"""Load an ONNX policy and check its contract against the robot data and the running code.

``load_policy(path)`` opens the file with onnxruntime (never pickle, never the ``onnx`` package: the robot
computer only has onnxruntime), reads ``custom_metadata_map`` into a ``PolicyMetadata`` (either dialect, see
``deploy.metadata``) and refuses to run, with a ``PolicyLoadError`` naming the mismatch, when any of these
differ:

- ``bar`` files: the observation schema: the embedded JSON must hash to the embedded fingerprint, and equal
  the layout that this code builds for the task and mode (``ObservationManager.for_task``);
- HC-only files: every term of ``observation_names`` and ``command_names`` must be one the runtime can feed
  (``supported_terms()``: the catalogue's command terms and the state / action terms the runtime computes);
  the schema is built from those names (HC's built-in meaning: ``joint_pos = (q - default) * 1``,
  ``joint_vel`` raw, ``actions`` = the previous action, every scale 1, no clip), whatever the ``task_type``;
- the joint set (``arms`` / ``arms_neck``) and the canonical joint order (``load_robot(mode)``; an HC-only
  file's joint set is the mode whose joints its ``joint_names`` lists, in canonical order);
- the action joints, default pose and command names (against the schema);
- the policy period against the runtime's control period (0.02 s unless overridden);
- the gains Kp / Kd: ``bar`` files against the robot data; HC-only files within each motor's MIT wire range
  (the file's gains are used);
- the graph's I/O: one float32 input ``obs`` of shape ``[batch, obs_size]`` and a float32 output
  ``actions`` of shape ``[batch, n_action_joints]``.

The accepted policy is an ``OnnxPolicy``: ``policy(obs)`` runs one inference and ``policy.q_command(action)``
turns an action into the unclipped joint target ``default + action_scale * action`` for the joints the
policy drives; joints it does not drive are pinned at 0 rad with the file's Kp / Kd, as Humanoid Control
holds them (lite-model.md 2.1). ``policy.hold_pose`` (that target at action 0) is where the HOLD ramp goes.

Action clip: the LiteReach env clips every action to [-1, 1] before ``q_cmd`` and feeds the clipped action
back as the ``actions`` observation term. ``OnnxPolicy.action_clip`` carries that bound: the optional
metadata key ``bar.action_clip`` (a JSON number, or null for none) when the file has it, else
``DEFAULT_ACTION_CLIP`` (1.0); an HC-only file gets no action clip (Humanoid Control applies none). The
runtime applies it and counts every clipped entry.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from bar_policy.deploy.metadata import MetadataError, PolicyMetadata
from bar_policy.obs.manager import ObservationManager, ObservationSchema, ObsTerm
from bar_policy.obs.terms import TERM_CATALOG
from bar_policy.robot.constants import MODES, RobotSpec, load_robot
from bar_policy.robot.mit import wire_ranges
from bar_policy.robot.mjcf import PHYSICS_DT

__all__ = [
    "ACTION_CLIP_KEY",
    "DEFAULT_ACTION_CLIP",
    "DEFAULT_CONTROL_DT",
    "HC_TERM_CLIP",
    "RUNTIME_INPUTS",
    "OnnxPolicy",
    "PolicyLoadError",
    "load_policy",
    "read_metadata",
    "supported_terms",
]

log = logging.getLogger(__name__)

DEFAULT_CONTROL_DT = 0.02
"""Control (policy) period the runtime expects, s (50 Hz)."""

ACTION_CLIP_KEY = "bar.action_clip"
"""Optional metadata key: symmetric bound applied to raw actions (JSON number > 0, or null for none)."""
DEFAULT_ACTION_CLIP = 1.0
"""Action bound when the file has no ``bar.action_clip`` (the LiteReach contract: actions in [-1, 1])."""

RUNTIME_INPUTS = ("joint_pos", "joint_vel", "actions", "fingertip_pos_left", "fingertip_pos_right")
"""Observation inputs the runtime computes itself each tick (measured q and dq, the previous action, forward
kinematics of the fingertips). Command-category terms come from the command source."""
HC_TERM_CLIP = 1e6
"""Clip of every term of an HC-only file's schema: effectively none, as Humanoid Control does not clip."""

_DT_TOL = 1e-9
"""Tolerance on the policy period, s."""
_GAIN_RTOL = 1e-6
"""Relative tolerance on Kp / Kd and on the default pose (JSON round-trips floats exactly; this is slack)."""
_PICKLE_SUFFIXES = (".pt", ".pth", ".pkl", ".pickle", ".ckpt", ".joblib")


class PolicyLoadError(ValueError):
    """A policy file cannot be run: unreadable, not ONNX, or its contract does not match this robot/code."""


def _refuse(path: Path, msg: str) -> PolicyLoadError:
    return PolicyLoadError(f"refusing policy {str(path)!r}: {msg}")


def supported_terms() -> tuple[str, ...]:
    """Observation terms a policy may use: the catalogue's terms the runtime can feed, catalogue order.

    Read from ``TERM_CATALOG`` each call: a command-category term is fed by the command source, any other
    term only when the runtime computes it (``RUNTIME_INPUTS``); IMU terms, for one, are not fed.
    """
    return tuple(n for n, kind in TERM_CATALOG.items() if kind.category == "command" or n in RUNTIME_INPUTS)


def _hc_mode(path: Path, meta: PolicyMetadata) -> str:
    """The joint set whose canonical joints an HC-only file's ``joint_names`` lists."""
    for mode in MODES:
        robot = load_robot(mode)
        if set(meta.joint_names) == set(robot.joint_names) and len(meta.joint_names) == robot.num_joints:
            msg = _diff_joints("metadata key 'joint_names'", meta.joint_names, robot.joint_names)
            if msg:
                raise _refuse(path, msg)
            return mode
    sets = "; ".join(f"{m}: {list(load_robot(m).joint_names)}" for m in MODES)
    raise _refuse(
        path,
        f"metadata key 'joint_names' lists {len(meta.joint_names)} joints {list(meta.joint_names)}, which is "
        f"not the joint set of any mode ({sets})",
    )


def _complete_hc(path: Path, meta: PolicyMetadata) -> PolicyMetadata:
    """An HC-only file's joint set and observation schema, built from its HC keys (refusing unknown terms)."""
    mode = _hc_mode(path, meta)
    robot = load_robot(mode)
    supported = supported_terms()
    for key, names in (("observation_names", meta.observation_names), ("command_names", meta.command_names)):
        unknown = [n for n in names if n not in supported]
        if unknown:
            raise _refuse(
                path,
                f"metadata key {key!r} uses terms {unknown} that this runtime cannot feed; "
                f"supported terms: {list(supported)}",
            )
    if not meta.observation_names:
        raise _refuse(path, "metadata key 'observation_names' is empty")
    obs_commands = tuple(n for n in meta.observation_names if TERM_CATALOG[n].category == "command")
    if set(meta.command_names) != set(obs_commands):
        raise _refuse(
            path,
            f"metadata key 'command_names' {list(meta.command_names)} differs from the command terms of "
            f"'observation_names' {list(obs_commands)}",
        )
    sizes = {"joints": len(meta.joint_names), "actions": len(meta.action_joint_names)}
    terms = tuple(
        ObsTerm(name=n, size=sizes.get(TERM_CATALOG[n].size, TERM_CATALOG[n].size), clip=HC_TERM_CLIP)  # type: ignore[arg-type]
        for n in meta.observation_names
    )
    try:
        schema = ObservationSchema(
            name=f"hc_{meta.task or 'policy'}_{mode}",
            version=0,
            robot=robot.robot,
            mode=mode,
            joint_names=meta.joint_names,
            action_joint_names=meta.action_joint_names,
            default_joint_pos=meta.default_joint_pos,
            terms=terms,
        )
    except ValueError as e:
        raise _refuse(path, f"the HC keys do not make a valid observation schema: {e}") from None
    return dataclasses.replace(
        meta,
        robot=robot.robot,
        mode=mode,
        command_names=obs_commands,
        obs_schema=schema.to_json(indent=None),
        obs_fingerprint=schema.fingerprint,
    )


def _check_hc_gains(path: Path, meta: PolicyMetadata, robot: RobotSpec) -> None:
    """An HC-only file's gains must be finite, >= 0 and within each motor's MIT wire range (never clamped)."""
    ranges = wire_ranges(robot.models)
    for key, values, top in (
        ("joint_stiffness", meta.joint_stiffness, ranges.kp_max),
        ("joint_damping", meta.joint_damping, ranges.kd_max),
    ):
        bad = [
            f"{robot.joint_names[i]}: {v:g} not in [0, {top[i]:g}]"
            for i, v in enumerate(values)
            if not (math.isfinite(v) and 0.0 <= v <= top[i])
        ]
        if bad:
            raise _refuse(path, f"metadata key {key!r} is outside the motors' MIT range: {', '.join(bad)}")


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
    meta = _metadata(path, sess)
    return _complete_hc(path, meta) if meta.dialect == "hc" else meta


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
    sess = _session(path, _read_bytes(path), threads)
    meta = _metadata(path, sess)
    if meta.dialect == "hc":
        meta = _complete_hc(path, meta)

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
    if meta.dialect == "hc":
        om = ObservationManager(schema)  # built from the file's HC keys: no code layout to compare with
    else:
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
    if meta.physics_dt is not None and not math.isclose(
        meta.physics_dt, PHYSICS_DT, rel_tol=0.0, abs_tol=_DT_TOL
    ):
        log.warning(
            "policy was trained with physics dt %g s; the sim target steps %g s", meta.physics_dt, PHYSICS_DT
        )

    # Gains: a bar file's must be the robot data's; an HC-only file's are used as they are (in range).
    kp, kd = np.asarray(meta.joint_stiffness), np.asarray(meta.joint_damping)
    if meta.dialect == "hc":
        _check_hc_gains(path, meta, robot)
    else:
        for label, unit, got, want in (("Kp", "N*m/rad", kp, robot.kp), ("Kd", "N*m*s/rad", kd, robot.kd)):
            msg = _diff_values(label, unit, robot.joint_names, got, want)
            if msg:
                raise _refuse(path, msg)
    undriven = [n for n in robot.joint_names if n not in meta.action_joint_names]
    if undriven:
        log.info("joints the policy does not drive, pinned at 0 rad with the file's Kp/Kd: %s", undriven)

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
        # HC-only files: no clip, as Humanoid Control runs them (q_cmd is still clipped to the limits).
        action_clip=_action_clip(path, sess) if meta.dialect == "bar" else None,
    )
