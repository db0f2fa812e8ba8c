"""The piano training preset: ``{dotted.path: value}`` on ``TrainConfig()`` (``training.config.preset``).

Plain data: this module imports only the plain-data ``tasks.robust_preset``.
"""

from __future__ import annotations

from bar_policy.tasks.robust_preset import robust

__all__ = ["PIANO", "PIANO_ROBUST", "PIANO_ROBUST_EXTRA"]

PIANO = {
    "preset": "piano",
    "env_name": "LitePiano",
    "max_minutes": 8.9,
    "ppo.num_timesteps": 8_000_000,
    "ppo.num_envs": 4096,
    "ppo.unroll_length": 20,
    "ppo.batch_size": 512,
    "ppo.num_minibatches": 16,
    "ppo.num_updates_per_batch": 4,
    "ppo.learning_rate": 1e-4,
    "ppo.schedule": "fixed",
    "ppo.actor_warmup_iterations": 10,
    "ppo.entropy_cost": 1e-3,
    "ppo.discounting": 0.98,
    # Measured with brax's targets and normaliser, not with the per-pass targets and std floor.
    "ppo.value_targets": "minibatch",
    "ppo.obs_std_eps": 0.0,
    "network.policy_hidden": (512, 256, 128),
    "network.action_prior": "key_pose",
    "network.prior_lead_steps": 2,
    "network.prior_noise_std": 0.1,
    "network.value_hidden": (512, 256, 256),
    "eval.num_evals": 7,
    "eval.num_eval_envs": 1024,
    "final_eval_envs": 2048,
    # A black goal key pressed earns twice a white one, and a wrong key at a black goal tick costs half a
    # wrong key elsewhere (docs/piano.md, "Black keys").
    # Encoder offsets of +-2 mrad, the calibration's accuracy (a 10 mrad shoulder offset moves the fingertip
    # about 5 mm: half a black key).
    # The stiff gain profile, Kp 100 / Kd 3 (robot.gains; docs/gains.md): the prior presses through a
    # joint's friction and a load's sag sooner, and passes the robustness suite where Kp 50 did not.
    "env_overrides": (
        "reward.scales.key_press_black=1.0",
        "reward.scales.wrong_keys_black_goal=0.25",
        "actuator.encoder_offset=0.002",
        "gains=stiff",
    ),
}
"""LitePiano on one H100 (``--preset piano``): a fixed learning rate of 1e-4 after 10 iterations of critic
warm-up (the actor held on the prior while the value function learns its returns; without it the first
updates unlearn the prior, and 1e-4 beat 3e-4: docs/piano.md), 4096 envs (the keyboard's 49 keys add
constraint rows: reach's nefc 82 becomes 137 with the contact caps), a wider first layer for the 631-entry
observation, the black goal keys' extra press reward (``reward.scales.key_press_black`` 1.0: files trained
without it unlearn the prior's black-key presses) and half the cost for a wrong key at a black goal tick
(``reward.scales.wrong_keys_black_goal`` 0.25 on ``wrong_keys`` -0.5: a black press brushes its neighbours
more than a white one; held-out black recall 0.82 -> 0.88 on seed 0), the stiff gains (Kp 100, Kd 3: the
file records ``bar.gains``), encoder offsets of +-2 mrad (the
system identification's calibration accuracy; at +-10 mrad the MJX evaluation's F1 of the prior alone is
0.810, at +-2 mrad 0.827), and 8 M env steps (the C MuJoCo gate's best iterate comes within the first 2 M;
later iterates trade black presses for fewer wrong keys and add chatter: docs/piano.md, "The shipped
policy and its seeds").
"""

PIANO_ROBUST_EXTRA: tuple[str, ...] = (
    "joint_error_ema=true",  # the integral-like input (layout lite_piano_arms v2): a payload's sag is seen
    "terminate_on_cap_fault=true",  # an episode ends where the robot's supervisor would fault
)
"""The piano's own items of the robust preset. The key-pose prior folds the nominal arm's gravity into its
commands, so a 0.5 kg fingertip payload sags the fingertip onto the keys and jams a wrist at its cap (the
suite's payload rows: docs/robustness.md); the residual needs the error average to see the sag, as reach's
and the tracker's do."""

PIANO_ROBUST = robust(PIANO, "piano-robust", PIANO_ROBUST_EXTRA)
"""The ``piano`` preset with the robustness randomisation (``tasks.robust_preset.ROBUST_ENV_OVERRIDES``;
docs/robust_training.md) and ``PIANO_ROBUST_EXTRA``."""
