"""Registry smoke test over every env: build, trace reset/step (batched and randomised too), check the
contract the trainers rely on. Traced with ``jax.eval_shape`` (no XLA compile); the numbers are checked by
the per-task tests on their compiled fixtures."""

from __future__ import annotations

import functools
import re

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from bar_policy import envs
from bar_policy.envs.base import MjxEnv
from bar_policy.tasks.registry import env_entries

EXPECTED = {
    "LiteReach": ("reach", 54, 14),
    "LiteReachNeck": ("reach", 63, 17),
    "LiteTrack": ("track", 292, 14),
}
"""(task, observation size, action size) worked out by hand for reach's and track's envs. Another task's
env is traced here with its record's task name and its layout's size, and pins its sizes in its own tests."""


def test_registry_names():
    """The env registry holds the records' envs, in registry order."""
    assert tuple(env_entries()) == envs.ALL_ENVS
    assert set(EXPECTED) <= set(envs.ALL_ENVS)
    names = re.escape(str(list(envs.ALL_ENVS)))
    with pytest.raises(ValueError, match=r"available envs: " + names):
        envs.load("LiteDance")


def test_default_env_is_the_registry_first_not_a_literal():
    """No name given: the first registered env (reach is the registration list's first task, LiteReach its
    first env), the same as bar-train's default --env."""
    from bar_policy.training.config import DEFAULT_ENV

    assert envs.DEFAULT_ENV == "LiteReach" == DEFAULT_ENV
    assert type(envs.default_config()) is type(envs.default_config("LiteReach"))


@pytest.mark.parametrize(
    "name", [pytest.param(n, marks=pytest.mark.slow) if n == "LitePiano" else n for n in envs.ALL_ENVS]
)
def test_every_env_traces_and_keeps_the_trainer_contract(name):
    env = envs.load(name)
    record = env_entries()[name][0]
    task, obs_size, act_size = EXPECTED.get(name) or (record.name, env.obs_manager.size, env.action_size)
    assert isinstance(env, MjxEnv) and env.task_name == task
    assert (env.observation_size, env.action_size) == (obs_size, act_size)
    assert env.obs_manager.size == obs_size
    assert env.episode_length == round(env.config.episode_length_s / env.dt)
    for arr in (env.kp, env.kd, env.default_pose, env.action_scale):
        assert arr.shape == (act_size,)
    # Batched and randomised, as the trainers run it (one trace covers the env's reset and step).
    keys = jax.random.split(jax.random.PRNGKey(1), 2)
    rand = functools.partial(envs.get_randomizer(name, env.config), rng=keys)
    w = envs.wrap_for_brax_training(env, episode_length=env.episode_length, randomization_fn=rand)
    s = jax.eval_shape(w.reset, keys)
    s1 = jax.eval_shape(w.step, s, jnp.zeros((2, act_size), jnp.float32))
    assert s1.obs.shape == (2, obs_size) and s1.reward.shape == (2,) and s1.done.shape == (2,)
    assert set(s1.metrics) == {f"reward/{k}" for k in env.reward_names} | set(env.metric_keys)
    # step(state) keeps the state's structure, shapes, dtypes and weak types (the training scan needs it).
    assert jax.tree_util.tree_structure(s) == jax.tree_util.tree_structure(s1)
    for a, b in zip(jax.tree_util.tree_leaves(s), jax.tree_util.tree_leaves(s1), strict=True):
        assert (a.shape, a.dtype, a.weak_type) == (b.shape, b.dtype, b.weak_type)
    assert "success_rate" in jax.eval_shape(env.eval_ratios, s1.metrics)
    # The keys training.metadata.policy_metadata writes into the file: any other would be dropped unseen.
    assert set(env.task_metadata()) <= {
        "body_names",
        "lookahead_steps",
        "dataset_repo_id",
        "command_transition_s",
        "song_lead_steps",
    }


def test_overrides_reach_robot_and_task_fields():
    cfg = envs.apply_overrides(
        envs.default_config("LiteTrack"),
        (
            "actuator.latency_steps=[0, 1]",
            "reward.scales.body_ori=0.25",
            "motion.num_clips=3",
            "episode_length_s=4",
        ),
    )
    assert cfg.actuator.latency_steps == (0, 1) and cfg.reward.scales.body_ori == 0.25
    assert cfg.motion.num_clips == 3 and cfg.episode_length == 200
    with pytest.raises(ValueError, match="clip sets"):
        envs.apply_overrides(cfg, ["motion.clip_set=mocap"])
    with pytest.raises(ValueError, match="termination_distance"):
        envs.apply_overrides(cfg, ["termination_distance=-1"])
    nominal = envs.nominal_config(cfg)
    assert nominal.motion == cfg.motion and nominal.init_noise == 0
    assert nominal.actuator.latency_steps == (0, 0)


def test_load_for_training_gives_the_env_and_the_randomiser_of_its_overridden_config():
    # One override reaches both: the env's config, and the randomiser's friction draw, whose range of
    # 0.2 to 0.2 N*m gives every robot joint exactly 0.2 N*m in every slot.
    items = ["randomization.frictionloss=[0.2, 0.2]", "randomization.link_mass_scale=null"]
    env, randomizer = envs.load_for_training("LiteReach", overrides=items)
    assert env.config == envs.load("LiteReach", overrides=items).config
    assert env.config.randomization.frictionloss == (0.2, 0.2)
    model, _ = randomizer(env.mjx_model, rng=jax.random.split(jax.random.PRNGKey(0), 3))
    joints = env.robot_index.dof
    friction = np.asarray(model.dof_frictionloss)[:, joints]
    np.testing.assert_array_equal(friction, np.full((3, len(joints)), np.float32(0.2)))
