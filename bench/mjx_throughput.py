"""MJX throughput benchmark of the Lite env, and the harness variants that explain a fixed per-call latency.

One invocation prints (and writes to ``--out``) markdown tables:

1. Throughput at each batch size for
   (a)   raw ``jit(vmap(mjx.step))`` on the Lite model, one physics step per call;
   (a10) the same with ``lax.scan`` over 10 raw steps per call (same physics work per call as b/c;
         only at ``--a10-batches``, default 8192 and 32768, to save compiles);
   (b)   the MIT law (``firmware_torque``, quantised, capped, env's damping treatment) written to
         ``qfrc_applied`` + ``lax.scan`` over 10 substeps: one control step per call;
   (c)   the full env step: ``BatchedEnv`` with model randomisation, latency, noise, obs, rewards,
         target resampling, episode bookkeeping and auto-reset;
   (d)   raw ``jit(vmap(mjx.step))`` of MuJoCo Playground's ``humanoid.xml`` (the anchor).
2. Ratios: env overhead (c vs b and c vs a10), Lite vs humanoid.
3. Diagnosis at one batch size: the same one-substep MIT wrapper ``f(m, d, q_cmd)`` called in different ways
   (not jitted, jit rebuilt per call, eager ``lax.scan``, host numpy inputs, model closed over, donated
   buffers, sync per call, a static argument that changes, inputs committed to the CPU). For each: ms per
   call, physics steps/s, XLA compiles and Python traces *during the timed calls* (counted with
   ``jax_log_compiles`` and a trace counter in ``f``), and the device of inputs and outputs. A row whose
   ms/call stays flat across batch sizes while compiles/traces per call are > 0 or the op-by-op path is
   used is the fixed-latency signature of shared/gpu/README.md.

Timing: one warm-up call (compile, reported separately), a second warm-up call, then timed calls until
``--min-time`` seconds and at least ``--min-iters`` calls, with ``block_until_ready`` after the last call
(and a per-call sync only in the variant that tests it).

Examples::

    python bench/mjx_throughput.py --quick --out $OUT/bench.md          # batches 8192, 32768 first
    python bench/mjx_throughput.py --out $OUT/bench.md                  # full run (GPU)
    python bench/mjx_throughput.py --harness a,b,c --batches 8192        # a subset
    python bench/mjx_throughput.py --smoke                               # CPU sanity check, tiny batch
    python bench/mjx_throughput.py --only-diagnose --profile $OUT/prof   # with a jax.profiler trace
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
import glob
import importlib.util
import logging
import os
import platform
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from mujoco import mjx

from bar_policy import envs
from bar_policy.envs.actuator import ActuatorParams, implicit_damping, make_command, motor_torque
from bar_policy.robot.constants import load_robot

ALL_HARNESSES = ("a", "a10", "b", "c", "d")
DEFAULT_BATCHES = (1024, 4096, 8192, 16384, 32768, 65536)
HUMANOID_REL = os.path.join("mujoco_playground", "_src", "dm_control_suite", "xmls", "humanoid.xml")


# ---------------------------------------------------------------------------------------------------
# Compile and trace counters
# ---------------------------------------------------------------------------------------------------
class _CompileCounter(logging.Handler):
    """Counts XLA compilations from jax's ``jax_log_compiles`` log records."""

    def __init__(self) -> None:
        super().__init__(level=logging.DEBUG)
        self.count = 0

    def emit(self, record: logging.LogRecord) -> None:
        msg = record.getMessage()
        if msg.startswith("Compiling ") or "Finished XLA compilation" in msg:
            self.count += "Finished XLA compilation" not in msg


COMPILES = _CompileCounter()
TRACES = {"n": 0}


def _install_counters() -> None:
    jax.config.update("jax_log_compiles", True)
    for name in ("jax", "jax._src.interpreters.pxla", "jax._src.dispatch", "jax._src.pjit"):
        lg = logging.getLogger(name)
        lg.addHandler(COMPILES)
        lg.propagate = False  # keep the compile log off stderr
        lg.setLevel(logging.DEBUG if name != "jax" else logging.WARNING)


