"""The ``rsl_rl.*`` settings a brax run leaves unused, one line each, said and recorded by the trainer.

``rsl_rl.config.not_applied`` is the counterpart: the brax settings an rsl-rl run leaves unused.
"""

from __future__ import annotations

import dataclasses

from bar_policy.training.config import RslRlConfig, TrainConfig

__all__ = ["brax_not_applied"]

_BRAX_SIDE = {"schedule": "schedule", "desired_kl": "desired_kl", "value_loss_coef": "vf_loss_coefficient"}
"""``RslRlConfig`` field -> the ``PPOConfig`` field a brax run reads for the same choice."""

_BRAX_HAS_NONE = {
    "clipped_value_loss": "brax's value loss is never clipped",
    "device": "the brax backend runs on jax's devices",
}
"""``RslRlConfig`` field with no ``PPOConfig`` counterpart -> what a brax run does instead (a field in neither
map, added later, gets ``_BRAX_IGNORES``: still said, never a KeyError in the brax trainer)."""

_BRAX_IGNORES = "the brax backend does not read it"


def brax_not_applied(cfg: TrainConfig) -> list[str]:
    """A line per ``rsl_rl.*`` setting a brax run leaves unused (``not_applied``'s counterpart).

    Only where it differs from ``RslRlConfig``'s default: at the default nobody asked for it (the field's
    values keep the defaults and set the brax side, ``field_overrides``). The brax trainer prints and
    records them.
    """
    if cfg.backend != "brax":
        return []
    out, default = [], RslRlConfig()
    for f in dataclasses.fields(RslRlConfig):
        value = getattr(cfg.rsl_rl, f.name)
        if value == getattr(default, f.name):
            continue
        brax = _BRAX_SIDE.get(f.name)
        ours = (
            f"the brax backend's is ppo.{brax}={getattr(cfg.ppo, brax)}"
            if brax
            else _BRAX_HAS_NONE.get(f.name, _BRAX_IGNORES)
        )
        out.append(f"rsl_rl.{f.name}={value} not applied: an rsl-rl backend setting; {ours}")
    return out
