"""Model-level domain randomisation: a pure ``(mjx_model, rng) -> (batched_model, in_axes)``.

Brax PPO calls the randomiser once at the start of training with one key per env slot (``rng`` shape
``(num_envs, 2)``); each slot then keeps its randomised model for the whole run, while the episode-level
effects (latency, Kp/Kd scale, encoder offset, observation noise, initial pose, targets) are sampled at
every reset by the env itself. The randomiser reads only the robot part of a config (``RobotEnvConfig``:
``mode`` and ``randomization``), so it is the same for every task. ``in_axes`` has the model's structure
with ``0`` on the randomised fields and ``None`` elsewhere, for ``jax.vmap(..., in_axes=(in_axes, 0))``.

In a task's scene (``bar_policy.robot.scene``) armature, friction and damping are drawn for the robot's
joints and written at their dof addresses (``RobotIndex``, read from the model by name); the scene's other
dofs keep theirs. The link-mass factor applies to every body of the scene.

The payload (``ModelRandomizationConfig.payload_kg``) needs a body in the compiled model: ``payload_scene``
adds a massless, geom-less body to each hand of the training scene (the env does it when ``payload_kg`` is
set), and the randomiser writes its drawn ``body_mass`` and ``body_inertia`` (and, for ``payload_at=either``,
its ``body_pos``). The draws the default config makes are unchanged by the optional ones (their keys are
folded from the slot's key, and a field left at its default draws nothing), so today's presets randomise
bit for bit as before.

With a robot-parameters file (``RobotEnvConfig.robot_params``) the env's model holds the identified values
and the additive draws (friction, damping, payload mass) are centred on them: the model's value plus
``U(lo, hi) - (lo + hi) / 2``, at least 0; the file's joints keep its armature (no motor-range draw); a
payload the file places keeps its centre. ``nominal_share`` draws that share of the slots as the nominal
robot (friction and link mass mapped onto the default ranges, the robust additions off).

``factor_share`` turns each robust factor on independently, per slot and factor (``MODEL_FACTORS``), with
that probability; a factor that is off takes the nominal slot's value. The env's per-episode actuator
draws (``episode_draws``: latency, encoder offset, strength, observation latency) apply the same share per
episode and factor (``EPISODE_FACTORS``), a factor that is off drawn as the default ``ActuatorConfig``
draws it. Both fold their own constant into the key, and a share of 1 (the default) draws nothing.
"""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from mujoco import mjx

from bar_policy.envs.robot_config import ActuatorConfig, RobotEnvConfig
from bar_policy.robot.actuators import ROBSTRIDE_MODELS
from bar_policy.robot.constants import load_robot
from bar_policy.robot.index import RobotIndex, model_names
from bar_policy.robot.params import HANDS, load_params
from bar_policy.robot.perturb import HAND_BODIES, PAYLOAD_POS, PAYLOAD_RADIUS, payload_body_name
from bar_policy.robot.scene import SceneEdit

__all__ = [
    "EPISODE_FACTORS",
    "MODEL_FACTORS",
    "armature_bounds",
    "episode_draws",
    "factors_on",
    "latency_buffers",
    "make_randomizer",
    "payload_body_ids",
    "payload_inertia",
    "payload_scene",
]

_OPTIONAL_KEY = 0x524F42
"""Folded into each slot's key for the optional draws (damping, armature scale, payload), so the draws of
the default fields keep their keys."""


def payload_scene(scene: SceneEdit | None = None, skip: tuple[str, ...] = ()) -> SceneEdit:
    """The scene edit that runs ``scene`` (a task's additions, or None), then adds a payload body per hand.

    Each payload body (``perturb.payload_body_name(hand)``) is a child of its hand at the fingertip site
    (``perturb.PAYLOAD_POS["fingertip"]``), with zero mass and inertia and no geom and no joint: it changes
    nothing until the randomiser gives it a mass (a massless body welded to its parent adds nothing to the
    composite rigid body). ``skip``: hands (``HAND_BODIES`` names) that ``scene`` gave a payload body
    already (a robot-parameters file's, ``robot.params.scene_edit``).
    """

    def edit(spec: mujoco.MjSpec) -> None:
        if scene is not None:
            scene(spec)
        for hand in HAND_BODIES:
            if hand in skip:
                continue
            body = spec.body(hand).add_body(name=payload_body_name(hand), pos=PAYLOAD_POS["fingertip"][hand])
            body.explicitinertial = True
            body.mass = 0.0
            body.ipos = [0.0, 0.0, 0.0]
            body.inertia = [0.0, 0.0, 0.0]

    return edit


