"""Safety and smoothness in the MJX evaluation: ``bar_policy.quality``'s definitions on device.

The evaluation (``brax.evaluation.evaluate``) runs one deterministic episode per env slot. Per tick, each
slot's ``quality_signals`` (the env's: unclipped torque demand of the command it applies, true q, applied
action, chatter signal) feed the same functions the deploy side uses (``at_cap``, ``near_limit``,
``cap_dwell_step``, ``action_rate``, ``chatter_mrad``):

- an episode **faults** when the task ends it (a lost reference, a non-finite state: not the time limit)
  or when a joint stays at its torque cap for more than ``CAP_DWELL_S`` without a break (the deploy
  supervisor's rule, which the env itself does not apply); a fault ends its counting, as on the robot;
- ticks count while the episode is alive (up to and including its end);
- chatter is measured on the episodes that completed, over the whole episode.

``finish`` reduces over the mesh (``psum``/``pmax``), so the figures are global: the ``summarise`` keys of
``bar_policy.quality.report`` under ``quality/<key>``.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from bar_policy.quality import metrics as qm
from bar_policy.training.parallel import AXIS

__all__ = ["QualityCarry", "finish", "init", "update"]

QualityCarry = dict
"""``{"dwell", "faulted", "ticks", "cap", "limit", "rate", "prev"}`` per slot (leading axis = slots)."""


def init(num_slots: int, n: int) -> QualityCarry:
    """Zero counts for ``num_slots`` episodes of ``n`` joints."""
    z = jnp.zeros(num_slots)
    return {
        "dwell": jnp.zeros((num_slots, n)),
        "faulted": z,
        "ticks": z,
        "cap": z,
        "limit": z,
        "rate": z,
        "prev": jnp.zeros((num_slots, n)),
    }


def update(
    c: QualityCarry,
    sig: dict[str, jax.Array],
    alive: jax.Array,
    terminated: jax.Array,
    first: bool | jax.Array,
    *,
    cap: jax.Array,
    lower: jax.Array,
    upper: jax.Array,
    dt: float,
) -> tuple[QualityCarry, jax.Array]:
    """Count one tick of every slot.

    Args:
        c: the counts so far.
        sig: the env's ``quality_signals`` for every slot (leaves (slots, n)).
        alive: 1 for slots whose episode had not ended before this tick, (slots,).
        terminated: 1 for slots the task ended on this tick (not by the time limit), (slots,).
        first: whether this is the episode's first tick (no action rate yet).
        cap: torque caps, N*m, (n,).
        lower: lower joint limits, rad, (n,).
        upper: upper joint limits, rad, (n,).
        dt: tick, s.

    Returns:
        ``(counts, alive after this tick)``: a slot stops counting after a termination or a cap fault.
    """
    live = alive * (1.0 - c["faulted"])
    hit = qm.at_cap(sig["demand"], cap)
    dwell = qm.cap_dwell_step(c["dwell"], hit, dt)
    cap_fault = jnp.any(qm.dwell_exceeded(dwell), axis=-1).astype(jnp.float32)
    rate = qm.action_rate(jnp.stack([c["prev"], sig["action"]]))[0]
    out = {
        "dwell": dwell,
        "faulted": jnp.maximum(c["faulted"], live * jnp.maximum(cap_fault, terminated)),
        "ticks": c["ticks"] + live,
        "cap": c["cap"] + live * jnp.any(hit, axis=-1),
        "limit": c["limit"] + live * jnp.any(qm.near_limit(sig["q"], lower, upper), axis=-1),
        "rate": c["rate"] + jnp.where(first, 0.0, live * rate),
        "prev": sig["action"],
    }
    return out, live


def finish(c: QualityCarry, signals: jax.Array, dt: float) -> dict[str, jax.Array]:
    """Global figures of the episodes (``quality/<summarise key>``), reduced over the mesh.

    Args:
        c: the counts after the last tick.
        signals: every tick's chatter signal, (T, slots, n).
        dt: tick, s.
    """
    psum = lambda x: jax.lax.psum(jnp.sum(x), AXIS)  # noqa: E731
    done = 1.0 - c["faulted"]
    chatter = qm.chatter_mrad(signals, dt)  # (slots,)
    measured = done * jnp.isfinite(chatter)
    chatter = jnp.where(measured > 0, chatter, 0.0)
    episodes = psum(jnp.ones_like(done))
    ticks = jnp.maximum(psum(c["ticks"]), 1.0)
    rate_ticks = jnp.maximum(psum(jnp.maximum(c["ticks"] - 1.0, 0.0)), 1.0)
    n_measured = psum(measured)
    return {
        "quality/episodes": episodes,
        "quality/completed": psum(done),
        "quality/completion_pct": 100.0 * psum(done) / episodes,
        "quality/cap_share_pct": 100.0 * psum(c["cap"]) / ticks,
        "quality/limit_share_pct": 100.0 * psum(c["limit"]) / ticks,
        "quality/action_rate": psum(c["rate"]) / rate_ticks,
        "quality/chatter_max_mrad": jnp.where(n_measured > 0, jax.lax.pmax(jnp.max(chatter), AXIS), jnp.nan),
        "quality/chatter_mean_mrad": jnp.where(n_measured > 0, psum(chatter) / n_measured, jnp.nan),
        "quality/chatter_unmeasured": episodes - n_measured,
    }
