"""The data-parallel programs of ``train_brax`` and their pure helpers (``training.brax.ppo``).

``set_up`` makes a run's mesh, learner and programs (``SetUp``): ``make_programs`` builds the ``init`` /
``reset`` / ``rollout`` / ``update`` / ``evaluate`` programs (``training.brax.ppo`` documents each) and
``to_compile`` lists them with their abstract arguments, in the order ``startup.compiled.compile_programs``
submits them; ``slot_keys`` / ``slot_env`` give every env slot its own key and randomised model whatever
the device count. ``training.brax.state`` runs them.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import jax
import numpy as np
from jax.sharding import PartitionSpec as P

from bar_policy.envs.reward_weights import weights, with_weights
from bar_policy.envs.wrappers import BatchedEnv
from bar_policy.obs.action_prior import Prior
from bar_policy.training.brax import evaluation
from bar_policy.training.brax.learner import Learner, TrainingState, make_learner, strip_weak_type
from bar_policy.training.config import TrainConfig
from bar_policy.training.parallel import AXIS, DataParallel, make_data_parallel
from bar_policy.training.prior import action_prior
from bar_policy.training.startup.compiled import Program

__all__ = [
    "Programs",
    "SetUp",
    "make_programs",
    "set_up",
    "slot_env",
    "slot_keys",
    "to_compile",
]


def slot_keys(key: jax.Array, total: int, local: int) -> jax.Array:
    """This device's keys among ``split(key, total)``: slot ``i`` gets key ``i`` on any device count.

    Per-device code (inside ``DataParallel.sharded_jit``); ``local = total / n_devices``.
    Shape ``(local, 2)``.
    """
    keys = jax.random.split(key, total)
    return jax.lax.dynamic_slice_in_dim(keys, jax.lax.axis_index(AXIS) * local, local)


def slot_env(
    env: Any,
    wrap_fn: Callable[..., BatchedEnv],
    randomizer: Callable[..., Any] | None,
    model_keys: jax.Array,
    weights: dict[str, jax.Array] | None = None,
    **kw: Any,
) -> BatchedEnv:
    """The batched env of this device's slots, each on the model its key draws (per-device code).

    The randomised model is built inside the program from the slots' keys (a traced value, sharded with
    the slots), not closed over as a constant; ``weights``: the reward weights the batch steps with
    (``envs.reward_weights.with_weights``; None: the env's own); ``kw`` goes to ``wrap_fn`` (e.g.
    ``auto_reset=False``).
    """
    env = env if weights is None else with_weights(env, weights)
    rfn = None
    if randomizer is not None:

        def rfn(model: Any) -> Any:
            return randomizer(model, rng=model_keys)

    return wrap_fn(env, episode_length=int(env.episode_length), action_repeat=1, randomization_fn=rfn, **kw)


@dataclass(frozen=True)
class Programs:
    """The five jitted data-parallel programs of a run (before compilation; see ``ppo``'s docstring)."""

    init: Callable[..., Any]
    reset: Callable[..., Any]
    rollout: Callable[..., Any]
    update: Callable[..., Any]
    evaluate: Callable[..., Any]


@dataclass(frozen=True)
class SetUp:
    """A brax run before its programs compile: the mesh, the learner and its five programs (``set_up``)."""

    dp: DataParallel
    """The mesh over the run's devices (``training.parallel``)."""
    prior: Prior | None
    """The policy's action prior (``training.prior.action_prior``), None without one."""
    learner: Learner
    """brax's PPO as per-device functions (``brax.learner``)."""
    programs: Programs
    """The five jitted programs (``make_programs``)."""
    template: TrainingState
    """The training state's shapes (``eval_shape`` of ``learner.init``): a resumed checkpoint's structure."""
    weights: dict[str, Any]
    """The reward weights (``envs.reward_weights``), the rollout's and evaluation's last argument."""

    def to_compile(self) -> list[Program]:
        """The programs with their abstract arguments, in submission order (``to_compile``)."""
        return to_compile(self.programs, self.dp, self.template, self.weights)


def set_up(
    env: Any,
    cfg: TrainConfig,
    wrap_fn: Callable[..., BatchedEnv],
    randomizer: Callable[..., Any] | None,
    eval_env: Any | None = None,
    eval_randomizer: Callable[..., Any] | None = None,
) -> SetUp:
    """The mesh (every device, or ``distributed.max_devices_per_host``), the learner and its programs.

    Refuses, before anything is traced, a prior the env does not serve (``training.prior.action_prior``) and
    batch sizes that do not split over the devices (``DataParallel.check_divisible``). ``eval_env`` and
    ``eval_randomizer``: as ``make_programs``'.
    """
    prior = action_prior(env, cfg.network, cfg.env_name)
    dp = make_data_parallel(cfg.distributed.max_devices_per_host)
    dp.check_divisible(
        **{
            "ppo.num_envs": cfg.ppo.num_envs,
            "ppo.batch_size": cfg.ppo.batch_size,
            "eval.num_eval_envs": cfg.eval.num_eval_envs,
        }
    )
    learner = make_learner(env.observation_size, env.action_size, cfg.ppo, cfg.network, prior)
    programs = make_programs(env, cfg, learner, dp, wrap_fn, randomizer, eval_env, eval_randomizer)
    template = jax.eval_shape(learner.init, dp.abstract(np.zeros(2, np.uint32), sharded=False))
    return SetUp(dp, prior, learner, programs, template, weights(env))


def make_programs(
    env: Any,
    cfg: TrainConfig,
    learner: Learner,
    dp: DataParallel,
    wrap_fn: Callable[..., BatchedEnv],
    randomizer: Callable[..., Any] | None,
    eval_env: Any | None = None,
    eval_randomizer: Callable[..., Any] | None = None,
) -> Programs:
    """The run's ``init``, ``reset``, ``rollout``, ``update`` and ``evaluate`` programs on the mesh of ``dp``.

    ``eval_env``: the env the evaluation runs (the task's held-out variant) with ``eval_randomizer``;
    None: ``env`` with ``randomizer``.

    ``rollout`` and ``evaluate`` take the reward weights as their last argument (a replicated
    ``{term: float32 scalar}``, ``envs.reward_weights.weights(env)``), so that a compiled program serves
    any weights: a run that changes only a weight loads both from the executable cache.
    """
    ppo = cfg.ppo
    n = dp.n_devices
    envs_local, eval_local = ppo.num_envs // n, cfg.eval.num_eval_envs // n
    unrolls = ppo.batch_size * ppo.num_minibatches // ppo.num_envs
    episode_length = int(env.episode_length)

    def batch(model_keys: jax.Array, weights: dict[str, jax.Array] | None = None, **kw: Any) -> BatchedEnv:
        return slot_env(env, wrap_fn, randomizer, model_keys, weights, **kw)

    def reset(key: jax.Array, model_key: jax.Array) -> tuple[Any, jax.Array]:
        model_keys, reset_keys = (slot_keys(k, ppo.num_envs, envs_local) for k in (model_key, key))
        envs: BatchedEnv = batch(model_keys)
        return envs.reset(reset_keys), model_keys

    def iteration_keys(key: jax.Array, i: jax.Array) -> jax.Array:
        """Iteration ``i``'s ``(rollout, SGD)`` keys of an epoch keyed ``key``, this device's (shape (2, 2)).

        The epoch's key, folded with the device index, is split once per iteration (``k, k_it = split(k)``)
        and each iteration's ``k_it`` into its rollout and SGD keys. ``rollout`` and ``update`` each derive
        the chain themselves (``i`` <= a few dozen splits), so neither passes keys to the other.
        """
        k = jax.random.fold_in(key, jax.lax.axis_index(AXIS))
        k = jax.lax.fori_loop(0, i, lambda _, c: jax.random.split(c)[0], k)
        return jax.random.split(jax.random.split(k)[1])

    def rollout(
        ts: TrainingState, envs: tuple[Any, jax.Array], key: jax.Array, i: jax.Array, weights: dict
    ) -> tuple:
        env_state, model_keys = envs
        k_roll = iteration_keys(key, i)[0]
        env_state, data, stats = learner.rollout(ts, env_state, k_roll, batch(model_keys, weights), unrolls)
        return (env_state, model_keys), data, jax.lax.psum(stats, axis_name=AXIS)

    def update(ts: TrainingState, data: Any, key: jax.Array, i: jax.Array) -> tuple:
        ts, metrics = learner.update(ts, data, iteration_keys(key, i)[1])
        return strip_weak_type(ts), jax.lax.pmean(metrics, axis_name=AXIS)

    def evaluate(params: Any, key: jax.Array, model_key: jax.Array, weights: dict) -> dict[str, jax.Array]:
        keys, reset_keys = (slot_keys(k, cfg.eval.num_eval_envs, eval_local) for k in (model_key, key))
        e_env, e_rand = (env, randomizer) if eval_env is None else (eval_env, eval_randomizer)
        env_e: BatchedEnv = slot_env(e_env, wrap_fn, e_rand, keys, weights, auto_reset=False)
        state = env_e.reset(reset_keys)
        return evaluation.evaluate(learner.make_policy, params, env_e, state, key, episode_length)

    rep, shard = P(), P(AXIS)
    return Programs(
        init=dp.sharded_jit(learner.init, (rep,), rep),
        reset=dp.sharded_jit(reset, (rep, rep), shard),
        rollout=dp.sharded_jit(
            rollout, (rep, shard, rep, rep, rep), (shard, shard, rep), donate_argnums=(1,)
        ),
        update=dp.sharded_jit(update, (rep, shard, rep, rep), (rep, rep), donate_argnums=(0,)),
        evaluate=dp.sharded_jit(evaluate, (rep, rep, rep, rep), rep),
    )


def to_compile(
    programs: Programs, dp: DataParallel, template: TrainingState, weights: dict[str, Any]
) -> list[Program]:
    """The five programs with their abstract arguments, in the order they are traced and submitted.

    The reset goes first (its outputs are the rollout's inputs), the rollout (the longest compile) right
    after it, the update (its inputs are the rollout's outputs, so on a warm start it is loaded on a worker
    while the rollout is loaded here), then the small init. Nothing waits on the evaluation before the
    first epochs end, so it is traced on a worker too: on a warm compile cache its trace is a third of what
    is left of the start-up, and it overlaps the first epochs. ``template``: the training state's shapes
    (``eval_shape`` of ``learner.init``); ``weights``: the reward weights (``envs.reward_weights``).
    """
    key = dp.abstract(np.zeros(2, np.uint32), sharded=False)
    i = dp.abstract(np.zeros((), np.int32), sharded=False)
    ts = dp.abstract(template, sharded=False)
    w = dp.abstract(weights, sharded=False)

    def rollout_args(out: Any) -> tuple:
        return ts, dp.abstract(out["reset"], sharded=True), key, i, w

    def update_args(out: Any) -> tuple:
        return ts, dp.abstract(out["rollout"][1], sharded=True), key, i

    return [
        Program("reset", programs.reset, (key, key)),
        Program("rollout", programs.rollout, rollout_args),
        Program("update", programs.update, update_args, load_in_background=True),
        Program("init", programs.init, (key,)),
        Program("evaluate", programs.evaluate, (_policy_params(ts), key, key, w), background=True),
    ]


def _policy_params(ts: TrainingState) -> tuple[Any, Any]:
    """What the deterministic policy reads: ``(normalizer, policy)``."""
    return (ts.normalizer_params, ts.params.policy)
