"""Tracking fidelity of an ONNX tracking policy on held-out clips: MJX, the C MuJoCo sim target, the bus.

The tracking error of one policy on the same clips in three places, side by side:

- ``mjx``: the training env (``LiteTrack`` on exactly these clips, a batch stepped in lockstep, nominal
  physics unless ``--randomize``), the policy's own ONNX graph (onnxruntime);
- ``sim``: the deploy code path (``Runtime``: observation manager, action clip, safety supervisor) on the C
  MuJoCo sim target (``bar_policy.tasks.track.evaluate``, as ``bar-deploy eval``);
- ``bus``: the same through ``RealTarget`` and the python-can ``virtual`` bus to the in-process Robstride
  emulator in lockstep (``bar-deploy --target real --can-interface virtual --emulate lockstep``; the
  ``EmulatedBusTarget``): the CAN codec, the 16-bit feedback and the motors' firmware law in the loop.

Every column runs each clip once from its first frame to its last plus ``--hold-s`` of holding the last
frame, and reports per clip and overall (frame-weighted): mean joint error (rad), mean tracked-body position
error (cm), mean fingertip error (cm), the per-step success rate (joint error <= 0.05 rad and fingertip
error <= 2 cm), and the steps on which a tracked body was more than 0.25 m off (``lost``). The sim and bus
columns model no latency, gain scaling or noise: compare them with the nominal MJX column. They start each
clip at the reference velocity (sim) or at rest (bus; the reference starts at rest in every library clip).

    python bench/track_fidelity.py --policy checkpoints/lite_track_arms.onnx \
        --json track_fidelity.json --markdown track_fidelity.md
    python bench/track_fidelity.py --policy runs/<run>/policy.onnx --columns mjx --randomize

Targets: on held-out clips (random clips of another seed plus the named gestures) mean joint
error <= 0.05 rad and mean fingertip error <= 2 cm on the sim target; sim within 20 % of MJX; the emulated
bus within 30 % of sim (``check_targets``; relative differences of the joint and fingertip errors).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

from bar_policy.deploy.episodes import SimEpisodes
from bar_policy.deploy.policy import OnnxPolicy, load_policy
from bar_policy.deploy.safety import CapDwell, SafetyConfig
from bar_policy.motion import Clip, clip_set
from bar_policy.motion.families import family_of
from bar_policy.quality import EpisodeQuality, QualityMeter
from bar_policy.quality import summarise as summarise_quality
from bar_policy.robot.action_filter import filter_alpha, lowpass_step
from bar_policy.robot.mit import MitCommand, mit_torque
from bar_policy.tasks.track.evaluate import (
    METRICS,
    ClipResult,
    clip_columns,
    evaluate_track,
    group_columns,
    groups,
)

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
    # The env filters actions as the file says its training env did (files made before the filter: none).
    cfg = dataclasses.replace(cfg, action_filter_hz=policy.metadata.action_filter_hz)
    env = envs.LiteTrack(cfg, clips=clips)
    n = len(clips)
    model, in_axes = env.mjx_model, None
    if args.randomize:
        keys = jax.random.split(jax.random.PRNGKey(args.seed + 1), n)
        model, in_axes = envs.get_randomizer("LiteTrack", cfg)(env.mjx_model, keys)

    def reset(m: object, key: jax.Array, clip: jax.Array) -> object:
        return env.reset_at(key, clip, jnp.zeros((), jnp.int32), model=m)

    robot = policy.robot
    safety = _safety(args)
    dwell = [CapDwell(safety.saturation_fraction * robot.torque_cap, safety.saturation_time) for _ in clips]
    cap_dwell = [""] * n

    meters = [
        QualityMeter(robot.torque_cap, robot.lower, robot.upper, env.dt, robot.joint_names) for _ in clips
    ]
    alpha = filter_alpha(cfg.action_filter_hz, cfg.ctrl_dt)
    last_frame = np.asarray(env.reference.clip_start) + np.asarray(env.reference.clip_length) - 1
    reset_b = jax.jit(jax.vmap(reset, in_axes=(in_axes, 0, 0)))
    step_b = jax.jit(jax.vmap(env.step_with_model, in_axes=(in_axes, 0, 0)))
    state = reset_b(model, jax.random.split(jax.random.PRNGKey(args.seed), n), jnp.arange(n))
    hold = round(args.hold_s / env.dt)
    lengths = np.array([env.reference.clip_length[i] - 1 + hold for i in range(n)])
    sums = {k: np.zeros(n) for k in METRICS}
    clip_lim = policy.action_clip or np.inf
    for t in range(int(lengths.max())):
        action = np.clip(
            policy.session.run(["actions"], {"obs": np.asarray(state.obs, dtype=np.float32)})[0],
            -clip_lim,
            clip_lim,
        )
        # The deploy supervisor's torque-saturation rule and the quality meter on the state before the step
        # (MJX only clips at the cap and runs on): the applied action (the env's low-pass of the clipped
        # one, when the env filters), q_cmd clipped to the joint limits, the unclipped MIT demand.
        q, dq = np.asarray(state.data.qpos), np.asarray(state.data.qvel)
        last_act = np.asarray(state.info["last_act"], dtype=np.float64)
        frame = np.minimum(np.asarray(state.info["frame"]) + 1, last_frame)
        for i in range(n):
            if t >= lengths[i]:
                continue
            applied = lowpass_step(last_act[i], action[i], alpha)  # alpha 1: no filter
            q_cmd = np.clip(policy.q_command(applied), robot.lower, robot.upper)
            demand = mit_torque(MitCommand.position(q_cmd, policy.kp, policy.kd), q[i], dq[i])
            q_ref = env.reference.joint_pos[frame[i]]
            meters[i].update(demand, q[i], applied, q_cmd - q_ref)
            if cap_dwell[i]:
                continue
            over = dwell[i].update(demand, env.dt)
            if over.size:
                names = ", ".join(robot.joint_names[j] for j in over)
                cap_dwell[i] = f"t={(t + 1) * env.dt:.2f} s: {names}"
        state = step_b(model, state, jnp.asarray(action, jnp.float32))
        live = t < lengths
        for k in METRICS:
            sums[k] += np.where(live, np.asarray(state.metrics[k]), 0.0)
    return [
        ClipResult(
            clip=c.name,
            steps=int(lengths[i]),
            sums={k: float(sums[k][i]) for k in METRICS},
            cap_dwell=cap_dwell[i],
            quality=meters[i].finish(c.name).to_dict(),
        )
        for i, c in enumerate(clips)
    ]


def _progress(name: str) -> Callable[[ClipResult], None]:
    def show(r: ClipResult) -> None:
        print(f"  [{name}] {r.clip}: {r.steps} steps, joint {r.mean('joint_error'):.4f} rad", flush=True)

    return show


def _safety(args: argparse.Namespace) -> SafetyConfig:
    """The deploy supervisor's thresholds, with ``--saturation-time``."""
    return SafetyConfig(saturation_time=args.saturation_time)


