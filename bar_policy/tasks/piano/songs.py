"""Songs for the piano task: notes with keys, times and hands; validation against the arms; goal keys.

The format (JSON, ``song_to_json`` / ``song_from_json``, ``read_song`` / ``write_song``)::

    {"format": "bar_policy.piano.song/1", "name": "ode_to_joy",
     "notes": [{"key": 64, "start_s": 0.0, "end_s": 0.5, "hand": "right"}, ...]}

``key`` is the MIDI note number (60 = C4, middle C), times are seconds from the song's start, ``hand`` is
``left``, ``right`` or ``either`` (the validator chooses). Standard MIDI files load through ``midi.py``.

``playable`` refuses, naming the note: a key off the keyboard or out of its hand's reach
(``keyboard.LEFT_REACH`` / ``RIGHT_REACH``); two notes of one hand that overlap (one key per hand at a
time); a note shorter than ``TempoLimits.min_note_s``; and a tempo beyond the arms: between two consecutive
notes of one hand the fingertip must lift and move from one key's aim point to the next at no more than
``max_speed``, so the next note may start no sooner than ``required_gap`` after the previous one ends. A
tempo refusal gives the factor that plays the note (``x0.5``: half speed); a note that starts as the
previous one ends (legato) is refused for its missing gap, which no tempo opens (``arrange.arrange``, which
the MIDI loader and ``--tempo`` use, ends each note in time).
``either`` notes are given, in time order, to the one hand that can play them, or when both can to the
hand on the note's side of ``split`` (below middle C: left). numpy only.

Every song read from a file is bounded before anything is built from it (``check_song_size``): a file of at
most ``MAX_SONG_FILE_BYTES``, at most ``MAX_SONG_NOTES`` notes, its last note ending by ``MAX_SONG_S``; the
goal-key tables played from it (``source.SongCommands``) must fit ``MAX_SONG_TABLE_BYTES``. Each refusal
names the limit and its value: a note held for 4.5e9 s would otherwise ask for 40 TiB of tables.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from functools import cache
from pathlib import Path

import numpy as np

from bar_policy._files import InputError, loads_json, shorten, strict_json
from bar_policy.signals import check_stop
from bar_policy.tasks.piano.keyboard import (
    HAND_SPLIT_MIDI,
    LEFT_REACH,
    RIGHT_REACH,
    KeyboardConfig,
    default_config,
    key_table,
    note_name,
)

__all__ = [
    "FORMAT",
    "HANDS",
    "MAX_SONG_FILE_BYTES",
    "MAX_SONG_NOTES",
    "MAX_SONG_S",
    "MAX_SONG_TABLE_BYTES",
    "Note",
    "Song",
    "SongError",
    "TempoLimits",
    "check_song_file",
    "check_song_size",
    "check_table_size",
    "count_in",
    "goal_keys",
    "key_distance",
    "playable",
    "read_song",
    "required_gap",
    "song_from_json",
    "song_to_json",
    "write_song",
]

FORMAT = "bar_policy.piano.song/1"
"""The ``format`` field of a song file."""
HANDS: tuple[str, ...] = ("left", "right", "either")
"""Valid ``Note.hand`` values."""

MAX_SONG_S = 600.0
"""Latest end of a song's last note, s (10 min: the library's songs last under a minute)."""
MAX_SONG_NOTES = 5000
"""Most notes in one song (5000 notes in 10 min is 8 a second, past what the arms' tempo allows)."""
MAX_SONG_FILE_BYTES = 512 * 1024
"""Largest song file (JSON or MIDI) read, bytes: 5000 notes take about 350 kB as JSON, 40 kB as MIDI (a
performance's pedal and controller messages add to that). ``mido`` parses MIDI at about 0.1 MB/s on the
project's loaded 2-core CPU (450 kB in 31 s): a larger bound would be a long wait before any refusal."""
MAX_SONG_TABLE_BYTES = 256 * 1024 * 1024
"""Largest goal-key tables built for playback, bytes, at their peak: 10 bytes per key and control step
(``bank.song_bank`` keeps float32 keys down and a uint8 per hand, 6 bytes, and ``goal_keys`` builds a
float32 working table, 4). 600 s at 50 Hz is 30 000 steps: 15 MB on the 49-key compact keyboard; the
limit binds only at a control period far below 20 ms."""
TABLE_BYTES_PER_KEY_STEP = 10
"""Peak bytes of goal-key tables per key and control step (``MAX_SONG_TABLE_BYTES``)."""


class SongError(InputError):
    """A song that cannot be read or played (the message names the note)."""


def check_song_file(path: Path) -> None:
    """Refuse a song file larger than ``MAX_SONG_FILE_BYTES`` before reading it (``SongError``)."""
    size = path.stat().st_size
    if size > MAX_SONG_FILE_BYTES:
        raise SongError(
            f"{path}: the file has {size} bytes; a song file may have at most {MAX_SONG_FILE_BYTES} "
            f"(bar_policy.tasks.piano.songs.MAX_SONG_FILE_BYTES, {MAX_SONG_NOTES} notes fit in far less)"
        )


def check_song_size(what: str, n_notes: int, end_s: float) -> None:
    """Refuse a song of more than ``MAX_SONG_NOTES`` notes or one ending after ``MAX_SONG_S`` (``SongError``).

    ``end_s``: the end of its last note so far, s (loaders call this while they read, to stop early).
    """
    if n_notes > MAX_SONG_NOTES:
        raise SongError(
            f"{what}: more than {MAX_SONG_NOTES} notes; a song may have at most {MAX_SONG_NOTES} "
            "(bar_policy.tasks.piano.songs.MAX_SONG_NOTES): split it into shorter songs"
        )
    if end_s > MAX_SONG_S:
        raise SongError(
            f"{what}: a note ends at {end_s:.4g} s; a song must end by {MAX_SONG_S:g} s "
            "(bar_policy.tasks.piano.songs.MAX_SONG_S): cut it or split it into shorter songs"
        )


def check_table_size(what: str, steps: int, n_keys: int) -> None:
    """Refuse goal-key tables of ``steps`` x ``n_keys`` past ``MAX_SONG_TABLE_BYTES`` (``SongError``)."""
    need = TABLE_BYTES_PER_KEY_STEP * steps * n_keys
    if need > MAX_SONG_TABLE_BYTES:
        raise SongError(
            f"{what}: playing it needs {need / 2**20:.4g} MiB of goal-key tables ({steps} control steps x "
            f"{n_keys} keys x {TABLE_BYTES_PER_KEY_STEP} bytes); the limit is "
            f"{MAX_SONG_TABLE_BYTES / 2**20:.4g} MiB "
            "(bar_policy.tasks.piano.songs.MAX_SONG_TABLE_BYTES): a shorter song or a longer control period"
        )


@dataclass(frozen=True)
class Note:
    """One note: a key held from ``start_s`` to ``end_s`` by one hand."""

    key: int
    """MIDI note number (60 = C4)."""
    start_s: float
    """Press time, s from the song's start."""
    end_s: float
    """Release time, s (> ``start_s``)."""
    hand: str = "either"
    """``left``, ``right`` or ``either``."""

    def describe(self) -> str:
        """``E4 (64) at 1.200-1.700 s, right``: how error messages name a note."""
        return f"{note_name(self.key)} ({self.key}) at {self.start_s:.3f}-{self.end_s:.3f} s, {self.hand}"


@dataclass(frozen=True)
class Song:
    """A named sequence of notes, sorted by start time (then key). Checks form, not playability."""

    name: str
    """Song name."""
    notes: tuple[Note, ...] = field(default_factory=tuple)
    """The notes."""

    def __post_init__(self) -> None:
        """Sort the notes and refuse malformed ones (``SongError`` naming the note)."""
        notes = tuple(sorted(self.notes, key=lambda n: (n.start_s, n.key)))
        object.__setattr__(self, "notes", notes)
        for i, n in enumerate(notes):
            bad = None
            if isinstance(n.key, bool) or not isinstance(n.key, int) or not 0 <= n.key <= 127:
                bad = f"key {shorten(n.key)!r} is not a MIDI note number 0..127"
            elif n.hand not in HANDS:
                bad = f"hand {shorten(n.hand)!r} is not one of {list(HANDS)}"
            elif not (math.isfinite(n.start_s) and math.isfinite(n.end_s)) or n.start_s < 0.0:
                bad = "times must be finite and start at or after 0 s"
            elif n.end_s <= n.start_s:
                bad = "it ends before it starts"
            if bad:
                raise SongError(f"song {self.name!r}, note {i} ({shorten(n)}): {bad}")

    @property
    def duration_s(self) -> float:
        """End of the last note, s (0 for an empty song)."""
        return max((n.end_s for n in self.notes), default=0.0)


@dataclass(frozen=True, kw_only=True)
class TempoLimits:
    """What the arms can play."""

    max_speed: float = 0.5
    """Fingertip speed between keys, m/s (the straight line between the keys' aim points)."""
    min_note_s: float = 0.15
    """Shortest note, s."""
    min_gap_s: float = 0.05
    """Shortest release-to-press time of one hand, s (lifting and pressing again, even on the same key)."""

    def __post_init__(self) -> None:
        """Refuse non-positive limits (``ValueError`` naming the value)."""
        for name in ("max_speed", "min_note_s", "min_gap_s"):
            if not getattr(self, name) > 0.0:
                raise ValueError(f"{name} = {getattr(self, name)} must be positive")


def key_distance(a: int, b: int, config: KeyboardConfig | None = None) -> float:
    """Distance between the aim points (key-top sites) of keys ``a`` and ``b`` (MIDI), m."""
    cfg = default_config() if config is None else config
    sites = _sites(cfg)
    return float(np.linalg.norm(sites[a - cfg.lowest] - sites[b - cfg.lowest]))


@cache
def _sites(config: KeyboardConfig) -> np.ndarray:
    """Key-top sites at rest, keyboard order, m, shape (n_keys, 3)."""
    return np.array([k.site for k in key_table(config)])


def required_gap(
    a: int, b: int, config: KeyboardConfig | None = None, limits: TempoLimits | None = None
) -> float:
    """Shortest time from releasing key ``a`` to pressing key ``b`` with one hand, s.

    ``max(min_gap_s, key_distance(a, b) / max_speed)``.
    """
    lim = TempoLimits() if limits is None else limits
    return max(lim.min_gap_s, key_distance(a, b, config) / lim.max_speed)


def _reach(hand: str, cfg: KeyboardConfig) -> tuple[int, int]:
    lo, hi = LEFT_REACH if hand == "left" else RIGHT_REACH
    return max(lo, cfg.lowest), min(hi, cfg.highest)


def playable(
    song: Song,
    config: KeyboardConfig | None = None,
    limits: TempoLimits | None = None,
    split: int = HAND_SPLIT_MIDI,
) -> Song:
    """``song`` with every hand resolved to ``left`` / ``right``, or ``SongError`` naming the first bad note.

    The checks are the module's (keyboard, reach, note length, one key per hand, tempo); ``split`` is
    the lowest key an ``either`` note gives to the right hand when both hands could play it. The reach
    ranges are those of the default placement (``front_x``, ``top_z``, ``centre_y``), cut to the keyboard.
    """
    cfg = default_config() if config is None else config
    lim = TempoLimits() if limits is None else limits
    last: dict[str, Note | None] = {"left": None, "right": None}

    def why_not(n: Note, hand: str) -> str | None:
        lo, hi = _reach(hand, cfg)
        if not lo <= n.key <= hi:
            return f"the {hand} fingertip reaches {note_name(lo)}..{note_name(hi)} only"
        prev = last[hand]
        if prev is None:
            return None
        if n.start_s < prev.end_s:
            return f"it overlaps {prev.describe()}: one key per hand at a time"
        need = required_gap(prev.key, n.key, cfg, lim)
        gap = n.start_s - prev.end_s
        if gap < need - 1e-9:
            why = (
                f"the {hand} fingertip needs {need:.3f} s ({1000 * key_distance(prev.key, n.key, cfg):.0f} "
                f"mm at {lim.max_speed} m/s, at least {lim.min_gap_s} s)"
            )
            if gap < 1e-9:  # legato: no tempo opens a gap that is not there
                return (
                    f"it starts as {prev.describe()} ends, with no gap; {why} to lift and move: a missing "
                    "gap, not a tempo (end the note before it sooner; bar-deploy --tempo 1 has the loader "
                    "do it)"
                )
            return (
                f"it starts {gap:.3f} s after {prev.describe()} ends; {why}: a tempo beyond the arms "
                f"(x{_floor3(gap / need):g} of it leaves the gap)"
            )
        return None

    out = []
    for i, n in enumerate(song.notes):
        where = f"song {song.name!r}, note {i} ({n.describe()})"
        if not cfg.lowest <= n.key <= cfg.highest:
            lo, hi = note_name(cfg.lowest), note_name(cfg.highest)
            raise SongError(f"{where}: off the keyboard ({lo}..{hi})")
        if n.end_s - n.start_s < lim.min_note_s - 1e-9:
            slower = _floor3((n.end_s - n.start_s) / lim.min_note_s)
            raise SongError(
                f"{where}: shorter than {lim.min_note_s} s, a tempo beyond the arms "
                f"(x{slower:g} of it plays it)"
            )
        hands = ("left", "right") if n.hand == "either" else (n.hand,)
        reasons = {h: why_not(n, h) for h in hands}
        ok = [h for h in hands if reasons[h] is None]
        if not ok:
            raise SongError(f"{where}: " + "; ".join(f"{r}" for r in reasons.values()))
        hand = ok[0] if len(ok) == 1 else ("left" if n.key < split else "right")
        resolved = replace(n, hand=hand)
        last[hand] = resolved
        out.append(resolved)
    return Song(song.name, tuple(out))


def _floor3(x: float) -> float:
    """``x`` rounded down to 3 decimals (a tempo factor that still plays: the printed one)."""
    return math.floor(x * 1000 + 1e-9) / 1000


def check_count_in(count_in_s: float) -> None:
    """Refuse a negative or non-finite count-in (``ValueError`` naming the value)."""
    if not (math.isfinite(count_in_s) and count_in_s >= 0.0):
        raise ValueError(f"count_in_s = {count_in_s} must be a finite number of seconds >= 0")


def count_in(song: Song, count_in_s: float) -> Song:
    """``song`` delayed so that its first note starts no earlier than ``count_in_s`` s (a count-in).

    Every note moves by ``max(0, count_in_s - first start)``: a song that already starts at or after
    ``count_in_s`` comes back unchanged (so applying it twice is applying it once), and the notes keep
    their keys, lengths, hands and spacing. An empty song comes back unchanged. Playback, not the file:
    song files keep their times as written (``bank.PlaybackConfig``).
    """
    check_count_in(count_in_s)
    shift = max(0.0, count_in_s - min((n.start_s for n in song.notes), default=count_in_s))
    if shift == 0.0:
        return song
    notes = tuple(replace(n, start_s=n.start_s + shift, end_s=n.end_s + shift) for n in song.notes)
    return Song(song.name, notes)


def goal_keys(
    song: Song, dt: float, steps: int, lookahead: int, config: KeyboardConfig | None = None
) -> np.ndarray:
    """Which keys should be down at each control step, and at the ``lookahead`` steps after it.

    Step ``t`` is time ``t * dt``. A note's times are rounded to the nearest step: its key is down at
    steps ``round(start_s / dt) <= t < round(end_s / dt)``. After the song, no key is down.

    Args:
        song: the song (its keys on the keyboard).
        dt: control period, s.
        steps: number of steps T.
        lookahead: L, future steps to include.
        config: the keyboard (default: ``default_config()``).

    Returns:
        float32 0/1 array, shape (T, L + 1, n_keys): ``[t, j, k]`` is 1 when key ``k`` (keyboard order,
        lowest first) is down at step ``t + j``.
    """
    cfg = default_config() if config is None else config
    if dt <= 0.0 or steps < 0 or lookahead < 0:
        raise ValueError(f"need dt > 0, steps >= 0, lookahead >= 0; got {dt}, {steps}, {lookahead}")
    down = np.zeros((steps + lookahead, cfg.n_keys), dtype=np.float32)
    for n in song.notes:
        if not cfg.lowest <= n.key <= cfg.highest:
            raise SongError(f"song {song.name!r}: {n.describe()} is off the keyboard")
        down[round(n.start_s / dt) : round(n.end_s / dt), n.key - cfg.lowest] = 1.0
    windows = np.lib.stride_tricks.sliding_window_view(down, lookahead + 1, axis=0)  # (T, n_keys, L + 1)
    return np.ascontiguousarray(windows.transpose(0, 2, 1))


# -- JSON ----------------------------------------------------------------------------------------------
def song_to_json(song: Song) -> str:
    """The song as JSON text (the module's format), one note per line."""
    notes = ",\n  ".join(
        strict_json({"key": n.key, "start_s": n.start_s, "end_s": n.end_s, "hand": n.hand})
        for n in song.notes
    )
    return f'{{"format": "{FORMAT}", "name": {strict_json(song.name)}, "notes": [\n  {notes}\n]}}\n'


def song_from_json(text: str | bytes, what: str = "song") -> Song:
    """Parse a song file's text; not checked against the keyboard.

    ``SongError`` for anything malformed or past ``check_song_size``'s limits.
    """
    data = loads_json(text, what, SongError)
    if not isinstance(data, dict) or data.get("format") != FORMAT:
        raise SongError(f"{what}: not a song file (format must be {FORMAT!r})")
    name, notes = data.get("name"), data.get("notes")
    if not isinstance(name, str) or not isinstance(notes, list):
        raise SongError(f"{what}: needs a string 'name' and a list 'notes'")
    check_song_size(what, len(notes), 0.0)
    out = []
    for i, n in enumerate(notes):
        if i % 256 == 0:
            check_stop(f"reading {what}")  # a stop request acts within 256 notes
        if (
            not isinstance(n, dict)
            or set(n) - {"key", "start_s", "end_s", "hand"}
            or not {"key", "start_s", "end_s"} <= set(n)
        ):
            raise SongError(f"{what}, note {i}: needs key, start_s, end_s (and hand); got {shorten(n)}")
        times = (n["start_s"], n["end_s"])
        if not all(isinstance(t, int | float) and not isinstance(t, bool) for t in times):
            raise SongError(f"{what}, note {i}: start_s and end_s must be numbers; got {shorten(n)}")
        out.append(Note(n["key"], float(times[0]), float(times[1]), n.get("hand", "either")))
        check_song_size(what, len(out), out[-1].end_s)
    return Song(name, tuple(out))


def read_song(
    path: str | Path, config: KeyboardConfig | None = None, limits: TempoLimits | None = None
) -> Song:
    """Read a song file and check it (``playable``): hands resolved, or ``SongError`` naming the note."""
    path = Path(path)
    check_song_file(path)
    return playable(song_from_json(path.read_bytes(), str(path)), config, limits)


def write_song(path: str | Path, song: Song) -> None:
    """Write ``song`` as a song file (UTF-8 JSON)."""
    Path(path).write_text(song_to_json(song), encoding="utf-8")
