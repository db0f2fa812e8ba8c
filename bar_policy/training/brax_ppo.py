"""The default backend: PPO on the MJX env, JAX end to end, data-parallel over every device.

The algorithm is brax's (``bar_policy.training.learner``: networks, loss, running statistics, data layout).
The loop around it is ours, for what ``ppo.train`` cannot give: checkpoints with the optimizer state and
step count (exact resume), progress lines with success rate and ETA, a wall-clock budget, the task's
evaluation ratios on fresh seeds, several hosts, and a fast start.

Programs (``jit`` of ``shard_map`` over the mesh of ``bar_policy.training.parallel``; env slots sharded,
learner state replicated), each compiled once, ahead of time and concurrently (``startup.Compiler``):

- ``init(key) -> state``: fresh params, Adam state, normaliser.
- ``reset(key, model_key) -> envs``: every env slot reset, with its randomised model's key kept beside its
  state. Slot ``i`` of ``num_envs`` gets key ``i`` of ``split(key, num_envs)`` whatever the device count, so
  every slot has its own model over the whole global batch (and 1, 2 or 8 devices draw the same models).
- ``epoch(state, envs, key) -> state, envs, losses, sums``: ``iters_per_epoch`` PPO iterations in one
  call (one host sync per progress line); state and envs are donated.
- ``evaluate(params, key, model_key) -> metrics``: one deterministic episode in each of ``num_eval_envs``
  slots (sharded too), without the in-step reset; every process takes part.

The evaluation is traced and compiled on a worker thread, and the evaluation at step 0 (on the initial
params, re-created) runs at the first epoch end where it is ready, so the training start waits for neither
its trace nor its compile. Each evaluation that ranks above every earlier one keeps a host copy of its
params (``bar_policy.training.best``): ``BraxTrainResult.best``.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import jax
import numpy as np
from jax.sharding import PartitionSpec as P

from bar_policy.obs.action_prior import ActionPrior
from bar_policy.training.best import BestIterate, BestKeeper
from bar_policy.training.checkpoint import load_checkpoint, save_checkpoint
from bar_policy.training.config import NetworkConfig, TrainConfig
from bar_policy.training.learner import Learner, TrainingState, make_learner, make_networks, strip_weak_type
from bar_policy.training.parallel import AXIS, DataParallel, barrier, make_data_parallel
from bar_policy.training.progress import RunLogger, next_would_overrun
from bar_policy.training.startup import Compiler, CompileStats, StartupTimer

__all__ = [
    "BraxTrainResult",
    "Programs",
    "TrainingState",
    "action_prior",
    "epoch_iterations",
    "host_key",
    "make_networks",
    "make_programs",
    "slot_env",
    "slot_keys",
    "train_brax",
]

_LINES_PER_EVAL = 2
"""Progress lines (training epochs) per evaluation period."""


def host_key(seed: int, *path: int) -> np.ndarray:
    """A raw threefry key (uint32[2]) derived on the host from ``seed`` and a path of ints (no device op)."""
    return np.random.default_rng([seed, *path]).integers(0, 2**32, 2, dtype=np.uint32)


_K_INIT, _K_MODEL, _K_RESET, _K_EPOCH, _K_EVAL, _K_EVAL_MODEL = range(6)


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
    evaluator: Callable[[Any, int], dict[str, float]] | None = None
    """``evaluator(host_params, seed)``: the run's compiled evaluation (``num_eval_envs`` episodes)."""
    num_eval_envs: int = 0
    """Episodes per ``evaluator`` call."""
    activation: str = "swish"
    """Hidden activation of the networks (for export)."""
    best: BestIterate | None = None
    """The best evaluated iterate of this run (``bar_policy.training.best``); None when nothing was
    evaluated after training started."""
    prior: ActionPrior | None = None
    """The policy's action prior (``NetworkConfig.action_prior``; for export), None without one."""

    def at(self, params: tuple[Any, Any, Any]) -> BraxTrainResult:
        """The same result with other parameters (e.g. ``best.params``), to evaluate or export them."""
        return dataclasses.replace(self, params=params)

    def final_evaluation(self, episodes: int, seed: int) -> dict[str, float]:
        """Evaluate on ``episodes`` fresh episodes (rounded up to whole evaluator batches).

        Reuses the compiled evaluator, so no new compile; rates are averaged over equal-size batches. Under
        ``jax.distributed`` every process must call it (the evaluation is one program over all devices).
        """
        if self.evaluator is None:
            raise ValueError("this result has no evaluator")
        rounds = max(1, math.ceil(episodes / self.num_eval_envs))
        runs = [self.evaluator(self.params, seed + i) for i in range(rounds)]
        out = {k: float(np.mean([r[k] for r in runs])) for k in runs[0]}
        out["episodes"] = float(rounds * self.num_eval_envs)
        return out

    def export_onnx(self, metadata: Any, path: str | Any) -> dict[str, Any]:
        """Export the deterministic policy with the parity gate (``bar_policy.export.export_brax_policy``)."""
        from bar_policy.export import export_brax_policy

        return export_brax_policy(
            self.params, self.make_policy, metadata, path, activation=self.activation, prior=self.prior
        )


