"""The saturation rule through the CAN code: a weakened motor that cannot hold its joint still faults.

The supervisor counts a joint at its cap while the demand reaches it and the torque the motor reports
reaches 0.8 of it (``quality.metrics.at_cap``). The reading a Robstride sends is its firmware's torque (the
current times the nominal torque constant), so a motor weaker than its rating reads its cap while it
delivers less. Here the lockstep emulator behind the python-can ``virtual`` bus (16-bit feedback codec)
carries a 1 kg point mass at each fingertip. From C MuJoCo, the wrist pitch's gravity torque at the
policy's default pose is 2.31 N*m: inside the 4 N*m cap, beyond half of it. At full strength the wrists
hold the pose for the whole run; at ``strength=0.5`` (2 N*m delivered at the cap) they cannot, the hands
fall, the demand passes the cap and the motors report it: a ``torque_saturation`` fault on both wrist
pitches, the reading the cap within the codec's step.
"""

from __future__ import annotations

import mujoco
import numpy as np
from policy_factory import make_policy_file

from bar_policy.deploy.policy import load_policy
from bar_policy.deploy.runtime import Runtime, RuntimeConfig
from bar_policy.deploy.safety import SafetyConfig
from bar_policy.deploy.targets.emulated import EmulatedBusTarget
from bar_policy.robot.constants import load_robot
from bar_policy.robot.perturb_spec import parse_perturbation
from bar_policy.tasks.reach.commands import SampledCommands

PAYLOAD = "payload_kg=1.0"
WRISTS = ("left_wrist_pitch", "right_wrist_pitch")


def _run(policy, spec: str):
    target = EmulatedBusTarget("arms", 0.02, perturbation=parse_perturbation(spec))
    q0 = np.asarray(policy.default_joint_pos, dtype=float)
    model, index = target.emu.model, target.emu.index
    data = mujoco.MjData(model)
    data.qpos[np.asarray(index.qpos)] = q0
    mujoco.mj_forward(model, data)
    gravity = data.qfrc_bias[np.asarray(index.dof)].copy()  # static holding torque at q0, N*m
    try:
        target.reset(q0)
        cfg = RuntimeConfig(duration=3.0, start_mode="policy", safety=SafetyConfig(ramp_time=0.0))
        runtime = Runtime(policy, target, SampledCommands(policy.obs_manager.command_names, seed=0), cfg)
        return gravity, runtime.run()
    finally:
        target.close()


def test_a_weak_wrist_that_cannot_hold_its_payload_faults_through_the_bus(tmp_path) -> None:
    policy = load_policy(make_policy_file(tmp_path / "zero.onnx"))  # action 0: hold the default pose
    robot = load_robot("arms")
    gravity, strong = _run(policy, PAYLOAD)
    cap = 4.0  # the wrists' firmware cap, N*m (docs: lite-model)
    wrist_idx = [robot.joint_names.index(w) for w in WRISTS]
    assert np.all(robot.torque_cap[wrist_idx] == cap)
    held = np.abs(gravity[wrist_idx])
    assert np.all((held > 0.5 * cap) & (held < cap)), held  # 2.31 N*m: strength 1 holds, 0.5 cannot
    assert strong.fault_count == 0 and strong.end_reason.startswith("duration reached"), strong.end_reason

    _, weak = _run(policy, PAYLOAD + ",strength=0.5")
    assert weak.fault_count == 1 and weak.end_reason.startswith("fault torque_saturation"), weak.end_reason
    for w in WRISTS:
        assert w in weak.end_reason
    # The reading is the firmware's clipped torque through the 16-bit codec: the cap to two decimals.
    assert weak.end_reason.count("4.00 reported, cap 4") == 2, weak.end_reason
