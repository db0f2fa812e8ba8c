"""Train a Lite policy with PPO on the MJX env: the same command as ``bar-train`` (same flags).

See ``bar-train --help`` (or ``python train/ppo.py --help``) and docs/training.md.
"""

from __future__ import annotations

import os
import sys

# A training process never renders: without a setting, MuJoCo's import loads its OpenGL bindings (glfw,
# cffi), about 75 ms of this command's start on the 2-core CPU. An explicit MUJOCO_GL is left alone.
os.environ.setdefault("MUJOCO_GL", "disable")

from bar_policy.training.cli import main  # after MUJOCO_GL: MuJoCo reads it when first imported

if __name__ == "__main__":
    sys.exit(main())
