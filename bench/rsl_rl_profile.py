"""Where an rsl-rl iteration's time goes: act, env step, process, returns, update.

Builds the rsl-rl backend's pieces exactly as ``train_rsl_rl`` does (``RslRlVecEnv`` + rsl-rl's
``OnPolicyRunner`` algorithm, config from a preset; the run's XLA flags from ``set_backend_env``, the update
under ``ppo.update_precision``) and times ``--iters`` iterations twice:

1. as the trainer runs them (no waits in the rollout): env steps/s end to end (best of a run before and one
   after the synced runs, after two warm-up iterations);
2. at its two boundaries (the rollout as queued by the host and as done on the device, the update), beside
   the env alone (the same steps with one fixed action batch, nothing of torch between them);
3. with a device sync after every phase, so each phase's own time shows: ``act`` (actor + critic forward
   and sampling), ``env`` (DLPack hand-off + jitted batched step), ``process`` (rsl-rl's storage and
   time-out bootstrap), ``returns`` (GAE), ``update`` (rsl-rl's PPO update), ``stats`` (the one host read
   of the logged sums).

On CUDA it also counts the torch calls that block the host in one rollout and in one update (CUDA's sync
debug mode) and sums one update's kernel time (torch.profiler): the update's time less its kernels' is
what the host's per-minibatch reads cost.

Examples::

    python bench/rsl_rl_profile.py --out $OUT/rsl_profile.md            # gpu preset, LiteReach
    python bench/rsl_rl_profile.py --preset tiny --iters 2             # CPU smoke check
    python bench/rsl_rl_profile.py --set ppo.num_envs=8192 ppo.batch_size=1024
    python bench/rsl_rl_profile.py --preset track-rsl --env LiteTrack      # the rsl-rl tracker's iteration
"""

from __future__ import annotations

import argparse
import time
import warnings
from collections import defaultdict
from collections.abc import Callable

