"""Would the epoch as two programs (rollout, update) compile and load sooner than as one?

A cold reach run waits for the epoch program's compile (H100: 28 s alone, 31 s beside the evaluation's) and
a warm one for its load from the executable cache (4-7 s). The epoch is ``iters`` PPO iterations, each a
rollout (the env step: most of the code) and an update (the networks' gradients). As two programs they
would compile side by side. This bench compiles each set of programs the way the trainer does (traced and
lowered one after the other on the main thread, compiled concurrently on threads, on an empty jax cache
with the shipped autotune seeds), then loads the serialised executables concurrently in a fresh process,
and reports per set: each program's compile and load, and the wall time until all of them are ready.

Sets: ``epoch+evaluate`` (the start until 2026-11-27: ``bench/fused_epoch.py``) and
``rollout+update+evaluate`` (the trainer's programs since); ``--sets`` picks. Each set's
compile runs in a process of its own (XLA keeps in-process caches).

Examples::

    python bench/program_split.py --out $OUT/program_split.md            # GPU (~3 min)
    python bench/program_split.py --preset tiny --sets rollout+update     # CPU smoke check
    python bench/program_split.py --sets rollout --profile $OUT/prof      # where a compile and a load go
"""

from __future__ import annotations

import argparse
import contextlib
import json
import pickle
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

from config_args import add_config_args, config_argv, config_label
from json_child import json_child
from one_device import one_device
from report import emit
from trace_summary import profiled, top_events

PROGRAMS = ("epoch", "rollout", "update", "evaluate")


def _compile_set(args: argparse.Namespace) -> dict[str, Any]:
    """Trace and lower the set's programs in turn, compile them concurrently, store their executables."""
    import jax
    from jax.experimental.serialize_executable import serialize

    from bar_policy.training.brax.programs import _policy_params

    names = args.compile_set.split("+")
    out: dict[str, Any] = {"set": args.compile_set}
    o = one_device(args, args.cache_dir)
    out["seed"] = o.seed_line
    dp, progs, key_abs, i_abs, ts_abs, envs_abs = o.dp, o.progs, o.key_abs, o.i_abs, o.ts_abs, o.envs_abs
    lowered: dict[str, Any] = {}
    t0 = time.monotonic()
    for name in names:  # traced and lowered in turn (the trainer's main thread)
        if name == "epoch":
            lowered[name] = o.fused.trace(ts_abs, envs_abs, key_abs).lower()
        elif name == "rollout":
            lowered[name] = progs.rollout.trace(ts_abs, envs_abs, key_abs, i_abs, o.w_abs).lower()
        elif name == "update":
            data_abs = jax.eval_shape(progs.rollout, ts_abs, envs_abs, key_abs, i_abs, o.w_abs)[1]
            update_args = (ts_abs, dp.abstract(data_abs, sharded=True), key_abs, i_abs)
            lowered[name] = progs.update.trace(*update_args).lower()
        elif name == "evaluate":
            lowered[name] = progs.evaluate.trace(_policy_params(ts_abs), key_abs, key_abs, o.w_abs).lower()
    out["trace_lower_s"] = time.monotonic() - t0

    def compile_one(name: str) -> tuple[str, Any, float]:
        t = time.monotonic()
        compiled = lowered[name].compile()
        return name, compiled, time.monotonic() - t

    prof = Path(args.profile) / f"compile_{args.compile_set}" if args.profile else None
    t0 = time.monotonic()
    with profiled(prof) if prof else contextlib.nullcontext(), ThreadPoolExecutor(len(names)) as pool:
        done = list(pool.map(compile_one, names))
    out["compile_wall_s"] = time.monotonic() - t0
    if prof:
        out["compile_events"] = top_events(prof)
    out["compile_s"] = {n: s for n, _, s in done}
    work = Path(args.workdir) / args.compile_set
    work.mkdir(parents=True, exist_ok=True)
    out["mb"] = {}
    for name, compiled, _ in done:
        try:
            blob, in_tree, out_tree = serialize(compiled)
        except Exception as e:  # jaxlib 0.10.2's CPU thunks: "`LessThan` is not serializable"
            out["error"] = f"{name} not serialisable: {str(e).splitlines()[0][:120]}"
            continue
        (work / f"{name}.pkl").write_bytes(pickle.dumps({"e": blob, "i": in_tree, "o": out_tree}))
        out["mb"][name] = len(blob) / 2**20
    return out


