"""Typed training configuration: one frozen dataclass tree shared by both PPO backends.

``TrainConfig`` is the root. ``preset(name)`` builds the variants the tasks register (``TaskRecord.presets``)
as dotted-path overrides of the base, which ``apply_overrides`` (``bar_policy.overrides``, the env's
``--env-overrides`` syntax: ``"ppo.learning_rate=1e-3"``) applies to any config. The CLI (``training.cli``)
makes every field a tyro flag whose ``--help`` shows the field's docstring below (units included).

Sizes follow brax's PPO: one training iteration collects ``batch_size * num_minibatches`` trajectories of
``unroll_length`` steps (``num_envs`` environments, ``batch_size * num_minibatches / num_envs`` unrolls
each), then runs ``num_updates_per_batch`` passes of ``num_minibatches`` SGD steps over them.
"""

from __future__ import annotations

import dataclasses
import json
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Annotated, Any, Literal, get_args

import tyro

from bar_policy.overrides import apply_overrides, split_override
from bar_policy.task_records import default_env, resolve
from bar_policy.tasks.registry import TASKS
from bar_policy.training.writers import LOGGERS

__all__ = [
    "ACTION_PRIORS",
    "INITIAL_EVALS",
    "PRESETS",
    "DistributedConfig",
    "EnvName",
    "EvalConfig",
    "NetworkConfig",
    "PPOConfig",
    "PresetName",
    "RslRlConfig",
    "TrainConfig",
    "apply_overrides",
    "config_from_dict",
    "config_to_dict",
    "preset",
]


EnvName = Literal[tuple(e.name for r in TASKS for e in r.envs)]  # type: ignore[valid-type]
"""Registered env names (``bar_policy.envs.ALL_ENVS``, from the task records: ``--help`` imports no jax)."""
DEFAULT_ENV: str = default_env()
"""The default ``--env``: the first registered task's first env (``LiteReach``, ``task_records.default_env``;
the same as ``bar_policy.envs.DEFAULT_ENV``)."""
ACTION_PRIORS: tuple[str, ...] = (
    "none",
    *dict.fromkeys(e.action_prior for r in TASKS for e in r.envs if e.action_prior),
)
"""``NetworkConfig.action_prior`` values: ``none`` and each registered env's own prior
(``EnvEntry.action_prior`` in its task record), in registry order."""
ActionPriorName = Literal[ACTION_PRIORS]  # type: ignore[valid-type]
"""The ``--network.action-prior`` choices (``ACTION_PRIORS``)."""
InitialEval = Literal["start", "end", "off"]
"""``EvalConfig.initial`` choices: when the step-0 evaluation runs."""
INITIAL_EVALS: tuple[str, ...] = get_args(InitialEval)
PresetName = Literal[tuple(name for r in TASKS for name, _ in r.presets)]  # type: ignore[valid-type]
"""Preset names (``PRESETS``, read from the task records)."""


