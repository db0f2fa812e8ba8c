"""``key_pressed`` without a keyboard: an estimate from the fingertips' forward kinematics.

``KinematicKeys`` is the ``key_input.KeySource`` the mock and real targets use when no MIDI keyboard is
connected: the fingertips by forward kinematics of the measured q (given each tick through ``observe``),
and per key the rule of ``kinematic_pressed``: a key is down when a fingertip contact sphere would touch
the key's box (the scene's collision geometry) from above were the key turned to its press threshold
angle (``keyboard.press_thresholds``, the angle ``keyboard.pressed`` compares): the key's top then cannot
be above the sphere's, so the key is at or past the threshold.

An estimate: it sees neither the key's spring nor its inertia (a key lags a fast finger by a tick or two,
going down and coming up), nor a missed contact, and whether an edge contact pushes a key down or the
finger aside depends on forces it does not know (``kinematic_pressed``).
"""

from __future__ import annotations

from functools import lru_cache
from typing import Any, NamedTuple

import numpy as np

from bar_policy.tasks.piano.key_input import KeySource
from bar_policy.tasks.piano.keyboard import KeyboardConfig, key_size, key_table, press_thresholds

__all__ = ["KinematicKeys", "kinematic_pressed"]


class _Boxes(NamedTuple):
    """Each key's box at its press threshold, per key arrays of shape (n_keys,); m and rad."""

    hinge_x: np.ndarray
    """The hinge line's x (the keys' back edge), m."""
    y: np.ndarray
    """The key's centre line, m."""
    top_z: np.ndarray
    """The key top at rest, the hinge's z, m."""
    lever: np.ndarray
    """Front edge to hinge, m (the box's length)."""
    half_width: np.ndarray
    """Half the box's width, m."""
    thickness: np.ndarray
    """The box's height below the key top, m."""
    cos: np.ndarray
    """cos of the press threshold angle."""
    sin: np.ndarray
    """sin of the press threshold angle."""


@lru_cache(maxsize=8)
def _boxes(config: KeyboardConfig) -> _Boxes:
    """The keys' boxes of ``config`` as ``scene.keyboard_scene`` builds them (``key_size``), at threshold."""
    keys = key_table(config)
    width, thickness = np.array([key_size(config, k) for k in keys]).T
    threshold = press_thresholds(config)
    return _Boxes(
        hinge_x=np.full(len(keys), config.back_x),
        y=np.array([k.y for k in keys]),
        top_z=np.array([k.top_z for k in keys]),
        lever=np.array([k.lever for k in keys]),
        half_width=width / 2.0,
        thickness=thickness,
        cos=np.cos(threshold),
        sin=np.sin(threshold),
    )