# ---------------------------------------------------------------------------------------------------
# Models and batched data
# ---------------------------------------------------------------------------------------------------
def find_humanoid_xml(explicit: str | None) -> str | None:
    """``--humanoid-xml``, else the installed ``mujoco_playground`` package, else a site-packages search."""
    if explicit:
        return explicit if os.path.exists(explicit) else None
    spec = importlib.util.find_spec("mujoco_playground")  # locates the package without importing it
    roots = []
    if spec is not None and spec.submodule_search_locations:
        roots += [str(Path(p).parent) for p in spec.submodule_search_locations]
    roots += [p for p in sys.path if p and os.path.isdir(p)]
    for root in roots:
        cand = os.path.join(root, HUMANOID_REL)
        if os.path.exists(cand):
            return cand
    for root in roots:
        hits = glob.glob(os.path.join(root, "**", "dm_control_suite", "xmls", "humanoid.xml"), recursive=True)
        if hits:
            return hits[0]
    return None


def batched_data(
    m: mjx.Model, mj: mujoco.MjModel, batch: int, seed: int = 0, noise: float = 0.05
) -> mjx.Data:
    """A batch of ``mjx.Data`` on the default device: qpos0 + U(-noise, noise), zero velocity."""
    d0 = mjx.put_data(mj, mujoco.MjData(mj))

    @jax.jit
    def make(key: jax.Array) -> mjx.Data:
        q = d0.qpos[None] + jax.random.uniform(key, (batch, mj.nq), minval=-noise, maxval=noise)
        if mj.nq != mj.nv:  # free joint: keep the quaternion part of qpos0 exact
            q = q.at[:, 3:7].set(d0.qpos[3:7])
        d = jax.tree.map(lambda x: jnp.broadcast_to(x, (batch, *x.shape)), d0)
        return d.replace(qpos=q)

    return make(jax.random.PRNGKey(seed))


def lite_law(env: Any) -> Callable[[mjx.Model, mjx.Data, jax.Array, int], mjx.Data]:
    """``law(m, d, q_cmd, n)``: the MIT law + mjx.step, ``n`` substeps (lax.scan), env's damping."""
    robot = load_robot(env.config.mode)
    params = ActuatorParams.from_robot(robot, quantize_wire=True, torque_saturation=True)
    kp, kd = jnp.asarray(env.kp), jnp.asarray(env.kd)
    implicit = env.config.actuator.damping == "implicit"

    def law(m: mjx.Model, d: mjx.Data, q_cmd: jax.Array, n: int) -> mjx.Data:
        TRACES["n"] += 1
        cmd = make_command(q_cmd, kp, kd, params)

        def sub(d: mjx.Data, _: None) -> tuple[mjx.Data, None]:
            tau = motor_torque(cmd, d.qpos, d.qvel, params)
            if implicit:
                m_sub, qfrc = implicit_damping(m, cmd.kd, tau, d.qvel, params.tau_cap)
            else:
                m_sub, qfrc = m, tau
            return mjx.step(m_sub, d.replace(qfrc_applied=qfrc)), None

        if n == 1:
            return sub(d, None)[0]
        return jax.lax.scan(sub, d, None, length=n)[0]

    return law


# ---------------------------------------------------------------------------------------------------
# Timing
# ---------------------------------------------------------------------------------------------------
@dataclasses.dataclass
class Result:
    """One measured configuration."""

    name: str
    batch: int
    phys_per_call: int
    env_per_call: int
    compile_s: float
    ms_per_call: float
    calls: int
    compiles: int
    traces: int
    note: str = ""

    @property
    def phys_sps(self) -> float:
        return self.phys_per_call / (self.ms_per_call / 1e3)

    @property
    def env_sps(self) -> float:
        return self.env_per_call / (self.ms_per_call / 1e3)


def _fmt(x: float) -> str:
    """Thousands separators for large rates, 3 significant digits for small ones."""
    return f"{x:,.0f}" if x >= 100 else f"{x:.3g}"


def _block(x: Any) -> None:
    jax.tree.map(lambda a: a.block_until_ready() if hasattr(a, "block_until_ready") else a, x)


