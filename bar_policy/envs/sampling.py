"""Adaptive start sampling: episodes start more often just before the clip segments where they fail.

Pure functions over a table of bins (``StartBins``): each clip's possible start frames ``0 .. length - 2``
cut into bins of ``bin_frames``. The batched wrapper (``wrappers.BatchedEnv``) keeps per device a
``(2, B)`` array of decaying counts, row 0 the episodes that failed in each bin (ended by the task's
termination there) and row 1 the env steps spent in it (``update_counts``), and draws each reset's start
bin from ``start_probabilities`` of those counts (``tasks/track/config.py``'s ``AdaptiveSamplingConfig`` gives
the rule and its parameters). ``pack``/``unpack`` spread the counts over the env axis, so that every leaf
of the batched state keeps its leading batch axis (the trainer shards env states along it) while the
counts cost a few numbers per env instead of a copy of all of them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np

__all__ = ["StartBins", "pack", "start_probabilities", "unpack", "update_counts"]


@dataclass(frozen=True)
class StartBins:
    """The start bins of a clip table (numpy, built once; ``B`` bins in all)."""

    clip: np.ndarray
    """Clip (table order) of each bin, int32 (B,)."""
    first_phase: np.ndarray
    """First start frame of each bin within its clip, int32 (B,)."""
    num_phases: np.ndarray
    """Start frames in each bin, int32 (B,), >= 1."""
    bin_of_frame: np.ndarray
    """Bin of every frame of the concatenated table, int32 (total frames,); a clip's last frame (never a
    start) belongs to its last bin."""

    @classmethod
    def build(cls, clip_start: np.ndarray, clip_length: np.ndarray, bin_frames: int) -> StartBins:
        """Bins of ``bin_frames`` start frames over clips starting at ``clip_start`` with ``clip_length``."""
        if bin_frames < 1:
            raise ValueError(f"bin_frames must be >= 1, got {bin_frames}")
        clips, firsts, counts = [], [], []
        total = int(clip_start[-1] + clip_length[-1]) if len(clip_start) else 0
        of_frame = np.zeros(total, dtype=np.int32)
        for c, (s, n) in enumerate(zip(clip_start, clip_length, strict=True)):
            starts = max(int(n) - 1, 1)  # start frames 0 .. n - 2 (a 1-frame clip: frame 0)
            for first in range(0, starts, bin_frames):
                clips.append(c)
                firsts.append(first)
                counts.append(min(bin_frames, starts - first))
                of_frame[int(s) + first : int(s) + min(first + bin_frames, int(n))] = len(clips) - 1
        i32 = np.int32
        return cls(np.array(clips, i32), np.array(firsts, i32), np.array(counts, i32), of_frame)

    @property
    def size(self) -> int:
        """B."""
        return len(self.clip)


def update_counts(counts: jax.Array, bins: jax.Array, failed: jax.Array, decay: float) -> jax.Array:
    """One batched step: ``decay * counts`` plus this step's failures and visits per bin.

    Args:
        counts: ``(2, B)``: failures, visits.
        bins: the bin of each env's current frame, int (E,).
        failed: 1 for an env whose episode the task ended this step, (E,).
        decay: factor on the old counts.
    """
    size = counts.shape[1]
    fails = jax.ops.segment_sum(failed.astype(counts.dtype), bins, num_segments=size)
    visits = jax.ops.segment_sum(jnp.ones_like(failed, dtype=counts.dtype), bins, num_segments=size)
    return decay * counts + jnp.stack([fails, visits])


def start_probabilities(
    counts: jax.Array, clip: np.ndarray, uniform_share: float, kernel_bins: int, kernel_decay: float
) -> jax.Array:
    """Start-bin probabilities (B,) from the counts (``AdaptiveSamplingConfig``'s rule).

    ``rate_b = failures_b / max(visits_b, 1)``; ``score_b = sum_{k < kernel_bins} kernel_decay^k
    rate_{b + k}`` over bins ``b + k`` of the same clip; ``p = uniform_share / B + (1 - uniform_share) *
    score / sum(score)``, or uniform when no bin has failed.
    """
    size = counts.shape[1]
    rate = counts[0] / jnp.maximum(counts[1], 1.0)
    score = rate
    for k in range(1, kernel_bins):
        same = np.zeros(size, dtype=bool)
        same[: size - k] = clip[k:] == clip[: size - k]
        ahead = jnp.concatenate([rate[k:], jnp.zeros(k, rate.dtype)])
        score = score + (kernel_decay**k) * jnp.where(jnp.asarray(same), ahead, 0.0)
    total = jnp.sum(score)
    adaptive = jnp.where(total > 0, score / jnp.maximum(total, 1e-30), 1.0 / size)
    return uniform_share / size + (1.0 - uniform_share) * adaptive


def pack(counts: jax.Array, num_envs: int) -> jax.Array:
    """``(2, B)`` -> ``(num_envs, 2, ceil(B / num_envs))``, zero-padded (the batched state's layout)."""
    size = counts.shape[1]
    per = math.ceil(size / num_envs)
    padded = jnp.pad(counts, ((0, 0), (0, per * num_envs - size)))
    return padded.reshape(2, num_envs, per).transpose(1, 0, 2)


def unpack(packed: jax.Array, size: int) -> jax.Array:
    """Inverse of ``pack``: ``(num_envs, 2, per)`` -> ``(2, B)``."""
    return packed.transpose(1, 0, 2).reshape(2, -1)[:, :size]
