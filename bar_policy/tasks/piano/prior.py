"""The key-pose prior: the piano policy starts from the arm poses that hover over and press the goal keys.

A piano policy must turn 539 goal-key bits into arm poses that put a fingertip on a 22.5 mm key and press
it 10 mm at the right 20 ms step: an inverse-kinematics table that plain PPO would have to learn from
scratch (the first 7-minute GPU run learnt only not to press: F1 0.21, recall 0.21, docs/piano.md). With
the prior, the policy's mean is ``mlp(obs) + atanh(prior(obs))`` (``obs.action_prior.BlendPrior``) and the
network learns the correction: timing, the press depth, the arm's dynamics.

**Tables** (``key_poses``, C MuJoCo, no jax): per key, the hand that plays it (keys below ``split_midi``:
left; the random songs and the library's two-hand pieces keep to this split) and two commands for that
hand's 7 joints, from damped least-squares IK (``reach.ReachChecker``, the span's own solver):

- *hover*: the fingertip sphere ``hover_m`` above the key's aim point (``piano_key{m}_top``);
- *press*: the sphere ``press_below_m`` below the aim point at full travel, holding ``press_force_n`` up
  from the key;

each at the flattest finger tilt that has a valid pose (``reach.TILTS``): first with the null space pulled to
``piano_ready``, then to other postures (``POSTURE_OFFSETS``; the one nearest the neighbouring key's pose),
and only then steeper, so that neighbouring keys share the wrist posture (a 40 degree C4 beside a flat D4
stepped the wrist past its torque cap at every switch; docs/piano.md, "Cap ticks");
each with the gravity (and key) torque folded into the command, ``q_cmd = q + (g(q) - J^T f) / Kp``, so
the MIT law's spring holds the pose rather than sagging 20 mm (``held.py``).

**Blend** (``key_pose_prior``, one ``BlendPrior``): goal-key frame ``j`` (0 = this step's goal;
``target_keys``) and key ``k`` act on the hand of ``k``, each hand's command the weighted mean of the
press pose press(k) of the goal keys in frames ``j <= lead_steps``, the hover pose hover(k) of those in the
later frames, each at weight ``decay ** j`` (the nearest note leads: a held note outweighs the next note
until it ends), and the default pose (``piano_ready``, action 0) at weight ``rest_weight``, so a hand with
no goal key in view rests. The fingertip goes down ``lead_steps`` steps before the note (ahead of the
action filter's and the arm's lag) and up ``lead_steps`` steps before its end; because the later frames'
hover poses stay in the mean, the blended press stops short of the press pose (``press_below_m``). A
second blend for the press depth, apart from the place, scored lower (docs/piano.md).

**Edge blend** (``edge_gain``, the ``BlendPrior``'s second blend, linear: no weight per entry, the rest
pose 0 at weight 1): per goal key ``k`` in frame ``j``, ``c_j (press(k) - hover(k))`` is added to the place
blend, with ``c_0 = -edge_gain`` and ``c_lead = +edge_gain``. While a note is held both frames are on and
the terms cancel; over the ``lead`` steps before a note (frame ``lead`` on, frame 0 not yet) the key is
pushed down, over the ``lead`` steps before its end (frame 0 on, frame ``lead`` off) lifted: the command
reaches the press sooner and leaves it sooner, where the weighted mean alone went down 3-9 steps late and
came up 1-5 late (docs/piano.md, "Edge blend").

**Release blend** (``release_gain``, feedback: the blends after the edge blend read ``key_pressed`` too):
a key observed down adds ``release_gain (hover(k) - press(k))`` to its hand, divided by
``1 + release_block goal_0(k)``, so it lifts a key held down while it is not this step's goal and nothing
while it is. It frees a finger caught against the neighbouring key's side: leaving E4 for D4 two steps
later, the fingertip met D4's side 1.3 mm below its top (a horizontal contact normal), and the push of
D4's press held it there, E4 down, through the whole D4 note (docs/piano.md, "Release blend"). One blend
per key rank (a left and a right key share one: they drive different arms), each a ratio whose
denominator holds that key's goal bit. ``open_loop()``: the same settings without it.
"""

from __future__ import annotations

import dataclasses
import functools
from dataclasses import dataclass

import numpy as np

from bar_policy._array_cache import cached_arrays
from bar_policy.obs.action_prior import BlendPrior
from bar_policy.obs.manager import ObservationManager
from bar_policy.robot.constants import load_robot
from bar_policy.tasks.piano.held import HoldingTorque
from bar_policy.tasks.piano.keyboard import HAND_SPLIT_MIDI, KeyboardConfig, key_table
from bar_policy.tasks.piano.reach import TILTS, ReachChecker
from bar_policy.tasks.piano.terms import TARGET_FRAMES

