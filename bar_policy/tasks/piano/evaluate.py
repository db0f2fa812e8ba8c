"""``bar-deploy eval`` for piano policies: each song on the C MuJoCo sim target, scored as RoboPianist does.

Each song runs from the held default pose (``held.held_pose``, as the env starts), with the policy from the
first tick (no ramp), through the deploy code path (the runner ``bar-deploy eval`` hands in,
``tasks.episodes.EpisodeRunner``: ``Runtime``, the safety supervisor, the firmware MIT law in the sim), in the
keyboard's scene with the simulated keys, each song with the env's count-in (``bank.PlaybackConfig``). At
every policy tick the goal keys of the song's step are compared with the keys down (``SongCommands.goal_now``,
``keys_down``): true positives, false positives and false negatives give each tick's precision, recall and F1
(``metrics``). Only the song's ticks count: from its first note's start to its last note's end
(``metrics.song_window``; ``SongCommands.tally``, the ticks the run summary of ``bar-deploy --song`` scores
too): keys pressed during the start-up, the count-in's silence or the final hold are not the song's. A song's
figures are the means over its ticks (RoboPianist's), with the F1 of the summed counts beside them (pooled),
and the recall of its black and of its white goal key-ticks (pooled, as the MJX evaluation's ``recall_black``
/ ``recall_white``; 1 in the JSON, ``-`` in the lines, for a song without a goal key of that colour). The ship
gate reads the mean F1 over every song's ticks (``success_pct`` = 100 x F1) and the songs' safety and
smoothness.

Chatter: the gate's is measured on ``q_cmd`` minus the song's key-pose reference (``reference.py``: the
key-pose prior's command for the tick's goal keys, through the policy's action filter; the source's
``target_q``), as the tracker's is on ``q_cmd`` minus its clip. The key-pose prior alone (a zero MLP)
commands the reference exactly and scores ~0; on ``q_cmd`` itself it scores 6-10 mrad, its keystrokes'
harmonics at 5-8 Hz. Each song's line also prints the chatter of ``q_cmd`` itself (``chatter_raw_mrad``,
not gated; both in ``--json``), and a line after the quality line gives its worst and mean over the
songs that completed (docs/piano.md, "Chatter against the key-pose reference").

Key sources (``keys``, ``bar-deploy eval --keys``): the policy's ``key_pressed`` comes from ``sim`` (the
simulated keys, the default), ``kinematic`` (the fingertips' forward kinematics of the measured q, what the
mock and real targets use without a keyboard) or ``sim-midi`` (``key_input.SimMidiKeys``: the simulated
keys' presses and releases turned into ``mido`` note messages and fed in memory to ``MidiKeys``: the MIDI
path end to end, without a port). The score always counts the simulated keys, the keys that really went
down (``SongCommands``'s ``truth``); each song also counts the ticks' keys where the source and the
simulated keys disagree. The result types are ``results.py``'s.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np

from bar_policy.quality.metrics import chatter_mrad
from bar_policy.tasks.episodes import EpisodeRunner, Policy, report_progress
from bar_policy.tasks.piano.bank import PlaybackConfig
from bar_policy.tasks.piano.held import held_pose
from bar_policy.tasks.piano.key_input import KeySource, SimMidiKeys
from bar_policy.tasks.piano.keyboard import KeyboardConfig, compact_config
from bar_policy.tasks.piano.keys import KinematicKeys
from bar_policy.tasks.piano.reference import KeyPoseReference
from bar_policy.tasks.piano.results import PianoEval, SongResult, SongTicks
from bar_policy.tasks.piano.scene import keyboard_scene
from bar_policy.tasks.piano.songs import Song
from bar_policy.tasks.piano.source import END_HOLD_S, SongCommands, policy_playback, sim_keys

__all__ = ["EVAL_KEY_SOURCES", "evaluate"]

EVAL_KEY_SOURCES = ("sim", "kinematic", "sim-midi")
"""Where the policy's ``key_pressed`` can come from in the evaluation (module docstring)."""


