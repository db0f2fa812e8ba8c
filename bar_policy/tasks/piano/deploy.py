"""The piano on the robot: ``--song NAME|PATH`` picks the song, ``--keys`` where the keys down come from.

``bar-deploy --policy piano.onnx --song ode_to_joy`` plays a library song (``song_library``), a song file
(``.json``, ``songs.read_song``) or a standard MIDI file (``.mid``/``.midi``, ``midi.load_midi``), each
checked for playability (the loader's refusal names the note). The sim target carries the keyboard
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
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from bar_policy.tasks.interfaces import DeployTask, EvalReport, OptionError
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
from bar_policy.tasks.piano.song_library import HELDOUT, SONG_NAMES, library_song
from bar_policy.tasks.piano.songs import Song, SongError, read_song
from bar_policy.tasks.piano.source import SongCommands

if TYPE_CHECKING:
    from bar_policy.robot.kinematics import Kinematics
    from bar_policy.robot.scene import SceneEdit
    from bar_policy.tasks.episodes import EpisodeRunner, Policy

__all__ = ["KEY_SOURCES", "TASK", "PianoTask", "eval_key_source", "key_source", "resolve_song"]

KEY_SOURCES = ("sim", "midi", "midi:PORT", "kinematic")
"""The ``--keys`` choices."""


def resolve_song(spec: str) -> Song:
    """A library song by name, or a song file (``.json``) / MIDI file (``.mid``, ``.midi``), checked.

    Raises ``OptionError`` naming the valid choices, or the loader's ``SongError`` naming the bad note.
    """
    kb = compact_config()
    if spec in SONG_NAMES:
        return library_song(spec)
    if spec in BLACK_HELDOUT:
        return heldout_song(spec)
    path = Path(spec)
    suffix = path.suffix.lower()
    if suffix not in (".json", ".mid", ".midi"):
        raise OptionError(
            f"--song {spec!r} is neither a library song ({', '.join(SONG_NAMES)}) nor a .json / .mid file"
        )
    if not path.is_file():
        raise OptionError(f"--song: file {spec!r} does not exist")
    try:
        if suffix == ".json":
            return read_song(path, kb)
        from bar_policy.tasks.piano.midi import load_midi

        return load_midi(path, kb)
    except SongError as e:
        msg = str(e).removeprefix(f"{spec}: ")  # the loader names the file first: once is enough
        raise OptionError(f"--song {spec}: {msg}") from None


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
    run_options = (("--song", "song"), ("--keys", "keys"))
    example_run = ("--song", "ode_to_joy")
    eval_options = (
        ("--songs", "songs"),
        ("--keys", "keys"),
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

    def add_eval_arguments(self, parser: argparse.ArgumentParser) -> None:
        """``--songs``, and ``--keys``: the policy's ``key_pressed`` source (the score counts the sim's)."""
        g = parser.add_argument_group("piano policies (key-press F1)")
        g.add_argument(
            "--songs",
            metavar="NAME[,NAME...]",
            help=f"songs to play (default the held-out ones: {', '.join(EVAL_HELDOUT)})",
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
        song = resolve_song(getattr(args, "song", None) or HELDOUT[0])
        emulated = getattr(args, "can_interface", None) == "virtual"
        keys = key_source(getattr(args, "keys", None), getattr(args, "target", "sim"), kin, emulated)
        reference = KeyPoseReference.for_policy(policy)
        return SongCommands(song, compact_config(), policy.policy_dt, keys, reference=reference)

    def plot(self, arrays: dict[str, np.ndarray], meta: dict[str, Any], out: Path) -> list[Path]:
        """The piano roll (``plot.piano_roll``)."""
        from bar_policy.tasks.piano.plot import piano_roll

        return piano_roll(arrays, meta, out)

    def evaluate(self, policy: Policy, args: argparse.Namespace, runner: EpisodeRunner) -> EvalReport:
        """Key-press precision, recall and F1 per song on the C MuJoCo sim target (``evaluate.py``)."""
        from bar_policy.tasks.piano.evaluate import evaluate

        keys = eval_key_source(getattr(args, "keys", None))  # refused before any song plays
        names = getattr(args, "songs", None)
        songs = (
            [resolve_song(s) for s in names.split(",")] if names else [heldout_song(n) for n in EVAL_HELDOUT]
        )
        count = getattr(args, "random_songs", None)
        count = (0 if names else RANDOM_EVAL_SONGS) if count is None else count  # --songs: those alone
        seed = getattr(args, "random_seed", None)
        seed = RANDOM_EVAL_SEED if seed is None else seed
        if count < 0:
            raise OptionError(f"--random-songs {count}: give a count >= 0 (0: no random songs)")
        randoms = random_eval_songs(count, seed)
        label = f"{count} of the bank's kind, seed {seed}, never trained on"
        return evaluate(policy, songs, runner=runner, keys=keys, random_songs=randoms, random_label=label)


TASK = PianoTask()
"""The ``piano`` deploy task."""
