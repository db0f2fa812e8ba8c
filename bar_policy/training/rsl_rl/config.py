"""rsl-rl's ``train_cfg`` from our ``TrainConfig``, and the field's reach/manipulation hyperparameters.

``rsl_rl_train_cfg(cfg)`` maps the shared ``PPOConfig`` so that one rsl-rl iteration is one brax iteration
(see ``RslRlConfig``). ``field_hyperparameters(cfg)`` sets those shared fields to the values the rsl-rl
community trains arm reach and manipulation tasks with (``FIELD_RSL_RL_PPO``), so that
``bar-train --backend rsl-rl`` can run rsl-rl as its users know it; ``field_cli_flags`` spells the same
as ``bar-train`` flags.

Sources (the rsl-rl ``OnPolicyRunner`` configs of the field, read 2026-11):

===================== ========== ============== ============ =========
(rsl-rl name)         IL reach   IL lift        mjlab lift   **ours**
===================== ========== ============== ============ =========
num_steps_per_env     24         24             24           **24**
learning_rate         1e-3       1e-4           1e-3         **1e-3**
schedule, desired_kl  adapt 0.01 adapt 0.01     adapt 0.01   **adapt 0.01**
clip_param            0.2        0.2            0.2          **0.2**
entropy_coef          0.001      0.006          0.005        **0.005**
gamma, lam            0.99, 0.95 0.98, 0.95     0.99, 0.95   **0.99, 0.95**
num_learning_epochs   8          5              5            **5**
num_mini_batches      4          4              4            **4**
max_grad_norm         1.0        1.0            1.0          **1.0**
value_loss_coef       1.0        1.0            1.0          **1.0**
init_noise_std        1.0        1.0            1.0          **1.0**
hidden dims (a = c)   64, 64     256, 128, 64   512, 256, 128 **256, 128, 64**
activation            elu        elu            elu          **elu**
obs normalization     off        off            on           **on**
===================== ========== ============== ============ =========

- IL reach: ``isaac-sim/IsaacLab:source/isaaclab_tasks/isaaclab_tasks/manager_based/manipulation/reach/
  config/franka/agents/rsl_rl_ppo_cfg.py`` (``FrankaReachPPORunnerCfg``).
- IL lift: ``isaac-sim/IsaacLab:.../manipulation/lift/config/franka/agents/rsl_rl_ppo_cfg.py``
  (``LiftCubePPORunnerCfg``).
- mjlab lift: ``mujocolab/mjlab:src/mjlab/tasks/manipulation/config/yam/rl_cfg.py``
  (``yam_lift_cube_ppo_runner_cfg``).

Ours is mjlab's YAM lift (the one MuJoCo arm-manipulation config of the three, and the consensus row but
for the width), with Isaac Lab lift's [256, 128, 64] networks (a 14-joint arm pair's policy, between the
reach and the lift sizes). Observation normalisation is on as in mjlab (our exporter folds it into the ONNX
graph). Both use rsl-rl's clipped value loss (its default).
"""

from __future__ import annotations

from typing import Any

from bar_policy.training.config import TrainConfig, apply_overrides

__all__ = [
    "FIELD_RSL_RL_PPO",
    "GAUSSIAN_HEAD",
    "RSL_RL_LR_BOUNDS",
    "RSL_RL_OBS_STD_EPS",
    "TORCH_PRECISIONS",
    "field_cli_flags",
    "field_hyperparameters",
    "field_overrides",
    "not_applied",
    "rsl_rl_train_cfg",
]

TORCH_PRECISIONS = ("run", "tensorfloat32")
"""The ``ppo.update_precision`` values the rsl-rl backend applies to torch's update (``torch_precision``)."""

RSL_RL_LR_BOUNDS = (1e-5, 1e-2)
"""rsl-rl's adaptive rule keeps its learning rate within these (``PPO.update``; brax's defaults match)."""

RSL_RL_OBS_STD_EPS = 1e-4
"""The ``ppo.obs_std_eps`` (variance added) nearest rsl-rl's normaliser, ``(x - mean) / (std + 0.01)``."""

GAUSSIAN_HEAD = "bar_policy.training.rsl_rl.sampling:GaussianNoSync"
"""The actor's ``distribution_cfg`` class: rsl-rl's Gaussian head without its per-step host sync (by name,
so that this module stays torch-free)."""

_ACT = {"swish": "swish", "elu": "elu", "relu": "relu", "tanh": "tanh"}

FIELD_RSL_RL_PPO: dict[str, Any] = {
    "num_steps_per_env": 24,
    "learning_rate": 1e-3,
    "schedule": "adaptive",
    "desired_kl": 0.01,
    "clip_param": 0.2,
    "entropy_coef": 0.005,
    "gamma": 0.99,
    "lam": 0.95,
    "num_learning_epochs": 5,
    "num_mini_batches": 4,
    "max_grad_norm": 1.0,
    "value_loss_coef": 1.0,
    "init_noise_std": 1.0,
    "hidden_dims": (256, 128, 64),
    "activation": "elu",
    "obs_normalization": True,
}
"""The field's rsl-rl PPO hyperparameters for arm reach/manipulation, rsl-rl's names (module docstring)."""