def evaluate(
    policy: Policy,
    songs: list[Song],
    target: Any = None,
    *,
    runner: EpisodeRunner,
    playback: PlaybackConfig | None = None,
    keys: str = "sim",
    on_song: Callable[[SongResult, SongTicks], None] | None = None,
    group: str = "held-out",
    random_songs: Sequence[Song] = (),
    random_label: str = "",
    arrangements: Mapping[str, Mapping[str, Any]] | None = None,
) -> PianoEval:
    """Play each song once on ``target`` (default: ``runner``'s in the keyboard's scene; module docstring).

    ``playback``: the count-in and the goal keys' lead (default ``source.policy_playback(policy)``: the
    env's count-in and the file's lead, as ``bar-deploy`` plays). ``keys``: where
    the policy's ``key_pressed`` comes from, one of ``EVAL_KEY_SOURCES`` (the score counts the simulated
    keys whatever it is). ``on_song``: called after each song with its result and its scored ticks as arrays
    (``SongTicks``), for analyses beyond the means. ``group``: the group of ``songs`` (``SongResult.group``);
    ``random_songs`` are played after them as the ``random`` group, ``random_label`` saying how they were
    drawn. ``arrangements``: song name -> ``Arrangement.to_dict`` of the songs played arranged, carried into
    the report's JSON. Raises ``ValueError`` for another ``keys``, naming the valid ones.
    """
    if keys not in EVAL_KEY_SOURCES:
        raise ValueError(f"keys = {keys!r}; valid: {', '.join(EVAL_KEY_SOURCES)}")
    kb = compact_config()
    sim = target or runner.target(scene=keyboard_scene(kb))
    kp = np.asarray(policy.metadata.joint_stiffness, np.float64)  # the file's gains, as the env trained it
    q0 = held_pose(policy.robot.pose("piano_ready"), policy.robot.mode, kp=kp)  # as the env starts
    reference = KeyPoseReference.for_policy(policy, kb)
    pb = policy_playback(policy) if playback is None else playback
    fingertips = None
    if keys == "kinematic":  # one model build for every song
        from bar_policy.robot.kinematics import Kinematics

        fingertips = Kinematics(policy.robot.mode).fingertips
    results = []
    played = [*((s, group) for s in songs), *((s, "random") for s in random_songs)]
    for index, (song, in_group) in enumerate(played, 1):
        sim.reset(q0)
        source, truth = _key_sources(keys, sim, kb, fingertips)
        commands = SongCommands(song, kb, policy.policy_dt, source, pb, reference, truth=truth)
        reads: list[np.ndarray] = []
        q_cmds: list[np.ndarray] = []

        def score(
            k: int, t: float, rt: Any, c: SongCommands = commands, r: list = reads, qc: list = q_cmds
        ) -> None:
            if rt.safety.mode != runner.policy_mode:  # the hold after the song's end is not scored
                return
            qc.append(rt.last_command.q)  # the tick's q_cmd as the supervisor wrote it
            if c.in_song():  # the runtime scored it in c.tally (after_policy_tick): the song's window
                r.append(c.record()["keys_down"])  # what fed key_pressed

        duration = commands.song_steps * policy.policy_dt + END_HOLD_S + 1.0
        res = runner.run(sim, commands, duration, on_tick=score)
        commands.close()
        tally = commands.tally
        down, goal = tally.down, tally.goal
        read = np.array(reads, bool).reshape(-1, kb.n_keys)
        counts = tally.counts()
        precision, recall, f1 = tally.means()
        raw = chatter_mrad(np.array(q_cmds), policy.policy_dt) if q_cmds else math.nan
        result = SongResult(
            song=song.name,
            ticks=int(res.ticks),
            scored=tally.ticks,
            true_pos=counts.tp,
            false_pos=counts.fp,
            false_neg=counts.fn,
            precision=precision,
            recall=recall,
            f1=f1,
            faulted=res.fault_count > 0,
            end_reason=res.end_reason,
            quality={**res.quality["episode"], "name": song.name},
            chatter_raw_mrad=_finite(raw),
            keys=keys,
            keys_extra=int(np.sum(read & ~down)),
            keys_missed=int(np.sum(down & ~read)),
            keys_down=int(np.sum(down)),
            **tally.colour(),
            group=in_group,
            **_hand_load(res.hand_load),
        )
        results.append(result)
        fault = ", faulted" if result.faulted else ""
        figure = f"{song.name}, precision {precision:.3f} recall {recall:.3f} F1 {f1:.3f}{fault}"
        report_progress(runner, "song", index, len(played), figure)
        if on_song is not None:
            on_song(result, SongTicks(song, tally.steps, down, goal, pb.count_in_s))
    return PianoEval(
        songs=results,
        policy=str(policy.path),
        fingerprint=policy.obs_manager.fingerprint,
        random_songs=random_label,
        arrangements=dict(arrangements or {}),
        target=runner.target_label if target is None else type(target).__name__,
    )


def _key_sources(
    keys: str, sim: Any, kb: KeyboardConfig, fingertips: Callable[[np.ndarray], Any] | None
) -> tuple[KeySource | None, KeySource | None]:
    """The song's ``key_pressed`` source and the simulated keys it is scored against (``truth``).

    ``sim``: (None, None): the runtime attaches the simulated keys, which both feed and score. Otherwise the
    truth is the sim target's keys read as ``attach`` reads them (the hinge now), so the scores compare.
    ``fingertips``: the robot's forward kinematics, for ``kinematic`` (built once per evaluation).
    """
    if keys == "sim":
        return None, None
    truth = sim_keys(sim, kb)
    if keys == "sim-midi":  # its own reader: each SimKeys counts what it reads
        return SimMidiKeys(sim_keys(sim, kb), kb), truth
    assert fingertips is not None, "kinematic keys need the robot's fingertips"
    return KinematicKeys(kb, fingertips), truth


def _finite(x: float) -> float | None:
    """``x`` as a float, None for NaN (a window too short to measure)."""
    x = float(x)
    return None if np.isnan(x) else x


def _hand_load(record: dict[str, Any]) -> dict[str, Any]:
    """``SongResult``'s hand-load fields from a run's record (``RunResult.hand_load``); none without a fit."""
    mass = record.get("mass_kg")
    if mass is None:
        return {}
    return {
        "hand_load_kg": (float(mass["left"]), float(mass["right"])),
        "hand_load_motion_mrad": 1e3 * float(record["motion_rad"]),
    }
