"""The robot-parameters file: what system identification measured of one robot, as the sim should model it.

``bar-bus identify --out FILE`` writes it; ``load_params(FILE)`` reads it back strictly; ``scene_edit`` and
``motor_strength`` apply it to the MuJoCo model and to the motors. Version 1, JSON, every key known:

.. code-block:: json

    {
      "version": 1,
      "source": {"kind": "identify", "date": "2026-12-02T05:40:00Z", "command": "bar-bus identify ...",
                 "mode": "arms", "emulated": true, "can_log": "identify.canlog", "excitation_s": 48.0,
                 "samples": 4800},
      "joints": {
        "left_elbow_pitch": {"friction_nm": {"value": 0.61, "ci95": [0.58, 0.64]},
                             "damping":     {"value": 0.02, "ci95": [0.0, 0.05]},
                             "armature":    {"value": 0.0021, "ci95": [0.0018, 0.0024]},
                             "strength":    {"value": 1.0, "ci95": [0.99, 1.01]}}
      },
      "payload": {"left":  {"mass_kg": {"value": 0.4, "ci95": [0.38, 0.42]},
                            "com_m": {"value": [0.0, -0.1, 0.0], "ci95": [[...], [...], [...]]}},
                  "right": {...}}
    }

Quantities, all totals (what the joint has, the model's own included, not an addition to it):

==================  ==========  ======================================================================
key                 unit        meaning (MuJoCo field)
==================  ==========  ======================================================================
``friction_nm``     N*m         Coulomb friction (``dof_frictionloss``)
``damping``         N*m*s/rad   viscous friction (``dof_damping``)
``armature``        kg*m^2      reflected rotor inertia beyond the links (``dof_armature``)
``strength``        x           torque produced per torque commanded (1: as the model); not in MuJoCo:
                                the sim target and the emulator scale the motor's torque by it
``mass_kg``         kg          payload on the hand (a point mass, 0: none)
``com_m``           m           its centre in the hand body's frame
==================  ==========  ======================================================================

``ci95`` is the 95 % confidence interval ``[lo, hi]`` (optional: ``null`` or absent for a value set by
hand). ``joints`` may list a subset of the arm joints (the others keep the model's values); ``payload`` may
omit a hand (no payload there). ``source`` records the run the values came from.

Refusals are one line (``ParamsError``, a ``ValueError``): wrong or missing version, an unknown key (with
the nearest valid one), a value that is not a finite number, a value out of its range (the range named),
an interval that does not hold its value. ``sha256`` is the hash of the canonical file (sorted keys, no
whitespace), the identity training and deploy record.
"""

from __future__ import annotations

import difflib
import hashlib
import json
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import mujoco
import numpy as np

from bar_policy.robot.constants import RobotSpec
from bar_policy.robot.scene import SceneEdit

__all__ = [
    "HANDS",
    "JOINT_KEYS",
    "PARAMS_VERSION",
    "SOURCE_KEYS",
    "Estimate",
    "JointParams",
    "ParamsError",
    "Payload",
    "RobotParams",
    "load_params",
    "motor_strength",
    "params_record",
    "parse_params",
    "scene_edit",
    "training_mismatch",
]

PARAMS_VERSION = 1
"""The file's version; any other is refused."""

JOINT_KEYS: dict[str, tuple[float, float, str]] = {
    "friction_nm": (0.0, 10.0, "N*m"),
    "damping": (0.0, 20.0, "N*m*s/rad"),
    "armature": (0.0, 0.5, "kg*m^2"),
    "strength": (0.3, 1.5, "x"),
}
"""Per-joint quantity -> (lowest, highest, unit)."""

MASS_RANGE = (0.0, 2.0)
"""Payload mass range, kg."""
COM_LIMIT = 0.5
"""Largest payload centre coordinate, m (hand frame)."""

HANDS: dict[str, str] = {"left": "left_hand", "right": "right_hand"}
"""Payload key -> the hand body that carries it."""

SOURCE_KEYS: dict[str, type | tuple[type, ...]] = {
    "kind": str,
    "date": str,
    "command": str,
    "mode": str,
    "emulated": bool,
    "can_log": (str, type(None)),
    "excitation_s": (int, float),
    "samples": int,
    "commit": (str, type(None)),
    "notes": str,
}
"""Keys ``source`` may hold and their JSON types."""

