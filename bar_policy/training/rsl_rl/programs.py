"""The jax side of the rsl-rl backend, torch-free: its envs' programs, submitted before torch is imported.

``EnvPrograms`` is everything of one ``RslRlVecEnv`` that is jax: the env wrapped for training (batch,
episode truncation, auto-reset, domain randomisation, exactly as for the brax backend), the pure jitted
``reset``, ``step`` and (for an evaluation env) ``quality`` functions with their logging-stats pytrees, and
the stream of reset keys. ``to_compile`` lists them as programs of their own (``<name> reset``, ``<name>
step``, ``<name> quality``) for the start-up's one call (``startup.compiled.compile_programs``): the step is
traced on the reset's abstract output (``out_info``), so nothing runs before the first state is needed, and
after ``use`` the reset runs from its compiled executable. The step takes the reward weights as its last
argument (``envs.reward_weights``): a run that changes only a weight loads it from the executable cache.

``prepare_rsl_rl`` builds the training and the evaluation env's programs and compiles them all, once.
``rsl_rl.entry.run_rsl_rl`` (what ``run`` calls) does so before it imports ``rsl_rl.backend`` (torch,
rsl_rl, tensordict: seconds of the main thread), so that import runs while XLA compiles; nothing imported
here pulls torch in (``tests/training/test_rsl_rl_start.py``). ``RslRlVecEnv`` (``rsl_rl.env``) is the
torch side over them.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import jax
import jax.numpy as jnp

from bar_policy.envs.base import eval_ratios
from bar_policy.envs.reward_weights import weights, with_weights
from bar_policy.envs.wrappers import BatchedEnv
from bar_policy.obs.action_prior import Prior, check_fits
from bar_policy.training import eval_quality
from bar_policy.training.config import TrainConfig
from bar_policy.training.parallel import AXIS
from bar_policy.training.prior import action_prior
from bar_policy.training.rollout_sums import step_sums, sum_layout
from bar_policy.training.rsl_rl.prior import commanded_action
from bar_policy.training.startup.compiled import CompiledPrograms, Program, compile_programs
from bar_policy.training.startup.session import StartUp

__all__ = ["EnvPrograms", "RslRlPrograms", "prepare_rsl_rl"]


class EnvPrograms:
    """The jax programs of a batch of ``num_envs`` copies of a ``bar_policy.envs`` env (see the module doc).

    Args:
        env: the unwrapped jax env.
        num_envs: batch size.
        wrap_fn: ``wrap_for_brax_training(env, episode_length=, action_repeat=, randomization_fn=)``.
        randomizer: ``(model, rng) -> (model, in_axes)``, or None for the nominal model.
        seed: seed of the randomisation and of the resets.
        quality: also measure the evaluation's safety and smoothness figures (``eval_quality``) on each
            slot's first episode (it keeps every step's chatter signal, episode_length x num_envs x joints).
        prior: the action prior, or None: the step's actions are then residuals added to ``prior(obs)``.
        name: the programs' name prefix (``<name> reset``, ``<name> step``, ``<name> quality``) for
            ``to_compile``: distinct per env, so each has its own executable-cache key. Until ``use`` the
            jitted functions run (compiled at their first call).
    """

    def __init__(
        self,
        env: Any,
        num_envs: int,
        *,
        wrap_fn: Callable[..., BatchedEnv],
        randomizer: Callable[..., Any] | None = None,
        seed: int = 0,
        quality: bool = False,
        prior: Prior | None = None,
        name: str = "env",
    ) -> None:
        self.task = env
        """The unwrapped env (its ``eval_ratios`` define the evaluation)."""
        self.num_envs = int(num_envs)
        self.num_actions = int(env.action_size)
        self.num_obs = int(env.observation_size)
        self.max_episode_length = int(env.episode_length)
        self.quality = quality
        if prior is not None:
            check_fits(prior, self.num_obs, self.num_actions)
        self.prior = prior
        """The action prior added to the step's actions, or None."""
        self.name = name
        self.layout = sum_layout(env)
        """The columns of the training sums ``stats["window"]`` (``rollout_sums``; as brax's rollout)."""
        key = jax.random.PRNGKey(seed)
        k_rand, self._key = jax.random.split(key)
        rfn = None
        if randomizer is not None:
            rfn = functools.partial(randomizer, rng=jax.random.split(k_rand, self.num_envs))
        self._env: BatchedEnv = wrap_fn(
            env, episode_length=self.max_episode_length, action_repeat=1, randomization_fn=rfn
        )
        self.weights = jax.device_put(weights(env), jax.local_devices()[0])
        """The reward weights, the step's last argument (``envs.reward_weights``): a compiled step serves
        any weights, so a run that changes only a weight loads it from the executable cache."""
        self.reset_jit = jax.jit(self._reset_fn)
        self.step_jit = jax.jit(self._step_fn)
        self.quality_jit = jax.jit(self._quality_fn)
        self.first_keys = self.next_keys()
        """The first reset's keys (drawn now, from the same stream as every later unseeded reset)."""
        self.reset: Callable[..., Any] = self.reset_jit
        """``keys -> (state, stats)``: the jitted reset, or its compiled executable once submitted."""
        self.step: Callable[..., Any] = lambda *args: self.step_jit(*args, self.weights)
        """``(state, actions, stats) -> (state, stats)``, on ``weights``."""
        self.finish_quality: Callable[..., Any] = self.quality_jit
        """``(quality sums, signals) -> figures``."""

    def next_keys(self, seed: int | None = None) -> jax.Array:
        """Reset keys for every env: the next of the stream, or those of ``seed`` (the stream is kept).

        Committed to jax's device (as the step's outputs are: its actions come from torch, committed): the
        step then sees one signature from the first call on (an uncommitted reset state compiled the jitted
        step a second time on the second call).
        """
        if seed is None:
            self._key, k = jax.random.split(self._key)
        else:
            k = jax.random.PRNGKey(seed)
        return jax.device_put(jax.random.split(k, self.num_envs), jax.local_devices()[0])

    def to_compile(self) -> list[Program]:
        """The reset, step and (with ``quality``) quality programs, for ``startup.compiled.compile_programs``.

        The step and the quality reduction are traced on the reset's abstract output, so nothing runs
        before the first state is needed; the step's stored executable is loaded on a worker.
        """
        reset_name, step_name, quality_name = self._names()
        device = jax.sharding.SingleDeviceSharding(jax.local_devices()[0])

        def reset_out(out: Any) -> Any:
            # A Lowered's out_info has no sharding, a loaded executable's has: rebuilt alike (the step's key).
            return jax.tree.map(
                lambda s: jax.ShapeDtypeStruct(s.shape, s.dtype, weak_type=s.weak_type, sharding=device),
                out[reset_name],
            )

        def step_args(out: Any) -> tuple:
            state, stats = reset_out(out)
            actions = jax.ShapeDtypeStruct((self.num_envs, self.num_actions), jnp.float32)
            w = jax.tree.map(lambda x: jax.ShapeDtypeStruct(x.shape, x.dtype, sharding=device), self.weights)
            return state, actions, stats, w

        def quality_args(out: Any) -> tuple:
            _, stats = reset_out(out)
            return stats["quality"], stats["signals"]

        programs = [
            Program(reset_name, self.reset_jit, (self.first_keys,)),
            Program(step_name, self.step_jit, step_args, load_in_background=True),
        ]
        if self.quality:
            programs.append(Program(quality_name, self.quality_jit, quality_args))
        return programs

    def use(self, compiled: CompiledPrograms) -> None:
        """Run the compiled (or loaded) programs from now on; a first call waits for its program."""
        reset_name, step_name, quality_name = self._names()
        self.reset = lambda *args: compiled[reset_name](*args)
        self.step = lambda *args: compiled[step_name](*args, self.weights)
        if self.quality:
            self.finish_quality = lambda *args: compiled[quality_name](*args)

    def _names(self) -> tuple[str, str, str]:
        return tuple(f"{self.name} {p}" for p in ("reset", "step", "quality"))  # type: ignore[return-value]

    # -- jitted pure functions ---------------------------------------------------------------------
    def _reset_fn(self, keys: jax.Array) -> tuple[Any, dict[str, Any]]:
        state = self._env.reset(keys)
        ratios = eval_ratios(self.task, state.metrics)  # a reset's metrics have the step's keys
        zeros = jnp.zeros(self.num_envs)
        stats = {
            "reward": jnp.zeros(()),
            "success": (jnp.zeros(()), jnp.zeros(())),
            "alive": zeros + 1.0,
            "return": zeros,
            "ratios": {k: (zeros, zeros) for k in ratios},
            "window": jnp.zeros(len(self.layout.columns)),
        }
        if self.quality:
            n = self.num_actions
            stats["quality"] = eval_quality.init(self.num_envs, n)
            stats["signals"] = jnp.zeros((self.max_episode_length, self.num_envs, n))
            stats["t"] = jnp.zeros((), jnp.int32)
        return state, stats

    def _step_fn(
        self, state: Any, actions: jax.Array, stats: dict[str, Any], w: dict[str, jax.Array]
    ) -> tuple[Any, dict[str, Any]]:
        stats_in = stats
        actions = commanded_action(self.prior, state.obs, actions)  # the observation the actor saw
        ns = self._env.with_env(with_weights(self.task, w)).step(state, actions)  # on the weights ``w``
        ratios = eval_ratios(self.task, ns.metrics)
        num, den = ratios["success_rate"]
        alive = stats["alive"]
        stats = {
            "reward": stats["reward"] + ns.reward.sum(),
            "success": (stats["success"][0] + num.sum(), stats["success"][1] + den.sum()),
            "alive": alive * (1.0 - ns.done),
            "return": stats["return"] + ns.reward * alive,
            "ratios": {
                k: (stats["ratios"][k][0] + n * alive, stats["ratios"][k][1] + d * alive)
                for k, (n, d) in ratios.items()
            },
            "window": stats["window"] + step_sums(self.layout, self.task, ns),
        }
        if self.quality:  # as brax.evaluation.evaluate: the applied action's signals, before the step
            t, task, f32 = stats_in["t"], self.task, lambda x: jnp.asarray(x, jnp.float32)
            sig = jax.vmap(task.quality_signals)(state, actions)
            robot = task.robot
            limits = {"cap": f32(robot.torque_cap), "lower": f32(robot.lower), "upper": f32(robot.upper)}
            terminated = ns.done * (1.0 - ns.info["truncation"])
            first = t == 0
            qc, _ = eval_quality.update(
                stats_in["quality"], sig, alive, terminated, first, dt=task.dt, **limits
            )
            last = self.max_episode_length - 1
            stats["quality"] = qc
            stats["signals"] = stats_in["signals"].at[jnp.minimum(t, last)].set(sig["signal"])
            stats["t"] = t + 1
        return ns, stats

    def _quality_fn(self, qc: dict[str, jax.Array], signals: jax.Array) -> dict[str, jax.Array]:
        # eval_quality.finish reduces over the mesh axis: a vmap of size 1 names it (the sums are this
        # device's). Chatter is measured over every tick of ``signals``: an evaluation steps all of them.
        one = jax.tree.map(lambda x: x[None], (qc, signals))
        out = jax.vmap(lambda q, s: eval_quality.finish(q, s, self.task.dt), axis_name=AXIS)(*one)
        return jax.tree.map(lambda x: x[0], out)


