"""The action prior a run's config names, resolved for the env it trains on (both backends).

``network.action_prior`` is ``none`` or the name of the prior the env serves (``EnvEntry.action_prior`` in
its task record; ``obs.action_prior`` has the priors themselves). ``action_prior`` refuses any other name,
before anything is traced, and builds the env's prior ``prior_lead_steps`` ahead. The brax backend hands it to
its networks (``brax.programs.set_up``), the rsl-rl backend to its envs (``rsl_rl.programs.prepare_rsl_rl``).
"""

from __future__ import annotations

from typing import Any

from bar_policy.obs.action_prior import Prior
from bar_policy.tasks.registry import env_entries
from bar_policy.training.config import NetworkConfig

__all__ = ["action_prior"]


def action_prior(env: Any, net: NetworkConfig, env_name: str) -> Prior | None:
    """The env's action prior that ``net.action_prior`` asks for (``LiteRobotEnv.action_prior``), or None.

    ``env_name`` is the env's registered name: its task record's ``EnvEntry.action_prior`` names the prior
    it serves.
    """
    if net.action_prior == "none":
        return None
    kind = env_entries()[env_name][1].action_prior
    if net.action_prior != kind:
        valid = ["none"] + ([kind] if kind else [])
        raise ValueError(
            f"network.action_prior={net.action_prior!r}: {type(env).__name__} has "
            f"{'the ' + repr(kind) + ' prior' if kind else 'no action prior'}; valid values for it: {valid}"
        )
    return env.action_prior(net.prior_lead_steps, net.prior_error_gain)
