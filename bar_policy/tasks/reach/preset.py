"""The reach training presets: ``{dotted.path: value}`` on ``TrainConfig()`` (``training.config.preset``).

Sizes follow brax's PPO (``training.config``): an iteration collects ``batch_size * num_minibatches``
unrolls of ``unroll_length`` steps over ``num_envs`` envs. Plain data: this module imports only the
plain-data ``tasks.robust_preset``.
"""

from __future__ import annotations

from bar_policy.tasks.robust_preset import robust

__all__ = ["CPU", "GPU", "GPU_RSL", "REACH_ROBUST", "RSL", "TINY"]

GPU = {
    "preset": "gpu",
    "ppo.batch_size": 256,
    "ppo.update_precision": "tensorfloat32",
    "eval.num_evals": 24,
    "env_overrides": ("sim_dt=0.004",),
}
"""Default, for one H100: 40 M steps, 4096 envs, 40,960 env steps and 128 SGD steps per iteration, a 4 ms
physics step (5 per 20 ms control step).

Measured (docs/performance.md, 2026-11-27, one or two runs per H100, evaluations every 327k env steps):
- ``batch_size`` 256 (one 10-step unroll per env per iteration, so twice the SGD steps per env step of 512)
  crossed 95 % success at 1.64 M env steps in 5 runs of 5 (seeds 0-2 at 2 ms, 1-2 at 4 ms; 95.5-99.9 %
  there), where 512 needed 2.29-2.46 M. It costs more per env step (the update runs as often for half the
  data): 130k against 143k env steps/s at 2 ms.
- ``sim_dt=0.004`` trains at about 1.6x the env steps/s of the model's 2 ms and learns as fast per env step.
  Its files are gated on the C MuJoCo sim at 2 ms like any other (``train/ship.py``, ``bar-deploy eval``):
  of 14 4 ms files (2026-11-27, the default command's own six included) eleven passed, as did four of
  five 2 ms files; every miss was torque-cap time at the episode's first command (two reward costs on it
  were tried on 2026-11-27 and rejected). The env's ``wrist_posture`` cost (2026-11-27) aims at its cause:
  its three files (seeds 0-2) reached 95 % at 1.64 M env steps each, and these three and the default
  command's cold and warm files on another host all passed (docs/performance.md, 2026-11-27).
  ``--env-overrides sim_dt=0.002`` trains at the model's own step (a path given on the command line
  replaces the preset's value for it; the preset's other items stay).
- ``update_precision`` tensorfloat32 (2026-11-28, H200): the SGD passes' matrix products on TF32 tensor
  cores, physics and rollout at float32; the update 30.6 -> 18.2 ms per iteration, steady training 297-302k
  -> 323-328k env steps/s. Seeds 0-2 learned as seeds 0-1 at float32 (97.4-97.7 % at the first evaluation,
  100 % after) and their three files passed the ship gate (``bar-deploy eval``), as did the two float32
  ones. ``--ppo.update-precision run`` trains at float32 throughout.
- 24 evaluations: one every 44 iterations (1.80 M env steps), the first just past the 1.64 M crossing, so a
  warm run pays one evaluation (about 1.4 s at 4 ms) on the way to 95 %. The recipe before it
  (batch 512, 2 ms, 41 evaluations every 1.15 M) saw 95 % at 2.29 M.
"""

RSL = {
    **GPU,
    "eval.num_evals": 21,  # as measured for rsl-rl (2026-11-27)
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
    "ppo.schedule": "adaptive",  # the brax side of the same choices: nothing unapplied to report
    "ppo.desired_kl": 0.01,
    "ppo.vf_loss_coefficient": 1.0,
    "ppo.value_targets": "iteration",
    "network.policy_hidden": (256, 128, 64),
    "network.value_hidden": (256, 128, 64),
    "network.activation": "elu",
    "network.init_noise_std": 1.0,
    "ppo.update_precision": "run",
}
"""The gpu preset on rsl-rl as its users train arm reach: the field's hyperparameters
(``training.rsl_rl.config.FIELD_RSL_RL_PPO``, sources there; a test holds this dict equal to
``field_hyperparameters(preset("gpu"))``) for 4096 envs: 24 steps per env and 5 epochs of 4 minibatches per
iteration (98,304 env steps, 20 SGD steps), KL-adaptive learning rate from 1e-3, [256, 128, 64] elu.
``python train/ppo.py --preset rsl``. One H200, cold (2026-11-29): 95 % at 92 s, 169 k env steps/s steady.
With ``--env-overrides cholesky=columns`` it trains at 236 k (the host no longer runs MJX's Newton loops)
but reaches 95 % at 104 s (its env step compiles 15 s longer): the choice for a long run, not for the
time to 95 %.
"""

