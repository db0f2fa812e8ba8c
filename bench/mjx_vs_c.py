"""The MJX training env's physics against C MuJoCo, for one randomised model draw and one action sequence.

For a robust preset's env (``--preset``: its env overrides, randomisation on), one env slot's model draw
(``envs.randomize``) and one episode's actuator draws (latency, Kp/Kd scale, offset, strength), the MJX env
steps an open-loop action sequence (smooth random actions, ``--steps`` control steps) and records, per
control step, the MIT command it decoded and the robot's true state. C MuJoCo then replays those commands
on the same model (every randomised field copied from the slot), the same initial state, with the env's
actuator (``mit.firmware_torque`` at the measured ``q + offset``, ``strength``, implicit Kd), at the env's
``sim_dt`` and at the sim target's 2 ms; and the deploy sim target itself (``PerturbedSimTarget`` with the
model fields and the motors' draws) plays them at 2 ms. Printed: the largest joint-position and velocity
differences, and the share of physics steps at a torque cap, for each pair.

    PYTHONPATH=$PWD python bench/mjx_vs_c.py --preset reach-robust --steps 150 --seed 0
"""

from __future__ import annotations

import argparse
import copy
import dataclasses
import time
from typing import Any

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from mujoco import mjx

from bar_policy import envs
from bar_policy.deploy.targets.perturbed import PerturbedSimTarget
from bar_policy.deploy.targets.sim import SimConfig
from bar_policy.envs.randomize import make_randomizer, payload_scene
from bar_policy.robot.mit import MitCommand, firmware_torque, wire_ranges
from bar_policy.robot.perturb_spec import Perturbation
from bar_policy.training.config import preset as train_preset

RANDOMISED = ("dof_armature", "dof_frictionloss", "dof_damping", "body_mass", "body_inertia", "body_pos")
"""Model fields the randomiser may draw (copied to the C model)."""


def robust_env(preset: str, extra: tuple[str, ...]) -> Any:
    """The preset's env with its overrides (and ``extra``): the training env, randomisation on."""
    cfg = train_preset(preset)
    return envs.load(cfg.env_name, overrides=[*cfg.env_overrides, *extra])


def slot_model(env: Any, seed: int) -> mjx.Model:
    """One env slot's randomised MJX model (the randomiser of ``env.config`` with key ``seed``)."""
    batched, _ = make_randomizer(env.config)(env.mjx_model, jax.random.PRNGKey(seed)[None])
    return env.mjx_model.replace(**{f: getattr(batched, f)[0] for f in RANDOMISED})


def actions(n_steps: int, n: int, seed: int) -> np.ndarray:
    """Smooth open-loop actions in [-1, 1]: three sinusoids per joint, 0.2-1.5 Hz, shape (steps, n)."""
    rng = np.random.default_rng(seed)
    t = np.arange(n_steps)[:, None] * 0.02
    a = np.zeros((n_steps, n))
    for _ in range(3):
        f = rng.uniform(0.2, 1.5, n)
        a += rng.uniform(0.1, 0.35, n) * np.sin(2 * np.pi * f * t + rng.uniform(0, 2 * np.pi, n))
    return np.clip(a, -1, 1)


def mjx_rollout(env: Any, model: mjx.Model, seed: int, acts: np.ndarray) -> tuple[Any, list[np.ndarray]]:
    """The MJX env's episode: (reset info, commands per step (q, kp, kd), q and dq after each step)."""
    state = jax.jit(env.reset_with_model)(model, jax.random.PRNGKey(seed))

    @jax.jit
    def step(state: Any, a: jax.Array) -> tuple[Any, tuple[jax.Array, ...]]:
        _, _, cmd = env._command(state.info, a)
        new = env.step_with_model(model, state, a)
        return new, (cmd.q, cmd.kp, cmd.kd, env.robot_q(new.data), env.robot_dq(new.data))

    first = state
    out = []
    for a in acts:
        state, rec = step(state, jnp.asarray(a, jnp.float32))
        out.append([np.asarray(x, np.float64) for x in rec])
    cols = [np.stack(c) for c in zip(*out, strict=True)]
    return first, cols


def c_model(env: Any, model: mjx.Model, dt: float) -> mujoco.MjModel:
    """The env's C model with the slot's randomised fields, at timestep ``dt``."""
    m = copy.copy(env.mj_model)
    for f in RANDOMISED:
        getattr(m, f)[:] = np.asarray(getattr(model, f), np.float64).reshape(getattr(m, f).shape)
    m.opt.timestep = dt
    return m


def c_replay(
    env: Any, m: mujoco.MjModel, info: dict, q0: np.ndarray, dq0: np.ndarray, cmds: tuple, dt: float
) -> tuple[np.ndarray, np.ndarray, float]:
    """Replay the MJX commands in C MuJoCo with the env's actuator: (q, dq per control step, cap share)."""
    robot = env.robot
    ranges = wire_ranges(robot.models)
    cap = robot.torque_cap
    idx = env.robot_index
    d = mujoco.MjData(m)
    d.qpos[idx.qpos] = q0
    d.qvel[idx.dof] = dq0
    mujoco.mj_forward(m, d)
    base_damping = m.dof_damping[idx.dof].copy()
    off = np.asarray(info["encoder_offset"], np.float64)
    s = np.asarray(info.get("strength", np.ones(robot.num_joints)), np.float64)
    sub = round(env.config.ctrl_dt / dt)
    qs, dqs, capped, total = [], [], 0, 0
    for q_cmd, kp, kd in zip(*cmds, strict=True):
        z = np.zeros_like(q_cmd)
        cmd = MitCommand(q=q_cmd, dq=z, kp=kp, kd=kd, tau_ff=z)
        for _ in range(sub):
            q, dq = d.qpos[idx.qpos], d.qvel[idx.dof]
            tau = firmware_torque(cmd, q + off, dq, ranges, cap, quantize_wire=False)
            d_law = np.where(np.abs(tau) < cap, kd, 0.0) * s
            m.dof_damping[idx.dof] = base_damping + d_law
            d.qfrc_applied[idx.dof] = s * tau + d_law * dq
            capped += int(np.sum(np.abs(tau) >= cap))
            total += tau.size
            mujoco.mj_step(m, d)
        qs.append(d.qpos[idx.qpos].copy())
        dqs.append(d.qvel[idx.dof].copy())
    m.dof_damping[idx.dof] = base_damping
    return np.stack(qs), np.stack(dqs), capped / total


