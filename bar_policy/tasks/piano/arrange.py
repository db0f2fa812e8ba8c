"""A written song made playable: hands by what each arm reaches in time, a tempo, every note articulated.

Music as notation software exports it is legato (each note-off at the next note-on) in one or several
tracks with no hands, at a tempo the arms may not reach. ``arrange`` turns it into a song ``songs.playable``
accepts and lists every change it made (``Arrangement``):

1. **Hands** (``assign_hands``): notes that start together (within ``CHORD_S``) are a chord: two go to the
   two hands, lower left, higher right; three or more are refused (one fingertip per arm). A note alone
   goes to a hand whose reach (``keyboard.LEFT_REACH`` / ``RIGHT_REACH``, cut to the keyboard) holds its
   key, choosing, in this order: a hand that takes it in time at the tempo played (below), then the hand
   on the note's side of ``split``, then a hand whose previous note has ended (a held note is not cut),
   then the faster hand. Greedy, in time order. Given hands (``left`` / ``right``) are kept. The split is
   the key-pose prior's (middle C), which every piano policy of this layout plays by: its observation has
   no hand, so a note given the arm across the split is listed (``Arrangement.against_split``): the
   policy plays it with the split's arm all the same.
2. **Tempo**: hand ``h`` can take note ``b`` after its note ``a`` at tempo factor ``f`` (times divided by
   ``f``) when ``(b.start - a.start) / f >= min_note_s + required_gap(a, b)``: ``a`` shortened to leave
   the gap still lasts the shortest note. The fastest factor of an assignment (``fastest_tempo``) is the
   least of ``(b.start - a.start) / (min_note_s + required_gap(a, b))`` over each hand's consecutive
   notes. ``tempo`` None plays the written tempo (factor 1), a number that factor, ``"auto"`` the fastest
   factor with the split's hands (``Arrangement.fastest``), capped at 1 and rounded down to 3 decimals:
   the fastest the policy plays as the loader plans it (Greensleeves of the melody set: F1 0.813 at x1
   with four notes across the split, 0.866 at x0.88 with none; docs/piano.md). A faster factor with notes
   across the split, when there is one and the split's hands cannot play the written tempo, is given
   beside it (``fastest_across``). A factor past what the
   hands picked at it allow is refused, naming the first note it cannot reach and the factor that plays.
3. **Articulation**: the times are divided by the factor; a note shorter than ``min_note_s`` is
   lengthened to it, and every note is ended ``required_gap`` before its hand's next note
   (``generator.articulate``, the library's own). Each note whose length changed is listed with the change.

numpy only (the deploy side imports it).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any

from bar_policy.tasks.piano.generator import articulate
from bar_policy.tasks.piano.keyboard import (
    HAND_SPLIT_MIDI,
    LEFT_REACH,
    RIGHT_REACH,
    KeyboardConfig,
    default_config,
    note_name,
)
from bar_policy.tasks.piano.songs import Note, Song, SongError, TempoLimits, playable, required_gap

__all__ = [
    "CHORD_S",
    "Arrangement",
    "NoteChange",
    "arrange",
    "assign_hands",
    "fastest_tempo",
    "parse_tempo",
]

CHORD_S = 0.001
"""Notes whose starts differ by less than this are one chord, s (a MIDI tick at 480 per beat and 120 bpm
is 1.04 ms; merged tracks give the same tick float sums that differ by ~1e-15 s)."""
_TEMPO_DECIMALS = 3
"""``auto`` rounds the fastest factor down to this many decimals (a factor one can type back)."""


def parse_tempo(text: str | None) -> float | str | None:
    """``--tempo``: None, ``auto`` or a factor > 0 (``0.5`` half speed); ``ValueError`` naming the choices."""
    if text is None or text == "auto":
        return text
    try:
        factor = float(text)
    except ValueError:
        factor = math.nan
    if not (math.isfinite(factor) and factor > 0.0):
        raise ValueError(f"--tempo {text!r}: give a factor > 0 (0.5 plays at half speed) or auto")
    return factor


@dataclass(frozen=True)
class NoteChange:
    """One note whose length the arrangement changed (times as played, after the tempo)."""

    key: int
    """MIDI note number."""
    hand: str
    """``left`` or ``right``."""
    start_s: float
    """Press time as played, s."""
    written_s: float
    """Its length at the tempo, before articulation, s."""
    played_s: float
    """Its length as played, s."""
    before: int | None
    """The key of the hand's next note it makes room for (None: lengthened to the shortest note)."""

    def describe(self) -> str:
        """``E4@1.200 0.500->0.450 s (-0.050, before D4)``."""
        d = self.played_s - self.written_s
        why = f"before {note_name(self.before)}" if self.before is not None else "the shortest note"
        return (
            f"{note_name(self.key)}@{self.start_s:.3f} {self.written_s:.3f}->{self.played_s:.3f} s "
            f"({d:+.3f}, {why})"
        )


