"""Bisect the multi-GPU crash of the old pmapped env reset (issue 9): each stage in its own subprocess.

On ``nvidia-h200-x2`` at commit bf9f572 the training died with ``Segmentation fault`` inside XLA's
``backend_compile_and_load``, called from ``jax.pmap(train_env.reset)`` (the whole env reset with the
randomised batched model closed over), while one GPU of the same machine trained and a plain ``pmap`` of a
``psum`` ran. The stages below build that reset up piece by piece over N devices; each runs in a fresh
subprocess, so a segfault is recorded (``SIGSEGV``) instead of ending the bisect. Every stage runs twice:
plain, and with ``import torch`` first (the old brax path imported torch through tensorboardX, and torch
brings its own CUDA and NCCL libraries into the process).

Stages (each compiles and runs one program over all N devices and waits for the result):

- ``control``: ``pmap`` of a ``psum`` (known to work).
- ``put_data``: ``mjx.put_model``/``put_data`` of the Lite model onto every device, then a ``pmap``ped
  elementwise op on ``qpos``.
- ``forward``: ``pmap(mjx.forward)`` of the nominal model (one env per device).
- ``randomized``: ``pmap`` of the domain randomiser (keys -> batched model fields).
- ``vmap_models``: ``pmap(vmap(mjx.forward over randomised models))``.
- ``env_reset``: ``pmap(BatchedEnv.reset)`` on the nominal model (closed over).
- ``old_reset``: the old trainer's reset: ``pmap(train_env.reset)``, randomised batched model computed on
  the host and closed over (commit bf9f572's ``brax_ppo.py``).
- ``cholesky``: ``pmap(jnp.linalg.cholesky)`` of a 14x14 SPD matrix (the Newton solver's factorisation).
- ``while_loop``: ``pmap`` of a ``lax.while_loop`` with a data-dependent exit (the solver's loop shape).
- ``forward_cg`` / ``forward_noconstraint``: ``forward`` with the CG solver / with constraints disabled.
- ``fwd_position``: ``pmap(mjx.fwd_position)`` only (kinematics, inertia, factorisation, constraints).
- ``shard_forward`` / ``shard_step``: ``jit(shard_map(mjx.forward / mjx.step))`` over a 2-device mesh,
  nominal model closed over (the new trainer's form, without the learner).
- ``upto_<fn>``: ``pmap`` of ``fwd_position``'s pieces in order, up to and including ``fn``
  (``kinematics``, ``com_pos``, ``crb``, ``factor_m``, ``collision``, ``make_constraint``).
- ``segment_sum``: ``pmap(jax.ops.segment_sum)`` (a scatter-add, as ``com_pos`` uses).
- ``kin_*``: ``mjx.kinematics`` in the forms the env uses it: ``kin_model_arg`` (model a pmap input, not a
  constant), ``kin_qpos_in`` (only ``qpos`` in, ``xpos`` out, data closed over), ``kin_make_data`` (data
  built in the program), ``kin_vmap`` (2 envs per device, data in), ``kin_qpos_in_vmap`` (``kin_qpos_in``
  over 2 envs per device), ``kin_jit_one`` (plain ``jit`` on one device with all devices visible),
  ``kin_pmap_one`` (``pmap`` over the first device only).
- ``zero_out``: ``pmap`` returning a zero-size array beside a normal one.
- ``vchol``: ``pmap(vmap(cholesky))`` over 2 matrices per device.
- ``ret.<fn>.<field>``: ``pmap`` of ``qpos -> fn(model, data(qpos)).field``, one env per device, for ``fn``
  one of ``fwd_position``'s pieces (all pieces up to it run), ``forward`` or ``step``.
- ``strip.<fn>``: as ``upto_<fn>`` but returning ``Data`` without its zero-size leaves.
- ``sharded_reset``: the new trainer's reset: ``jit(shard_map)`` over a ``Mesh``, each slot's model built
  in the program from its key (``bar_policy.training.brax_ppo``).

Usage::

    python bench/pmap_reset_bisect.py                     # every visible device, 128 envs per device
    CUDA_VISIBLE_DEVICES=0,1 python bench/pmap_reset_bisect.py --out $OUT/bisect.md
    JAX_PLATFORMS=cpu XLA_FLAGS=--xla_force_host_platform_device_count=2 \\
        python bench/pmap_reset_bisect.py --envs-per-device 2        # CPU smoke check
    python bench/pmap_reset_bisect.py --stages forward,old_reset --no-torch-variant

Children inherit the environment (keep ``NCCL_NVLS_ENABLE=0`` and friends set on multi-GPU machines);
``XLA_PYTHON_CLIENT_PREALLOCATE=false`` is set so that ``--parallel`` children can share the GPUs.
"""