def target_replay(
    env: Any, m_slot: mujoco.MjModel, info: dict, q0: np.ndarray, dq0: np.ndarray, cmds: tuple
) -> tuple[np.ndarray, float]:
    """The deploy sim target (2 ms), its model given the slot's fields and its motors the episode's draws."""
    scene = payload_scene() if env.config.randomization.payload_kg is not None else None
    t = PerturbedSimTarget(env.config.mode, SimConfig(), scene=scene, perturbation=Perturbation())
    for f in RANDOMISED:
        getattr(t.model, f)[:] = getattr(m_slot, f)
    t._mjcf_damping = t.model.dof_damping[t._dadr].copy()
    strength = np.asarray(info.get("strength", np.ones(t.num_joints)), np.float64)
    offset = np.asarray(info["encoder_offset"], np.float64)
    t.motors = dataclasses.replace(t.motors, strength=strength, offset=offset)
    t.reset(q0, dq0)
    qs, capped, total = [], 0, 0
    for q_cmd, kp, kd in zip(*cmds, strict=True):
        z = np.zeros_like(q_cmd)
        t.write_command(MitCommand(q=q_cmd, dq=z, kp=kp, kd=kd, tau_ff=z))
        for _ in range(10):
            tau = t.applied_torque()
            capped += int(np.sum(np.abs(tau) >= t._cap))
            total += tau.size
            t.step()
        qs.append(t.true_q())
    return np.stack(qs), capped / total


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--preset", default="reach-robust")
    p.add_argument("--steps", type=int, default=150)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--set", nargs="*", default=[], help="more env overrides (dotted.path=value)")
    args = p.parse_args()
    t0 = time.time()
    env = robust_env(args.preset, tuple(args.set))
    model = slot_model(env, args.seed)
    acts = actions(args.steps, env.action_size, args.seed)
    first, (q_cmd, kp, kd, q_mjx, dq_mjx) = mjx_rollout(env, model, args.seed, acts)
    info = {k: np.asarray(v) for k, v in first.info.items() if k in ("encoder_offset", "strength")}
    info_all = {k: np.asarray(v) for k, v in first.info.items() if np.asarray(v).size <= 14}
    print(f"episode draws: { {k: np.round(v, 3).tolist() for k, v in info_all.items() if k != 'rng'} }")
    idx = env.robot_index
    q0 = np.asarray(first.data.qpos, np.float64)[idx.qpos]
    dq0 = np.asarray(first.data.qvel, np.float64)[idx.dof]
    cmds = (q_cmd, kp, kd)
    dt = env.config.sim_dt
    m_env = c_model(env, model, dt)
    q_c, dq_c, cap_c = c_replay(env, m_env, info, q0, dq0, cmds, dt)
    m2 = c_model(env, model, 0.002)
    q_c2, dq_c2, cap_c2 = c_replay(env, m2, info, q0, dq0, cmds, 0.002)
    q_t, cap_t = target_replay(env, m2, info, q0, dq0, cmds)
    # The description's model (no draw) under the same commands: how much the draw itself moves the arm,
    # the scale against which a field that never reached the MJX step would show.
    q_nom, _, _ = c_replay(env, copy.copy(env.mj_model), info, q0, dq0, cmds, dt)
    names = env.robot.joint_names

    def diff(a: np.ndarray, b: np.ndarray, what: str) -> None:
        e = np.abs(a - b)
        j = int(np.argmax(e.max(axis=0)))
        print(f"  {what}: max {e.max():.2e} (joint {names[j]}), mean {e.mean():.2e}")

    print(f"{args.preset}, slot/episode seed {args.seed}, {args.steps} control steps, sim_dt {dt} s")
    print("MJX env vs C MuJoCo, same model, same dt:")
    diff(q_mjx, q_c, "q rad")
    diff(dq_mjx, dq_c, "dq rad/s")
    print("C, the slot's model vs the description's (the draw's own effect):")
    diff(q_c, q_nom, "q rad")
    print(f"C at {dt} s vs C at 0.002 s:")
    diff(q_c, q_c2, "q rad")
    diff(dq_c, dq_c2, "dq rad/s")
    print("C at 0.002 s vs the deploy sim target (2 ms):")
    diff(q_c2, q_t, "q rad")
    print(
        f"physics steps x joints at a torque cap: C {dt} s {100 * cap_c:.2f} %, C 2 ms {100 * cap_c2:.2f} %,"
        f" sim target {100 * cap_t:.2f} %"
    )
    print(f"({time.time() - t0:.0f} s)")


if __name__ == "__main__":
    main()