__all__ = ["KeyPosePriorConfig", "KeyPoses", "key_pose_prior", "key_poses"]


@dataclass(frozen=True, kw_only=True)
class KeyPosePriorConfig:
    """How the key poses are solved and blended (see the module docstring)."""

    hover_m: float = 0.03
    """Fingertip sphere above the key top when hovering, m (prior alone on the held-out songs, sim target:
    mean F1 0.60 at 15 mm, 0.79 at 30 mm, 0.72 at 40 mm, lead 2; with the count-in and an 8 mm press,
    0.74 at 15 mm, 0.78 at 20 mm, 0.80 at 25 mm, 0.82 at 30 mm; docs/piano.md)."""
    press_below_m: float = 0.014
    """Press target below the aim point's full-travel depth, m (the key's stop takes the rest). Deeper than
    the key needs because the place blend mixes the press pose with the hover poses of the later frames:
    a deeper press puts the blended fingertip past the press threshold sooner. Prior alone, rest weight
    0.02, sim target: held-out F1 0.901 at 8 mm, 0.909 at 14, 0.907 at 16; random songs (32, seed 2026)
    black recall 0.838 at 8 mm, 0.850 at 12, 0.851 at 14, 0.856 at 16 (docs/piano.md, "Press depth")."""
    press_force_n: float = 1.5
    """Upward key force the press command holds, N (full travel takes 1.2 N at a white key's aim point)."""
    decay: float = 0.6
    """Weight ratio of successive goal-key frames (< 1: the nearest note leads)."""
    rest_weight: float = 0.02
    """Weight of the default pose, always in the place blend (a hand with no goal key in view rests). The
    default pose holds the fingertip in front of the black keys and 7 mm below their tops, so between two
    notes it pulls the hand's path low and forward: at 0.05 the fingertip crossed the keys below the black
    tops and wedged beside a black key or reached it late. Prior alone, sim target, 8 random songs of seed
    2026: black recall 0.767 at 0.05, 0.832 at 0.02, 0.835 at 0.01, 0.835 at 0.005; held-out F1 0.886,
    0.901, 0.899, 0.900 (docs/piano.md, "The place blend")."""
    split_midi: int = HAND_SPLIT_MIDI
    """Keys below this MIDI number are the left hand's, the others the right's (middle C)."""
    press_gain: float = 1.0
    """Factor on the weights of the press frames (0..lead) against the hover frames and the rest pose."""
    hover_decay: float | None = None
    """Weight ratio of successive hover frames (after the lead): frame ``j > lead`` weighs
    ``decay**lead * hover_decay**(j - lead)``; None: ``decay`` (one geometric series)."""
    frame_weights: tuple[float, ...] | None = None
    """Explicit weight per goal-key frame (``TARGET_FRAMES`` of them, >= 0), in place of ``decay``,
    ``hover_decay`` and ``press_gain``; None: those."""
    edge_gain: float = 0.45
    """The edge blend's factor ``a`` (``edge_weights``: ``c_0 = -a``, ``c_lead = +a``, the other frames 0):
    a key is pushed ``a`` of the way from its hover to its press command over the ``lead`` steps before
    its note and lifted as much over the ``lead`` steps before the note's end; 0: no edge blend (the prior
    before 2026-11-26's change). Prior alone, sim target, 8 training songs: mean F1 0.796 at 0, 0.829 at
    0.4, 0.839 at 0.45, 0.835 at 0.5, 0.808 at 0.6; held-out songs 0.816 at 0, 0.869 at 0.45
    (docs/piano.md, "Edge blend")."""
    edge_weights: tuple[float, ...] | None = None
    """Explicit factors ``c_j`` of the edge blend, one per goal-key frame (``TARGET_FRAMES``), in place of
    ``edge_gain``'s. The edge blend is a second, linear blend added to the place blend: per goal key ``k``
    of frame ``j``, ``c_j (press(k) - hover(k))``. With ``c_0 = -a`` and ``c_P = a`` it pushes a key down
    the ``P`` steps before its note, lifts it the ``P`` steps before the note's end and adds nothing while
    the note is held."""

    release_gain: float = 0.2
    """The release blend's factor: a key observed down (``key_pressed``) while it is not this step's goal
    adds ``release_gain (hover(k) - press(k))`` to its hand (lifts the fingertip where it is); 0: none
    (the prior before 2026-11-26's second change). Prior alone, sim target, 8 training songs: mean F1 0.839
    at 0, 0.863 at 0.15, 0.865 at 0.2, 0.864 at 0.3, 0.861 at 0.4, 0.858 at 0.6; held-out songs 0.871 at 0,
    0.882 at 0.2 (docs/piano.md, "Release blend")."""
    release_block: float = 100.0
    """Weight of a key's own frame-0 goal bit in its release blend's denominator: the lift is
    ``1 / (1 + release_block)`` of itself while the key is the goal."""

    def __post_init__(self) -> None:
        if (
            not 0.0 < self.decay <= 1.0
            or self.rest_weight <= 0.0
            or self.hover_m < 0.0
            or self.press_force_n < 0
            or self.press_gain <= 0.0
            or (self.hover_decay is not None and not 0.0 <= self.hover_decay <= 1.0)
            or (self.frame_weights is not None and min(self.frame_weights) < 0.0)
            or self.edge_gain < 0.0
            or self.release_gain < 0.0
            or self.release_block <= 0.0
        ):
            raise ValueError(
                "need 0 < decay <= 1, rest_weight > 0, hover_m >= 0, press_force_n >= 0, press_gain > 0, "
                "0 <= hover_decay <= 1, frame_weights >= 0, edge_gain >= 0, release_gain >= 0, "
                f"release_block > 0; got {self}"
            )
        for name in ("frame_weights", "edge_weights"):
            v = getattr(self, name)
            if v is not None and len(v) != TARGET_FRAMES:
                raise ValueError(f"{name} needs {TARGET_FRAMES} values (one per goal-key frame), got {v}")

    def open_loop(self) -> KeyPosePriorConfig:
        """These settings without the release blend: the prior of the goal keys alone (the reference's)."""
        return dataclasses.replace(self, release_gain=0.0)

    def frame_weight(self, j: int, lead_steps: int) -> float:
        """The blend's weight of goal-key frame ``j`` (pressing frames ``0..lead_steps``)."""
        if self.frame_weights is not None:
            return float(self.frame_weights[j])
        if j <= lead_steps:
            return self.press_gain * self.decay**j
        hd = self.decay if self.hover_decay is None else self.hover_decay
        return self.decay**lead_steps * hd ** (j - lead_steps)

    def edge_factors(self, lead_steps: int) -> np.ndarray | None:
        """The edge blend's ``c_j`` per goal-key frame, None when there is none (all 0)."""
        if self.edge_weights is not None:
            c = np.asarray(self.edge_weights, np.float64)
        else:
            c = np.zeros(TARGET_FRAMES)
            if lead_steps > 0:
                c[0], c[lead_steps] = -self.edge_gain, self.edge_gain
        return c if np.any(c != 0.0) else None


