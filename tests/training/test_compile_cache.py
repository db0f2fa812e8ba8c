"""The persistent compilation cache: hits counted per program, and never a stale program.

jax keys a cached executable on the lowered program itself (``jax/_src/cache_key.py``: the StableHLO module,
in which config values the program closes over are constants), jaxlib's version, the backend, XLA flags and
the compile options. So a changed config, changed code or another jax cannot be served an executable built
for the old one: each makes a new key, a miss, a fresh compile. These tests show it with the trainer's own
``Compiler`` and ``CompileStats`` on the stand-in env, whose one step is worked out by hand, in an empty
cache directory.
"""

from __future__ import annotations

from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from toy_env import ToyConfig, ToyReach

from bar_policy.training.startup.breakdown import StartupTimer
from bar_policy.training.startup.compile_cache import configure_compile_cache
from bar_policy.training.startup.compiler import Compiler, CompileStats

ACTION = np.linspace(-1.5, 1.5, 14, dtype=np.float32)
"""One action; entries beyond +-1 are clipped by the env."""


@pytest.fixture
def tmp_cache(tmp_path: Path, restore_cache_config: None) -> Path:
    """jax's persistent cache opened afresh in an empty directory, every program stored."""
    from jax.experimental.compilation_cache import compilation_cache as cc

    cc.reset_cache()  # jax opens its cache once per process: close the suite's
    path = configure_compile_cache(directory=str(tmp_path / "jax"))
    assert path is not None
    yield path
    cc.reset_cache()  # the suite's directory opens again at the next compile


def _entries(cache: Path) -> set[str]:
    """The keys of ``program`` stored in ``cache`` (jax names an entry ``jit_<function>-<hash>...``; the
    eager ``PRNGKey`` and ``asarray`` of the test store their own)."""
    return {p.name for p in cache.iterdir() if p.name.startswith("jit_program-")}


def _one_step(env: ToyReach, timer: StartupTimer, name: str) -> np.ndarray:
    """Joint positions after reset and one step of ``ACTION``, compiled through the trainer's ``Compiler``.

    Pass a fresh env object: with jax's in-memory caches cleared, nothing is reused but what the
    persistent cache holds.
    """

    def program(key: jax.Array, action: jax.Array) -> jax.Array:
        return env.step(env.reset(key), action).data["q"]

    jax.clear_caches()
    compiler = Compiler(timer)
    compiler.submit(name, jax.jit(program), jax.random.PRNGKey(0), jnp.asarray(ACTION))
    q = np.asarray(compiler.get(name)(jax.random.PRNGKey(0), jnp.asarray(ACTION)))
    compiler.close()
    return q


def _expected_q(config: ToyConfig) -> np.ndarray:
    """By hand: reset puts q at the default pose, one step moves it ``gain * action_scale * clip(a)``."""
    default = ToyReach(config)._default
    return default + config.gain * config.action_scale * np.clip(ACTION, -1.0, 1.0)


def test_same_config_hits_changed_config_compiles_afresh(tmp_cache):
    stats = CompileStats.get()
    timer = StartupTimer()
    base, changed = ToyConfig(), ToyConfig(gain=0.6)
    assert base.gain != changed.gain

    q_first = _one_step(ToyReach(base), timer, "first")
    keys_first = _entries(tmp_cache)
    assert timer.programs["first"].cache == "miss" and len(keys_first) == 1

    # The process-wide listeners count the hit too (with the test's eager ops, cached by the first call).
    before = stats.snapshot()
    q_again = _one_step(ToyReach(ToyConfig()), timer, "same config")
    after = stats.snapshot()
    again = timer.programs["same config"]
    assert again.cache == "hit" and again.cache_load_s > 0
    assert after["cache_hits"] >= before["cache_hits"] + 1 and after["cache_misses"] == before["cache_misses"]
    assert _entries(tmp_cache) == keys_first  # served from the one entry, nothing new written
    np.testing.assert_array_equal(q_again, q_first)

    q_changed = _one_step(ToyReach(changed), timer, "changed config")
    assert timer.programs["changed config"].cache == "miss"
    assert stats.snapshot()["cache_misses"] >= after["cache_misses"] + 1
    assert len(_entries(tmp_cache) - keys_first) == 1  # a key of its own

    # And each program computed its own config's step, not the other's.
    np.testing.assert_allclose(q_first, _expected_q(base), rtol=1e-6)
    np.testing.assert_allclose(q_changed, _expected_q(changed), rtol=1e-6)
    assert not np.allclose(q_changed, q_first)


