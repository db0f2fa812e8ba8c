"""Shared, module-compiled training runs on the stand-in env (``toy_env.ToyReach``).

Each run is done once per session and reused: the brax run feeds the improvement, artifact, export and
resume tests; the rsl-rl run feeds its own tests.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).parent))

from toy_configs import TOY_BRAX, TOY_RSL, toy_config
from toy_env import ToyReach


@pytest.fixture(scope="session")
def toy_env() -> ToyReach:
    return ToyReach()


@pytest.fixture(scope="session")
def run_walls() -> dict[str, float]:
    """Wall time measured around each shared run's ``run()`` call, s (``brax`` once ``brax_run`` ran)."""
    return {}


@pytest.fixture(scope="session")
def brax_run(tmp_path_factory: pytest.TempPathFactory, toy_env: ToyReach, run_walls: dict) -> tuple:
    from bar_policy.training.run import run

    tmp = tmp_path_factory.mktemp("runs")
    cfg = toy_config(tmp, "brax", TOY_BRAX)
    t0 = time.monotonic()
    summary = run(cfg, env=toy_env)
    run_walls["brax"] = time.monotonic() - t0
    return cfg, summary


_CACHE_OPTIONS = (
    "jax_enable_compilation_cache",
    "jax_compilation_cache_dir",
    "jax_persistent_cache_min_compile_time_secs",
    "jax_persistent_cache_min_entry_size_bytes",
)


@pytest.fixture
def restore_cache_config():
    """Put jax's cache options back (the suite shares one cache, set up in tests/conftest.py)."""
    import jax

    saved = {k: getattr(jax.config, k) for k in _CACHE_OPTIONS}
    yield
    for k, v in saved.items():
        jax.config.update(k, v)


@pytest.fixture(scope="session")
def rsl_run(tmp_path_factory: pytest.TempPathFactory, toy_env: ToyReach) -> tuple:
    from bar_policy.training.run import run

    tmp = tmp_path_factory.mktemp("runs")
    cfg = toy_config(tmp, "rsl", TOY_RSL)
    return cfg, run(cfg, env=toy_env)
