"""One markdown row per training run of a recipe (``gpu_session.sh recipe track|piano``).

Each row: env steps, wall time and the final MJX evaluation's ``--keys`` from the run's ``final_eval.json``,
then the best iterate (``last``, or its step and its ``--best`` figures).

    python3 bench/recipe_summary.py RUNS_DIR --keys f1 precision recall --best f1
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("runs", type=Path, help="directory holding one directory per run")
    p.add_argument("--keys", nargs="+", required=True, help="final_eval.json figures, one column each")
    p.add_argument("--best", nargs="+", required=True, help="figures shown for an earlier best iterate")
    a = p.parse_args()
    nan = float("nan")
    names = " | ".join(k.split("/")[-1] for k in a.keys)
    print(f"| run | env steps | wall s | {names} | best iterate |")
    print("|---" * (len(a.keys) + 4) + "|")
    for run in sorted(a.runs.iterdir()):
        f = run / "final_eval.json"
        if not f.exists():
            print(f"| {run.name} | (no final_eval.json) |")
            continue
        r = json.loads(f.read_text())
        fe, best = r["final_eval"], r.get("best_iterate", {})
        b = "last"
        if not best.get("is_last", True):
            figures = ", ".join(f"{k.split('/')[-1]} {best['final_eval'].get(k, nan):.4g}" for k in a.best)
            b = f"{best['step']:,}: {figures}"
        cells = " | ".join(f"{fe.get(k, nan):.4g}" for k in a.keys)
        print(f"| {run.name} | {r['env_steps']:,} | {r['wall_s']:.0f} | {cells} | {b} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
