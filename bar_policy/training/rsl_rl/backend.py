"""The ``--backend rsl-rl`` path: rsl-rl-lib's PPO (torch) on the same MJX env through ``RslRlVecEnv``.

rsl-rl's ``OnPolicyRunner`` builds the algorithm (actor/critic ``MLPModel`` with empirical observation
normalisation, Gaussian policy, adaptive-KL schedule); the rollout/update loop is written here so that it
shares our progress lines, evaluation, msgpack checkpoints (torch state dicts as numpy, no pickle) and
export with the brax backend. The loop is the runner's: ``act`` -> ``env.step`` -> ``process_env_step``
for ``num_steps_per_env`` steps, then ``compute_returns`` and ``update``.

Config mapping from ``PPOConfig`` (``rsl_rl_train_cfg``): one rsl-rl iteration collects the env steps
of one brax iteration, ``ppo.steps_per_iteration`` (num_steps_per_env = steps_per_iteration / num_envs,
the ``batch_size * num_minibatches / num_envs`` segments of ``unroll_length`` that brax collects per env,
back to back), and updates on them as brax does: num_learning_epochs = num_updates_per_batch passes of
num_mini_batches = num_minibatches minibatches (``batch_size * unroll_length`` samples each);
gamma = discounting, lam = gae_lambda, clip_param = clipping_epsilon, entropy_coef = entropy_cost,
learning_rate, max_grad_norm. The field's rsl-rl values for arm reach/manipulation (Isaac Lab's Franka
reach and lift, mjlab's YAM lift; table and sources in ``rsl_rl.config``): num_steps_per_env 24,
learning_rate 1e-3 adaptive (desired_kl 0.01), clip 0.2, entropy 0.005, gamma 0.99, lam 0.95, 5 epochs
of 4 minibatches, max_grad_norm 1.0, value_loss_coef 1.0, init_noise_std 1.0, actor = critic
[256, 128, 64] elu with observation normalisation; ``rsl_rl.config.field_hyperparameters(cfg)`` applies
them (``field_cli_flags`` gives the ``bar-train`` flags).

Action prior (``network.action_prior``, e.g. the tracker's ``reference``): the env commands
``prior(obs) + actor's action`` (``rsl_rl.prior`` gives the design and why rsl-rl's PPO is unchanged), the
evaluations step envs with the same prior, and the exported file carries it in its graph (``MlpPolicy``'s
``identity`` head plus the prior); the parity gate's reference adds it in numpy.
``ppo.actor_warmup_iterations`` stays a brax-backend option.

Start-up (``startup.breakdown``'s rows): the envs' jax programs (train reset and step, eval reset, step
and quality; ``rsl_rl.programs``) are traced, lowered and compiling (``startup.compiled.compile_programs``)
before this module (torch, rsl_rl, tensordict) is imported (``run`` calls ``rsl_rl.entry.run_rsl_rl``,
which prepares them first), so the imports run while XLA compiles on worker threads. The
training env's first reset waits for its program, the runner reads its observations, and training starts
once the training step is ready. As in the brax backend, the step-0 evaluation (of the initial actor,
copied before training) runs as ``eval.initial`` says: ``end`` (default) after the last periodic
evaluation; ``start`` after the first iteration where the evaluation step is compiled, or before the first
periodic evaluation, whichever comes first (the start-up then ends after it, else after the first
iteration; its report is printed and recorded once the evaluation's programs are ready, before the first
evaluation at the latest, so that no row is a program still compiling); ``off`` never.

Speed: nothing in the rollout waits for the device. Actions and observations cross by DLPack on the
device; the logged sums accumulate on the device (``RslRlVecEnv.take_stats`` reads them once per
iteration). rsl-rl's own ``update`` still reads its losses and KL with ``.item()`` once per minibatch.
"""

from __future__ import annotations

import copy
import dataclasses
import math
import time
from collections.abc import Callable, Generator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch

