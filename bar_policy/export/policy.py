"""Trained policy -> self-describing ONNX file, gated on numerical parity with the training framework.

The graph is written directly with ``onnx.helper`` (no TF, no tracing): ``obs`` (float32, ``[batch, obs]``)
-> ``(obs - mean) / std`` (the observation normaliser, folded in) -> dense layers with the hidden activation
-> output head -> ``actions`` (float32, ``[batch, actions]``). Two heads exist:

- ``tanh_loc`` (brax's ``NormalTanhDistribution``): the policy MLP outputs ``2 * A`` numbers (loc, scale); the
  deterministic action is ``tanh(loc)`` with ``loc`` the first ``A``. Only the loc columns of the last layer
  are exported.
- ``identity`` (rsl-rl's Gaussian): the MLP output is the action mean.

Every file carries ``PolicyMetadata.to_props()`` (``bar.*`` JSON keys plus Humanoid Control's 13 keys), and
``bar.provenance`` when the metadata holds it (commit, dirty flag, library versions, training command).

**Parity gate.** ``export_policy`` serialises the model, runs it in onnxruntime on 4096 fresh random
observations (``mean + k * std * normal`` with k = 1, 4 and 8, see ``parity_observations``), compares with
the framework's own inference function (``reference_fn``) and raises ``ParityError`` without writing
anything when the abs difference on a row at k sigma exceeds ``k * PARITY_TOLERANCE`` (1e-5 per sigma).
A second set spread over the whole clip range (+-100 raw, thousands of sigma) is checked at
``EXTREME_TOLERANCE`` (1e-3): out there float32 rounding alone separates two correct implementations by
more than 1e-5. The file is written to a temporary name and renamed only after both checks pass.

The JAX reference runs with float32 matmul precision on the CPU, so TF32 on a GPU cannot fake a mismatch.
"""

from __future__ import annotations

import json
import os
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

import bar_policy
from bar_policy._files import write_atomic
from bar_policy.deploy.metadata import PolicyMetadata
from bar_policy.export.graph import (
    Activation,
    MlpPolicy,
    build_onnx_model,
)
from bar_policy.export.parity import (
    EXTREME_TOLERANCE,
    PARITY_TOLERANCE,
    check_parity,
    extreme_observations,
    parity_observations,
    parity_sigmas,
)
from bar_policy.obs.action_prior import Prior

__all__ = [
    "brax_policy_reference",
    "code_version",
    "export_brax_policy",
    "export_policy",
    "mlp_policy_from_brax",
]


# ----------------------------------------------------------------------------------------------------------
# Export
# ----------------------------------------------------------------------------------------------------------


def code_version() -> str:
    """``<bar_policy version>+g<short sha>`` (``+dirty`` for a changed tree) or the bare version.

    The full commit, the dirty flag and the library versions are in ``bar.provenance``
    (``bar_policy.provenance``); this short form stays for ``bar.code_version``.
    """
    from bar_policy.provenance import UNKNOWN, git_state

    commit, dirty = git_state()
    if commit == UNKNOWN:
        return bar_policy.__version__
    return f"{bar_policy.__version__}+g{commit[:7]}{'+dirty' if dirty is True else ''}"


