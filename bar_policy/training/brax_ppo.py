"""The default backend: PPO on the MJX env, JAX end to end, from brax's PPO building blocks.

The algorithm is brax's (``brax.training.agents.ppo``): its networks (``make_ppo_networks``, tanh-normal
policy), its loss (``compute_ppo_loss`` with GAE), its running observation statistics and its data layout
(``batch_size * num_minibatches`` segments of ``unroll_length`` steps per iteration, ``num_updates_per_batch``
SGD passes, gradients averaged over devices with ``pmean``). The loop around them is ours, for what
``ppo.train`` cannot give: checkpoints with the optimizer state and step count (exact resume), progress
lines with success rate and ETA between evaluations, a wall-clock budget, and evaluation of the reach
success rate (the task's ``eval_ratios``) on fresh seeds with randomisation on.

Data parallelism: the training epoch is ``jax.pmap``-ed over the local devices (``num_envs`` and
``batch_size`` split evenly); under ``jax.distributed`` the same ``pmap`` spans every process's devices
and ``pmean`` averages gradients and observation statistics across hosts.
"""

from __future__ import annotations

import functools
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import flax
import jax
import jax.numpy as jnp
import numpy as np
import optax
from brax.training import types
from brax.training.acme import running_statistics, specs
from brax.training.agents.ppo import losses as ppo_losses
from brax.training.agents.ppo import networks as ppo_networks
from flax import linen

from bar_policy.envs.base import eval_ratios
from bar_policy.training.checkpoint import load_checkpoint, save_checkpoint
from bar_policy.training.config import NetworkConfig, TrainConfig
from bar_policy.training.progress import RunLogger

__all__ = ["BraxTrainResult", "TrainingState", "make_evaluator", "make_networks", "train_brax"]

_AXIS = "devices"

_ACTIVATIONS: dict[str, Callable[[jax.Array], jax.Array]] = {
    "swish": linen.swish,
    "elu": linen.elu,
    "relu": linen.relu,
    "tanh": linen.tanh,
}


@flax.struct.dataclass
class TrainingState:
    """Everything the learner carries between iterations (and what a checkpoint stores)."""

    optimizer_state: optax.OptState
    params: ppo_losses.PPONetworkParams
    normalizer_params: running_statistics.RunningStatisticsState


@dataclass(frozen=True, kw_only=True)
class BraxTrainResult:
    """Outcome of ``train_brax``."""

    params: tuple[Any, Any, Any]
    """``(normalizer, policy, value)`` params on the host (brax's layout)."""
    make_policy: Callable[..., Any]
    """brax's ``make_inference_fn(networks)``: ``make_policy(params, deterministic) -> policy(obs, key)``."""
    env_steps: int
    """Total env steps trained (including those before a resume)."""
    run_env_steps: int
    """Env steps trained in this process's run (excluding those before a resume)."""
    train_seconds: float
    """Wall time of the training loop in this run, s (compile and evaluations included)."""
    evals: list[dict[str, float]] = field(default_factory=list)
    """Evaluation records (``step``, ``time_s``, ``success_rate``, ``episode_reward``, ...)."""
    time_to_threshold_s: float | None = None
    """Seconds from logger start to the first evaluation at or above the success threshold."""
    evaluate: Callable[[Any, jax.Array], dict[str, jax.Array]] | None = None
    """The run's jitted evaluator (``make_evaluator``), batch ``num_eval_envs``."""
    num_eval_envs: int = 0
    """Episodes per ``evaluate`` call."""
    activation: str = "swish"
    """Hidden activation of the networks (for export)."""

    def final_evaluation(self, episodes: int, seed: int) -> dict[str, float]:
        """Evaluate on ``episodes`` fresh episodes (rounded up to whole evaluator batches).

        Reuses the compiled evaluator, so no new compile; rates are averaged over equal-size batches.
        """
        if self.evaluate is None:
            raise ValueError("this result has no evaluator")
        rounds = max(1, math.ceil(episodes / self.num_eval_envs))
        params = jax.device_put(self.params, jax.local_devices()[0])
        runs = [self.evaluate(params, jax.random.PRNGKey(seed + i)) for i in range(rounds)]
        out = {k: float(np.mean([float(r[k]) for r in runs])) for k in runs[0]}
        out["episodes"] = float(rounds * self.num_eval_envs)
        return out

    def export_onnx(self, metadata: Any, path: str | Any) -> dict[str, Any]:
        """Export the deterministic policy with the parity gate (``bar_policy.export.export_brax_policy``)."""
        from bar_policy.export import export_brax_policy

        return export_brax_policy(self.params, self.make_policy, metadata, path, activation=self.activation)


