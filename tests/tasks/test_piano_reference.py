"""The piano's joint-space reference (``tasks.piano.reference``): chatter is measured on ``q_cmd`` minus it.

Expected values, each worked apart from the code under test:

- the key-pose prior alone (a zero-MLP ONNX file, made here as ``bench/piano_prior.py`` makes it) commands the
  reference tick by tick: the runtime's ``q_cmd`` and the logged ``ref_q`` differ only by the float32
  rounding of the two evaluations of the same blend (ONNX's ``tanh(atanh(p))`` against numpy's ``p``), so its
  chatter against the reference is ~0 while its ``q_cmd`` itself has the keystrokes' 6-10 mrad;
- for a hand-made goal-key window, the reference is the blend computed here from the key poses
  (``prior.key_poses``: press in frames 0..2, hover later, weight ``decay ** frame``, the rest pose at
  ``rest_weight``; plus the edge blend, -0.45 of press - hover for a key in frame 0 and +0.45 in frame 2),
  through the first-order filter written out by hand;
- a sine of amplitude A on a DFT bin below Nyquist added to ``q_cmd`` shows as A / sqrt(2) of chatter
  against the reference (the metric's exactness, tests/quality/test_metrics.py), so a policy oscillating on
  top of the reference still fails the 5 mrad gate.
"""

from __future__ import annotations

import dataclasses
import math
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).parents[1] / "deploy"))
from piano_blend import hand_blend
from policy_factory import default_metadata

from bar_policy.deploy.cli import main
from bar_policy.deploy.log.read import load_log
from bar_policy.deploy.safety import Mode
from bar_policy.obs import ObservationManager
from bar_policy.quality import QualityMeter
from bar_policy.quality.metrics import chatter_mrad
from bar_policy.robot.constants import load_robot
from bar_policy.tasks.piano.bank import PlaybackConfig
from bar_policy.tasks.piano.keyboard import compact_config
from bar_policy.tasks.piano.prior import key_pose_prior
from bar_policy.tasks.piano.reference import LEAD_STEPS, KeyPoseReference
from bar_policy.tasks.piano.songs import Note, Song
from bar_policy.tasks.piano.source import SongCommands
from bar_policy.tasks.piano.terms import PIANO_KEYS, TARGET_FRAMES

KB = compact_config()
ROBOT = load_robot("arms")
SCALE = 0.8
"""rad per action unit, the piano env's ``action_scale``."""
CUTOFF_HZ = 3.0
"""The piano env's action filter, Hz."""
DT = 0.02
ALPHA = 1.0 - math.exp(-2.0 * math.pi * CUTOFF_HZ * DT)
"""The filter's factor, written out (``robot.action_filter``'s definition): 0.314."""

# Tolerance of ``q_cmd`` against the reference, tick by tick. The ONNX graph and numpy evaluate the same
# float32 blend; the graph then takes tanh(atanh(p)). Each is within a few float32 ulps of 1 (2^-23 = 1.2e-7)
# of the exact prior, say |delta a| <= 1e-6 action units (the export's parity gate measures 1.3e-7 over 4096
# random observations). The filter passes a bounded input error through with gain <= 1 and adds at most
# half an ulp per tick when the two states round differently (6e-8, contracted by 1 - alpha each tick:
# <= 6e-8 / alpha = 2e-7 in all), so |delta q| <= SCALE * (1e-6 + 2e-7) < 1e-6 rad.
Q_TOL = 1e-6
# Chatter is a seminorm no larger than the largest deviation from a segment's mean (Parseval, the window's
# weights normalised): |x| <= Q_TOL gives at most 2 Q_TOL rad = 2e-3 mrad.
CHATTER_TOL_MRAD = 2e3 * Q_TOL


@pytest.fixture(scope="module")
def prior_file(tmp_path_factory) -> Path:
    """The key-pose prior alone, ``actions = tanh(0 + atanh(prior(obs)))``, at the env's scale and filter."""
    from bar_policy.export.graph import MlpPolicy
    from bar_policy.export.policy import export_policy

    meta = dataclasses.replace(
        default_metadata(task="piano"),
        action_filter_hz=CUTOFF_HZ,
        action_scale=(SCALE,) * 14,
        training={"backend": "none: the key-pose prior alone (tests)"},
    )
    om = ObservationManager.for_task("piano", "arms")
    prior = key_pose_prior(om, KB, np.asarray(meta.default_joint_pos), np.full(14, SCALE), LEAD_STEPS)
    policy = MlpPolicy.prior_only(om.size, prior)
    path = tmp_path_factory.mktemp("piano_ref") / "prior.onnx"
    export_policy(policy, meta, path, prior.apply)
    return path


@pytest.fixture(scope="module")
def prior_run(prior_file, tmp_path_factory) -> tuple[dict, dict, Path]:
    """``bar-deploy --song ode_to_joy`` on the sim target with the prior alone: the log and its run."""
    out = tmp_path_factory.mktemp("piano_ref_run")
    rc = main(
        [
            "--policy",
            str(prior_file),
            "--target",
            "sim",
            "--song",
            "ode_to_joy",
            "--ramp-time",
            "0.5",
            "--log",
            str(out),
        ]
    )
    assert rc == 0
    (run,) = out.iterdir()
    return (*load_log(run), run)