PAYLOAD_RADIUS = 0.01
"""The payload body's inertia is a 1 cm solid sphere's (a point mass to the arm that MuJoCo accepts), m."""


class ParamsError(ValueError):
    """A robot-parameters file that cannot be used; the message is one line naming the problem."""


@dataclass(frozen=True)
class Estimate:
    """A value with its 95 % confidence interval (None: not given)."""

    value: float
    ci95: tuple[float, float] | None = None

    def to_json(self) -> dict[str, Any]:
        """``{"value": v, "ci95": [lo, hi] | null}``."""
        return {"value": self.value, "ci95": None if self.ci95 is None else list(self.ci95)}


@dataclass(frozen=True)
class JointParams:
    """One joint's identified values (totals, see the module docstring)."""

    friction_nm: Estimate
    damping: Estimate
    armature: Estimate
    strength: Estimate


@dataclass(frozen=True)
class Payload:
    """A point mass on one hand: ``mass_kg`` (kg) at ``com_m`` (m, hand frame, shape (3,))."""

    mass_kg: Estimate
    com_m: tuple[float, float, float]
    com_ci95: tuple[tuple[float, float], ...] | None = None


@dataclass(frozen=True)
class RobotParams:
    """A parsed robot-parameters file (module docstring)."""

    joints: Mapping[str, JointParams]
    payload: Mapping[str, Payload] = field(default_factory=dict)
    source: Mapping[str, Any] = field(default_factory=dict)

    def to_json(self) -> dict[str, Any]:
        """The file's JSON object (``parse_params`` of it gives back an equal ``RobotParams``)."""
        pay = {}
        for hand, p in self.payload.items():
            pay[hand] = {
                "mass_kg": p.mass_kg.to_json(),
                "com_m": {
                    "value": list(p.com_m),
                    "ci95": None if p.com_ci95 is None else [list(c) for c in p.com_ci95],
                },
            }
        return {
            "version": PARAMS_VERSION,
            "source": dict(self.source),
            "joints": {
                name: {k: getattr(jp, k).to_json() for k in JOINT_KEYS} for name, jp in self.joints.items()
            },
            "payload": pay,
        }

    def canonical(self) -> bytes:
        """The canonical bytes: sorted keys, no whitespace, UTF-8 (what ``sha256`` hashes)."""
        return json.dumps(self.to_json(), sort_keys=True, separators=(",", ":"), allow_nan=False).encode()

    @property
    def sha256(self) -> str:
        """Hex sha256 of the canonical file: equal for equal parameters, whatever the layout on disk."""
        return hashlib.sha256(self.canonical()).hexdigest()

    def save(self, path: str | Path) -> None:
        """Write the file (indented, sorted keys); refuses what ``parse_params`` would refuse."""
        obj = self.to_json()
        parse_params(obj)
        Path(path).write_text(json.dumps(obj, indent=2, sort_keys=True, allow_nan=False) + "\n")


def _keys(obj: Any, valid: Sequence[str], where: str, required: Sequence[str] = ()) -> dict[str, Any]:
    if not isinstance(obj, dict):
        raise ParamsError(f"{where}: expected an object, got {type(obj).__name__}")
    for k in obj:
        if k not in valid:
            near = difflib.get_close_matches(str(k), valid, n=1)
            hint = f"; did you mean {near[0]!r}?" if near else ""
            raise ParamsError(f"{where}: unknown key {k!r}{hint} (valid: {', '.join(valid)})")
    missing = [k for k in required if k not in obj]
    if missing:
        raise ParamsError(f"{where}: missing {', '.join(repr(m) for m in missing)}")
    return obj


def _number(x: Any, where: str, lo: float, hi: float, unit: str) -> float:
    if isinstance(x, bool) or not isinstance(x, int | float):
        raise ParamsError(f"{where}: expected a number ({unit}), got {x!r}")
    v = float(x)
    if not math.isfinite(v):
        raise ParamsError(f"{where}: {x!r} is not a finite number")
    if not lo <= v <= hi:
        raise ParamsError(f"{where}={v:g} is out of range: valid {lo:g}..{hi:g} {unit}")
    return v


