"""A brax run's state between its programs' calls, and the calls: epochs, evaluations, checkpoints, result.

``BraxRun`` holds what ``train_brax`` carries from one epoch to the next (the replicated training state, the
env slots, the host keys, the counts) and runs the compiled programs (``training.brax.programs``) on it:
``rollout_and_update`` is an epoch (``run_epoch``: the calls queue on the device, one host sync at its end,
``epoch_totals``), ``evaluate`` one evaluation, ``checkpoint`` the state to save, ``result`` what the run
returns. ``host_key`` derives every key on the host from the seed and a path; ``epoch_iterations`` sizes an
epoch (one progress line).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Generator
from typing import Any

import jax
import numpy as np

from bar_policy.training.brax.learner import TrainingState
from bar_policy.training.brax.programs import _policy_params
from bar_policy.training.brax.result import BraxTrainResult
from bar_policy.training.checkpoint import Checkpoint
from bar_policy.training.config import TrainConfig
from bar_policy.training.evaluations import Evaluations
from bar_policy.training.log_tags import brax_losses
from bar_policy.training.parallel import DataParallel, barrier
from bar_policy.training.records import Epoch, Record, SaveCheckpoint
from bar_policy.training.rollout_sums import RatioWindow, sum_layout, window_metrics
from bar_policy.training.startup.compiled import CompiledPrograms

__all__ = ["BraxRun", "epoch_iterations", "epoch_totals", "host_key", "run_epoch"]

_LINES_PER_EVAL = 2
"""Progress lines (training epochs) per evaluation period."""


def host_key(seed: int, *path: int) -> np.ndarray:
    """A raw threefry key (uint32[2]) derived on the host from ``seed`` and a path of ints (no device op)."""
    return np.random.default_rng([seed, *path]).integers(0, 2**32, 2, dtype=np.uint32)


_K_INIT, _K_MODEL, _K_RESET, _K_EPOCH, _K_EVAL, _K_EVAL_MODEL = range(6)


def epoch_iterations(cfg: TrainConfig) -> int:
    """Training iterations per compiled epoch (one progress line).

    ``log_every_iterations``, or when it is 0 about ``_LINES_PER_EVAL`` lines per evaluation period.
    """
    total_iters = math.ceil(cfg.ppo.num_timesteps / cfg.ppo.steps_per_iteration)
    periods = max((cfg.eval.num_evals - 1) * _LINES_PER_EVAL, 1)
    return cfg.log_every_iterations or max(1, math.ceil(total_iters / periods))


def run_epoch(
    rollout: Callable[..., Any],
    update: Callable[..., Any],
    ts: TrainingState,
    envs: Any,
    key: jax.Array,
    iterations: list[jax.Array],
    weights: dict[str, jax.Array],
) -> tuple[TrainingState, Any, list[Any], list[Any]]:
    """One epoch: ``rollout`` then ``update`` (compiled programs) for each iteration index in ``iterations``.

    Dispatched without a host sync (the calls queue on the device); returns ``(ts, envs, metrics, stats)``
    with one entry per iteration in ``metrics`` and ``stats``, to reduce with ``epoch_totals`` once on
    the host. ``iterations``: replicated int32 scalars 0 .. iters - 1, made once; ``weights``: the reward
    weights, replicated (``envs.reward_weights``).
    """
    metrics, stats = [], []
    for i in iterations:
        envs, data, st = rollout(ts, envs, key, i, weights)
        ts, m = update(ts, data, key, i)
        metrics.append(m)
        stats.append(st)
    return ts, envs, metrics, stats


def epoch_totals(metrics: list[dict[str, Any]], stats: list[Any]) -> tuple[dict[str, float], np.ndarray]:
    """Host copies of ``run_epoch``'s lists -> each loss metric's mean over the epoch, the stats' sums.

    ``stats`` rows are ``rollout_sums.step_sums`` vectors (reward, success numerator and denominator, then
    the columns of ``rollout_sums.sum_layout``) over every device's slots.
    """
    means = {k: float(np.mean([m[k] for m in metrics])) for k in metrics[0]}
    return means, np.sum(np.stack(stats), axis=0)


def _host_params(host: TrainingState) -> tuple[Any, Any, Any]:
    """``(normalizer, policy, value)`` of a host copy of the training state (brax's layout)."""
    return (host.normalizer_params, host.params.policy, host.params.value)


class BraxRun:
    """One brax run's state between set-up and result: the training state, the envs, the counts.

    Made once the programs are submitted (the ``WAIT`` row): the training state resumed (``state``, restored
    from ``resume``) or made by ``init``, every env slot reset. Every process holds one (only process 0's
    logger writes).
    """

    def __init__(
        self,
        cfg: TrainConfig,
        env: Any,
        dp: DataParallel,
        programs: CompiledPrograms,
        weights: dict[str, Any],
        resume: Checkpoint | None,
        state: TrainingState | None,
        evaluations: Evaluations,
    ) -> None:
        self.cfg, self.env, self.dp, self.programs = cfg, env, dp, programs
        seed = cfg.seed
        self.env_steps, self.iteration = 0, 0
        if resume is not None:
            self.env_steps, self.iteration = resume.env_steps, resume.iteration
        self.iters_per_epoch = epoch_iterations(cfg)
        # Every host value the run starts from, on the devices at once (replicated).
        host = {
            "init": host_key(seed, _K_INIT),
            "model": host_key(seed, _K_MODEL),
            "reset": host_key(seed, _K_RESET, self.iteration),
            "eval_model": host_key(seed, _K_EVAL_MODEL),
            "weights": weights,
            "iterations": [np.int32(i) for i in range(self.iters_per_epoch)],
            "state": state,
        }
        dev = dp.replicate(host)
        self.ts = dev["state"] if state is not None else programs["init"](dev["init"])
        self.envs = programs["reset"](dev["reset"], dev["model"])
        self.rollout, self.update = programs["rollout"], programs["update"]
        self.iteration_index = dev["iterations"]
        if jax.process_count() > 1:
            # Start together: a process still compiling in the background would reach the first
            # collective late, and CPU (gloo) collectives give up after 30 s.
            programs["evaluate"]
            barrier("bar_policy: programs compiled")
        self.eval_model_key, self.weights = dev["eval_model"], dev["weights"]
        self.epochs = 0
        self.epoch_s = self.epoch_end = 0.0  # the last epoch's seconds and end (time.monotonic())
        self.evaluations = evaluations
        self.layout = sum_layout(env)  # the rollout's logged sums (rollout_sums)
        self.ratios: dict[str, RatioWindow] = {}  # the training ratios, carried over event-less epochs
        self.last_eval_s = 0.0
        # The step-0 evaluation: none after a resume. Every process decides alike (config and checkpoint),
        # so under jax.distributed all of them run it, collectively, at the same point.
        self.eval_at_start = self.iteration == 0 and cfg.eval.initial == "start"
        self.eval_at_end = self.iteration == 0 and cfg.eval.initial == "end"

    def rollout_and_update(self) -> Epoch:
        """One epoch (``iters_per_epoch`` PPO iterations); returns its record (its seconds: ``epoch_s``).

        The record's look-ahead for the wall-clock budget (``Epoch.next_s``): this epoch's length, plus an
        evaluation's when the next epoch ends with one, plus one more while the step-0 evaluation waits for
        the end of training.
        """
        t0 = time.monotonic()
        epoch_key = self.dp.replicate(host_key(self.cfg.seed, _K_EPOCH, self.iteration))
        self.ts, self.envs, metrics, stats = run_epoch(
            self.rollout, self.update, self.ts, self.envs, epoch_key, self.iteration_index, self.weights
        )
        metrics, stats = epoch_totals(*jax.device_get((metrics, stats)))
        self.epoch_end = time.monotonic()
        self.epoch_s = seconds = self.epoch_end - t0
        steps = self.iters_per_epoch * self.cfg.ppo.steps_per_iteration
        self.iteration += self.iters_per_epoch
        self.env_steps += steps
        self.epochs += 1
        ppo = self.cfg.ppo
        train_metrics = {
            **window_metrics(self.layout.named(stats), steps, self.env.episode_length, self.ratios),
            **brax_losses(metrics, ppo.entropy_cost, ppo.vf_loss_coefficient),
            "sps": steps / seconds,
        }
        next_eval_due = (self.epochs + 1) % _LINES_PER_EVAL == 0
        evals_s = self.last_eval_s * (next_eval_due + self.eval_at_end)
        budget_s = 60 * self.cfg.max_minutes
        return Epoch(self.env_steps, train_metrics, next_s=seconds + evals_s, budget_s=budget_s)

    def evaluate(self, params: tuple[Any, Any], step: int) -> Generator[Record, Any, None]:
        """Evaluate replicated ``(normalizer, policy)`` params on step ``step``'s keys; report, rank, keep."""
        t_eval = time.monotonic()
        m = self.evaluation(params, host_key(self.cfg.seed, _K_EVAL, step))
        if step:  # the step-0 evaluation's time includes its compile
            self.last_eval_s = time.monotonic() - t_eval
        kept = f"  best so far: the parameters at {step:,} steps are kept"
        yield from self.evaluations.record(step, m, lambda: _host_params(jax.device_get(self.ts)), kept)
        self.programs.confirm()  # every loaded program has run: none is a suspect of a crash

    def evaluation(self, params: tuple[Any, Any], key: np.ndarray) -> dict[str, float]:
        """The evaluation program's figures, as host floats, for replicated ``(normalizer, policy)``."""
        m = self.programs["evaluate"](params, self.dp.replicate(key), self.eval_model_key, self.weights)
        return {k: float(v) for k, v in jax.device_get(m).items()}

    def evaluate_initial(self) -> Generator[Record, Any, float]:
        """The untrained policy's evaluation (its params re-created by ``init``), reported as step 0.

        Returns its seconds (with its report, and its wait for the evaluation program: a start-up row).
        """
        self.eval_at_start = False
        t = time.monotonic()
        initial = self.programs["init"](self.dp.replicate(host_key(self.cfg.seed, _K_INIT)))
        yield from self.evaluate(_policy_params(initial), 0)
        return time.monotonic() - t

    def checkpoint(self) -> SaveCheckpoint:
        """The training state to save (every process fetches its own replica; only process 0 writes)."""
        return SaveCheckpoint(jax.device_get(self.ts), self.env_steps, self.iteration)

    def result(self, learner: Any, prior: Any, start_steps: int, train_seconds: float) -> BraxTrainResult:
        """The run's result: host params, the records, and an evaluator on the compiled evaluation."""
        dp = self.dp

        def evaluator(params: Any, eval_seed: int) -> dict[str, float]:
            return self.evaluation(dp.replicate(tuple(params[:2])), host_key(eval_seed, _K_EVAL))

        return BraxTrainResult(
            params=_host_params(jax.device_get(self.ts)),
            make_policy=learner.make_policy,
            env_steps=self.env_steps,
            run_env_steps=self.env_steps - start_steps,
            train_seconds=train_seconds,
            evals=self.evaluations.records,
            time_to_threshold_s=self.evaluations.time_to_threshold_s,
            evaluator=evaluator,
            num_eval_envs=self.cfg.eval.num_eval_envs,
            activation=self.cfg.network.activation,
            best=self.evaluations.best,
            prior=prior,
        )