@dataclass(frozen=True)
class KeyPoses:
    """Commands per key for the hand that plays it (the other arm's columns hold the default pose)."""

    hover: np.ndarray
    """q_cmd hovering over each key, rad, shape (n_keys, n_joints)."""
    press: np.ndarray
    """q_cmd pressing each key, rad, shape (n_keys, n_joints)."""
    hand: np.ndarray
    """0 left, 1 right, per key, shape (n_keys,)."""


@functools.lru_cache(maxsize=4)
def key_poses(
    keyboard: KeyboardConfig,
    mode: str = "arms",
    config: KeyPosePriorConfig | None = None,
    kp: tuple[float, ...] | None = None,
) -> KeyPoses:
    """The hover and press commands of every key of ``keyboard`` (see the module docstring).

    ``kp``: the Kp the commands are for, N*m/rad, one per joint (a tuple: the result is memoised; the spring
    that holds gravity and the key force: ``q_cmd = q + tau / Kp``); None: the joint table's.

    The IK takes about 6 s on the 2-core CPU (10-16 s on the H100 machine's), so the result is kept on
    disk (``bar_policy._array_cache``), keyed on the keyboard, the mode, the prior config, the gains (when
    not the table's) and the package's files; a rerun loads it bit for bit.

    Raises:
        ValueError: IK finds no valid pose (joint limits, self-contact, the keyboard's case) for a key.
    """
    pc = config or KeyPosePriorConfig()
    parts = {"keyboard": repr(keyboard), "mode": mode, "config": repr(pc)}
    gains = None if kp is None else np.asarray(kp, np.float64)
    if gains is not None and not np.array_equal(gains, load_robot(mode).kp):
        parts["kp"] = repr(gains.tolist())
    names = tuple(f.name for f in dataclasses.fields(KeyPoses))
    solve = lambda: vars(_solve_key_poses(keyboard, mode, pc, gains))  # noqa: E731
    arrays = cached_arrays("piano_key_poses", parts, names, solve)
    return KeyPoses(**arrays)


