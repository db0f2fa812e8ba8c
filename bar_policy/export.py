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
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np
import onnx
from onnx import TensorProto, helper, numpy_helper

import bar_policy
from bar_policy._files import write_atomic
from bar_policy.deploy.metadata import PolicyMetadata
from bar_policy.obs.action_prior import ActionPrior

__all__ = [
    "EXTREME_TOLERANCE",
    "OPSET",
    "PARITY_TOLERANCE",
    "MlpPolicy",
    "ParityError",
    "brax_policy_reference",
    "build_onnx_model",
    "check_parity",
    "code_version",
    "export_brax_policy",
    "export_policy",
    "extreme_observations",
    "mlp_policy_from_brax",
    "parity_observations",
    "parity_sigmas",
]

OPSET = 17
"""ONNX opset of exported files."""

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

Activation = Literal["swish", "elu", "relu", "tanh"]
Head = Literal["tanh_loc", "identity"]


class ParityError(RuntimeError):
    """The exported graph does not reproduce the training framework's policy."""


@dataclass(frozen=True, kw_only=True)
class MlpPolicy:
    """A deterministic MLP policy as plain float32 arrays (framework-independent).

    ``action = head(W_n @ act(... act(W_1 @ ((obs - obs_mean) / obs_std) + b_1) ...) + b_n)``
    """

    obs_mean: np.ndarray
    """Normaliser mean, shape (obs,)."""
    obs_std: np.ndarray
    """Normaliser divisor (already including any epsilon), shape (obs,), > 0."""
    kernels: tuple[np.ndarray, ...]
    """Dense kernels, shapes (in, out), input side first."""
    biases: tuple[np.ndarray, ...]
    """Dense biases, shapes (out,)."""
    activation: Activation
    """Hidden activation (not applied after the last layer)."""
    head: Head
    """``tanh_loc`` = tanh of the output (brax); ``identity`` = the output itself (rsl-rl)."""
    prior: ActionPrior | None = None
    """Added to the last layer's output before the head: ``atanh(prior(obs))`` for ``tanh_loc``, the
    prior itself for ``identity`` (``bar_policy.obs.action_prior``); None: no prior."""

    def __post_init__(self) -> None:
        if len(self.kernels) != len(self.biases) or not self.kernels:
            raise ValueError(
                f"need as many kernels as biases (>0), got {len(self.kernels)}/{len(self.biases)}"
            )
        n = self.obs_mean.shape[0]
        if self.obs_std.shape != (n,) or self.kernels[0].shape[0] != n:
            raise ValueError(
                f"normaliser shapes {self.obs_mean.shape}/{self.obs_std.shape} do not match the first "
                f"kernel's input size {self.kernels[0].shape[0]}"
            )
        if not np.all(self.obs_std > 0):
            raise ValueError("obs_std must be > 0 everywhere")
        if self.prior is not None:
            if self.prior.action_size != self.kernels[-1].shape[1]:
                raise ValueError(
                    f"the action prior has {self.prior.action_size} actions, the last layer "
                    f"{self.kernels[-1].shape[1]}"
                )
            self.prior.check_observation_size(n)
        for i, (k, b) in enumerate(zip(self.kernels, self.biases, strict=True)):
            if k.ndim != 2 or b.shape != (k.shape[1],):
                raise ValueError(f"layer {i}: kernel {k.shape} and bias {b.shape} do not fit")
            if i and k.shape[0] != self.kernels[i - 1].shape[1]:
                raise ValueError(
                    f"layer {i}: input {k.shape[0]} != previous output {self.kernels[i - 1].shape[1]}"
                )

    @property
    def obs_size(self) -> int:
        """Observation size."""
        return int(self.obs_mean.shape[0])

    @property
    def action_size(self) -> int:
        """Action size."""
        return int(self.kernels[-1].shape[1])


# ----------------------------------------------------------------------------------------------------------
# Graph
# ----------------------------------------------------------------------------------------------------------


