"""Training curves of tracker runs side by side: the held-out MJX evaluations in each run's metrics.jsonl.

    python bench/track_curves.py runs/recipe-seed0 runs/recipe-seed1 --png docs/tracking_seeds.png \
        --markdown curves.md

Per evaluation: env steps, wall time, success rate, joint error (rad), fingertip error (cm), chatter (worst
episode, mrad), share of ticks at a torque cap (%). The PNG plots the fingertip and joint errors and the
success rate against env steps, one line per run (labelled by the run directory's name).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

KEYS = (
    ("success_rate", "success", 100.0, "%"),
    ("joint_error_rad", "joint", 1.0, "rad"),
    ("fingertip_error_cm", "fingertip", 1.0, "cm"),
    ("quality/chatter_max_mrad", "chatter max", 1.0, "mrad"),
    ("quality/cap_share_pct", "at cap", 1.0, "%"),
)


def evaluations(run: Path) -> list[dict[str, Any]]:
    """The run's evaluation records (``kind`` eval in step order, then final, in order)."""
    rows = [json.loads(line) for line in (run / "metrics.jsonl").read_text().splitlines() if line.strip()]
    rows = [r for r in rows if r.get("kind") in ("eval", "final")]
    # The step-0 evaluation may have been written last (eval.initial=end); a stable sort keeps the finals.
    return sorted(rows, key=lambda r: (r["kind"] == "final", r["step"] if r["kind"] == "eval" else 0))


def markdown(runs: list[Path]) -> str:
    """One table per run: a row per evaluation."""
    out = []
    for run in runs:
        out.append(f"**{run.name}**\n")
        out.append("| env steps | wall s | " + " | ".join(f"{k[1]}, {k[3]}" for k in KEYS) + " |")
        out.append("|---:" * (len(KEYS) + 2) + "|")
        for r in evaluations(run):
            vals = [r.get(k) for k, *_ in KEYS]
            cells = ["" if v is None else f"{v * s:.4g}" for v, (_, _, s, _) in zip(vals, KEYS, strict=True)]
            step = f"{r['step'] / 1e6:.1f} M" + (" (final)" if r["kind"] == "final" else "")
            out.append(f"| {step} | {r['time_s']:.0f} | " + " | ".join(cells) + " |")
        out.append("")
    return "\n".join(out)


def plot(runs: list[Path], png: Path) -> None:
    """Fingertip error, joint error and success rate against env steps."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(13, 3.6))
    for run in runs:
        ev = [r for r in evaluations(run) if r["kind"] == "eval"]
        x = [r["step"] / 1e6 for r in ev]
        axes[0].plot(x, [r["fingertip_error_cm"] for r in ev], marker="o", label=run.name)
        axes[1].plot(x, [r["joint_error_rad"] for r in ev], marker="o", label=run.name)
        axes[2].plot(x, [100 * r["success_rate"] for r in ev], marker="o", label=run.name)
    titles = ("fingertip error, cm", "joint error, rad", "steps within 0.05 rad and 2 cm, %")
    for ax, title, target in zip(axes, titles, (1.0, 0.02, None), strict=True):
        ax.set_title(title)
        ax.set_xlabel("env steps, M")
        ax.set_yscale("log" if target else "linear")
        if target:
            ax.axhline(target, color="k", lw=0.8, ls="--")
        ax.grid(alpha=0.3)
    axes[0].legend()
    fig.tight_layout()
    fig.savefig(png, dpi=90)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("runs", nargs="+", type=Path, help="run directories (each with metrics.jsonl)")
    p.add_argument("--png", type=Path, default=None, help="write the plot here")
    p.add_argument("--markdown", type=Path, default=None, help="write the tables here")
    a = p.parse_args()
    text = markdown(a.runs)
    print(text)
    if a.markdown:
        a.markdown.write_text(text)
    if a.png:
        plot(a.runs, a.png)


if __name__ == "__main__":
    main()