def test_prior_alone_commands_the_reference_tick_by_tick(prior_run) -> None:
    """Every POLICY tick's q_cmd is the logged ``ref_q`` within ``Q_TOL``; the run's chatter (the gate's,
    against the reference) is ~0, the chatter of q_cmd itself is the keystrokes' (> 5 mrad)."""
    log, meta, run = prior_run
    policy = np.asarray(log["mode"]) == int(Mode.POLICY)
    q_cmd, ref = np.asarray(log["q_cmd"]), np.asarray(log["ref_q"])
    assert policy.sum() > 500 and meta["command_source"]["reference"].startswith("piano key poses, lead 2")
    np.testing.assert_allclose(q_cmd[policy], ref[policy], rtol=0, atol=Q_TOL)
    # The filter starts at the HOLD target's action (action 0: the default pose) and has moved by the
    # first POLICY tick only alpha of the way to the prior: before POLICY the reference is that pose.
    default = np.asarray(meta["hold_pose"])
    first = int(np.argmax(policy))
    np.testing.assert_array_equal(ref[first - 1], default)
    chatter = meta["quality"]["episode"]["chatter_mrad"]
    assert chatter < CHATTER_TOL_MRAD
    assert chatter_mrad(q_cmd[policy] - ref[policy], DT) < CHATTER_TOL_MRAD
    assert chatter_mrad(q_cmd[policy], DT) > 5.0  # the keystrokes (6.9 mrad on ode_to_joy)
    from bar_policy.deploy.log.plot import plot_log

    assert {"joints.png", "tracking.png", "piano_roll.png"} <= {p.name for p in plot_log(run)}


@pytest.mark.parametrize("freq_hz", [12.5, 20.0])
def test_an_oscillation_on_top_of_the_reference_is_chatter(prior_run, freq_hz) -> None:
    """A sine of A = 10 mrad at a DFT bin of the 2 s segments (12.5 Hz: bin 25, 20 Hz: bin 40; both clear
    of the 5 Hz cutoff and below Nyquist) added to one joint of the prior's q_cmd: chatter against the
    reference is A / sqrt(2) = 7.071 mrad (within the prior's own ~0, by the triangle inequality), above
    the gate's 5 mrad, as the runtime's meter counts it (``QualityMeter``, the signal q_cmd - ref)."""
    log, _, _ = prior_run
    policy = np.asarray(log["mode"]) == int(Mode.POLICY)
    q_cmd, ref = np.asarray(log["q_cmd"])[policy], np.asarray(log["ref_q"])[policy]
    amp = 0.010
    k = np.arange(len(q_cmd))
    wobble = np.zeros_like(q_cmd)
    wobble[:, 3] = amp * np.sin(2.0 * math.pi * freq_hz * k * DT + 0.3)
    meter = QualityMeter(ROBOT.torque_cap, ROBOT.lower, ROBOT.upper, DT, ROBOT.joint_names)
    for i in range(len(q_cmd)):
        meter.update(np.zeros(14), ref[i], np.zeros(14), q_cmd[i] + wobble[i] - ref[i])
    rec = meter.finish("wobble")
    assert rec.chatter_mrad == pytest.approx(1e3 * amp / math.sqrt(2.0), abs=CHATTER_TOL_MRAD)
    assert rec.chatter_joint == ROBOT.joint_names[3] and rec.chatter_mrad > 5.0


def test_a_nyquist_alternation_is_its_amplitude() -> None:
    """At the 50 Hz policy rate 25 Hz is Nyquist: a "25 Hz sine" is the alternation A sin(phi) (-1)^k, whose
    chatter is its RMS |A sin(phi)| (A for a +-A alternation), not A / sqrt(2) (the Nyquist bin and its
    neighbour both lie above the cutoff)."""
    k = np.arange(1117)[:, None]
    assert chatter_mrad(0.010 * (-1.0) ** k, DT) == pytest.approx(10.0, rel=1e-9)
    phi = 0.7
    assert chatter_mrad(0.010 * np.sin(math.pi * k + phi), DT) == pytest.approx(
        10.0 * math.sin(phi), rel=1e-9
    )