def export_policy(
    policy: MlpPolicy,
    metadata: PolicyMetadata,
    path: str | os.PathLike[str],
    reference_fn: Callable[[np.ndarray], np.ndarray],
    *,
    num_parity_obs: int = 4096,
    seed: int = 0,
    tolerance: float = PARITY_TOLERANCE,
    action_clip: float | None = 1.0,
) -> dict[str, Any]:
    """Build, gate and write an ONNX policy file.

    Args:
        policy: the weights.
        metadata: the deployment contract written to ``metadata_props``.
        path: output file; written atomically, only when the gate passes.
        reference_fn: the framework's deterministic policy, (n, obs) float32 -> (n, A).
        num_parity_obs: test observations for the gate.
        seed: seed of the test observations.
        tolerance: max abs difference allowed at one sigma (``k`` times that at k sigma).
        action_clip: bound the runtime applies to raw actions (``bar.action_clip``; the reach env clips
            actions to [-1, 1]); None writes ``null`` (no clip).

    Returns:
        ``{"path", "max_abs_error", "max_abs_error_extreme", "num_parity_obs", "tolerance", "bytes"}``.

    Raises:
        ParityError: onnxruntime disagrees with ``reference_fn`` (nothing is written).
        ValueError: the metadata does not fit the policy's sizes.
    """
    if len(metadata.action_joint_names) != policy.action_size:
        raise ValueError(
            f"policy has {policy.action_size} actions but metadata names {len(metadata.action_joint_names)} "
            "action joints"
        )
    props = {**metadata.to_props(), "bar.action_clip": json.dumps(action_clip)}
    model = build_onnx_model(policy, props)
    data = model.SerializeToString()
    obs = parity_observations(policy, num_parity_obs, seed)
    err = check_parity(data, reference_fn, obs, tolerance, parity_sigmas(num_parity_obs))
    err_extreme = check_parity(
        data,
        reference_fn,
        extreme_observations(policy, max(num_parity_obs // 8, 1), seed + 1),
        EXTREME_TOLERANCE,
    )
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    write_atomic(path, data)
    return {
        "path": str(path),
        "max_abs_error": err,
        "max_abs_error_extreme": err_extreme,
        "num_parity_obs": num_parity_obs,
        "tolerance": tolerance,
        "bytes": len(data),
    }


# ----------------------------------------------------------------------------------------------------------
# brax
# ----------------------------------------------------------------------------------------------------------


def mlp_policy_from_brax(
    params: Sequence[Any],
    action_size: int,
    activation: Activation = "swish",
    prior: Prior | None = None,
) -> MlpPolicy:
    """Extract the deterministic policy from brax PPO params ``(normalizer, policy, value)``.

    The normaliser is brax's ``RunningStatisticsState`` (``(x - mean) / std``, where ``std`` already holds
    ``sqrt(var + std_eps)`` clipped to its bounds, and no output clipping in PPO); the policy params are
    flax ``{"params": {"hidden_0": {"kernel", "bias"}, ...}}`` from brax's ``MLP``.
    """
    normalizer, policy_params = params[0], params[1]
    layers = policy_params["params"]
    names = sorted(layers, key=lambda s: int(s.rsplit("_", 1)[1]))
    kernels = [np.asarray(layers[n]["kernel"], dtype=np.float32) for n in names]
    biases = [np.asarray(layers[n]["bias"], dtype=np.float32) for n in names]
    if kernels[-1].shape[1] != 2 * action_size:
        raise ValueError(
            f"brax tanh-normal policy head should output 2 x {action_size}, got {kernels[-1].shape[1]}"
        )
    kernels[-1] = kernels[-1][:, :action_size]  # loc columns; the scale half does not affect the mode
    biases[-1] = biases[-1][:action_size]
    mean = np.asarray(normalizer.mean, dtype=np.float32).reshape(-1)
    std = np.asarray(normalizer.std, dtype=np.float32).reshape(-1)
    return MlpPolicy(
        obs_mean=mean,
        obs_std=std,
        kernels=tuple(kernels),
        biases=tuple(biases),
        activation=activation,
        head="tanh_loc",
        prior=prior,
    )


def brax_policy_reference(
    make_inference_fn: Callable[..., Any], params: Sequence[Any]
) -> Callable[[np.ndarray], np.ndarray]:
    """Brax's own deterministic policy as a numpy function, run on the CPU at float32 matmul precision.

    Args:
        make_inference_fn: ``ppo_networks.make_inference_fn(networks)`` (the ``make_policy`` factory).
        params: ``(normalizer, policy, value)``.
    """
    import jax

    cpu = jax.devices("cpu")[0]
    params_cpu = jax.device_put(params, cpu)
    policy = make_inference_fn(params_cpu, deterministic=True)

    def fn(obs: np.ndarray) -> np.ndarray:
        with jax.default_device(cpu), jax.default_matmul_precision("float32"):
            action, _ = jax.jit(policy)(jax.device_put(obs, cpu), jax.random.PRNGKey(0))
            return np.asarray(action)

    return fn


def export_brax_policy(
    params: Sequence[Any],
    make_inference_fn: Callable[..., Any],
    metadata: PolicyMetadata,
    path: str | os.PathLike[str],
    *,
    activation: Activation = "swish",
    num_parity_obs: int = 4096,
    seed: int = 0,
    prior: Prior | None = None,
) -> dict[str, Any]:
    """Export brax PPO params to ONNX, gated on parity with ``make_inference_fn(params, deterministic=True)``.

    Args:
        params: ``(normalizer, policy, value)`` as returned by brax PPO / our trainer.
        make_inference_fn: brax's ``make_policy`` factory for these networks.
        metadata: deployment contract (``bar_policy.training.metadata.policy_metadata``).
        path: output ``.onnx`` path.
        activation: the networks' hidden activation.
        num_parity_obs: observations checked by the gate.
        seed: seed of those observations.
        prior: the networks' action prior (``training.brax.networks.make_networks``), None without one.

    Returns:
        ``export_policy``'s summary.
    """
    policy = mlp_policy_from_brax(params, len(metadata.action_joint_names), activation, prior)
    return export_policy(
        policy,
        metadata,
        path,
        brax_policy_reference(make_inference_fn, params),
        num_parity_obs=num_parity_obs,
        seed=seed,
    )
