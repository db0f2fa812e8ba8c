"""The policy of an rsl-rl actor: its exportable ``MlpPolicy``, rsl-rl's own reference, its evaluation.

Used by the rsl-rl backend (``rsl_rl.backend``: the evaluations during training, the result's export and
final evaluation); below it in the layers (imports only the export, the prior and the env adapter).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import torch
from rsl_rl.modules import GaussianDistribution

from bar_policy.export.graph import MlpPolicy
from bar_policy.obs.action_prior import Prior
from bar_policy.training.rsl_rl.env import RslRlVecEnv

__all__ = [
    "deterministic_module",
    "evaluate_torch_policy",
    "mlp_policy_from_rsl_rl",
    "torch_policy_reference",
]


def mlp_policy_from_rsl_rl(actor: torch.nn.Module, prior: Prior | None = None) -> MlpPolicy:
    """The deterministic policy of an rsl-rl ``MLPModel`` actor as an ``MlpPolicy``.

    Folds ``EmpiricalNormalization`` (``(x - mean) / (std + eps)``) into (mean, std + eps); reads the
    ``Linear`` layers of ``actor.mlp`` (kernel = weight.T); the Gaussian head's deterministic output is the
    MLP output itself (``identity``). ``prior``: the action prior the env added to the actor's actions in
    training (``rsl_rl.prior``); the graph then outputs ``mlp(obs) + prior(obs)``, shape (batch, A).
    """
    norm = actor.obs_normalizer
    n = actor.obs_dim
    if isinstance(norm, torch.nn.Identity):
        mean, std = np.zeros(n, np.float32), np.ones(n, np.float32)
    else:
        mean = norm._mean.detach().cpu().numpy().reshape(-1).astype(np.float32)
        std = (norm._std.detach().cpu().numpy().reshape(-1) + norm.eps).astype(np.float32)
    kernels, biases, acts = [], [], set()
    names = {torch.nn.ELU: "elu", torch.nn.SiLU: "swish", torch.nn.ReLU: "relu", torch.nn.Tanh: "tanh"}
    for layer in actor.mlp:
        if isinstance(layer, torch.nn.Linear):
            kernels.append(layer.weight.detach().cpu().numpy().T.copy())
            biases.append(layer.bias.detach().cpu().numpy().copy())
        elif type(layer) in names:
            if isinstance(layer, torch.nn.ELU) and layer.alpha != 1.0:
                raise ValueError(f"ELU alpha {layer.alpha} is not exportable (only 1.0)")
            acts.add(names[type(layer)])
        else:
            raise ValueError(f"cannot export layer {layer!r}; supported: Linear, {sorted(names.values())}")
    if len(acts) != 1:
        raise ValueError(f"expected one hidden activation, found {sorted(acts)}")
    dist = getattr(actor, "distribution", None)
    if dist is not None and not isinstance(dist, GaussianDistribution):
        raise ValueError(f"only the Gaussian head exports (identity mean), got {type(dist).__name__}")
    return MlpPolicy(
        obs_mean=mean,
        obs_std=std,
        kernels=tuple(kernels),
        biases=tuple(biases),
        activation=acts.pop(),  # type: ignore[arg-type]
        head="identity",
        prior=prior,
    )


def deterministic_module(actor: torch.nn.Module, device: str | torch.device) -> torch.nn.Module:
    """rsl-rl's deterministic export module of ``actor`` on ``device``, in eval mode.

    ``as_onnx`` copies the actor's observation normaliser (its statistics then frozen) and MLP, with the
    Gaussian head's mean as the output.
    """
    return actor.as_onnx(verbose=False).to(device).eval()


def torch_policy_reference(
    actor: torch.nn.Module, prior: Prior | None = None
) -> Callable[[np.ndarray], np.ndarray]:
    """rsl-rl's own deterministic export module (``actor.as_onnx``) as a CPU float32 numpy function.

    With ``prior``, adds ``prior.apply(obs)`` (numpy float32, independent of the ONNX graph's nodes): the
    commanded action, (n, obs) -> (n, A), that the parity gate compares the file with.
    """
    module = deterministic_module(actor, "cpu")

    def fn(obs: np.ndarray) -> np.ndarray:
        with torch.inference_mode():
            out = module(torch.as_tensor(obs, dtype=torch.float32)).numpy()
        if prior is not None:
            out = out + prior.apply(np.asarray(obs, np.float32))
        return out

    return fn


def evaluate_torch_policy(
    policy: Callable[[torch.Tensor], torch.Tensor], vec_env: RslRlVecEnv, episode_length: int, seed: int
) -> dict[str, float]:
    """Deterministic evaluation on ``vec_env`` (one episode per env from a fresh reset with ``seed``).

    ``policy`` gives the actor's actions; an env with a ``prior`` adds it (prior + residual, as in training).

    Reports ``episode_reward`` (mean and std over envs), one ratio per entry of the task's
    ``eval_ratios`` (``success_rate`` always): sums of numerators over steps and envs / sums of
    denominators, and, on a ``quality`` env, the ``quality/<figure>`` safety and smoothness figures. As in
    the brax evaluator, a slot counts until its episode's first ``done``. The sums accumulate on the
    device; the host reads them once at the end.
    """
    vec_env.reset_all(seed=seed)
    obs = vec_env.get_observations()
    with torch.inference_mode():
        for _ in range(episode_length):
            obs, _, _, _ = vec_env.step(policy(obs["policy"]))
    stats = vec_env.take_stats()
    ret = stats["return"]
    out = {"episode_reward": float(np.mean(ret)), "episode_reward_std": float(np.std(ret))}
    out.update({k: n / max(d, 1.0) for k, (n, d) in stats["ratios"].items()})
    out.update(stats.get("quality", {}))  # quality/<figure>, as the brax evaluator's (eval_quality)
    return out
