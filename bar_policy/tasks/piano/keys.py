"""``key_pressed`` without a keyboard: an estimate from the fingertips' forward kinematics.

``KinematicKeys`` is the ``key_input.KeySource`` the mock and real targets use when no MIDI keyboard is
connected: a key is down when a fingertip contact sphere's bottom is inside the key's footprint and below
the key top by more than the press threshold's travel (the fingertips by forward kinematics of the
measured q, given each tick through ``observe``). Where a black key covers a white one, the black key (in
front and higher) takes the press. An estimate: it sees neither the key's spring nor a missed contact.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from bar_policy.tasks.piano.key_input import KeySource
from bar_policy.tasks.piano.keyboard import KeyboardConfig, key_table

__all__ = ["KinematicKeys"]


class KinematicKeys(KeySource):
    """Keys estimated from the fingertips' forward kinematics (no keyboard connected)."""

    name = "kinematic"

    def __init__(self, config: KeyboardConfig, fingertips: Any) -> None:
        """``fingertips(q) -> (left, right)`` positions, m (``robot.kinematics.Kinematics.fingertips``)."""
        super().__init__(config)
        self._q: np.ndarray | None = None
        keys = key_table(config)
        self._fingertips = fingertips
        half = np.array(
            [(config.black_width if k.black else config.white_pitch - config.white_gap) / 2 for k in keys]
        )
        self._y_lo = np.array([k.y for k in keys]) - half
        self._y_hi = np.array([k.y for k in keys]) + half
        self._x_lo = np.array([k.front_x for k in keys])
        self._x_hi = self._x_lo + np.array([k.lever for k in keys])
        # Depth of the press threshold under the key top at the fingertip's x is at most the front edge's
        # travel; the front edge's (press_fraction * travel) is used: a conservative (shallower) test.
        self._press_z = np.array([k.top_z for k in keys]) - config.press_fraction * config.travel
        self._black = np.array([k.black for k in keys])
        self._radius = config.fingertip_radius

    def observe(self, q: np.ndarray) -> None:
        """The measured joint positions, rad (canonical order), each tick before ``read``."""
        self._q = np.asarray(q, np.float64)

    def read(self, t_s: float) -> np.ndarray:
        """Spheres inside a key's footprint, bottom below its press depth (none before ``observe``)."""
        q = self._q
        if q is None:
            return np.zeros(self.n_keys, bool)
        down = np.zeros(self.n_keys, bool)
        for tip in self._fingertips(q):
            x, y, z = (float(v) for v in tip)
            inside = (self._x_lo <= x) & (x <= self._x_hi) & (self._y_lo <= y) & (y <= self._y_hi)
            # Where a black key covers a white one, the black key (higher, in front) takes the press.
            if (inside & self._black).any():
                inside &= self._black
            down |= inside & (z - self._radius <= self._press_z)
        return down