import numpy as np
from config_args import add_config_args, config_label, config_of, load_env
from report import emit


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    add_config_args(p)
    p.add_argument("--iters", type=int, default=3)
    p.add_argument("--out", default="")
    args = p.parse_args()
    cfg = config_of(args, "backend=rsl-rl")
    from bar_policy.training.startup.backend_env import set_backend_env

    notes = set_backend_env(cfg)  # as the run does, before jax starts: memory, XLA's graph flags

    import jax
    import torch
    from rsl_rl.runners import OnPolicyRunner

    from bar_policy import envs
    from bar_policy.training.rsl_rl.backend import rsl_rl_train_cfg
    from bar_policy.training.rsl_rl.env import RslRlVecEnv, torch_device_for_jax
    from bar_policy.training.rsl_rl.torch_bridge import jax_to_torch, torch_to_jax
    from bar_policy.training.rsl_rl.torch_precision import update_precision
    from bar_policy.training.startup.compile_cache import configure_compile_cache

    configure_compile_cache(True)
    env = load_env(args.env, cfg)
    device = torch_device_for_jax()
    vec = RslRlVecEnv.from_env(
        env,
        cfg.ppo.num_envs,
        wrap_fn=envs.wrap_for_brax_training,
        randomizer=envs.get_randomizer(args.env, env.config),
        seed=0,
        device=device,
    )
    runner = OnPolicyRunner(vec, rsl_rl_train_cfg(cfg), log_dir=None, device=device)
    alg = runner.alg
    steps_per_env = cfg.ppo.steps_per_iteration // cfg.ppo.num_envs
    steps = steps_per_env * cfg.ppo.num_envs

    def sync() -> None:
        jax.block_until_ready(vec.state.obs)
        if device.startswith("cuda"):
            torch.cuda.synchronize()

    def update() -> None:
        """rsl-rl's PPO update as trained (under the run's update precision)."""
        with update_precision(cfg.ppo.update_precision):
            alg.update()

    def unmarked(name: str, t: float) -> float:
        return t

    def rollout(obs: object, mark: Callable[[str, float], float] = unmarked) -> tuple[object, float]:
        """The trainer's rollout (``rsl_rl.backend``'s loop), ``mark`` called after each phase; returns the
        last observations and ``mark``'s last time."""
        t = time.perf_counter()
        with torch.inference_mode():
            for _ in range(steps_per_env):
                actions = alg.act(obs)
                t = mark("act", t)
                obs, rew, dones, extras = vec.step(actions)
                t = mark("env", t)
                alg.process_env_step(obs, rew, dones, extras)
                t = mark("process", t)
            alg.compute_returns(obs)
        return obs, mark("returns", t)

    def iteration(obs: object, phases: dict[str, float] | None) -> object:
        def mark(name: str, t: float) -> float:
            if phases is None:
                return t
            sync()
            now = time.perf_counter()
            phases[name] += now - t
            return now

        obs, t = rollout(obs, mark)
        update()
        t = mark("update", t)
        vec.take_stats()
        mark("stats", t)
        return obs

    alg.train_mode()
    obs = vec.get_observations()
    t0 = time.perf_counter()
    obs = iteration(obs, None)  # warm-up: compiles the env step
    sync()
    warm = time.perf_counter() - t0
    obs = iteration(obs, None)  # and a second one: the first iterations after it still run slow

    def free_run() -> float:
        nonlocal obs
        sync()
        t0 = time.perf_counter()
        for _ in range(args.iters):
            obs = iteration(obs, None)
        sync()
        return (time.perf_counter() - t0) / args.iters

    free_first = free_run()

    def parts() -> tuple[float, float, float, float]:
        """One iteration as trained, timed at its two boundaries: (rollout queued by the host, rollout done
        on the device, update as trained, env alone: the same steps with fixed actions, no torch between)."""
        nonlocal obs
        sync()
        t0 = time.perf_counter()
        obs, _ = rollout(obs)
        queued = time.perf_counter() - t0
        sync()
        done = time.perf_counter() - t0
        t0 = time.perf_counter()
        update()
        sync()
        update_s = time.perf_counter() - t0
        vec.take_stats()
        with torch.inference_mode():
            fixed = alg.act(obs)
            alg.storage.clear()
            alg.transition.clear()
            sync()
            t0 = time.perf_counter()
            for _ in range(steps_per_env):
                vec.step(fixed)
            sync()
            env_alone = time.perf_counter() - t0
        obs = vec.get_observations()
        return queued, done, update_s, env_alone

    def host_calls(check: bool) -> tuple[dict[str, float], float]:
        """One rollout as trained (``vec.step``'s pieces written out), each host call timed without waits:
        where the host spends an iteration, and whether a call blocks it. ``check``: the bridge's
        ``torch_to_jax`` (which compares buffer pointers) or ``jax.dlpack.from_dlpack`` alone."""
        nonlocal obs
        host: dict[str, float] = defaultdict(float)

        def tick(name: str, t: float) -> float:
            now = time.perf_counter()
            host[name] += now - t
            return now

        sync()
        t0 = t = time.perf_counter()
        with torch.inference_mode():
            for _ in range(steps_per_env):
                actions = alg.act(obs)
                t = tick("act", t)
                a = actions.to(torch.float32)
                x = torch_to_jax(a) if check else jax.dlpack.from_dlpack(a)
                t = tick("torch -> jax (actions)", t)
                vec.state, vec.stats = vec._step(vec.state, x, vec.stats)
                t = tick("jitted step call", t)
                obs = vec.get_observations()
                s = vec.state
                rew, done = jax_to_torch(s.reward), jax_to_torch(s.done)
                log = {f"Metrics/{k}": jax_to_torch(v) for k, v in s.metrics.items()}
                extras = {"time_outs": jax_to_torch(s.info["truncation"]), "log": log}
                t = tick(f"jax -> torch ({4 + len(log)} arrays)", t)
                alg.process_env_step(obs, rew, done, extras)
                t = tick("process", t)
            alg.compute_returns(obs)
        host["queued (all of the above)"] = time.perf_counter() - t0
        sync()
        done_s = time.perf_counter() - t0
        update()
        vec.take_stats()
        return host, done_s

    calls = {check: [host_calls(check) for _ in range(args.iters)] for check in (True, False)}

    def blocking(fn: Callable[[], object]) -> int:
        """torch calls that block the host while ``fn`` runs (CUDA's sync debug mode)."""
        sync()
        torch.cuda.set_sync_debug_mode("warn")
        try:
            with warnings.catch_warnings(record=True) as seen:
                warnings.simplefilter("always")
                fn()
        finally:
            torch.cuda.set_sync_debug_mode(0)
        return sum("synchronizing" in str(w.message) for w in seen)

    def kernel_seconds(fn: Callable[[], object]) -> float:
        """The device's kernel time while ``fn`` runs: torch.profiler's self CUDA time, summed."""
        sync()
        with torch.profiler.profile(activities=[torch.profiler.ProfilerActivity.CUDA]) as prof:
            fn()
            sync()
        return 1e-6 * sum(e.self_device_time_total for e in prof.key_averages())

    def rollout_and_update() -> tuple[int, int, float] | None:
        """One rollout's and one update's blocking torch calls, and one update's kernel time (s), each of an
        iteration as trained; None off CUDA. rsl-rl's update reads its losses with ``.item()`` per
        minibatch: the counts and the kernel time say how much of the update's time is the host's."""
        if not device.startswith("cuda"):
            return None

        def collect() -> None:
            nonlocal obs
            obs, _ = rollout(obs)

        in_rollout = blocking(collect)
        in_update = blocking(update)
        collect()
        return in_rollout, in_update, kernel_seconds(update)

    cuda_checks = rollout_and_update()

    split = [parts() for _ in range(args.iters)]
    queued, rollout_done, update_s, env_alone = (min(x) for x in zip(*split, strict=True))
    phases: dict[str, float] = defaultdict(float)
    for _ in range(args.iters):
        obs = iteration(obs, phases)
    total = sum(phases.values()) / args.iters
    free = min(free_first, free_run())  # before and after the synced runs: the better of the two

    lines = [
        f"rsl-rl profile: {args.env}, {config_label(args)}, torch {device}, "
        f"{cfg.ppo.num_envs} envs x {steps_per_env} steps = {steps:,} env steps per iteration, "
        f"{cfg.ppo.num_updates_per_batch} x {cfg.ppo.num_minibatches} minibatches, "
        f"update precision {cfg.ppo.update_precision}",
        *notes,
        "",
        f"as trained (no waits): {1e3 * free:.0f} ms per iteration, {steps / free:,.0f} env steps/s "
        f"(first iteration with compile {warm:.1f} s)",
        "torch calls that block the host (CUDA's sync debug mode), one rollout of "
        f"{steps_per_env} steps / one update: "
        + ("n/a (not CUDA)" if cuda_checks is None else f"{cuda_checks[0]} / {cuda_checks[1]}"),
        "",
        "| one iteration as trained, best of the runs | ms per iteration |",
        "|---|---:|",
        f"| rollout: queued by the host (no waits) | {1e3 * queued:.1f} |",
        f"| rollout: done on the device | {1e3 * rollout_done:.1f} |",
        f"| update (rsl-rl's, its own per-minibatch reads) | {1e3 * update_s:.1f} |",
        "| update: its kernels' time on the device (torch.profiler) | "
        + ("n/a |" if cuda_checks is None else f"{1e3 * cuda_checks[2]:.1f} |"),
        f"| env alone: the same {steps_per_env} steps, fixed actions, no torch between "
        f"| {1e3 * env_alone:.1f} "
        f"({steps / env_alone:,.0f} env steps/s) |",
        "",
        "| host time per call, one rollout as trained (median of the runs) | bridge's torch_to_jax: ms "
        "| jax.dlpack.from_dlpack alone: ms |",
        "|---|---:|---:|",
    ]
    med = {c: {k: float(np.median([h[k] for h, _ in runs])) for k in runs[0][0]} for c, runs in calls.items()}
    for k in med[True]:
        lines.append(f"| {k} | {1e3 * med[True][k]:.1f} | {1e3 * med[False][k]:.1f} |")
    done_med = {c: float(np.median([d for _, d in runs])) for c, runs in calls.items()}
    lines += [
        f"| rollout done on the device | {1e3 * done_med[True]:.1f} | {1e3 * done_med[False]:.1f} |",
        "",
        "| phase (synced after each) | ms per iteration | share |",
        "|---|---:|---:|",
    ]
    for k, v in phases.items():
        lines.append(f"| {k} | {1e3 * v / args.iters:.1f} | {v / args.iters / total:.1%} |")
    lines.append(f"| total (synced) | {1e3 * total:.1f} | {steps / total:,.0f} env steps/s |")
    emit("\n".join(lines), args.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