def action_prior(env: Any, net: NetworkConfig) -> ActionPrior | None:
    """The env's action prior that ``net.action_prior`` asks for (``LiteRobotEnv.action_prior``), or None."""
    if net.action_prior == "none":
        return None
    return env.action_prior(net.prior_lead_steps)


def epoch_iterations(cfg: TrainConfig) -> int:
    """Training iterations per compiled epoch (one progress line).

    ``log_every_iterations``, or when it is 0 about ``_LINES_PER_EVAL`` lines per evaluation period.
    """
    total_iters = math.ceil(cfg.ppo.num_timesteps / cfg.ppo.steps_per_iteration)
    periods = max((cfg.eval.num_evals - 1) * _LINES_PER_EVAL, 1)
    return cfg.log_every_iterations or max(1, math.ceil(total_iters / periods))


def slot_keys(key: jax.Array, total: int, local: int) -> jax.Array:
    """This device's keys among ``split(key, total)``: slot ``i`` gets key ``i`` on any device count.

    Per-device code (inside ``DataParallel.map``); ``local = total / n_devices``. Shape ``(local, 2)``.
    """
    keys = jax.random.split(key, total)
    return jax.lax.dynamic_slice_in_dim(keys, jax.lax.axis_index(AXIS) * local, local)


def slot_env(
    env: Any,
    wrap_fn: Callable[..., Any],
    randomizer: Callable[..., Any] | None,
    model_keys: jax.Array,
    **kw: Any,
) -> Any:
    """The batched env of this device's slots, each on the model its key draws (per-device code).

    The randomised model is built inside the program from the slots' keys (a traced value, sharded with
    the slots), not closed over as a constant; ``kw`` goes to ``wrap_fn`` (e.g. ``auto_reset=False``).
    """
    rfn = None
    if randomizer is not None:

        def rfn(model: Any) -> Any:
            return randomizer(model, rng=model_keys)

    return wrap_fn(env, episode_length=int(env.episode_length), action_repeat=1, randomization_fn=rfn, **kw)


@dataclass(frozen=True)
class Programs:
    """The four jitted data-parallel programs of a run (before compilation; see the module docstring)."""

    init: Callable[..., Any]
    reset: Callable[..., Any]
    epoch: Callable[..., Any]
    evaluate: Callable[..., Any]