@dataclass(frozen=True)
class Arrangement:
    """A song as played and what was changed to play it (``arrange``)."""

    song: Song
    """The playable song (hands resolved, times at ``tempo``, notes articulated)."""
    tempo: float
    """The factor applied (1: as written; 0.5: half speed)."""
    fastest: float
    """The fastest factor that plays it with the hands of the key-pose prior's split (each note, but for
    chords, by the arm on its side of ``split``; inf: a song with no two notes in one hand)."""
    fastest_across: tuple[float, int] | None
    """A faster factor with some notes given the arm across the split, and how many (None: none faster,
    or the split's hands play the written tempo)."""
    written_bpm: float | None
    """The song's written tempo at its start, bpm (None: not known, a song file of times)."""
    changes: tuple[NoteChange, ...]
    """Every note whose length changed, in time order."""
    hands: dict[str, int]
    """Notes per hand."""
    against_split: tuple[Note, ...]
    """Notes given the hand across ``split`` from them (the key-pose prior plays them with the other)."""
    split: int
    """The split the hands were compared with (MIDI)."""

    def to_dict(self) -> dict[str, Any]:
        """The arrangement for the run's log (JSON-ready)."""
        return {
            "tempo": self.tempo,
            "fastest_tempo": None if math.isinf(self.fastest) else self.fastest,
            "fastest_tempo_across_split": None if self.fastest_across is None else self.fastest_across[0],
            "written_bpm": self.written_bpm,
            "played_bpm": None if self.written_bpm is None else self.written_bpm * self.tempo,
            "hands": dict(self.hands),
            "against_split": [n.describe() for n in self.against_split],
            "split": self.split,
            "changed": [
                {
                    "key": c.key,
                    "hand": c.hand,
                    "start_s": round(c.start_s, 6),
                    "written_s": round(c.written_s, 6),
                    "played_s": round(c.played_s, 6),
                    "before": c.before,
                }
                for c in self.changes
            ],
        }

    def brief(self) -> str:
        """``tempo x0.800 (96 bpm), 40 notes shortened, 2 lengthened, 0 across the split``."""
        bpm = "" if self.written_bpm is None else f" ({self.written_bpm * self.tempo:.4g} bpm)"
        shorter = sum(c.played_s < c.written_s for c in self.changes)
        return (
            f"tempo x{self.tempo:.3f}{bpm}, {shorter} notes shortened, {len(self.changes) - shorter} "
            f"lengthened, {len(self.against_split)} across the split"
        )

    def lines(self) -> list[str]:
        """The summary printed at a run's start: tempo, hands, then every changed note (a few per line)."""
        bpm = "" if self.written_bpm is None else f" ({self.written_bpm * self.tempo:.4g} bpm, written "
        bpm += "" if self.written_bpm is None else f"{self.written_bpm:.4g})"
        fastest = "any" if math.isinf(self.fastest) else f"x{_round_down(self.fastest):.3f}"  # still plays
        if self.fastest_across is not None:
            x, n_across = self.fastest_across
            fastest += f" (x{x:.3f} with {n_across} notes across the split)"
        n = len(self.song.notes)
        shorter = sum(c.played_s < c.written_s for c in self.changes)
        out = [
            f"song {self.song.name!r}: tempo x{self.tempo:.3f}{bpm}, fastest playable {fastest}; "
            f"hands: {self.hands['left']} left, {self.hands['right']} right "
            f"({len(self.against_split)} across the split at {note_name(self.split)}); "
            f"{shorter} of {n} notes shortened, {len(self.changes) - shorter} lengthened"
        ]
        if self.against_split:
            out.append(
                "  across the split (the key-pose prior plays these with the other arm): "
                + ", ".join(n.describe() for n in self.against_split)
            )
        for k in range(0, len(self.changes), 4):
            out.append("  " + "; ".join(c.describe() for c in self.changes[k : k + 4]))
        return out


def _reach(hand: str, cfg: KeyboardConfig) -> tuple[int, int]:
    lo, hi = LEFT_REACH if hand == "left" else RIGHT_REACH
    return max(lo, cfg.lowest), min(hi, cfg.highest)


def _rate(a: Note | None, b: Note, cfg: KeyboardConfig, lim: TempoLimits) -> float:
    """Fastest factor at which one hand plays ``b`` after ``a``: onsets over note + move (inf: none)."""
    if a is None:
        return math.inf
    return (b.start_s - a.start_s) / (lim.min_note_s + required_gap(a.key, b.key, cfg, lim))


