"""The two-tick action delay on the tracker's held-out clips: what the motors do, what the supervisor sees.

Every tracker file so far ends two held-out clips (random-s1-001, -005) of the suite's ``action delay 2
ticks`` row in a ``torque_saturation`` fault on a wrist yaw (docs/robust_training.md, "The tracker with the
error average"). A scripted player with no feedback separates the robot from the rule: each tick it sends the
clip's reference 4 ticks ahead (the 2 ticks of delay plus 2 for the arm's own lag, ``Kd / Kp`` = 40 ms at
Kp 50, Kd 2), at the firmware's Kp and Kd, ``dq_cmd = 0``, on the perturbed sim target the suite runs
(``action_delay_ticks=2``).

- The motors: no physics step of any of the 12 clips has a joint at its torque cap (the firmware's torque,
  which the target reports clipped; measured 2026-12-03, 2-core CPU: at most 47 % of a cap, on
  random-s1-001; mean |q - q_ref| 0.009-0.020 rad, the same player's with 2 ticks of lead and no delay).
- The demand alone: the command the runtime sends now at the state it has just read, not the older
  command the motor applies, so the lead that keeps the delayed arm on its reference reads as demand. On
  random-s1-001 and -005 it is over the cap for 0.90 s and 0.62 s (up to 1.51 and 1.17 caps): a fault
  on both under a demand-only rule; under 1 cap on the other ten.
- The supervisor (``deploy.safety``) counts a joint at its cap only while its motor also reports at least
  ``saturation_reported_fraction`` (0.8) of the cap (``quality.metrics.at_cap``): no clip trips it.

So a demand-only rule faulted this row on a lead the delay requires, with no motor saturated; the rule
with the motor's reported torque does not, and still faults a joint that is held at its cap
(``test_deploy_safety.py``). The training env's ``terminate_on_cap_fault`` applies the same rule.
"""

from __future__ import annotations

import numpy as np

from bar_policy.deploy.safety_checks import CapDwell
from bar_policy.deploy.safety_config import SafetyConfig
from bar_policy.deploy.targets.perturbed import sim_target
from bar_policy.deploy.targets.sim import SimConfig
from bar_policy.robot.mit import MitCommand, mit_torque
from bar_policy.robot.perturb_spec import parse_perturbation
from bar_policy.tasks.track.evaluate import eval_clips

DELAY_TICKS = 2
LEAD_TICKS = DELAY_TICKS + 2  # the delay plus Kd / Kp = 0.04 s, in 20 ms ticks
SUBSTEPS = 10  # 2 ms physics steps per 20 ms tick
TICK_S = 0.02


def test_a_led_reference_never_saturates_a_motor_nor_trips_the_supervisor() -> None:
    _, clips = eval_clips("heldout")
    assert len(clips) == 12
    target = sim_target(
        "arms", SimConfig(), scene=None, perturbation=parse_perturbation(f"action_delay_ticks={DELAY_TICKS}")
    )
    robot, safety = target.robot, SafetyConfig()
    cap, n = robot.torque_cap, robot.num_joints
    motor_peak: dict[str, float] = {}
    tripped: set[str] = set()
    demand_only: set[str] = set()
    for clip in clips:
        ref = clip.joint_pos.astype(np.float64)
        frames = ref.shape[0]
        target.reset(q=ref[0])
        level = safety.saturation_fraction * cap
        dwell = CapDwell(level, safety.saturation_time, safety.saturation_reported_fraction * cap)
        demand_dwell = CapDwell(level, safety.saturation_time)
        peak = np.zeros(n)
        for k in range(frames):
            state = target.read_state()
            q_cmd = np.clip(ref[min(k + LEAD_TICKS, frames - 1)], robot.lower, robot.upper)
            cmd = MitCommand(q_cmd, np.zeros(n), robot.kp, robot.kd, np.zeros(n))
            demand = mit_torque(cmd, state.q, state.dq)
            if dwell.update(demand, TICK_S, state.tau).size:  # the supervisor's rule
                tripped.add(clip.name)
            if demand_dwell.update(demand, TICK_S).size:
                demand_only.add(clip.name)
            target.write_command(cmd)
            for _ in range(SUBSTEPS):
                target.step()
                # read_state's torque is the firmware's, clipped to the cap: at the cap means equal to it
                peak = np.maximum(peak, np.abs(target.read_state().tau) / cap)
        motor_peak[clip.name] = float(peak.max())
    at_cap = {name: share for name, share in motor_peak.items() if share >= 1.0 - 1e-9}
    assert not at_cap, f"led references that met a torque cap under {DELAY_TICKS} ticks of delay: {at_cap}"
    # The fastest wrist clip works a motor hard without saturating it (measured 47 % of a cap).
    assert motor_peak["random-s1-001"] > 0.3
    assert demand_only == {"random-s1-001", "random-s1-005"}
    assert not tripped
