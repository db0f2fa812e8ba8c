"""Tick-to-tick action reversals in deploy run logs: the limit cycle behind the tracker's torque faults.

A run's policy action ``a[t]`` (``log.npz`` key ``action``, POLICY ticks only) reverses on a joint at tick
``t`` when ``a[t+1] - a[t]`` and ``a[t] - a[t-1]`` have opposite signs. A smooth tracking policy reverses
on a few percent of (tick, joint) pairs. A 25 Hz limit cycle reverses on nearly all of them, and with
Kp at the shipped gains it drives the MIT torque between +cap and -cap, which the deploy supervisor stops
as ``torque_saturation`` after 0.5 s. Per run, this prints the share over the whole run, the worst window,
the largest one-tick q_cmd jump and how the run ended.

    for i in 0 1 2 3 4 5 6 7; do python -c "from bar_policy.motion import clip_set, save_clip; \\
        save_clip(clip_set('heldout').clips[$i], '/tmp/clip$i.npz')"; \\
      bar-deploy --policy checkpoints/lite_track_arms.onnx --motion /tmp/clip$i.npz --log /tmp/chatter; done
    python bench/track_chatter.py /tmp/chatter/*
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from bar_policy.deploy.log.read import load_log


def reversal_share(action: np.ndarray) -> np.ndarray:
    """Share of joints whose action difference reverses sign at each inner tick.

    Args:
        action: (T, n) actions of consecutive POLICY ticks.

    Returns:
        (T - 2,) shares in [0, 1].
    """
    d = np.diff(np.asarray(action, dtype=float), axis=0)
    return (np.sign(d[1:]) * np.sign(d[:-1]) < 0).mean(axis=1)


def worst_window(share: np.ndarray, ticks: int) -> tuple[float, int]:
    """Highest mean of ``share`` over ``ticks`` consecutive ticks, and the window's first tick."""
    if share.size < ticks:
        return (float(share.mean()) if share.size else float("nan")), 0
    w = np.convolve(share, np.ones(ticks) / ticks, mode="valid")
    return float(w.max()), int(np.argmax(w))


def main(argv: Sequence[str] | None = None) -> int:
    """Print one line per run directory."""
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("runs", nargs="+", type=Path, help="run directories (or their log.npz)")
    p.add_argument("--window", type=float, default=0.5, help="window length, s (the supervisor's 0.5 s)")
    args = p.parse_args(argv)
    head = ("run", "ticks", "reversal", "worst window", "at s", "max dq_cmd rad")
    print(f"{head[0]:<24}{head[1]:>7}{head[2]:>10}{head[3]:>14}{head[4]:>7}{head[5]:>16}  end")
    for run in args.runs:
        arrays, meta = load_log(run)
        act = arrays["action"]
        live = np.isfinite(act).all(axis=1)  # POLICY ticks (other modes log NaN actions)
        name = str(meta.get("commands", run.name)).removeprefix("motion(").split(",")[0][:23]
        if live.sum() < 3:
            print(f"{name:<24}  fewer than 3 policy ticks")
            continue
        dt = float(np.median(np.diff(arrays["t"])))
        share = reversal_share(act[live])
        worst, at = worst_window(share, max(1, round(args.window / dt)))
        jump = float(np.abs(np.diff(arrays["q_cmd"][live], axis=0)).max())
        end = str(meta.get("end_reason", ""))[:60]
        row = f"{name:<24}{live.sum():>7}{share.mean():>10.2f}{worst:>14.2f}{at * dt:>7.2f}{jump:>16.2f}"
        print(f"{row}  {end}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
