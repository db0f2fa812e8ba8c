"""How much of a perturbed row's tracking error is the unknown model: the tracker plus an exact feed-forward.

    python bench/track_oracle.py --policy checkpoints/lite_track_arms.onnx --perturb payload_kg=0.5
    python bench/track_oracle.py --policy F --perturb payload_kg=0.5 --part dynamic --frame 2 --json out.json

A policy never knows the perturbed robot; this bench hands it the difference. Each tick, the file's command
plus ``(tau_true - tau_nominal)[joint] / Kp`` rad, the torque the perturbed model needs beyond the nominal
one to follow the reference, folded into the command through the P-law's spring (after the policy's
action: its observation's last action stays the file's own, which the policy would otherwise answer):
``mj_inverse`` of both models at the reference's frame ``--frame`` (1 = the next tick's pose) with its
velocity and acceleration by central differences of the observed frames (the layout's
``motion_joint_pos``, 20 ms apart). ``--part full`` adds all of it; ``gravity`` the difference at rest
(inverse dynamics at zero velocity and acceleration) alone; ``dynamic`` all but that, for a file on the
integral prior, whose error average already carries a steady load (adding it again doubles it: the
average tends to the whole spring deflection).
The clips run through ``bar-deploy eval``'s code (``tasks.track.evaluate.evaluate_track``, the sim target
of ``--perturb``); the table's first line is the file alone on the same robot.

What it bounds: the row's error with the model known exactly at the reference (not at the measured state,
which an estimator would also need), through the same filter, latency and torque caps. A row this leaves
above the gate is out of reach of any estimate of the model for that file's feedback; a row it brings under
the gate is one that identification (a history, an estimate) can close.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path
from typing import Any

import mujoco
import numpy as np

from bar_policy.deploy.episodes import SimEpisodes
from bar_policy.deploy.policy import OnnxPolicy, load_policy
from bar_policy.robot.index import RobotIndex
from bar_policy.robot.perturb_spec import Perturbation, parse_perturbation
from bar_policy.tasks.track.evaluate import eval_clips, evaluate_track, summarise

PARTS = ("full", "gravity", "dynamic")


class ModelFeedforward:
    """``policy`` with the inverse-dynamics difference of two models added to its action (module docstring).

    Everything but ``__call__`` is the policy's (the runtime reads its metadata, layout and command map).
    """

    def __init__(
        self, policy: OnnxPolicy, nominal: mujoco.MjModel, true: mujoco.MjModel, frame: int, part: str
    ) -> None:
        om = policy.obs_manager
        self.policy = policy
        self.frame = frame
        self.part = part
        self.dt = policy.policy_dt
        self.slice = om.term_slice("motion_joint_pos")
        self.term_scale = float(om.term("motion_joint_pos").scale)
        self.n = len(om.joint_names)
        self.k = om.schema.lookahead_steps
        if not 2 <= frame <= self.k - 1:
            raise ValueError(f"--frame must be in 2..{self.k - 1} (central differences), got {frame}")
        names = policy.robot.joint_names
        self.models = [(m, mujoco.MjData(m), RobotIndex.from_model(m, names)) for m in (nominal, true)]
        self.act = np.asarray(policy.action_index)
        self.kp = np.asarray(policy.robot.kp, np.float64)[self.act]
        self.ff = np.zeros(len(self.act))  # this tick's feed-forward, rad per action joint
        self.added = []  # mean |feed-forward| per tick, rad (the report's mean)

    def __getattr__(self, name: str) -> Any:
        return getattr(self.policy, name)

    def _tau(self, which: int, q: np.ndarray, dq: np.ndarray, ddq: np.ndarray) -> np.ndarray:
        m, d, idx = self.models[which]
        d.qpos[idx.qpos], d.qvel[:], d.qacc[:] = q, 0.0, 0.0
        d.qvel[idx.dof], d.qacc[idx.dof] = dq, ddq
        mujoco.mj_inverse(m, d)
        return d.qfrc_inverse[idx.dof].copy()

    def q_command(self, action: np.ndarray) -> np.ndarray:
        """The file's command plus this tick's feed-forward, rad, shape ``(num_joints,)``."""
        q = self.policy.q_command(action)
        q[self.act] += self.ff
        return q

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        """The file's action; computes the feed-forward ``q_command`` adds (the runtime calls it next)."""
        frames = np.asarray(obs[self.slice], np.float64).reshape(self.k, self.n) / self.term_scale
        f = self.frame - 1  # row of frame `frame` (row 0: the next tick's)
        q = frames[f]
        dq = (frames[f + 1] - frames[f - 1]) / (2 * self.dt)
        ddq = (frames[f + 1] - 2 * frames[f] + frames[f - 1]) / self.dt**2
        zero = np.zeros_like(q)
        static = self._tau(1, q, zero, zero) - self._tau(0, q, zero, zero)
        dtau = static
        if self.part != "gravity":
            dtau = self._tau(1, q, dq, ddq) - self._tau(0, q, dq, ddq)
        if self.part == "dynamic":
            dtau = dtau - static
        self.ff = dtau[self.act] / self.kp
        self.added.append(float(np.mean(np.abs(self.ff))))
        return self.policy(obs)


