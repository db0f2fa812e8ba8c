"""What XLA's per-compile options do to the reach epoch: compile time, training speed, load time.

The epoch here is the one-program epoch the trainer had until 2026-11-27 (``bench/fused_epoch.py``). A cold
run waited about 39 s for it to compile (H100, shipped autotune seeds) and a warm run about 5.8 s for its
executable to load from the executable cache. This bench compiles that epoch (``--preset``, one device)
under each named set of XLA debug options, passed per
compile (``Lowered.compile(compiler_options=...)``, so the rest of the process keeps XLA's defaults), and
reports per variant:

- ``compile s``: the epoch's compile, on an empty jax cache with the shipped autotune seeds (as a cold
  training run: ``train/ppo.py`` copies the seeds before it compiles);
- ``env steps/s``: the compiled epoch's training speed (one call after a warm-up call, host sync included);
- ``MB``: the serialised executable (``jax.experimental.serialize_executable``), as the executable cache
  stores it;
- ``load s``: ``deserialize_and_load`` of that file in a fresh process (as a warm run's load), once with
  XLA's defaults and once with ``XLA_FLAGS=--xla_gpu_experimental_aot_compiled_thunks=true`` (the load
  flag, in case the loader reads it rather than the file).

Every variant compiles in a process of its own (``--one``): XLA keeps in-process caches (autotuning results,
``ptxas`` output) that would let a later variant reuse an earlier one's work. An option XLA does not know
makes that variant's row say so; the others go on.

Examples::

    python bench/compile_options.py --out $OUT/compile_options.md        # GPU: every variant (~8 min)
    python bench/compile_options.py --preset tiny --variants default,noexp --epoch-iters 1   # CPU smoke check
"""

from __future__ import annotations

import argparse
import json
import os
import pickle
import tempfile
import time
from pathlib import Path
from typing import Any

from config_args import add_config_args, config_argv, config_label, pick
from json_child import json_child
from one_device import one_device
from report import emit

VARIANTS: dict[str, dict[str, Any]] = {
    "default": {},
    "par16": {"xla_gpu_force_compilation_parallelism": 16},
    "noexp": {"xla_llvm_disable_expensive_passes": True},
    "ptx0": {"xla_gpu_disable_gpuasm_optimizations": True},
    "thunks": {"xla_gpu_experimental_aot_compiled_thunks": True},
    "fast": {
        "xla_gpu_force_compilation_parallelism": 16,
        "xla_llvm_disable_expensive_passes": True,
        "xla_gpu_disable_gpuasm_optimizations": True,
    },
}
"""Name -> XLA debug options (DebugOptions field names, as ``XLA_FLAGS`` spells them without ``--``)."""

LOAD_FLAG = "--xla_gpu_experimental_aot_compiled_thunks=true"


def _one(args: argparse.Namespace) -> dict[str, Any]:
    """Compile, run and serialise the epoch under one variant (this process only); the row as a dict."""
    from jax.experimental.serialize_executable import serialize

    from bar_policy.training.brax.programs import host_key

    row: dict[str, Any] = {"variant": args.one, "options": VARIANTS[args.one]}
    o = one_device(args, args.cache_dir, args.epoch_iters)
    row["seed"] = o.seed_line
    dp = o.dp
    t0 = time.monotonic()
    lowered = o.fused.trace(o.ts_abs, o.envs_abs, o.key_abs).lower()
    row["trace_lower_s"] = time.monotonic() - t0
    t0 = time.monotonic()
    try:
        epoch = lowered.compile(compiler_options=VARIANTS[args.one] or None)
    except Exception as e:  # an option this XLA does not know, or refuses
        row["error"] = f"{type(e).__name__}: {str(e).splitlines()[0][:200]}"
        return row
    row["compile_s"] = time.monotonic() - t0
    ts = o.progs.init.trace(o.key_abs).lower().compile()(dp.replicate(host_key(0, 1)))
    carry = o.reset.compile()(dp.replicate(host_key(0, 2)), dp.replicate(host_key(0, 3)))
    key = dp.replicate(host_key(0, 9))
    times = []
    for _ in range(2):  # a warm-up call, then the timed one
        t0 = time.monotonic()
        ts, carry, metrics, stats = epoch(ts, carry, key)
        dp.to_host((metrics, stats))
        times.append(time.monotonic() - t0)
    row["env_steps_per_s"] = o.iters * o.cfg.ppo.steps_per_iteration / times[-1]
    row["first_call_s"] = times[0]
    try:
        blob, in_tree, out_tree = serialize(epoch)
    except Exception as e:  # jaxlib 0.10.2's CPU thunks: "`LessThan` is not serializable"
        row["error"] = f"not serialisable: {type(e).__name__}: {str(e).splitlines()[0][:160]}"
        return row
    path = Path(args.workdir) / f"{args.one}.pkl"
    path.write_bytes(pickle.dumps({"executable": blob, "in_tree": in_tree, "out_tree": out_tree}))
    row["mb"] = len(blob) / 2**20
    row["file"] = str(path)
    return row