def measure(
    name: str,
    call: Callable[[Any], Any],
    state: Any,
    *,
    batch: int,
    phys_per_call: int,
    env_per_call: int,
    args: argparse.Namespace,
    sync_each: bool = False,
    max_calls: int | None = None,
    note: str = "",
) -> tuple[Result, Any]:
    """Warm up (compile) then time ``state = call(state)``."""
    t0 = time.perf_counter()
    state = call(state)
    _block(state)
    compile_s = time.perf_counter() - t0
    if max_calls is None:  # a second warm-up call; the slow diagnosis variants skip it
        state = call(state)
        _block(state)
    c0, tr0 = COMPILES.count, TRACES["n"]
    n = 0
    t0 = time.perf_counter()
    limit = max_calls if max_calls is not None else args.max_iters
    while True:
        state = call(state)
        if sync_each:
            _block(state)
        n += 1
        if n >= limit or (n >= args.min_iters and time.perf_counter() - t0 >= args.min_time):
            break
    _block(state)
    dt = time.perf_counter() - t0
    r = Result(
        name,
        batch,
        phys_per_call,
        env_per_call,
        compile_s,
        dt / n * 1e3,
        n,
        COMPILES.count - c0,
        TRACES["n"] - tr0,
        note,
    )
    print(
        f"  {name:<22} B={batch:<6} {r.ms_per_call:9.3f} ms/call  {r.phys_sps:12.4g} phys/s  "
        f"compile {compile_s:6.1f} s  compiles/traces {r.compiles}/{r.traces}",
        flush=True,
    )
    return r, state


# ---------------------------------------------------------------------------------------------------
# Harnesses
# ---------------------------------------------------------------------------------------------------
def run_throughput(args: argparse.Namespace, env: Any, humanoid: str | None) -> list[Result]:
    """Harnesses a, a10, b, c, d at every batch size."""
    out: list[Result] = []
    m, mj = env.mjx_model, env.mj_model
    law = lite_law(env)
    n_sub = env.n_substeps
    hm = hmj = None
    if "d" in args.harness and humanoid:
        hmj = mujoco.MjModel.from_xml_path(humanoid)
        hm = mjx.put_model(hmj)

    raw = jax.jit(jax.vmap(mjx.step, in_axes=(None, 0)))

    def raw_scan(m: mjx.Model, d: mjx.Data) -> mjx.Data:
        return jax.lax.scan(lambda d, _: (mjx.step(m, d), None), d, None, length=n_sub)[0]

    raw10 = jax.jit(jax.vmap(raw_scan, in_axes=(None, 0)))
    ctrl = jax.jit(jax.vmap(functools.partial(law, n=n_sub), in_axes=(None, 0, 0)))

    for batch in args.batches:
        print(f"batch {batch}", flush=True)
        if "a" in args.harness:
            d = batched_data(m, mj, batch)
            r, _ = measure(
                "a raw mjx.step",
                lambda d: raw(m, d),
                d,
                batch=batch,
                phys_per_call=batch,
                env_per_call=0,
                args=args,
            )
            out.append(r)
        if "a10" in args.harness and batch in args.a10_batches:
            d = batched_data(m, mj, batch)
            r, _ = measure(
                "a10 raw scan x10",
                lambda d: raw10(m, d),
                d,
                batch=batch,
                phys_per_call=batch * n_sub,
                env_per_call=batch,
                args=args,
            )
            out.append(r)
        if "b" in args.harness:
            d = batched_data(m, mj, batch)
            q_cmd = jnp.broadcast_to(jnp.asarray(env.default_pose), (batch, env.action_size))
            r, _ = measure(
                "b MIT law + scan x10",
                functools.partial(lambda d, q: ctrl(m, d, q), q=q_cmd),
                d,
                batch=batch,
                phys_per_call=batch * n_sub,
                env_per_call=batch,
                args=args,
            )
            out.append(r)
        if "c" in args.harness:
            keys = jax.random.split(jax.random.PRNGKey(0), batch)
            rand = functools.partial(envs.get_randomizer("LiteReach", env.config), rng=keys)
            w = envs.wrap_for_brax_training(env, randomization_fn=rand)
            reset, step = jax.jit(w.reset), jax.jit(w.step, donate_argnums=(0,))
            act = jax.random.uniform(jax.random.PRNGKey(1), (batch, env.action_size), minval=-1, maxval=1)
            s = reset(keys)
            r, _ = measure(
                "c full env step",
                functools.partial(lambda s, f, a: f(s, a), f=step, a=act),
                s,
                batch=batch,
                phys_per_call=batch * n_sub,
                env_per_call=batch,
                args=args,
                note="DR + auto-reset",
            )
            out.append(r)
            del s, w
        if hm is not None:
            d = batched_data(hm, hmj, batch, noise=0.01)
            r, _ = measure(
                "d humanoid raw step",
                lambda d: raw(hm, d),
                d,
                batch=batch,
                phys_per_call=batch,
                env_per_call=0,
                args=args,
            )
            out.append(r)
    return out


