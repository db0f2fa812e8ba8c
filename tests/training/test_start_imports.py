"""What ``python train/ppo.py`` (brax backend, LiteReach: the defaults) imports before it trains.

The command runs in a fresh interpreter up to the end of its env build (``run``'s run-directory step,
``open_run``, is replaced by a stop): the CLI's imports and parsing, ``run``'s imports phase and the env
build. By then it has the training stack (jax, MJX, flax, brax's training code) and none of what the brax
start does not use: torch and the rsl-rl backend's packages, the ONNX export's (imported when the policy is
exported), TensorBoard (the run's logger imports tensorboardX later, without torch), the deploy side's log
and plot libraries.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]

NOT_BEFORE_TRAINING = (
    "torch",
    "rsl_rl",
    "tensordict",
    "onnx",
    "onnxruntime",
    "onnxscript",
    "tensorboard",
    "tensorboardX",
    "matplotlib",
    "mcap",
    "mcap_ros2",
)
NEEDED = ("jax", "mujoco.mjx", "flax", "brax.training", "bar_policy.tasks.reach.env")

PROBE = """
import contextlib, json, os, sys
from bar_policy.training.cli import parse_config
cfg = parse_config(sys.argv[1:])
from bar_policy.training import run as run_mod
class StopError(Exception):
    pass
def stop(cfg, env, *args):
    with open("result.json", "w") as f:  # not stdout: compile threads may print progress mid-line
        json.dump({"env": type(env).__name__, "modules": sorted(sys.modules)}, f)
    raise StopError
run_mod.open_run = stop
with contextlib.suppress(StopError):
    run_mod.run(cfg)
sys.stdout.flush()
os._exit(0)
"""


def test_the_brax_start_imports_no_torch_onnx_or_tensorboard(tmp_path: Path) -> None:
    env = {**os.environ, "JAX_PLATFORMS": "cpu", "PYTHONPATH": str(REPO)}
    args = ["--runs-dir", str(tmp_path / "runs"), "--compile-cache-dir", str(tmp_path / "cache")]
    out = subprocess.run(
        [sys.executable, "-c", PROBE, *args],
        capture_output=True,
        text=True,
        cwd=tmp_path,
        env=env,
        timeout=300,
    )
    assert out.returncode == 0, out.stderr[-4000:]
    got = json.loads((tmp_path / "result.json").read_text())
    modules = set(got["modules"])
    assert got["env"] == "LiteReach"
    assert [m for m in NEEDED if m not in modules] == []  # it did reach the end of the env build
    loaded = sorted(m for m in modules if m.partition(".")[0] in NOT_BEFORE_TRAINING)
    assert loaded == []
