"""Piano policies on random songs of the training bank's kind: F1, and where the goal key-ticks are missed.

    python bench/piano_prior.py --out /tmp/prior.onnx        # the key-pose prior alone (a zero MLP)
    python bench/piano_random_songs.py --seed 2026 --songs 32 --tempo 60 120 \\
        --policies /tmp/prior.onnx,checkpoints/lite_piano_arms.onnx --out /tmp/random_2026.md

The songs are drawn as the training bank draws them (``bank.training_songs``): ``rng =
np.random.default_rng(SEED)``, then for each song a tempo ``rng.uniform(LO, HI)`` bpm and
``generator.random_song(rng, compact_config(), DURATION, tempo)``, named ``random-SEED-NNNN``. Each policy
plays every song on the C MuJoCo sim target through ``bar-deploy eval``'s code (``tasks.piano.evaluate``,
the env's count-in, scored against the simulated keys), ~2 s a song. Per policy: F1, precision and recall
(means over songs of each song's tick means, as the evaluation reports them), the pooled F1, the songs that
faulted and the ticks with a joint at its torque cap.

Missed goal key-ticks (a goal key up at a scored tick) are then broken down by the note they belong to: the
song's tempo (three equal bins of ``--tempo``), the note's length as played, the jump from the hand's previous
note (semitones; ``first``: the hand's first note), the gap since that note ended, white or black key, the
hand (the prior's split, ``KeyPosePriorConfig.split_midi``), the tick's place in the note (``onset``: its
first 0.1 s, ``release``: its last 0.1 s, ``sustain``: between), whether the other hand has a goal key then,
and the key's colour crossed with the hand and with the place in the note. Each row gives the goal key-ticks
of that kind (the song's; the same for every policy unless one faults) and, per policy, the misses and the
miss rate; the last column is the misses of the last policy minus the first's. Two dimensions count misses
only (rate: share of the policy's misses): the hand's keys at the miss (its previous note's key still down,
another of its keys down, none) and whether the goal key had been down earlier in the same note (lost) or not
yet. The last rows count notes never sounded (the key never down while a goal), by key colour. A per-song
table follows, and how much of the change in misses the songs with the largest increase hold. ``--out`` writes
the markdown (also printed).
"""

from __future__ import annotations

import argparse
import time
from collections import Counter, defaultdict
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from bar_policy.deploy.episodes import SimEpisodes
from bar_policy.deploy.policy import load_policy
from bar_policy.tasks.piano.bank import random_songs
from bar_policy.tasks.piano.evaluate import evaluate
from bar_policy.tasks.piano.keyboard import compact_config, is_black
from bar_policy.tasks.piano.prior import KeyPosePriorConfig
from bar_policy.tasks.piano.results import SongResult, SongTicks
from bar_policy.tasks.piano.songs import Note, Song, count_in

ONSET_S = 0.1
"""A tick within this long of its note's start is ``onset``; within it of the note's end, ``release``."""
DIMENSIONS = (
    "tempo",
    "note length",
    "jump",
    "gap before",
    "key",
    "hand",
    "place in note",
    "other hand",
    "key and hand",
    "key and place",
)
"""The breakdown's dimensions, in the table's order."""
MISS_ONLY = "hand's keys at a miss"
"""Counted at missed key-ticks only (its rate: share of the policy's misses): the hand's keys then."""
MISS_NOTE = "goal key at a miss"
"""Counted at missed key-ticks only: whether the key was down at an earlier tick of the same note (lost)."""
NEVER = "notes never sounded"
"""Notes whose key was never down while it was a goal (by key colour; rate: share of the notes)."""


@dataclass
class Tally:
    """One policy's results: each song's figures and the goal / missed key-ticks per category."""

    songs: list[SongResult] = field(default_factory=list)
    goal: Counter[tuple[str, str]] = field(default_factory=Counter)
    missed: Counter[tuple[str, str]] = field(default_factory=Counter)
    song_missed: dict[str, int] = field(default_factory=dict)
    song_goal: dict[str, int] = field(default_factory=dict)


