"""The load-inertia feed-forward (``deploy.load_inertia``): its torque against C MuJoCo's mass matrix, its
bounds, what it does to a loaded arm, and the runtime's use of it.

Expected values: a point mass ``m`` on a hand adds ``m J_p^T J_p`` to the robot's joint-space inertia
(``J_p``: the point's translational Jacobian), which C MuJoCo's composite-rigid-body ``mj_fullM`` of the
perturbed model holds independently, plus the payload sphere's own rotational inertia ``2/5 m r^2``
(r = ``PAYLOAD_RADIUS``), the tolerance. The reference arm's acceleration is a separately built nominal
sim target's under the same command.
"""

from __future__ import annotations

from pathlib import Path

import mujoco
import numpy as np
import pytest

from bar_policy.deploy.load_inertia import LoadInertia
from bar_policy.deploy.targets.perturbed import sim_target
from bar_policy.deploy.targets.sim import SimConfig, SimTarget
from bar_policy.robot.constants import FINGERTIP_SITES, load_robot
from bar_policy.robot.index import RobotIndex
from bar_policy.robot.mit import MitCommand
from bar_policy.robot.perturb import PAYLOAD_RADIUS
from bar_policy.robot.perturb_spec import parse_perturbation
from bar_policy.robot.scene import load_model

ROBOT = load_robot("arms")
DT = 0.02
LEFT, RIGHT = np.arange(7), np.arange(7, 14)
PIANO = Path(__file__).resolve().parents[2] / "checkpoints" / "lite_piano_arms.onnx"


def _command(q: np.ndarray) -> MitCommand:
    """A position command at ``q`` with the robot's Kp, Kd."""
    return MitCommand.position(q, ROBOT.kp, ROBOT.kd)


def _mass_matrix(model: mujoco.MjModel, q: np.ndarray) -> np.ndarray:
    """C MuJoCo's joint-space inertia of ``model``'s robot joints at ``q``, (14, 14)."""
    d = mujoco.MjData(model)
    idx = RobotIndex.from_model(model, ROBOT.joint_names)
    d.qpos[idx.qpos] = q
    mujoco.mj_forward(model, d)
    full = np.zeros((model.nv, model.nv))
    mujoco.mj_fullM(model, d, full)
    return full[np.ix_(idx.dof, idx.dof)]


def test_feedforward_is_the_payloads_inertia_times_the_reference_arms_acceleration():
    """One tick from piano_ready toward a pose 20-40 mrad away: the feed-forward at a measured pose ``q``
    (not the reference's) is ``Delta M(q) a_ref`` per arm, ``Delta M`` the perturbed model's mass matrix
    less the nominal one (0.5 kg at each fingertip, scaled to each hand's mass: it is linear in it), and
    ``a_ref`` a nominal sim target's mean acceleration over the tick under the same command."""
    q0 = np.asarray(ROBOT.pose("piano_ready"))
    goal = q0 + 0.2 * np.array([0.1, -0.1, 0.15, 0.2, -0.1, 0.15, -0.2] * 2)
    cmd = _command(goal)
    ff = LoadInertia("arms", DT)
    ff.start(q0, np.zeros(14))
    q_meas = q0 + 0.05
    masses = np.array([0.5, 0.3])
    out = ff.step(cmd, q_meas, masses)

    ref = SimTarget("arms", SimConfig())
    ref.reset(q0)
    ref.write_command(cmd)
    ref.advance(DT)
    acc = ref.read_state().dq / DT
    assert np.max(np.abs(acc)) > 10.0  # a real step: rad/s^2
    assert ff.clip.clip_count == 0
    loaded = load_model("arms", _payload_scene(0.5))
    dm = _mass_matrix(loaded, q_meas) - _mass_matrix(load_model("arms"), q_meas)
    for arm, m in ((LEFT, 0.5), (RIGHT, 0.3)):
        expected = (m / 0.5) * dm[np.ix_(arm, arm)] @ acc[arm]
        # The sphere's rotational inertia I = 2/5 m r^2 is in dm, not in the point-mass feed-forward:
        # |J_r^T I J_r a| <= 3 I sum|a| (rotation Jacobian entries within +-1).
        tol = 3 * 0.4 * m * PAYLOAD_RADIUS**2 * np.sum(np.abs(acc[arm]))
        np.testing.assert_allclose(out[arm], expected, rtol=0, atol=tol)
        assert np.max(np.abs(expected)) > 20 * tol  # the check is not swamped by its tolerance
    assert ff.steps == 1 and ff.massless_count == 0
    np.testing.assert_allclose(ff.reference.read_state().q, ref.read_state().q, rtol=0, atol=1e-12)
    assert ff.max_deviation_rad == pytest.approx(0.05)  # q_meas against the reference's start, q0


