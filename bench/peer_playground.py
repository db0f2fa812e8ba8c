"""Side by side with a peer: our reach env and MuJoCo Playground envs in one process, one batch, one device.

For our env (``--ours``, default LiteReach, through ``bar_policy.envs.load``) and each
Playground env (``--peers``, loaded through Playground's own ``mujoco_playground.registry``, MJX's JAX
implementation: ``impl="jax"``, since Warp is not installed) at the same ``--batch``:

1. Physics throughput: each env inside its own project's training wrapper (vmap over the batch, its own
   domain randomisation unless ``--no-dr``, episode length, auto-reset), ``jit(step)`` built once with the
   state donated, fixed uniform random actions in [-1, 1]; one warm-up call (compile, reported apart), a
   second one, then timed calls until ``--min-time`` s and ``--min-iters`` calls (``block_until_ready`` at
   the end). Env steps/s = batch / time per call; physics steps/s = env steps/s x the env's substeps per
   control step; per actuated joint = physics steps/s x the env's action size.
2. Training throughput (``--train-steps`` > 0): brax's ``ppo.train`` for each env with the *same* PPO
   settings, Playground's published ones for the first peer (``mujoco_playground.config.locomotion_params``
   or ``dm_control_suite_params``; the network's hidden sizes too; the observation keys only where the
   env's observation is a dict that has them), ``num_envs = --batch``, ``num_timesteps = --train-steps``
   split into ``--train-chunks`` progress calls, no evaluations. Steady env steps/s = env steps between the
   second and the last progress call over the wall time between them (the first chunk holds the compile,
   the second may hold brax's recompile; with 2 chunks: from the first); end to end = all steps over the
   whole ``train`` call.
3. Ratios ours / peer, and the issue's target: at least as many physics steps per second per actuated
   joint as the Playground env in the same run.

Playground's Berkeley Humanoid envs need the ``berkeley_humanoid`` meshes of mujoco_menagerie, which
Playground clones at run time when its ``MENAGERIE_PATH`` folder is missing (no network here or on the GPU
machine): ``--menagerie`` gives a folder holding ``berkeley_humanoid/`` or a ``.tar.xz`` of it (made by
``bench/peer_assets.py``), and this script points ``mujoco_playground._src.mjx_env.MENAGERIE_PATH`` there
before any env is loaded. The dm_control humanoid (``HumanoidWalk``) needs no assets.

Examples::

    python bench/peer_playground.py --menagerie .peer_assets/berkeley_humanoid.tar.xz --out $OUT/peer.json
    python bench/peer_playground.py --peers HumanoidWalk --batch 8192 --train-steps 0
    python bench/peer_playground.py --smoke --menagerie .peer_assets/berkeley_humanoid.tar.xz   # CPU check

Writes the JSON after every row, so a run cut short keeps what it measured.
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
import importlib.metadata
import inspect
import itertools
import json
import math
import os
import platform
import tarfile
import tempfile
import time
import traceback
from collections.abc import Callable
from pathlib import Path
from typing import Any

import jax
import mujoco

from bar_policy import envs
from bar_policy.provenance import collect, commit_text

DEFAULT_PEERS = ("BerkeleyHumanoidJoystickFlatTerrain",)
MENAGERIE_ROBOTS = {"BerkeleyHumanoid": "berkeley_humanoid"}
"""Playground env-name prefix -> the menagerie folder its XML needs (those this bench can be given)."""


@dataclasses.dataclass
class Side:
    """One env of the comparison and what its project uses to train it."""

    label: str
    name: str
    env: Any
    wrap: Callable[..., Any]
    randomizer: Callable[..., Any] | None
    episode_length: int

    @property
    def n_substeps(self) -> int:
        return int(self.env.n_substeps)

    @property
    def joints(self) -> int:
        return int(self.env.action_size)


# ---------------------------------------------------------------------------------------------------
# Loading
# ---------------------------------------------------------------------------------------------------
def use_menagerie(path: str | None, needed: list[str]) -> str | None:
    """Point Playground's ``MENAGERIE_PATH`` at ``path`` (a folder, or an archive unpacked to a temp dir).

    Fails early, naming what is missing, when a peer needs a robot folder that ``path`` does not hold:
    Playground would otherwise try to clone mujoco_menagerie.
    """
    if not needed and path is None:
        return None
    if path is None:
        raise SystemExit(f"peers need menagerie folders {needed}: pass --menagerie DIR_OR_TAR_XZ")
    src = Path(path)
    if src.is_file():
        root = Path(tempfile.mkdtemp(prefix="peer_menagerie_"))
        with tarfile.open(src) as tf:
            tf.extractall(root, filter="data")
    else:
        root = src
    missing = [r for r in needed if not (root / r / "assets").is_dir()]
    if missing:
        raise SystemExit(f"--menagerie {path}: no {missing}/assets in it (has {sorted(os.listdir(root))})")
    from etils import epath
    from mujoco_playground._src import mjx_env

    mjx_env.MENAGERIE_PATH = epath.Path(root)
    return str(root)


def load_ours(name: str, overrides: list[str]) -> Side:
    """Our env, its brax training wrapper and randomiser."""
    env = envs.load(name, overrides=overrides or None)
    return Side(
        "ours",
        name,
        env,
        envs.wrap_for_brax_training,
        envs.get_randomizer(name, env.config),
        int(env.episode_length),
    )


def load_peer(name: str, impl: str) -> Side:
    """A Playground env from Playground's registry, with Playground's wrapper and randomiser."""
    from mujoco_playground import registry, wrapper

    env = registry.load(name, config_overrides={"impl": impl})
    cfg = registry.get_default_config(name)
    return Side(
        "peer",
        name,
        env,
        wrapper.wrap_for_brax_training,
        registry.get_domain_randomizer(name),
        int(cfg.episode_length),
    )


def peer_ppo_config(name: str) -> dict[str, Any]:
    """Playground's published brax PPO settings for ``name`` (a plain dict)."""
    from mujoco_playground import registry
    from mujoco_playground.config import dm_control_suite_params, locomotion_params, manipulation_params

    if name in registry.locomotion.ALL_ENVS:
        cfg = locomotion_params.brax_ppo_config(name)
    elif name in registry.dm_control_suite.ALL_ENVS:
        cfg = dm_control_suite_params.brax_ppo_config(name)
    else:
        cfg = manipulation_params.brax_ppo_config(name)
    return cfg.to_dict()