@dataclass(frozen=True, kw_only=True)
class NetworkConfig:
    """Actor and critic MLPs."""

    policy_hidden: tuple[int, ...] = (128, 128, 128)
    """Hidden layer widths of the policy MLP (its output layer is added: 2 x action size for brax)."""
    value_hidden: tuple[int, ...] = (256, 256, 256)
    """Hidden layer widths of the value MLP."""
    activation: Literal["swish", "elu", "relu", "tanh"] = "swish"
    """Hidden activation (brax's default is swish = x * sigmoid(x); rsl-rl's is elu)."""
    init_noise_std: float = 1.0
    """Initial action noise std, action units (rsl-rl backend; brax's tanh-normal head learns its own)."""
    action_prior: ActionPriorName = "none"
    """What the policy's mean starts from (``bar_policy.obs.action_prior``): ``none`` (the MLP gives the
    whole action) or the prior the env serves (its record's ``EnvEntry.action_prior``, built by the env's
    ``action_prior``; e.g. the tracker's ``reference``, its reference pose ``prior_lead_steps`` ahead, read
    from the observation); the MLP learns the correction. Both backends (rsl-rl: the env adds the prior to
    the Gaussian actor's action, ``training.rsl_rl.prior``); written into the ONNX graph."""
    prior_lead_steps: int = 5
    """Reference frame of the ``reference`` prior, control steps ahead (1..the layout's lookahead): 5 = 100
    ms, which the action filter's lag (53-64 ms at 2.5-3 Hz) and the PD law's need: with a zero MLP on the sim
    target (wave, clap at 2.5 Hz) leads 1, 3, 5 gave 0.020, 0.018, 0.014 rad (docs/tracking.md). Each
    task's prior states what its lead means (its env's ``action_prior``)."""

    prior_error_gain: float = 0.0
    """Gain of the prior's integral term, >= 0 (``obs.action_prior``, "Integral term"; the tracker's
    ``reference`` prior, on a layout with ``joint_error_ema``): the prior's command adds this times the
    error average, rad per rad; 1 cancels a steady load (a payload's sag, gravity itself) before the MLP
    learns anything; 0: none. The prior alone on the sim target, 12 held-out clips: 3.80 cm at 0, 0.90 cm
    at 1 (docs/robust_training.md, "The integral prior")."""

    prior_noise_std: float | None = None
    """With an action prior: the policy's initial action noise std, pre-tanh action units (None: brax's
    init, softplus(0) = 0.69). A small one keeps the first policies near the prior (the piano preset's 0.1:
    0.69 moves a fingertip several key widths). rsl-rl backend: the Gaussian's initial std, action units
    (replacing ``init_noise_std``)."""

    def __post_init__(self) -> None:
        if self.prior_noise_std is not None and not self.prior_noise_std > 0.001:
            raise ValueError(
                f"prior_noise_std must be > 0.001 (brax's minimum std), got {self.prior_noise_std}"
            )
        if self.action_prior not in ACTION_PRIORS:
            raise ValueError(f"unknown action_prior {self.action_prior!r}; valid: {list(ACTION_PRIORS)}")
        if not (math.isfinite(self.prior_error_gain) and self.prior_error_gain >= 0.0):
            raise ValueError(f"prior_error_gain must be a finite number >= 0, got {self.prior_error_gain}")
        if self.prior_error_gain > 0.0 and self.action_prior == "none":
            raise ValueError("prior_error_gain > 0 needs an action prior (network.action_prior), got none")
        if self.prior_lead_steps < 1:
            raise ValueError(f"prior_lead_steps must be >= 1 control step, got {self.prior_lead_steps}")
        if not self.policy_hidden or any(w <= 0 for w in (*self.policy_hidden, *self.value_hidden)):
            raise ValueError(
                f"hidden layer widths must be positive and policy_hidden non-empty, got "
                f"policy_hidden={self.policy_hidden}, value_hidden={self.value_hidden}"
            )


