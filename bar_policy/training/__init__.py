"""PPO training for the MJX envs (brax or rsl-rl backend), checkpoints, evaluation and publishing.

``python train/ppo.py`` is the command line (``bar_policy.training.cli``); ``run(cfg)`` is the library entry.
"""

from bar_policy.training.config import PRESETS, TrainConfig, apply_overrides, preset

__all__ = ["PRESETS", "TrainConfig", "apply_overrides", "preset"]