# ---------------------------------------------------------------------------------------------------
# Measurements
# ---------------------------------------------------------------------------------------------------
def _block(x: Any) -> None:
    jax.tree.map(lambda a: a.block_until_ready() if hasattr(a, "block_until_ready") else a, x)


def physics_row(side: Side, args: argparse.Namespace) -> dict[str, Any]:
    """Time ``jit(step)`` of the wrapped, batched env (see the module docstring)."""
    batch = args.batch
    keys = jax.random.split(jax.random.PRNGKey(0), batch)
    rand = None
    if side.randomizer is not None and not args.no_dr:
        rand = functools.partial(side.randomizer, rng=keys)
    w = side.wrap(side.env, episode_length=side.episode_length, action_repeat=1, randomization_fn=rand)
    reset, step = jax.jit(w.reset), jax.jit(w.step, donate_argnums=(0,))
    act = jax.random.uniform(jax.random.PRNGKey(1), (batch, side.joints), minval=-1.0, maxval=1.0)
    t0 = time.perf_counter()
    state = reset(keys)
    _block(state)
    reset_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    state = step(state, act)
    _block(state)
    compile_s = time.perf_counter() - t0
    state = step(state, act)
    _block(state)
    n, t0 = 0, time.perf_counter()
    while True:
        state = step(state, act)
        n += 1
        if n >= args.max_iters or (n >= args.min_iters and time.perf_counter() - t0 >= args.min_time):
            break
    _block(state)
    dt = (time.perf_counter() - t0) / n
    env_sps = batch / dt
    row = {
        "side": side.label,
        "env": side.name,
        "batch": batch,
        "dr": rand is not None,
        "substeps": side.n_substeps,
        "joints": side.joints,
        "ms_per_call": dt * 1e3,
        "calls": n,
        "env_sps": env_sps,
        "physics_sps": env_sps * side.n_substeps,
        "physics_sps_x_joints": env_sps * side.n_substeps * side.joints,
        "compile_s": compile_s,
        "reset_s": reset_s,
    }
    print(
        f"  physics {side.label:<4} {side.name:<38} {row['ms_per_call']:9.3f} ms/call  "
        f"{row['physics_sps']:11.4g} phys/s  x{side.joints} joints {row['physics_sps_x_joints']:11.4g}  "
        f"compile {compile_s:.1f} s",
        flush=True,
    )
    return row