def _load(path: str) -> dict[str, Any]:
    """Time ``deserialize_and_load`` of one stored executable in this (fresh) process."""
    import jax
    from jax.experimental.serialize_executable import deserialize_and_load

    from bar_policy.training.startup.executable_cache import _init_lazy_kernels

    jax.devices()  # the backend's own start-up is not the load's
    _init_lazy_kernels()  # as the executable cache does before a load
    entry = pickle.loads(Path(path).read_bytes())
    t0 = time.monotonic()
    deserialize_and_load(entry["executable"], entry["in_tree"], entry["out_tree"])
    return {"load_s": time.monotonic() - t0}


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    add_config_args(p)
    p.add_argument("--variants", default=",".join(VARIANTS), help=f"comma-separated, of {sorted(VARIANTS)}")
    p.add_argument("--epoch-iters", type=int, default=0, help="iterations per epoch (0: the trainer's)")
    p.add_argument("--workdir", default="", help="where the variants' caches and executables go")
    p.add_argument("--out", default="")
    p.add_argument("--timeout", type=float, default=240, help="seconds per variant's process")
    p.add_argument("--one", default="", help=argparse.SUPPRESS)
    p.add_argument("--load", default="", help=argparse.SUPPRESS)
    p.add_argument("--cache-dir", default="", help=argparse.SUPPRESS)
    args = p.parse_args()
    if args.load:
        print(json.dumps(_load(args.load)))
        return 0
    if args.one:
        print(json.dumps(_one(args)))
        return 0
    names = pick(p, args.variants, sorted(VARIANTS), "variants")
    work = Path(args.workdir or tempfile.mkdtemp(prefix="compile_options_"))
    work.mkdir(parents=True, exist_ok=True)
    rows = []
    for name in names:
        argv = ["--one", name, *config_argv(args), "--workdir", str(work)]
        argv += ["--epoch-iters", str(args.epoch_iters), "--cache-dir", str(work / f"cache_{name}")]
        t0 = time.monotonic()
        row = {"variant": name, **json_child(__file__, argv, timeout=args.timeout)}
        row["process_s"] = time.monotonic() - t0
        if "file" in row:
            row["load_s"] = json_child(__file__, ["--load", row["file"]], timeout=120).get("load_s")
            flagged = {**os.environ, "XLA_FLAGS": f"{os.environ.get('XLA_FLAGS', '')} {LOAD_FLAG}".strip()}
            row["load_flag_s"] = json_child(__file__, ["--load", row["file"]], env=flagged, timeout=120).get(
                "load_s"
            )
        rows.append(row)
        print(json.dumps(row), flush=True)
    emit(_table(rows, args), args.out)
    if args.out:
        Path(args.out).with_suffix(".jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))
    return 0


def _table(rows: list[dict[str, Any]], args: argparse.Namespace) -> str:
    import jax

    def f(v: Any, fmt: str) -> str:
        return "-" if v is None else format(v, fmt)

    lines = [
        f"compile options: {args.env}, {config_label(args)}, epoch program, "
        f"{jax.devices()[0].device_kind}, jax {jax.__version__}",
        "",
        "| variant | options | compile s | env steps/s | first call s | MB | load s | load s (load flag) "
        "| note |",
        "|---|---|---:|---:|---:|---:|---:|---:|---|",
    ]
    for r in rows:
        opts = " ".join(f"{k}={v}" for k, v in VARIANTS[r["variant"]].items()) or "XLA defaults"
        lines.append(
            f"| {r['variant']} | {opts} | {f(r.get('compile_s'), '.1f')} "
            f"| {f(r.get('env_steps_per_s'), ',.0f')} "
            f"| {f(r.get('first_call_s'), '.2f')} | {f(r.get('mb'), '.1f')} | {f(r.get('load_s'), '.2f')} "
            f"| {f(r.get('load_flag_s'), '.2f')} | {r.get('error', '')} |"
        )
    return "\n".join(lines)


if __name__ == "__main__":
    raise SystemExit(main())