def test_changed_code_and_another_jaxlib_make_new_keys(tmp_cache, monkeypatch):
    timer = StartupTimer()
    _one_step(ToyReach(), timer, "base")
    keys = _entries(tmp_cache)

    # Changed code: the same config through a subclass whose step differs (the gain applied twice).
    class Edited(ToyReach):
        def step_with_model(self, model: dict, state: object, action: jax.Array) -> object:
            return super().step_with_model({"gain": 2.0 * model["gain"]}, state, action)

    q = _one_step(Edited(ToyConfig()), timer, "edited")
    assert timer.programs["edited"].cache == "miss"
    np.testing.assert_allclose(q, _expected_q(ToyConfig(gain=2 * ToyConfig().gain)), rtol=1e-6)

    # Another jaxlib: the version string is part of the key (jax/_src/cache_key.py), so the same program
    # misses instead of loading an executable built by the installed one.
    from jax._src import cache_key

    if not hasattr(cache_key, "jaxlib_version_str"):  # pragma: no cover - a jax that hashes it elsewhere
        pytest.skip("this jax keeps its version out of jax._src.cache_key.jaxlib_version_str")
    monkeypatch.setattr(cache_key, "jaxlib_version_str", cache_key.jaxlib_version_str + ".other")
    _one_step(ToyReach(), timer, "other jaxlib")
    assert timer.programs["other jaxlib"].cache == "miss"
    assert len(_entries(tmp_cache) - keys) == 2  # the edited program's and the other jaxlib's


@pytest.mark.slow
def test_a_reward_weight_is_part_of_the_lowered_program_unless_it_is_an_argument():
    """LiteReach's step for another reward weight lowers to another module (so another cache key).

    What jax hashes for the key is this module; the same config, built afresh, lowers to the same text,
    so it hits. With the weights as an argument (``envs.reward_weights``, as the brax programs take
    them) every weight lowers to one module, so the compile cache serves it. Lowering only (about 3 s a
    program on a CPU), no compile.
    """
    from bar_policy import envs
    from bar_policy.envs.reward_weights import weights, with_weights

    def lowered_step(overrides: list[str]) -> str:
        env = envs.load("LiteReach", overrides=overrides or None)
        state = jax.eval_shape(env.reset, jax.random.PRNGKey(0))
        action = jax.ShapeDtypeStruct((env.action_size,), jnp.float32)
        return jax.jit(env.step).trace(state, action).lower().as_text()

    def lowered_weighted_step(overrides: list[str]) -> str:
        env = envs.load("LiteReach", overrides=overrides or None)
        state = jax.eval_shape(env.reset, jax.random.PRNGKey(0))
        action = jax.ShapeDtypeStruct((env.action_size,), jnp.float32)
        w = jax.tree.map(lambda x: jax.ShapeDtypeStruct((), jnp.float32), weights(env))
        step = jax.jit(lambda s, a, w: with_weights(env, w).step(s, a))
        return step.trace(state, action, w).lower().as_text()

    default = lowered_step([])
    assert lowered_step([]) == default
    assert lowered_step(["reward.scales.reach_fine=2.0"]) != default
    weighted = lowered_weighted_step([])
    assert lowered_weighted_step(["reward.scales.reach_fine=2.0", "reward.scales.success=0.6"]) == weighted
    assert lowered_weighted_step(["reward.fine_std=0.04"]) != weighted  # a kernel's length is no weight