def run_diagnosis(args: argparse.Namespace, env: Any) -> list[Result]:
    """The one-substep MIT wrapper called in different ways at one batch size."""
    m, mj = env.mjx_model, env.mj_model
    law = lite_law(env)
    f = functools.partial(law, n=1)
    batch = args.diag_batch
    q_cmd = jnp.broadcast_to(jnp.asarray(env.default_pose), (batch, env.action_size))
    vf = jax.vmap(f, in_axes=(None, 0, 0))
    res: list[Result] = []
    kw = dict(batch=batch, phys_per_call=batch, env_per_call=0, args=args)
    print(f"diagnosis at batch {batch}", flush=True)

    def run(name: str, call: Callable, state: Any, **extra: Any) -> Any:
        r, s = measure(name, call, state, **kw, **extra)
        res.append(r)
        return s

    d = batched_data(m, mj, batch)
    fast = jax.jit(vf)
    run("D0 jit, reused", lambda d: fast(m, d, q_cmd), d, note="reference")
    run(
        "D1 no jit (eager vmap)",
        lambda d: vf(m, d, q_cmd),
        d,
        max_calls=args.slow_calls,
        note="op-by-op dispatch",
    )
    run(
        "D2 jit rebuilt per call",
        lambda d: jax.jit(vf)(m, d, q_cmd),
        d,
        max_calls=args.slow_calls,
        note="new jit object: retrace",
    )
    run(
        "D3 jit(lambda) per call",
        lambda d: jax.jit(lambda m, d, q: vf(m, d, q))(m, d, q_cmd),
        d,
        max_calls=args.slow_calls,
        note="new function: retrace",
    )

    def eager_scan(d: mjx.Data) -> mjx.Data:
        return jax.lax.scan(lambda d, _: (vf(m, d, q_cmd), None), d, None, length=5)[0]

    r, _ = measure(
        "D4 eager lax.scan x5",
        eager_scan,
        d,
        batch=batch,
        phys_per_call=batch * 5,
        env_per_call=0,
        args=args,
        max_calls=args.slow_calls,
        note="scan outside jit: retrace",
    )
    res.append(r)
    host = jax.tree.map(np.asarray, jax.device_get(d))
    q_host = np.asarray(q_cmd)

    def host_call(h: Any) -> Any:
        return jax.tree.map(np.asarray, jax.device_get(fast(m, h, q_host)))

    run("D5 host numpy inputs", host_call, host, note="H2D + D2H each call")
    closed = jax.jit(lambda d: vf(m, d, q_cmd))
    run("D6 model closed over", closed, d, note="constants in the HLO")
    donated = jax.jit(vf, donate_argnums=(1,))
    run("D7 donate data", lambda d: donated(m, d, q_cmd), batched_data(m, mj, batch))
    run("D8 sync every call", lambda d: fast(m, d, q_cmd), d, sync_each=True)
    counter = {"i": 0}

    def static_changing(d: mjx.Data) -> mjx.Data:
        counter["i"] += 1
        g = jax.jit(lambda m, d, q, s: vf(m, d, q * s), static_argnums=(3,))
        return g(m, d, q_cmd, 1.0 + 1e-6 * counter["i"])

    run("D9 static arg changes", static_changing, d, max_calls=args.slow_calls, note="recompile per call")
    cpus = jax.devices("cpu")
    if jax.default_backend() != "cpu" and cpus:
        d_cpu = jax.device_put(d, cpus[0])
        m_cpu, q_cpu = jax.device_put(m, cpus[0]), jax.device_put(q_cmd, cpus[0])
        run(
            "D10 inputs on CPU",
            lambda d: fast(m_cpu, d, q_cpu),
            d_cpu,
            max_calls=args.slow_calls,
            note="committed to CPU: runs there",
        )
    if args.profile:
        with jax.profiler.trace(args.profile):
            _block(fast(m, d, q_cmd))
            _block(jax.jit(vf)(m, d, q_cmd))
            _block(vf(m, d, q_cmd))
        print(f"profile written to {args.profile}")
    return res


