"""``ppo.update_precision`` on the rsl-rl backend: torch's float32 matmul precision around the update.

The brax backend traces its SGD passes under ``jax.default_matmul_precision`` (``Learner.sgd_pass``); the
rollout's policy, the physics and the evaluations keep float32. Here ``update_precision(setting)`` does the
same for torch: it sets the precision of CUDA float32 matrix products for the span of ``alg.update()``
alone and restores the one before, so the rollout's actor still acts in IEEE float32.

- ``run``: nothing changes (torch's own default, IEEE float32, unless the user changed it).
- ``tensorfloat32``: ``torch.backends.cuda.matmul.fp32_precision = "tf32"`` (TF32 tensor cores, XLA's
  ``tensorfloat32``; the API of every torch the project pins, >= 2.11).
- ``BF16_BF16_F32_X3``: torch has no three-pass bfloat16 product, so it is not applied
  (``rsl_rl.config.not_applied`` says so).

CPU products are float32 either way (the setting is CUDA's).
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator

import torch

__all__ = ["update_precision"]


@contextlib.contextmanager
def update_precision(setting: str) -> Iterator[None]:
    """CUDA float32 matmuls at ``setting`` inside the block; the previous setting after it, raised or not.

    ``run`` and the settings torch lacks (``rsl_rl.config.not_applied`` says which) change nothing.
    """
    if setting != "tensorfloat32":
        yield
        return
    matmul = torch.backends.cuda.matmul
    before = matmul.fp32_precision
    matmul.fp32_precision = "tf32"
    try:
        yield
    finally:
        matmul.fp32_precision = before
