"""The keyboard in the robot's ``MjSpec``: keys on spring-loaded hinges, fingertip contact spheres.

Geometry, springs and placement come from ``keyboard.KeyboardConfig`` / ``key_table`` (docs/piano.md).
Contacts: each hand gets a massless sphere (``FINGERTIP_GEOMS``, the finger capsule's radius) centred on its
fingertip site, in a collision group of its own (contype ``FINGERTIP_BIT`` = 8, conaffinity 0); every key has
contype 0 and conaffinity 8, so keys touch the two fingertip spheres and nothing else (not each other, not
the palm or wrist: a task that cares checks those itself). The robot's own geoms keep their bits
(``links.COLLISION_BITS``: 1 torso, 2 left arm, 4 right arm), so its own contact pairs are unchanged.

MJX's contact caps (docs/physics.md, "A cheaper keyboard step"): MJX carries every candidate contact of the
scene as a constraint row, every physics step, whether it touches or not: 98 fingertip-key pairs with 49
keys, beside the robot's 54 contacts. The scene sets MJX's two numerics (C MuJoCo ignores them), with
values that drop no contact that touches:

- ``max_geom_pairs`` = ``MAX_GEOM_PAIRS`` (30): per collision group, MJX runs the narrow phase only on the
  30 pairs nearest by bounding sphere (``|p1 - p2| - rbound1 - rbound2``). A pair in contact has that
  distance <= 0, and no fingertip sphere is inside more than 13 keys' bounding spheres (so 26 for two),
  so every touching pair is among the 30. The robot's groups hold at most 30 pairs and are not culled.
- ``max_contact_points`` = ``MAX_CONTACT_POINTS`` (60): of the condim-1 contacts (the robot's 54 and the
  keys' 30), MJX keeps the 60 deepest. A fingertip sphere (12 mm across in y) meets at most 3 keys' y
  extents (two white, one black, or one white, two black; a key's hinge turns it about y, so its y extent
  never changes), so at most 54 + 2 * 3 = 60 contacts can touch at once.

numpy + mujoco + ``bar_policy.robot`` only (the deploy side imports it).
"""

from __future__ import annotations

import mujoco

from bar_policy.robot.constants import FINGERTIP_SITES
from bar_policy.robot.links import FINGERTIP_SITE_POS
from bar_policy.robot.scene import SceneEdit
from bar_policy.tasks.piano.keyboard import KeyboardConfig, default_config, key_size, key_table

__all__ = ["FINGERTIP_BIT", "FINGERTIP_GEOMS", "MAX_CONTACT_POINTS", "MAX_GEOM_PAIRS", "keyboard_scene"]

FINGERTIP_BIT = 8
"""Collision bit of the fingertip spheres (the robot's groups use 1, 2, 4: ``links.COLLISION_BITS``)."""
FINGERTIP_GEOMS: tuple[str, str] = ("piano_left_fingertip", "piano_right_fingertip")
"""Names of the fingertip contact spheres (left, right), on ``left_hand`` / ``right_hand``."""
MAX_GEOM_PAIRS = 30
"""MJX's ``max_geom_pairs``: narrow-phase pairs per collision group, nearest first (module docstring).
At least the robot's largest group (30 capsule-capsule pairs in ``arms``, 22 in ``arms_neck``) and twice
the keys' bounding spheres one fingertip sphere can be inside (13, counted with margins): tested."""
MAX_CONTACT_POINTS = 60
"""MJX's ``max_contact_points``: contacts kept, deepest first, of one condim (all of this scene's are
condim 1): the robot's 54 (``arms``; 46 in ``arms_neck``) + 3 keys per fingertip sphere x 2. Tested."""

_WHITE_RGBA = (0.92, 0.92, 0.9, 1.0)
_BLACK_RGBA = (0.08, 0.08, 0.1, 1.0)
_TIP_RGBA = (0.9, 0.5, 0.2, 1.0)


def keyboard_scene(config: KeyboardConfig | None = None) -> SceneEdit:
    """A ``SceneEdit`` adding the keyboard of ``config`` (default: ``default_config()``) to the robot's spec.

    Adds per key (``m`` its MIDI number): a body ``piano_key{m}`` at the hinge, a hinge joint
    ``piano_key{m}`` (axis -y: pressing is positive, range [0, angle_max], spring with ``springref`` 0,
    damping), one box geom ``piano_key{m}`` (contype 0, conaffinity ``FINGERTIP_BIT``), a site
    ``piano_key{m}_top`` at the aim point, and a joint-position sensor ``piano_key{m}_angle`` (rad, the
    keys' sensors in key order). Per hand: a fingertip sphere (``FINGERTIP_GEOMS``) at the fingertip site,
    massless, contype ``FINGERTIP_BIT`` and conaffinity 0. Keys are children of the world, so their joints
    come after the robot's in ``qpos``. And MJX's contact caps, the numerics ``max_geom_pairs``
    (``MAX_GEOM_PAIRS``) and ``max_contact_points`` (``MAX_CONTACT_POINTS``), which drop no touching
    contact (module docstring); C MuJoCo ignores them.
    """
    cfg = default_config() if config is None else config

    def edit(spec: mujoco.MjSpec) -> None:
        spec.add_numeric(name="max_geom_pairs", data=[float(MAX_GEOM_PAIRS)])
        spec.add_numeric(name="max_contact_points", data=[float(MAX_CONTACT_POINTS)])
        for geom, site in zip(FINGERTIP_GEOMS, FINGERTIP_SITES, strict=True):
            spec.body(site.split("_")[0] + "_hand").add_geom(
                name=geom,
                type=mujoco.mjtGeom.mjGEOM_SPHERE,
                size=[cfg.fingertip_radius, 0.0, 0.0],
                pos=FINGERTIP_SITE_POS[site],
                mass=0.0,
                contype=FINGERTIP_BIT,
                conaffinity=0,
                rgba=_TIP_RGBA,
            )
        for key in key_table(cfg):
            name = f"piano_key{key.midi}"
            width, thick = key_size(cfg, key)
            body = spec.worldbody.add_body(name=name, pos=[cfg.back_x, key.y, key.top_z])
            body.explicitinertial = True
            mass = cfg.black_mass if key.black else cfg.white_mass
            body.mass = mass
            body.ipos = [0.0, 0.0, 0.0]  # balanced lever: centre of mass on the hinge
            i_x = mass * (width**2 + thick**2) / 3.0
            i_z = mass * (key.lever**2 + width**2) / 3.0
            body.fullinertia = [i_x, key.inertia, i_z, 0.0, 0.0, 0.0]
            body.add_joint(
                name=name,
                type=mujoco.mjtJoint.mjJNT_HINGE,
                axis=[0.0, -1.0, 0.0],
                range=[0.0, key.angle_max],
                stiffness=key.stiffness,
                springref=0.0,
                damping=key.damping,
            )
            body.add_geom(
                name=name,
                type=mujoco.mjtGeom.mjGEOM_BOX,
                size=[key.lever / 2.0, width / 2.0, thick / 2.0],
                pos=[-key.lever / 2.0, 0.0, -thick / 2.0],
                contype=0,
                conaffinity=FINGERTIP_BIT,
                rgba=_BLACK_RGBA if key.black else _WHITE_RGBA,
            )
            body.add_site(name=f"{name}_top", pos=[cfg.press_depth - key.lever, 0.0, 0.0])
            spec.add_sensor(
                name=f"{name}_angle",
                type=mujoco.mjtSensor.mjSENS_JOINTPOS,
                objtype=mujoco.mjtObj.mjOBJ_JOINT,
                objname=name,
            )

    return edit