def assign_hands(
    song: Song,
    config: KeyboardConfig | None = None,
    limits: TempoLimits | None = None,
    split: int = HAND_SPLIT_MIDI,
    tempo: float = 1.0,
) -> Song:
    """``song`` with every ``either`` note given a hand (module docstring, 1); ``SongError`` naming the note.

    ``tempo``: the factor the song will play at; a hand "takes a note in time" when it can at that factor.

    Refused: a key off the keyboard or out of its hand's reach, a chord of three or more notes, a chord of
    two whose lower key the left cannot reach or whose higher key the right cannot.
    """
    cfg = default_config() if config is None else config
    lim = TempoLimits() if limits is None else limits
    last: dict[str, Note | None] = {"left": None, "right": None}
    notes = song.notes
    out: list[Note] = []
    i = 0
    while i < len(notes):
        j = i + 1
        while j < len(notes) and notes[j].start_s - notes[i].start_s < CHORD_S:
            j += 1
        group = notes[i:j]
        where = f"song {song.name!r}, note {i} ({group[0].describe()})"
        for n in group:
            if not cfg.lowest <= n.key <= cfg.highest:
                lo, hi = note_name(cfg.lowest), note_name(cfg.highest)
                raise SongError(f"song {song.name!r}, {n.describe()}: off the keyboard ({lo}..{hi})")
        if len(group) > 2:
            names = ", ".join(note_name(n.key) for n in group)
            raise SongError(f"{where}: a chord of {len(group)} notes ({names}); the arms play one key each")
        if len(group) == 2:
            hands = [(group[0], "left"), (group[1], "right")]
            given = {n.hand for n in group}
            if given != {"either"} and given != {"left", "right"} and "either" in given:
                fixed = next(n for n in group if n.hand != "either")
                other = "right" if fixed.hand == "left" else "left"
                hands = [(n, n.hand if n.hand != "either" else other) for n in group]
            for n, h in hands:
                if n.hand not in ("either", h):
                    raise SongError(f"{where}: a chord whose two notes are both the {n.hand} hand's")
                lo, hi = _reach(h, cfg)
                if not lo <= n.key <= hi:
                    raise SongError(
                        f"song {song.name!r}, {n.describe()}: in a chord of two it is the {h} hand's; the "
                        f"{h} fingertip reaches {note_name(lo)}..{note_name(hi)} only"
                    )
                last[h] = replace(n, hand=h)
                out.append(last[h])
        else:
            n = group[0]
            hands = ("left", "right") if n.hand == "either" else (n.hand,)
            ok = [h for h in hands if _reach(h, cfg)[0] <= n.key <= _reach(h, cfg)[1]]
            if not ok:
                spans = {h: "..".join(note_name(k) for k in _reach(h, cfg)) for h in hands}
                reaches = "; ".join(f"the {h} fingertip reaches {span}" for h, span in spans.items())
                raise SongError(f"{where}: {reaches} only")

            def rank(h: str, n: Note = n) -> tuple[float, bool, bool, float]:
                prev = last[h]
                rate = _rate(prev, n, cfg, lim)
                free = prev is None or prev.end_s <= n.start_s + 1e-9
                home = (h == "left") == (n.key < split)
                return (min(rate, tempo), home, free, rate)

            hand = max(ok, key=rank)
            last[hand] = replace(n, hand=hand)
            out.append(last[hand])
        i = j
    return Song(song.name, tuple(out))


def _pairs(song: Song) -> list[tuple[int, Note, Note]]:
    """(index of b, a, b) for each hand's consecutive notes a, b; in b's time order."""
    out = []
    last: dict[str, Note] = {}
    for i, n in enumerate(song.notes):
        if n.hand in last:
            out.append((i, last[n.hand], n))
        last[n.hand] = n
    return out


def fastest_tempo(
    song: Song, config: KeyboardConfig | None = None, limits: TempoLimits | None = None
) -> float:
    """The fastest tempo factor that plays ``song`` (hands given) once articulated (module docstring, 2).

    ``min over each hand's consecutive notes a, b of (b.start - a.start) / (min_note_s + required_gap(a,
    b))``; inf for a song with no two notes in one hand.
    """
    cfg = default_config() if config is None else config
    lim = TempoLimits() if limits is None else limits
    return min((_rate(a, b, cfg, lim) for _, a, b in _pairs(song)), default=math.inf)


def _round_down(x: float) -> float:
    if math.isinf(x):
        return x
    scale = 10**_TEMPO_DECIMALS
    return math.floor(x * scale + 1e-9) / scale


def _bpm(bpm: float | None, factor: float) -> str:
    return "" if bpm is None else f" ({bpm * factor:.4g} bpm)"