def _payload_scene(kg: float):
    """The scene edit of ``kg`` at each fingertip (``--perturb payload_kg=...``)."""
    from bar_policy.robot.perturb import perturbed_scene

    return perturbed_scene(parse_perturbation(f"payload_kg={kg},payload_at=fingertip"))


def test_a_hand_without_mass_gets_nothing_and_the_caps_clip_counted():
    """A hand whose mass reads 0 or below gets no feed-forward (counted per hand-tick); a feed-forward
    beyond a firmware cap is clipped to it and counted."""
    q0 = np.asarray(ROBOT.pose("piano_ready"))
    ff = LoadInertia("arms", DT)
    ff.start(q0, np.zeros(14))
    out = ff.step(_command(q0 + 0.3), q0, np.array([0.0, -0.1]))
    assert np.all(out == 0.0) and ff.massless_count == 2
    out = ff.step(_command(q0 - 0.3), q0, np.array([100.0, 100.0]))
    cap = np.asarray(ROBOT.torque_cap)
    assert np.all(np.abs(out) <= cap) and ff.clip.clip_count > 0
    assert np.any(np.isclose(np.abs(out), cap))
    rec = ff.record()
    assert rec["steps"] == 2 and rec["massless_hand_ticks"] == 2
    assert rec["clipped_joint_evaluations"] == ff.clip.clip_count


def _follow(feedforward: bool) -> tuple[np.ndarray, np.ndarray]:
    """The loaded (0.5 kg at each fingertip) and the nominal arm's q over 0.5 s of a filtered step.

    The command moves 0.1-0.2 rad per joint through the piano policy's 3 Hz first-order action filter,
    as a policy's step does.

    The payload's weight is cancelled exactly each tick (``m g J_z^T`` of the fingertip at the measured
    q), so what is left is its inertia; with ``feedforward`` the load-inertia term is added too.
    """
    q0 = np.asarray(ROBOT.pose("piano_ready"))
    step = np.array([0.15, -0.1, 0.1, 0.2, -0.15, 0.2, -0.2] * 2)
    alpha = 1.0 - np.exp(-2 * np.pi * 3.0 * DT)
    nominal = SimTarget("arms", SimConfig())
    loaded = sim_target("arms", SimConfig(), scene=None, perturbation=parse_perturbation("payload_kg=0.5"))
    nominal.reset(q0)
    loaded.reset(q0)
    ff = LoadInertia("arms", DT)
    ff.start(q0, np.zeros(14))
    m = load_model("arms")
    d = mujoco.MjData(m)
    jac = np.zeros((3, m.nv))
    index = RobotIndex.from_model(m, ROBOT.joint_names)
    qs_nom, qs_load = [], []
    for k in range(25):
        cmd = _command(q0 + (1.0 - (1.0 - alpha) ** (k + 1)) * step)
        q = loaded.read_state().q
        d.qpos[index.qpos] = q
        mujoco.mj_forward(m, d)
        weight = np.zeros(14)
        for arm, site in zip((LEFT, RIGHT), FINGERTIP_SITES, strict=True):
            mujoco.mj_jacSite(m, d, jac, None, m.site(site).id)
            weight[arm] = 0.5 * 9.81 * jac[2, index.dof[arm]]
        inertia = ff.step(cmd, q, np.array([0.5, 0.5])) if feedforward else 0.0
        loaded.write_command(cmd._replace(tau_ff=weight + inertia))
        nominal.write_command(cmd)
        loaded.advance(DT)
        nominal.advance(DT)
        qs_nom.append(nominal.read_state().q)
        qs_load.append(loaded.read_state().q)
    return np.array(qs_load), np.array(qs_nom)


