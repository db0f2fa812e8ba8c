"""The reach training presets: ``{dotted.path: value}`` on ``TrainConfig()`` (``training.config.preset``).

Sizes follow brax's PPO (``training.config``): an iteration collects ``batch_size * num_minibatches``
unrolls of ``unroll_length`` steps over ``num_envs`` envs. Plain data: this module imports nothing.
"""

from __future__ import annotations

__all__ = ["CPU", "GPU", "RSL", "TINY"]

GPU = {"preset": "gpu", "eval.num_evals": 41}
"""Default, for one H100: 40 M steps, 4096 envs, 81,920 env steps and 128 SGD steps per iteration.

Budget: about 5 minutes including compile if the batched env runs at >= 200 k steps/s. Evaluations every
1.15 M steps (41 over the run, each about 3 s on an H100): the policy crosses 95 % success between 1.7 M and
2.3 M env steps (session 34: at or above 95 % at 2.29 M in 10 of 11 runs, 94.8 % in the other; 84-85 % at
1.72 M), which evaluations every 2.1 M steps (21) only saw at 4.3 M, about 15 s later. The cost is 20 more
evaluations over a full run.
"""

RSL = {
    **GPU,
    "eval.num_evals": 21,  # as measured for rsl-rl (session 33)
    "preset": "rsl",
    "backend": "rsl-rl",
    "ppo.unroll_length": 24,
    "ppo.num_minibatches": 4,
    "ppo.batch_size": 1024,
    "ppo.num_updates_per_batch": 5,
    "ppo.learning_rate": 1e-3,
    "ppo.entropy_cost": 0.005,
    "ppo.discounting": 0.99,
    "ppo.gae_lambda": 0.95,
    "ppo.clipping_epsilon": 0.2,
    "ppo.max_grad_norm": 1.0,
    "ppo.normalize_observations": True,
    "rsl_rl.schedule": "adaptive",
    "rsl_rl.desired_kl": 0.01,
    "rsl_rl.value_loss_coef": 1.0,
    "network.policy_hidden": (256, 128, 64),
    "network.value_hidden": (256, 128, 64),
    "network.activation": "elu",
    "network.init_noise_std": 1.0,
}
"""The gpu preset on rsl-rl as its users train arm reach: the field's hyperparameters
(``training.rsl_rl_config.FIELD_RSL_RL_PPO``, sources there; a test holds this dict equal to
``field_hyperparameters(preset("gpu"))``) for 4096 envs: 24 steps per env and 5 epochs of 4 minibatches per
iteration (98,304 env steps, 20 SGD steps), KL-adaptive learning rate from 1e-3, [256, 128, 64] elu.
``python train/ppo.py --preset rsl``.
"""

CPU = {
    "preset": "cpu",
    "ppo.num_timesteps": 1_000_000,
    "ppo.num_envs": 128,
    "ppo.unroll_length": 10,
    "ppo.batch_size": 64,
    "ppo.num_minibatches": 8,
    "ppo.num_updates_per_batch": 4,
    "network.policy_hidden": (64, 64),
    "network.value_hidden": (128, 128),
    "eval.num_evals": 6,
    "eval.num_eval_envs": 128,
    "final_eval_envs": 256,
}
"""A few minutes on a laptop CPU: small batches, short run."""

TINY = {
    "preset": "tiny",
    "ppo.num_timesteps": 4 * 16 * 8 * 4,
    "ppo.num_envs": 16,
    "ppo.unroll_length": 8,
    "ppo.batch_size": 16,
    "ppo.num_minibatches": 4,
    "ppo.num_updates_per_batch": 2,
    "ppo.learning_rate": 1e-3,
    "network.policy_hidden": (32, 32),
    "network.value_hidden": (32, 32),
    "eval.num_evals": 3,
    "eval.num_eval_envs": 16,
    "final_eval_envs": 32,
}
"""Seconds of training on a CPU, for tests and smoke runs (not expected to solve the task)."""
