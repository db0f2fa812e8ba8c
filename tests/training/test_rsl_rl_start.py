"""The rsl-rl start: its jax programs are submitted before torch, rsl_rl and tensordict are imported.

Each check runs in a fresh interpreter (this test process has torch imported already), which exits as soon
as it has what it checks (``os._exit``: the compiles on the worker threads are not waited for).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

HERE = Path(__file__).parent
REPO = HERE.parents[1]

TORCH_SIDE = ("torch", "rsl_rl", "tensordict")

PROGRAMS = ["train reset", "train step", "eval reset", "eval step", "eval quality"]
"""Both envs' programs, in the order ``prepare_rsl_rl`` submits them (the evaluation env alone measures the
quality figures)."""

PRELUDE = f"""
import json, os, sys
sys.path.insert(0, {str(HERE)!r})
from pathlib import Path
from toy_configs import TOY_RSL, toy_config
from toy_env import ToyReach
"""


def _run(script: str, tmp_path: Path) -> dict:
    env = {**os.environ, "JAX_PLATFORMS": "cpu", "PYTHONPATH": str(REPO)}
    out = subprocess.run(
        [sys.executable, "-c", PRELUDE + script],
        capture_output=True,
        text=True,
        cwd=tmp_path,
        env=env,
        timeout=240,
    )
    assert out.returncode == 0, out.stderr[-4000:]
    # The result goes to a file, not stdout: the compile threads print their progress lines there while
    # the script runs, and a line of theirs can land in the middle of a printed result.
    return json.loads((tmp_path / "result.json").read_text())


@pytest.mark.slow
def test_prepare_submits_every_program_without_importing_torch(tmp_path):
    got = _run(
        f"""
from bar_policy.training.rsl_rl.programs import prepare_rsl_rl
from bar_policy.training.startup.breakdown import StartupTimer
from bar_policy.training.startup.session import StartUp
timer = StartupTimer()
cfg = toy_config(Path({str(tmp_path)!r}), "prep", TOY_RSL)
prepare_rsl_rl(ToyReach(), cfg, randomizer=None, start=StartUp(timer=timer))
loaded = [m for m in {TORCH_SIDE!r} if m in sys.modules]
Path("result.json").write_text(json.dumps({{"programs": list(timer.programs), "loaded": loaded}}))
os._exit(0)
""",
        tmp_path,
    )
    assert got == {"programs": PROGRAMS, "loaded": []}


@pytest.mark.slow
def test_run_submits_the_programs_before_importing_torch(tmp_path):
    """``run`` on the rsl-rl backend: every program is submitted with none of torch's side imported, then
    ``rsl_rl.backend`` (which imports torch) is imported (stopped there, which ends the run)."""
    got = _run(
        f"""
import importlib.abc
from bar_policy.training.startup import compiler as startup
events = []
def torch_loaded():
    return [m for m in {TORCH_SIDE!r} if m in sys.modules]
submit = startup.Compiler.submit
def recording(self, name, *args, **kw):
    events.append([name, torch_loaded()])
    return submit(self, name, *args, **kw)
startup.Compiler.submit = recording
class Stop(BaseException):
    pass
class Watch(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        if name == "bar_policy.training.rsl_rl.backend":
            events.append([name, torch_loaded()])
            raise Stop(name)
        return None
sys.meta_path.insert(0, Watch())
from bar_policy.training.run import run
cfg = toy_config(Path({str(tmp_path)!r}), "order", TOY_RSL)
try:
    run(cfg, env=ToyReach())
except Stop:
    pass
Path("result.json").write_text(json.dumps({{"events": events}}))
os._exit(0)
""",
        tmp_path,
    )
    assert got["events"] == [[name, []] for name in [*PROGRAMS, "bar_policy.training.rsl_rl.backend"]]
