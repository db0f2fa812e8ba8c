"""The piano on the robot: ``--song NAME|PATH`` picks the song, ``--keys`` where the keys down come from.

``bar-deploy --policy piano.onnx --song ode_to_joy`` plays a library song (``song_library``), a song file
(``.json``, ``songs.read_song``) or a standard MIDI file (``.mid``/``.midi``, ``midi.arrange_midi``), each
checked for playability (the loader's refusal names the note). ``--tempo FACTOR|auto`` (run and eval
alike) scales the song (``arrange.arrange``); the arrangement's changes are printed at the start and logged
in the command source's metadata. The sim target carries the keyboard
(``scene``), and ``--keys`` defaults to its simulated keys there; on the mock and real targets the default is
the fingertips' kinematics, or ``--keys midi:PORT`` reads a MIDI keyboard. ``bar-deploy eval`` plays every
held-out song (``heldout.EVAL_HELDOUT``) and 32 random songs of the training bank's kind (a seed never trained
on; ``--random-songs``, ``--random-seed``) on the sim target and reports precision, recall and F1 per song and
the per-colour recall of each set (``evaluate.py``), its ``--keys`` (``EVAL_KEY_SOURCES``) feeding
``key_pressed`` while the score counts the simulated keys. Both measure chatter against the song's key-pose
reference (``reference.py``). No jax, no torch.
"""

from __future__ import annotations

import argparse
import logging
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from bar_policy.tasks.interfaces import CommandSource, DeployTask, EvalReport, OptionError, RunFigure
from bar_policy.tasks.piano.arrange import Arrangement, arrange, parse_tempo
from bar_policy.tasks.piano.heldout import (
    BLACK_HELDOUT,
    EVAL_HELDOUT,
    RANDOM_EVAL_SEED,
    RANDOM_EVAL_SONGS,
    heldout_song,
    random_eval_songs,
)
from bar_policy.tasks.piano.key_input import KeySource, MidiKeys
from bar_policy.tasks.piano.keyboard import compact_config
from bar_policy.tasks.piano.keys import KinematicKeys
from bar_policy.tasks.piano.scene import keyboard_scene
from bar_policy.tasks.piano.song_library import HELDOUT, SONG_NAMES, library_bpm, library_song
from bar_policy.tasks.piano.songs import Song, SongError, read_song, song_from_json
from bar_policy.tasks.piano.source import SongCommands, policy_playback

if TYPE_CHECKING:
    from bar_policy.robot.kinematics import Kinematics
    from bar_policy.robot.scene import SceneEdit
    from bar_policy.tasks.episodes import EpisodeRunner, Policy

__all__ = [
    "KEY_SOURCES",
    "TASK",
    "PianoTask",
    "eval_key_source",
    "key_source",
    "resolve_arrangement",
    "resolve_song",
    "song_tempo",
]

log = logging.getLogger(__name__)

KEY_SOURCES = ("sim", "midi", "midi:PORT", "kinematic")
"""The ``--keys`` choices."""


def resolve_song(spec: str, tempo: float | str | None = None) -> Song:
    """The song of ``resolve_arrangement`` (its arrangement aside)."""
    return resolve_arrangement(spec, tempo)[0]


def resolve_arrangement(spec: str, tempo: float | str | None = None) -> tuple[Song, Arrangement | None]:
    """A library song by name, or a song file (``.json``) / MIDI file (``.mid``, ``.midi``), checked.

    A MIDI file is always arranged (``midi.arrange_midi``: hands, tempo, articulation); a library song or a
    song file only with a ``tempo`` (``--tempo``: a factor or ``auto``), and is played as written without.
    Returns the song and its arrangement (None: as written). Raises ``OptionError`` naming the valid
    choices, or the loader's ``SongError`` naming the bad note.
    """
    kb = compact_config()
    if spec in BLACK_HELDOUT:  # the held-out songs of heldout.py, by name
        song = heldout_song(spec)
        try:
            return (song, None) if tempo is None else _arranged(arrange(song, tempo, kb))
        except SongError as e:
            raise OptionError(f"--song {spec}: {str(e).removeprefix(f'{spec}: ')}") from None
    path = Path(spec)
    suffix = path.suffix.lower()
    if spec not in SONG_NAMES:
        if suffix not in (".json", ".mid", ".midi"):
            raise OptionError(
                f"--song {spec!r} is neither a library song ({', '.join(SONG_NAMES)}) nor a .json / .mid file"
            )
        if not path.is_file():
            raise OptionError(f"--song: file {spec!r} does not exist")
    try:
        if spec in SONG_NAMES:
            if tempo is None:
                return library_song(spec), None
            return _arranged(arrange(library_song(spec), tempo, kb, written_bpm=library_bpm(spec)))
        if suffix == ".json":
            if tempo is None:
                return read_song(path, kb), None
            return _arranged(arrange(song_from_json(path.read_bytes(), spec), tempo, kb))
        from bar_policy.tasks.piano.midi import arrange_midi

        return _arranged(arrange_midi(path, tempo, kb))
    except SongError as e:
        msg = str(e).removeprefix(f"{spec}: ")  # the loader names the file first: once is enough
        raise OptionError(f"--song {spec}: {msg}") from None


