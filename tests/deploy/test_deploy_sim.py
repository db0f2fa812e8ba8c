"""The C MuJoCo sim target: the exact MIT law through qfrc_applied, stepping, video; runtime parity on it."""

from __future__ import annotations

import logging
import os
import subprocess
import sys
import textwrap

import numpy as np
import pytest

from bar_policy.deploy.policy import load_policy
from bar_policy.deploy.runtime import Runtime, RuntimeConfig
from bar_policy.deploy.safety import SafetyConfig
from bar_policy.deploy.targets.base import TargetError
from bar_policy.deploy.targets.sim import SimConfig, SimTarget, note_physics_dt
from bar_policy.robot.kinematics import Kinematics
from bar_policy.robot.mit import MitCommand, firmware_torque, wire_ranges
from bar_policy.tasks.reach.commands import SampledCommands

DEFAULT = np.array([0.3, -1.0, 0.0, -1.7, -1.2, 0.0, 0.3, 0.3, 1.0, 0.0, -1.7, 1.2, 0.0, -0.3])
# Per-joint Robstride models of the arms (lite-model.md 2): rs-02 shoulder pitch, rs-00, rs-05 wrists.
MODELS = ["rs-02", "rs-00", "rs-00", "rs-00", "rs-05", "rs-05", "rs-05"] * 2
V_MAX = {"rs-00": 33.0, "rs-02": 44.0, "rs-05": 50.0}
T_MAX = {"rs-00": 14.0, "rs-02": 17.0, "rs-05": 5.5}
CAP = np.array([17.0, 14, 14, 14, 4, 4, 4] * 2)
"""Firmware torque caps (torque_limit), N*m."""


def _wire(x, lo, hi):
    """Robstride float_to_uint then uint_to_float, written out: clamp, truncate to 16 bits, decode."""
    x = np.clip(x, lo, hi)
    u = np.floor((x - lo) * (65535.0 / (hi - lo)))
    return u * ((hi - lo) / 65535.0) + lo


def _hand_torque(cmd, q, dq):
    p = np.full(14, 4 * np.pi)
    v = np.array([V_MAX[m] for m in MODELS])
    t = np.array([T_MAX[m] for m in MODELS])
    qc, dqc = _wire(cmd.q, -p, p), _wire(cmd.dq, -v, v)
    kp, kd = _wire(cmd.kp, 0.0, 500.0), _wire(cmd.kd, 0.0, 5.0)
    ff = _wire(cmd.tau_ff, -t, t)
    return np.clip(kp * (qc - q) + kd * (dqc - dq) + ff, -CAP, CAP)


def test_sim_applies_the_quantised_mit_law_through_qfrc_applied():
    sim = SimTarget("arms", SimConfig(damping="explicit"))
    rng = np.random.default_rng(3)
    q = DEFAULT + rng.uniform(-0.2, 0.2, 14)
    dq = rng.uniform(-1.0, 1.0, 14)
    sim.reset(q, dq)
    cmd = MitCommand(
        q=DEFAULT + rng.uniform(-0.1, 0.1, 14),
        dq=rng.uniform(-0.5, 0.5, 14),
        kp=np.full(14, 20.0),
        kd=np.full(14, 1.3),
        tau_ff=rng.uniform(-0.5, 0.5, 14),
    )
    cmd = cmd._replace(q=cmd.q.copy())
    cmd.q[4] += 3.0  # wrist yaw 3 rad off: 20 N*m/rad * 3 rad = 60 N*m, far above its 4 N*m cap
    sim.write_command(cmd)
    sim.step()
    applied = sim.data.qfrc_applied[:14].copy()
    expected = _hand_torque(cmd, q, dq)
    np.testing.assert_allclose(applied, expected, rtol=1e-12, atol=1e-12)
    assert applied[4] == 4.0  # at the firmware cap
    # Bit-for-bit the shared actuator model.
    ranges = wire_ranges(MODELS)
    np.testing.assert_array_equal(applied, firmware_torque(cmd, q, dq, ranges, CAP))
    # The law is re-evaluated every physics step at the new state.
    q1, dq1 = sim.data.qpos[:14].copy(), sim.data.qvel[:14].copy()
    sim.step()
    np.testing.assert_allclose(sim.data.qfrc_applied[:14], _hand_torque(cmd, q1, dq1), rtol=1e-12, atol=1e-12)
    np.testing.assert_array_equal(sim.read_state().tau, sim.data.qfrc_applied[:14])