def test_reference_of_a_hand_made_window(prior_file) -> None:
    """Two ticks of hand-made goal keys: the reference is the hand blend through the filter from action 0.

    Tick 1: C3 (left hand) in frame 0 (press, weight 1; edge: lifted by 0.45 of press - hover), C4 (right)
    in frame 3 (hover, 0.216). Tick 2: C3 gone, C4 in frame 2 (press, 0.36; edge: pushed by 0.45 of
    press - hover), E4 in frame 5 (hover, 0.078). f1 = alpha a1, f2 = f1 + alpha (a2 - f1),
    q = default + 0.8 f."""
    from bar_policy.deploy.policy import load_policy

    policy = load_policy(str(prior_file))
    ref = KeyPoseReference.for_policy(policy)
    default = np.asarray(policy.default_joint_pos)
    assert ref.alpha == pytest.approx(ALPHA, rel=1e-12) and LEAD_STEPS == 2

    def window(frames: dict[int, list[int]]) -> np.ndarray:
        w = np.zeros((TARGET_FRAMES, PIANO_KEYS), np.float32)
        for j, midis in frames.items():
            w[j, [m - KB.lowest for m in midis]] = 1.0
        return w.reshape(-1)

    ticks = ({0: [48], 3: [60]}, {2: [60], 5: [64]})
    f = np.zeros(14)
    state = ref.start
    for frames in ticks:
        a = hand_blend(frames, default, KB, SCALE)
        np.testing.assert_allclose(ref.action(window(frames)), a, rtol=0, atol=1e-6)
        f = f + ALPHA * (a - f)
        state = ref.filtered(state, window(frames))
        np.testing.assert_allclose(ref.q(state), default + SCALE * f, rtol=0, atol=1e-6)
    # Both hands moved: each arm's command is off the default pose.
    assert np.abs(ref.q(state) - default)[:7].max() > 1e-3 and np.abs(ref.q(state) - default)[7:].max() > 1e-3


class _NoKeys:
    """A key source with nothing down."""

    def __init__(self) -> None:
        self.counts: dict = {}

    def read(self, t: float) -> np.ndarray:
        return np.zeros(PIANO_KEYS, bool)

    def close(self) -> None:
        pass


def test_song_source_steps_the_reference_once_per_policy_tick(prior_file) -> None:
    """``SongCommands`` with a reference: before ``begin`` the reference is the filter's start (the default
    pose) however often it is called; from ``begin`` each call is one filter step on that tick's
    ``target_keys``; ``record`` logs it as ``ref_q``. Without one, ``target_q`` is None (q_cmd itself)."""
    from bar_policy.deploy.policy import load_policy

    policy = load_policy(str(prior_file))
    ref = KeyPoseReference.for_policy(policy)
    default = np.asarray(policy.default_joint_pos)
    # C4 at 0.02-0.20 s, no count-in: goal rows 1..9; at step s the window holds C4 in frames 1-s..9-s.
    song = Song("one", (Note(60, 0.02, 0.20, "right"),))
    src = SongCommands(song, KB, DT, _NoKeys(), PlaybackConfig(count_in_s=0.0), reference=ref)  # type: ignore[arg-type]
    assert src.log_fields["ref_q"] == ((14,), np.float64)
    for _ in range(3):
        src(0.0)
        np.testing.assert_array_equal(src.target_q(), default)
    src.begin(1.0)
    f = np.zeros(14)
    for s in range(4):
        frames = {j: [60] for j in range(max(1 - s, 0), 10 - s)}
        f = f + ALPHA * (hand_blend(frames, default, KB, SCALE) - f)
        src(1.0 + s * DT)
        np.testing.assert_allclose(src.target_q(), default + SCALE * f, rtol=0, atol=1e-6)
        np.testing.assert_array_equal(src.record()["ref_q"], src.target_q())
    plain = SongCommands(song, KB, DT, _NoKeys(), PlaybackConfig(count_in_s=0.0))  # type: ignore[arg-type]
    plain.begin(0.0)
    plain(0.0)
    assert plain.target_q() is None and "ref_q" not in plain.log_fields and "ref_q" not in plain.record()


def test_eval_prints_both_chatters(prior_file) -> None:
    """``bar-deploy eval``'s piano report: per song the chatter against the reference (~0 for the prior
    alone: the gate's) and of q_cmd itself (the keystrokes, > 5 mrad), in the lines and the JSON."""
    from bar_policy.deploy.episodes import SimEpisodes
    from bar_policy.deploy.policy import load_policy
    from bar_policy.tasks.piano.evaluate import evaluate

    policy = load_policy(str(prior_file))
    song = Song(
        "two",
        (
            Note(60, 0.0, 0.5, "right"),
            Note(64, 0.5, 1.0, "right"),
            Note(48, 1.0, 1.5, "left"),
            Note(67, 1.5, 2.0, "right"),
            Note(60, 2.0, 2.5, "right"),
        ),
    )
    res = evaluate(policy, [song], runner=SimEpisodes(policy))
    (s,) = res.songs
    assert not s.faulted and s.chatter_mrad is not None and s.chatter_mrad < CHATTER_TOL_MRAD
    assert s.chatter_raw_mrad is not None and s.chatter_raw_mrad > 1.0
    assert res.gate_report()["quality"]["chatter_max_mrad"] == s.chatter_mrad
    text = res.format()
    assert (
        "mrad vs the key-pose reference (q_cmd itself" in text
        and "chatter of q_cmd itself (not gated" in text
    )
    d = res.to_dict()["songs"][0]
    assert d["chatter_mrad"] == s.chatter_mrad and d["chatter_raw_mrad"] == s.chatter_raw_mrad