import bar_policy
from bar_policy.export.policy import export_policy
from bar_policy.obs.action_prior import Prior
from bar_policy.training.best import BestIterate
from bar_policy.training.checkpoint import Checkpoint
from bar_policy.training.config import TrainConfig
from bar_policy.training.evaluations import Evaluations
from bar_policy.training.log_tags import rsl_rl_losses
from bar_policy.training.records import Epoch, NotApplied, Record, Resumed, Said, SaveCheckpoint, ScalarWriter
from bar_policy.training.rollout_sums import RatioWindow, window_metrics
from bar_policy.training.rsl_rl.config import not_applied, rsl_rl_train_cfg
from bar_policy.training.rsl_rl.env import RslRlVecEnv
from bar_policy.training.rsl_rl.policy import (
    deterministic_module,
    evaluate_torch_policy,
    mlp_policy_from_rsl_rl,
    torch_policy_reference,
)
from bar_policy.training.rsl_rl.prior import start_actor_at_prior
from bar_policy.training.rsl_rl.programs import RslRlPrograms
from bar_policy.training.rsl_rl.state import (
    load_ppo_state,
    ppo_state,
)
from bar_policy.training.rsl_rl.torch_bridge import COPIES, torch_device_for_jax
from bar_policy.training.rsl_rl.torch_precision import update_precision
from bar_policy.training.startup import breakdown as sb
from bar_policy.training.startup.session import StartUp
from bar_policy.training.writers import rsl_rl_logger_cfg

__all__ = [
    "RslRlTrainResult",
    "evaluate_torch_policy",
    "mlp_policy_from_rsl_rl",
    "rsl_rl_train_cfg",
    "torch_policy_reference",
    "train_rsl_rl",
]

_EVAL_PROGRAMS = ("eval reset", "eval step", "eval quality")
"""The evaluation env's programs (``rsl_rl.programs.EnvPrograms``, named ``eval``), compiled on workers."""


@dataclass(frozen=True, kw_only=True)
class RslRlTrainResult:
    """Outcome of ``train_rsl_rl`` (same interface as ``BraxTrainResult`` where ``run`` uses it)."""

    actor: torch.nn.Module
    """The trained rsl-rl actor (``MLPModel``)."""
    eval_env: RslRlVecEnv
    """Evaluation env (randomised like training, its own seeds)."""
    episode_length: int
    """Control steps per episode."""
    env_steps: int
    """Total env steps trained (including before a resume)."""
    run_env_steps: int
    """Env steps trained in this run."""
    train_seconds: float
    """Wall time of the training loop, s."""
    evals: list[dict[str, float]] = field(default_factory=list)
    """Evaluation records, in step order (as ``BraxTrainResult.evals``)."""
    time_to_threshold_s: float | None = None
    """Seconds to the first evaluation at or above the success threshold (as ``BraxTrainResult``'s)."""
    best: BestIterate | None = None
    """The best evaluated iterate of this run (its ``params`` is a copy of the actor's state dict)."""
    spare_actor: torch.nn.Module | None = None
    """An actor of the same structure that ``at`` loads other parameters into (the trained one is kept)."""
    prior: Prior | None = None
    """The action prior the envs add to the actor's actions (``rsl_rl.prior``; exported), None without one."""

    def at(self, state: dict[str, torch.Tensor]) -> RslRlTrainResult:
        """The same result with the actor parameters ``state`` (e.g. ``best.params``), to evaluate or export.

        Loads ``state`` into ``spare_actor`` (one spare per result: the previous ``at`` result then
        shares it).
        """
        if self.spare_actor is None:
            raise ValueError("this result has no spare actor to load other parameters into")
        self.spare_actor.load_state_dict(state)
        self.spare_actor.eval()
        return dataclasses.replace(self, actor=self.spare_actor)

    def policy_fn(self) -> Callable[[torch.Tensor], torch.Tensor]:
        """Deterministic torch policy on the env's device: the actor's action (the env adds any prior)."""
        module = deterministic_module(self.actor, self.eval_env.device)
        return lambda obs: module(obs)

    def final_evaluation(self, episodes: int, seed: int) -> dict[str, float]:
        """Evaluate on ``episodes`` episodes, in batches of the eval env size."""
        rounds = max(1, math.ceil(episodes / self.eval_env.num_envs))
        runs = [
            evaluate_torch_policy(self.policy_fn(), self.eval_env, self.episode_length, seed + i)
            for i in range(rounds)
        ]
        out = {k: float(np.mean([r[k] for r in runs])) for k in runs[0]}
        out["episodes"] = float(rounds * self.eval_env.num_envs)
        return out

    def export_onnx(self, metadata: Any, path: str | Any) -> dict[str, Any]:
        """Export with the parity gate against rsl-rl's own deterministic module (plus the prior)."""
        actor, prior = self.actor, self.prior
        return export_policy(
            mlp_policy_from_rsl_rl(actor, prior), metadata, path, torch_policy_reference(actor, prior)
        )