def ppo_kwargs(cfg: dict[str, Any], side: Side, args: argparse.Namespace) -> tuple[dict[str, Any], list[str]]:
    """``ppo.train`` keywords from a Playground PPO config, fitted to ``side`` and the run's sizes."""
    from brax.training.agents.ppo import networks as ppo_networks
    from brax.training.agents.ppo import train as ppo

    cfg = dict(cfg)
    net = dict(cfg.pop("network_factory", {}) or {})
    for item in args.ppo_set:
        key, _, value = item.partition("=")
        cfg[key] = json.loads(value)
    net_kw = {k: tuple(v) for k, v in net.items() if k.endswith("hidden_layer_sizes")}
    obs_size = side.env.observation_size
    for k in ("policy_obs_key", "value_obs_key"):
        if k in net and isinstance(obs_size, dict) and net[k] in obs_size:
            net_kw[k] = net[k]
    cfg.update(
        num_envs=args.batch,
        num_timesteps=args.train_steps,
        num_evals=args.train_chunks + 1,
        run_evals=False,
        episode_length=side.episode_length,
        seed=0,
    )
    accepted = set(inspect.signature(ppo.train).parameters)
    dropped = sorted(k for k in cfg if k not in accepted)
    kw = {k: v for k, v in cfg.items() if k in accepted}
    if (kw["batch_size"] * kw["num_minibatches"]) % kw["num_envs"]:
        prod = kw["batch_size"] * kw["num_minibatches"]
        raise SystemExit(
            f"batch_size x num_minibatches = {prod} is not a multiple of --batch "
            f"{args.batch} (brax needs it); pick another --batch"
        )
    kw["network_factory"] = functools.partial(ppo_networks.make_ppo_networks, **net_kw)
    kw["randomization_fn"] = None if args.no_dr else side.randomizer
    return kw, dropped


def restore_device_put_replicated() -> bool:
    """Give jax back ``device_put_replicated`` when it lacks it; True when the shim was installed.

    jax 0.10 removed it (its module ``__getattr__`` raises), and brax 0.14.2's ``ppo.train`` (which
    Playground trains with) still calls it once, to put the training state on the devices it ``pmap``s
    over. The stand-in is a ``pmap`` that returns its unmapped argument on every device, so the state
    comes out laid out as the old function laid it out (and as the epoch's own ``pmap`` outputs are).
    Used by this bench only; our trainer needs no shim.
    """
    try:
        jax.device_put_replicated  # noqa: B018 - the attribute access is the test
        return False
    except AttributeError:
        pass
    import jax.numpy as jnp

    def device_put_replicated(x: Any, devices: list[Any]) -> Any:
        devices = list(devices)
        put = jax.pmap(lambda _, y: y, in_axes=(0, None), devices=devices)
        return put(jnp.arange(len(devices)), x)

    jax.device_put_replicated = device_put_replicated
    return True