def run_sim(policy: OnnxPolicy, clips: Sequence[Clip], args: argparse.Namespace) -> list[ClipResult]:
    """The deploy path on the C MuJoCo sim target (training's damping integration), nominal physics."""
    res = evaluate_track(
        policy,
        clips,
        runner=SimEpisodes(policy, _safety(args)),
        hold_s=args.hold_s,
        on_clip=_progress("sim") if args.verbose else None,
    )
    return res.clips


def run_bus(policy: OnnxPolicy, clips: Sequence[Clip], args: argparse.Namespace) -> list[ClipResult]:
    """The deploy path through RealTarget and the lockstep Robstride emulator on virtual CAN buses."""
    from bar_policy.deploy.targets.emulated import EmulatedBusTarget

    target = EmulatedBusTarget(policy.robot.mode, policy.policy_dt)
    try:
        res = evaluate_track(
            policy,
            clips,
            runner=SimEpisodes(policy, _safety(args)),
            hold_s=args.hold_s,
            target=target,
            on_clip=_progress("bus") if args.verbose else None,
        )
    finally:
        target.close()
    return res.clips


COLUMNS: dict[str, Column] = {"mjx": run_mjx, "sim": run_sim, "bus": run_bus}
"""Targets by name, in table order."""

ROWS = (
    ("joint_error_rad", "joint error, rad", "{:.4f}"),
    ("body_pos_error_cm", "tracked-body position error, cm", "{:.2f}"),
    ("fingertip_error_cm", "fingertip error, cm", "{:.2f}"),
    ("success_pct", "steps within 0.05 rad and 2 cm, %", "{:.1f}"),
    ("lost_steps", "steps with a body > 25 cm off", "{}"),
    ("faults", "clips ended by a fault", "{}"),
    (
        "cap_dwell_clips",
        "clips with a torque demand at the cap > saturation time (MJX: counted, not stopped)",
        "{}",
    ),
    ("steps", "steps scored", "{}"),
)


