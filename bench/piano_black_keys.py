"""Why a piano policy misses black keys: the fingertip, the residual and the contacts at each note.

    python bench/piano_prior.py --out /tmp/prior.onnx        # the key-pose prior alone (a zero MLP)
    python bench/piano_black_keys.py --seed 2026 --songs 8 \\
        --policies /tmp/prior.onnx,checkpoints/lite_piano_arms.onnx --out /tmp/black_keys.md

Each policy plays the same random songs (``bank.random_songs``, as ``bench/piano_random_songs.py`` draws them)
on the C MuJoCo sim target through ``bar-deploy eval``'s code (``tasks.piano.evaluate``), and at every
scored tick this script also records, from the sim target's ``MjData`` after the tick's 20 ms of physics:

- each fingertip sphere's centre (``robot.FINGERTIP_SITES``, world = chest frame: x forward, away from the
  robot; y left; z up);
- the keys each fingertip sphere touches (``scene.FINGERTIP_GEOMS`` against ``piano_key{m}``), each as a
  *top* contact (normal within 45 degrees of vertical) or a *side* contact;
- the residual: the policy's raw action minus the key-pose prior's action for the same observation
  (``KeyPoseReference.prior``, the blend the ONNX graph holds), in joint space
  (``action_scale * (a - a_prior)``), and the filtered one the arm gets, ``q_cmd`` minus the key-pose
  reference (``SongCommands.target_q``; the action filter is linear, so this is the filtered residual);
  each mapped to a fingertip displacement through the hand's site Jacobian, ``dp = J_tip(q) dq``
  (quasi-static, the pose the command would move the fingertip to with the gains' sag unchanged).

Notes (``songs.count_in`` of the song, each hand by ``KeyPosePriorConfig.split_midi``) are grouped by key
colour and by which policy sounded them (the key down at some tick of the note). For each note the *lowest
tick* is the note's tick with the playing hand's fingertip lowest; there the table gives the fingertip
relative to the goal key: depth ``x - aim x`` (the aim point, ``piano_key{m}_top``, 25 mm behind the key's
front edge; black keys begin 55 mm behind the white keys' front edge), lateral ``|y - key y|`` and the
sphere's bottom above the key's top at rest; and what the fingertip touches then. The residual is averaged
over the note's goal ticks (x and z as they are; y signed towards the goal key's centre line). The first
policy is the reference column of each pair; the table prints ``first / last`` for every row. The prior's
residual is 0 by construction (checked: its largest is printed). The last row is a counterfactual: the
raw residual for the same observation with every black goal bit of ``target_keys`` (all 11 frames) moved
to the white key below, the pose, velocities, ``key_pressed`` and previous actions as they were: whether
the residual answers the goal key's colour or the arm's pose.
"""

from __future__ import annotations

import argparse
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import mujoco
import numpy as np

from bar_policy.deploy.episodes import SimEpisodes
from bar_policy.deploy.policy import OnnxPolicy, load_policy
from bar_policy.robot.constants import FINGERTIP_SITES
from bar_policy.tasks.piano.bank import random_songs
from bar_policy.tasks.piano.evaluate import evaluate
from bar_policy.tasks.piano.keyboard import Key, black_keys, compact_config, is_black, key_table
from bar_policy.tasks.piano.prior import KeyPosePriorConfig
from bar_policy.tasks.piano.reference import KeyPoseReference
from bar_policy.tasks.piano.results import SongResult, SongTicks
from bar_policy.tasks.piano.scene import FINGERTIP_GEOMS
from bar_policy.tasks.piano.songs import Song, count_in

TOP_COS = np.cos(np.deg2rad(45.0))
"""A contact whose normal is within 45 degrees of vertical is a *top* contact, else a *side* contact."""
HANDS = ("left", "right")


class _RecordingPolicy:
    """``policy`` with its last observation and raw action kept (the runtime calls it once a tick)."""

    def __init__(self, policy: OnnxPolicy) -> None:
        self._policy = policy
        self.last_obs = np.zeros(0, np.float32)
        self.last_action = np.zeros(0, np.float32)

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        action = self._policy(obs)
        self.last_obs, self.last_action = np.array(obs), np.array(action)
        return action

    def __getattr__(self, name: str) -> Any:
        return getattr(self._policy, name)


