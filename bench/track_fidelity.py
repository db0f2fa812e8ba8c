"""Tracking fidelity of an ONNX tracking policy on held-out clips, one column per execution target.

Issue 10 item 5 compares the tracking error of the shipped policy in MJX, on the C MuJoCo sim target and
through the emulated Robstride bus, side by side. This script has the MJX column; the ``sim`` and ``bus``
columns plug into ``COLUMNS`` with the same signature once the deploy side streams motion references
(``bar-deploy --motion``). Every column runs each clip once from its first frame to its last plus
``--hold-s`` of holding the last frame, with the policy's own ONNX graph (onnxruntime), and reports per
clip and overall (frame-weighted): mean joint error (rad), mean tracked-body position error (cm), mean
fingertip error (cm), the per-step success rate (joint error <= 0.05 rad and fingertip error <= 2 cm),
and the steps on which a tracked body was more than 0.25 m off (``lost``).

    python bench/track_fidelity.py --policy checkpoints/lite_track_arms.onnx
    python bench/track_fidelity.py --policy runs/<run>/policy.onnx --randomize --json track_fidelity.json

Targets (issue 10): on held-out clips (random clips of another seed plus the named gestures) mean joint
error <= 0.05 rad and mean fingertip error <= 2 cm on the sim target; sim within 20 % of MJX.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from bar_policy.deploy.policy import OnnxPolicy, load_policy
from bar_policy.motion import Clip, clip_set

METRICS = ("joint_error", "body_pos_error", "fingertip_error", "success", "lost")


@dataclass(frozen=True)
class ClipResult:
    """One clip on one target: sums over its steps (divide by ``steps`` for means)."""

    clip: str
    steps: int
    sums: dict[str, float]

    def mean(self, key: str) -> float:
        """Mean of a metric over the clip's steps."""
        return self.sums[key] / max(self.steps, 1)


Column = Callable[[OnnxPolicy, Sequence[Clip], argparse.Namespace], list[ClipResult]]
"""A target: runs every clip with the policy and returns one result per clip, in order."""


def run_mjx(policy: OnnxPolicy, clips: Sequence[Clip], args: argparse.Namespace) -> list[ClipResult]:
    """All clips at once as a batch of MJX envs (``LiteTrack`` on exactly these clips), stepped in lockstep.

    Nominal physics unless ``--randomize`` (then the training config's episode-level effects and the model
    randomiser, one randomised model per clip, seeded by ``--seed``).
    """
    import jax
    import jax.numpy as jnp

    from bar_policy import envs

    base = envs.default_config("LiteTrack")
    cfg = base if args.randomize else envs.nominal_config(base)
    env = envs.LiteTrack(cfg, clips=clips)
    n = len(clips)
    model, in_axes = env.mjx_model, None
    if args.randomize:
        keys = jax.random.split(jax.random.PRNGKey(args.seed + 1), n)
        model, in_axes = envs.get_randomizer("LiteTrack", cfg)(env.mjx_model, keys)

    def reset(m: object, key: jax.Array, clip: jax.Array) -> object:
        return env.reset_at(key, clip, jnp.zeros((), jnp.int32), model=m)

    reset_b = jax.jit(jax.vmap(reset, in_axes=(in_axes, 0, 0)))
    step_b = jax.jit(jax.vmap(env.step_with_model, in_axes=(in_axes, 0, 0)))
    state = reset_b(model, jax.random.split(jax.random.PRNGKey(args.seed), n), jnp.arange(n))
    hold = round(args.hold_s / env.dt)
    lengths = np.array([env.reference.clip_length[i] - 1 + hold for i in range(n)])
    sums = {k: np.zeros(n) for k in METRICS}
    clip_lim = policy.action_clip or np.inf
    for t in range(int(lengths.max())):
        action = policy.session.run(["actions"], {"obs": np.asarray(state.obs, dtype=np.float32)})[0]
        state = step_b(model, state, jnp.asarray(np.clip(action, -clip_lim, clip_lim), jnp.float32))
        live = t < lengths
        for k in METRICS:
            sums[k] += np.where(live, np.asarray(state.metrics[k]), 0.0)
    return [
        ClipResult(clip=c.name, steps=int(lengths[i]), sums={k: float(sums[k][i]) for k in METRICS})
        for i, c in enumerate(clips)
    ]