from __future__ import annotations

import argparse
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

STAGES = (
    "control",
    "put_data",
    "forward",
    "randomized",
    "vmap_models",
    "env_reset",
    "old_reset",
    "sharded_reset",
    "cholesky",
    "while_loop",
    "forward_cg",
    "forward_noconstraint",
    "fwd_position",
    "shard_forward",
    "shard_step",
    "upto_kinematics",
    "upto_com_pos",
    "upto_crb",
    "upto_factor_m",
    "upto_collision",
    "upto_make_constraint",
    "segment_sum",
    "kin_model_arg",
    "kin_qpos_in",
    "kin_make_data",
    "kin_vmap",
    "kin_jit_one",
    "kin_pmap_one",
    "kin_qpos_in_vmap",
    "zero_out",
    "vchol",
    "trsm",
    "cho_solve",
)


# ---------------------------------------------------------------------------------------------------------
# Child: one stage
# ---------------------------------------------------------------------------------------------------------
def _stage(name: str, envs_per_device: int) -> str:
    """Run one stage in this process; returns a short description of what ran."""
    import functools

    import jax
    import jax.numpy as jnp
    import numpy as np

    n = jax.local_device_count()

    def host_stack(tree: object) -> object:
        """n copies of a tree on the host (pmap inputs must not be committed to one device)."""
        return jax.tree.map(lambda x: np.stack([np.asarray(x)] * n), tree)

    if name == "control":
        out = jax.pmap(lambda x: jax.lax.psum(x, "i"), axis_name="i")(jnp.ones(n))
        jax.block_until_ready(out)
        return f"psum over {n} devices = {float(out[0]):.0f}"

    import mujoco
    from mujoco import mjx

    from bar_policy import envs
    from bar_policy.robot.mjcf import load_model

    mj_model = load_model("arms")
    if name == "put_data":
        outs = []
        for dev in jax.local_devices():
            m = mjx.put_model(mj_model, device=dev)
            d = mjx.put_data(mj_model, mujoco.MjData(mj_model), device=dev)
            outs.append((m, d))
        qpos = np.stack([np.asarray(d.qpos) for _, d in outs])
        jax.block_until_ready(jax.pmap(lambda q: q * 2.0)(qpos))
        return f"model and data on {n} devices"

    env = envs.load("LiteReach")
    randomizer = envs.get_randomizer("LiteReach", env.config)
    b = envs_per_device
    keys = jax.random.split(jax.random.PRNGKey(0), n * b).reshape(n, b, 2)
    model = env.mjx_model
    if name == "forward":
        d = mjx.put_data(mj_model, mujoco.MjData(mj_model))
        jax.block_until_ready(jax.pmap(lambda dd: mjx.forward(model, dd))(host_stack(d)))
        return "mjx.forward, 1 env per device"
    if name == "randomized":
        out = jax.pmap(lambda k: randomizer(model, k)[0])(keys)
        jax.block_until_ready(out)
        return f"randomiser, {b} models per device"
    if name == "vmap_models":
        d = mjx.put_data(mj_model, mujoco.MjData(mj_model))

        def fwd(k: jax.Array) -> jax.Array:
            batched, in_axes = randomizer(model, k)
            return jax.vmap(mjx.forward, in_axes=(in_axes, None))(batched, d).qacc

        jax.block_until_ready(jax.pmap(fwd)(keys))
        return f"vmap(mjx.forward) over {b} randomised models per device"
    if name == "env_reset":
        w = envs.wrap_for_brax_training(env, episode_length=env.episode_length)
        jax.block_until_ready(jax.pmap(w.reset, axis_name="devices")(keys).obs)
        return f"BatchedEnv.reset, nominal model, {b} envs per device"
    if name == "old_reset":
        rfn = functools.partial(randomizer, rng=jax.random.split(jax.random.PRNGKey(1), b))
        w = envs.wrap_for_brax_training(env, episode_length=env.episode_length, randomization_fn=rfn)
        jax.block_until_ready(jax.pmap(w.reset, axis_name="devices")(keys).obs)
        return f"old trainer's reset: pmap, randomised model closed over, {b} envs per device"
    if name == "cholesky":
        a = np.eye(14, dtype=np.float32) * 2.0 + 0.1
        out = jax.pmap(jnp.linalg.cholesky)(np.stack([a] * n))
        jax.block_until_ready(out)
        return "cholesky of a 14x14 SPD matrix per device"
    if name == "while_loop":

        def loop(x: jax.Array) -> jax.Array:
            return jax.lax.while_loop(lambda c: c[1] < 3, lambda c: (c[0] * 0.5 + 1.0, c[1] + 1), (x, 0))[0]

        jax.block_until_ready(jax.pmap(loop)(np.ones((n, 14), np.float32)))
        return "while_loop with a carried counter"
    if name in ("forward_cg", "forward_noconstraint", "fwd_position"):
        import copy

        mm = copy.deepcopy(mj_model)
        if name == "forward_cg":
            mm.opt.solver = mujoco.mjtSolver.mjSOL_CG
        if name == "forward_noconstraint":
            mm.opt.disableflags |= mujoco.mjtDisableBit.mjDSBL_CONSTRAINT
        m2 = mjx.put_model(mm)
        d = mjx.put_data(mm, mujoco.MjData(mm))
        fn = mjx.fwd_position if name == "fwd_position" else mjx.forward
        jax.block_until_ready(jax.pmap(lambda dd: fn(m2, dd))(host_stack(d)))
        return f"{fn.__name__}, 1 env per device"
    if name in ("shard_forward", "shard_step"):
        from jax.sharding import PartitionSpec as P

        from bar_policy.training.parallel import AXIS, make_data_parallel

        dp = make_data_parallel()
        d = mjx.put_data(mj_model, mujoco.MjData(mj_model))
        fn = mjx.step if name == "shard_step" else mjx.forward

        def run(q: jax.Array) -> jax.Array:
            dd = jax.vmap(lambda qi: d.replace(qpos=qi))(q)
            return jax.vmap(lambda x: fn(model, x))(dd).qacc

        q = np.zeros((n * b, mj_model.nq), np.float32)
        jax.block_until_ready(dp.map(run, (P(AXIS),), P(AXIS))(q))
        return f"jit(shard_map({fn.__name__})), {b} envs per device"
    if name == "zero_out":
        out = jax.pmap(lambda x: (x * 2.0, jnp.zeros((0, 3), x.dtype)))(np.ones((n, 4), np.float32))
        jax.block_until_ready(out)
        return "a (4,) and a (0, 3) output"
    if name in ("trsm", "cho_solve"):
        import jax.scipy.linalg as jsl

        a = np.tril(np.ones((14, 14), np.float32)) + np.eye(14, dtype=np.float32)
        if name == "trsm":
            fn = lambda x: jsl.solve_triangular(a, x, lower=True)  # noqa: E731
        else:
            fn = lambda x: jsl.cho_solve((a, True), x)  # noqa: E731
        jax.block_until_ready(jax.pmap(fn)(np.ones((n, 14), np.float32)))
        return f"{name} of a 14x14 triangular factor"
    if name == "vchol":
        a = np.eye(14, dtype=np.float32) * 2.0 + 0.1
        jax.block_until_ready(jax.pmap(jax.vmap(jnp.linalg.cholesky))(np.stack([np.stack([a] * 2)] * n)))
        return "vmap(cholesky), 2 per device"
    if name.startswith(("ret.", "strip.")):
        from mujoco.mjx._src import collision_driver, constraint, smooth

        order = ["kinematics", "com_pos", "camlight", "tendon", "crb", "tendon_armature", "factor_m"]
        order += ["collision", "make_constraint"]
        mods = {"collision": collision_driver, "make_constraint": constraint}
        parts = name.split(".")
        fn_name = parts[1]
        d = mjx.put_data(mj_model, mujoco.MjData(mj_model))
        if fn_name in ("forward", "step"):
            fns = [getattr(mjx, fn_name)]
        elif fn_name == "solve":  # forward's pieces, the constraint solver last
            from mujoco.mjx._src import forward as fwd_mod
            from mujoco.mjx._src import solver

            fns = [fwd_mod.fwd_position, fwd_mod.fwd_velocity, fwd_mod.fwd_actuation]
            fns += [fwd_mod.fwd_acceleration, solver.solve]
        elif fn_name == "nosolve":  # forward's pieces without the constraint solver
            from mujoco.mjx._src import forward as fwd_mod

            fns = [fwd_mod.fwd_position, fwd_mod.fwd_velocity, fwd_mod.fwd_actuation]
            fns += [fwd_mod.fwd_acceleration]
        elif fn_name.startswith("fwd_"):  # one stage of forward alone, on the initial data
            from mujoco.mjx._src import forward as fwd_mod

            fns = [getattr(fwd_mod, fn_name)]
        else:
            fns = [getattr(mods.get(f, smooth), f) for f in order[: order.index(fn_name) + 1]]

        def run(q: jax.Array) -> object:
            dd = d.replace(qpos=q)
            for f in fns:
                dd = f(model, dd)
            if parts[0] == "ret":
                return getattr(dd, parts[2])
            return [x for x in jax.tree.leaves(dd) if x.size > 0]

        out = jax.pmap(run)(np.zeros((n, mj_model.nq), np.float32))
        jax.block_until_ready(out)
        return name
    if name.startswith("upto_"):
        from mujoco.mjx._src import collision_driver, constraint, smooth

        pieces = [
            ("kinematics", smooth.kinematics),
            ("com_pos", smooth.com_pos),
            ("camlight", smooth.camlight),
            ("tendon", smooth.tendon),
            ("crb", smooth.crb),
            ("tendon_armature", smooth.tendon_armature),
            ("factor_m", smooth.factor_m),
            ("collision", collision_driver.collision),
            ("make_constraint", constraint.make_constraint),
        ]
        last = name.removeprefix("upto_")
        upto = [f for f in pieces[: [p for p, _ in pieces].index(last) + 1]]
        d = mjx.put_data(mj_model, mujoco.MjData(mj_model))

        def part(dd: object) -> object:
            for _, fn in upto:
                dd = fn(model, dd)
            return dd

        jax.block_until_ready(jax.pmap(part)(host_stack(d)))
        return "fwd_position pieces: " + ", ".join(p for p, _ in upto)
    if name.startswith("kin_"):
        d = mjx.put_data(mj_model, mujoco.MjData(mj_model))
        kin = mjx.kinematics
        q1 = np.zeros((n, mj_model.nq), np.float32)
        if name == "kin_model_arg":
            out = jax.pmap(lambda mm, dd: kin(mm, dd).xpos)(host_stack(model), host_stack(d))
        elif name == "kin_qpos_in":
            out = jax.pmap(lambda q: kin(model, d.replace(qpos=q)).xpos)(q1)
        elif name == "kin_make_data":
            out = jax.pmap(lambda q: kin(model, mjx.make_data(model).replace(qpos=q)).xpos)(q1)
        elif name == "kin_vmap":
            d2 = jax.tree.map(lambda x: np.stack([np.asarray(x)] * 2), d)
            out = jax.pmap(jax.vmap(lambda dd: kin(model, dd).xpos))(host_stack(d2))
        elif name == "kin_qpos_in_vmap":
            q2 = np.zeros((n, 2, mj_model.nq), np.float32)
            out = jax.pmap(jax.vmap(lambda q: kin(model, d.replace(qpos=q)).xpos))(q2)
        elif name == "kin_jit_one":
            out = jax.jit(lambda dd: kin(model, dd).xpos)(d)
        else:
            out = jax.pmap(lambda dd: kin(model, dd).xpos, devices=jax.local_devices()[:1])(
                jax.tree.map(lambda x: np.asarray(x)[None], d)
            )
        jax.block_until_ready(out)
        return name
    if name == "segment_sum":
        seg = np.array([0, 0, 1, 2, 2, 2, 3, 3], np.int32)
        out = jax.pmap(lambda x: jax.ops.segment_sum(x, seg, 4))(np.ones((n, 8), np.float32))
        jax.block_until_ready(out)
        return "segment_sum of 8 values into 4 segments"
    if name == "sharded_reset":
        from jax.sharding import PartitionSpec as P

        from bar_policy.training.brax_ppo import host_key, slot_env, slot_keys
        from bar_policy.training.parallel import AXIS, make_data_parallel

        dp = make_data_parallel()
        total = n * b

        def reset(key: jax.Array, model_key: jax.Array) -> jax.Array:
            batch = slot_env(env, envs.wrap_for_brax_training, randomizer, slot_keys(model_key, total, b))
            return batch.reset(slot_keys(key, total, b)).obs

        f = dp.map(reset, (P(), P()), P(AXIS))
        jax.block_until_ready(f(dp.replicate(host_key(0, 1)), dp.replicate(host_key(0, 2))))
        return f"new trainer's reset: jit(shard_map) over a {n}-device mesh, {b} envs per device"
    raise ValueError(f"unknown stage {name!r}; stages: {list(STAGES)}")