@dataclass(frozen=True, kw_only=True)
class PPOConfig:
    """PPO hyperparameters (brax names; the rsl-rl backend maps them, see ``RslRlConfig``)."""

    num_timesteps: int = 40_000_000
    """Total environment steps (policy steps summed over all envs and devices) to train for."""
    num_envs: int = 4096
    """Parallel environments, summed over all devices and hosts (must divide by the device count)."""
    unroll_length: int = 10
    """Policy steps per environment per rollout segment (the GAE horizon)."""
    batch_size: int = 512
    """Trajectory segments per SGD minibatch."""
    num_minibatches: int = 16
    """SGD minibatches per pass; batch_size * num_minibatches must be a multiple of num_envs."""
    num_updates_per_batch: int = 8
    """Passes (epochs) over the collected data per training iteration."""
    learning_rate: float = 5e-4
    """Adam learning rate (the initial one with the adaptive schedule)."""
    schedule: Literal["fixed", "adaptive"] = "fixed"
    """Learning-rate schedule: ``fixed``, or ``adaptive`` (rsl-rl's KL-targeting rule, brax backend: before
    each minibatch step, the learning rate is divided by 1.5 when the policy's KL divergence from the one
    that collected the data exceeds 2 x ``desired_kl``, multiplied by 1.5 below ``desired_kl`` / 2, and kept
    within [``min_learning_rate``, ``max_learning_rate``]; the rsl-rl backend uses ``rsl_rl.schedule``)."""
    desired_kl: float = 0.01
    """KL target of the adaptive schedule (nats; the KL of the whole action distribution, as rsl-rl's)."""
    min_learning_rate: float = 1e-5
    """Floor of the adaptive learning rate."""
    max_learning_rate: float = 1e-2
    """Ceiling of the adaptive learning rate."""
    entropy_cost: float = 5e-3
    """Weight of the entropy bonus in the loss."""
    discounting: float = 0.97
    """Discount factor gamma per policy step."""
    gae_lambda: float = 0.95
    """GAE lambda."""
    clipping_epsilon: float = 0.2
    """PPO ratio clip."""
    reward_scaling: float = 1.0
    """Multiplier applied to rewards inside the loss."""
    max_grad_norm: float = 1.0
    """Global gradient-norm clip (<= 0 disables it)."""
    normalize_observations: bool = True
    """Keep running mean/std of observations and feed (obs - mean) / std to the networks."""
    obs_std_eps: float = 1e-4
    """Added to the observations' running variance, (obs unit)^2 (brax's ``std_eps``): std >= 0.01, as in
    rsl-rl's normaliser. At 0 (brax's) reach's first targets (1.3 mm apart) gave z = 30 (docs/training.md)."""
    value_targets: Literal["minibatch", "pass", "iteration"] = "pass"
    """GAE's targets and advantages from the critic at every minibatch (brax), at each SGD pass's start, or
    once per iteration (rsl-rl; ``ppo_loss.with_value_targets``). Reach's value loss spiked at minibatch,
    not at pass, which learns as fast (docs/training.md). brax backend; track and piano keep minibatch."""
    vf_loss_coefficient: float = 0.5
    """Weight of the value loss."""
    update_precision: Literal["run", "tensorfloat32", "BF16_BF16_F32_X3"] = "run"
    """SGD passes' matrix products: ``run`` (``TrainConfig.matmul_precision``) or tensor cores' (jax's names;
    physics, rollout keep the run's; rsl-rl: TF32 only). H200 (280175b, 2026-11-28): 30 -> 17 / 22 ms."""
    actor_warmup_iterations: int = 0
    """First iterations in which only the critic learns (policy gradients zeroed; brax backend): against an
    untrained critic the first updates push the policy off an action prior (piano: F1 0.70 -> 0.23 in 2.3M
    steps, docs/piano.md). 0: off."""

    def __post_init__(self) -> None:
        ints = ("num_timesteps", "num_envs", "unroll_length", "batch_size", "num_minibatches")
        for name in (*ints, "num_updates_per_batch"):
            if getattr(self, name) <= 0:
                raise ValueError(f"ppo.{name} must be positive, got {getattr(self, name)}")
        if (self.batch_size * self.num_minibatches) % self.num_envs:
            raise ValueError(
                f"ppo.batch_size * ppo.num_minibatches = {self.batch_size * self.num_minibatches} must be a "
                f"multiple of ppo.num_envs = {self.num_envs}"
            )
        if not (
            0 < self.min_learning_rate <= self.learning_rate <= self.max_learning_rate and self.desired_kl > 0
        ):
            raise ValueError(
                f"need 0 < ppo.min_learning_rate <= ppo.learning_rate <= ppo.max_learning_rate and "
                f"ppo.desired_kl > 0, got {self.min_learning_rate}, {self.learning_rate}, "
                f"{self.max_learning_rate}, {self.desired_kl}"
            )
        if not 0 <= self.obs_std_eps < float("inf"):
            raise ValueError(f"ppo.obs_std_eps must be a finite variance >= 0, got {self.obs_std_eps}")
        if not 0 < self.discounting <= 1 or not 0 <= self.gae_lambda <= 1:
            raise ValueError(f"discounting must be in (0, 1] and gae_lambda in [0, 1], got {self}")
        if self.actor_warmup_iterations < 0:
            raise ValueError(f"ppo.actor_warmup_iterations must be >= 0, got {self.actor_warmup_iterations}")

    @property
    def steps_per_iteration(self) -> int:
        """Environment steps collected per training iteration."""
        return self.batch_size * self.num_minibatches * self.unroll_length


