"""A perturbation of the robot: what differs between the model a policy trained on and the robot it runs on.

``parse_perturbation("mass_scale=1.2,payload_kg=0.5,payload_at=palm")`` returns a frozen ``Perturbation``;
``bar-deploy --perturb SPEC`` and ``bar-deploy eval --perturb SPEC`` apply it to the sim target, and on the
emulated bus (``--target real --can-interface virtual``) to the emulator's robot, which the runtime does
not see (``bar_policy.robot.perturb`` builds the model edits, the deploy targets apply the rest). Keys, one
table (``KEYS``, printed by ``--help``):

========================  ==========  ================================================================
key                       unit        what changes
========================  ==========  ================================================================
``mass_scale``            x           every arm link's mass and inertia (the hands' too)
``payload_kg``            kg          a point-mass body on each hand, at ``payload_at``
``payload_at``            site        ``fingertip`` (the finger's tip site) or ``palm`` (the palm's centre)
``friction_nm``           N*m         Coulomb friction added on every arm joint (``frictionloss``)
``damping``               N*m*s/rad   passive damping added on every arm joint (``dof_damping``)
``armature_scale``        x           every arm joint's armature
``strength``              x           the torque the motor produces and its cap (not its torque reading)
``action_delay_ticks``    ticks       control ticks between a command and the motor acting on it
``obs_delay_ticks``       ticks       control ticks between a state and the policy seeing it
``offset_rad``            rad         encoder offset: the policy and the firmware's law see ``q + offset``
``push_n``                N           a force on each hand for 0.1 s, random direction, every 1-3 s
``seed``                  -           the draws of ``~VALUE`` keys and of the pushes
========================  ==========  ================================================================

``~VALUE`` draws per joint (per link for ``mass_scale``), seeded by ``seed``: the scale keys
(``mass_scale``, ``armature_scale``, ``strength``) a factor uniform in ``1 +- VALUE``; ``offset_rad`` an
offset uniform in ``+-VALUE`` (random signs); ``friction_nm`` and ``damping`` an addition uniform in
``0..VALUE`` (one-sided: the model's own friction and damping are the floor, a negative addition could
make them negative). Arm joints are the ``left_arm`` and ``right_arm`` groups (the neck of ``arms_neck``
is not perturbed).

Refusals are one line (``PerturbationError``, a ``ValueError``): an unknown key (with the nearest valid
one), a duplicate key, a value that is not a number, a value out of its range (the range named),
``~`` on a key that has no draw, ``payload_at`` without ``payload_kg``.
"""

from __future__ import annotations

import difflib
import math
from collections.abc import Sequence
from dataclasses import dataclass, fields

import numpy as np

__all__ = [
    "KEYS",
    "PAYLOAD_SITES",
    "KeySpec",
    "Perturbation",
    "PerturbationError",
    "help_text",
    "parse_perturbation",
]

PAYLOAD_SITES = ("fingertip", "palm")
"""Where ``payload_at`` puts the payload on each hand."""


class PerturbationError(ValueError):
    """A perturbation spec that cannot be used; the message is one line naming the problem."""


@dataclass(frozen=True)
class KeySpec:
    """One key of the spec: its unit, valid range, whether ``~VALUE`` draws, and a help phrase."""

    name: str
    unit: str
    kind: str
    """``float``, ``int`` or ``choice``."""
    lo: float
    hi: float
    draw: str | None
    """``~VALUE``: ``scale`` (factor in 1 +- V), ``signed`` (+-V), ``positive`` (0..V); None: no draw."""
    what: str
    draw_hi: float = 0.0
    """Largest ``~VALUE`` allowed."""


KEYS: dict[str, KeySpec] = {
    k.name: k
    for k in (
        KeySpec("mass_scale", "x", "float", 0.5, 2.0, "scale", "arm link masses and inertias", 0.5),
        KeySpec("payload_kg", "kg", "float", 0.0, 2.0, None, "point mass on each hand"),
        KeySpec("payload_at", "site", "choice", 0, 0, None, "payload site: fingertip | palm"),
        KeySpec("friction_nm", "N*m", "float", 0.0, 5.0, "positive", "added Coulomb friction", 5.0),
        KeySpec("damping", "N*m*s/rad", "float", 0.0, 10.0, "positive", "added passive damping", 10.0),
        KeySpec("armature_scale", "x", "float", 0.25, 4.0, "scale", "arm joint armature", 0.75),
        KeySpec("strength", "x", "float", 0.3, 1.5, "scale", "motor torque and its cap", 0.5),
        KeySpec("action_delay_ticks", "ticks", "int", 0, 10, None, "command latency"),
        KeySpec("obs_delay_ticks", "ticks", "int", 0, 10, None, "state latency"),
        KeySpec("offset_rad", "rad", "float", -0.2, 0.2, "signed", "encoder offset, policy and law", 0.2),
        KeySpec("push_n", "N", "float", 0.0, 100.0, None, "push on each hand, 0.1 s every 1-3 s"),
        KeySpec("seed", "-", "int", 0, 2**31 - 1, None, "seed of the ~ draws and the pushes"),
    )
}
"""Every key, in the order ``--help`` lists them."""