def kinematic_pressed(centres: Any, config: KeyboardConfig) -> np.ndarray:
    """Keys a fingertip sphere holds at or past the press threshold, from the spheres' centres alone.

    Key ``k`` is pressed when a sphere of radius ``r = config.fingertip_radius`` touches it from above with
    the key turned about its hinge to the threshold angle ``t_k = press_fraction * angle_max_k`` (the angle
    ``keyboard.pressed`` compares). The hinge is at the key top's back edge (``back_x``, the key's ``y``,
    ``top_z``), axis -y, so a sphere centre ``c`` is, in the key's frame at ``t_k`` (x along the key from
    the hinge, z normal to its top),

        p_x = cos(t_k) (c_x - back_x) + sin(t_k) (c_z - top_z)
        p_y = c_y - y_k
        p_z = -sin(t_k) (c_x - back_x) + cos(t_k) (c_z - top_z)

    and the key's box (``scene.keyboard_scene``'s collision geom) spans ``p_x`` in [-lever, 0], ``p_y`` in
    [-w/2, w/2], ``p_z`` in [-thickness, 0]. With ``(e_x, e_y, e_z)`` the distance from ``p`` to the box
    along each axis (0 within its extent), the key is pressed iff

        e_x^2 + e_y^2 + e_z^2 <= r^2                     the sphere overlaps the box at t_k, and
        (e_x = e_y = 0) or p_z >= sqrt(e_x^2 + e_y^2)    it touches the top face, or an edge from above.

    Why each part:

    - Overlap, not the centre over the key: a sphere whose centre is over the gap or the neighbour still
      holds a key down with its rim (up to ``r`` = 6 mm past the key's edge), in y and in x alike.
    - The threshold at the sphere's own x: a key's top at distance ``u`` from the hinge is ``u sin(t)``
      below rest, so the depth that presses depends on where the finger is (a white key: 5 mm at the front
      edge, 4.17 mm at 125 mm from the hinge, the aim point). Over the key, ``p_z <= r`` is the tangent-
      plane form of "the angle implied by the sphere's lowest point, ``asin(depth / u)``, at or past
      ``t_k``" (the two differ by a factor ``cos(t_k)`` >= 0.9986 on the centre's height above the top).
    - From above: contacts are frictionless (condim 1), so a sphere pushes a key along the normal from the
      key's nearest point to the sphere's centre. On the top face it is the key's normal; on an edge it
      tilts toward the horizontal, and a sphere beside a key, level with or below its top, pushes it along
      the hinge axis or into it and not down (a finger slid down a neighbour's side, its rim just over the
      neighbour's edge). An edge contact counts when its normal is within 45 degrees of the key's normal
      (pushes the key down at least as hard as sideways): a choice where the true boundary depends on the
      forces (the key's spring against the arm's lateral stiffness), not geometry.
    - Each key alone: a sphere on the boundary of two keys, deep enough for both, presses both (a real
      fingertip can hold two). No key hides another: a sphere on a black key cannot reach the white key
      under it (the black key stops at full travel 2 mm or more above the white key's top).

    Args:
        centres: fingertip sphere centres, m, chest frame, shape (n_spheres, 3), or (3,) for one.
        config: the keyboard (key geometry, press threshold, ``fingertip_radius``).

    Returns:
        bool array, shape (n_keys,), keyboard order (lowest key first): pressed by any sphere.
    """
    c = np.asarray(centres, np.float64).reshape(-1, 3)[:, None, :]  # (n_spheres, 1, 3)
    b = _boxes(config)
    dx, dy, dz = c[..., 0] - b.hinge_x, c[..., 1] - b.y, c[..., 2] - b.top_z  # (n_spheres, n_keys)
    px = b.cos * dx + b.sin * dz
    pz = -b.sin * dx + b.cos * dz
    # Distance from the centre to the box, per axis (0 inside the box's extent on that axis).
    ex = np.maximum(np.maximum(-b.lever - px, px), 0.0)
    ey = np.maximum(np.abs(dy) - b.half_width, 0.0)
    ez = np.maximum(np.maximum(-b.thickness - pz, pz), 0.0)
    r = config.fingertip_radius
    overlap = ex**2 + ey**2 + ez**2 <= r * r
    # On the top face (the centre over the key's footprint, sunk in or not), or on an edge from above.
    on_top = ((ex == 0.0) & (ey == 0.0)) | ((pz >= 0.0) & (pz * pz >= ex**2 + ey**2))
    return (overlap & on_top).any(axis=0)


class KinematicKeys(KeySource):
    """Keys from the fingertips' forward kinematics (no keyboard connected), by ``kinematic_pressed``."""

    name = "kinematic"

    def __init__(self, config: KeyboardConfig, fingertips: Any) -> None:
        """``fingertips(q) -> (left, right)`` positions, m (``robot.kinematics.Kinematics.fingertips``)."""
        super().__init__(config)
        self._q: np.ndarray | None = None
        self._fingertips = fingertips

    def observe(self, q: np.ndarray) -> None:
        """The measured joint positions, rad (canonical order), each tick before ``read``."""
        self._q = np.asarray(q, np.float64)

    def read(self, t_s: float) -> np.ndarray:
        """Keys a fingertip sphere holds past the threshold (``t_s`` unused; none before ``observe``)."""
        if self._q is None:
            return np.zeros(self.n_keys, bool)
        return kinematic_pressed(np.array(self._fingertips(self._q), np.float64), self.config)