def make_networks(
    observation_size: int, action_size: int, net: NetworkConfig, normalize: bool
) -> ppo_networks.PPONetworks:
    """Brax PPO networks (tanh-normal policy) with our layer sizes and activation."""
    return ppo_networks.make_ppo_networks(
        observation_size,
        action_size,
        preprocess_observations_fn=running_statistics.normalize
        if normalize
        else types.identity_observation_preprocessor,
        policy_hidden_layer_sizes=net.policy_hidden,
        value_hidden_layer_sizes=net.value_hidden,
        activation=_ACTIVATIONS[net.activation],
    )


def make_evaluator(
    eval_env: Any, make_policy: Callable[..., Any], episode_length: int, num_envs: int
) -> Callable[[Any, jax.Array], dict[str, jax.Array]]:
    """A jitted deterministic evaluation: ``num_envs`` episodes of ``episode_length`` steps from reset.

    Args:
        eval_env: the env wrapped for a batch of ``num_envs`` (randomised like training).
        make_policy: brax's inference-function factory.
        episode_length: control steps per episode.
        num_envs: episodes per call.

    Returns:
        ``evaluate(params, key) -> {"episode_reward", "episode_reward_std", <ratio>...}`` (device
        scalars), one ratio per entry of the task's ``eval_ratios`` (``success_rate`` always): the sums of
        its numerators over all steps and episodes divided by the sums of its denominators.
    """
    task = eval_env.unwrapped

    def evaluate(params: Any, key: jax.Array) -> dict[str, jax.Array]:
        policy = make_policy(params, deterministic=True)
        state = eval_env.reset(jax.random.split(key, num_envs))

        def step(s: Any, _: None) -> tuple[Any, tuple[Any, ...]]:
            action, _ = policy(s.obs, key)
            ns = eval_env.step(s, action)
            sums = {k: (n.sum(), d.sum()) for k, (n, d) in eval_ratios(task, ns.metrics).items()}
            return ns, (ns.reward, sums)

        _, (rew, sums) = jax.lax.scan(step, state, None, length=episode_length)
        ret = rew.sum(axis=0)
        out = {"episode_reward": ret.mean(), "episode_reward_std": ret.std()}
        out.update({k: n.sum() / jnp.maximum(d.sum(), 1.0) for k, (n, d) in sums.items()})
        return out

    return jax.jit(evaluate)