def test_the_feedforward_makes_a_loaded_arm_move_as_the_nominal_one():
    """C MuJoCo, a filtered step on every joint: with the payload's weight cancelled, its inertia alone moves
    the loaded arm off the nominal arm's path by up to 72 mrad (a shoulder pitch; the wrists, 7x their
    inertia, 27 mrad); the feed-forward, updated once per 20 ms tick as the runtime does, brings both
    under a third (14 and 7 mrad measured)."""
    load_off, nom = _follow(False)
    load_on, nom_on = _follow(True)
    np.testing.assert_array_equal(nom, nom_on)
    off = np.max(np.abs(load_off - nom))
    on = np.max(np.abs(load_on - nom))
    assert off > 0.03
    assert on < off / 3
    wrists = np.r_[4:7, 11:14]
    assert np.max(np.abs(load_on - nom)[:, wrists]) < np.max(np.abs(load_off - nom)[:, wrists]) / 3


def _piano_runtime(config):
    """A runtime of the shipped piano policy on the keyboard's sim target, playing ode_to_joy."""
    from bar_policy.deploy.episodes import SimEpisodes
    from bar_policy.deploy.policy import load_policy
    from bar_policy.deploy.runtime import Runtime
    from bar_policy.tasks.piano.keyboard import compact_config
    from bar_policy.tasks.piano.scene import keyboard_scene
    from bar_policy.tasks.piano.song_library import library_song
    from bar_policy.tasks.piano.source import SongCommands

    policy = load_policy(str(PIANO))
    kb = compact_config()
    target = SimEpisodes(policy).target(scene=keyboard_scene(kb))
    commands = SongCommands(library_song("ode_to_joy"), kb, policy.policy_dt, None)
    return Runtime(policy, target, commands, config)


def test_the_piano_feeds_it_forward_by_default_and_it_needs_the_fit():
    """The piano's source wants it (``SongCommands.load_inertia``) with its ``tare``: on, its reference arm
    in the keyboard's scene (the keys' joints in it). With the fit off it is left off, saying why; asked
    for with the fit off it is refused naming what works; asked off it is off. The tracker's source does
    not want it."""
    from bar_policy.deploy.run_config import RuntimeConfig
    from bar_policy.tasks.interfaces import CommandSource

    rt = _piano_runtime(RuntimeConfig())
    assert rt.loads.inertia_kind == "on" and rt.loads.kind == "tare"
    keys = rt.loads.inertia.reference.model
    assert keys.njnt > len(ROBOT.joint_names) and keys.joint(keys.njnt - 1).name.startswith("piano_key")
    assert _piano_runtime(RuntimeConfig(load_inertia=False)).loads.inertia is None
    rt_off = _piano_runtime(RuntimeConfig(hand_load="off"))
    assert rt_off.loads.inertia is None
    assert rt_off.hand_load_record() == {
        "kind": "off",
        "load_inertia": {"kind": "off (wanted; hand-load off)"},
    }
    msg = r"load inertia on needs the hand-load fit's mass: hand load must be estimate or tare \(got off\)"
    with pytest.raises(ValueError, match=msg):
        _piano_runtime(RuntimeConfig(hand_load="off", load_inertia=True))
    assert CommandSource.load_inertia is False


def test_cli_refuses_load_inertia_on_without_the_fit_in_one_line(capsys):
    """``bar-deploy eval --hand-load off --load-inertia on``: the runtime's refusal, one line, exit 2."""
    from bar_policy.deploy.cli import main

    code = main(
        [
            "eval",
            "--policy",
            str(PIANO),
            "-q",
            "--songs",
            "ode_to_joy",
            "--random-songs",
            "0",
            "--hand-load",
            "off",
            "--load-inertia",
            "on",
        ]
    )
    assert code == 2
    err = capsys.readouterr().err
    assert (
        "load inertia on needs the hand-load fit's mass: hand load must be estimate or tare (got off)" in err
    )