GPU_RSL = {
    **RSL,
    "preset": "gpu-rsl",
    "rsl_rl.schedule": "fixed",
    "ppo.schedule": "fixed",  # the brax side of the same choice: nothing unapplied to report
    "ppo.learning_rate": 1e-3,
    "ppo.entropy_cost": 1e-3,
}
"""What ``bar-train --backend rsl-rl`` runs without ``--preset``: the ``rsl`` preset's sizes (24 steps per
env, 5 epochs of 4 minibatches: 98,304 env steps and 20 Adam steps per iteration, the 160-200 k env steps/s
of one H200) with the regularisation the brax path's robot-grade files train under, two departures from the
field:

- a fixed learning rate, 1e-3 (the field's KL-adaptive rate from 1e-3: rsl-rl's rule raises it up to 1e-2
  whenever an update's KL falls under half the target, which it does once the policy settles). The
  project's measurements tie the period-2 action chatter to that rule on both backends: the trackers'
  files chattered at 16-18 mrad adaptive against 0.47-0.54 fixed on rsl-rl, and brax's worst MJX episode
  at 20-56 against 0.4-2.8 mrad (docs/tracking.md); ``--preset rsl``'s reach evaluations chattered at 7-44
  mrad (gate 5) with up to 5.3 % of ticks at a torque cap (one H200). The brax gpu preset's rate is fixed
  too (5e-4 over 128 Adam steps per iteration; here 20 steps on larger minibatches, at twice the rate);
- entropy cost 1e-3 (Isaac Lab's Franka reach value; the field's 5e-3 is mjlab's lift): with a fixed rate
  the tracker learned too slowly for its precision gate at 5e-3 (docs/training.md, ``track-rsl``), and
  reach's final distance on ``rsl`` was 1.04 cm against brax's 0.6.

Kept at the field's: 24 steps per env, 5 x 4 minibatches (fewer Adam steps per env step is where the
speed is: the gpu preset's 128 per 40,960 steps ran rsl-rl at 35-41 k env steps/s), gamma 0.99, lambda
0.95, clip 0.2, initial std 1.0, [256, 128, 64] elu, observation normalisation, rsl-rl's clipped value loss.
Not yet measured on a GPU: ``--preset rsl`` holds the field's values unchanged.
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
    "eval.num_evals": 2,
    "eval.num_eval_envs": 16,
    "final_eval_envs": 16,
    "quick_compile": True,
}
"""The smoke run: ``bar-train --preset tiny``, chosen for a cold start on a 2-core CPU, for
tests and a first try (not expected to solve the task). What it chooses for that, each a CPU's cost:

- ``quick_compile``: XLA's LLVM at -O1 (``startup.compile_cache.QUICK_COMPILE``): the programs compile sooner
  and run about as fast.
- ``eval.num_evals`` 2: one evaluation, at the end (the periodic one is the last); with the step-0 one
  (``eval.initial=end``) and the final evaluation, three runs of the one compiled evaluation.
- ``final_eval_envs`` = ``eval.num_eval_envs``: the final evaluation is one batch, not two.

Measured in docs/training.md ("Smoke run")."""

REACH_ROBUST_EXTRA: tuple[str, ...] = (
    "reward.scales.torque_near_cap=-1.0",  # x10 the nominal weight: delay and damping met the caps
    "reward.scales.wrist_posture=-0.5",  # x5: wrists held off their default sent every episode's first
    # ticks into the 4 N*m wrist caps (0.4-1.2 % of the gate's ticks, the suite's whole cap budget)
    "joint_error_ema=true",  # the integral-like input (layout lite_reach_arms v2)
)
"""Reach's own items of the robust preset, after the randomisation: measured on the suite in
docs/robust_training.md, "Reach: shipped"."""

REACH_ROBUST = robust(GPU, "reach-robust", REACH_ROBUST_EXTRA)
"""The ``gpu`` preset with the robustness randomisation (``tasks.robust_preset.ROBUST_ENV_OVERRIDES``;
docs/robust_training.md) and ``REACH_ROBUST_EXTRA``."""
