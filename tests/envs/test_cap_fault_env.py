"""``terminate_on_cap_fault``: the env ends an episode on the deploy supervisor's saturation fault.

The nominal reach env with the option on; the left wrist yaw is held still by a passive damping of
1e4 N*m*s/rad put into the model (so a command away from it asks more than its 4 N*m cap for as long as
the command stays away), and the policy's action on that joint steps to +1 for 10 steps, to 0.05 for 20
(about 2 N*m once the 3 Hz action filter has settled: the run at the cap breaks and the dwell restarts),
then +1 until the episode ends. Two steps of action latency: the motor applies the command of two steps
ago, while the deploy supervisor checks the one the runtime sends now, and so must the termination, with
the torque the motor reports as the second half of the test. The time at the cap is worked out here from
the states the env reached: the MIT demand ``Kp (q_cmd - q) - Kd dq`` of each step's sent command (the
filtered action, no latency) at the state the step starts from must reach the cap, and the motor's torque
(the same law for the command sent two steps earlier, clipped to the cap) must reach 0.8 of it
(``quality.metrics.at_cap`` with ``reported``), summed over unbroken runs of 20 ms steps; the episode must
end on the 26th step of an unbroken run (0.52 s > 0.5 s) and not before. The first two steps do not count:
the sent command asks 12.6 N*m while the motor still applies the reset's hold and reports nothing (a lead,
not a saturated joint).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from bar_policy import envs

CAP_DWELL_TICKS = 26  # the first step whose unbroken time at the cap, 26 x 0.02 s, is past 0.5 s


def test_the_episode_ends_on_the_26th_step_at_the_cap_and_a_break_restarts_the_count() -> None:
    config = envs.apply_overrides(
        envs.nominal_config(envs.default_config("LiteReach")),
        ["terminate_on_cap_fault=true", "actuator.latency_steps=(2, 2)"],
    )
    env = envs.load("LiteReach", config=config)
    j = env.robot.joint_names.index("left_wrist_yaw")
    dof = int(np.asarray(env._index.dof)[j])
    model = env.mjx_model
    model = model.replace(dof_damping=model.dof_damping.at[dof].set(1e4))
    reset = jax.jit(env.reset)
    step = jax.jit(env.step_with_model)
    s = reset(jax.random.PRNGKey(3))
    np.testing.assert_array_equal(np.asarray(s.info["cap_dwell"]), 0.0)
    cap = float(env.robot.torque_cap[j])
    assert cap == 4.0  # the wrist's firmware cap (docs: lite-model), N*m
    lower, upper = float(env.robot.lower[j]), float(env.robot.upper[j])
    pattern = [1.0] * 10 + [0.05] * 20 + [1.0] * 40
    dwell_hand, done_at, margins, rep_margins, dwells, sent_hist = 0.0, None, [], [], [], [0.0, 0.0]
    for k, a_j in enumerate(pattern):
        q0 = float(env.robot_q(s.data)[j])
        dq0 = float(env.robot_dq(s.data)[j])
        kp, kd = float(env.robot.kp[j]), float(env.robot.kd[j])  # the file's gains, as the runtime sends
        action = jnp.zeros(env.action_size).at[j].set(a_j)
        s = step(model, s, action)
        sent = float(s.info["last_act"][j])  # after the env's action filter, before the latency
        q_cmd = float(np.clip(env.default_pose[j] + env.action_scale[j] * sent, lower, upper))
        demand = kp * (q_cmd - q0) - kd * dq0  # dq_cmd = 0, tau_ff = 0, no encoder offset (nominal)
        applied = sent_hist[-2]  # two steps of latency: the reset's hold (action 0) for the first two
        sent_hist.append(sent)
        q_app = float(np.clip(env.default_pose[j] + env.action_scale[j] * applied, lower, upper))
        reported = float(np.clip(kp * (q_app - q0) - kd * dq0, -cap, cap))
        margins.append(abs(abs(demand) - cap) / cap)
        if abs(reported) > 0.01 * cap:
            rep_margins.append(abs(abs(reported) - 0.8 * cap) / cap)
        dwell_hand = dwell_hand + 0.02 if abs(demand) >= cap and abs(reported) >= 0.8 * cap else 0.0
        dwells.append(dwell_hand)
        # float32 sums of 0.02 against float64: 26 additions, well inside 1e-5 s
        np.testing.assert_allclose(float(s.info["cap_dwell"][j]), dwell_hand, rtol=0, atol=1e-5)
        others = np.delete(np.asarray(s.info["cap_dwell"]), j)
        assert np.all(others == 0.0), f"step {k}: another joint at its cap: {others}"
        if float(s.done) > 0:
            done_at = k
            break
    # The boolean at-cap test is exact only away from the cap: the command's 16-bit quantisation moves the
    # demand by at most Kp * 4e-4 rad = 0.02 N*m (0.5 % of 4 N*m); every step here is further than 1 %.
    assert min(margins) > 0.01, f"a step's demand within 1 % of the cap: {min(margins):.4f}"
    # The reported torque's test likewise, against its 0.8 x cap level: outside the 0.5 % quantisation.
    assert min(rep_margins) > 0.006, f"a step's torque within 0.6 % of 0.8 x cap: {min(rep_margins):.4f}"
    assert dwells[:3] == [0.0, 0.0, 0.02], "a lead over the cap counts once the motor reports it"
    assert done_at is not None, "the episode never ended on the cap"
    broke = [k for k in range(1, len(dwells)) if dwells[k] == 0.0 and dwells[k - 1] > 0.0]
    assert broke and broke[0] < 30, "the 0.05 phase must bring the demand under the cap"
    assert max(dwells[: broke[0]]) < 0.5, "the first run must be too short to end the episode"
    assert done_at > 30, "the episode must end in the second run at the cap"
    assert round(dwell_hand / 0.02) == CAP_DWELL_TICKS, f"ended after {dwell_hand:.2f} s at the cap"


def test_off_by_default_the_state_has_no_dwell_and_the_layout_is_unchanged() -> None:
    config = envs.nominal_config(envs.default_config("LiteReach"))
    assert config.terminate_on_cap_fault is False
    env = envs.load("LiteReach", config=config)
    s = jax.jit(env.reset)(jax.random.PRNGKey(0))
    assert "cap_dwell" not in s.info