def run(policy: OnnxPolicy, clips: list, p: Perturbation, wrap: dict | None) -> dict[str, Any]:
    """The clips on the sim target of ``p``; ``wrap``: ``ModelFeedforward``'s frame and part (None: none)."""
    nominal_runner = SimEpisodes(policy)
    runner = SimEpisodes(policy, perturbation=p)
    target = runner.target()
    used: Any = policy
    if wrap is not None:
        used = ModelFeedforward(policy, nominal_runner.target().model, target.model, **wrap)
        runner = SimEpisodes(used, perturbation=p)
    res = evaluate_track(used, clips, runner=runner, target=target)
    s = summarise(res.clips, "all")  # frame-weighted, as bar-deploy eval's table
    ticks = sum(c.quality.get("ticks", 0) for c in res.clips)
    out = {
        "fingertip_cm": s["fingertip_error_cm"],
        "joint_rad": s["joint_error_rad"],
        "faulted": s["faults"],
        "cap_pct": 100.0 * sum(c.quality.get("cap_ticks", 0) for c in res.clips) / max(ticks, 1),
        "summary": s,
    }
    if wrap is not None:
        out["mean_feedforward_rad"] = float(np.mean(used.added))
    return out


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--policy", required=True, type=Path, help="a tracking policy file (.onnx)")
    p.add_argument("--perturb", required=True, help="the robot, as bar-deploy --perturb KEY=VALUE[,...]")
    p.add_argument("--frame", type=int, default=2, help="reference frame of the feed-forward (default 2)")
    p.add_argument("--part", nargs="+", default=["full"], choices=PARTS, help="feed-forwards to run")
    p.add_argument("--clips", default="heldout", help="a clip set or motion names (default heldout)")
    p.add_argument("--json", type=Path, help="write the results here")
    args = p.parse_args()
    policy = load_policy(str(args.policy))
    pert = parse_perturbation(args.perturb)
    _, clips = eval_clips(args.clips, policy.robot.mode)
    rows = {}
    print(f"{args.policy}, --perturb {args.perturb}, {len(clips)} clips, frame {args.frame}")
    print("| feed-forward | fingertip cm | joint rad | faulted | at a cap % | mean abs feed-forward mrad |")
    print("|---|---:|---:|---:|---:|---:|")
    for part in ("none", *args.part):
        t0 = time.perf_counter()
        wrap = None if part == "none" else {"frame": args.frame, "part": part}
        r = rows[part] = run(policy, clips, pert, wrap)
        ff = f"{1000 * r['mean_feedforward_rad']:.1f}" if "mean_feedforward_rad" in r else ""
        print(
            f"| {part} | {r['fingertip_cm']:.2f} | {r['joint_rad']:.4f} | {r['faulted']} | "
            f"{r['cap_pct']:.2f} | {ff} |  ({time.perf_counter() - t0:.0f} s)"
        )
    if args.json:
        args.json.write_text(json.dumps({"policy": str(args.policy), "perturb": args.perturb, "rows": rows}))


if __name__ == "__main__":
    main()
