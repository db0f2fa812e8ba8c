"""How strongly a policy's action feeds back on itself: d action / d last action at logged states.

The observation holds the last action (term ``actions``), so a policy closes a loop through it from one
control step to the next. A period-2 oscillation at the control rate's Nyquist frequency (the rsl-rl
tracker's chatter, docs/performance.md, 2026-11-29) is that loop's mode at eigenvalue -1: this prints the
eigenvalues of the (n, n) Jacobian of the action with respect to the last action, by central differences on
the ONNX file, at states taken from a deploy run's log. Its most negative real eigenvalue is the candidate
for such a mode; a magnitude above 1 alone does not make the closed loop unstable (the plant, the action
filter and the other observations close it too), so this is a lead to compare files by, not a verdict.

Usage::

    bar-deploy --policy A.onnx --target sim --motion random-s1-000 --start policy --log /tmp/jlog
    python bench/action_jacobian.py --log /tmp/jlog/*/log.npz A.onnx B.onnx [--states 12] [--json F]

Every file is probed at the same logged observations (the log's POLICY ticks, evenly spaced), so files
compare at the same states; the files must share the log's observation layout.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

from bar_policy.deploy.log.read import load_log
from bar_policy.deploy.policy import load_policy
from bar_policy.deploy.safety_config import Mode

LAST_ACTION_TERM = "actions"
"""The observation term that holds the last action (ObservationManager's name)."""


def last_action_jacobian(
    act: Callable[[np.ndarray], np.ndarray], obs: np.ndarray, cols: slice, eps: float = 1e-3
) -> np.ndarray:
    """Central-difference Jacobian of ``act(obs)`` with respect to ``obs[cols]``.

    Args:
        act: callable mapping an observation (obs_size,) to an action (n,).
        obs: one observation, shape (obs_size,).
        cols: the last action's slice of the observation, n entries.
        eps: step in action units (float32 inference: rounding ~1e-7 relative over 2 eps = 2e-3 keeps the
            difference's error ~1e-4, far below the O(1) entries compared).

    Returns:
        (n, n) array, row i = action i, column j = last action j.
    """
    base = np.asarray(obs, dtype=np.float64)
    idx = np.arange(base.size)[cols]
    out = []
    for j in idx:
        up, down = base.copy(), base.copy()
        up[j] += eps
        down[j] -= eps
        out.append(
            (np.asarray(act(up), dtype=np.float64) - np.asarray(act(down), dtype=np.float64)) / (2 * eps)
        )
    return np.stack(out, axis=1)


def probe(policy_path: str, obs_rows: np.ndarray) -> dict[str, float | list[float]]:
    """Eigenvalue figures of one file's last-action Jacobian over the given observations."""
    policy = load_policy(policy_path)
    cols = policy.obs_manager.term_slice(LAST_ACTION_TERM)
    if obs_rows.shape[1] != policy.obs_manager.size:
        raise ValueError(
            f"{policy_path}: observation size {policy.obs_manager.size} != the log's {obs_rows.shape[1]}; "
            "probe files of the log's task and layout"
        )
    most_negative, radius = [], []
    for row in obs_rows:
        eig = np.linalg.eigvals(last_action_jacobian(policy, row, cols))
        most_negative.append(float(eig.real.min()))
        radius.append(float(np.abs(eig).max()))
    return {
        "most_negative_real_mean": float(np.mean(most_negative)),
        "most_negative_real_min": float(np.min(most_negative)),
        "spectral_radius_mean": float(np.mean(radius)),
        "most_negative_real_per_state": most_negative,
    }


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("policies", nargs="+", help="ONNX files to probe")
    ap.add_argument("--log", required=True, help="a deploy run's log.npz (or its directory)")
    ap.add_argument("--states", type=int, default=12, help="POLICY ticks probed, evenly spaced")
    ap.add_argument("--json", help="write the figures here")
    args = ap.parse_args(argv)
    log, _meta = load_log(args.log)
    policy_ticks = np.flatnonzero(np.asarray(log["mode"]) == int(Mode.POLICY))
    if policy_ticks.size < args.states:
        raise SystemExit(f"{args.log}: {policy_ticks.size} POLICY ticks, fewer than --states {args.states}")
    pick = policy_ticks[np.linspace(0, policy_ticks.size - 1, args.states).round().astype(int)]
    obs_rows = np.asarray(log["obs"])[pick]
    results = {}
    head = f"most negative real eigenvalue, mean (min) over {args.states} states"
    print(f"| file | {head} | spectral radius, mean |")
    print("|---|---:|---:|")
    for path in args.policies:
        r = probe(path, obs_rows)
        results[path] = r
        print(
            f"| {path} | {r['most_negative_real_mean']:.2f} ({r['most_negative_real_min']:.2f}) | "
            f"{r['spectral_radius_mean']:.2f} |"
        )
    if args.json:
        Path(args.json).write_text(
            json.dumps({"log": str(args.log), "ticks": pick.tolist(), "files": results})
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