def _child(args: argparse.Namespace) -> int:
    t0 = time.monotonic()
    if args.torch:
        import torch  # noqa: F401  (the point of the variant: torch's CUDA/NCCL libraries loaded first)
    import jax

    desc = _stage(args.stage, args.envs_per_device)
    print(f"STAGE-OK {time.monotonic() - t0:.1f} {jax.local_device_count()} {desc}", flush=True)
    return 0


# ---------------------------------------------------------------------------------------------------------
# Parent: the table
# ---------------------------------------------------------------------------------------------------------
def _run_one(stage: str, torch_first: bool, args: argparse.Namespace, log: Path | None) -> subprocess.Popen:
    cmd = [
        sys.executable,
        __file__,
        "--child",
        "--stage",
        stage,
        "--envs-per-device",
        str(args.envs_per_device),
    ]
    if torch_first:
        cmd.append("--torch")
    # jax's own default partitioner (Shardy) unless the caller chose: the stages probe XLA as jax ships it,
    # and the sharded ones go through make_data_parallel, which would otherwise pick GSPMD.
    env = {"JAX_USE_SHARDY_PARTITIONER": "true", **os.environ}
    env |= {"XLA_PYTHON_CLIENT_PREALLOCATE": "false", "PYTHONFAULTHANDLER": "1"}
    if log is None:
        return subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    with open(log, "w") as out:  # the child keeps its own copy of the descriptor
        return subprocess.Popen(cmd, env=env, stdout=out, stderr=subprocess.STDOUT, text=True)