def help_text() -> str:
    """The keys with their units, for ``--help`` (one phrase per key)."""
    parts = []
    for k in KEYS.values():
        tilde = " (~V: random)" if k.draw else ""
        parts.append(f"{k.name} [{k.unit}] {k.what}{tilde}")
        if k.name == "payload_at":
            parts[-1] = "payload_at=fingertip|palm"
    return "; ".join(parts)


@dataclass(frozen=True, kw_only=True)
class Perturbation:
    """What differs between the model and the robot; the defaults are the nominal robot (no change)."""

    mass_scale: float = 1.0
    """Factor on every arm link's mass and inertia (``~V``: per link, uniform in 1 +- V)."""
    payload_kg: float = 0.0
    """Point mass on each hand, kg (0: none)."""
    payload_at: str = "fingertip"
    """Where the payload sits: ``fingertip`` (the fingertip site) or ``palm`` (the palm collider's centre)."""
    friction_nm: float = 0.0
    """Coulomb friction added on every arm joint, N*m (MuJoCo ``frictionloss``; ``~V``: per joint 0..V)."""
    damping: float = 0.0
    """Passive damping added on every arm joint, N*m*s/rad (``dof_damping``; ``~V``: per joint 0..V)."""
    armature_scale: float = 1.0
    """Factor on every arm joint's armature (reflected rotor inertia; ``~V``: per joint 1 +- V)."""
    strength: float = 1.0
    """Factor on the torque each motor produces and on its cap (``~V``: per joint 1 +- V). The motor's
    torque reading is the firmware's own (unscaled) estimate: a weak motor does not know it is weak."""
    action_delay_ticks: int = 0
    """Control ticks between a command's write and the motor acting on it."""
    obs_delay_ticks: int = 0
    """Control ticks between a joint state and the policy (the runtime) reading it."""
    offset_rad: float = 0.0
    """Encoder offset, rad, joint frame: the runtime reads ``q + offset`` and the firmware's MIT law acts on
    it (``~V``: per joint uniform in +-V)."""
    push_n: float = 0.0
    """External force on each hand, N, for 0.1 s in a random direction, every 1-3 s (0: none)."""
    seed: int = 0
    """Seed of the ``~`` draws and of the pushes' times and directions."""
    random: frozenset[str] = frozenset()
    """Keys given as ``~VALUE``: their value is the spread of a per-joint (per-link) draw."""
    text: str = ""
    """The spec as given (for logs and tables); empty for the nominal robot."""

    def __post_init__(self) -> None:
        for f in fields(self):
            spec = KEYS.get(f.name)
            if spec is None or spec.kind == "choice":
                continue
            _check_range(spec, getattr(self, f.name), f.name in self.random)
        if self.payload_at not in PAYLOAD_SITES:
            raise PerturbationError(f"payload_at={self.payload_at!r}: valid sites are {list(PAYLOAD_SITES)}")
        bad = sorted(self.random - {k for k, s in KEYS.items() if s.draw})
        if bad:
            raise PerturbationError(f"~VALUE is not allowed for {bad}")

    @property
    def nominal(self) -> bool:
        """True when nothing differs from the model."""
        return self == Perturbation(seed=self.seed, text=self.text)

    @property
    def changes_model(self) -> bool:
        """True when the MuJoCo model itself changes (masses, payload, friction, damping, armature)."""
        return (
            self.mass_scale != 1.0
            or "mass_scale" in self.random
            or self.payload_kg > 0
            or self.friction_nm != 0
            or self.damping != 0
            or self.armature_scale != 1.0
            or "armature_scale" in self.random
        )

    def values(self, key: str, n: int) -> np.ndarray:
        """The per-joint (per-link) values of ``key``, shape (n,): the value, or the ``~`` draws.

        Each key draws from its own stream (``seed`` and the key's position in ``KEYS``), so adding one
        key to a spec does not change another's draws.
        """
        spec = KEYS[key]
        v = float(getattr(self, key))
        if key not in self.random:
            return np.full(n, v)
        rng = np.random.default_rng([self.seed, list(KEYS).index(key)])
        u = rng.uniform(-1.0, 1.0, size=n)
        if spec.draw == "scale":
            return 1.0 + v * u
        if spec.draw == "signed":
            return v * u
        return v * (u + 1.0) / 2.0  # positive: 0..V

    def describe(self) -> str:
        """The spec as text (``text`` when given, else the keys that differ from the nominal robot)."""
        if self.text:
            return self.text
        parts = []
        for f in fields(self):
            if f.name in ("random", "text"):
                continue
            v = getattr(self, f.name)
            if v != f.default:
                parts.append(f"{f.name}={'~' if f.name in self.random else ''}{v}")
        return ",".join(parts) or "nominal"