def payload_body_ids(model: mujoco.MjModel | mjx.Model, field: str) -> np.ndarray:
    """The payload bodies' ids (``perturb.payload_body_name`` of each of ``HAND_BODIES``), shape (2,) int.

    ``field``: the ``randomization`` field that needs them, named in the error.

    Raises:
        ValueError: the model has no payload bodies (``payload_scene`` adds them).
    """
    bodies = model_names(model, model.name_bodyadr)
    names = [payload_body_name(h) for h in HAND_BODIES]
    missing = [n for n in names if n not in bodies]
    if missing:
        raise ValueError(
            f"randomization.{field} needs the payload bodies {missing} in the model "
            "(randomize.payload_scene; the robot env adds them when payload_kg is set)"
        )
    return np.array([bodies.index(n) for n in names])


def payload_inertia(mass: jax.Array) -> jax.Array:
    """Principal inertia of a payload of ``mass`` kg (any shape S), kg*m^2, shape S + (3,).

    A solid sphere of ``PAYLOAD_RADIUS``, ``2/5 m r^2`` on each axis, as the deploy side's
    ``perturb.apply_to_spec`` gives it.
    """
    i = 0.4 * mass * PAYLOAD_RADIUS**2
    return jnp.stack([i, i, i], axis=-1)


_NOMINAL_KEY = 0x4E4F4D
"""Folded into each slot's key for its nominal-slot draw (``nominal_share``)."""

_FACTOR_KEY = 0x464143
"""Folded into each slot's key (and an episode's reset key) for the per-factor draws (``factor_share``)."""

MODEL_FACTORS = ("frictionloss", "link_mass_scale", "damping", "armature_scale", "payload_kg")
"""The model's robust factors, in the order of a slot's ``factor_share`` draws."""


def factors_on(key: jax.Array, share: float, n: int) -> jax.Array | None:
    """Whether each of ``n`` factors is on: Bernoulli(``share``) each, independent, shape (n,) bool.

    ``key`` is the slot's (or the episode's) own; the draw uses ``fold_in(key, _FACTOR_KEY)``, so no other
    draw's key changes. ``share`` 1 (``factor_share``'s default): every factor on, nothing drawn (None).
    """
    if share >= 1.0:
        return None
    return jax.random.bernoulli(jax.random.fold_in(key, _FACTOR_KEY), share, (n,))


EPISODE_FACTORS = ("strength", "latency_steps", "obs_latency_steps", "encoder_offset")
"""The actuator's robust factors (``ActuatorConfig`` fields), in the order of an episode's ``factor_share``
draws."""

_DEFAULT_ACTUATOR = ActuatorConfig()
"""The default actuator config: an episode factor that is off takes its draw (``episode_draws``)."""


def latency_buffers(act: ActuatorConfig, factor_share: float) -> tuple[int, int]:
    """The longest action and observation latency a reset can draw, control steps.

    The config's, and with ``factor_share`` below 1 at least the default config's (a factor that is off
    draws in the default's range).
    """
    lat_hi, obs_hi = act.latency_steps[1], act.obs_latency_steps[1]
    if factor_share < 1.0:
        lat_hi = max(lat_hi, _DEFAULT_ACTUATOR.latency_steps[1])
        obs_hi = max(obs_hi, _DEFAULT_ACTUATOR.obs_latency_steps[1])
    return lat_hi, obs_hi