def _status(proc: subprocess.Popen, text: str, timed_out: bool) -> tuple[str, str]:
    if timed_out:
        return "TIMEOUT", ""
    rc = proc.returncode
    ok = [line for line in text.splitlines() if line.startswith("STAGE-OK")]
    if rc == 0 and ok:
        _, secs, _, desc = ok[-1].split(" ", 3)
        return f"ok {float(secs):.0f} s", desc
    if rc is not None and rc < 0:
        return signal.Signals(-rc).name, ""
    tail = [line for line in text.splitlines() if line.strip()][-1:] or ["?"]
    return f"exit {rc}", tail[0][:120]


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--stages", default=",".join(STAGES), help=f"comma-separated subset of {','.join(STAGES)}")
    p.add_argument("--envs-per-device", type=int, default=128)
    p.add_argument("--no-torch-variant", action="store_true", help="skip the 'import torch first' runs")
    p.add_argument("--timeout", type=float, default=240.0, help="seconds per stage")
    p.add_argument("--parallel", type=int, default=2, help="stages run at the same time")
    p.add_argument("--out", default="", help="also write the table (markdown) here")
    p.add_argument("--logs", default="", help="directory for one log per stage")
    p.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    p.add_argument("--stage", default="", help=argparse.SUPPRESS)
    p.add_argument("--torch", action="store_true", help=argparse.SUPPRESS)
    args = p.parse_args()
    if args.child:
        return _child(args)

    stages = [s for s in args.stages.split(",") if s]
    bad = [s for s in stages if s not in STAGES and not s.startswith(("ret.", "strip."))]
    if bad:
        p.error(f"unknown stages {bad}; valid: {list(STAGES)}")
    variants = (False,) if args.no_torch_variant else (False, True)
    jobs = [(s, t) for s in stages for t in variants]
    logs = Path(args.logs) if args.logs else None
    if logs:
        logs.mkdir(parents=True, exist_ok=True)
    results: dict[tuple[str, bool], tuple[str, str]] = {}
    t_all = time.monotonic()
    for i in range(0, len(jobs), max(1, args.parallel)):
        batch = jobs[i : i + max(1, args.parallel)]
        running = []
        for stage, torch_first in batch:
            log = logs / f"{stage}{'-torch' if torch_first else ''}.log" if logs else None
            running.append(
                (stage, torch_first, log, _run_one(stage, torch_first, args, log), time.monotonic())
            )
        for stage, torch_first, log, proc, t0 in running:
            timed_out = False
            try:
                text = proc.communicate(timeout=max(1.0, args.timeout - (time.monotonic() - t0)))[0] or ""
            except subprocess.TimeoutExpired:
                proc.kill()
                text = proc.communicate()[0] or ""
                timed_out = True
            if log:
                text = log.read_text()
            results[(stage, torch_first)] = _status(proc, text, timed_out)
            variant = "torch first" if torch_first else "plain"
            print(f"  {stage:<14} {variant:<11} {results[(stage, torch_first)][0]}", flush=True)

    import jax

    head = f"devices: {os.environ.get('CUDA_VISIBLE_DEVICES', 'all visible')}, jax {jax.__version__}"
    lines = [
        f"pmap reset bisect ({head}, {args.envs_per_device} envs per device, "
        f"{time.monotonic() - t_all:.0f} s)",
        "",
        "| stage | plain | torch imported first | what ran |",
        "|---|---|---|---|",
    ]
    for s in stages:
        plain = results.get((s, False), ("-", ""))
        tor = results.get((s, True), ("-", ""))
        lines.append(f"| {s} | {plain[0]} | {tor[0]} | {plain[1] or tor[1]} |")
    text = "\n".join(lines)
    print(text)
    if args.out:
        Path(args.out).write_text(text + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
