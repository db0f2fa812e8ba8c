"""``ppo.update_precision`` on the rsl-rl backend: torch's float32 matmul precision around the update.

The brax backend traces its SGD passes under ``jax.default_matmul_precision`` (``Learner.sgd_pass``); the
rollout's policy, the physics and the evaluations keep float32. Here ``update_precision(setting)`` does the
same for torch: it sets the precision of CUDA float32 matrix products for the span of ``alg.update()``
alone and restores the one before, so the rollout's actor still acts in IEEE float32.

- ``run``: nothing changes (torch's own default, IEEE float32, unless the user changed it).
- ``tensorfloat32``: ``torch.backends.cuda.matmul.fp32_precision = "tf32"`` (TF32 tensor cores, XLA's
  ``tensorfloat32``; torch >= 2.9's API, the legacy ``allow_tf32`` flag before it).
- ``BF16_BF16_F32_X3``: torch has no three-pass bfloat16 product, so it is not applied
  (``rsl_rl_config.not_applied`` says so).

CPU products are float32 either way (the setting is CUDA's).
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator

import torch

from bar_policy.training.rsl_rl_config import TORCH_PRECISIONS

__all__ = ["TORCH_PRECISIONS", "update_precision"]


@contextlib.contextmanager
def update_precision(setting: str) -> Iterator[None]:
    """CUDA float32 matmuls at ``setting`` inside the block; the previous setting after it, raised or not.

    Settings outside ``TORCH_PRECISIONS`` change nothing (the run has said they are not applied).
    """
    if setting != "tensorfloat32":
        yield
        return
    matmul = torch.backends.cuda.matmul
    new_api = hasattr(matmul, "fp32_precision")
    before = matmul.fp32_precision if new_api else matmul.allow_tf32
    if new_api:
        matmul.fp32_precision = "tf32"
    else:  # pragma: no cover - torch < 2.9
        matmul.allow_tf32 = True
    try:
        yield
    finally:
        if new_api:
            matmul.fp32_precision = before
        else:  # pragma: no cover - torch < 2.9
            matmul.allow_tf32 = before