# ---------------------------------------------------------------------------------------------------
# Report
# ---------------------------------------------------------------------------------------------------
def _commit() -> str:
    try:
        return subprocess.run(
            ["git", "rev-parse", "--short", "HEAD"],
            capture_output=True,
            text=True,
            check=True,
            cwd=Path(__file__).parent,
        ).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


def report(args: argparse.Namespace, thr: list[Result], diag: list[Result], humanoid: str | None) -> str:
    """Markdown tables."""
    dev = jax.devices()[0]
    lines = [
        "## MJX throughput",
        "",
        f"- device: {dev.device_kind} ({jax.default_backend()}), {len(jax.devices())} device(s); "
        f"host {platform.node()}",
        f"- jax {jax.__version__}, mujoco {mujoco.__version__}, commit {args.commit or _commit()}",
        f"- Lite: mode arms, timestep {args.dt_info}, {args.n_sub} substeps per control step, "
        f"damping {args.damping}; humanoid.xml: {humanoid or 'NOT FOUND (pass --humanoid-xml)'}",
        "- persistent compilation cache: "
        f"{args.cache_dir or os.environ.get('JAX_COMPILATION_CACHE_DIR') or 'off'}",
        f"- timing: warm-up excluded, >= {args.min_time} s and >= {args.min_iters} calls, "
        "block_until_ready at the end",
        "",
    ]
    if thr:
        lines += [
            "| harness | batch | physics steps/s | env steps/s | ms/call | compile s "
            "| compiles/traces in timed calls |",
            "|---|---:|---:|---:|---:|---:|---|",
        ]
        for r in thr:
            env_sps = _fmt(r.env_sps) if r.env_per_call else "-"
            lines.append(
                f"| {r.name} | {r.batch} | {_fmt(r.phys_sps)} | {env_sps} | {r.ms_per_call:.3f} | "
                f"{r.compile_s:.1f} | {r.compiles}/{r.traces} |"
            )
        by = {(r.name.split()[0], r.batch): r for r in thr}
        lines += [
            "",
            "| batch | env overhead c vs b | c vs a10 | b vs a10 (MIT law cost) | Lite a / humanoid d |",
            "|---:|---:|---:|---:|---:|",
        ]
        for b in args.batches:

            def ratio(x: str, y: str, b: int = b) -> str:
                if (x, b) in by and (y, b) in by:
                    return f"{by[(y, b)].phys_sps / by[(x, b)].phys_sps - 1:+.1%}"
                return "-"

            lite_h = "-"
            if ("a", b) in by and ("d", b) in by:
                lite_h = f"{by[('a', b)].phys_sps / by[('d', b)].phys_sps:.2f}x"
            lines.append(
                f"| {b} | {ratio('c', 'b')} | {ratio('c', 'a10')} | {ratio('b', 'a10')} | {lite_h} |"
            )
        lines += ["", "(overhead = time per physics step of the first harness over the second, minus 1)"]
    if diag:
        lines += [
            "",
            f"### Per-call latency diagnosis (batch {args.diag_batch}, MIT law + 1 mjx.step per call)",
            "",
            "| variant | ms/call | physics steps/s | calls | compiles/traces in timed calls | note |",
            "|---|---:|---:|---:|---|---|",
        ]
        for r in diag:
            lines.append(
                f"| {r.name} | {r.ms_per_call:.3f} | {_fmt(r.phys_sps)} | {r.calls} | "
                f"{r.compiles}/{r.traces} | {r.note} |"
            )
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--batches", default=",".join(map(str, DEFAULT_BATCHES)), help="comma-separated")
    p.add_argument("--harness", default=",".join(ALL_HARNESSES), help=f"subset of {ALL_HARNESSES}")
    p.add_argument("--diag-batch", type=int, default=8192)
    p.add_argument("--no-diagnose", action="store_true")
    p.add_argument("--only-diagnose", action="store_true")
    p.add_argument("--min-time", type=float, default=1.0, help="s of timed calls per row")
    p.add_argument("--min-iters", type=int, default=5)
    p.add_argument("--max-iters", type=int, default=2000)
    p.add_argument("--slow-calls", type=int, default=2, help="timed calls of the slow diagnosis variants")
    p.add_argument("--a10-batches", default="8192,32768", help="batches of harness a10 (comma-separated)")
    p.add_argument("--quick", action="store_true", help="batches 8192,32768 only (about half the compiles)")
    p.add_argument("--humanoid-xml", default=None)
    p.add_argument("--damping", default="implicit", choices=("implicit", "explicit"))
    p.add_argument("--profile", default=None, help="write a jax.profiler trace of D0/D2/D1 here")
    p.add_argument("--out", default=None, help="also write the markdown here")
    p.add_argument("--commit", default=None)
    p.add_argument(
        "--cache-dir",
        default=None,
        help="enable jax's persistent compilation cache here (off by default: with it, the "
        "recompile-per-call variants turn into retrace + cache load)",
    )
    p.add_argument("--smoke", action="store_true", help="CPU sanity check: batch 4, 1-2 calls")
    args = p.parse_args(argv)
    if args.quick:
        args.batches = "8192,32768"
    args.batches = [int(b) for b in args.batches.split(",") if b]
    args.a10_batches = [int(b) for b in args.a10_batches.split(",") if b]
    args.harness = [h for h in args.harness.split(",") if h]
    bad = [h for h in args.harness if h not in ALL_HARNESSES]
    if bad:
        raise SystemExit(f"unknown harness {bad}; valid: {list(ALL_HARNESSES)}")
    if args.smoke:
        args.batches, args.diag_batch, args.a10_batches = [4], 4, [4]
        args.min_time, args.min_iters, args.max_iters, args.slow_calls = 0.0, 1, 2, 1
    _install_counters()
    if args.cache_dir:
        jax.config.update("jax_compilation_cache_dir", args.cache_dir)
        jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    elif os.environ.get("JAX_COMPILATION_CACHE_DIR"):
        print(f"note: JAX_COMPILATION_CACHE_DIR={os.environ['JAX_COMPILATION_CACHE_DIR']} is set", flush=True)
    cfg = envs.default_config("LiteReach")
    cfg = dataclasses.replace(cfg, actuator=dataclasses.replace(cfg.actuator, damping=args.damping))
    env = envs.load("LiteReach", config=cfg)
    args.dt_info, args.n_sub = cfg.sim_dt, env.n_substeps
    humanoid = find_humanoid_xml(args.humanoid_xml) if "d" in args.harness else None
    print(f"devices: {jax.devices()}; humanoid.xml: {humanoid}", flush=True)
    t_start = time.perf_counter()
    thr = [] if args.only_diagnose else run_throughput(args, env, humanoid)
    diag = [] if args.no_diagnose else run_diagnosis(args, env)
    print(f"total wall time {time.perf_counter() - t_start:.0f} s (compiles included)", flush=True)
    text = report(args, thr, diag, humanoid)
    print(text)
    if args.out:
        Path(args.out).parent.mkdir(parents=True, exist_ok=True)
        Path(args.out).write_text(text)


if __name__ == "__main__":
    main()