@dataclass(frozen=True, kw_only=True)
class RslRlConfig:
    """Settings that only the rsl-rl backend uses (the rest comes from ``PPOConfig``).

    Mapping: num_steps_per_env = ppo.steps_per_iteration / ppo.num_envs, num_learning_epochs =
    ppo.num_updates_per_batch, num_mini_batches = ppo.num_minibatches, gamma = ppo.discounting, lam =
    ppo.gae_lambda, clip_param = ppo.clipping_epsilon, entropy_coef = ppo.entropy_cost.
    """

    schedule: Literal["adaptive", "fixed"] = "adaptive"
    """Learning-rate schedule (adaptive = rsl-rl's KL-targeting schedule)."""
    desired_kl: float = 0.01
    """KL target of the adaptive schedule."""
    value_loss_coef: float = 1.0
    """Weight of the value loss."""
    clipped_value_loss: bool = True
    """rsl-rl's ``use_clipped_value_loss``: per sample, the larger of the squared error and the one with the
    value's change since the rollout clipped to ``ppo.clipping_epsilon`` (rsl-rl's default and the field's;
    brax's is never clipped). ``--rsl-rl.no-clipped-value-loss``: the plain squared error."""
    device: str = "auto"
    """Torch device: ``auto`` (cuda when jax runs on a GPU, else cpu), ``cpu`` or ``cuda``."""


@dataclass(frozen=True, kw_only=True)
class EvalConfig:
    """Periodic evaluation on fresh seeds (deterministic policy, domain randomisation as in training)."""

    num_evals: int = 11
    """Evaluations over the run (step 0's counted, see ``initial``; the last at the end)."""
    num_eval_envs: int = 1024
    """Episodes per evaluation (one per parallel env)."""
    success_threshold: float = 0.95
    """Success rate that counts as solved (reported as time-to-threshold)."""
    initial: InitialEval = "end"
    """When the untrained policy is evaluated (recorded at step 0; a resume has none): ``start`` (at the
    first epoch end where the evaluation is compiled, before the first periodic one), ``end`` (after the
    last periodic one: it costs nothing on the way to the first trained policy, about 3 s on an H100) or
    ``off``. Not counted for the time to threshold when it runs late."""

    def __post_init__(self) -> None:
        if self.num_evals < 2 or self.num_eval_envs <= 0:
            raise ValueError(f"eval.num_evals must be >= 2 and num_eval_envs > 0, got {self}")
        if self.initial not in INITIAL_EVALS:
            raise ValueError(f"unknown eval.initial {self.initial!r}; valid: {list(INITIAL_EVALS)}")


@dataclass(frozen=True, kw_only=True)
class DistributedConfig:
    """Multi-host training through ``jax.distributed.initialize`` (leave empty on one machine)."""

    coordinator_address: str | None = None
    """host:port of process 0, e.g. ``10.0.0.1:1234``; None = single process."""
    num_processes: int = 1
    """Number of processes (hosts) taking part."""
    process_id: int = 0
    """This process's rank, 0 .. num_processes - 1."""
    max_devices_per_host: int | None = None
    """Use at most this many local devices (None = all of them; single-process runs only)."""
    local_device_ids: tuple[int, ...] | None = None
    """GPUs this process uses, e.g. ``(0,)`` for one process per GPU on one host (None = all visible)."""

    def __post_init__(self) -> None:
        if self.num_processes < 1 or not 0 <= self.process_id < self.num_processes:
            raise ValueError(
                f"distributed.process_id must be in 0 .. num_processes - 1 and num_processes >= 1, got "
                f"process_id={self.process_id}, num_processes={self.num_processes}"
            )
        if self.max_devices_per_host is not None and self.max_devices_per_host <= 0:
            raise ValueError(
                f"distributed.max_devices_per_host must be positive or None, got {self.max_devices_per_host}"
            )


