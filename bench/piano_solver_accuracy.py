"""How far the piano's solver settings are from a converged constraint solve, state by state.

States: C MuJoCo (the sim target's model, float64) holding ``piano_ready`` by the MIT law (Kp 50, Kd 2) with
both elbows commanded ``--press`` rad further, so both fingertips push keys down, sampled every 2 ms for
``--seconds``. At each state ``physics_step.forward`` (the env's) runs in float64 with the model's
settings and with each variant's, and each ``qacc`` is compared with a converged solve (Newton,
``--ref-iterations`` iterations and line-search steps, tolerance 1e-12). Printed: the error's median, 99th
percentile and maximum over states, robot joints and keys apart (rad/s^2), and the keys down (past
``keyboard.pressed``'s threshold) after one more step that differ from the converged solve's.

    python bench/piano_solver_accuracy.py --variants it3+ls5,it3+ls3,it2+ls5
"""

from __future__ import annotations

import argparse
import copy
from pathlib import Path

import jax
import mujoco
import numpy as np
from mujoco import mjx

from bar_policy.envs import physics_step
from bar_policy.robot.constants import load_robot
from bar_policy.robot.scene import load_model
from bar_policy.tasks.piano.keyboard import compact_config, pressed
from bar_policy.tasks.piano.scene import keyboard_scene

ROBOT = load_robot("arms")
KB = compact_config()


def press_states(m: mujoco.MjModel, press: float, seconds: float) -> list[mujoco.MjData]:
    """C MuJoCo states, both elbows commanded ``press`` rad past piano_ready, one per physics step."""
    d = mujoco.MjData(m)
    q_ref = np.asarray(ROBOT.pose("piano_ready")) + np.tile([0.0, 0.0, 0.0, press, 0.0, 0.0, 0.0], 2)
    d.qpos[:14] = ROBOT.pose("piano_ready")
    out = []
    for _ in range(int(seconds / m.opt.timestep)):
        d.qfrc_applied[:14] = 50.0 * (q_ref - d.qpos[:14]) - 2.0 * d.qvel[:14]
        mujoco.mj_step(m, d)
        out.append(copy.copy(d))
    return out


def with_options(m: mujoco.MjModel, variant: str) -> mujoco.MjModel:
    """``m`` with ``itN`` / ``lsN`` / ``tolE`` (tolerance 10^-E) edits joined by ``+``."""
    out = copy.deepcopy(m)
    for part in variant.split("+"):
        if part.startswith("it"):
            out.opt.iterations = int(part[2:])
        elif part.startswith("ls"):
            out.opt.ls_iterations = int(part[2:])
        elif part.startswith("tol"):
            out.opt.tolerance = 10.0 ** -int(part[3:])
        elif part:
            raise ValueError(f"unknown edit {part!r}; valid: itN, lsN, tolE")
    return out


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--variants", default="it3+ls5,it3+ls3,it2+ls5")
    p.add_argument("--press", type=float, default=0.25, help="rad of extra elbow command")
    p.add_argument("--seconds", type=float, default=0.6)
    p.add_argument("--ref-iterations", type=int, default=100)
    p.add_argument("--out", type=Path, default=None)
    a = p.parse_args()
    jax.config.update("jax_enable_x64", True)
    base = load_model("arms", keyboard_scene(KB))
    states = press_states(base, a.press, a.seconds)
    ref_m = with_options(base, f"it{a.ref_iterations}+ls{a.ref_iterations}+tol12")
    stacked = jax.tree.map(lambda *x: np.stack(x), *[mjx.put_data(base, s) for s in states])

    def run(m: mujoco.MjModel) -> tuple[np.ndarray, np.ndarray]:
        mx, plan = mjx.put_model(m), physics_step.plan(m)
        fwd = jax.jit(jax.vmap(lambda d: physics_step.forward(mx, d, plan)))
        stp = jax.jit(jax.vmap(lambda d: physics_step.step(mx, d, plan)))
        return np.asarray(fwd(stacked).qacc), np.asarray(stp(stacked).qpos)

    ref_acc, ref_q = run(ref_m)
    ref_down = np.array([pressed(q[14:], KB) for q in ref_q])
    rows = [
        f"{len(states)} states ({a.seconds} s of both elbows +{a.press} rad), float64, reference: Newton "
        f"{a.ref_iterations} iterations and line-search steps, tolerance 1e-12; max key angle "
        f"{max(np.abs(s.qpos[14:]).max() for s in states):.4f} rad",
        "",
        "| variant | robot qacc error p50 / p99 / max (rad/s^2) | key qacc error p50 / p99 / max "
        "| keys down differing |",
        "|---|---|---|---:|",
    ]
    print("\n".join(rows), flush=True)
    for v in a.variants.split(","):
        acc, q = run(with_options(base, v))
        err = np.abs(acc - ref_acc)
        robot, keys = err[:, :14].max(1), err[:, 14:].max(1)
        down = np.array([pressed(x[14:], KB) for x in q])
        fmt = lambda e: " / ".join(f"{x:.3g}" for x in np.percentile(e, [50, 99, 100]))  # noqa: E731
        rows.append(f"| {v} | {fmt(robot)} | {fmt(keys)} | {int((down != ref_down).sum())} |")
        print(rows[-1], flush=True)
    if a.out:
        a.out.write_text("\n".join(rows) + "\n")


if __name__ == "__main__":
    main()