def _arranged(arrangement: Arrangement) -> tuple[Song, Arrangement]:
    return arrangement.song, arrangement


def song_tempo(args: argparse.Namespace) -> float | str | None:
    """``--tempo`` parsed (``arrange.parse_tempo``); ``OptionError`` naming the choices."""
    try:
        return parse_tempo(getattr(args, "tempo", None))
    except ValueError as e:
        raise OptionError(str(e)) from None


def key_source(
    spec: str | None, target: str, kinematics: Kinematics, emulated: bool = False
) -> KeySource | None:
    """The ``--keys`` source: None for ``sim`` (the runtime attaches the simulated keys of the target).

    ``emulated``: the real target runs on the in-process bus emulator (``--can-interface virtual``), whose
    scene has the keyboard, so ``sim`` keys (its default there) exist.
    """
    kb = compact_config()
    simulated = target == "sim" or (target == "real" and emulated)
    spec = spec or ("sim" if simulated else "kinematic")
    if spec == "sim":
        if not simulated:
            raise OptionError(
                f"--keys sim needs --target sim or the emulated bus (the {target} target has no "
                "simulated keys)"
            )
        return None
    if spec == "kinematic":
        return KinematicKeys(kb, kinematics.fingertips)
    kind, _, port = spec.partition(":")
    if kind == "midi":
        import mido  # a deploy extra, imported when a keyboard is asked for

        names = mido.get_input_names()
        if not port and not names:
            raise OptionError("--keys midi: no MIDI input is connected; give --keys midi:PORT or kinematic")
        try:
            return MidiKeys(port or names[0], kb)
        except (OSError, ValueError) as e:
            raise OptionError(f"--keys {spec}: cannot open MIDI input ({e}); inputs: {names}") from None
    raise OptionError(f"unknown --keys {spec!r}; valid: {', '.join(KEY_SOURCES)}")


def eval_key_source(spec: str | None) -> str:
    """``bar-deploy eval --keys``: ``sim`` when not given; ``OptionError`` naming the valid choices.

    Only sources the sim target can drive: a MIDI keyboard's keys would not be the simulated ones the score
    counts, so ``midi[:PORT]`` is refused (``sim-midi`` sends the simulated keys through the MIDI path).
    """
    from bar_policy.tasks.piano.evaluate import EVAL_KEY_SOURCES

    spec = spec or "sim"
    if spec not in EVAL_KEY_SOURCES:
        raise OptionError(f"unknown eval --keys {spec!r}; valid: {', '.join(EVAL_KEY_SOURCES)}")
    return spec