def _interval(x: Any, value: float, where: str, unit: str) -> tuple[float, float] | None:
    if x is None:
        return None
    if not isinstance(x, list) or len(x) != 2:
        raise ParamsError(f"{where}.ci95: expected [lo, hi], got {x!r}")
    lo, hi = (_number(v, f"{where}.ci95", -math.inf, math.inf, unit) for v in x)
    if not lo <= value <= hi:
        raise ParamsError(f"{where}.ci95 [{lo:g}, {hi:g}] does not hold its value {value:g}")
    return lo, hi


def _estimate(x: Any, where: str, lo: float, hi: float, unit: str) -> Estimate:
    obj = _keys(x, ("value", "ci95"), where, required=("value",))
    v = _number(obj["value"], f"{where}.value", lo, hi, unit)
    return Estimate(v, _interval(obj.get("ci95"), v, where, unit))


def parse_params(obj: Any, joint_names: Sequence[str] | None = None) -> RobotParams:
    """Validate a parsed JSON object -> ``RobotParams``; ``joint_names``: the joints a name may be.

    Raises:
        ParamsError: one line naming the key, the value and what is valid.
    """
    top = _keys(obj, ("version", "source", "joints", "payload"), "robot params", required=("version",))
    version = top["version"]
    if isinstance(version, bool) or version != PARAMS_VERSION:
        raise ParamsError(f"robot params: version {version!r} is not supported (valid: {PARAMS_VERSION})")
    source = _keys(top.get("source", {}), list(SOURCE_KEYS), "source")
    for k, v in source.items():
        if not isinstance(v, SOURCE_KEYS[k]) or (isinstance(v, bool) and SOURCE_KEYS[k] is not bool):
            raise ParamsError(f"source.{k}: {v!r} has the wrong type")
        if isinstance(v, float) and not math.isfinite(v):
            raise ParamsError(f"source.{k}: {v!r} is not a finite number")
    joints_obj = top.get("joints", {})
    if not isinstance(joints_obj, dict):
        raise ParamsError(f"joints: expected an object, got {type(joints_obj).__name__}")
    joints: dict[str, JointParams] = {}
    for name, jobj in joints_obj.items():
        if joint_names is not None and name not in joint_names:
            near = difflib.get_close_matches(str(name), joint_names, n=1)
            hint = f"; did you mean {near[0]!r}?" if near else ""
            raise ParamsError(f"joints: unknown joint {name!r}{hint}")
        body = _keys(jobj, list(JOINT_KEYS), f"joints.{name}", required=list(JOINT_KEYS))
        vals = {k: _estimate(body[k], f"joints.{name}.{k}", *JOINT_KEYS[k]) for k in JOINT_KEYS}
        joints[name] = JointParams(**vals)
    payload: dict[str, Payload] = {}
    for hand, pobj in _keys(top.get("payload", {}), list(HANDS), "payload").items():
        where = f"payload.{hand}"
        body = _keys(pobj, ("mass_kg", "com_m"), where, required=("mass_kg", "com_m"))
        mass = _estimate(body["mass_kg"], f"{where}.mass_kg", *MASS_RANGE, "kg")
        com = _keys(body["com_m"], ("value", "ci95"), f"{where}.com_m", required=("value",))
        value = com["value"]
        if not isinstance(value, list) or len(value) != 3:
            raise ParamsError(f"{where}.com_m.value: expected [x, y, z] in m, got {value!r}")
        c = tuple(_number(v, f"{where}.com_m.value", -COM_LIMIT, COM_LIMIT, "m") for v in value)
        ci = com.get("ci95")
        cis = None
        if ci is not None:
            if not isinstance(ci, list) or len(ci) != 3:
                raise ParamsError(f"{where}.com_m.ci95: expected three [lo, hi], got {ci!r}")
            cis = tuple(_interval(i, v, f"{where}.com_m", "m") for i, v in zip(ci, c, strict=True))
        payload[hand] = Payload(mass, c, cis)  # type: ignore[arg-type]
    return RobotParams(joints, payload, source)


def load_params(path: str | Path, robot: RobotSpec | None = None) -> RobotParams:
    """Read and validate a robot-parameters file (``robot``: check joint names against its joints)."""
    try:
        text = Path(path).read_text()
    except OSError as exc:
        raise ParamsError(f"{path}: cannot read: {exc.strerror or exc}") from None
    try:
        obj = json.loads(text, parse_constant=lambda c: float(c))
    except json.JSONDecodeError as exc:
        raise ParamsError(f"{path}: not JSON: {exc.msg} at line {exc.lineno}") from None
    try:
        return parse_params(obj, None if robot is None else robot.joint_names)
    except ParamsError as exc:
        raise ParamsError(f"{path}: {exc}") from None