def field_overrides(num_envs: int) -> dict[str, Any]:
    """``FIELD_RSL_RL_PPO`` as overrides of our config's fields, for ``num_envs`` parallel envs.

    ``num_steps_per_env`` = ``batch_size * num_minibatches * unroll_length / num_envs`` in our mapping: 24
    with ``unroll_length=24``, ``num_minibatches=4``, ``batch_size=num_envs/4`` (the minibatch is
    ``num_envs * 24 / 4`` samples, as rsl-rl's).

    Raises:
        ValueError: ``num_envs`` does not divide by ``num_mini_batches`` (4).
    """
    f = FIELD_RSL_RL_PPO
    if num_envs <= 0 or num_envs % f["num_mini_batches"]:
        raise ValueError(f"num_envs must be a positive multiple of {f['num_mini_batches']}, got {num_envs}")
    return {
        "ppo.unroll_length": f["num_steps_per_env"],
        "ppo.num_minibatches": f["num_mini_batches"],
        "ppo.batch_size": num_envs // f["num_mini_batches"],
        "ppo.num_updates_per_batch": f["num_learning_epochs"],
        "ppo.learning_rate": f["learning_rate"],
        "ppo.entropy_cost": f["entropy_coef"],
        "ppo.discounting": f["gamma"],
        "ppo.gae_lambda": f["lam"],
        "ppo.clipping_epsilon": f["clip_param"],
        "ppo.max_grad_norm": f["max_grad_norm"],
        "ppo.normalize_observations": f["obs_normalization"],
        "rsl_rl.schedule": f["schedule"],
        "rsl_rl.desired_kl": f["desired_kl"],
        "rsl_rl.value_loss_coef": f["value_loss_coef"],
        # The brax side of the same choices (what rsl-rl does), so that not_applied has nothing to say.
        "ppo.schedule": f["schedule"],
        "ppo.desired_kl": f["desired_kl"],
        "ppo.vf_loss_coefficient": f["value_loss_coef"],
        "ppo.value_targets": "iteration",
        "network.policy_hidden": f["hidden_dims"],
        "network.value_hidden": f["hidden_dims"],
        "network.activation": f["activation"],
        "network.init_noise_std": f["init_noise_std"],
        "ppo.update_precision": "run",  # the field trains its torch update at float32
    }


def field_hyperparameters(cfg: TrainConfig) -> TrainConfig:
    """``cfg`` with the field's rsl-rl hyperparameters (``field_overrides(cfg.ppo.num_envs)``)."""
    return apply_overrides(cfg, field_overrides(cfg.ppo.num_envs))


def not_applied(cfg: TrainConfig) -> list[str]:
    """A line per brax-backend setting in ``cfg`` that the rsl-rl backend runs without (it prints them).

    rsl-rl runs its own PPO, so a brax setting it has no counterpart for, or one whose counterpart is set
    apart (``rsl_rl.*``) to another value, would otherwise vanish unsaid (``--preset track --backend
    rsl-rl`` took rsl-rl's KL-adaptive rate where the preset asks for a fixed one). Said:
    ``ppo.update_precision`` ``BF16_BF16_F32_X3`` (torch has no three-pass bfloat16 product;
    ``tensorfloat32`` applies, ``torch_precision``); ``ppo.schedule`` against ``rsl_rl.schedule``, and under
    both adaptive ``ppo.desired_kl`` against ``rsl_rl.desired_kl`` and the rate's bounds against rsl-rl's
    fixed ``RSL_RL_LR_BOUNDS``; ``ppo.value_targets`` other than ``iteration`` (rsl-rl computes returns
    once per rollout); ``ppo.vf_loss_coefficient`` against ``rsl_rl.value_loss_coef``; ``ppo.obs_std_eps``
    other than ``RSL_RL_OBS_STD_EPS`` (rsl-rl's normaliser divides by std + 0.01); ``ppo.reward_scaling``
    other than 1. The field's values (``field_overrides``) set the brax side to match, so ``--preset rsl``
    says nothing.
    """
    ppo, r = cfg.ppo, cfg.rsl_rl
    out = []
    if ppo.update_precision not in TORCH_PRECISIONS:
        out.append(
            f"ppo.update_precision={ppo.update_precision} not applied: rsl-rl updates in torch, which has "
            f"no such product (it applies {', '.join(TORCH_PRECISIONS)})"
        )
    if ppo.schedule != r.schedule:
        out.append(
            f"ppo.schedule={ppo.schedule} not applied: rsl-rl's learning rate follows "
            f"rsl_rl.schedule={r.schedule} (--rsl-rl.schedule)"
        )
    elif r.schedule == "adaptive":
        if ppo.desired_kl != r.desired_kl:
            out.append(
                f"ppo.desired_kl={ppo.desired_kl:g} not applied: rsl-rl's adaptive rate targets "
                f"rsl_rl.desired_kl={r.desired_kl:g} (--rsl-rl.desired-kl)"
            )
        if (ppo.min_learning_rate, ppo.max_learning_rate) != RSL_RL_LR_BOUNDS:
            lo, hi = RSL_RL_LR_BOUNDS
            out.append(
                f"ppo.min_learning_rate={ppo.min_learning_rate:g}, ppo.max_learning_rate="
                f"{ppo.max_learning_rate:g} not applied: rsl-rl's adaptive rate stays within [{lo:g}, {hi:g}]"
            )
    if ppo.value_targets != "iteration":
        out.append(
            f"ppo.value_targets={ppo.value_targets} not applied: rsl-rl computes the value targets and "
            "advantages once per iteration (as ppo.value_targets=iteration)"
        )
    if ppo.vf_loss_coefficient != r.value_loss_coef:
        out.append(
            f"ppo.vf_loss_coefficient={ppo.vf_loss_coefficient:g} not applied: rsl-rl weighs its value loss "
            f"by rsl_rl.value_loss_coef={r.value_loss_coef:g} (--rsl-rl.value-loss-coef)"
        )
    if ppo.normalize_observations and ppo.obs_std_eps != RSL_RL_OBS_STD_EPS:
        out.append(
            f"ppo.obs_std_eps={ppo.obs_std_eps:g} not applied: rsl-rl's normaliser divides by its running "
            f"std + 0.01 (as ppo.obs_std_eps={RSL_RL_OBS_STD_EPS:g})"
        )
    if ppo.reward_scaling != 1.0:
        out.append(
            f"ppo.reward_scaling={ppo.reward_scaling:g} not applied: rsl-rl's loss takes the env's rewards "
            "unscaled"
        )
    return out