@dataclass(frozen=True, kw_only=True)
class TrainConfig:
    """Root configuration of ``python train/ppo.py``."""

    env_name: Annotated[EnvName, tyro.conf.arg(aliases=("--env",))] = DEFAULT_ENV
    """Registered environment (``bar_policy.envs.load``); ``--env`` is short for it."""
    env_overrides: tuple[str, ...] = ()
    """Env/reward settings, ``path=value`` in the env config's units: ``reward.scales.action_rate=-0.1``; a
    shorthand for the typed ``--env.*`` flags (``--env.reward.scales.action-rate -0.1``), which the run
    records here too."""
    backend: Literal["brax", "rsl-rl"] = "brax"
    """brax = brax's PPO pieces, JAX end to end (default); rsl-rl = rsl-rl-lib (torch) on the same env."""
    preset: PresetName = "gpu"
    """Preset supplying every default shown: gpu (one H100; the default), gpu-rsl (the rsl-rl backend's
    default: gpu on rsl-rl, fast sizes, fixed rate), rsl (gpu on rsl-rl at the field's values), cpu,
    tiny (tests), track (LiteTrack, H100), track-rsl (track on rsl-rl), piano (LitePiano, H100)."""
    seed: int = 0
    """Seed of parameter init, env resets and evaluation."""
    run_name: str = ""
    """Run directory name under runs_dir (empty = ``<env>-<backend>-<timestamp>``)."""
    runs_dir: str = "runs"
    """Parent directory of run directories (path)."""
    resume: str | None = None
    """Run directory or checkpoint file to resume from (params, normaliser, optimizer, step count)."""
    log_every_iterations: int = 0
    """Training iterations per progress line (one compiled epoch); 0 = auto, about 2 lines per evaluation."""
    checkpoint_every: int = 1
    """Save a checkpoint every this many evaluation periods (0 = only at the end)."""
    logger: Literal["tensorboard", "wandb", "none"] = "tensorboard"
    """Where the scalars go besides metrics.jsonl (``training.writers``): TensorBoard event files in
    ``<run>/tb``; ``wandb``, those and a Weights & Biases run (optional package; ``WANDB_MODE=offline``
    works without a network); ``none``. Tags: ``training.log_tags`` (docs/training.md)."""
    wandb_project: str = "bar_policy"
    """Weights & Biases project (for the wandb logger)."""
    max_minutes: float = 0.0
    """Wall-clock budget of training, min (0 = no limit; counted from the start of the process): no epoch
    starts that would end past it (by the last epoch's and evaluation's lengths); then export."""
    export_onnx: bool = True
    """Export ONNX (with the parity gate) and the final evaluation at the end."""
    onnx_path: str = ""
    """Where to write the ONNX file (empty = ``<run dir>/policy.onnx``)."""
    final_eval_envs: int = 4096
    """Episodes in the final evaluation written next to the ONNX file, episodes."""
    matmul_precision: Literal["default", "highest"] = "highest"
    """float32 matrix products: ``highest`` (full float32, what MuJoCo Playground sets: TF32 products on
    NVIDIA GPUs destabilised its training) or ``default`` (the backend's fastest, TF32 on Ampere and later;
    no effect on CPUs)."""
    compile_cache: bool = True
    """Persistent XLA compilation cache (a rerun of the same command loads programs instead of compiling)."""
    compile_cache_dir: str = ""
    """Cache directory (empty: $JAX_COMPILATION_CACHE_DIR, else $XDG_CACHE_HOME/bar_policy/jax)."""
    autotune_seed: bool = True
    """Seed XLA's per-fusion autotune cache (in the compile cache) with the results shipped for this GPU
    and jaxlib (``training/startup/autotune.py``); GPUs only, never overwrites. H100, LiteReach gpu preset,
    empty compile cache: first evaluation at 68.6 s instead of 99.4 s, same training speed (2026-11-27)."""
    quick_compile: bool = False
    """Compile every program with XLA's LLVM at -O1 and its older CPU fusion emitters
    (``startup.compile_cache.QUICK_COMPILE``): a shorter compile at about the same speed on a CPU. For smoke
    runs and tests on a CPU (the tiny preset sets it); not measured on GPUs
    (docs/training.md, "Smoke run")."""
    executable_cache: bool = True
    """Executable cache in <cache directory>/executables (with the compile cache): a rerun of the same
    command and code loads each program without tracing, lowering or compiling it. Used on GPU backends;
    on a CPU only with BAR_POLICY_EXECUTABLE_CACHE_ON_CPU=1; under several processes each keeps its own
    entries, loaded only when every process holds them. H100, LiteReach gpu preset (2026-11-27): two warm
    runs loaded all 4 programs, first evaluation at 22.0 and 25.0 s instead of 35-41 s with jax's
    persistent cache alone, same learning curve (docs/training.md)."""
    ppo: PPOConfig = field(default_factory=PPOConfig)
    network: NetworkConfig = field(default_factory=NetworkConfig)
    eval: EvalConfig = field(default_factory=EvalConfig)
    rsl_rl: RslRlConfig = field(default_factory=RslRlConfig)
    distributed: DistributedConfig = field(default_factory=DistributedConfig)

    def __post_init__(self) -> None:
        if (
            self.checkpoint_every < 0
            or self.max_minutes < 0
            or self.final_eval_envs <= 0
            or self.log_every_iterations < 0
        ):
            raise ValueError(
                "checkpoint_every, max_minutes and log_every_iterations must be >= 0 and final_eval_envs "
                f"> 0, got {self.checkpoint_every}, {self.max_minutes}, {self.log_every_iterations}, "
                f"{self.final_eval_envs}"
            )
        for o in self.env_overrides:
            split_override(o)
        if self.logger not in LOGGERS:
            raise ValueError(f"unknown logger {self.logger!r}; choices: {', '.join(LOGGERS)}")