def train_brax(
    env: Any,
    cfg: TrainConfig,
    logger: RunLogger,
    *,
    wrap_fn: Callable[..., Any],
    randomizer: Callable[..., Any] | None,
    checkpoint_dir: str | None,
    config_record: dict[str, Any] | None = None,
) -> BraxTrainResult:
    """Train with brax PPO pieces; see the module docstring.

    Args:
        env: unwrapped env (``reset``/``step``, ``observation_size``, ``action_size``, ``episode_length``).
        cfg: the run's config (``cfg.ppo``, ``cfg.network``, ``cfg.eval``, ``cfg.resume``, ...).
        logger: progress/metric sink (disabled on processes other than 0).
        wrap_fn: ``wrap_for_brax_training(env, episode_length=, action_repeat=, randomization_fn=)``.
        randomizer: ``(model, rng) -> (model, in_axes)`` domain randomiser, or None.
        checkpoint_dir: where checkpoints go (None: no checkpoints).
        config_record: JSON record stored in checkpoint sidecars.

    Returns:
        The trained params and a record of the run.
    """
    ppo = cfg.ppo
    t_start = time.monotonic()
    local_devices = jax.local_devices()
    if cfg.distributed.max_devices_per_host:
        local_devices = local_devices[: cfg.distributed.max_devices_per_host]
    n_local = len(local_devices)
    n_global = n_local * jax.process_count()
    if n_local < jax.local_device_count() and jax.process_count() > 1:
        raise ValueError("distributed.max_devices_per_host is supported in single-process runs only")
    if ppo.num_envs % n_global or ppo.batch_size % n_global:
        raise ValueError(
            f"ppo.num_envs ({ppo.num_envs}) and ppo.batch_size ({ppo.batch_size}) must be multiples of the "
            f"device count ({n_global} = {n_local} local x {jax.process_count()} processes)"
        )
    envs_per_device = ppo.num_envs // n_global
    unrolls = ppo.batch_size * ppo.num_minibatches // ppo.num_envs
    steps_per_iter = ppo.steps_per_iteration
    episode_length = int(env.episode_length)

    key = jax.random.PRNGKey(cfg.seed)
    key_init, key_local, key_rand, key_eval_rand, key_eval = jax.random.split(key, 5)
    key_local = jax.random.fold_in(key_local, jax.process_index())

    def wrap(num: int, rkey: jax.Array) -> Any:
        rfn = None if randomizer is None else functools.partial(randomizer, rng=jax.random.split(rkey, num))
        return wrap_fn(env, episode_length=episode_length, action_repeat=1, randomization_fn=rfn)

    train_env = wrap(envs_per_device, key_rand)
    eval_env = wrap(cfg.eval.num_eval_envs, key_eval_rand)

    networks = make_networks(env.observation_size, env.action_size, cfg.network, ppo.normalize_observations)
    make_policy = ppo_networks.make_inference_fn(networks)
    optimizer = optax.adam(ppo.learning_rate)
    if ppo.max_grad_norm > 0:
        optimizer = optax.chain(optax.clip_by_global_norm(ppo.max_grad_norm), optimizer)

    k_pol, k_val = jax.random.split(key_init)
    init_params = ppo_losses.PPONetworkParams(
        policy=networks.policy_network.init(k_pol), value=networks.value_network.init(k_val)
    )
    state = TrainingState(
        optimizer_state=optimizer.init(init_params),
        params=init_params,
        normalizer_params=running_statistics.init_state(specs.Array((env.observation_size,), jnp.float32)),
    )
    env_steps, iteration = 0, 0
    if cfg.resume:
        ckpt = load_checkpoint(cfg.resume, state)
        state, env_steps, iteration = ckpt.state, ckpt.env_steps, ckpt.iteration
        logger.print(f"resumed {ckpt.path} at {env_steps} env steps (iteration {iteration})")

    loss_fn = functools.partial(
        ppo_losses.compute_ppo_loss,
        ppo_network=networks,
        entropy_cost=ppo.entropy_cost,
        discounting=ppo.discounting,
        reward_scaling=ppo.reward_scaling,
        gae_lambda=ppo.gae_lambda,
        clipping_epsilon=ppo.clipping_epsilon,
        normalize_advantage=True,
        vf_coefficient=ppo.vf_loss_coefficient,
    )
    grad_fn = jax.value_and_grad(loss_fn, has_aux=True)

    def sgd_pass(carry: tuple, _: None, data: types.Transition, normalizer: Any) -> tuple:
        opt_state, params, k = carry
        k, k_perm, k_mb = jax.random.split(k, 3)

        def shuffle(x: jax.Array) -> jax.Array:
            x = jax.random.permutation(k_perm, x)
            return x.reshape((ppo.num_minibatches, -1, *x.shape[1:]))

        def minibatch(c: tuple, mb: types.Transition) -> tuple:
            o, p, kk = c
            kk, k_loss = jax.random.split(kk)
            (_, metrics), grads = grad_fn(p, normalizer, mb, k_loss)
            grads = jax.lax.pmean(grads, axis_name=_AXIS)
            updates, o = optimizer.update(grads, o, p)
            return (o, optax.apply_updates(p, updates), kk), metrics

        (opt_state, params, _), metrics = jax.lax.scan(
            minibatch, (opt_state, params, k_mb), jax.tree_util.tree_map(shuffle, data)
        )
        return (opt_state, params, k), metrics

    def iteration_fn(carry: tuple, _: None) -> tuple:
        ts, env_state, k = carry
        k, k_roll, k_sgd = jax.random.split(k, 3)
        policy = make_policy((ts.normalizer_params, ts.params.policy, ts.params.value))

        def env_step(c: tuple, _: None) -> tuple:
            s, kk = c
            kk, k_act = jax.random.split(kk)
            action, extras = policy(s.obs, k_act)
            ns = train_env.step(s, action)
            num, den = eval_ratios(env, ns.metrics)["success_rate"]
            tr = types.Transition(
                observation=s.obs,
                action=action,
                reward=ns.reward,
                discount=1.0 - ns.done,
                next_observation=ns.obs,
                extras={"policy_extras": extras, "state_extras": {"truncation": ns.info["truncation"]}},
            )
            return (ns, kk), (tr, jnp.stack([ns.reward.sum(), num.sum(), den.sum()]))

        def unroll(c: tuple, _: None) -> tuple:
            return jax.lax.scan(env_step, c, None, length=ppo.unroll_length)

        (env_state, _), (data, stats) = jax.lax.scan(unroll, (env_state, k_roll), None, length=unrolls)
        # (unrolls, T, envs, ...) -> (unrolls * envs, T, ...)
        data = jax.tree_util.tree_map(lambda x: jnp.swapaxes(x, 1, 2), data)
        data = jax.tree_util.tree_map(lambda x: x.reshape((-1, *x.shape[2:])), data)
        normalizer = ts.normalizer_params
        if ppo.normalize_observations:
            normalizer = running_statistics.update(normalizer, data.observation, pmap_axis_name=_AXIS)
        (opt_state, params, _), metrics = jax.lax.scan(
            functools.partial(sgd_pass, data=data, normalizer=normalizer),
            (ts.optimizer_state, ts.params, k_sgd),
            None,
            length=ppo.num_updates_per_batch,
        )
        ts = TrainingState(optimizer_state=opt_state, params=params, normalizer_params=normalizer)
        return (ts, env_state, k), (jax.tree_util.tree_map(jnp.mean, metrics), stats.sum(axis=(0, 1)))

    total_iters = math.ceil(ppo.num_timesteps / steps_per_iter)
    periods = max((cfg.eval.num_evals - 1) * _LINES_PER_EVAL, 1)
    iters_per_epoch = cfg.log_every_iterations or max(1, math.ceil(total_iters / periods))

    def epoch(ts: TrainingState, env_state: Any, k: jax.Array) -> tuple:
        (ts, env_state, _), (metrics, stats) = jax.lax.scan(
            iteration_fn, (ts, env_state, k), None, length=iters_per_epoch
        )
        metrics = jax.lax.pmean(jax.tree_util.tree_map(jnp.mean, metrics), axis_name=_AXIS)
        stats = jax.lax.psum(stats.sum(axis=0), axis_name=_AXIS)
        return ts, env_state, metrics, stats

    # Without max_devices_per_host, pmap's default device set (every local device; under jax.distributed
    # the collective spans all processes) is used, as brax does; an explicit subset is single-process only.
    dev_kw = {} if n_local == jax.local_device_count() else {"devices": local_devices}
    p_epoch = jax.pmap(epoch, axis_name=_AXIS, donate_argnums=(0, 1), **dev_kw)
    p_reset = jax.pmap(train_env.reset, axis_name=_AXIS, **dev_kw)
    evaluate = make_evaluator(eval_env, make_policy, episode_length, cfg.eval.num_eval_envs)

    key_local, k_reset = jax.random.split(jax.random.fold_in(key_local, iteration))
    reset_keys = jax.random.split(k_reset, n_local * envs_per_device).reshape(n_local, envs_per_device, 2)
    env_state = p_reset(reset_keys)
    # Replicate through a pmap so the first epoch call sees the same input sharding as later ones (one
    # compile instead of two).
    ts = jax.pmap(lambda x: x, **dev_kw)(
        _strip_weak_type(jax.tree_util.tree_map(lambda x: np.stack([np.asarray(x)] * n_local), state))
    )

    is_main = jax.process_index() == 0
    evals: list[dict[str, float]] = []
    time_to_threshold: list[float] = []

    def host_params() -> tuple[Any, Any, Any]:
        s = jax.tree_util.tree_map(_first_replica, ts)
        return (s.normalizer_params, s.params.policy, s.params.value)

    def run_eval(step: int) -> None:
        if not is_main:
            return
        k = jax.random.fold_in(key_eval, step)
        m = {k2: float(v) for k2, v in evaluate(jax.device_put(host_params(), local_devices[0]), k).items()}
        logger.record_eval(step, m, evals, time_to_threshold, cfg.eval.success_threshold)

    def checkpoint(step: int, it: int) -> None:
        if is_main and checkpoint_dir is not None:
            s = jax.tree_util.tree_map(_first_replica, ts)
            save_checkpoint(checkpoint_dir, s, env_steps=step, iteration=it, extra=config_record)

    if iteration == 0:
        run_eval(0)
    start_steps = env_steps
    epochs_done = 0
    t_loop = time.monotonic()
    while iteration < total_iters:
        key_local, k_epoch = jax.random.split(key_local)
        t0 = time.monotonic()
        ts, env_state = _strip_weak_type((ts, env_state))
        ts, env_state, metrics, stats = p_epoch(ts, env_state, jax.random.split(k_epoch, n_local))
        metrics = {k: float(v[0]) for k, v in metrics.items()}
        stats = np.asarray(stats[0])
        dt = time.monotonic() - t0
        iteration += iters_per_epoch
        env_steps += iters_per_epoch * steps_per_iter
        epochs_done += 1
        sps = iters_per_epoch * steps_per_iter / dt
        steps_in_epoch = iters_per_epoch * steps_per_iter
        train_metrics = {
            **{f"loss/{k}": v for k, v in metrics.items()},
            "episode_reward": float(stats[0]) / steps_in_epoch * episode_length,
            "success_rate": float(stats[1]) / max(float(stats[2]), 1.0),
            "sps": sps,
        }
        logger.log(env_steps, train_metrics, kind="train")
        logger.progress(env_steps, sps, train_metrics)
        over_budget = cfg.max_minutes > 0 and logger.elapsed() > 60 * cfg.max_minutes
        if jax.process_count() > 1:
            from jax.experimental import multihost_utils

            over_budget = bool(multihost_utils.broadcast_one_to_all(np.asarray(over_budget)))
        last = iteration >= total_iters or over_budget
        if last or epochs_done % _LINES_PER_EVAL == 0:
            run_eval(env_steps)
            n_evals = epochs_done // _LINES_PER_EVAL
            if last or (cfg.checkpoint_every and n_evals % cfg.checkpoint_every == 0):
                checkpoint(env_steps, iteration)
        if over_budget and not iteration >= total_iters:
            logger.print(f"stopping: wall-clock budget of {cfg.max_minutes} min reached")
            break
    train_seconds = time.monotonic() - t_start
    if epochs_done:
        logger.print(
            f"trained {env_steps - start_steps:,} env steps in {time.monotonic() - t_loop:.1f} s of loop "
            f"({train_seconds:.1f} s with setup and compile)"
        )
    return BraxTrainResult(
        params=host_params(),
        make_policy=make_policy,
        env_steps=env_steps,
        run_env_steps=env_steps - start_steps,
        train_seconds=train_seconds,
        evals=evals,
        time_to_threshold_s=time_to_threshold[0] if time_to_threshold else None,
        evaluate=evaluate,
        num_eval_envs=cfg.eval.num_eval_envs,
        activation=cfg.network.activation,
    )


def _strip_weak_type(tree: Any) -> Any:
    """Same tree with weak types removed, so the first and later epoch calls share one compile."""
    return jax.tree_util.tree_map(lambda x: jnp.asarray(x).astype(jnp.asarray(x).dtype), tree)


def _first_replica(x: Any) -> np.ndarray:
    """Device 0's copy of a replicated (leading device axis) array, on the host."""
    if hasattr(x, "addressable_shards"):
        return np.asarray(x.addressable_shards[0].data[0])
    return np.asarray(x[0])


_LINES_PER_EVAL = 2
"""Progress lines (training epochs) per evaluation period."""
