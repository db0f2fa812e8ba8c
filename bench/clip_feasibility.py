"""Can the robot follow a clip set at all? Reference inverse dynamics against the torque caps, and contacts.

For every frame of every clip, the reference q, dq and ddq (central differences at the clip's rate) go
through C MuJoCo's ``mj_inverse`` on the Lite model (gravity, inertia, armature, passive forces; no
contacts, since the reference poses are checked separately). The largest |torque| per joint is compared
with the joint's actuator cap. ``mj_forward`` at each reference pose lists the geom pairs that interpenetrate
by more than 1 mm (the model's own collision geoms and exclusions). A clip whose reference needs more than
the cap, or passes through the robot's own body, is a clip problem; a tracking policy that faults on a
feasible clip is a policy problem (``docs/tracking.md``).

    python bench/clip_feasibility.py                 # the held-out set
    python bench/clip_feasibility.py --clips train --num-clips 16
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

import numpy as np

from bar_policy.motion import clip_set
from bar_policy.robot.constants import load_robot
from bar_policy.robot.mjcf import load_model


def main(argv: Sequence[str] | None = None) -> int:
    """Print one line per clip; exit 1 when any clip exceeds ``--fraction`` of a cap or interpenetrates."""
    import mujoco

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--clips", default="heldout", choices=["heldout", "gestures", "train"], help="clip set")
    p.add_argument("--num-clips", type=int, default=None, help="random clips in the set (library default)")
    p.add_argument("--mode", default="arms", choices=["arms", "arms_neck"])
    p.add_argument("--fraction", type=float, default=0.8, help="report joints above this share of their cap")
    args = p.parse_args(argv)
    robot = load_robot(args.mode)
    m = load_model(args.mode)
    d = mujoco.MjData(m)
    jid = [mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, n) for n in robot.joint_names]
    qadr, dadr = m.jnt_qposadr[jid], m.jnt_dofadr[jid]
    cap = robot.torque_cap
    bad = 0
    print(f"{'clip':<26}{'frames':>7}{'worst tau / cap':>17}  {'joint':<22}{'penetrating frames':>20}")
    for clip in clip_set(args.clips, mode=args.mode, num_clips=args.num_clips).clips:
        q = clip.joint_pos.astype(float)
        dq = np.gradient(q, 1.0 / clip.rate_hz, axis=0)
        ddq = np.gradient(dq, 1.0 / clip.rate_hz, axis=0)
        peak = np.zeros(len(cap))
        pen: dict[tuple[str, str], float] = {}
        pen_frames = 0
        for f in range(len(q)):
            d.qpos[:], d.qvel[:] = 0.0, 0.0
            d.qpos[qadr], d.qvel[dadr] = q[f], dq[f]
            mujoco.mj_forward(m, d)  # contacts at the pose; it also overwrites qacc with the free motion
            hit = False
            for c in d.contact[: d.ncon]:
                if c.dist < -1e-3:
                    pair = (m.body(m.geom_bodyid[c.geom1]).name, m.body(m.geom_bodyid[c.geom2]).name)
                    pen[pair] = min(pen.get(pair, 0.0), float(c.dist))
                    hit = True
            pen_frames += hit
            d.qacc[:] = 0.0
            d.qacc[dadr] = ddq[f]
            mujoco.mj_inverse(m, d)
            peak = np.maximum(peak, np.abs(d.qfrc_inverse[dadr]))
        ratio = peak / cap
        j = int(np.argmax(ratio))
        flag = ratio[j] > args.fraction or pen_frames > 0
        bad += flag
        print(f"{clip.name:<26}{len(q):>7}{ratio[j]:>17.2f}  {robot.joint_names[j]:<22}{pen_frames:>20}")
        for (a, b), depth in sorted(pen.items()):
            print(f"    {a} / {b}: deepest {100 * depth:.1f} cm")
    print(f"{bad} clip(s) above {args.fraction:.0%} of a cap or interpenetrating")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
