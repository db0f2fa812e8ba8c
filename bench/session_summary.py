"""Compact results table of a GPU session (``bench/gpu_session.sh``): one row per training run.

For each run directory: devices, envs, steady env steps/s (median of the progress lines after the first,
whose epoch includes the compile), its ratio to the first row, the time from process start to the first
evaluation at >= the threshold (compile included), the env steps there, when the first progress line came,
the start-up breakdown's compile and wait figures, and the final success rate. Files given with ``--append``
(e.g. the bisect table, bench tables) are printed after it.

Usage::

    python bench/session_summary.py RUN_DIR [RUN_DIR ...] [--append FILE ...] [--out FILE]
"""

from __future__ import annotations

import argparse
import json
import statistics
from pathlib import Path


def _records(run: Path) -> list[dict]:
    path = run / "metrics.jsonl"
    if not path.exists():
        return []
    return [json.loads(x) for x in path.read_text().splitlines() if x.strip()]


def summarize(run: Path, threshold: float = 0.95) -> dict[str, str]:
    """One row: figures as text ('-' where the run did not produce them)."""
    recs = _records(run)
    cfg = json.loads((run / "config.json").read_text()) if (run / "config.json").exists() else {}
    train = [r for r in recs if r["kind"] == "train"]
    evals = [r for r in recs if r["kind"] == "eval"]
    final = [r for r in recs if r["kind"] == "final"]
    startup = [r for r in recs if r["kind"] == "startup"]
    sps = [r["sps"] for r in train[1:]] or [r["sps"] for r in train]
    # As the run's own time to threshold: an evaluation of an earlier step than one before it in the file
    # (the step-0 evaluation after training, eval.initial=end) ran late and does not count.
    ran = [e for i, e in enumerate(evals) if all(e["step"] >= x["step"] for x in evals[:i])]
    ordered = sorted(ran, key=lambda e: e["step"])
    hit = next((e for e in ordered if e.get("success_rate", 0) >= threshold), None)
    dev = cfg.get("device", {})
    n_dev = len(dev.get("devices", [])) * int(dev.get("process_count", 1) or 1)
    row = {
        "run": run.name,
        "devices": f"{n_dev} x {dev.get('device_kind', '?')}" if dev else "-",
        "envs": str(cfg.get("train", {}).get("ppo", {}).get("num_envs", "-")),
        "backend": str(cfg.get("train", {}).get("backend", "-")),
        "steady sps": f"{statistics.median(sps):,.0f}" if sps else "-",
        "lines": str(len(train)),
        "first line s": f"{train[0]['time_s']:.0f}" if train else "-",
        f"to {threshold:.0%} s": f"{hit['time_s']:.0f}" if hit else "not reached",
        f"steps at {threshold:.0%}": f"{hit['step']:,}" if hit else "-",
        "final success": f"{100 * final[-1]['success_rate']:.1f}%" if final else "-",
    }
    if startup and "phases" in startup[0]:  # the named breakdown (training.startup.breakdown)
        s = startup[0]
        progs = s["programs"]
        row["compiles s"] = " ".join(f"{k}={p['compile_s']:.0f}" for k, p in progs.items()) or "-"
        row["wait s"] = f"{next(v for k, v in s['phases'].items() if k.startswith('wait for')):.0f}"
        c = s.get("compiles", {})  # an rsl-rl run's record has no cache counts
        row["cache hit/miss"] = f"{c['cache_hits']:.0f}/{c['cache_misses']:.0f}" if "cache_hits" in c else "-"
    elif startup:  # runs recorded before it: flat "compile <program>" keys
        s = startup[0]
        compiles = {k: v for k, v in s.items() if k.startswith("compile ")}
        row["compiles s"] = " ".join(f"{k[8:]}={v:.0f}" for k, v in compiles.items()) or "-"
        wait = next((v for k, v in s.items() if k.startswith("wait for compiles")), None)
        row["wait s"] = f"{wait:.0f}" if wait is not None else "-"
        if "cache_hits" in s:
            row["cache hit/miss"] = f"{s['cache_hits']:.0f}/{s['cache_misses']:.0f}"
    return row


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("runs", nargs="*")
    p.add_argument("--append", nargs="*", default=[])
    p.add_argument("--out", default="")
    args = p.parse_args()
    rows = [summarize(Path(r)) for r in args.runs if Path(r).is_dir()]
    lines = []
    if rows:
        keys: list[str] = []
        for r in rows:
            keys += [k for k in r if k not in keys]
        base = None
        for r in rows:
            try:
                v = float(r["steady sps"].replace(",", ""))
            except ValueError:
                continue
            base = base or v
            r["x first"] = f"{v / base:.2f}"
        keys.insert(keys.index("steady sps") + 1, "x first")
        lines.append("| " + " | ".join(keys) + " |")
        lines.append("|" + "---|" * len(keys))
        lines += ["| " + " | ".join(r.get(k, "-") for k in keys) + " |" for r in rows]
    missing = [r for r in args.runs if not Path(r).is_dir()]
    if missing:
        lines.append(f"no run directory (failed before start?): {' '.join(missing)}")
    for f in args.append:
        path = Path(f)
        lines += ["", f"## {path.name}", path.read_text().rstrip() if path.exists() else "(missing)"]
    text = "\n".join(lines)
    print(text)
    if args.out:
        Path(args.out).write_text(text + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
