"""The Lite's compiled model under its first import path; it is built with ``mujoco.MjSpec`` in ``scene.py``.

``load_model(mode)`` and ``PHYSICS_DT`` are ``bar_policy.robot.scene``'s (the model, the physics options
and the collision filter are documented there and in ``links.py``). The text-template MJCF this module
used to write is kept, as it compiled, in tests/data/lite_<mode>.xml: tests/robot/test_scene.py checks
that the MjSpec build compiles to the same model, array by array.
"""

from __future__ import annotations

from bar_policy.robot.scene import PHYSICS_DT, load_model, scene_xml

__all__ = ["PHYSICS_DT", "lite_xml", "load_model"]


def lite_xml(mode: str = "arms") -> str:
    """MJCF text of the robot alone (``scene.scene_xml``: 6 significant digits; for logs and viewers)."""
    return scene_xml(mode)