def make_programs(
    env: Any,
    cfg: TrainConfig,
    learner: Learner,
    dp: DataParallel,
    wrap_fn: Callable[..., Any],
    randomizer: Callable[..., Any] | None,
    iters_per_epoch: int,
    eval_env: Any | None = None,
    eval_randomizer: Callable[..., Any] | None = None,
) -> Programs:
    """The run's ``init``, ``reset``, ``epoch`` and ``evaluate`` programs on the mesh of ``dp``.

    ``eval_env``: the env the evaluation runs (the task's held-out variant) with ``eval_randomizer``;
    None: ``env`` with ``randomizer``.
    """
    ppo = cfg.ppo
    n = dp.n_devices
    envs_local, eval_local = ppo.num_envs // n, cfg.eval.num_eval_envs // n
    unrolls = ppo.batch_size * ppo.num_minibatches // ppo.num_envs
    episode_length = int(env.episode_length)

    def batch(model_keys: jax.Array, **kw: Any) -> Any:
        return slot_env(env, wrap_fn, randomizer, model_keys, **kw)

    def reset(key: jax.Array, model_key: jax.Array) -> tuple[Any, jax.Array]:
        model_keys = slot_keys(model_key, ppo.num_envs, envs_local)
        return batch(model_keys).reset(slot_keys(key, ppo.num_envs, envs_local)), model_keys

    def epoch(ts: TrainingState, envs: tuple[Any, jax.Array], key: jax.Array) -> tuple:
        env_state, model_keys = envs
        env_b = batch(model_keys)
        key = jax.random.fold_in(key, jax.lax.axis_index(AXIS))

        def body(c: tuple, _: None) -> tuple:
            ts, s, k = c
            k, k_it = jax.random.split(k)
            ts, s, metrics, stats = learner.iteration(ts, s, k_it, env_b, unrolls)
            return (ts, s, k), (metrics, stats)

        (ts, env_state, _), (metrics, stats) = jax.lax.scan(
            body, (ts, env_state, key), None, length=iters_per_epoch
        )
        metrics = jax.lax.pmean(jax.tree.map(lambda x: x.mean(), metrics), axis_name=AXIS)
        stats = jax.lax.psum(stats.sum(axis=0), axis_name=AXIS)
        return strip_weak_type(ts), (env_state, model_keys), metrics, stats

    def evaluate(params: Any, key: jax.Array, model_key: jax.Array) -> dict[str, jax.Array]:
        keys = slot_keys(model_key, cfg.eval.num_eval_envs, eval_local)
        e_env, e_rand = (env, randomizer) if eval_env is None else (eval_env, eval_randomizer)
        env_e = slot_env(e_env, wrap_fn, e_rand, keys, auto_reset=False)
        state = env_e.reset(slot_keys(key, cfg.eval.num_eval_envs, eval_local))
        return learner.evaluate(params, env_e, state, key, episode_length)

    rep, shard = P(), P(AXIS)
    return Programs(
        init=dp.map(learner.init, (rep,), rep),
        reset=dp.map(reset, (rep, rep), shard),
        epoch=dp.map(epoch, (rep, shard, rep), (rep, shard, rep, rep), donate_argnums=(0, 1)),
        evaluate=dp.map(evaluate, (rep, rep, rep), rep),
    )


def _host_params(host: TrainingState) -> tuple[Any, Any, Any]:
    """``(normalizer, policy, value)`` of a host copy of the training state (brax's layout)."""
    return (host.normalizer_params, host.params.policy, host.params.value)


def _policy_params(ts: TrainingState) -> tuple[Any, Any]:
    """What the deterministic policy reads: ``(normalizer, policy)``."""
    return (ts.normalizer_params, ts.params.policy)