def _solve_key_poses(
    keyboard: KeyboardConfig, mode: str, pc: KeyPosePriorConfig, kp: np.ndarray | None
) -> KeyPoses:
    """``key_poses`` without the cache: IK for every key, outward from the keys under the fingertips."""
    checker = ReachChecker(keyboard)
    keys = key_table(keyboard)
    robot = load_robot(mode)
    kp = np.asarray(robot.kp if kp is None else kp, np.float64)
    cap = np.asarray(robot.torque_cap, np.float64)
    q_ready = np.asarray(robot.pose("piano_ready"), np.float64)
    hand = np.array([0 if k.midi < pc.split_midi else 1 for k in keys])
    hover, press = np.tile(q_ready, (len(keys), 1)), np.tile(q_ready, (len(keys), 1))
    hold = HoldingTorque(mode)
    r = keyboard.fingertip_radius
    for h, name in enumerate(("left", "right")):
        mine = [i for i in range(len(keys)) if hand[i] == h]
        tip = checker.fingertip(q_ready, name)
        start = min(mine, key=lambda i: abs(keys[i].y - tip[1]))
        order = sorted(mine, key=lambda i: (abs(i - start), i))  # outward from the key under the fingertip
        q_prev = q_ready
        solved: dict[int, np.ndarray] = {}  # IK hover pose per key
        arm = np.arange(7) + 7 * h
        for i in order:
            k = keys[i]
            down = (k.lever - keyboard.press_depth) * k.angle_max
            site = np.asarray(k.site)
            targets = (
                site + np.array([0, 0, r + pc.hover_m]),
                site + np.array([0, 0, r - down - pc.press_below_m]),
            )
            # the key one step nearer the start key, solved before this one (the start key: piano_ready)
            near = solved.get(i + (1 if i < start else -1), q_ready)
            found = None
            for tilt in TILTS:
                for q0 in (q_prev, q_ready):  # the usual posture, piano_ready
                    found = _pose_pair(checker, name, targets, q0, tilt)
                    if found is not None:
                        break
                if found is None:
                    found = _other_posture(checker, name, targets, near, q_ready, arm, cap, tilt)
                if found is not None:
                    break
            if found is None:
                raise ValueError(f"no IK pose for key {k.midi} with the {name} hand (keyboard {keyboard})")
            qh, qp = found
            q_prev = solved[i] = qh
            hover[i, arm] = (qh + hold(qh) / kp)[arm]
            press[i, arm] = (qp + hold(qp, name, pc.press_force_n) / kp)[arm]
    return KeyPoses(hover=hover, press=press, hand=hand)


POSTURE_OFFSETS: tuple[float, ...] = (-0.2, 0.2, -0.4, 0.4)
"""Offsets, rad, of one arm joint from ``piano_ready`` that make the other postures ``key_poses`` tries."""


def _pose_pair(
    checker: ReachChecker,
    name: str,
    targets: tuple[np.ndarray, np.ndarray],
    q0: np.ndarray,
    tilt: float,
    posture: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray] | None:
    """Hover, then press IK poses from ``q0`` at finger ``tilt`` (None: no valid pair).

    Valid: both reach within 2 mm and the hover pose passes ``ReachChecker.valid``.
    """
    qh, eh = checker.solve(name, targets[0], q0, tilt, posture=posture)
    qp, ep = checker.solve(name, targets[1], qh, tilt, posture=posture)
    return (qh, qp) if max(eh, ep) <= 0.002 and checker.valid(qh, name) else None


def _other_posture(
    checker: ReachChecker,
    name: str,
    targets: tuple[np.ndarray, np.ndarray],
    near: np.ndarray,
    q_ready: np.ndarray,
    arm: np.ndarray,
    cap: np.ndarray,
    tilt: float,
) -> tuple[np.ndarray, np.ndarray] | None:
    """Hover and press IK poses at finger ``tilt`` with the null space pulled to another posture.

    The postures are ``piano_ready`` with one of the arm's joints moved by each of ``POSTURE_OFFSETS``;
    of the valid poses, the one nearest ``near`` (the neighbouring key's hover pose) in torque-cap units
    (``max |q - near| / cap`` over the arm: the blend steps between the two poses), None when none is valid.
    """
    best, best_cost = None, np.inf
    for j in arm:
        for dv in POSTURE_OFFSETS:
            posture = q_ready.copy()
            posture[j] += dv
            pair = _pose_pair(checker, name, targets, near, tilt, posture)
            if pair is not None:
                cost = float(np.max(np.abs(pair[0] - near)[arm] / cap[arm]))
                if cost < best_cost:
                    best, best_cost = pair, cost
    return best