def episode_draws(
    act: ActuatorConfig, factor_share: float, ks: jax.Array, n: int, strength: np.ndarray | None
) -> dict[str, jax.Array]:
    """An episode's actuator draws (``LiteRobotEnv._reset``) from its reset keys ``ks`` (shape (8, 2)).

    Returns ``latency`` (action latency, control steps, int32 scalar; key 2), ``encoder_offset`` (rad,
    shape (n,); key 5), and ``strength`` (x, shape (n,); the config's draw from ``fold_in(key 3)`` times
    ``strength``, the identified strengths, when the config draws one, else ``strength`` when given) and
    ``obs_latency`` (control steps; ``fold_in(key 2)``) when ``latency_buffers`` has room for one.

    ``factor_share`` below 1: each of ``EPISODE_FACTORS`` is on with that probability (``factors_on``,
    from key 5); one that is off takes the default ``ActuatorConfig``'s draw from the same key (strength
    1, no observation latency, action latency in (0, 2), encoder offset in U(-0.01, 0.01) rad, the same
    uniform mapped onto it). 1: every factor as the config draws it, nothing else drawn.
    """
    d = _DEFAULT_ACTUATOR
    on = factors_on(ks[5], factor_share, len(EPISODE_FACTORS))

    def pick(field: str, draw: Callable[[ActuatorConfig], jax.Array]) -> jax.Array:
        """The config's draw, or (``field``'s factor off) the default config's; one draw when they agree."""
        value = draw(act)
        if on is None or getattr(act, field) == getattr(d, field):
            return value
        return jnp.where(on[EPISODE_FACTORS.index(field)], value, draw(d))

    def latency(a: ActuatorConfig) -> jax.Array:
        return jax.random.randint(ks[2], (), a.latency_steps[0], a.latency_steps[1] + 1)

    def offset(a: ActuatorConfig) -> jax.Array:
        return jax.random.uniform(ks[5], (n,), minval=-a.encoder_offset, maxval=a.encoder_offset)

    def scale(a: ActuatorConfig) -> jax.Array:
        k = jax.random.fold_in(ks[3], _OPTIONAL_KEY)
        return (1.0 if strength is None else strength) * jax.random.uniform(
            k, (n,), minval=a.strength[0], maxval=a.strength[1]
        )

    def obs_latency(a: ActuatorConfig) -> jax.Array:
        k = jax.random.fold_in(ks[2], _OPTIONAL_KEY)
        return jax.random.randint(k, (), a.obs_latency_steps[0], a.obs_latency_steps[1] + 1)

    out = {"latency": pick("latency_steps", latency), "encoder_offset": pick("encoder_offset", offset)}
    if act.strength != (1.0, 1.0):
        out["strength"] = pick("strength", scale)
    elif strength is not None:
        out["strength"] = jnp.asarray(strength)  # the identified strengths, not drawn
    if latency_buffers(act, factor_share)[1] > 0:
        out["obs_latency"] = pick("obs_latency_steps", obs_latency)
    return out


def _nominal_factors(nom: jax.Array | None, on: jax.Array | None) -> dict[str, jax.Array | None]:
    """Per ``MODEL_FACTORS`` name: whether the slot takes that factor's nominal value (None: never).

    A nominal slot (``nom``) takes every one; otherwise a factor drawn off (``on``, ``factors_on``).
    """
    if on is None:
        return dict.fromkeys(MODEL_FACTORS, nom)
    return {f: ~on[i] if nom is None else nom | ~on[i] for i, f in enumerate(MODEL_FACTORS)}


DEFAULT_FRICTION = (0.05, 0.35)
"""The default friction range, N*m (``ModelRandomizationConfig.frictionloss``): a nominal slot's."""
DEFAULT_MASS_SCALE = (0.9, 1.1)
"""The default link-mass range, x (``ModelRandomizationConfig.link_mass_scale``): a nominal slot's."""


def _remap(x: jax.Array, lo: float, hi: float, to: tuple[float, float]) -> jax.Array:
    """``x`` drawn in U(lo, hi) mapped affinely onto U(to): the same draw in the other range."""
    if hi <= lo:
        return jnp.full_like(x, (to[0] + to[1]) / 2)
    return to[0] + (x - lo) * ((to[1] - to[0]) / (hi - lo))


Randomizer = Callable[[mjx.Model, jax.Array], tuple[mjx.Model, mjx.Model]]


