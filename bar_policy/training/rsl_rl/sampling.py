"""rsl-rl's Gaussian action head, sampled without a host-device sync (the rollout's actions).

rsl-rl's ``GaussianDistribution.sample`` is ``torch.distributions.Normal(mean, std).sample()``, which is
``torch.normal(mean, std)`` with a tensor std; on CUDA that checks ``std >= 0`` on the host, a
``cudaStreamSynchronize`` per rollout step. In our rollout the step before it is the MJX env step, so the
host waited for each env step to finish before it could queue the next one, and the device sat idle while
the host dispatched it: 8-9 ms per control step of the tracker (8192 envs: 36 ms a step against 29 ms for the
env alone; docs/performance.md, 2026-11-29, ``bench/rsl_rl_profile.py`` counts the syncs).

``GaussianNoSync`` is rsl-rl's ``GaussianDistribution`` with that one method replaced: the same draw,
``mean + std * z`` with ``z ~ N(0, 1)`` of the broadcast shape from the same generator, which is what
``torch.normal(mean, std)`` computes (bit for bit on CPU: ``tests/training/test_rsl_rl_sampling.py``). Its std
is a clamped parameter (``std_range[0] >= 1e-6``), so the check it skips cannot fail. Parameters, state-dict
keys, log-probabilities, entropy and KL are rsl-rl's own; checkpoints of either load into the other.
``rsl_rl.config.rsl_rl_train_cfg`` names it as the actor's ``distribution_cfg`` class.
"""

from __future__ import annotations

import torch
from rsl_rl.modules import GaussianDistribution

__all__ = ["GaussianNoSync"]


class GaussianNoSync(GaussianDistribution):
    """rsl-rl's state-independent Gaussian head whose ``sample`` never waits for the device."""

    def sample(self) -> torch.Tensor:
        """One action per row, shape broadcast(mean, std) = (num_envs, num_actions): ``mean + std * z``."""
        d = self._distribution
        if d is None:
            raise RuntimeError("GaussianNoSync.sample before update(mlp_output): no distribution yet")
        shape = torch.broadcast_shapes(d.loc.shape, d.scale.shape)
        with torch.no_grad():
            z = torch.randn(shape, dtype=d.loc.dtype, device=d.loc.device)
            return z * d.scale + d.loc