def key_pose_prior(
    manager: ObservationManager,
    keyboard: KeyboardConfig,
    default: np.ndarray,
    scale: np.ndarray,
    lead_steps: int,
    config: KeyPosePriorConfig | None = None,
    kp: np.ndarray | None = None,
) -> BlendPrior:
    """The piano's prior over the ``target_keys`` entries of ``manager``'s layout (module docstring).

    Args:
        manager: the piano layout (``target_keys``: ``TARGET_FRAMES`` frames x the keyboard's keys).
        keyboard: the trained keyboard (its key order is the observation's).
        default: q_cmd at action 0, rad, shape (n,).
        scale: rad per action unit, shape (n,), > 0.
        lead_steps: goal-key frames 0..lead_steps get the press pose, 0..``TARGET_FRAMES - 1``.
        config: the poses' and the blend's settings.
        kp: the Kp the policy runs on, N*m/rad, shape (n,) (``key_poses``); None: the joint table's.
    """
    pc = config or KeyPosePriorConfig()
    if "target_keys" not in manager.term_names:
        raise ValueError(f"layout {manager.schema.name} has no target_keys term: no key-pose prior")
    if not 0 <= lead_steps < TARGET_FRAMES:
        raise ValueError(
            f"lead_steps must be in 0..{TARGET_FRAMES - 1} (the goal-key frames), got {lead_steps}"
        )
    gains = None if kp is None else tuple(float(x) for x in np.asarray(kp, np.float64))
    poses = key_poses(keyboard, manager.schema.mode, pc, gains)
    n_keys = len(poses.hand)
    sl = manager.term_slice("target_keys")
    if sl.stop - sl.start != TARGET_FRAMES * n_keys:
        raise ValueError(
            f"target_keys has {sl.stop - sl.start} entries, {TARGET_FRAMES} x {n_keys} keys expected"
        )
    term = manager.term("target_keys")
    default, scale = np.asarray(default, np.float64), np.asarray(scale, np.float64)
    n = default.shape[0]
    edge = pc.edge_factors(lead_steps)
    m = 1 if edge is None else 2
    m_place = m
    n_in = TARGET_FRAMES * n_keys
    if pc.release_gain > 0:
        kp_sl = manager.term_slice("key_pressed")
        kp_term = manager.term("key_pressed")
        n_in = kp_sl.stop - sl.start
        rank = np.zeros(n_keys, int)
        for h in (0, 1):
            idx = np.flatnonzero(poses.hand == h)
            rank[idx] = np.arange(len(idx))
        m += int(rank.max()) + 1
    numer = np.zeros((m, n_in, n))
    denom = np.zeros_like(numer)
    for j in range(TARGET_FRAMES):
        pose = poses.press if j <= lead_steps else poses.hover
        # per unit of the observation entry (obs = term.scale * goal)
        w = pc.frame_weight(j, lead_steps) / term.scale
        for k in range(n_keys):
            arm = np.arange(7) + 7 * poses.hand[k]
            numer[0, j * n_keys + k, arm] = w * (pose[k, arm] - default[arm]) / scale[arm]
            denom[0, j * n_keys + k, arm] = w
            if edge is not None:  # the edge blend, linear: weight 0 per entry, rest pose 0 at weight 1
                c = edge[j] / term.scale
                numer[1, j * n_keys + k, arm] = c * (poses.press[k, arm] - poses.hover[k, arm]) / scale[arm]
    denom_bias = np.ones((m, n))
    denom_bias[0] = pc.rest_weight
    if pc.release_gain > 0:
        for k in range(n_keys):
            arm = np.arange(7) + 7 * poses.hand[k]
            b = m_place + rank[k]
            row = kp_sl.start - sl.start + k
            numer[b, row, arm] = (
                pc.release_gain / kp_term.scale * (poses.hover[k, arm] - poses.press[k, arm]) / scale[arm]
            )
            denom[b, k, arm] = pc.release_block / term.scale
    return BlendPrior(
        start=sl.start,
        numer=numer,
        denom=denom,
        numer_bias=np.zeros((m, n)),
        denom_bias=denom_bias,
        label=f"piano key poses, lead {lead_steps}, {pc}",
    )