def arrange(
    song: Song,
    tempo: float | str | None = None,
    config: KeyboardConfig | None = None,
    limits: TempoLimits | None = None,
    split: int = HAND_SPLIT_MIDI,
    written_bpm: float | None = None,
) -> Arrangement:
    """``song`` made playable at ``tempo`` (None: as written, a factor, or ``auto``), every change listed.

    ``SongError`` (one line) for a song no hand assignment plays, or a tempo past the fastest: the message
    names the first note it cannot reach in time and the factor (and bpm, when ``written_bpm`` is known)
    that plays the song.
    """
    cfg = default_config() if config is None else config
    lim = TempoLimits() if limits is None else limits
    split_fastest = fastest_tempo(assign_hands(song, cfg, lim, split, 0.0), cfg, lim)  # the split's hands
    across = _fastest_across(song, cfg, lim, split, split_fastest)
    if tempo == "auto":
        factor = min(1.0, _round_down(split_fastest)) or split_fastest  # below 0.001: refused below
    else:
        factor = 1.0 if tempo is None else float(tempo)
    assigned = assign_hands(song, cfg, lim, split, factor)
    if factor > fastest_tempo(assigned, cfg, lim) * (1 + 1e-9) or factor <= 0.0:
        pairs = _pairs(assigned)
        i, a, b = next(
            (p for p in pairs if _rate(p[1], p[2], cfg, lim) < factor),
            min(pairs, key=lambda p: _rate(p[1], p[2], cfg, lim)),
        )
        gap = required_gap(a.key, b.key, cfg, lim)
        works = _round_down(split_fastest)
        if works <= 0.0:
            hint = "no tempo plays it (two notes at once in one hand)"
        elif across is None:
            hint = (
                f"the song plays at x{works:g}{_bpm(written_bpm, works)} at most: give --tempo {works:g} or "
            )
            hint += "--tempo auto"
        else:
            hint = f"the song plays at x{works:g}{_bpm(written_bpm, works)} with the split's hands (--tempo "
            hint += f"{works:g} or --tempo auto), at x{across[0]:g} with {across[1]} notes across the split"
        at = f"x{factor:g}{_bpm(written_bpm, factor)}" if factor > 0.0 else "any tempo"
        after = (b.start_s - a.start_s) / factor if factor > 0.0 else 0.0
        raise SongError(
            f"song {assigned.name!r}, note {i} ({b.describe()}, as written): at {at} it starts {after:.3f} s "
            f"after {note_name(a.key)} ({a.key}) starts; the {b.hand} hand needs "
            f"{lim.min_note_s + gap:.3f} s ({lim.min_note_s:g} s of note, then {gap:.3f} s to lift and "
            f"move): a tempo beyond the arms; {hint}"
        )
    scaled = tuple(replace(n, start_s=n.start_s / factor, end_s=n.end_s / factor) for n in assigned.notes)
    longer = tuple(
        replace(n, end_s=n.start_s + lim.min_note_s) if n.end_s - n.start_s < lim.min_note_s else n
        for n in scaled
    )
    played = articulate(longer, cfg, lim)
    nxt: dict[int, int] = {}  # index of a note -> the key of its hand's next note
    last: dict[str, int] = {}
    for k, n in enumerate(played):
        if n.hand in last:
            nxt[last[n.hand]] = n.key
        last[n.hand] = k
    changes = []
    for k, (s, p) in enumerate(zip(scaled, played, strict=True)):
        written, now = s.end_s - s.start_s, p.end_s - p.start_s
        if abs(now - written) > 1e-9:
            before = nxt.get(k) if now < written else None
            changes.append(NoteChange(p.key, p.hand, p.start_s, written, now, before))
    result = playable(Song(song.name, played), cfg, lim, split)  # the arrangement's own check
    hands = {h: sum(n.hand == h for n in result.notes) for h in ("left", "right")}
    against = tuple(n for n in result.notes if (n.hand == "left") != (n.key < split))
    return Arrangement(
        result, factor, split_fastest, across, written_bpm, tuple(changes), hands, against, split
    )


def _fastest_across(
    song: Song, cfg: KeyboardConfig, lim: TempoLimits, split: int, split_fastest: float
) -> tuple[float, int] | None:
    """A faster factor than the split's hands allow, with notes given the other arm, and how many; or None.

    Only sought when the split's hands cannot play the written tempo.
    The hands that maximise each note's own rate (``assign_hands`` at an unbounded tempo) give a candidate,
    rounded down to 3 decimals; it counts when the hands ``assign_hands`` picks at that factor play it.
    """
    if _round_down(split_fastest) >= 1.0:  # the written tempo plays with the split's hands
        return None
    candidate = _round_down(fastest_tempo(assign_hands(song, cfg, lim, split, math.inf), cfg, lim))
    if not candidate > _round_down(split_fastest):
        return None
    hands = assign_hands(song, cfg, lim, split, candidate)
    if fastest_tempo(hands, cfg, lim) < candidate * (1 - 1e-9):
        return None
    return candidate, sum((n.hand == "left") != (n.key < split) for n in hands.notes)
