"""Build small ONNX policy files with full ``bar.*`` metadata, for tests (uses ``onnx``; tests only).

``make_policy_file(path, ...)`` writes a linear policy ``actions = obs @ W + b`` whose output can be worked
out by hand: with the default ``W = 0`` the action is the constant ``b``, so the runtime must command
``q_cmd = default_joint_pos + action_scale * b`` exactly (clipped to the joint limits).

``make_hc_policy_file(path, props, ...)`` writes the same kind of graph with only the 13 Humanoid Control keys
(comma-separated values, no ``bar.*`` key), as mjlab exports them; ``hc_props`` builds those keys.

Reuse from other test folders::

    sys.path.insert(0, str(Path(__file__).parents[1] / "deploy"))
    from policy_factory import make_policy_file, default_metadata
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import numpy as np
import onnx
from onnx import TensorProto, helper, numpy_helper

from bar_policy.deploy.metadata import PolicyMetadata
from bar_policy.obs.manager import ObservationManager
from bar_policy.robot.constants import load_robot
from bar_policy.robot.mjcf import PHYSICS_DT

__all__ = ["default_metadata", "hc_props", "make_hc_policy_file", "make_policy_file"]


def default_metadata(mode: str = "arms", task: str = "reach", **overrides: Any) -> PolicyMetadata:
    """Metadata that matches the robot data and the running code; ``overrides`` replace fields.

    ``task="track"`` gives the tracking layout with its HC keys (``body_names``, ``lookahead_steps``).
    """
    robot = load_robot(mode)
    om = ObservationManager.for_task(task, mode)
    meta = PolicyMetadata(
        task=task,
        robot=robot.robot,
        mode=mode,
        joint_names=robot.joint_names,
        action_joint_names=om.schema.action_joint_names,
        joint_stiffness=tuple(float(x) for x in robot.kp),
        joint_damping=tuple(float(x) for x in robot.kd),
        default_joint_pos=tuple(om.schema.default_joint_pos),
        action_scale=(0.25,) * len(om.schema.action_joint_names),
        action_semantics="delta_from_default",
        policy_dt=0.02,
        physics_dt=PHYSICS_DT,
        obs_schema=om.schema.to_json(),
        obs_fingerprint=om.fingerprint,
        command_names=om.command_names,
        code_version="test",
        training={"backend": "test"},
        body_names=om.schema.body_names,
        lookahead_steps=om.schema.lookahead_steps,
        dataset_repo_id="test" if om.schema.lookahead_steps else "",
    )
    return dataclasses.replace(meta, **overrides) if overrides else meta


def make_policy_file(
    path: str | Path,
    *,
    mode: str = "arms",
    weight: np.ndarray | None = None,
    bias: np.ndarray | float = 0.0,
    metadata: PolicyMetadata | None = None,
    props: dict[str, str] | None = None,
    drop_keys: tuple[str, ...] = (),
    obs_size: int | None = None,
    n_actions: int | None = None,
    dtype: int = TensorProto.FLOAT,
    input_name: str = "obs",
    output_name: str = "actions",
    batch: str | int = "batch",
    hidden: int = 0,
    seed: int = 0,
) -> Path:
    """Write a policy ``actions = obs @ weight + bias`` (or a tanh MLP when ``hidden > 0``).

    Args:
        path: output file.
        mode: joint set of the default metadata.
        weight: shape (obs_size, n_actions); zeros when None.
        bias: shape (n_actions,) or a scalar.
        metadata: replaces the default metadata.
        props: extra / overriding metadata_props strings (applied after ``metadata.to_props()``).
        drop_keys: metadata keys to leave out.
        obs_size, n_actions: graph sizes (default: the metadata's layout) - to build wrong files.
        dtype: ONNX element type of input and output (FLOAT, DOUBLE, ...).
        input_name, output_name: graph I/O names.
        batch: symbolic or fixed batch dimension.
        hidden: hidden width of a random 2-layer MLP (tests of timing); 0 gives the linear policy.
        seed: seed of the MLP weights.
    """
    meta = metadata or default_metadata(mode)
    om = ObservationManager.from_json(meta.obs_schema)
    n_obs = om.size if obs_size is None else obs_size
    n_act = len(meta.action_joint_names) if n_actions is None else n_actions
    np_dtype = helper.tensor_dtype_to_np_dtype(dtype)
    nodes, inits = [], []
    if hidden > 0:
        rng = np.random.default_rng(seed)
        w1 = (rng.standard_normal((n_obs, hidden)) / np.sqrt(n_obs)).astype(np_dtype)
        w2 = (rng.standard_normal((hidden, hidden)) / np.sqrt(hidden)).astype(np_dtype)
        w3 = (0.01 * rng.standard_normal((hidden, n_act))).astype(np_dtype)
        for name, arr in (("w1", w1), ("w2", w2), ("w3", w3)):
            inits.append(numpy_helper.from_array(arr, name))
        nodes += [
            helper.make_node("MatMul", [input_name, "w1"], ["h1"]),
            helper.make_node("Tanh", ["h1"], ["a1"]),
            helper.make_node("MatMul", ["a1", "w2"], ["h2"]),
            helper.make_node("Tanh", ["h2"], ["a2"]),
            helper.make_node("MatMul", ["a2", "w3"], ["out"]),
        ]
        last = "out"
    else:
        w = np.zeros((n_obs, n_act)) if weight is None else np.asarray(weight)
        inits.append(numpy_helper.from_array(w.astype(np_dtype), "W"))
        nodes.append(helper.make_node("MatMul", [input_name, "W"], ["xw"]))
        last = "xw"
    b = np.broadcast_to(np.asarray(bias, dtype=np.float64), (n_act,))
    inits.append(numpy_helper.from_array(b.astype(np_dtype), "b"))
    nodes.append(helper.make_node("Add", [last, "b"], [output_name]))
    graph = helper.make_graph(
        nodes,
        "test_policy",
        [helper.make_tensor_value_info(input_name, dtype, [batch, n_obs])],
        [helper.make_tensor_value_info(output_name, dtype, [batch, n_act])],
        initializer=inits,
    )
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])
    model.ir_version = 8
    all_props = meta.to_props()
    all_props.update(props or {})
    for k in drop_keys:
        all_props.pop(k, None)
    helper.set_model_props(model, all_props)
    onnx.checker.check_model(model)
    path = Path(path)
    onnx.save(model, str(path))
    return path


def hc_props(
    *,
    task_type: str = "tracking",
    joint_names: tuple[str, ...] | None = None,
    action_joint_names: tuple[str, ...] | None = None,
    stiffness: float | tuple[float, ...] = 30.0,
    damping: float | tuple[float, ...] = 1.5,
    default_joint_pos: tuple[float, ...] | None = None,
    observation_names: tuple[str, ...] = ("joint_pos", "joint_vel", "actions"),
    command_names: tuple[str, ...] = (),
    action_scale: float | tuple[float, ...] = 0.5,
    policy_dt: float = 0.02,
    mode: str = "arms",
) -> dict[str, str]:
    """The 13 HC keys as mjlab writes them (defaults: the canonical joints of ``mode``, all driven)."""
    robot = load_robot(mode)
    joints = robot.joint_names if joint_names is None else joint_names
    acts = joints if action_joint_names is None else action_joint_names
    default = tuple(robot.pose("piano_ready")) if default_joint_pos is None else default_joint_pos

    def per(value: float | tuple[float, ...], n: int) -> tuple[float, ...]:
        return (value,) * n if isinstance(value, int | float) else tuple(value)

    def csv(values: tuple) -> str:
        return ",".join(str(v) for v in values)

    return {
        "task_type": task_type,
        "joint_names": csv(joints),
        "action_joint_names": csv(acts),
        "joint_stiffness": csv(per(stiffness, len(joints))),
        "joint_damping": csv(per(damping, len(joints))),
        "default_joint_pos": csv(default),
        "observation_names": csv(observation_names),
        "command_names": csv(command_names),
        "action_scale": csv(per(action_scale, len(acts))),
        "policy_dt": str(policy_dt),
        "body_names": "",
        "dataset_repo_id": "",
        "lookahead_steps": "0",
    }


def make_hc_policy_file(
    path: str | Path,
    props: dict[str, str],
    *,
    obs_size: int,
    weight: np.ndarray | None = None,
    bias: np.ndarray | float = 0.0,
) -> Path:
    """A linear policy ``actions = obs @ weight + bias`` with exactly ``props`` as metadata (no ``bar.*``)."""
    n_act = len([n for n in props["action_joint_names"].split(",") if n])
    w = np.zeros((obs_size, n_act)) if weight is None else np.asarray(weight)
    b = np.broadcast_to(np.asarray(bias, dtype=np.float64), (n_act,))
    graph = helper.make_graph(
        [helper.make_node("MatMul", ["obs", "W"], ["xw"]), helper.make_node("Add", ["xw", "b"], ["actions"])],
        "hc_policy",
        [helper.make_tensor_value_info("obs", TensorProto.FLOAT, ["batch", obs_size])],
        [helper.make_tensor_value_info("actions", TensorProto.FLOAT, ["batch", n_act])],
        initializer=[
            numpy_helper.from_array(w.astype(np.float32), "W"),
            numpy_helper.from_array(b.astype(np.float32), "b"),
        ],
    )
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])
    model.ir_version = 8
    helper.set_model_props(model, dict(props))
    onnx.checker.check_model(model)
    path = Path(path)
    onnx.save(model, str(path))
    return path