def train_row(side: Side, cfg: dict[str, Any], args: argparse.Namespace) -> dict[str, Any]:
    """brax PPO on ``side`` for ``--train-steps`` env steps; env steps/s steady and end to end."""
    from brax.training.agents.ppo import train as ppo

    kw, dropped = ppo_kwargs(cfg, side, args)
    marks: list[tuple[float, int, float]] = []

    def progress(step: int, metrics: dict[str, Any]) -> None:
        marks.append((time.perf_counter(), int(step), float(metrics.get("training/sps", math.nan))))

    t0 = time.perf_counter()
    ppo.train(environment=side.env, wrap_env_fn=side.wrap, progress_fn=progress, **kw)
    total = time.perf_counter() - t0
    steps = marks[-1][1] if marks else 0
    # The first chunk holds the epoch's compile, and the second compiles again (on CPU: 34-49 s, then
    # 0.1 s for the third; with either shim), so from 3 chunks on the steady rate starts after the second.
    first = 1 if len(marks) >= 3 else 0
    steady = math.nan
    if len(marks) >= 2 and marks[-1][0] > marks[first][0]:
        steady = (marks[-1][1] - marks[first][1]) / (marks[-1][0] - marks[first][0])
    times = [t0] + [m[0] for m in marks]
    row = {
        "side": side.label,
        "env": side.name,
        "num_envs": kw["num_envs"],
        "env_steps": steps,
        "wall_s": total,
        "first_chunk_s": marks[0][0] - t0 if marks else math.nan,
        "chunk_s": [b - a for a, b in itertools.pairwise(times)],
        "chunk_steps": [m[1] for m in marks],
        "steady_from_chunk": first + 1,
        "steady_env_sps": steady,
        "end_to_end_env_sps": steps / total if total > 0 else math.nan,
        "brax_last_sps": marks[-1][2] if marks else math.nan,
        "ppo": {k: v for k, v in kw.items() if k not in ("network_factory", "randomization_fn")},
        "network": {k: v for k, v in kw["network_factory"].keywords.items()},
        "config_keys_not_passed": dropped,
    }
    print(
        f"  train   {side.label:<4} {side.name:<38} {steps:>10} steps  {total:7.1f} s  steady "
        f"{steady:11.4g}  end to end {row['end_to_end_env_sps']:11.4g} env steps/s",
        flush=True,
    )
    return row


# ---------------------------------------------------------------------------------------------------
# Report
# ---------------------------------------------------------------------------------------------------
def ratios(result: dict[str, Any]) -> list[dict[str, Any]]:
    """Ours / peer for every peer: physics, per joint, env, training (steady and end to end)."""
    phys = {(r["side"], r["env"]): r for r in result["physics"]}
    train = {(r["side"], r["env"]): r for r in result["train"]}
    ours = result["ours"]
    out = []
    for peer in result["peers"]:
        row: dict[str, Any] = {"peer": peer}
        a, b = phys.get(("ours", ours)), phys.get(("peer", peer))
        if a and b:
            row["env_sps"] = a["env_sps"] / b["env_sps"]
            row["physics_sps"] = a["physics_sps"] / b["physics_sps"]
            row["physics_sps_x_joints"] = a["physics_sps_x_joints"] / b["physics_sps_x_joints"]
            row["target_met"] = bool(row["physics_sps_x_joints"] >= 1.0)
        a, b = train.get(("ours", ours)), train.get(("peer", peer))
        if a and b:
            row["train_steady_env_sps"] = a["steady_env_sps"] / b["steady_env_sps"]
            row["train_end_to_end_env_sps"] = a["end_to_end_env_sps"] / b["end_to_end_env_sps"]
        out.append(row)
    return out


def _g(x: Any) -> str:
    return "-" if x is None or (isinstance(x, float) and math.isnan(x)) else f"{x:.4g}"


