"""The parity gate of ``export.policy``: onnxruntime against the training framework's own inference.

``parity_observations`` (k = 1, 4, 8 sigma) are checked at ``k * PARITY_TOLERANCE``,
``extreme_observations`` (anywhere in +-100 raw) at ``EXTREME_TOLERANCE``; ``check_parity`` raises
``ParityError`` on a mismatch. ``export.policy`` gives the reasons for both tolerances' values.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from bar_policy.export.graph import MlpPolicy

__all__ = [
    "EXTREME_TOLERANCE",
    "PARITY_TOLERANCE",
    "ParityError",
    "check_parity",
    "extreme_observations",
    "parity_observations",
    "parity_sigmas",
]

PARITY_TOLERANCE = 1e-5
"""Max abs difference allowed between onnxruntime and the training framework, action units.

Both run the MLP in float32 but sum each dot product in their own order: a dot product of ``n`` terms then
differs by about ``sqrt(n) * eps32 * sum|w_i x_i|`` (rounding errors of a reordered sum add like a random
walk). With ``n <= 256`` and ``sum|w_i x_i| <= 5`` on normalised observations that is ``16 * 1.2e-7 * 5 =
1e-5`` per layer before the output's tanh (slope <= 1), whose error the next layer's weights scale down
again in trained networks (measured: 3.4e-6 for the shipped reach policy, 7.0e-6 for the tracker, in
checkpoints/*.json).

That is for observations at one standard deviation. The rounding error grows in proportion to the size of
the inputs (every pre-activation scales with them), so a row at k sigma (``parity_observations``) is
allowed ``k * PARITY_TOLERANCE``. Measured against float64 on the shipped tracker: 0.8e-6 at 1 sigma,
3.3e-6 at 4 and 6.4e-6 at 8 (linear in k); a tracker trained for 60 M steps reached 1.47e-5 at 8 sigma,
which a flat 1e-5 refused."""

EXTREME_TOLERANCE = 1e-3
"""Max abs difference allowed anywhere in the clip bound (+-100 raw), see ``extreme_observations``."""


class ParityError(RuntimeError):
    """The exported graph does not reproduce the training framework's policy."""


# ----------------------------------------------------------------------------------------------------------
# Parity gate
# ----------------------------------------------------------------------------------------------------------


def parity_sigmas(n: int) -> np.ndarray:
    """The k of each row of ``parity_observations(policy, n)``: 1 for the first half, then 4, then 8."""
    k = np.ones(n)
    k[n // 2 :] = 4.0
    k[3 * n // 4 :] = 8.0
    return k


def parity_observations(policy: MlpPolicy, n: int = 4096, seed: int = 0) -> np.ndarray:
    """Fresh test observations for the gate, shape (n, obs), float32: ``mean + k * std * normal``.

    Half at k = 1 (what the policy sees in training), a quarter at k = 4 and a quarter at k = 8 (large
    outliers, 8 standard deviations out on every entry at once); ``parity_sigmas`` gives each row's k.
    """
    rng = np.random.default_rng(seed)
    d = policy.obs_size
    k = parity_sigmas(n)
    mean, std = policy.obs_mean.astype(np.float64), policy.obs_std.astype(np.float64)
    return (mean + k[:, None] * std * rng.standard_normal((n, d))).astype(np.float32)


def extreme_observations(policy: MlpPolicy, n: int = 512, seed: int = 1) -> np.ndarray:
    """Observations anywhere inside the schema's clip bound: uniform in +-100 raw units, shape (n, obs).

    These sit up to thousands of standard deviations out, where float32 rounding alone (XLA and MLAS sum
    the matmuls in different orders) separates two correct implementations by ~1e-5 per 100 sigma; the gate
    checks them at ``EXTREME_TOLERANCE``, which still catches any wrong weight, activation or normaliser.
    """
    rng = np.random.default_rng(seed)
    return rng.uniform(-100.0, 100.0, (n, policy.obs_size)).astype(np.float32)


def _run_onnx(model_bytes: bytes, obs: np.ndarray) -> np.ndarray:
    import onnxruntime as ort

    options = ort.SessionOptions()
    options.log_severity_level = 3
    sess = ort.InferenceSession(model_bytes, options, providers=["CPUExecutionProvider"])
    return sess.run(["actions"], {"obs": obs})[0]


def check_parity(
    model_bytes: bytes,
    reference_fn: Callable[[np.ndarray], np.ndarray],
    obs: np.ndarray,
    tolerance: float = PARITY_TOLERANCE,
    row_scale: np.ndarray | None = None,
) -> float:
    """Compare onnxruntime with the framework's inference on ``obs``; raise ``ParityError`` on a mismatch.

    Args:
        model_bytes: serialised ONNX model.
        reference_fn: framework policy, (n, obs) float32 -> (n, A).
        obs: test observations, shape (n, obs), float32.
        tolerance: max abs difference allowed (per unit of ``row_scale``).
        row_scale: per-row multiplier of the tolerance, shape (n,) (the rows' sigmas); None: 1.

    Returns:
        The max abs difference (each row within its tolerance).
    """
    got = _run_onnx(model_bytes, obs)
    want = np.asarray(reference_fn(obs), dtype=np.float32)
    if got.shape != want.shape:
        raise ParityError(f"ONNX output shape {got.shape} != reference shape {want.shape}")
    if not np.all(np.isfinite(got)):
        raise ParityError("ONNX output contains non-finite values")
    diff = np.max(np.abs(got.astype(np.float64) - want.astype(np.float64)), axis=-1)
    scale = np.ones(len(diff)) if row_scale is None else np.asarray(row_scale, dtype=np.float64)
    excess = diff / (tolerance * scale)
    if not np.all(excess <= 1.0):
        row = int(np.argmax(np.where(np.isnan(excess), np.inf, excess)))
        raise ParityError(
            f"ONNX policy differs from the training framework by {diff[row]:.3g} (> "
            f"{tolerance * scale[row]:g}) on row {row} of {obs.shape[0]} observations; nothing was written"
        )
    return float(np.max(diff))
