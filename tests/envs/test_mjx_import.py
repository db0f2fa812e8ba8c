"""Importing the envs prints nothing about MJX's optional Warp backend (``bar_policy._mjx_quiet``)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

from bar_policy._mjx_quiet import drop_warp_notice

REPO = Path(__file__).resolve().parents[2]


def test_only_the_warp_not_installed_lines_are_dropped():
    text = (
        "Failed to import warp: No module named 'warp'\n"
        "Failed to import mujoco_warp: No module named 'warp'\n"
        "something else mujoco printed\n"
        "Failed to import warp: CUDA driver too old\n"  # Warp installed but broken: worth seeing
        "Failed to import mujoco_warp: No module named 'mujoco_warp._src'\n"
    )
    assert drop_warp_notice(text) == (
        "something else mujoco printed\n"
        "Failed to import warp: CUDA driver too old\n"
        "Failed to import mujoco_warp: No module named 'mujoco_warp._src'\n"
    )


def test_importing_the_envs_prints_no_warp_notice():
    path = os.pathsep.join(filter(None, [str(REPO), os.environ.get("PYTHONPATH")]))
    env = dict(os.environ, PYTHONPATH=path)
    probe = "import bar_policy.envs, mujoco.mjx, sys; print('mjx' if 'mujoco.mjx' in sys.modules else '')"
    out = subprocess.run(
        [sys.executable, "-c", probe], capture_output=True, text=True, env=env, check=True, timeout=300
    )
    assert out.stdout == "mjx\n"  # mujoco.mjx imported, and nothing else on stdout
    assert "warp" not in out.stderr.lower()