def field_cli_flags(num_envs: int, leave_out: tuple[str, ...] = ()) -> list[str]:
    """``field_overrides`` as ``bar-train`` flags: ``["--ppo.unroll-length", "24", ...]``.

    ``leave_out``: dotted paths of ``field_overrides`` to omit (a task keeping its own networks, say).
    """
    out = []
    for path, value in field_overrides(num_envs).items():
        if path in leave_out:
            continue
        group, name = path.split(".")
        flag = f"--{group.replace('_', '-')}.{name.replace('_', '-')}"
        if isinstance(value, bool):
            out.append(flag if value else f"--{group.replace('_', '-')}.no-{name.replace('_', '-')}")
        elif isinstance(value, tuple):
            out += [flag, *(str(v) for v in value)]
        else:
            out += [flag, str(value)]
    return out


def rsl_rl_train_cfg(cfg: TrainConfig) -> dict[str, Any]:
    """rsl-rl 5.x ``train_cfg`` dict for ``OnPolicyRunner`` from our config (mapping: ``RslRlConfig``)."""
    ppo, net, r = cfg.ppo, cfg.network, cfg.rsl_rl
    # With an action prior, network.prior_noise_std (when set) is the initial std, as on brax (rsl_rl.prior).
    std = net.init_noise_std
    if net.action_prior != "none" and net.prior_noise_std is not None:
        std = net.prior_noise_std
    # rsl-rl's Gaussian head, sampled without its per-step host sync (rsl_rl.sampling).
    dist = {"class_name": GAUSSIAN_HEAD, "init_std": std, "std_type": "scalar"}
    return {
        "num_steps_per_env": ppo.steps_per_iteration // ppo.num_envs,
        "save_interval": 10**9,
        "obs_groups": {"actor": ["policy"], "critic": ["policy"]},
        "check_for_nan": True,
        "algorithm": {
            "class_name": "PPO",
            "num_learning_epochs": ppo.num_updates_per_batch,
            "num_mini_batches": ppo.num_minibatches,
            "clip_param": ppo.clipping_epsilon,
            "gamma": ppo.discounting,
            "lam": ppo.gae_lambda,
            "value_loss_coef": r.value_loss_coef,
            "use_clipped_value_loss": r.clipped_value_loss,
            "entropy_coef": ppo.entropy_cost,
            "learning_rate": ppo.learning_rate,
            "max_grad_norm": ppo.max_grad_norm if ppo.max_grad_norm > 0 else 1e9,
            "schedule": r.schedule,
            "desired_kl": r.desired_kl,
        },
        "actor": {
            "class_name": "MLPModel",
            "hidden_dims": list(net.policy_hidden),
            "activation": _ACT[net.activation],
            "obs_normalization": ppo.normalize_observations,
            "distribution_cfg": dist,
        },
        "critic": {
            "class_name": "MLPModel",
            "hidden_dims": list(net.value_hidden),
            "activation": _ACT[net.activation],
            "obs_normalization": ppo.normalize_observations,
        },
    }
