"""The hand-load fit (``deploy.hand_load``): its estimate and feed-forward against C MuJoCo, its bounds,
and the runtime's use of it.

Expected values: the torque holding a robot still is C MuJoCo's gravity torque ``qfrc_bias`` at zero
velocity (``deploy.gravity``'s); the torque holding a point mass ``m`` at a site is ``m g J_z^T`` of that
site (``mj_jacSite``), by hand from the Jacobian. A point mass anywhere on the hand body is an exact mix
of the fit's four points (the translational Jacobian is affine in the point on one body), so fed the
perturbed robot's holding torque the fit recovers the payload up to its ridge and float64 round-off.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from pathlib import Path

import mujoco
import numpy as np
import pytest

from bar_policy.deploy.hand_load import GRAVITY, HandLoadConfig, HandLoadEstimator
from bar_policy.deploy.targets.perturbed import sim_target
from bar_policy.deploy.targets.sim import SimConfig
from bar_policy.robot.constants import FINGERTIP_SITES, load_robot
from bar_policy.robot.index import RobotIndex
from bar_policy.robot.perturb_spec import parse_perturbation
from bar_policy.robot.scene import load_model

ROBOT = load_robot("arms")
DT = 0.02
TRACKER = Path(__file__).resolve().parents[2] / "checkpoints" / "lite_track_arms.onnx"
"""The shipped tracker (the runtime tests run it on its held-out clip)."""
PIANO = TRACKER.with_name("lite_piano_arms.onnx")
"""The shipped piano policy (the tare tests play a held-out song)."""


def _poses(n: int, seed: int = 0) -> np.ndarray:
    """``n`` poses, rad, (n, 14): piano_ready plus up to +-0.4 rad per joint, inside the limits."""
    rng = np.random.default_rng(seed)
    q0 = np.asarray(ROBOT.pose("piano_ready"))
    q = q0 + rng.uniform(-0.4, 0.4, (n, q0.size))
    return np.clip(q, np.asarray(ROBOT.lower) + 0.05, np.asarray(ROBOT.upper) - 0.05)


def _holding_torque(model: mujoco.MjModel, q: np.ndarray) -> np.ndarray:
    """C MuJoCo's gravity torque at ``q`` (zero velocity) on ``model``'s robot joints, N*m."""
    d = mujoco.MjData(model)
    idx = RobotIndex.from_model(model, ROBOT.joint_names)
    d.qpos[idx.qpos] = q
    mujoco.mj_forward(model, d)
    return d.qfrc_bias[idx.dof].copy()


def _site_torque(q: np.ndarray, site: str, mass: float) -> np.ndarray:
    """``mass g J_z^T`` of ``site`` at ``q`` on the nominal model, N*m (the torque holding that mass)."""
    m = load_model("arms")
    d = mujoco.MjData(m)
    idx = RobotIndex.from_model(m, ROBOT.joint_names)
    d.qpos[idx.qpos] = q
    mujoco.mj_forward(m, d)
    jac = np.zeros((3, m.nv))
    mujoco.mj_jacSite(m, d, jac, None, m.site(site).id)
    return mass * GRAVITY * jac[2, idx.dof]


@pytest.fixture(scope="module")
def payload_model() -> mujoco.MjModel:
    """The sim target's model with 0.5 kg at each fingertip (the suite's payload row)."""
    return sim_target(
        "arms", SimConfig(), scene=None, perturbation=parse_perturbation("payload_kg=0.5")
    ).model


def test_fit_recovers_a_fingertip_payload_and_its_torque(payload_model):
    """Fed the perturbed robot's holding torque at 60 poses (ridge 1e-6: no bias to speak of), each hand
    reads 0.5 kg, and the feed-forward at a new pose equals the payload's torque by hand, ``0.5 g J_z^T``
    of each fingertip site: the fit's normal equations are solved in float64 on well-excited data
    (torques of a few N*m), so 1e-6 kg and 1e-5 N*m."""
    est = HandLoadEstimator("arms", DT, HandLoadConfig(ridge=1e-6, tau_s=100.0))
    for q in _poses(60):
        est.step(q, _holding_torque(payload_model, q))
    np.testing.assert_allclose(est.masses, [0.5, 0.5], atol=1e-6)
    q = _poses(1, seed=7)[0]
    want = _site_torque(q, FINGERTIP_SITES[0], 0.5) + _site_torque(q, FINGERTIP_SITES[1], 0.5)
    np.testing.assert_allclose(est.torque(q), want, atol=1e-5)
    assert est.updates == 60 and est.clip.clip_count == 0 and est.mass_bound_count == 0


def test_a_still_pose_reads_a_fingertip_load_as_mass(payload_model):
    """The piano's tare: 12 ticks (0.24 s) at piano_ready of the 0.5 kg payload's holding torque. One pose
    cannot tell the mass from its centre (the centre's columns are nearly collinear with the mass's); the
    centre's ridge keeps the load at the fingertip, so the mass reads it. By hand: the mass's ridge alone
    keeps ``S / (S + ridge)`` of it, ``S`` the 12 ticks' forgetting-weighted sum of ``|g J_z|^2`` over each
    arm's joints (``_site_torque`` of 1 kg), about 0.996; the centre's leak is held under 1 % (the ridge
    of 1000 on each ``m c`` against the same sum of its columns, at most 8x the mass's): 0.99 x that to
    that. One ridge of 10 on all four moves a third of the load into a centre offset (0.33 kg)."""
    q = np.asarray(ROBOT.pose("piano_ready"))
    config = HandLoadConfig()
    lam = np.exp(-DT / config.tau_s)
    weight = sum(lam**k for k in range(12))
    tau = _holding_torque(payload_model, q)
    est = HandLoadEstimator("arms", DT)
    uniform = HandLoadEstimator("arms", DT, HandLoadConfig(ridge=10.0, ridge_centre=10.0))
    for _ in range(12):
        est.step(q, tau)
        uniform.step(q, tau)
    for h, site in enumerate(FINGERTIP_SITES):
        s = weight * float(np.sum(_site_torque(q, site, 1.0) ** 2))
        kept = 0.5 * s / (s + config.ridge)
        assert 0.99 * kept <= est.masses[h] <= kept
    assert np.all(uniform.masses < 0.35)


def test_nominal_robot_reads_no_load():
    """The nominal robot's own holding torque leaves nothing to fit: zero estimate, zero feed-forward
    (the residual is exactly 0 up to round-off, 1e-12)."""
    model = load_model("arms")
    est = HandLoadEstimator("arms", DT)
    for q in _poses(10):
        ff = est.step(q, _holding_torque(model, q))
    np.testing.assert_allclose(est.masses, 0.0, atol=1e-12)
    np.testing.assert_allclose(ff, 0.0, atol=1e-12)


def test_the_fit_records_how_far_the_arm_moved_while_it_ran():
    """``motion_rad``: the largest joint excursion from the first fitted pose. Poses q0, q0 + 0.01 rad on
    one joint, q0 - 0.02 on another, q0 again: 0.02 rad; a non-finite tick is not fitted and moves nothing."""
    model = load_model("arms")
    est = HandLoadEstimator("arms", DT)
    q0 = _poses(1)[0]
    a, b = q0.copy(), q0.copy()
    a[3] += 0.01
    b[9] -= 0.02
    for q in (q0, a, b, q0):
        est.step(q, _holding_torque(model, q))
    est.step(np.full_like(q0, np.nan), np.zeros_like(q0))
    assert est.motion_rad == pytest.approx(0.02, abs=1e-15) and est.record()["motion_rad"] == est.motion_rad


def test_forgetting_follows_a_load_taken_off(payload_model):
    """With ``tau_s`` 0.1 s (5 ticks), 40 ticks of the payload then 40 of the bare robot: the estimate's
    memory of the payload is weighted by exp(-40 / 5) = 3e-4 of the new data's, so it reads below 1e-3 kg
    (the ridge 1e-6 adds nothing)."""
    est = HandLoadEstimator("arms", DT, HandLoadConfig(ridge=1e-6, tau_s=0.1))
    poses = _poses(80, seed=3)
    for q in poses[:40]:
        est.step(q, _holding_torque(payload_model, q))
    assert est.masses == pytest.approx([0.5, 0.5], abs=1e-6)
    nominal = load_model("arms")
    for q in poses[40:]:
        est.step(q, _holding_torque(nominal, q))
    assert np.all(np.abs(est.masses) < 1e-3)


def test_bounds_are_counted(payload_model):
    """A torque that reads as 10 kg per hand (the nominal holding torque plus 20x the 0.5 kg payload's) is
    scaled back to ``max_kg`` per hand, counted once per fit; its feed-forward (10 kg at 0.5 m: ~50 N*m at
    a shoulder) goes past the caps and is clipped to them, counted per joint."""
    model = load_model("arms")
    est = HandLoadEstimator("arms", DT, HandLoadConfig(ridge=1e-6, max_kg=1.5))
    for q in _poses(5):
        base = _holding_torque(model, q)
        ff = est.step(q, base + 20 * (_holding_torque(payload_model, q) - base))
    np.testing.assert_allclose(np.abs(est.masses), 1.5, rtol=1e-9)
    assert est.mass_bound_count == 10  # 5 fits x 2 hands
    cap = np.asarray(ROBOT.torque_cap)
    assert np.all(np.abs(ff) <= cap + 1e-12)
    rec = est.record()
    assert rec["mass_bound_count"] == 10 and rec["fits"] == 5 and rec["max_kg"] == 1.5


def test_config_refusals():
    with pytest.raises(ValueError, match=r"HandLoadConfig.tau_s must be a finite number > 0, got 0"):
        HandLoadConfig(tau_s=0.0)
    with pytest.raises(ValueError, match=r"HandLoadConfig.max_kg must be a finite number > 0, got nan"):
        HandLoadConfig(max_kg=float("nan"))


@contextlib.contextmanager
def _runtimes() -> Iterator[list]:
    """Collect every ``Runtime`` made inside the block (an evaluation makes one per episode)."""
    from bar_policy.deploy import runtime as runtime_module

    made: list = []
    init = runtime_module.Runtime.__init__

    def spy(self, *a, **k):
        init(self, *a, **k)
        made.append(self)

    runtime_module.Runtime.__init__ = spy  # type: ignore[method-assign]
    try:
        yield made
    finally:
        runtime_module.Runtime.__init__ = init  # type: ignore[method-assign]


def _clip_run(spec: str | None, hand_load: str | None):
    """The shipped tracker on held-out clip random-s1-003 on the sim target of ``spec``, as ``bar-deploy
    eval`` runs it; returns ``(runtime, fingertip error cm)``."""
    from bar_policy.deploy.episodes import SimEpisodes
    from bar_policy.deploy.policy import load_policy
    from bar_policy.tasks.track.evaluate import evaluate_track
    from bar_policy.tasks.track.reference import load_motion

    policy = load_policy(str(TRACKER))
    perturbation = None if spec is None else parse_perturbation(spec)
    runner = SimEpisodes(policy, perturbation=perturbation, hand_load=hand_load)
    with _runtimes() as made:
        res = evaluate_track(policy, [load_motion("random-s1-003", "arms")], runner=runner)
    return made[0], 100 * res.clips[0].mean("fingertip_error")


@pytest.mark.slow
def test_runtime_fits_the_payload_and_the_tracker_holds_its_accuracy():
    """The tracking task's default (``estimate``) on the sim target with 0.5 kg at each fingertip: the
    clip's fingertip error falls from 2.8 cm without it (the payload's sag, tau / Kp up to 0.05 rad at a
    shoulder) to under the gate's 1 cm (0.67; nominal 0.68 on this clip), the last command carries the
    feed-forward, and the fit reads a load of that order, 0.3-0.7 kg per hand on average over the clip
    (in motion the payload's inertia and the arm's dynamics share the residual with its weight, and the
    ridge trades the mass against its centre: 0.41 measured; the exact recovery at rest is
    ``test_fit_recovers_a_fingertip_payload_and_its_torque``). ``--hand-load off`` adds nothing; on the
    nominal robot the fit reads under 0.05 kg on average.
    """
    rt, tip = _clip_run("payload_kg=0.5", None)
    assert rt.loads.kind == "estimate"
    assert np.all((rt.loads.fit.mean_masses > 0.3) & (rt.loads.fit.mean_masses < 0.7))
    assert np.any(np.abs(rt.last_command.tau_ff) > 0.1)
    assert tip < 1.0
    rt_off, tip_off = _clip_run("payload_kg=0.5", "off")
    assert rt_off.loads.fit is None
    assert rt_off.hand_load_record() == {"kind": "off", "load_inertia": {"kind": "off"}}
    assert tip_off > 2.0
    rt_nom, _ = _clip_run(None, None)
    assert np.all(np.abs(rt_nom.loads.fit.mean_masses) < 0.05)


def test_mock_target_leaves_the_fit_off():
    """The mock echoes commands (its torque is the law's at the echoed state, no motor's): a requested fit
    is left off, and the record says why."""
    from bar_policy.deploy.policy import load_policy
    from bar_policy.deploy.runtime import Runtime, RuntimeConfig
    from bar_policy.deploy.targets.mock import MockTarget
    from bar_policy.tasks.track.reference import load_motion, reference_for

    policy = load_policy(str(TRACKER))
    ref = reference_for(policy, load_motion("random-s1-003", "arms"))
    rt = Runtime(policy, MockTarget("arms"), ref, RuntimeConfig(hand_load="estimate"))
    assert rt.loads.fit is None
    assert rt.hand_load_record()["kind"].startswith("off (asked estimate; MockTarget measures no applied")
    kinds = r"\('estimate', 'tare', 'off'\)"
    with pytest.raises(ValueError, match=r"RuntimeConfig.hand_load must be one of " + kinds):
        RuntimeConfig(hand_load="on")


@pytest.mark.parametrize("sub", [["eval"], []])
@pytest.mark.parametrize(
    ("option", "value", "choices"),
    [("--hand-load", "on", "'estimate', 'tare', 'off'"), ("--load-inertia", "yes", "'on', 'off'")],
)
def test_cli_refuses_an_unknown_load_compensation_in_one_line(sub, option, value, choices, capsys):
    """``--hand-load`` and ``--load-inertia`` (``deploy.load_compensation``) outside their choices."""
    from bar_policy.deploy.cli import main

    with pytest.raises(SystemExit) as e:
        main([*sub, "--policy", str(TRACKER), option, value])
    assert e.value.code == 2
    assert f"argument {option}: invalid choice: '{value}' (choose from {choices})" in capsys.readouterr().err


def test_a_non_finite_reading_is_not_fitted_and_gets_no_feed_forward(payload_model):
    """A NaN torque (a garbled reading) or position: the tick is counted, the estimate kept, the
    feed-forward 0."""
    est = HandLoadEstimator("arms", DT, HandLoadConfig(ridge=1e-6, tau_s=100.0))
    poses = _poses(21, seed=5)
    for q in poses[:20]:
        est.step(q, _holding_torque(payload_model, q))
    before = est.theta.copy()
    bad = _holding_torque(payload_model, poses[20])
    bad[3] = np.nan
    assert np.all(est.step(poses[20], bad) == 0.0)
    q_nan = poses[20].copy()
    q_nan[0] = np.nan
    assert np.all(est.step(q_nan, _holding_torque(payload_model, poses[20])) == 0.0)
    assert np.all(est.torque(q_nan) == 0.0)
    np.testing.assert_array_equal(est.theta, before)
    assert est.nonfinite_count == 2 and est.updates == 20 and est.record()["nonfinite_count"] == 2


def _song_run(spec: str | None, hand_load: str | None):
    """The shipped piano policy playing held-out g_major_scales_two_hands (270 ticks) on the sim target of
    ``spec``, as ``bar-deploy eval`` plays it; returns ``(runtime, song result)``."""
    from bar_policy.deploy.episodes import SimEpisodes
    from bar_policy.deploy.policy import load_policy
    from bar_policy.tasks.piano.evaluate import evaluate
    from bar_policy.tasks.piano.song_library import library_song

    policy = load_policy(str(PIANO))
    perturbation = None if spec is None else parse_perturbation(spec)
    with _runtimes() as made, SimEpisodes(policy, perturbation=perturbation, hand_load=hand_load) as runner:
        res = evaluate(policy, [library_song("g_major_scales_two_hands")], runner=runner)
    return made[0], res.songs[0]


def test_piano_tares_the_load_in_its_count_in_and_keeps_it():
    """The piano's default (``tare``) with 0.5 kg at each fingertip: the fit runs on exactly the count-in's
    still ticks, 25 - lead 2 - (11 - 1) look-ahead = 13 (``SongCommands.still_s``), and then stops; the
    kept estimate reads the load within 10 % (the ridges keep 99 % of a still load,
    ``test_a_still_pose_reads_a_fingertip_load_as_mass``; the rest is the sag's transient in the 13 ticks)
    and its feed-forward is in every later command. Without
    it the sagging fingertips land on the keys and a wrist roll ends at its cap (a fault, F1 0.24 measured);
    with it and the piano's load-inertia feed-forward (``deploy.load_inertia``, on through every POLICY tick)
    the song completes at F1 over 0.9 (0.96 measured; the files on Kp 50: 0.94, the tare alone 0.88). On
    the nominal robot the tare reads no load (under 0.02 kg: the held pose is the model's static solve).
    """
    rt, song = _song_run("payload_kg=0.5", None)
    assert rt.loads.kind == "tare" and rt.hand_load_record()["tare_ticks"] == 13
    assert rt.loads.fit.updates == 13
    assert np.all((rt.loads.fit.masses > 0.45) & (rt.loads.fit.masses < 0.55))
    kept = rt.loads.fit.torque(rt.last_state.q)
    np.testing.assert_allclose(rt.last_command.tau_ff, kept, atol=1e-12)  # the end's HOLD: the kept estimate
    assert not song.faulted and song.f1 > 0.9
    assert rt.loads.inertia_kind == "on" and rt.loads.inertia.steps > song.scored  # the count-in's ticks too
    assert song.hand_load_kg == tuple(rt.loads.fit.masses)  # the evaluation's record of the kept estimate
    assert song.hand_load_motion_mrad == 1e3 * rt.loads.fit.motion_rad
    _, off = _song_run("payload_kg=0.5", "off")
    assert off.faulted and off.f1 < 0.5 and off.hand_load_kg is None
    rt_nom, _ = _song_run(None, None)
    assert rt_nom.loads.fit.updates == 13 and np.all(np.abs(rt_nom.loads.fit.masses) < 0.02)


def test_tare_is_refused_on_a_source_that_is_never_still():
    """The tracker's clip moves from its first frame: ``tare`` has no window there, refused naming the
    kinds that work (``bar-deploy`` prints it as its one error line, exit 2)."""
    from bar_policy.deploy.policy import load_policy
    from bar_policy.deploy.runtime import Runtime, RuntimeConfig
    from bar_policy.tasks.track.reference import load_motion, reference_for

    policy = load_policy(str(TRACKER))
    ref = reference_for(policy, load_motion("random-s1-003", "arms"))
    assert ref.still_s == 0.0
    target = sim_target("arms", SimConfig(), scene=None, perturbation=None)
    msg = r"hand-load tare needs a still start and MotionReference has 0 s \(CommandSource.still_s\); valid"
    with pytest.raises(ValueError, match=msg):
        Runtime(policy, target, ref, RuntimeConfig(hand_load="tare"))


def _start_run(tmp_path: Path, name: str, *extra: str) -> dict:
    """``bar-deploy`` playing ode_to_joy from the robot's own start (the 3 s HOLD ramp) on the sim target,
    cut at 4.6 s (the ramp, a 1 s dwell, the 0.5 s count-in); returns its ``run.json``."""
    import json

    from bar_policy.deploy.cli import main

    log = tmp_path / name
    argv = ["--policy", str(PIANO), "--song", "ode_to_joy", "--duration", "4.6", "--log", str(log), *extra]
    assert main(argv) == 0
    (run,) = log.glob("*/run.json")
    return json.loads(run.read_text())


def test_the_robot_start_tares_in_a_still_hold_after_the_ramp(tmp_path):
    """Through the start-up sequence a loaded arm sags onto the keys during the ramp, and a fit on the
    count-in alone reads only what the keys do not carry. With ``tare`` the runtime holds the ramp's end
    still for ``--start-tare`` (1 s, 50 ticks) while the fit runs and feeds its estimate forward, lifting
    the hands; POLICY then starts at 3 + 1 s and the count-in's 13 ticks fit on. Expected: the hidden
    0.5 kg at each fingertip within 0.02 kg (the ridge keeps 99.6 % of a still load, 0.002 kg; the rest
    allowed for the lift's transient, under e^-4 of it after four of the fit's 0.25 s time constants);
    the nominal arm under 0.01 kg (the held pose is the model's static solve). Without the dwell the keys
    hold part of the load and the fit reads under 0.46 kg (0.44 measured with the shipped file, 0.42 with
    the files on the table's Kp 50, which sag twice as far)."""
    loaded = "payload_kg=0.5,payload_at=fingertip"
    run = _start_run(tmp_path, "dwell", "--perturb", loaded)
    start = [tr for tr in run["transitions"] if tr["to"] == "POLICY"]
    assert len(start) == 1 and start[0]["tick"] == 200 and "held still 1 s" in start[0]["reason"]
    load = run["hand_load"]
    assert load["kind"] == "tare" and load["start_tare_ticks"] == 50 and load["fits"] == 50 + 13
    masses = np.array(list(load["mass_kg"].values()))
    np.testing.assert_allclose(masses, 0.5, atol=0.02)

    run0 = _start_run(tmp_path, "count_in", "--perturb", loaded, "--start-tare", "0")
    start0 = [tr for tr in run0["transitions"] if tr["to"] == "POLICY"]
    assert start0[0]["tick"] == 150 and run0["hand_load"]["start_tare_ticks"] == 0
    assert np.all(np.array(list(run0["hand_load"]["mass_kg"].values())) < 0.46)

    nominal = _start_run(tmp_path, "nominal")
    assert np.all(np.abs(np.array(list(nominal["hand_load"]["mass_kg"].values()))) < 0.01)
