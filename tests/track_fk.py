"""The tracked bodies' poses straight from C MuJoCo: the independent reference of the track tests.

A module with a name no test folder uses, so both ``tests/envs`` and ``tests/deploy`` import the same one
(``tests/`` is on ``sys.path`` through its ``conftest.py``).
"""

from __future__ import annotations

from collections.abc import Sequence

import mujoco
import numpy as np

from bar_policy.robot.mjcf import load_model


def c_fk(q: np.ndarray, bodies: Sequence[str]) -> tuple[np.ndarray, np.ndarray]:
    """Positions (B, 3) and 6-D orientations (B, 6) of ``bodies`` at joint positions ``q`` (arms), from
    MjData after ``mj_kinematics``; the 6-D layout is the rotation's first two columns by row
    (r00, r01, r10, r11, r20, r21)."""
    m = load_model("arms")
    d = mujoco.MjData(m)
    d.qpos[:] = q
    mujoco.mj_kinematics(m, d)
    pos = np.stack([d.body(b).xpos for b in bodies])
    rot = np.stack([d.body(b).xmat.reshape(3, 3) for b in bodies])
    return pos, rot[:, :, :2].reshape(-1, 6)