def table(result: dict[str, Any]) -> str:
    """Markdown tables of a result."""
    lines = [
        f"## Peer bench: {result['ours']} vs {', '.join(result['peers'])}",
        "",
        f"- device: {result['device']}; jax {result['jax']}, mujoco {result['mujoco']}, "
        f"playground {result['playground']}, brax {result['brax']}; commit {result['commit']}",
        f"- batch {result['batch']}, domain randomisation "
        f"{'off' if result['no_dr'] else 'on (each env its own)'}",
        "",
        "| side | env | joints | substeps | env steps/s | physics steps/s | x joints | ms/call | compile s |",
        "|---|---|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in result["physics"]:
        lines.append(
            f"| {r['side']} | {r['env']} | {r['joints']} | {r['substeps']} | {_g(r['env_sps'])} | "
            f"{_g(r['physics_sps'])} | {_g(r['physics_sps_x_joints'])} | {r['ms_per_call']:.3f} | "
            f"{r['compile_s']:.1f} |"
        )
    if result["train"]:
        lines += [
            "",
            "| side | env | envs | env steps | wall s | first chunk s | steady env steps/s "
            "| end to end env steps/s |",
            "|---|---|---:|---:|---:|---:|---:|---:|",
        ]
        for r in result["train"]:
            lines.append(
                f"| {r['side']} | {r['env']} | {r['num_envs']} | {r['env_steps']} | "
                f"{r['wall_s']:.1f} | {r['first_chunk_s']:.1f} | {_g(r['steady_env_sps'])} | "
                f"{_g(r['end_to_end_env_sps'])} |"
            )
    lines += [
        "",
        "| ours / peer | env steps/s | physics steps/s | per actuated joint (target >= 1) "
        "| training steady | training end to end |",
        "|---|---:|---:|---:|---:|---:|",
    ]
    for r in result["ratios"]:
        met = {True: " (met)", False: " (NOT met)"}.get(r.get("target_met"), "")
        lines.append(
            f"| {r['peer']} | {_g(r.get('env_sps'))} | {_g(r.get('physics_sps'))} | "
            f"{_g(r.get('physics_sps_x_joints'))}{met} | {_g(r.get('train_steady_env_sps'))} | "
            f"{_g(r.get('train_end_to_end_env_sps'))} |"
        )
    return "\n".join(lines) + "\n"


def _write(result: dict[str, Any], out: str | None) -> None:
    result["ratios"] = ratios(result)
    if out:
        Path(out).parent.mkdir(parents=True, exist_ok=True)
        Path(out).write_text(json.dumps(result, indent=1, default=str) + "\n")


def main(argv: list[str] | None = None) -> dict[str, Any]:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--ours", default="LiteReach", help=f"one of {list(envs.ALL_ENVS)}")
    p.add_argument("--ours-overrides", nargs="*", default=[], help="dotted-path overrides of our env")
    p.add_argument("--peers", default=",".join(DEFAULT_PEERS), help="Playground env names, comma-separated")
    p.add_argument("--impl", default="jax", help="MJX implementation for the Playground envs")
    p.add_argument("--menagerie", default=None, help="folder with berkeley_humanoid/, or its .tar.xz")
    p.add_argument("--batch", type=int, default=4096)
    p.add_argument("--no-dr", action="store_true", help="nominal models (no domain randomisation) for both")
    p.add_argument("--min-time", type=float, default=2.0, help="s of timed physics calls per env")
    p.add_argument("--min-iters", type=int, default=10)
    p.add_argument("--max-iters", type=int, default=5000)
    p.add_argument(
        "--train-steps",
        type=int,
        default=4_900_000,
        help="env steps of PPO per env (brax rounds up to whole epochs: 4.92M at the Berkeley "
        "Humanoid's settings); 0: no training",
    )
    p.add_argument("--train-chunks", type=int, default=3, help="progress calls (the first holds the compile)")
    p.add_argument(
        "--train-envs", default=None, help="envs to train, comma-separated (default: ours and the first peer)"
    )
    p.add_argument("--no-physics", action="store_true", help="skip the physics rows")
    p.add_argument(
        "--ppo-config-from",
        default=None,
        help="Playground env whose PPO settings all use (default: the first peer)",
    )
    p.add_argument(
        "--ppo-set",
        action="append",
        default=[],
        metavar="KEY=JSON",
        help="override one PPO setting for every env, e.g. batch_size=4",
    )
    p.add_argument("--cache-dir", default=None, help="jax persistent compilation cache")
    p.add_argument("--out", default=None, help="JSON result (rewritten after every row)")
    p.add_argument("--markdown", default=None, help="also write the tables here")
    p.add_argument("--smoke", action="store_true", help="CPU check: batch 4, 2 timed calls, no training")
    args = p.parse_args(argv)
    if args.smoke:
        args.batch, args.min_time, args.min_iters, args.max_iters, args.train_steps = 4, 0.0, 2, 2, 0
    if args.cache_dir:
        jax.config.update("jax_compilation_cache_dir", args.cache_dir)
        jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    peers = [n for n in args.peers.split(",") if n]
    needed = sorted({r for n in peers for pre, r in MENAGERIE_ROBOTS.items() if n.startswith(pre)})
    menagerie = use_menagerie(args.menagerie, needed)
    from mujoco_playground import registry

    unknown = [n for n in peers if n not in registry.ALL_ENVS]
    if unknown:
        raise SystemExit(f"unknown Playground envs {unknown}; available: {list(registry.ALL_ENVS)}")
    dev = jax.devices()[0]
    result: dict[str, Any] = {
        "device": f"{dev.device_kind} ({jax.default_backend()}), {len(jax.devices())} device(s), "
        f"{platform.node()}",
        "jax": jax.__version__,
        "mujoco": mujoco.__version__,
        "playground": importlib.metadata.version("playground"),
        "brax": importlib.metadata.version("brax"),
        "commit": commit_text(collect()),  # git, or BAR_POLICY_GIT_COMMIT on the GPU copy
        "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
        "ours": args.ours,
        "peers": peers,
        "batch": args.batch,
        "no_dr": args.no_dr,
        "menagerie": menagerie,
        "physics": [],
        "train": [],
    }
    t_start = time.perf_counter()
    print(f"devices: {jax.devices()}; menagerie: {menagerie}", flush=True)
    result["errors"] = []

    def attempt(stage: str, name: str, fn: Callable[[], Any]) -> Any:
        """``fn()``, or None with the error recorded: one failing env or stage does not end the run."""
        try:
            return fn()
        except Exception as exc:  # a device run is one shot: keep the other rows
            traceback.print_exc()
            result["errors"].append({"stage": stage, "env": name, "error": repr(exc)})
            _write(result, args.out)
            return None

    sides = [load_ours(args.ours, args.ours_overrides)]
    sides += [s for n in peers if (s := attempt("load", n, functools.partial(load_peer, n, args.impl)))]

    def physics(group: list[Side]) -> None:
        for side in [] if args.no_physics else group:
            row = attempt("physics", side.name, functools.partial(physics_row, side, args))
            if row:
                result["physics"].append(row)
                _write(result, args.out)

    # Ours and the first peer first (physics, then training), the other peers' physics last: a run cut
    # short by its time limit loses the extras, not the main comparison.
    physics(sides[:2])
    if args.train_steps > 0:
        result["device_put_replicated_shim"] = restore_device_put_replicated()
        cfg = peer_ppo_config(args.ppo_config_from or peers[0])
        result["ppo_config_from"] = args.ppo_config_from or peers[0]
        train_envs = args.train_envs.split(",") if args.train_envs else [args.ours, peers[0]]
        for side in [s for s in sides if s.name in train_envs]:
            row = attempt("train", side.name, functools.partial(train_row, side, cfg, args))
            if row:
                result["train"].append(row)
                _write(result, args.out)
    physics(sides[2:])
    result["wall_s"] = time.perf_counter() - t_start
    _write(result, args.out)
    text = table(result)
    for err in result["errors"]:
        text += f"\nERROR in {err['stage']} of {err['env']}: {err['error']}\n"
    print(text)
    print(f"total wall time {result['wall_s']:.0f} s (compiles included)")
    if args.markdown:
        Path(args.markdown).parent.mkdir(parents=True, exist_ok=True)
        Path(args.markdown).write_text(text)
    return result


if __name__ == "__main__":
    main()