QUALITY_ROWS = (
    ("completion_pct", "clips completed, %", "{:.0f}"),
    ("cap_share_pct", "ticks at a torque cap, %", "{:.2f}"),
    ("limit_share_pct", "ticks within 0.02 rad of a limit, %", "{:.2f}"),
    ("chatter_max_mrad", "chatter, worst clip, mrad (RMS above 5 Hz of q_cmd - q_ref)", "{:.2f}"),
)
"""The safety and smoothness rows (``bar_policy.quality``), per clip group and column."""


def _group_quality(clips: list[dict], group: str) -> dict | None:
    """``quality.summarise`` over the group's clips (``all``: every clip); None when none was measured."""
    eps = [
        EpisodeQuality.from_dict(c["quality"])
        for c in clips
        if c.get("quality") and (group == "all" or family_of(c["clip"]) == group)
    ]
    return summarise_quality(eps) if eps else None


def _rel(a: float, b: float) -> float:
    """Relative difference a / b - 1 (NaN when b is 0)."""
    return a / b - 1.0 if b else float("nan")


def check_targets(table: dict[str, dict[str, dict]]) -> list[tuple[str, bool | None, str]]:
    """The issue's targets on the ``all`` group: (target, met (None: column not run), the numbers)."""
    out: list[tuple[str, bool | None, str]] = []
    sim, mjx, bus = (table.get(c, {}).get("all") for c in ("sim", "mjx", "bus"))
    if sim is None:
        return [("sim target: joint error <= 0.05 rad, fingertip error <= 2 cm", None, "sim column not run")]
    j, f = sim["joint_error_rad"], sim["fingertip_error_cm"]
    out.append(("sim: mean joint error <= 0.05 rad", j <= 0.05, f"{j:.4f} rad"))
    out.append(("sim: mean fingertip error <= 2 cm", f <= 2.0, f"{f:.2f} cm"))
    for name, ref, other, limit in (
        ("sim within 20 % of MJX", mjx, sim, 0.2),
        ("bus within 30 % of sim", sim, bus, 0.3),
    ):
        if ref is None or other is None:
            out.append((name, None, "column not run"))
            continue
        rj = _rel(other["joint_error_rad"], ref["joint_error_rad"])
        rf = _rel(other["fingertip_error_cm"], ref["fingertip_error_cm"])
        ok = abs(rj) <= limit and abs(rf) <= limit
        out.append((name, ok, f"joint {100 * rj:+.1f} %, fingertip {100 * rf:+.1f} %"))
    return out


def markdown(out: dict) -> str:
    """The side-by-side table (one row per metric and clip group, one column per target) and the targets."""
    cols = [c for c in COLUMNS if c in out["columns"]]
    table = {c: {g["group"]: g for g in out["columns"][c]["groups"]} for c in cols}
    names = {"mjx": "MJX", "sim": "sim target (C MuJoCo)", "bus": "emulated bus (lockstep)"}
    head = ["clips", "metric", *(names[c] for c in cols)]
    if "sim" in cols and "mjx" in cols:
        head.append("sim vs MJX")
    if "sim" in cols and "bus" in cols:
        head.append("bus vs sim")
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * 2 + "---:|" * (len(head) - 2)]
    first = table[cols[0]]
    for group, g0 in first.items():
        label = f"{group} ({g0['clips']} clips)"
        for key, metric, fmt in ROWS:
            row = [label, metric] + [
                fmt.format(table[c][group][key]) if group in table[c] else "" for c in cols
            ]
            for a, b in (("sim", "mjx"), ("bus", "sim")):
                if a in cols and b in cols:
                    ok = key.endswith(("_rad", "_cm")) and group in table[a] and group in table[b]
                    row.append(
                        f"{100 * _rel(table[a][group][key], table[b][group][key]):+.1f} %" if ok else ""
                    )
            lines.append("| " + " | ".join(row) + " |")
            label = ""
    for group in first:
        label = f"{group} quality"
        for key, metric, fmt in QUALITY_ROWS:
            row = [label, metric]
            for c in cols:
                qs = _group_quality(out["columns"][c]["clips"], group)
                row.append(fmt.format(qs[key]) if qs else "")
            row += [""] * (len(head) - len(row))
            lines.append("| " + " | ".join(row) + " |")
            label = ""
    lines += ["", "| target (all held-out clips) | met | value |", "|---|---|---|"]
    for name, ok, value in check_targets(table):
        lines.append(f"| {name} | {'n/a' if ok is None else 'yes' if ok else 'NO'} | {value} |")
    secs = ", ".join(f"{names[c]} {out['columns'][c]['wall_s']:.0f} s" for c in cols)
    physics = "training randomisation (MJX only)" if out["randomize"] else "nominal physics"
    lines += [
        "",
        f"Policy `{out['policy']}` ({out['dataset_repo_id']}), clips `{out['clip_set']}`, {physics}, hold "
        f"{out['hold_s']:g} s after each clip, torque-saturation fault after {out['saturation_time']:g} s "
        f"(sim, bus); wall time: {secs}. A clip ended by a fault is scored up to the fault.",
    ]
    return "\n".join(lines)