def draw_songs(
    seed: int, count: int, tempo: tuple[float, float], duration_s: float
) -> list[tuple[Song, float]]:
    """``count`` random songs and their tempos, as the training bank draws them (``bank.random_songs``)."""
    return random_songs(compact_config(), count, duration_s, tempo, seed)


def _bin(x: float, edges: tuple[float, ...], unit: str) -> str:
    """``x``'s bin among ``edges`` (ascending), labelled ``<a``, ``a-b``, ``>=b``."""
    for i, e in enumerate(edges):
        if x < e:
            return f"<{e:g} {unit}" if i == 0 else f"{edges[i - 1]:g}-{e:g} {unit}"
    return f">={edges[-1]:g} {unit}"


def _jump_bin(semitones: int | None) -> str:
    if semitones is None:
        return "first note"
    if semitones == 0:
        return "0 (repeat)"
    return "1-2" if semitones <= 2 else ("3-7" if semitones <= 7 else "8+")


def categorise(
    ticks: SongTicks, bpm: float, tempo: tuple[float, float], dt: float, split: int
) -> tuple[Counter[tuple[str, str]], Counter[tuple[str, str]]]:
    """Goal and missed key-ticks of one song per (dimension, category), the misses' ``MISS_ONLY`` and
    ``NEVER`` (the goal's ``NEVER`` counts the notes)."""
    lowest = compact_config().lowest
    played = count_in(ticks.song, ticks.count_in_s)
    notes = sorted(played.notes, key=lambda n: n.start_s)
    goal: Counter[tuple[str, str]] = Counter()
    missed: Counter[tuple[str, str]] = Counter()
    prev: dict[int, Note | None] = {}
    last: dict[str, Note] = {}
    for n in notes:
        goal[(NEVER, "black" if is_black(n.key) else "white")] += 1
        h = "left" if n.key < split else "right"
        prev[id(n)] = last.get(h)
        last[h] = n
    width = (tempo[1] - tempo[0]) / 3
    tempo_bin = _bin(bpm, (tempo[0] + width, tempo[0] + 2 * width), "bpm")
    n_steps = int(ticks.steps.max(initial=0)) + 1
    owner: dict[tuple[int, int], Note] = {}
    for n in notes:
        for s in range(round(n.start_s / dt), min(round(n.end_s / dt), n_steps)):
            owner[(s, n.key - lowest)] = n
    side = np.arange(ticks.goal.shape[1]) + lowest < split  # True: the left hand's keys
    for i, k in zip(*np.nonzero(ticks.goal), strict=True):
        s = int(ticks.steps[i])
        n = owner.get((s, int(k)))
        if n is None:  # a goal key with no note: cannot happen with the bank's rounding
            raise RuntimeError(f"{ticks.song.name}: goal key {k + lowest} at step {s} has no note")
        hand = "left" if n.key < split else "right"
        p = prev[id(n)]
        t0, t1 = s * dt - n.start_s, n.end_s - s * dt
        miss = not ticks.down[i, k]
        mine = ticks.down[i] & (side if hand == "left" else ~side)
        if not miss:
            keys_state = None
        elif p is not None and p.key != n.key and ticks.down[i, p.key - lowest]:
            keys_state = "previous key still down"
        elif mine.any():
            keys_state = "another key down"
        else:
            keys_state = "none down"
        other = ticks.goal[i] & (~side if hand == "left" else side)
        cats = {
            "tempo": tempo_bin,
            "note length": _bin(n.end_s - n.start_s, (0.5, 0.75, 1.0), "s"),
            "jump": _jump_bin(None if p is None else abs(n.key - p.key)),
            "gap before": "first note" if p is None else _bin(n.start_s - p.end_s, (0.3,), "s"),
            "key": "black" if is_black(n.key) else "white",
            "hand": hand,
            "place in note": "onset"
            if t0 < ONSET_S - 1e-9
            else ("release" if t1 <= ONSET_S + 1e-9 else "sustain"),
            "other hand": "has a goal key" if other.any() else "free",
        }
        cats["key and hand"] = f"{cats['key']}, {hand}"
        cats["key and place"] = f"{cats['key']}, {cats['place in note']}"
        for dim, cat in cats.items():
            goal[(dim, cat)] += 1
            missed[(dim, cat)] += miss
        if keys_state is not None:
            missed[(MISS_ONLY, keys_state)] += 1
            earlier = (ticks.steps >= round(n.start_s / dt)) & (ticks.steps < s)
            lost = bool(ticks.down[earlier, k].any())
            missed[(MISS_NOTE, "down earlier in the note" if lost else "not yet down in the note")] += 1
    for n in notes:
        rows = (ticks.steps >= round(n.start_s / dt)) & (ticks.steps < round(n.end_s / dt))
        if rows.any() and not ticks.down[rows, n.key - lowest].any():
            missed[(NEVER, "black" if is_black(n.key) else "white")] += 1
    return goal, missed