def build_onnx_model(policy: MlpPolicy, props: Mapping[str, str] | None = None) -> onnx.ModelProto:
    """The ONNX model of ``policy`` with input ``obs`` [batch, obs] and output ``actions`` [batch, A].

    Args:
        policy: weights and structure.
        props: ``metadata_props`` to attach (e.g. ``PolicyMetadata.to_props()``).

    Returns:
        A checked ``onnx.ModelProto`` (opset ``OPSET``), float32, dynamic batch dimension ``batch``.
    """
    inits = [
        numpy_helper.from_array(policy.obs_mean.astype(np.float32), "obs_mean"),
        numpy_helper.from_array(policy.obs_std.astype(np.float32), "obs_std"),
    ]
    nodes = [
        helper.make_node("Sub", ["obs", "obs_mean"], ["obs_centered"]),
        helper.make_node("Div", ["obs_centered", "obs_std"], ["h0"]),
    ]
    x = "h0"
    last = len(policy.kernels) - 1
    for i, (k, b) in enumerate(zip(policy.kernels, policy.biases, strict=True)):
        inits += [
            numpy_helper.from_array(k.astype(np.float32), f"dense{i}_kernel"),
            numpy_helper.from_array(b.astype(np.float32), f"dense{i}_bias"),
        ]
        nodes += [
            helper.make_node("MatMul", [x, f"dense{i}_kernel"], [f"dense{i}_mm"]),
            helper.make_node("Add", [f"dense{i}_mm", f"dense{i}_bias"], [f"dense{i}_out"]),
        ]
        x = f"dense{i}_out"
        if i < last:
            nodes += _activation_nodes(policy.activation, x, f"act{i}")
            x = f"act{i}"
    if policy.prior is not None:
        inits_p, nodes_p, prior_out = _prior_nodes(policy.prior, atanh=policy.head == "tanh_loc")
        inits += inits_p
        nodes += [*nodes_p, helper.make_node("Add", [x, prior_out], ["with_prior"])]
        x = "with_prior"
    nodes.append(helper.make_node("Tanh" if policy.head == "tanh_loc" else "Identity", [x], ["actions"]))
    graph = helper.make_graph(
        nodes,
        "bar_policy_mlp",
        [helper.make_tensor_value_info("obs", TensorProto.FLOAT, ["batch", policy.obs_size])],
        [helper.make_tensor_value_info("actions", TensorProto.FLOAT, ["batch", policy.action_size])],
        initializer=inits,
    )
    model = helper.make_model(
        graph, opset_imports=[helper.make_opsetid("", OPSET)], producer_name="bar_policy.export"
    )
    model.ir_version = 8  # readable by onnxruntime >= 1.14
    model.producer_version = bar_policy.__version__
    if props:
        helper.set_model_props(model, dict(props))
    onnx.checker.check_model(model, full_check=True)
    return model


def _prior_nodes(prior: ActionPrior, atanh: bool) -> tuple[list[onnx.TensorProto], list[onnx.NodeProto], str]:
    """``clip(gain * obs[:, index] + offset, -bound, bound)``, then ``Atanh``: initialisers, nodes, output."""
    inits = [
        numpy_helper.from_array(np.asarray(prior.index, np.int64), "prior_index"),
        numpy_helper.from_array(np.asarray(prior.gain, np.float32), "prior_gain"),
        numpy_helper.from_array(np.asarray(prior.offset, np.float32), "prior_offset"),
        numpy_helper.from_array(np.asarray(-prior.bound, np.float32), "prior_low"),
        numpy_helper.from_array(np.asarray(prior.bound, np.float32), "prior_high"),
    ]
    nodes = [
        helper.make_node("Gather", ["obs", "prior_index"], ["prior_obs"], axis=1),
        helper.make_node("Mul", ["prior_obs", "prior_gain"], ["prior_scaled"]),
        helper.make_node("Add", ["prior_scaled", "prior_offset"], ["prior_affine"]),
        helper.make_node("Clip", ["prior_affine", "prior_low", "prior_high"], ["prior_action"]),
    ]
    if not atanh:
        return inits, nodes, "prior_action"
    nodes.append(helper.make_node("Atanh", ["prior_action"], ["prior_pre_tanh"]))
    return inits, nodes, "prior_pre_tanh"


def _activation_nodes(kind: Activation, x: str, out: str) -> list[onnx.NodeProto]:
    """Nodes computing ``out = activation(x)``; swish is written as ``x * sigmoid(x)`` like flax's."""
    if kind == "swish":
        return [
            helper.make_node("Sigmoid", [x], [f"{out}_sig"]),
            helper.make_node("Mul", [x, f"{out}_sig"], [out]),
        ]
    ops = {"elu": "Elu", "relu": "Relu", "tanh": "Tanh"}
    if kind not in ops:
        raise ValueError(f"unsupported activation {kind!r}; supported: swish, {sorted(ops)}")
    return [helper.make_node(ops[kind], [x], [out])]


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
    prior: ActionPrior | None = None,
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
    prior: ActionPrior | None = None,
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
        prior: the networks' action prior (``learner.make_networks``), None without one.

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
