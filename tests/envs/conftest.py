"""Shared, compiled-once env fixtures (CPU JIT of mjx.step takes tens of seconds per function)."""

from __future__ import annotations

import dataclasses
import functools
import sys
from pathlib import Path

import jax
import pytest

sys.path.insert(0, str(Path(__file__).parent))  # env_support

from env_support import BATCH

from bar_policy import envs


@pytest.fixture(scope="session")
def nominal_env():
    """LiteReach with every randomisation and noise off (implicit damping, quantisation, saturation on)."""
    return envs.load("LiteReach", config=envs.nominal_config())


@pytest.fixture(scope="session")
def nominal_fns(nominal_env):
    """(jit reset, jit step) of the nominal env, unbatched."""
    return jax.jit(nominal_env.reset), jax.jit(nominal_env.step)


@pytest.fixture(scope="session")
def dr_env():
    """The training config (all randomisation on) with 1 s episodes so a 10 s rollout auto-resets."""
    return envs.load(
        "LiteReach", overrides=["episode_length_s=1.0", "resample_period_s=0.5", "target_transition_s=0.2"]
    )


@pytest.fixture(scope="session")
def wrapped(dr_env):
    """(wrapper, jit reset, jit step) at batch BATCH with model randomisation."""
    keys = jax.random.split(jax.random.PRNGKey(42), BATCH)
    rand = functools.partial(envs.get_randomizer("LiteReach", dr_env.config), rng=keys)
    w = envs.wrap_for_brax_training(dr_env, episode_length=dr_env.episode_length, randomization_fn=rand)
    return w, jax.jit(w.reset), jax.jit(w.step)


@pytest.fixture(scope="session")
def explicit_env():
    """Nominal config with the explicit (ros2_control-exact) damping treatment."""
    cfg = envs.nominal_config()
    return envs.load(
        "LiteReach",
        config=dataclasses.replace(cfg, actuator=dataclasses.replace(cfg.actuator, damping="explicit")),
    )


@pytest.fixture(scope="session")
def track_clips():
    """A 3-frame clip worked by hand (piano_ready + 0.01 rad per frame on every joint), and a gesture."""
    import numpy as np

    from bar_policy.motion import Clip, gesture
    from bar_policy.robot.constants import load_robot

    piano = load_robot("arms").pose("piano_ready")
    tiny = Clip.make("tiny", 50.0, piano + 0.01 * np.arange(3)[:, None])
    return (tiny, gesture("hanging_to_piano_ready"))


@pytest.fixture(scope="session")
def track_env(track_clips):
    """LiteTrack with every randomisation and noise off, on ``track_clips``."""
    return envs.LiteTrack(envs.nominal_config(envs.default_config("LiteTrack")), clips=track_clips)


@pytest.fixture(scope="session")
def track_fns(track_env):
    """(jit reset, jit step, jit reset_at) of ``track_env``, unbatched."""
    return jax.jit(track_env.reset), jax.jit(track_env.step), jax.jit(track_env.reset_at)
