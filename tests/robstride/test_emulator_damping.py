"""The emulator's motors damp as the firmware's fast loop does, not as a 500 Hz law.

The firmware evaluates ``tau = Kp (q_cmd - q) + Kd (dq_cmd - dq) + tau_ff`` inside its own control loop,
far faster than the emulator's 2 ms physics step. The reference here is that law written to C MuJoCo every
0.1 ms (10 kHz, the same model): there a wrist's fast mode, inertia ``mu`` ~ 0.002-0.005 kg*m^2 (docs/
physics.md: the armature 0.002 plus a little link inertia), decays as ``exp(-x)`` per 2 ms step, ``x = h Kd
/ mu`` = 0.8-2, that is 0.14-0.45, without changing sign. Per step the emulator's ``trapezoid`` (the
default) decays it by ``(1 - x/2) / (1 + x/2)``, 0.43-0: within 0.135 of the reference over that range;
``implicit`` by ``1 / (1 + x)``, 0.56-0.33; ``explicit`` by ``1 - x``, 0.2 to -1.0: at the wrist's smallest
inertia it flips the velocity's sign every step (ringing a motor does not have).
"""

from __future__ import annotations

import itertools

import mujoco
import numpy as np
import pytest

from bar_policy.robot.constants import load_robot
from bar_policy.robot.mit import MitCommand, firmware_torque, wire_ranges
from bar_policy.robot.scene import PHYSICS_DT, load_model
from bar_policy.robstride.emulator import RobstrideEmulator
from bar_policy.robstride.emulator_physics import EMULATOR_DAMPING

from .helpers import command_position

ROBOT = load_robot("arms")
POSE = ROBOT.pose("piano_ready")
KICK = 1.0  # rad/s given to one wrist joint at rest, the rest held at the pose
STEPS = 5  # 2 ms physics steps observed
MU = (0.002, 0.005)  # the wrists' effective inertia range, kg*m^2 (module docstring)
_channel = itertools.count()


def _emulator_velocities(joint: int, damping: str) -> np.ndarray:
    """The kicked joint's velocity after each of ``STEPS`` emulator steps, every motor holding the pose."""
    k = next(_channel)
    channels = {"can0": f"damping-test{k}-can0", "can1": f"damping-test{k}-can1"}
    emu = RobstrideEmulator(ROBOT, channels, initial_q=POSE, damping=damping)
    try:
        command_position(emu, ROBOT, POSE)
        emu.data.qvel[emu.index.dof[joint]] = KICK
        out = []
        for _ in range(STEPS):
            with emu._lock:
                emu._step(1)
            out.append(float(emu.data.qvel[emu.index.dof[joint]]))
        return np.array(out)
    finally:
        emu.close()


def _firmware_velocities(joint: int, h: float = 1e-4) -> np.ndarray:
    """The same kick under the law evaluated every ``h`` s (the firmware's loop), sampled every 2 ms."""
    m = load_model("arms")
    m.opt.timestep = h
    d = mujoco.MjData(m)
    d.qpos[:] = POSE
    d.qvel[joint] = KICK
    cmd = MitCommand.position(POSE, ROBOT.kp, ROBOT.kd)
    ranges = wire_ranges(ROBOT.models)
    out = []
    for _ in range(STEPS):
        for _ in range(round(PHYSICS_DT / h)):
            d.qfrc_applied[:] = firmware_torque(
                cmd, d.qpos, d.qvel, ranges, ROBOT.torque_cap, quantize_wire=False
            )
            mujoco.mj_step(m, d)
        out.append(float(d.qvel[joint]))
    return np.array(out)


def test_unknown_damping_is_refused_with_the_choices() -> None:
    valid = r"valid: \['trapezoid', 'implicit', 'explicit'\]"
    with pytest.raises(ValueError, match=r"unknown emulator damping 'rk4'; " + valid):
        RobstrideEmulator(ROBOT, {"can0": "x-can0", "can1": "x-can1"}, damping="rk4")


@pytest.mark.parametrize("name", ["left_wrist_yaw", "left_wrist_pitch", "right_wrist_roll"])
def test_a_kicked_wrist_decays_as_under_the_firmware_loop(name: str) -> None:
    j = ROBOT.joint_names.index(name)
    assert ROBOT.kd[j] == 2.0  # the wrists' gain the bounds below are worked out for, N*m*s/rad
    fast, slow = PHYSICS_DT * ROBOT.kd[j] / np.array(MU)  # h Kd / mu at the smallest and the largest inertia
    firmware = _firmware_velocities(j)
    default = _emulator_velocities(j, EMULATOR_DAMPING[0])
    implicit = _emulator_velocities(j, "implicit")
    explicit = _emulator_velocities(j, "explicit")
    # The firmware loop: a monotone decay, the first step within the single-mode bounds (the joint's
    # friction loss, 0.1 N*m over mu, takes at most 0.1 / 0.002 * 0.002 = 0.1 rad/s more).
    assert np.all(firmware > 0) and np.all(np.diff(firmware) < 0)
    assert np.exp(-fast) - 0.1 <= firmware[0] / KICK <= np.exp(-slow)
    # The default is the trapezoid: within the single mode's largest gap to exp(-x) over x in [0.8, 2]
    # (0.135, at x = 2) on every step.
    assert EMULATOR_DAMPING[0] == "trapezoid"
    gap = np.abs(default - firmware).max()
    assert gap <= 0.135 * KICK
    # Implicit: monotone too, its first factor within 1 / (1 + x) less the friction's 0.1, farther off.
    assert np.all(implicit > 0) and np.all(np.diff(implicit) < 0)
    assert 1 / (1 + fast) - 0.1 <= implicit[0] / KICK <= 1 / (1 + slow)
    assert gap < np.abs(implicit - firmware).max()
    # The 500 Hz law: the first step overshoots through zero, the farthest of the three.
    assert explicit[0] < 0
    assert np.abs(implicit - firmware).max() < np.abs(explicit - firmware).max()