COLUMNS: dict[str, Column] = {"mjx": run_mjx}
"""Targets by name. ``sim`` (C MuJoCo sim target) and ``bus`` (through the Robstride CAN emulator) are
added with the deploy side of tracking (issue 10 item 4)."""


def summarise(results: list[ClipResult], label: str) -> dict[str, float]:
    """Frame-weighted means over ``results`` (errors in rad and cm, rates in %)."""
    steps = sum(r.steps for r in results)
    tot = {k: sum(r.sums[k] for r in results) for k in METRICS}
    return {
        "group": label,
        "clips": len(results),
        "steps": steps,
        "joint_error_rad": tot["joint_error"] / steps,
        "body_pos_error_cm": 100 * tot["body_pos_error"] / steps,
        "fingertip_error_cm": 100 * tot["fingertip_error"] / steps,
        "success_pct": 100 * tot["success"] / steps,
        "lost_steps": int(tot["lost"]),
    }


def main(argv: Sequence[str] | None = None) -> int:
    """Run the chosen columns and print a table per column (and JSON with ``--json``)."""
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--policy", required=True, help="ONNX tracking policy (checked with the deploy loader)")
    p.add_argument("--clips", default="heldout", choices=["heldout", "gestures", "train"], help="clip set")
    p.add_argument("--num-clips", type=int, default=None, help="random clips in the set (library default)")
    p.add_argument("--columns", nargs="+", default=["mjx"], choices=sorted(COLUMNS), help="targets to run")
    p.add_argument("--hold-s", type=float, default=0.5, help="s of holding the last frame after each clip")
    p.add_argument("--randomize", action="store_true", help="training randomisation instead of nominal")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--json", type=Path, default=None, help="write the results here")
    args = p.parse_args(argv)

    policy = load_policy(args.policy, task="track")
    chosen = clip_set(args.clips, mode=policy.metadata.mode, num_clips=args.num_clips)
    meta = policy.metadata
    print(f"policy {args.policy} [{policy.obs_manager.fingerprint}] trained on {meta.dataset_repo_id}")
    print(f"clips {chosen.id}: {len(chosen.clips)} clips, {'randomised' if args.randomize else 'nominal'}")
    out: dict[str, object] = {"policy": str(args.policy), "clip_set": chosen.id, "randomize": args.randomize}
    for name in args.columns:
        t0 = time.monotonic()
        results = COLUMNS[name](policy, chosen.clips, args)
        groups = [summarise(results, "all")]
        rand = [r for r in results if r.clip.startswith("random-")]
        named = [r for r in results if not r.clip.startswith("random-")]
        groups += [summarise(sub, label) for label, sub in (("random", rand), ("gestures", named)) if sub]
        print(f"\n[{name}] {time.monotonic() - t0:.0f} s")
        head = ("clip", "steps", "joint rad", "body cm", "tip cm", "success %", "lost")
        print("{:<26}{:>7}{:>11}{:>9}{:>8}{:>11}{:>6}".format(*head))
        rows = [
            (r.clip, r.steps, r.mean("joint_error"), 100 * r.mean("body_pos_error"),
             100 * r.mean("fingertip_error"), 100 * r.mean("success"), int(r.sums["lost"]))
            for r in results
        ] + [
            ("= " + g["group"], g["steps"], g["joint_error_rad"], g["body_pos_error_cm"],
             g["fingertip_error_cm"], g["success_pct"], g["lost_steps"])
            for g in groups
        ]  # fmt: skip
        for c, st, j, b, f, su, lo in rows:
            print(f"{c:<26}{st:>7}{j:>11.4f}{b:>9.2f}{f:>8.2f}{su:>11.1f}{lo:>6}")
        out[name] = {"groups": groups, "clips": [dataclasses.asdict(r) for r in results]}
    if args.json:
        args.json.write_text(json.dumps(out, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