@dataclass(frozen=True, kw_only=True)
class RslRlPrograms:
    """The rsl-rl backend's jax side, compiling (``prepare_rsl_rl``), for ``train_rsl_rl(programs=...)``."""

    compiled: CompiledPrograms
    """Every program below, compiling or compiled (``train_rsl_rl`` waits on it)."""
    train: EnvPrograms
    """The training env's (``train reset``, ``train step``)."""
    eval: EnvPrograms
    """The evaluation env's (``eval reset``, ``eval step``, ``eval quality``)."""
    prior: Prior | None
    """The action prior both envs add (``training.prior.action_prior``; ``rsl_rl.prior``), or None."""


def prepare_rsl_rl(
    env: Any,
    cfg: TrainConfig,
    *,
    wrap_fn: Callable[..., BatchedEnv] | None = None,
    randomizer: Callable[..., Any] | None,
    eval_env: Any | None = None,
    start: StartUp | None = None,
) -> RslRlPrograms:
    """Build both envs' programs and compile them (``compile_programs``, once); torch is not imported.

    In order: train reset, train step, eval reset, eval step, eval quality; ``start``: the run's start-up
    (its breakdown and executable cache; None: a fresh one).

    ``eval_env``: the env the evaluations run (the task's held-out variant) on its nominal model, as brax's;
    None: ``env`` with ``randomizer``. Seeds: ``cfg.seed`` for training, ``cfg.seed + 1`` for evaluation.

    Raises:
        ValueError: ``ppo.actor_warmup_iterations`` is set (a brax-backend option), or a prior the env does
            not serve (``training.prior.action_prior``) or that does not fit it (``EnvPrograms``).
    """
    if cfg.ppo.actor_warmup_iterations:
        raise ValueError(
            f"ppo.actor_warmup_iterations={cfg.ppo.actor_warmup_iterations} is a brax-backend option; the "
            "rsl-rl backend's PPO has no critic warm-up (valid here: 0; or --backend brax)"
        )
    prior = action_prior(env, cfg.network, cfg.env_name)  # refuses a prior the env does not serve
    if wrap_fn is None:
        from bar_policy.envs import wrap_for_brax_training as wrap_fn
    kw = {"wrap_fn": wrap_fn, "randomizer": randomizer, "prior": prior}
    train = EnvPrograms(env, cfg.ppo.num_envs, seed=cfg.seed, name="train", **kw)
    e_env, e_kw = (env, kw) if eval_env is None else (eval_env, {**kw, "randomizer": None})
    evals = EnvPrograms(e_env, cfg.eval.num_eval_envs, seed=cfg.seed + 1, name="eval", quality=True, **e_kw)
    compiled = compile_programs([*train.to_compile(), *evals.to_compile()], start)
    train.use(compiled)
    evals.use(compiled)
    return RslRlPrograms(compiled=compiled, train=train, eval=evals, prior=prior)