def armature_bounds(mode: str) -> tuple[np.ndarray, np.ndarray]:
    """Per-joint armature range ``(description, identified)``, kg*m^2, shape (n,) each.

    The identified value is the motor model's ``armature_identified`` (robstride-protocol.md section 8:
    rs-00 0.0149, rs-02 0.01369, rs-05 0.00678); a model without an identification keeps its description
    value (zero-width range). The range is ordered (low <= high) whichever is larger.
    """
    robot = load_robot(mode)
    desc = robot.armature
    ident = np.array(
        [ROBSTRIDE_MODELS[m].armature_identified or d for m, d in zip(robot.models, desc, strict=True)]
    )
    return np.minimum(desc, ident), np.maximum(desc, ident)


def make_randomizer(config: RobotEnvConfig) -> Randomizer:
    """The randomiser for any task's ``config`` (its ``randomization`` field and ``mode``).

    Returns:
        ``domain_randomize(model, rng)``: ``rng`` is a batch of keys, shape ``(B, 2)``; returns the model
        with the randomised fields given a leading axis B, and the matching ``in_axes`` tree.
    """
    rc = config.randomization
    arm_lo, arm_hi = (x.astype(np.float32) for x in armature_bounds(config.mode))
    robot = load_robot(config.mode)
    joint_names = robot.joint_names
    # With a robot-parameters file the model holds the identified values (the env's scene edit) and the
    # additive draws are centred on them; its listed joints' armature is the file's, not drawn.
    params = None if config.robot_params is None else load_params(config.robot_params, robot)
    centred = params is not None
    from_file = np.zeros(len(HAND_BODIES), bool)
    if params is not None:
        for name, jp in params.joints.items():
            i = joint_names.index(name)
            arm_lo[i] = arm_hi[i] = np.float32(jp.armature.value)
        placed = {HANDS[k] for k, pay in params.payload.items() if pay.mass_kg.value > 0}
        from_file = np.array([h in placed for h in HAND_BODIES])
    tip = np.array([PAYLOAD_POS["fingertip"][h] for h in HAND_BODIES], dtype=np.float32)
    palm = np.array([PAYLOAD_POS["palm"][h] for h in HAND_BODIES], dtype=np.float32)

    def domain_randomize(model: mjx.Model, rng: jax.Array) -> tuple[mjx.Model, mjx.Model]:
        if rng.ndim != 2 or rng.shape[-1] != 2:
            raise ValueError(f"rng must be a batch of keys, shape (B, 2); got shape {rng.shape}")
        index = RobotIndex.from_model(model, joint_names)
        payload_ids = None if rc.payload_kg is None else payload_body_ids(model, "payload_kg")

        def robot_dofs(field: jax.Array, values: jax.Array) -> jax.Array:
            """``field`` (nv,) with ``values`` (n,) at the robot's dofs (``values`` itself, robot alone)."""
            return values if index.robot_only else field.at[index.dof].set(values)

        def one(key: jax.Array) -> dict[str, jax.Array]:
            k_arm, k_fric, k_mass = jax.random.split(key, 3)
            out = {}
            # A nominal slot (``nominal_share``): default ranges for friction and mass, no robust addition.
            nom = (
                jax.random.bernoulli(jax.random.fold_in(key, _NOMINAL_KEY), rc.nominal_share)
                if rc.nominal_share > 0
                else None
            )
            # Each robust factor on with probability ``factor_share``, else as in a nominal slot.
            nominal = _nominal_factors(nom, factors_on(key, rc.factor_share, len(MODEL_FACTORS)))
            if rc.armature:
                # Armature: U(description, identified) per joint (up to 7.4x for rs-00).
                arm = jax.random.uniform(k_arm, arm_lo.shape, minval=arm_lo, maxval=arm_hi)
                out["dof_armature"] = robot_dofs(model.dof_armature, arm)
            if rc.frictionloss is not None:
                # Joint Coulomb friction: U(frictionloss) per joint, N*m (MJCF 0.1, identified 0.16-0.31).
                lo, hi = rc.frictionloss
                fric = jax.random.uniform(k_fric, (index.num_joints,), minval=lo, maxval=hi)
                if centred:  # the file's friction + U(lo, hi) - (lo + hi) / 2, at least 0
                    fric = jnp.maximum(index.dq(model.dof_frictionloss) + fric - (lo + hi) / 2, 0.0)
                off = nominal["frictionloss"]
                if off is not None:
                    base = (
                        index.dq(model.dof_frictionloss)
                        if centred
                        else _remap(fric, lo, hi, DEFAULT_FRICTION)
                    )
                    fric = jnp.where(off, base, fric)
                out["dof_frictionloss"] = robot_dofs(model.dof_frictionloss, fric)
            if rc.link_mass_scale is not None:
                # Link mass and inertia: *U(link_mass_scale) per body (same factor: density scaling).
                lo, hi = rc.link_mass_scale
                s = jax.random.uniform(k_mass, model.body_mass.shape, minval=lo, maxval=hi)
                off = nominal["link_mass_scale"]
                if off is not None:
                    s = jnp.where(off, _remap(s, lo, hi, DEFAULT_MASS_SCALE), s)
                out["body_mass"] = model.body_mass * s
                out["body_inertia"] = model.body_inertia * s[:, None]
            k_damp, k_ascale, k_pay, k_site = jax.random.split(jax.random.fold_in(key, _OPTIONAL_KEY), 4)
            if rc.damping is not None:
                # Added passive damping: MJCF dof_damping + U(damping) per joint, N*m*s/rad.
                lo, hi = rc.damping
                d = jax.random.uniform(k_damp, (index.num_joints,), minval=lo, maxval=hi)
                total = index.dq(model.dof_damping) + d
                if centred:  # the file's damping + U(lo, hi) - (lo + hi) / 2, at least 0
                    total = jnp.maximum(total - (lo + hi) / 2, 0.0)
                off = nominal["damping"]
                if off is not None:
                    total = jnp.where(off, index.dq(model.dof_damping), total)
                out["dof_damping"] = robot_dofs(model.dof_damping, total)
            if rc.armature_scale is not None:
                # Armature x U(armature_scale) per joint, on the drawn armature when that is randomised.
                lo, hi = rc.armature_scale
                a = jax.random.uniform(k_ascale, (index.num_joints,), minval=lo, maxval=hi)
                off = nominal["armature_scale"]
                if off is not None:
                    a = jnp.where(off, 1.0, a)
                base = out.get("dof_armature", model.dof_armature)
                out["dof_armature"] = robot_dofs(base, index.dq(base) * a)
            if payload_ids is not None:
                # Payload: U(payload_kg) per hand, a 1 cm sphere's inertia, at the fingertip or the palm.
                lo, hi = rc.payload_kg
                m = jax.random.uniform(k_pay, (len(HAND_BODIES),), minval=lo, maxval=hi)
                if centred:  # the file's payload (0 for a hand it gives none) + U(lo, hi) - (lo + hi) / 2
                    m = jnp.maximum(model.body_mass[payload_ids] + m - (lo + hi) / 2, 0.0)
                off = nominal["payload_kg"]
                if off is not None:
                    m = jnp.where(off, model.body_mass[payload_ids], m)  # none (or the file's)
                mass = out.get("body_mass", model.body_mass)
                inertia = out.get("body_inertia", model.body_inertia)
                out["body_mass"] = mass.at[payload_ids].set(m)
                out["body_inertia"] = inertia.at[payload_ids].set(payload_inertia(m))
                if rc.payload_at != "fingertip":
                    at_palm = (
                        jax.random.bernoulli(k_site, 0.5, (len(HAND_BODIES),))
                        if rc.payload_at == "either"
                        else jnp.ones(len(HAND_BODIES), bool)
                    )
                    pos = jnp.where(at_palm[:, None], palm, tip)
                    # A payload the file placed keeps its identified centre.
                    pos = jnp.where(from_file[:, None], model.body_pos[payload_ids], pos)
                    out["body_pos"] = model.body_pos.at[payload_ids].set(pos)
            return out

        fields = jax.vmap(one)(rng)
        in_axes = jax.tree.map(lambda _: None, model)
        in_axes = in_axes.tree_replace(dict.fromkeys(fields, 0))
        return model.tree_replace(fields), in_axes

    return domain_randomize