def run_policy(path: str, songs: list[tuple[Song, float]], tempo: tuple[float, float], split: int) -> Tally:
    """Play every song with the policy at ``path`` on the sim target, tallying the misses."""
    policy = load_policy(path)
    runner = SimEpisodes(policy)
    tally = Tally()
    bpm = {s.name: t for s, t in songs}

    def on_song(result: SongResult, ticks: SongTicks) -> None:
        goal, missed = categorise(ticks, bpm[ticks.song.name], tempo, policy.policy_dt, split)
        tally.goal.update(goal)
        tally.missed.update(missed)
        tally.song_goal[result.song] = int(ticks.goal.sum())
        tally.song_missed[result.song] = int((ticks.goal & ~ticks.down).sum())

    res = evaluate(policy, [s for s, _ in songs], runner=runner, on_song=on_song)
    tally.songs = res.songs
    return tally


def _mean(xs: list[float]) -> float:
    return float(np.mean(xs)) if xs else float("nan")


def _order(cat: str) -> tuple[int, float, str]:
    """Bins in numeric order (``<a``, ``a-b``, ``>=b``), named categories after them."""
    head = cat.lstrip("<>=").split(" ")[0].split("-")[0].rstrip("+")
    try:
        x = float(head)
    except ValueError:
        return (3, 0.0, cat)
    return (0 if cat.startswith("<") else 2 if cat.startswith(">=") else 1, x, cat)


def _summary_row(name: str, t: Tally) -> str:
    """One policy's line: means over songs, pooled F1, misses, faults, cap ticks."""
    tp = sum(s.true_pos for s in t.songs)
    pooled = 2 * tp / max(1, sum(2 * s.true_pos + s.false_pos + s.false_neg for s in t.songs))
    faulted = ", ".join(f"{s.song} ({s.end_reason})" for s in t.songs if s.faulted) or "none"
    caps = sum(int(s.quality.get("cap_ticks", 0)) for s in t.songs)
    miss, goal = sum(t.song_missed.values()), sum(t.song_goal.values())
    f1, prec, rec = (_mean([getattr(s, k) for s in t.songs]) for k in ("f1", "precision", "recall"))
    return (
        f"| {name} | {f1:.3f} | {prec:.3f} | {rec:.3f} | {pooled:.3f} | {miss} / {goal} "
        f"({100 * miss / max(goal, 1):.1f} %) | {faulted} | {caps} |"
    )


def _breakdown(names: list[str], tallies: list[Tally]) -> list[str]:
    """The missed goal key-ticks per dimension and category, each policy's count and rate."""
    delta = len(tallies) > 1
    head = "| dimension | category | goal | " + " | ".join(f"missed: {n}" for n in names)
    lines = [head + (" | change |" if delta else " |"), "|---|---|---:|" + "---:|" * (len(names) + delta)]
    cats: dict[str, set[str]] = defaultdict(set)
    for t in tallies:
        for dim, cat in (*t.goal, *t.missed):
            cats[dim].add(cat)
    for dim in (*DIMENSIONS, MISS_ONLY, MISS_NOTE, NEVER):
        for cat in sorted(cats[dim], key=_order):
            key = (dim, cat)
            cells = []
            for t in tallies:
                scale = sum(t.song_missed.values()) if dim in (MISS_ONLY, MISS_NOTE) else t.goal[key]
                cells.append(f"{t.missed[key]} ({100 * t.missed[key] / max(scale, 1):.1f} %)")
            goal = "" if dim in (MISS_ONLY, MISS_NOTE) else str(tallies[0].goal[key])
            row = f"| {dim} | {cat} | {goal} | " + " | ".join(cells)
            lines.append(
                row + (f" | {tallies[-1].missed[key] - tallies[0].missed[key]:+d} |" if delta else " |")
            )
    return lines