@dataclass
class Ticks:
    """One song's recorded ticks (the scored ones, in ``SongTicks``' order); hands left, right."""

    tip: list[np.ndarray] = field(default_factory=list)
    """Fingertip sphere centres, m, (2, 3) a tick."""
    touch: list[tuple[list[tuple[int, bool]], list[tuple[int, bool]]]] = field(default_factory=list)
    """Per hand: (MIDI number, top contact) of every key its fingertip sphere touches."""
    res_raw: list[np.ndarray] = field(default_factory=list)
    """Fingertip displacement of the raw residual, m, (2, 3) a tick."""
    res_filt: list[np.ndarray] = field(default_factory=list)
    """Fingertip displacement of the filtered residual (``q_cmd - q_ref``), m, (2, 3) a tick."""
    res_moved: list[np.ndarray] = field(default_factory=list)
    """Fingertip displacement of the raw residual with every black goal bit of ``target_keys`` moved to the
    white key below (``BLACK_TO_WHITE``), the rest of the observation as it was, m, (2, 3) a tick."""


class RecordingEpisodes(SimEpisodes):
    """``SimEpisodes`` that records the fingertips, contacts and residual at every scored tick."""

    def __init__(self, policy: OnnxPolicy) -> None:
        """``policy``: the loaded file; it is wrapped to keep its raw action."""
        self.recording = _RecordingPolicy(policy)
        super().__init__(self.recording)  # type: ignore[arg-type]
        self.reference = KeyPoseReference.for_policy(policy, compact_config())
        self.ticks = Ticks()
        self.max_raw_residual = 0.0
        """Largest |a - a_prior| seen, action units (0 for the prior's own file)."""

    def _setup(self, target: Any) -> None:
        m = target.model
        self._sites = [m.site(s).id for s in FINGERTIP_SITES]
        self._tips = [m.geom(g).id for g in FINGERTIP_GEOMS]
        self._key_of = {m.geom(f"piano_key{k.midi}").id: k.midi for k in key_table(compact_config())}
        self._dof = np.asarray(target.index.dof)
        n = len(self._dof)
        self._hand_cols = [np.arange(n) < n // 2, np.arange(n) >= n // 2]  # arms: left 7, then right 7
        self._jac = np.zeros((3, m.nv))
        kb = compact_config()
        self._targets = self.recording.obs_manager.term_slice("target_keys")
        self._black = np.flatnonzero(black_keys(kb))

    def target(self, **kwargs: Any) -> Any:
        """The sim target, its ids looked up once."""
        t = super().target(**kwargs)
        self._setup(t)
        return t

    def run(self, target: Any, commands: Any, duration: float, **kwargs: Any) -> Any:
        """One episode; every POLICY tick after ``evaluate``'s own hook, recorded into ``self.ticks``."""
        inner = kwargs.pop("on_tick", None)
        self.ticks = Ticks()

        def hook(k: int, t: float, rt: Any) -> None:
            if inner is not None:
                inner(k, t, rt)
            if rt.safety.mode == self.policy_mode:
                self._record(rt)

        return super().run(target, commands, duration, on_tick=hook, **kwargs)

    def _record(self, rt: Any) -> None:
        m, d = rt.target.model, rt.target.data
        ref = self.reference
        obs, action = self.recording.last_obs, self.recording.last_action
        diff = self._residual(obs, action)
        self.max_raw_residual = max(self.max_raw_residual, float(np.abs(diff).max()))
        dq_raw = np.zeros(len(self._dof))
        dq_raw[ref.action_index] = ref.action_scale * diff
        moved = obs.copy()
        goals = moved[self._targets].reshape(-1, compact_config().n_keys)  # (frames, keys), a view
        goals[:, self._black - 1] = np.maximum(goals[:, self._black - 1], goals[:, self._black])
        goals[:, self._black] = 0.0
        dq_moved = np.zeros(len(self._dof))
        dq_moved[ref.action_index] = ref.action_scale * self._residual(moved, self.recording(moved))
        q_ref = rt.commands.target_q()
        dq_filt = np.asarray(rt.last_command.q) - (q_ref if q_ref is not None else rt.last_command.q)
        tip, raw, filt, mov = (np.zeros((2, 3)) for _ in range(4))
        for h, site in enumerate(self._sites):
            tip[h] = d.site_xpos[site]
            mujoco.mj_jacSite(m, d, self._jac, None, site)
            cols = self._hand_cols[h]
            jac = self._jac[:, self._dof[cols]]
            raw[h], filt[h], mov[h] = jac @ dq_raw[cols], jac @ dq_filt[cols], jac @ dq_moved[cols]
        touch: tuple[list[tuple[int, bool]], list[tuple[int, bool]]] = ([], [])
        for c in d.contact[: d.ncon]:
            for h, g in enumerate(self._tips):
                other = c.geom2 if c.geom1 == g else c.geom1 if c.geom2 == g else None
                if other is not None and other in self._key_of:
                    touch[h].append((self._key_of[other], abs(c.frame[2]) >= TOP_COS))
        self.ticks.tip.append(tip)
        self.ticks.touch.append(touch)
        self.ticks.res_raw.append(raw)
        self.ticks.res_filt.append(filt)
        self.ticks.res_moved.append(mov)

    def _residual(self, obs: np.ndarray, action: np.ndarray) -> np.ndarray:
        """The policy's raw action minus the prior's for ``obs``, action units (float64, n_actions)."""
        ref = self.reference
        prior = np.asarray(ref.prior.blend(obs[ref.prior.start : ref.prior.stop]), np.float64)
        if ref.action_clip is not None:
            prior = np.clip(prior, -ref.action_clip, ref.action_clip)
        return action.astype(np.float64) - prior


@dataclass(frozen=True)
class NotePlay:
    """One note as one policy played it."""

    song: str
    key: int
    """MIDI number."""
    hand: int
    """0 left, 1 right."""
    sounded: bool
    """The key was down at some tick of the note."""
    depth_mm: float
    """At the lowest tick: fingertip x minus the key's aim point x, mm (+: further from the robot)."""
    lateral_mm: float
    """At the lowest tick: |fingertip y - key centre y|, mm."""
    height_mm: float
    """At the lowest tick: fingertip sphere bottom above the key's top at rest, mm."""
    contact: str
    """At the lowest tick: what the playing fingertip touches (``_contact_class``)."""
    touch_frac: dict[str, float]
    """Share of the note's ticks the fingertip touches: the goal key, a white neighbour, any key."""
    res_raw_mm: np.ndarray
    """Mean raw-residual fingertip displacement over the note's goal ticks, mm: x, y towards the key, z."""
    res_filt_mm: np.ndarray
    """The same for the filtered residual."""
    res_moved_mm: np.ndarray
    """The same for the raw residual with the black goal bits moved to the white key below."""


def _neighbours(midi: int) -> set[int]:
    """The white keys beside ``midi`` (a black key's two; a white key's white neighbours)."""
    out, step = set(), 1
    for s in (-1, 1):
        n = midi + s * step
        if is_black(n):
            n += s
        out.add(n)
    return out


def _contact_class(midi: int, touch: list[tuple[int, bool]]) -> str:
    """What a fingertip touches, by priority: the goal key's top, its side, a white neighbour, another key."""
    keys = {k for k, _ in touch}
    if (midi, True) in touch:
        return "goal key, top"
    if midi in keys:
        return "goal key, side"
    if keys & _neighbours(midi):
        return "white neighbour"
    return "another key" if keys else "nothing"


def notes_played(song: Song, ticks: SongTicks, rec: Ticks, dt: float, split: int) -> list[NotePlay]:
    """Each note of ``song`` as played: its lowest tick's fingertip, contacts and the residual."""
    kb = compact_config()
    keys: dict[int, Key] = {k.midi: k for k in key_table(kb)}
    tip = np.asarray(rec.tip)
    raw, filt, moved = np.asarray(rec.res_raw), np.asarray(rec.res_filt), np.asarray(rec.res_moved)
    out = []
    for n in count_in(song, ticks.count_in_s).notes:
        rows = np.flatnonzero((ticks.steps >= round(n.start_s / dt)) & (ticks.steps < round(n.end_s / dt)))
        rows = rows[ticks.goal[rows, n.key - kb.lowest]]
        if rows.size == 0:
            continue
        h = 0 if n.key < split else 1
        key = keys[n.key]
        low = rows[np.argmin(tip[rows, h, 2])]
        toward = np.sign(key.y - tip[rows, h, 1])
        per_tick = [rec.touch[i][h] for i in rows]
        goal_t = np.mean([any(k == n.key for k, _ in t) for t in per_tick])
        white_t = np.mean([any(k in _neighbours(n.key) for k, _ in t) for t in per_tick])
        any_t = np.mean([bool(t) for t in per_tick])

        def mean_push(
            r: np.ndarray, rows: np.ndarray = rows, h: int = h, toward: np.ndarray = toward
        ) -> np.ndarray:
            return 1e3 * np.array(
                [r[rows, h, 0].mean(), (r[rows, h, 1] * toward).mean(), r[rows, h, 2].mean()]
            )

        out.append(
            NotePlay(
                song=song.name,
                key=n.key,
                hand=h,
                sounded=bool(ticks.down[rows, n.key - kb.lowest].any()),
                depth_mm=1e3 * (tip[low, h, 0] - key.site[0]),
                lateral_mm=1e3 * abs(tip[low, h, 1] - key.y),
                height_mm=1e3 * (tip[low, h, 2] - kb.fingertip_radius - key.top_z),
                contact=_contact_class(n.key, rec.touch[low][h]),
                touch_frac={"goal key": goal_t, "white neighbour": white_t, "any key": any_t},
                res_raw_mm=mean_push(raw),
                res_filt_mm=mean_push(filt),
                res_moved_mm=mean_push(moved),
            )
        )
    return out


def run_policy(path: str, songs: list[Song]) -> tuple[list[NotePlay], list[SongResult], float]:
    """Play ``songs`` with the file at ``path``: each note as played, each song's result, the largest raw
    residual (action units)."""
    policy = load_policy(path)
    runner = RecordingEpisodes(policy)
    split = KeyPosePriorConfig().split_midi
    notes: list[NotePlay] = []

    def on_song(result: SongResult, ticks: SongTicks) -> None:
        if len(runner.ticks.tip) != len(ticks.steps):
            raise RuntimeError(f"{result.song}: {len(runner.ticks.tip)} recorded, {len(ticks.steps)} scored")
        notes.extend(notes_played(ticks.song, ticks, runner.ticks, policy.policy_dt, split))

    res = evaluate(policy, songs, runner=runner, on_song=on_song)
    return notes, res.songs, runner.max_raw_residual


CONTACTS = ("goal key, top", "goal key, side", "white neighbour", "another key", "nothing")


def _stat(xs: list[float]) -> str:
    """``median [p25, p75]`` of ``xs``, one decimal."""
    if not xs:
        return "n/a"
    q = np.percentile(xs, [50, 25, 75])
    return f"{q[0]:+.1f} [{q[1]:+.1f}, {q[2]:+.1f}]"


def _column(plays: list[NotePlay]) -> list[str]:
    """One policy's cells for one group of notes, in ``ROWS`` order."""
    n = len(plays)
    cells = [
        str(n),
        f"{sum(p.sounded for p in plays)}",
        _stat([p.depth_mm for p in plays]),
        _stat([p.lateral_mm for p in plays]),
        _stat([p.height_mm for p in plays]),
    ]
    cells += [f"{100 * sum(p.contact == c for p in plays) / max(n, 1):.0f} %" for c in CONTACTS]
    for k in ("goal key", "white neighbour", "any key"):
        cells.append(f"{100 * np.mean([p.touch_frac[k] for p in plays]) if plays else np.nan:.0f} %")
    for attr in ("res_raw_mm", "res_filt_mm", "res_moved_mm"):
        v = np.mean([getattr(p, attr) for p in plays], axis=0) if plays else np.full(3, np.nan)
        cells.append(f"{v[0]:+.1f} / {v[1]:+.1f} / {v[2]:+.1f}")
    return cells


ROWS = (
    "notes",
    "notes sounded",
    "lowest tick: depth x - aim x, mm (median [IQR])",
    "lowest tick: lateral abs(y - key y), mm",
    "lowest tick: sphere bottom above key top, mm",
    *(f"lowest tick touches: {c}" for c in CONTACTS),
    "ticks touching the goal key",
    "ticks touching a white neighbour",
    "ticks touching any key",
    "raw residual at the fingertip x / y to key / z, mm (mean)",
    "filtered residual (q_cmd - q_ref) x / y to key / z, mm",
    "raw residual, black goal bits moved to the white key below, x / y to key / z, mm",
)


def report(names: list[str], plays: list[list[NotePlay]], header: str) -> str:
    """The markdown table: note groups by colour and who sounded them, ``first / last`` policy per cell."""
    first, last = plays[0], plays[-1]
    groups = {
        "black, missed by last, sounded by first": lambda a, b: (
            is_black(a.key) and a.sounded and not b.sounded
        ),
        "black, sounded by both": lambda a, b: is_black(a.key) and a.sounded and b.sounded,
        "white, sounded by both": lambda a, b: not is_black(a.key) and a.sounded and b.sounded,
    }
    cols = []
    for pick in groups.values():
        idx = [i for i, (a, b) in enumerate(zip(first, last, strict=True)) if pick(a, b)]
        ca, cb = _column([first[i] for i in idx]), _column([last[i] for i in idx])
        cols.append(
            [x if x == y and r < 1 else f"{x} / {y}" for r, (x, y) in enumerate(zip(ca, cb, strict=True))]
        )
    lines = [header, "", f"Each cell: {names[0]} / {names[-1]} (one count: the same notes).", ""]
    lines.append("| | " + " | ".join(groups) + " |")
    lines.append("|---|" + "---:|" * len(groups))
    for r, row in enumerate(ROWS):
        lines.append(f"| {row} | " + " | ".join(c[r] for c in cols) + " |")
    return "\n".join(lines) + "\n"


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--seed", type=int, default=2026)
    p.add_argument("--songs", type=int, default=8, help="number of random songs")
    p.add_argument("--tempo", type=float, nargs=2, default=(60.0, 120.0), metavar=("LO", "HI"), help="bpm")
    p.add_argument("--duration", type=float, default=9.5, help="each song ends by this, s (the bank's 9.5)")
    p.add_argument("--policies", required=True, help="FIRST,LAST: two ONNX files (e.g. prior, shipped)")
    p.add_argument("--out", type=Path, help="write the markdown table here")
    args = p.parse_args()
    paths = args.policies.split(",")
    if len(paths) != 2:
        raise SystemExit(f"--policies: need two comma-separated files, got {len(paths)}")
    songs = [
        s for s, _ in random_songs(compact_config(), args.songs, args.duration, tuple(args.tempo), args.seed)
    ]
    plays = []
    for path in paths:
        t0 = time.perf_counter()
        notes, results, max_res = run_policy(path, songs)
        plays.append(notes)
        f1 = np.mean([r.f1 for r in results])
        faults = sum(r.faulted for r in results)
        print(
            f"{path}: {len(songs)} songs in {time.perf_counter() - t0:.0f} s, F1 {f1:.3f}, "
            f"{faults} faulted, largest raw residual {max_res:.3g} (action units)",
            flush=True,
        )
    if [(p.song, p.key) for p in plays[0]] != [(p.song, p.key) for p in plays[1]]:
        raise RuntimeError("the two policies' notes differ (a faulted song?)")
    lo, hi = args.tempo
    header = (
        f"Random songs: seed {args.seed}, {args.songs} songs, tempo U({lo:g}, {hi:g}) bpm; C MuJoCo sim "
        "target. Depth: + is further from the robot (a black key's aim point is 55 mm behind a white "
        "key's); heights against each key's own top (black tops 12 mm above white)."
    )
    text = report([Path(x).name for x in paths], plays, header)
    print(text)
    if args.out:
        args.out.write_text(text)


if __name__ == "__main__":
    main()
