"""Train a Lite policy with PPO on the MJX env: the same command as ``bar-train`` (same flags).

See ``bar-train --help`` (or ``python train/ppo.py --help``) and docs/training.md.
"""

from __future__ import annotations

import sys

from bar_policy.training.cli import main

if __name__ == "__main__":
    sys.exit(main())