def test_implicit_damping_keeps_the_force_and_moves_kd_into_the_integrator():
    sim = SimTarget("arms", SimConfig(damping="implicit"))
    rng = np.random.default_rng(4)
    q = DEFAULT + rng.uniform(-0.2, 0.2, 14)
    dq = rng.uniform(-1.0, 1.0, 14)
    sim.reset(q, dq)
    cmd = MitCommand(DEFAULT.copy(), np.zeros(14), np.full(14, 20.0), np.full(14, 1.3), np.zeros(14))
    cmd.q[4] += 3.0  # saturated wrist yaw: no implicit damping there
    sim.write_command(cmd)
    sim.step()
    tau = _hand_torque(cmd, q, dq)
    kd_wire = np.floor(1.3 * 65535 / 5.0) * 5.0 / 65535  # Kd after the 16-bit wire
    d_law = np.where(np.abs(tau) < CAP, kd_wire, 0.0)
    assert d_law[4] == 0.0 and d_law[0] == kd_wire
    np.testing.assert_allclose(sim.model.dof_damping[:14], d_law, rtol=0, atol=1e-15)
    np.testing.assert_allclose(sim.data.qfrc_applied[:14], tau + d_law * dq, rtol=1e-12, atol=1e-12)
    # Applied + passive (-D dq, from the step's forward pass at the old state) = the firmware torque.
    np.testing.assert_allclose(sim.data.qfrc_applied[:14] + sim.data.qfrc_passive[:14], tau, atol=1e-12)
    np.testing.assert_array_equal(sim.read_state().tau, tau)


def test_training_damping_follows_the_randomisation_record():
    from bar_policy.deploy.targets.sim import training_damping

    assert training_damping({"actuator": {"damping": "explicit"}}) == "explicit"
    assert training_damping({"actuator": {"latency_steps": [0, 1]}}) == "implicit"
    assert training_damping({}) == "implicit"


def test_advance_steps_whole_physics_steps_only():
    sim = SimTarget("arms")
    sim.advance(0.02)
    assert sim.now() == pytest.approx(0.02, abs=1e-12)  # 10 steps of 2 ms
    with pytest.raises(TargetError, match=r"whole number of 0\.002 s physics steps"):
        sim.advance(0.003)
    with pytest.raises(TargetError, match="not finite"):
        sim.write_command(MitCommand.damping(np.full(14, np.nan), 1.0))
    with pytest.raises(TargetError, match="shape"):
        sim.write_command(MitCommand.damping(np.zeros(13), 1.0))


def test_zero_torque_falls_and_pd_holds():
    sim = SimTarget("arms")
    sim.write_command(MitCommand.zero_torque(14))
    sim.advance(0.5)
    sagged = np.abs(sim.read_state().q - DEFAULT).max()
    assert sagged > 0.1  # nothing holds the arms against gravity
    sim.reset()
    sim.write_command(MitCommand.position(DEFAULT, np.full(14, 50.0), np.full(14, 2.0)))
    sim.advance(1.0)
    s = sim.read_state()
    assert np.abs(s.q - DEFAULT).max() < 0.1 and np.abs(s.dq).max() < 0.05


def test_runtime_on_sim_builds_the_observation_from_the_measured_state(make_policy, tmp_path):
    w = np.zeros((54, 14))
    w[14:28, :] = -0.05 * np.eye(14)  # damp on joint_vel: actions = -0.05 * 0.1 * dq
    pol = load_policy(make_policy(weight=w, bias=0.1))
    sim = SimTarget("arms")
    cmds = SampledCommands(pol.obs_manager.command_names, seed=5)
    rt = Runtime(
        pol,
        sim,
        cmds,
        RuntimeConfig(duration=0.5, start_mode="policy", safety=SafetyConfig(ramp_time=0.0)),
        log_dir=tmp_path,
    )
    res = rt.run()
    assert res.ticks == 25 and res.fault_count == 0
    from bar_policy.deploy.log.read import load_log

    a, _ = load_log(res.log_path)
    kin = Kinematics("arms")
    om = pol.obs_manager
    prev = np.zeros(14, np.float32)
    for k in range(25):
        left, right = kin.fingertips(a["q"][k])
        expected = om.compute(
            {
                "joint_pos": a["q"][k],
                "joint_vel": a["dq"][k],
                "actions": prev,
                "fingertip_pos_left": left,
                "fingertip_pos_right": right,
                "target_pos_left": a["target_pos_left"][k],
                "target_pos_right": a["target_pos_right"][k],
            }
        )
        np.testing.assert_array_equal(a["obs"][k], expected)
        np.testing.assert_array_equal(a["action"][k], pol(expected))
        prev = a["action"][k]
        np.testing.assert_allclose(
            a["q_cmd"][k], DEFAULT + 0.25 * a["action"][k].astype(np.float64), atol=1e-12
        )
    # The measured q moved toward q_cmd (PD in the sim): the first arm joint starts at rest.
    np.testing.assert_array_equal(a["dq"][0], 0.0)