def apply_to_spec(spec: mujoco.MjSpec, params: RobotParams) -> None:
    """Set each listed joint's friction, damping and armature (totals) and add each hand's payload body."""
    for name, jp in params.joints.items():
        j = spec.joint(name)
        j.frictionloss = jp.friction_nm.value
        damping = np.array(j.damping, dtype=np.float64)  # MuJoCo 3.17: [linear, higher-order terms]
        damping[0] = jp.damping.value
        j.damping = damping
        j.armature = jp.armature.value
    for hand, p in params.payload.items():
        if p.mass_kg.value <= 0:
            continue
        m = p.mass_kg.value
        i = 0.4 * m * PAYLOAD_RADIUS**2
        body = spec.body(HANDS[hand]).add_body(name=f"{HANDS[hand]}_payload", pos=list(p.com_m))
        body.explicitinertial = True
        body.mass = m
        body.ipos = [0.0, 0.0, 0.0]
        body.fullinertia = [i, i, i, 0.0, 0.0, 0.0]


def _payload_hands(params: RobotParams) -> tuple[str, ...]:
    """The hands (``HANDS`` keys) whose payload ``apply_to_spec`` adds (mass above 0)."""
    return tuple(h for h, p in params.payload.items() if p.mass_kg.value > 0)


def scene_edit(params: RobotParams, scene: SceneEdit | None = None) -> SceneEdit:
    """The scene edit of the identified robot: ``scene`` (a task's additions, or None), then the params."""

    def edit(spec: mujoco.MjSpec) -> None:
        if scene is not None:
            scene(spec)
        apply_to_spec(spec, params)

    return edit


def motor_strength(params: RobotParams, robot: RobotSpec) -> np.ndarray:
    """Per-joint strength, canonical order, shape (num_joints,) (1 for joints the file does not list)."""
    out = np.ones(robot.num_joints)
    for name, jp in params.joints.items():
        out[robot.joint_names.index(name)] = jp.strength.value
    return out


def params_record(params: RobotParams) -> dict[str, Any]:
    """What a policy file records of the parameters it trained on (``bar.robot_params``), plain JSON.

    ``sha256``: the file's identity (``RobotParams.sha256``); ``summary``: the values at a glance, each
    joint quantity's lowest and highest over the listed joints (``friction_nm`` N*m, ``damping``
    N*m*s/rad, ``armature`` kg*m^2, ``strength`` x), ``joints`` (how many are listed), ``payload_kg`` per
    hand listed, and the source's ``kind`` and ``date`` when given.
    """
    summary: dict[str, Any] = {"joints": len(params.joints)}
    for key in JOINT_KEYS:
        values = [getattr(jp, key).value for jp in params.joints.values()]
        if values:
            summary[key] = [min(values), max(values)]
    summary["payload_kg"] = {hand: p.mass_kg.value for hand, p in sorted(params.payload.items())}
    for key in ("kind", "date"):
        if key in params.source:
            summary[f"source_{key}"] = params.source[key]
    return {"sha256": params.sha256, "summary": summary}


def training_mismatch(trained: Mapping[str, Any] | None, params: RobotParams | None) -> str | None:
    """One line when the run's parameters differ from the ones the policy trained on; None when they agree.

    ``trained``: the policy file's ``bar.robot_params`` record (``params_record``; empty or None: trained on
    the nominal model); ``params``: the run's ``--robot-params`` file (None: the nominal model). Agreement
    is equal ``sha256``; a policy trained nominal and run nominal agrees.
    """
    trained_hash = str(trained.get("sha256", "")) if trained else ""
    run_hash = "" if params is None else params.sha256
    if trained_hash == run_hash:
        return None
    was = f"robot parameters sha256 {trained_hash[:12]}" if trained_hash else "the nominal model"
    now = f"--robot-params sha256 {run_hash[:12]}" if run_hash else "the nominal model (no --robot-params)"
    return f"robot parameters mismatch: the policy was trained on {was}, this run models {now}"
