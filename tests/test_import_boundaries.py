"""The robot side (deploy, robstride, obs, robot, tasks) imports without jax or torch."""

from __future__ import annotations

import subprocess
import sys

PROBE = r"""
import importlib, pkgutil, sys
import bar_policy.deploy, bar_policy.obs, bar_policy.robot, bar_policy.robstride, bar_policy.tasks
import bar_policy.robot.kinematics, bar_policy.robot.mjcf
mods = [m.name for m in pkgutil.walk_packages(bar_policy.deploy.__path__, "bar_policy.deploy.")]
mods += [m.name for m in pkgutil.walk_packages(bar_policy.robstride.__path__, "bar_policy.robstride.")]
for name in mods:
    importlib.import_module(name)
HEAVY = ("jax", "jaxlib", "torch", "brax", "flax", "onnx", "mujoco.mjx")
heavy = sorted(m for m in HEAVY if m in sys.modules)
print(len(mods), heavy)
"""


def test_deploy_side_imports_without_jax_or_torch() -> None:
    out = subprocess.run(
        [sys.executable, "-c", PROBE], capture_output=True, text=True, check=True, timeout=120
    ).stdout.split()
    # Every module under bar_policy.deploy and bar_policy.robstride was imported, and none pulled a
    # training dependency in.
    assert out[-1] == "[]", out