_GL_PROBE = textwrap.dedent(
    """
    import mujoco
    from bar_policy.robot.mjcf import load_model
    r = mujoco.Renderer(load_model("arms"), 48, 64)
    r.close()
    """
)


def _gl_env() -> dict[str, str]:
    return os.environ | {"MUJOCO_GL": "egl", "EGL_PLATFORM": "surfaceless"}


@pytest.fixture(scope="module")
def egl_available() -> bool:
    probe = subprocess.run([sys.executable, "-c", _GL_PROBE], env=_gl_env(), capture_output=True, timeout=120)
    return probe.returncode == 0


def test_headless_video_writes_frames(tmp_path, egl_available):
    if not egl_available:
        pytest.skip("no EGL offscreen OpenGL on this machine (MUJOCO_GL=egl fails)")
    out = tmp_path / "run.gif"
    code = textwrap.dedent(
        f"""
        from bar_policy.deploy.targets.sim import SimConfig, SimTarget
        import imageio.v3 as iio
        sim = SimTarget("arms", SimConfig(video_path={str(out)!r}, video_fps=25.0, video_size=(48, 64)))
        with sim:
            for _ in range(25):
                sim.advance(0.02)
        frames = iio.imread(sim.video_path)
        print(frames.shape)
        """
    )
    r = subprocess.run(
        [sys.executable, "-c", code], env=_gl_env(), capture_output=True, text=True, timeout=300
    )
    assert r.returncode == 0, r.stderr[-2000:]
    # 0.5 s at 25 frames/s: frames at the first step at or after 0, 0.04, ..., 0.48 s -> 13 frames.
    assert "(13, 48, 64, 3)" in r.stdout


def test_video_without_opengl_fails_with_a_clear_error(tmp_path):
    code = textwrap.dedent(
        f"""
        from bar_policy.deploy.targets.sim import SimConfig, SimTarget
        from bar_policy.deploy.targets.base import TargetError
        sim = SimTarget("arms", SimConfig(video_path={str(tmp_path / "x.gif")!r}))
        try:
            sim.start()
        except TargetError as e:
            print("ERROR:", e)
        else:
            print("RENDERED")
        """
    )
    env = {k: v for k, v in os.environ.items() if k not in ("MUJOCO_GL", "DISPLAY", "WAYLAND_DISPLAY")}
    r = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=120)
    if "RENDERED" in r.stdout:
        pytest.skip("a display / GL context is available here, so the no-GL path cannot be exercised")
    assert "ERROR: headless video needs an OpenGL context" in r.stdout, r.stdout + r.stderr[-2000:]
    assert "MUJOCO_GL=egl" in r.stdout


def test_sim_config_validates():
    with pytest.raises(ValueError, match=r"\.mp4 or \.gif"):
        SimConfig(video_path="out.avi")
    with pytest.raises(ValueError, match="video_fps"):
        SimConfig(video_fps=0.0)


def test_a_coarser_training_step_is_noted_at_info_on_the_sim_target_only(caplog):
    """A file trained at 4 ms (the gpu preset) on the 2 ms sim target: one INFO line naming both steps; a
    file at the sim's own step or one that does not say: nothing. Not a warning: the gate judges at 2 ms."""
    with caplog.at_level(logging.DEBUG, logger="bar_policy.deploy.targets.sim"):
        note_physics_dt(0.004)
        note_physics_dt(0.002)
        note_physics_dt(None)
    assert [(r.levelname, r.getMessage()) for r in caplog.records] == [
        ("INFO", "policy was trained with physics dt 0.004 s; the sim target steps 0.002 s")
    ]
