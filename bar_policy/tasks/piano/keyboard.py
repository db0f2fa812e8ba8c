"""The piano keyboard: spring-loaded keys built with ``MjSpec`` onto the Lite's scene.

Geometry (``KeyboardConfig``; sources in docs/piano.md):

- White keys on a 23.5 mm pitch (7 white keys span 164.5 mm, the standard octave of 164-165 mm), 22.5 mm
  wide (1 mm gap, as RoboPianist's MuJoCo keyboard: Zakka et al. 2023, ``piano_constants.py``), 150 mm long.
- Black keys 13.7 mm wide, 95 mm long, their tops 12 mm above the white keys' (RoboPianist: 12.5 mm),
  centred on the boundary between their two white neighbours, back edges flush with the white keys'.
- Every key is a balanced lever on a hinge at the keyboard's back edge, at its top surface: the front edge
  of a key of lever ``L`` drops ``L sin(angle)`` (10 mm at full travel, ``angle_max = travel / L``). A
  spring (``springref`` 0, the key's rest) gives ``k = F_full L / angle_max``: a force ``F`` normal to the
  key top at its front edge holds it at ``angle = F L / k``, i.e. 1.0 N for full travel and 0.5 N at the
  press threshold (a real key's downweight is about 0.5 N, ~50 g). The key's centre of mass is on the
  hinge (real keys are counterweighted), so gravity adds no torque and a free key rests at angle 0.
- A key counts as **pressed** past ``press_fraction`` (0.5) of its travel (``pressed``).

Frames: the world is the chest frame (x forward, y left, z up), m. Higher notes lie to the robot's right
(-y). Middle C (C4, MIDI 60) is centred on y = 0. The keyboard's front edge and surface are placed from the
fingertips at the ``piano_ready`` pose as the robot holds it: under gravity at its gains (Kp 50, Kd 2) the
arms sag and the fingertips sit 19.7 mm below the exact pose's (left (0.357, 0.157, 0.191), right
(0.357, -0.157, 0.191) on the sim target, against (0.361, +-0.159, 0.210)). Each fingertip's contact
sphere then rests ~5 mm above the white keys, ~25 mm behind their front edge, the left over C3 and the
right over C5 (both ~5 mm off the key's centre line), so the held pose presses nothing.

Span: MIDI 23..96 (B0..C7, 74 keys), the union of what the two fingertips reach: the sweep of ``reach.py``
(docs/piano.md) puts the left fingertip on B0..F#4 and the right on F#3..C7 (``LEFT_REACH``,
``RIGHT_REACH``); both reach F#3..F#4, and only one arm reaches each key outside it. The far ends need
an arm stretched sideways (B0 is 0.52 m left of the midline).

The scene itself (hinges, boxes, sites, sensors, fingertip contact spheres) is ``scene.py``'s
``keyboard_scene``. numpy only here (the deploy side imports it).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, replace
from typing import Any, NamedTuple

import numpy as np

__all__ = [
    "HAND_SPLIT_MIDI",
    "LEFT_REACH",
    "RIGHT_REACH",
    "Key",
    "KeyboardConfig",
    "black_keys",
    "compact_config",
    "default_config",
    "is_black",
    "key_size",
    "key_table",
    "note_name",
    "note_number",
    "press_thresholds",
    "pressed",
]

LEFT_REACH: tuple[int, int] = (23, 66)
"""MIDI range the left fingertip reaches (B0..F#4), from the sweep of ``reach.py`` (docs/piano.md)."""
RIGHT_REACH: tuple[int, int] = (54, 96)
"""MIDI range the right fingertip reaches (F#3..C7)."""

_BLACK_PITCH_CLASSES = frozenset({1, 3, 6, 8, 10})
_NAMES = ("C", "C#", "D", "D#", "E", "F", "F#", "G", "G#", "A", "A#", "B")


HAND_SPLIT_MIDI = 60
"""Middle C: where a song's hands split when it does not say (below: the left hand's)."""


def is_black(midi: int) -> bool:
    """True for a black key (C#, D#, F#, G#, A#)."""
    return midi % 12 in _BLACK_PITCH_CLASSES


def note_name(midi: int) -> str:
    """Scientific pitch name with sharps: 60 -> ``C4``, 61 -> ``C#4``, 21 -> ``A0``."""
    return f"{_NAMES[midi % 12]}{midi // 12 - 1}"


def note_number(name: str) -> int:
    """MIDI number of a pitch name with sharps: ``C4`` -> 60, ``C#4`` -> 61, ``A0`` -> 21 (``ValueError``)."""
    pitch = name[:2] if len(name) > 2 and name[1] == "#" else name[:1]
    try:
        octave = int(name[len(pitch) :])
        midi = _NAMES.index(pitch) + 12 * (octave + 1)
    except ValueError:
        raise ValueError(f"{name!r} is not a pitch name like C4 or F#3 (sharps only)") from None
    if not 0 <= midi <= 127:
        raise ValueError(f"{name!r} is outside MIDI 0..127")
    return midi


def _white_index(midi: int) -> int:
    """White keys strictly below ``midi``, from MIDI 0 (a black key: its upper white neighbour's count)."""
    octave, pc = divmod(midi, 12)
    return 7 * octave + sum(1 for p in range(pc) if p not in _BLACK_PITCH_CLASSES)


@dataclass(frozen=True, kw_only=True)
class KeyboardConfig:
    """Where the keyboard is and what its keys are like. Lengths m, forces N, chest frame."""

    lowest: int = 23
    """MIDI number of the lowest key (B0: the left fingertip's reach); must be white."""
    highest: int = 96
    """MIDI number of the highest key (C7: the right fingertip's reach); must be white."""
    centre_note: int = 60
    """The white key centred on ``centre_y`` (middle C)."""
    centre_y: float = 0.0
    """y of ``centre_note``'s centre line, m."""
    front_x: float = 0.336
    """x of the white keys' front edge, m (~25 mm in front of the fingertips at ``piano_ready``)."""
    top_z: float = 0.180
    """z of the white keys' top surface at rest, m (~5 mm below the fingertip spheres in the held
    ``piano_ready`` pose, which sags 19.7 mm under gravity; 24.7 mm below the exact pose's spheres)."""
    white_pitch: float = 0.0235
    """Centre-to-centre distance of adjacent white keys, m (standard octave 164.5 mm / 7)."""
    white_gap: float = 0.001
    """Gap between white keys, m (white key width = pitch - gap = 22.5 mm)."""
    white_length: float = 0.150
    """White key length, front edge to hinge, m (the lever of a white key)."""
    white_thickness: float = 0.020
    """White key box height, m (visual: keys touch only fingertips)."""
    black_width: float = 0.0137
    """Black key width, m."""
    black_length: float = 0.095
    """Black key length, front edge to hinge, m (its lever)."""
    black_rise: float = 0.012
    """Black key top above the white key top, m."""
    black_thickness: float = 0.020
    """Black key box height, m."""
    travel: float = 0.010
    """Drop of a key's front edge at full travel, m (3/8 inch)."""
    full_force: float = 1.0
    """Force normal to the key top at its front edge that holds the key at full travel, N."""
    press_fraction: float = 0.5
    """A key is pressed past this fraction of its travel (so past 0.5 N at the front edge)."""
    press_depth: float = 0.025
    """Key-top site (the aim point) behind each key's own front edge, m."""
    white_mass: float = 0.04
    """White key mass, kg (RoboPianist's); centre of mass on the hinge."""
    black_mass: float = 0.02
    """Black key mass, kg."""
    damping_ratio: float = 1.0
    """Hinge damping as a fraction of critical, sqrt(k I) * 2 (I the key's inertia about its hinge)."""
    fingertip_radius: float = 0.006
    """Radius of the fingertip contact spheres, m (the finger capsule's)."""

    def __post_init__(self) -> None:
        """Refuse black end keys, an empty range, and non-positive sizes (``ValueError`` naming the value)."""
        for name in ("lowest", "highest", "centre_note"):
            midi = getattr(self, name)
            if not 0 <= midi <= 127 or is_black(midi):
                raise ValueError(f"{name} = {midi} must be a white key's MIDI number in 0..127")
        if self.highest <= self.lowest:
            raise ValueError(f"highest ({self.highest}) must be above lowest ({self.lowest})")
        if not 0.0 < self.press_fraction < 1.0:
            raise ValueError(f"press_fraction = {self.press_fraction} must be in (0, 1)")
        for name in ("white_pitch", "white_length", "black_width", "black_length", "travel", "full_force"):
            if getattr(self, name) <= 0.0:
                raise ValueError(f"{name} = {getattr(self, name)} must be positive")
        if self.travel >= self.black_length:
            raise ValueError(f"travel = {self.travel} m must be shorter than the black lever")

    @property
    def n_keys(self) -> int:
        """Number of keys, ``highest - lowest + 1``."""
        return self.highest - self.lowest + 1

    @property
    def back_x(self) -> float:
        """The hinge line's x (the keys' back edge), m."""
        return self.front_x + self.white_length


def default_config() -> KeyboardConfig:
    """The keyboard of docs/piano.md: B0..C7 (74 keys), placed for the held ``piano_ready`` pose."""
    return KeyboardConfig()


def compact_config() -> KeyboardConfig:
    """C2..C6 (MIDI 36..84, 49 keys): every library song and random song fits, with fewer keys to simulate.

    The same placement as ``default_config()``; in MJX each key costs a degree of freedom, a joint-limit row
    and two fingertip contact pairs (49 keys: nefc 229 instead of the robot's 82; 137 under the scene's MJX
    contact caps, ``scene.MAX_GEOM_PAIRS`` and ``scene.MAX_CONTACT_POINTS``).
    """
    return replace(default_config(), lowest=36, highest=84)


class Key(NamedTuple):
    """One key of the keyboard. Lengths m, angles rad, chest frame."""

    index: int
    """Position in the keyboard (0 = lowest), the order of every per-key array."""
    midi: int
    """MIDI note number."""
    name: str
    """Pitch name (``C4``)."""
    black: bool
    """True for a black key."""
    y: float
    """Centre line of the key, m."""
    front_x: float
    """x of the key's front edge, m."""
    top_z: float
    """z of the key's top at rest, m."""
    lever: float
    """Front edge to hinge, m."""
    angle_max: float
    """Hinge angle at full travel (``travel / lever``), rad; pressing is a positive rotation."""
    stiffness: float
    """Hinge spring, N*m/rad (``full_force * lever / angle_max``)."""
    inertia: float
    """Inertia about the hinge axis, kg*m^2."""
    damping: float
    """Hinge damping, N*m*s/rad."""
    site: tuple[float, float, float]
    """The key-top site (aim point) at rest, m."""


@functools.cache
def key_table(config: KeyboardConfig) -> tuple[Key, ...]:
    """All keys, lowest first (``config.n_keys`` of them).

    Cached per keyboard (the config is frozen, the keys immutable): the deploy side reads each tick's
    pressed keys through it (``pressed``), where building the table took 0.4 ms of a piano tick.
    """
    c = config
    centre = _white_index(c.centre_note)
    keys = []
    for i, midi in enumerate(range(c.lowest, c.highest + 1)):
        black = is_black(midi)
        if black:  # on the boundary between the white keys below and above
            y = c.centre_y - (_white_index(midi) - centre - 0.5) * c.white_pitch
            lever, top, mass, thick = c.black_length, c.top_z + c.black_rise, c.black_mass, c.black_thickness
        else:
            y = c.centre_y - (_white_index(midi) - centre) * c.white_pitch
            lever, top, mass, thick = c.white_length, c.top_z, c.white_mass, c.white_thickness
        angle_max = c.travel / lever
        stiffness = c.full_force * lever / angle_max
        inertia = mass * (lever**2 + thick**2) / 3.0  # a uniform bar about its end
        front = c.back_x - lever
        keys.append(
            Key(
                index=i,
                midi=midi,
                name=note_name(midi),
                black=black,
                y=float(y),
                front_x=float(front),
                top_z=float(top),
                lever=lever,
                angle_max=angle_max,
                stiffness=stiffness,
                inertia=inertia,
                damping=2.0 * c.damping_ratio * math.sqrt(stiffness * inertia),
                site=(float(front + c.press_depth), float(y), float(top)),
            )
        )
    return tuple(keys)


def key_size(config: KeyboardConfig, key: Key) -> tuple[float, float]:
    """Width and thickness of ``key``'s box, m (the scene's collision geom; the kinematic key estimate's)."""
    if key.black:
        return config.black_width, config.black_thickness
    return config.white_pitch - config.white_gap, config.white_thickness


def black_keys(config: KeyboardConfig | None = None) -> np.ndarray:
    """Which keys are black, bool, shape (n_keys,), keyboard order (``metrics.colour_counts``' mask)."""
    cfg = default_config() if config is None else config
    return np.array([k.black for k in key_table(cfg)], dtype=bool)


def press_thresholds(config: KeyboardConfig | None = None) -> np.ndarray:
    """Angle at which each key counts as pressed (``press_fraction * angle_max``), rad, shape (n_keys,)."""
    cfg = default_config() if config is None else config
    return cfg.press_fraction * np.array([k.angle_max for k in key_table(cfg)])


def pressed(angles: Any, config: KeyboardConfig | None = None) -> Any:
    """Which keys are pressed: hinge angle at or past ``press_fraction`` of each key's ``angle_max``.

    Array-agnostic (numpy here, ``jnp`` in the MJX env): a comparison with ``press_thresholds(config)``.

    Args:
        angles: key hinge angles, rad, shape (..., n_keys), key order (the ``piano_key*_angle`` sensors).
        config: the keyboard (default: ``default_config()``).

    Returns:
        bool array, shape (..., n_keys).
    """
    threshold = press_thresholds(config)
    if not hasattr(angles, "shape"):
        angles = np.asarray(angles)
    if angles.shape[-1:] != threshold.shape:
        raise ValueError(f"angles has shape {angles.shape}, expected (..., {len(threshold)})")
    return angles >= threshold