class PianoTask(DeployTask):
    """``piano``: ``--song NAME|PATH``, ``--keys``; eval: F1 per held-out song on the sim target."""

    name = "piano"
    summary = "play the keyboard"
    usage = "give --song NAME|PATH (a library song, a song .json or a .mid file)"
    run_options = (("--song", "song"), ("--keys", "keys"), ("--tempo", "tempo"))
    example_run = ("--song", "ode_to_joy")
    eval_options = (
        ("--songs", "songs"),
        ("--keys", "keys"),
        ("--tempo", "tempo"),
        ("--random-songs", "random_songs"),
        ("--random-seed", "random_seed"),
    )
    default_duration = None

    def add_run_arguments(self, parser: argparse.ArgumentParser) -> None:
        """``--song`` and ``--keys``."""
        g = parser.add_argument_group("piano policies (songs)")
        songs = ", ".join(SONG_NAMES)
        g.add_argument(
            "--song",
            metavar="NAME|PATH",
            help=f"song to play: {songs}, or a .json song file "
            "or a .mid file (default: the first held-out song)",
        )
        g.add_argument(
            "--keys",
            metavar="SOURCE",
            help="where key_pressed comes from: sim (the sim target's "
            "keys, its default), midi[:PORT] (a MIDI keyboard), kinematic (the fingertips; the "
            "mock and real targets' default)",
        )
        _tempo_argument(g)

    def add_eval_arguments(self, parser: argparse.ArgumentParser) -> None:
        """``--songs``, and ``--keys``: the policy's ``key_pressed`` source (the score counts the sim's)."""
        g = parser.add_argument_group("piano policies (key-press F1)")
        g.add_argument(
            "--songs",
            metavar="NAME[,NAME...]",
            help=f"songs to play: names or .json / .mid files (default the held-out ones: "
            f"{', '.join(EVAL_HELDOUT)})",
        )
        g.add_argument(
            "--random-songs",
            type=int,
            metavar="N",
            help=f"random songs of the training bank's kind to play after them (default {RANDOM_EVAL_SONGS}, "
            "none with --songs; 0: none, and the gate's random recall rows are not measured)",
        )
        g.add_argument(
            "--random-seed",
            type=int,
            metavar="SEED",
            help=f"their seed (default {RANDOM_EVAL_SEED}, never a training bank's)",
        )
        g.add_argument(
            "--keys",
            metavar="SOURCE",
            help="where the policy's key_pressed comes from: sim "
            "(the simulated keys, default), kinematic (the fingertips, as on the mock and real "
            "targets), sim-midi (the simulated keys sent as MIDI messages in memory); F1 always "
            "counts the simulated keys",
        )
        _tempo_argument(g)

    def scene(self, policy: Policy) -> SceneEdit | None:
        """The keyboard the policy was trained at (``compact_config()``)."""
        return keyboard_scene(compact_config())

    def command_source(
        self, policy: Policy, args: argparse.Namespace, kinematics: Kinematics | None = None
    ) -> SongCommands:
        """The song ``--song`` names, with the ``--keys`` source and the policy's key-pose reference.

        The reference (``reference.KeyPoseReference``, from the policy's metadata) is what the run's chatter
        is measured against (``SongCommands.target_q``).
        """
        from bar_policy.robot.kinematics import Kinematics
        from bar_policy.tasks.piano.reference import KeyPoseReference

        kin = kinematics or Kinematics(policy.robot.mode)
        song, arrangement = resolve_arrangement(getattr(args, "song", None) or HELDOUT[0], song_tempo(args))
        if arrangement is not None:
            log.info("%s", "\n".join(arrangement.lines()))
        emulated = getattr(args, "can_interface", None) == "virtual"
        keys = key_source(getattr(args, "keys", None), getattr(args, "target", "sim"), kin, emulated)
        reference = KeyPoseReference.for_policy(policy)
        return SongCommands(
            song,
            compact_config(),
            policy.policy_dt,
            keys,
            policy_playback(policy),
            reference=reference,
            arrangement=arrangement,
        )

    def run_figure(
        self, policy: Policy, commands: CommandSource, kinematics: Kinematics | None = None
    ) -> RunFigure | None:
        """The song's precision, recall, F1 and per-colour recall over its window (``tally.SongFigure``)."""
        if not isinstance(commands, SongCommands):
            return None
        from bar_policy.tasks.piano.tally import SongFigure

        return SongFigure(commands.tally, commands.song.name, commands.dt)

    def plot(self, arrays: dict[str, np.ndarray], meta: dict[str, Any], out: Path) -> list[Path]:
        """The piano roll (``plot.piano_roll``)."""
        from bar_policy.tasks.piano.plot import piano_roll

        return piano_roll(arrays, meta, out)

    def evaluate(self, policy: Policy, args: argparse.Namespace, runner: EpisodeRunner) -> EvalReport:
        """Key-press precision, recall and F1 per song on the C MuJoCo sim target (``evaluate.py``)."""
        from bar_policy.tasks.piano.evaluate import evaluate

        keys = eval_key_source(getattr(args, "keys", None))  # refused before any song plays
        names = getattr(args, "songs", None)
        tempo = song_tempo(args)
        songs, arrangements = [], {}
        for name in names.split(",") if names else EVAL_HELDOUT:
            song, arrangement = resolve_arrangement(name, tempo)
            if arrangement is not None:
                log.info("%s", "\n".join(arrangement.lines()))
                arrangements[song.name] = arrangement.to_dict()
            songs.append(song)
        count = getattr(args, "random_songs", None)
        count = (0 if names else RANDOM_EVAL_SONGS) if count is None else count  # --songs: those alone
        seed = getattr(args, "random_seed", None)
        seed = RANDOM_EVAL_SEED if seed is None else seed
        if count < 0:
            raise OptionError(f"--random-songs {count}: give a count >= 0 (0: no random songs)")
        randoms = random_eval_songs(count, seed)
        label = f"{count} of the bank's kind, seed {seed}, never trained on"
        return evaluate(
            policy,
            songs,
            runner=runner,
            keys=keys,
            random_songs=randoms,
            random_label=label,
            arrangements=arrangements,
        )


def _tempo_argument(group: argparse._ArgumentGroup) -> None:
    """``--tempo FACTOR|auto``, the same on ``bar-deploy`` and ``bar-deploy eval``."""
    group.add_argument(
        "--tempo",
        metavar="FACTOR|auto",
        help="play the song(s) at FACTOR times the written tempo (0.5: half speed), or auto: the fastest "
        "the arms play, at most the written tempo; a .mid file is always arranged (hands, every note "
        "ended in time for its hand's next, the changes printed and logged), a library song or .json "
        "file only with --tempo (default: as written)",
    )


TASK = PianoTask()
"""The ``piano`` deploy task."""