def main(argv: Sequence[str] | None = None) -> int:
    """Run the chosen columns; print a table per column and the markdown table; write JSON / markdown."""
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--policy", required=True, help="ONNX tracking policy (checked with the deploy loader)")
    p.add_argument(
        "--clips", default="heldout", choices=["heldout", "gestures", "families", "train"], help="clip set"
    )
    p.add_argument("--num-clips", type=int, default=None, help="random clips in the set (library default)")
    p.add_argument(
        "--columns", nargs="+", default=list(COLUMNS), choices=list(COLUMNS), help="targets to run"
    )
    p.add_argument("--hold-s", type=float, default=0.5, help="s of holding the last frame after each clip")
    p.add_argument("--randomize", action="store_true", help="MJX column: training randomisation")
    p.add_argument(
        "--saturation-time",
        type=float,
        default=SafetyConfig().saturation_time,
        help="s a joint may stay at its torque cap: sim / bus fault and stop (default 0.5, the deploy "
        "default; 1e9 for a physics-only comparison); MJX only clips at the cap and counts the clips that "
        "would have faulted",
    )
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--json", type=Path, default=None, help="write the results here")
    p.add_argument("--markdown", type=Path, default=None, help="write the side-by-side table here")
    p.add_argument("-v", "--verbose", action="store_true", help="print each clip as it finishes")
    args = p.parse_args(argv)

    policy = load_policy(args.policy, task="track")
    chosen = clip_set(args.clips, mode=policy.metadata.mode, num_clips=args.num_clips)
    meta = policy.metadata
    print(f"policy {args.policy} [{policy.obs_manager.fingerprint}] trained on {meta.dataset_repo_id}")
    print(f"clips {chosen.id}: {len(chosen.clips)} clips, {'randomised' if args.randomize else 'nominal'}")
    out: dict = {
        "policy": str(args.policy),
        "obs_fingerprint": policy.obs_manager.fingerprint,
        "dataset_repo_id": meta.dataset_repo_id,
        "clip_set": chosen.id,
        "randomize": args.randomize,
        "hold_s": args.hold_s,
        "saturation_time": args.saturation_time,
        "columns": {},
    }
    for name in [c for c in COLUMNS if c in args.columns]:
        t0 = time.monotonic()
        results = COLUMNS[name](policy, chosen.clips, args)
        wall = time.monotonic() - t0
        grp = groups(results)
        print(f"\n[{name}] {wall:.0f} s")
        head = ("clip", "steps", "joint rad", "body cm", "tip cm", "success %", "lost", "fault")
        print("{:<26}{:>7}{:>11}{:>9}{:>8}{:>11}{:>6}{:>7}".format(*head))
        rows = [(*clip_columns(r), int(r.faulted)) for r in results] + [group_columns(g) for g in grp]
        for c, st, j, b, f, su, lo, fa in rows:
            print(f"{c:<26}{st:>7}{j:>11.4f}{b:>9.2f}{f:>8.2f}{su:>11.1f}{lo:>6}{fa:>7}")
        for r in results:
            if r.cap_dwell or r.faulted:
                print(f"  {r.clip}: {r.cap_dwell or r.end_reason}")
        out["columns"][name] = {
            "wall_s": wall,
            "groups": grp,
            "clips": [dataclasses.asdict(r) for r in results],
        }
    md = markdown(out)
    print("\n" + md)
    if args.json:
        args.json.write_text(json.dumps(out, indent=2))
    if args.markdown:
        args.markdown.write_text(md + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
