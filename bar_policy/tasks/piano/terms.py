"""The observation terms the piano adds to the robot's (Humanoid Control's piano task names).

Sizes are fixed by the trained keyboard and lookahead: ``compact_config()`` (C2..C6, ``PIANO_KEYS`` = 49
keys) and ``TARGET_FRAMES`` = 11 control steps (the current one and the next 10: 0.2 s at 50 Hz, RoboPianist's
lookahead). The song source feeds all three at deploy time (``target_keys`` and ``progress`` from the song,
``key_pressed`` from its pluggable key source: the simulated keys, or a MIDI keyboard on the robot).
"""

from __future__ import annotations

from bar_policy.obs.terms import TermKind

__all__ = ["PIANO_KEYS", "TARGET_FRAMES", "TERMS"]

PIANO_KEYS = 49
"""Keys of the trained keyboard (``keyboard.compact_config()``: MIDI 36..84), in keyboard order."""
TARGET_FRAMES = 11
"""Goal-key frames in ``target_keys``: the current control step and the next ``TARGET_FRAMES - 1``."""

TERMS: dict[str, TermKind] = {
    "target_keys": TermKind(
        size=TARGET_FRAMES * PIANO_KEYS,
        category="command",
        unit="1",
        doc="goal keys (1: down) at the current and the next 10 control steps, frame-major, then key "
        "(keyboard order, lowest first)",
    ),
    "progress": TermKind(size=1, category="command", unit="1", doc="fraction of the song elapsed, 0..1"),
    "key_pressed": TermKind(
        size=PIANO_KEYS,
        category="command",
        unit="1",
        doc="keys down now (1: past the press threshold), keyboard order; the key source's reading",
    ),
}
"""Term name -> meaning (``TaskRecord.terms``)."""