def report(args: argparse.Namespace, paths: list[str], tallies: list[Tally], bpm: dict[str, float]) -> str:
    """The markdown: summary, breakdown, per-song table and concentration of the change in misses."""
    names = [Path(p).name for p in paths]
    lo, hi = args.tempo
    lines = [
        f"Random songs: seed {args.seed}, {args.songs} songs, {args.duration:g} s, "
        f"tempo U({lo:g}, {hi:g}) bpm; C MuJoCo sim target.",
        "",
        "| policy | F1 | precision | recall | pooled F1 | goal key-ticks missed | faulted | cap ticks |",
        "|---|---:|---:|---:|---:|---:|---|---:|",
    ]
    lines += [_summary_row(n, t) for n, t in zip(names, tallies, strict=True)]
    lines += ["", *_breakdown(names, tallies), ""]
    lines.append("| song | bpm | goal | " + " | ".join(f"F1 / recall / missed: {n}" for n in names) + " |")
    lines.append("|---|---:|---:|" + "---:|" * len(names))
    by_song = [{s.song: s for s in t.songs} for t in tallies]
    for song in by_song[0]:
        cells = [
            f"{b[song].f1:.3f} / {b[song].recall:.3f} / {t.song_missed[song]}"
            + (" faulted" if b[song].faulted else "")
            for b, t in zip(by_song, tallies, strict=True)
        ]
        lines.append(
            f"| {song} | {bpm[song]:.0f} | {tallies[0].song_goal[song]} | " + " | ".join(cells) + " |"
        )
    if len(tallies) > 1:
        change = {s: tallies[-1].song_missed[s] - tallies[0].song_missed[s] for s in by_song[0]}
        ranked = sorted(change.values(), reverse=True)
        worse = sum(1 for s in by_song[0] if by_song[-1][s].recall < by_song[0][s].recall)
        top = " / ".join(f"{sum(ranked[:k]):+d}" for k in (3, 5, 10))
        lines += [
            "",
            f"Change in missed key-ticks, {names[-1]} minus {names[0]}: {sum(change.values()):+d}; "
            f"recall lower on {worse} of {len(change)} songs; "
            f"the 3 / 5 / 10 songs with the largest increase: {top}.",
        ]
    return "\n".join(lines) + "\n"


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--seed", type=int, default=2026)
    p.add_argument("--songs", type=int, default=32, help="number of random songs")
    p.add_argument("--tempo", type=float, nargs=2, default=(60.0, 120.0), metavar=("LO", "HI"), help="bpm")
    p.add_argument("--duration", type=float, default=9.5, help="each song ends by this, s (the bank's 9.5)")
    p.add_argument(
        "--policies", required=True, help="comma-separated ONNX files (the change is last - first)"
    )
    p.add_argument("--out", type=Path, help="write the markdown tables here")
    args = p.parse_args()
    paths = args.policies.split(",")
    songs = draw_songs(args.seed, args.songs, tuple(args.tempo), args.duration)
    split = KeyPosePriorConfig().split_midi
    tallies = []
    for path in paths:
        t0 = time.perf_counter()
        tallies.append(run_policy(path, songs, tuple(args.tempo), split))
        print(f"{path}: {len(songs)} songs in {time.perf_counter() - t0:.0f} s", flush=True)
    text = report(args, paths, tallies, {s.name: t for s, t in songs})
    print(text)
    if args.out:
        args.out.write_text(text)


if __name__ == "__main__":
    main()