def _load_set(directory: str, profile: str = "") -> dict[str, Any]:
    """Load every stored executable of a set concurrently (as a warm run does), in this fresh process."""
    import jax
    from jax.experimental.serialize_executable import deserialize_and_load

    from bar_policy.training.startup.executable_cache import _init_lazy_kernels

    jax.devices()
    _init_lazy_kernels()
    files = sorted(Path(directory).glob("*.pkl"))

    def load(path: Path) -> tuple[str, float]:
        entry = pickle.loads(path.read_bytes())
        t = time.monotonic()
        deserialize_and_load(entry["e"], entry["i"], entry["o"])
        return path.stem, time.monotonic() - t

    prof = Path(profile) / f"load_{Path(directory).name}" if profile else None
    t0 = time.monotonic()
    with profiled(prof) if prof else contextlib.nullcontext(), ThreadPoolExecutor(max(len(files), 1)) as pool:
        loads = dict(pool.map(load, files))
    out = {"load_s": loads, "load_wall_s": time.monotonic() - t0}
    return {**out, "load_events": top_events(prof)} if prof else out


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    add_config_args(p)
    p.add_argument("--sets", default="epoch+evaluate,rollout+update+evaluate")
    p.add_argument("--workdir", default="")
    p.add_argument("--timeout", type=float, default=200, help="seconds per child process")
    p.add_argument(
        "--profile", default="", help="trace the compiles and loads into this folder; print their top events"
    )
    p.add_argument("--out", default="")
    p.add_argument("--compile-set", default="", help=argparse.SUPPRESS)
    p.add_argument("--load-set", default="", help=argparse.SUPPRESS)
    p.add_argument("--cache-dir", default="", help=argparse.SUPPRESS)
    args = p.parse_args()
    if args.load_set:
        print(json.dumps(_load_set(args.load_set, args.profile)))
        return 0
    if args.compile_set:
        print(json.dumps(_compile_set(args)))
        return 0
    sets = [s for s in args.sets.split(",") if s]
    bad = [n for s in sets for n in s.split("+") if n not in PROGRAMS]
    if bad:
        p.error(f"unknown programs {bad}; valid: {list(PROGRAMS)}")
    work = Path(args.workdir or tempfile.mkdtemp(prefix="program_split_"))
    rows = []
    for s in sets:
        argv = ["--compile-set", s, *config_argv(args), "--workdir", str(work)]
        argv += ["--cache-dir", str(work / f"cache_{s}")]
        argv += ["--profile", args.profile] if args.profile else []
        row = json_child(__file__, argv, timeout=args.timeout)
        if "compile_s" in row:
            load_argv = ["--load-set", str(work / s)] + (["--profile", args.profile] if args.profile else [])
            row.update(json_child(__file__, load_argv, timeout=args.timeout))
        rows.append({"set": s, **row})
        print(json.dumps(rows[-1]), flush=True)
    lines = [
        f"program split: {args.env}, {config_label(args)}",
        "",
        "| set | trace+lower s (main) | compile s each (concurrent) | all compiled s | MB each | load s each "
        "(concurrent, fresh process) | all loaded s | note |",
        "|---|---:|---|---:|---|---|---:|---|",
    ]
    for r in rows:

        def each(d: dict[str, float] | None, fmt: str) -> str:
            return ", ".join(f"{k} {format(v, fmt)}" for k, v in (d or {}).items()) or "-"

        lines.append(
            f"| {r['set']} | {r.get('trace_lower_s', float('nan')):.1f} | {each(r.get('compile_s'), '.1f')} "
            f"| {r.get('compile_wall_s', float('nan')):.1f} | {each(r.get('mb'), '.1f')} "
            f"| {each(r.get('load_s'), '.2f')} | {r.get('load_wall_s', float('nan')):.2f} "
            f"| {r.get('error', '')} |"
        )
    for r in rows:
        for part in ("compile_events", "load_events"):
            if r.get(part):
                lines += ["", f"{r['set']}, {part} (ms summed over threads, nested included):", ""]
                fmt = "- {ms:,.0f} ms  x{count} ({threads} thr)  {name}"
                lines += [fmt.format(**e) for e in r[part]]
    emit("\n".join(lines), args.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