# ----------------------------------------------------------------------------------------------------------
# Presets
# ----------------------------------------------------------------------------------------------------------


def _task_preset(ref: str) -> Callable[[], TrainConfig]:
    def make() -> TrainConfig:
        return apply_overrides(TrainConfig(), resolve(ref))

    return make


PRESETS: dict[str, Callable[[], TrainConfig]] = {
    name: _task_preset(ref) for record in TASKS for name, ref in record.presets
}
"""Preset name -> factory: each task's presets (``TaskRecord.presets``: ``{dotted.path: value}`` mappings on
``TrainConfig()``, e.g. ``bar_policy/tasks/track/preset.py``), in registry order."""


def preset(name: str) -> TrainConfig:
    """The config of a named preset; raises ``ValueError`` listing the valid names."""
    if name not in PRESETS:
        raise ValueError(f"unknown preset {name!r}; presets: {sorted(PRESETS)}")
    return PRESETS[name]()


def config_to_dict(cfg: TrainConfig) -> dict[str, Any]:
    """Plain-JSON form of a config."""
    return json.loads(json.dumps(dataclasses.asdict(cfg)))


def _from_dict(cls: type, data: dict[str, Any]) -> Any:
    kwargs = {}
    hints = {f.name: f for f in dataclasses.fields(cls)}
    for name, value in data.items():
        if name not in hints:
            raise ValueError(f"{cls.__name__} has no field {name!r}; valid: {sorted(hints)}")
        default = getattr(cls(), name) if name in hints else None
        if dataclasses.is_dataclass(default):
            kwargs[name] = _from_dict(type(default), value)
        elif isinstance(value, list):
            kwargs[name] = tuple(value)
        else:
            kwargs[name] = value
    return cls(**kwargs)


def config_from_dict(data: dict[str, Any]) -> TrainConfig:
    """Inverse of ``config_to_dict`` (e.g. to read a run's ``config.json``)."""
    return _from_dict(TrainConfig, data)