def train_rsl_rl(
    env: Any,
    cfg: TrainConfig,
    *,
    evaluations: Evaluations,
    programs: RslRlPrograms,
    randomizer: Callable[..., Any] | None,
    resume: Checkpoint | None = None,
    start: StartUp | None = None,
    eval_env: Any | None = None,
    scalars_dir: Path | None = None,
) -> Generator[Record, Any, RslRlTrainResult]:
    """Train with rsl-rl-lib's PPO on ``env``; same arguments, records and outputs as ``train_brax``.

    ``programs``: the envs' jax programs, compiling since ``rsl_rl.programs.prepare_rsl_rl`` (which
    ``rsl_rl.entry.run_rsl_rl``, the backend's entry, calls before it imports this module).
    ``resume``: the checkpoint the run resumes (``checkpoint.read_checkpoint``), loaded into the actor,
    critic and optimizer. ``eval_env``: the env the evaluations run (the task's held-out variant) on its
    nominal model, as brax's; None: ``env`` with ``randomizer``. ``scalars_dir``: where rsl-rl's runner
    logger writes the scalars (the run's ``tb/``, with ``cfg.logger``'s writer, which the run's logger then
    writes through: ``records.ScalarWriter``); None: no scalars.
    """
    from rsl_rl.runners import OnPolicyRunner

    ppo = cfg.ppo
    t_start = time.monotonic()
    timer = (start or StartUp()).timer
    compiled, prior = programs.compiled, programs.prior
    device = torch_device_for_jax() if cfg.rsl_rl.device == "auto" else cfg.rsl_rl.device
    torch.manual_seed(cfg.seed)
    steps_per_env = ppo.steps_per_iteration // ppo.num_envs
    steps_per_iter = ppo.num_envs * steps_per_env
    total_iters = math.ceil(ppo.num_timesteps / steps_per_iter)
    env_steps = iteration = 0
    # Set-up: the two envs over the compiling programs, rsl-rl's runner (actor, critic, storage).
    with timer.phase(sb.RSL_RUNNER):
        # Both envs add the prior to the actor's actions. Our loop records its own sums on the device
        # (take_stats); extras["log"] is for OnPolicyRunner.learn.
        vec_env = RslRlVecEnv(programs.train, device=device, log_metrics=False)
        eval_vec = RslRlVecEnv(programs.eval, device=device, log_metrics=False)
        with timer.phase(sb.RSL_RESET):  # the runner reads the first observations
            vec_env.get_observations()
        # rsl-rl's own runner logger, writing into the run's tb/ (its writer: TensorBoard or wandb, as
        # --logger says; it also stores the code state, tb/git/*.diff). Our loop writes the scalars
        # through it, under the tags both backends share (log_tags), from the sums read once per iteration.
        train_cfg, unused = rsl_rl_train_cfg(cfg), not_applied(cfg)  # unused: brax settings rsl-rl ignores
        log_dir = None if scalars_dir is None else str(scalars_dir)
        run_name = "" if scalars_dir is None else scalars_dir.parent.name
        train_cfg["logger"] = rsl_rl_logger_cfg(cfg.logger, project=cfg.wandb_project, run_name=run_name)
        runner = OnPolicyRunner(vec_env, train_cfg, log_dir=log_dir, device=device)
        if log_dir is not None:
            runner.logger.git_status_repos.append(bar_policy.__file__)  # our tree's diff beside rsl-rl's
            runner.logger.init_logging_writer()
            yield ScalarWriter(runner.logger.writer)
        yield NotApplied(tuple(unused))
        alg = runner.alg
        if prior is not None:
            start_actor_at_prior(alg.actor)  # a resume loads its own parameters over it
        # The untrained actor, for the step-0 evaluation (copied before any forward pass, as spare_actor
        # below); frozen in eval mode.
        initial_actor = copy.deepcopy(alg.actor).eval()
        if resume is not None:
            load_ppo_state(alg, resume.state, device)
            env_steps, iteration = resume.env_steps, resume.iteration
            yield Resumed(resume.path, env_steps, iteration, resume.changes)
        # Copied before any forward pass: later the Gaussian head holds non-leaf tensors deepcopy refuses.
        spare_actor = copy.deepcopy(alg.actor)
    start_steps = env_steps
    periods = max((cfg.eval.num_evals - 1), 1)
    iters_per_eval = max(1, math.ceil(total_iters / periods))
    episode_length = int(env.episode_length)
    # The training figures (rollout_sums): each iteration's record, and each progress line over the
    # iterations since the previous line (as brax's line covers its epoch); ratios carried over windows
    # without an event (reach: segment ends, which all envs reach at the same steps).
    record_ratios: dict[str, RatioWindow] = {}
    line_ratios: dict[str, RatioWindow] = {}
    line_sums: dict[str, float] = {}
    line_steps, line_s = 0, 0.0

    last_eval_s = 0.0

    def line() -> tuple[float, dict[str, float]]:
        """The progress line's steps/s and figures over the iterations since the previous line."""
        nonlocal line_sums, line_steps, line_s
        shown = line_steps / line_s, window_metrics(line_sums, line_steps, episode_length, line_ratios)
        line_sums, line_steps, line_s = {}, 0, 0.0
        return shown

    def run_eval(step: int, actor: torch.nn.Module) -> Generator[Record, Any, None]:
        """Evaluate ``actor`` (the current one, or the initial one at step 0), report it and keep it."""
        nonlocal last_eval_s
        t_eval = time.monotonic()
        training = actor.training
        actor.eval()
        module = deterministic_module(actor, device)
        m = evaluate_torch_policy(lambda o: module(o), eval_vec, episode_length, seed=cfg.seed + 1000 + step)
        if step:  # the step-0 evaluation's time may include a wait for its compile
            last_eval_s = time.monotonic() - t_eval

        def snapshot() -> dict[str, torch.Tensor]:
            return {k: v.detach().clone() for k, v in actor.state_dict().items()}

        kept = f"  best so far: the actor at {step:,} steps is kept"
        yield from evaluations.record(step, m, snapshot, kept)
        actor.train(training)
        compiled.confirm()  # every loaded program has run: none is a suspect of a crash

    def eval_at_zero() -> Generator[Record, Any, float]:
        """The initial actor's evaluation; returns its seconds (a start-up row when it runs inside it)."""
        t = time.monotonic()
        yield from run_eval(0, initial_actor)
        return time.monotonic() - t

    # As the brax backend: the step-0 evaluation (of the initial actor; a resume has none) runs after the
    # last periodic one (eval.initial=end), or (start) after the first iteration where the evaluation step
    # is compiled, or before the first periodic evaluation, so training waits only for the training step.
    eval_at_start = iteration == 0 and cfg.eval.initial == "start"
    eval_at_end = iteration == 0 and cfg.eval.initial == "end"
    with timer.phase(sb.WAIT):
        compiled["train step"]
        obs = vec_env.get_observations().to(device)
    alg.train_mode()
    t_loop = time.monotonic()
    copies_seen = COPIES.count
    # The loop: rollout (act -> env.step -> process_env_step) -> update, then every iters_per_eval
    # iterations an evaluation (and a checkpoint).
    while iteration < total_iters:
        t0 = time.monotonic()
        with torch.inference_mode():
            for _ in range(steps_per_env):
                actions = alg.act(obs)
                obs, rewards, dones, extras = vec_env.step(actions)
                alg.process_env_step(obs, rewards, dones, extras)
            alg.compute_returns(obs)
        with update_precision(ppo.update_precision):  # the SGD passes only, as brax's
            losses = alg.update()
        stats = vec_env.take_stats()
        notes: tuple[str, ...] = ()
        if COPIES.count > copies_seen:  # never silent: a torch->jax crossing that could not share
            copies_seen = COPIES.count
            notes = (f"  torch->jax bridge copies so far: {dict(COPIES.by_reason)}",)
        iteration += 1
        env_steps += steps_per_iter
        ended_at = time.monotonic()
        dt = ended_at - t0
        window = stats["window"]
        train_metrics = {
            **window_metrics(window, steps_per_iter, episode_length, record_ratios),
            **rsl_rl_losses(losses, alg.learning_rate),
            "policy_std": float(alg.get_policy().output_std.detach().mean()),
            "sps": steps_per_iter / dt,
        }
        for k, v in window.items():
            line_sums[k] = line_sums.get(k, 0.0) + v
        line_steps, line_s = line_steps + steps_per_iter, line_s + dt
        last = iteration >= total_iters
        # Room for the step-0 evaluation when it runs after training (the periodic ones are not counted).
        reserve = last_eval_s if eval_at_end else 0.0
        over_budget = yield Epoch(
            env_steps,
            train_metrics,
            next_s=dt + reserve,
            budget_s=60 * cfg.max_minutes,
            line=line,
            line_due=iteration % max(1, iters_per_eval // 2) == 0 or last,
            notes=notes,
        )
        eval_due = iteration % iters_per_eval == 0 or last or over_budget
        step0_s = None
        if eval_at_start and (eval_due or compiled.ready("eval step")):
            eval_at_start = False
            step0_s = yield from eval_at_zero()  # always before a periodic evaluation
        report = compiled.epoch_ended(
            dt,
            ended_at=ended_at,
            step=env_steps,
            step0_s=step0_s,
            step0_waiting=eval_at_start,
            eval_due=eval_due,
            eval_programs=_EVAL_PROGRAMS,
        )
        if report is not None:
            yield report
        if eval_due:
            yield from run_eval(env_steps, alg.actor)
            if (
                last
                or over_budget
                or (cfg.checkpoint_every and (iteration // iters_per_eval) % cfg.checkpoint_every == 0)
            ):
                yield SaveCheckpoint(ppo_state(alg), env_steps, iteration)
        if over_budget and not last:
            yield Said((f"stopping: wall-clock budget of {cfg.max_minutes} min reached",))
            break
    loop_s = time.monotonic() - t_loop
    if eval_at_end:  # eval.initial=end: the untrained actor, once the trained one is out
        yield Said(("step-0 evaluation (the untrained policy; after training: --eval.initial end)",))
    if eval_at_start or eval_at_end:  # start: no iteration ran (nothing to train); it is still evaluated
        yield from eval_at_zero()
    yield Said((f"trained {env_steps - start_steps:,} env steps in {loop_s:.1f} s of loop",))
    if runner.logger.writer is not None:
        runner.logger.stop_logging_writer()  # rsl-rl's own end of logging (a wandb run is finished)
    alg.eval_mode()
    return RslRlTrainResult(
        actor=alg.actor,
        eval_env=eval_vec,
        episode_length=episode_length,
        env_steps=env_steps,
        run_env_steps=env_steps - start_steps,
        train_seconds=time.monotonic() - t_start,
        evals=evaluations.records,
        time_to_threshold_s=evaluations.time_to_threshold_s,
        best=evaluations.best,
        spare_actor=spare_actor,
        prior=prior,
    )