def train_brax(
    env: Any,
    cfg: TrainConfig,
    logger: RunLogger,
    *,
    wrap_fn: Callable[..., Any],
    randomizer: Callable[..., Any] | None,
    checkpoint_dir: str | None,
    config_record: dict[str, Any] | None = None,
    timer: StartupTimer | None = None,
    eval_env: Any | None = None,
    eval_randomizer: Callable[..., Any] | None = None,
) -> BraxTrainResult:
    """Train with brax PPO pieces on every device; see the module docstring.

    Args:
        env: unwrapped env (``reset``/``step``, ``observation_size``, ``action_size``, ``episode_length``).
        cfg: the run's config (``cfg.ppo``, ``cfg.network``, ``cfg.eval``, ``cfg.resume``, ...).
        logger: progress/metric sink (disabled on processes other than 0).
        wrap_fn: ``wrap_for_brax_training(env, episode_length=, action_repeat=, randomization_fn=)``.
        randomizer: ``(model, rng) -> (model, in_axes)`` domain randomiser, or None.
        checkpoint_dir: where checkpoints go (None: no checkpoints).
        config_record: JSON record stored in checkpoint sidecars.
        timer: start-up breakdown to add the compile phases to (printed after the first epoch).
        eval_env: the env every evaluation runs (the task's held-out variant, ``evaluation_env()``) with
            ``eval_randomizer``; None: ``env`` with ``randomizer``.
        eval_randomizer: the model randomiser of ``eval_env`` (None: its nominal model).

    Returns:
        The trained params and a record of the run.
    """
    ppo = cfg.ppo
    t_start = time.monotonic()
    timer = timer or StartupTimer()
    stats0 = CompileStats.get().snapshot()
    dp = make_data_parallel(cfg.distributed.max_devices_per_host)
    dp.check_divisible(
        **{
            "ppo.num_envs": ppo.num_envs,
            "ppo.batch_size": ppo.batch_size,
            "eval.num_eval_envs": cfg.eval.num_eval_envs,
        }
    )
    steps_per_iter = ppo.steps_per_iteration
    total_iters = math.ceil(ppo.num_timesteps / steps_per_iter)
    iters_per_epoch = epoch_iterations(cfg)

    prior = action_prior(env, cfg.network)
    learner = make_learner(env.observation_size, env.action_size, ppo, cfg.network, prior)
    programs = make_programs(
        env, cfg, learner, dp, wrap_fn, randomizer, iters_per_epoch, eval_env, eval_randomizer
    )
    seed = cfg.seed

    # Trace each program here and compile it on a worker thread. The reset goes first (its outputs are the
    # epoch's inputs), the epoch (the longest compile) right after it, then the small init. Nothing waits on
    # the evaluation before the first epoch ends, so it is traced on a worker too: on a warm compile cache
    # its trace is a third of what is left of the start-up, and it now overlaps the first epochs.
    key_abs = dp.abstract(np.zeros(2, np.uint32), sharded=False)
    template = jax.eval_shape(learner.init, key_abs)
    ts_abs = dp.abstract(template, sharded=False)
    compiler = Compiler(timer)
    reset_lowered = compiler.submit("reset", programs.reset, key_abs, key_abs)
    envs_abs = dp.abstract(reset_lowered.out_info, sharded=True)
    compiler.submit("epoch", programs.epoch, ts_abs, envs_abs, key_abs)
    compiler.submit("init", programs.init, key_abs)
    compiler.submit("evaluate", programs.evaluate, _policy_params(ts_abs), key_abs, key_abs, background=True)

    env_steps, iteration = 0, 0
    if cfg.resume:
        ckpt = load_checkpoint(cfg.resume, template)
        env_steps, iteration = ckpt.env_steps, ckpt.iteration
        ts = dp.replicate(ckpt.state)
        logger.print(f"resumed {ckpt.path} at {env_steps} env steps (iteration {iteration})")
    else:
        ts = compiler.get("init")(dp.replicate(host_key(seed, _K_INIT)))
    model_key = dp.replicate(host_key(seed, _K_MODEL))
    t_wait = time.monotonic()
    envs = compiler.get("reset")(dp.replicate(host_key(seed, _K_RESET, iteration)), model_key)
    epoch = compiler.get("epoch")
    if jax.process_count() > 1:
        # Start together: a process still compiling in the background would reach the first collective
        # late, and CPU (gloo) collectives give up after 30 s.
        compiler.get("evaluate")
        barrier("bar_policy: programs compiled")
    timer.add("wait for compiles (init, reset, epoch)", time.monotonic() - t_wait)

    eval_model_key = dp.replicate(host_key(seed, _K_EVAL_MODEL))

    def evaluator(params: Any, eval_seed: int) -> dict[str, float]:
        metrics = compiler.get("evaluate")(
            dp.replicate(tuple(params[:2])), dp.replicate(host_key(eval_seed, _K_EVAL)), eval_model_key
        )
        return {k: float(v) for k, v in dp.to_host(metrics).items()}

    last_eval_s = 0.0

    def device_eval(params: tuple[Any, Any], step: int) -> None:
        nonlocal last_eval_s
        t_eval = time.monotonic()
        m = compiler.get("evaluate")(params, dp.replicate(host_key(seed, _K_EVAL, step)), eval_model_key)
        m = {k: float(v) for k, v in dp.to_host(m).items()}
        if step:  # the step-0 evaluation's time includes its compile
            last_eval_s = time.monotonic() - t_eval
        logger.record_eval(step, m, evals, time_to_threshold, cfg.eval.success_threshold)
        if keeper.offer(step, m, lambda: _host_params(dp.to_host(ts))):
            logger.print(f"  best so far: the parameters at {step:,} steps are kept")

    is_main = jax.process_index() == 0
    evals: list[dict[str, float]] = []
    time_to_threshold: list[float] = []

    def checkpoint(step: int, it: int) -> None:
        host = dp.to_host(ts)  # every process fetches its own replica; only process 0 writes
        if is_main and checkpoint_dir is not None:
            save_checkpoint(checkpoint_dir, host, env_steps=step, iteration=it, extra=config_record)

    start_steps = env_steps
    keeper = BestKeeper(start_steps, getattr(env, "task_name", None))
    eval_at_start = iteration == 0
    epochs_done = 0
    first_epoch_end = 0.0
    startup_pending = True

    def eval_at_zero() -> None:
        """The untrained policy's evaluation (its params re-created by ``init``), logged as step 0."""
        t_eval = time.monotonic()
        initial = compiler.get("init")(dp.replicate(host_key(seed, _K_INIT)))
        device_eval(_policy_params(initial), 0)
        timer.add("eval @ 0 (first epoch end with the evaluation compiled)", time.monotonic() - t_eval)

    t_loop = time.monotonic()
    while iteration < total_iters:
        t0 = time.monotonic()
        ts, envs, metrics, stats = epoch(ts, envs, dp.replicate(host_key(seed, _K_EPOCH, iteration)))
        metrics, stats = dp.to_host((metrics, stats))
        dt = time.monotonic() - t0
        iteration += iters_per_epoch
        env_steps += iters_per_epoch * steps_per_iter
        epochs_done += 1
        steps_in_epoch = iters_per_epoch * steps_per_iter
        train_metrics = {
            **{f"loss/{k}": float(v) for k, v in metrics.items()},
            "episode_reward": float(stats[0]) / steps_in_epoch * env.episode_length,
            "success_rate": float(stats[1]) / max(float(stats[2]), 1.0),
            "sps": steps_in_epoch / dt,
        }
        logger.log(env_steps, train_metrics, kind="train")
        logger.progress(env_steps, steps_in_epoch / dt, train_metrics)
        if epochs_done == 1:
            timer.add("first epoch (run)", dt)
            first_epoch_end = logger.elapsed()
        # Stop before an epoch that would end past the budget (its expected length: this epoch's, plus an
        # evaluation's when the next epoch ends with one).
        next_eval_due = (epochs_done + 1) % _LINES_PER_EVAL == 0
        over_budget = next_would_overrun(
            logger.elapsed(), dt + (last_eval_s if next_eval_due else 0.0), 60 * cfg.max_minutes
        )
        if jax.process_count() > 1:
            from jax.experimental import multihost_utils

            over_budget = bool(multihost_utils.broadcast_one_to_all(np.asarray(over_budget)))
        last = iteration >= total_iters or over_budget
        eval_due = last or epochs_done % _LINES_PER_EVAL == 0
        # The step-0 evaluation runs at the first epoch end where the evaluation program is ready, and
        # always before the first periodic one (so it is the first record). Under jax.distributed it was
        # compiled before the start on every process, so every process takes the same branch.
        if eval_at_start and (eval_due or compiler.done("evaluate")):
            eval_at_start = False
            eval_at_zero()
        if startup_pending and not eval_at_start:
            startup_pending = False
            stats1 = CompileStats.get().snapshot()
            delta = {k: stats1[k] - stats0[k] for k in stats1}
            for line in timer.lines(first_epoch_end, delta):
                logger.print(line)
            logger.log(env_steps, {**timer.phases, **delta}, kind="startup")
        if eval_due:
            device_eval(_policy_params(ts), env_steps)
            n_evals = epochs_done // _LINES_PER_EVAL
            if last or (cfg.checkpoint_every and n_evals % cfg.checkpoint_every == 0):
                checkpoint(env_steps, iteration)
        if over_budget and not iteration >= total_iters:
            logger.print(f"stopping: wall-clock budget of {cfg.max_minutes} min reached")
            break
    compiler.get("evaluate")  # surface a compile error even when no evaluation ran
    train_seconds = time.monotonic() - t_start
    if epochs_done:
        logger.print(
            f"trained {env_steps - start_steps:,} env steps in {time.monotonic() - t_loop:.1f} s of loop "
            f"({train_seconds:.1f} s with setup and compile)"
        )
    return BraxTrainResult(
        params=_host_params(dp.to_host(ts)),
        make_policy=learner.make_policy,
        env_steps=env_steps,
        run_env_steps=env_steps - start_steps,
        train_seconds=train_seconds,
        evals=evals,
        time_to_threshold_s=time_to_threshold[0] if time_to_threshold else None,
        evaluator=evaluator,
        num_eval_envs=cfg.eval.num_eval_envs,
        activation=cfg.network.activation,
        best=keeper.best,
        prior=prior,
    )
