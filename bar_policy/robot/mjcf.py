"""The Lite's compiled model under its first import path; it is built with ``mujoco.MjSpec`` in ``scene.py``.

``load_model(mode)`` and ``PHYSICS_DT`` are ``bar_policy.robot.scene``'s (the model, the physics options
and the collision filter are documented there and in ``links.py``). The text-template MJCF this module
used to write is kept, as it compiled, in tests/data/lite_<mode>.xml: tests/robot/test_scene.py checks
that the MjSpec build compiles to the same model, array by array.
"""

from __future__ import annotations

from bar_policy.robot.scene import PHYSICS_DT, load_model

__all__ = ["PHYSICS_DT", "load_model"]
