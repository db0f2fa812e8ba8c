"""Shared, module-compiled training runs on the stand-in env (``toy_env.ToyReach``).

Each run is done once per session and reused: the brax run feeds the improvement, artifact, export and
resume tests; the rsl-rl run feeds its own tests.
"""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).parent))

from toy_configs import TOY_BRAX, TOY_RSL, toy_config
from toy_env import ToyReach


@pytest.fixture(scope="session")
def toy_env() -> ToyReach:
    return ToyReach()


@pytest.fixture(scope="session")
def brax_run(tmp_path_factory: pytest.TempPathFactory, toy_env: ToyReach) -> tuple:
    from bar_policy.training.run import run

    tmp = tmp_path_factory.mktemp("runs")
    cfg = toy_config(tmp, "brax", TOY_BRAX)
    return cfg, run(cfg, env=toy_env)


@pytest.fixture(scope="session")
def rsl_run(tmp_path_factory: pytest.TempPathFactory, toy_env: ToyReach) -> tuple:
    from bar_policy.training.run import run

    tmp = tmp_path_factory.mktemp("runs")
    cfg = toy_config(tmp, "rsl", TOY_RSL)
    return cfg, run(cfg, env=toy_env)