def _check_range(spec: KeySpec, value: float, drawn: bool) -> None:
    if isinstance(value, float) and not math.isfinite(value):
        raise PerturbationError(f"{spec.name}={value}: not a finite number")
    if drawn:
        if not 0 < value <= spec.draw_hi:
            raise PerturbationError(
                f"{spec.name}=~{value:g}: the spread must be in (0, {spec.draw_hi:g}] {spec.unit}"
            )
        return
    if not spec.lo <= value <= spec.hi:
        raise PerturbationError(
            f"{spec.name}={value:g} is out of range: valid {spec.lo:g}..{spec.hi:g} {spec.unit}"
        )


def _value(spec: KeySpec, text: str) -> tuple[float | int | str, bool]:
    """The value of one ``KEY=VALUE`` and whether it was ``~VALUE``."""
    drawn = text.startswith("~")
    body = text[1:] if drawn else text
    if drawn and not spec.draw:
        valid = [k for k, s in KEYS.items() if s.draw]
        raise PerturbationError(f"{spec.name}={text}: '~' (a random draw) is only allowed for {valid}")
    if spec.kind == "choice":
        if body not in PAYLOAD_SITES:
            raise PerturbationError(f"{spec.name}={body!r}: valid values are {list(PAYLOAD_SITES)}")
        return body, False
    if spec.kind == "int":
        try:
            return int(body), drawn
        except ValueError:
            raise PerturbationError(f"{spec.name}={text!r}: not a whole number ({spec.unit})") from None
    try:
        x = float(body)
    except ValueError:
        raise PerturbationError(f"{spec.name}={text!r}: not a number ({spec.unit})") from None
    if not math.isfinite(x):
        raise PerturbationError(f"{spec.name}={text!r}: not a finite number")
    return x, drawn


def parse_perturbation(text: str) -> Perturbation:
    """``KEY=VALUE[,KEY=VALUE...]`` -> ``Perturbation`` (``""`` and ``nominal``: the nominal robot).

    Raises:
        PerturbationError: one line naming the key, the value and what is valid.
    """
    text = text.strip()
    if text in ("", "nominal"):
        return Perturbation()
    given: dict[str, object] = {}
    random: set[str] = set()
    for item in text.split(","):
        item = item.strip()
        if "=" not in item:
            raise PerturbationError(f"{item!r} is not KEY=VALUE (keys: {', '.join(KEYS)})")
        key, _, raw = (s.strip() for s in item.partition("="))
        if key not in KEYS:
            near = difflib.get_close_matches(key, KEYS, n=1)
            hint = f"; did you mean {near[0]!r}?" if near else ""
            raise PerturbationError(f"unknown perturbation key {key!r}{hint} (keys: {', '.join(KEYS)})")
        if key in given:
            raise PerturbationError(f"perturbation key {key!r} given twice")
        value, drawn = _value(KEYS[key], raw)
        given[key] = value
        if drawn:
            random.add(key)
    if "payload_at" in given and not given.get("payload_kg"):
        raise PerturbationError("payload_at without payload_kg > 0 changes nothing: give payload_kg too")
    return Perturbation(**given, random=frozenset(random), text=text)  # type: ignore[arg-type]


def arm_joint_mask(groups: Sequence[str]) -> np.ndarray:
    """True for the arm joints (groups ``left_arm`` and ``right_arm``) of a joint list's groups."""
    return np.array([g in ("left_arm", "right_arm") for g in groups], dtype=bool)
