"""A deterministic MLP policy as plain arrays (``MlpPolicy``) and its ONNX graph (``build_onnx_model``).

``export.policy`` documents the graph (normaliser folded in, dense layers, the ``tanh_loc`` /
``identity`` heads) and the parity gate that guards every written file.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Literal

import numpy as np
import onnx
from onnx import TensorProto, helper, numpy_helper

import bar_policy
from bar_policy.obs.action_prior import ActionPrior, BlendPrior, Prior, check_fits

__all__ = ["OPSET", "Activation", "Head", "MlpPolicy", "build_onnx_model"]

OPSET = 17
"""ONNX opset of exported files."""

Activation = Literal["swish", "elu", "relu", "tanh"]
Head = Literal["tanh_loc", "identity"]


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
    prior: Prior | None = None
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
            check_fits(self.prior, n, self.kernels[-1].shape[1], holder="the last layer")
        for i, (k, b) in enumerate(zip(self.kernels, self.biases, strict=True)):
            if k.ndim != 2 or b.shape != (k.shape[1],):
                raise ValueError(f"layer {i}: kernel {k.shape} and bias {b.shape} do not fit")
            if i and k.shape[0] != self.kernels[i - 1].shape[1]:
                raise ValueError(
                    f"layer {i}: input {k.shape[0]} != previous output {self.kernels[i - 1].shape[1]}"
                )

    @classmethod
    def prior_only(cls, obs_size: int, prior: Prior) -> MlpPolicy:
        """The ``tanh_loc`` policy of one zero layer on ``prior``: its actions are ``prior(obs)`` itself.

        ``tanh(0 + atanh(prior(obs)))``: what a run would export before its first update with the MLP's
        output at exactly zero (the benches of a prior alone; ``obs_size`` entries, the prior's actions).
        """
        n_act = prior.action_size
        return cls(
            obs_mean=np.zeros(obs_size, np.float32),
            obs_std=np.ones(obs_size, np.float32),
            kernels=(np.zeros((obs_size, n_act), np.float32),),
            biases=(np.zeros(n_act, np.float32),),
            activation="swish",
            head="tanh_loc",
            prior=prior,
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


def _prior_nodes(prior: Prior, atanh: bool) -> tuple[list[onnx.TensorProto], list[onnx.NodeProto], str]:
    """The prior's nodes (affine or blend), then ``Atanh``: initialisers, nodes, output."""
    inits, nodes = _blend_nodes(prior) if isinstance(prior, BlendPrior) else _affine_nodes(prior)
    if not atanh:
        return inits, nodes, "prior_action"
    nodes.append(helper.make_node("Atanh", ["prior_action"], ["prior_pre_tanh"]))
    return inits, nodes, "prior_pre_tanh"


def _affine_nodes(prior: ActionPrior) -> tuple[list[onnx.TensorProto], list[onnx.NodeProto]]:
    """``prior_action = clip(gain * obs[:, index] + offset [+ integral term], -bound, bound)``.

    The integral term is ``error_gain * obs[:, error_index]`` (``ActionPrior``); its nodes only for a
    prior that has one, so a prior without it exports the graph it always had.
    """
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
    ]
    affine = "prior_affine"
    if prior.has_error_term:
        inits += [
            numpy_helper.from_array(np.asarray(prior.error_index, np.int64), "prior_error_index"),
            numpy_helper.from_array(np.asarray(prior.error_gain, np.float32), "prior_error_gain"),
        ]
        nodes += [
            helper.make_node("Gather", ["obs", "prior_error_index"], ["prior_error_obs"], axis=1),
            helper.make_node("Mul", ["prior_error_obs", "prior_error_gain"], ["prior_error_scaled"]),
            helper.make_node("Add", ["prior_affine", "prior_error_scaled"], ["prior_integral"]),
        ]
        affine = "prior_integral"
    nodes.append(helper.make_node("Clip", [affine, "prior_low", "prior_high"], ["prior_action"]))
    return inits, nodes


def _blend_nodes(prior: BlendPrior) -> tuple[list[onnx.TensorProto], list[onnx.NodeProto]]:
    """``prior_action = clip(sum_i (x @ numer[i] + numer_bias[i]) / (x @ denom[i] + denom_bias[i]), -b, b)``.

    ``x = max(obs[:, start:stop], 0)``: Slice, Relu, then per blend two MatMuls and a Div (``BlendPrior``).
    """
    f32 = np.float32
    inits = [
        numpy_helper.from_array(np.asarray([prior.start], np.int64), "prior_start"),
        numpy_helper.from_array(np.asarray([prior.stop], np.int64), "prior_stop"),
        numpy_helper.from_array(np.asarray([1], np.int64), "prior_axis"),
        numpy_helper.from_array(np.asarray(-prior.bound, f32), "prior_low"),
        numpy_helper.from_array(np.asarray(prior.bound, f32), "prior_high"),
    ]
    nodes = [
        helper.make_node("Slice", ["obs", "prior_start", "prior_stop", "prior_axis"], ["prior_sel"]),
        helper.make_node("Relu", ["prior_sel"], ["prior_x"]),
    ]
    total = ""
    for i in range(np.shape(prior.numer)[0]):
        b = f"prior{i}"
        inits += [
            numpy_helper.from_array(np.asarray(prior.numer[i], f32), f"{b}_numer"),
            numpy_helper.from_array(np.asarray(prior.denom[i], f32), f"{b}_denom"),
            numpy_helper.from_array(np.asarray(prior.numer_bias[i], f32), f"{b}_numer_bias"),
            numpy_helper.from_array(np.asarray(prior.denom_bias[i], f32), f"{b}_denom_bias"),
        ]
        nodes += [
            helper.make_node("MatMul", ["prior_x", f"{b}_numer"], [f"{b}_num_mm"]),
            helper.make_node("Add", [f"{b}_num_mm", f"{b}_numer_bias"], [f"{b}_num"]),
            helper.make_node("MatMul", ["prior_x", f"{b}_denom"], [f"{b}_den_mm"]),
            helper.make_node("Add", [f"{b}_den_mm", f"{b}_denom_bias"], [f"{b}_den"]),
            helper.make_node("Div", [f"{b}_num", f"{b}_den"], [f"{b}_blend"]),
        ]
        if total:
            nodes.append(helper.make_node("Add", [total, f"{b}_blend"], [f"{b}_sum"]))
            total = f"{b}_sum"
        else:
            total = f"{b}_blend"
    nodes.append(helper.make_node("Clip", [total, "prior_low", "prior_high"], ["prior_action"]))
    return inits, nodes


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
