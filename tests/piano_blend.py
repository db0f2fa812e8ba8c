"""The piano's key-pose blend worked out by hand, for the reference tests on both sides.

``tests/tasks/test_piano_reference.py`` (deploy) and ``tests/tasks/test_piano_env_reference.py`` (MJX) hold
the prior's reference to this, each on its own hand-made windows.
"""

from __future__ import annotations

import numpy as np

from bar_policy.tasks.piano.keyboard import KeyboardConfig
from bar_policy.tasks.piano.prior import KeyPosePriorConfig, key_poses


def hand_blend(
    frames: dict[int, list[int]], default: np.ndarray, kb: KeyboardConfig, scale: float
) -> np.ndarray:
    """The key-pose blend of goal keys ``{frame: [midi, ...]}`` with no key down, action units (14,), float64.

    Per arm: sum_j w_j (pose_j - default) / scale over its keys / (sum_j w_j + rest), w_j = decay ** frame,
    pose = press for frames 0..lead (2), hover later; a hand is left below middle C. Plus the edge blend:
    per key, c_j (press - hover) / scale with c_0 = -0.45 and c_2 (the lead) = +0.45, the other frames 0.
    (The release blend reads the keys down: with none down it adds 0.) Clipped to +-0.99.
    """
    pc = KeyPosePriorConfig()
    edge = {0: -0.45, 2: 0.45}
    assert pc.edge_gain == 0.45 and pc.edge_weights is None
    poses = key_poses(kb)
    num, den, lin = np.zeros(14), np.full(14, pc.rest_weight), np.zeros(14)
    for j, midis in frames.items():
        for m in midis:
            k = m - kb.lowest
            arm = np.arange(7) + (0 if m < 60 else 7)
            pose = poses.press[k] if j <= 2 else poses.hover[k]
            w = pc.decay**j
            num[arm] += w * (pose[arm] - default[arm]) / scale
            den[arm] += w
            lin[arm] += edge.get(j, 0.0) * (poses.press[k, arm] - poses.hover[k, arm]) / scale
    return np.clip(num / den + lin, -0.99, 0.99)
