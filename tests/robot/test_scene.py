"""The robot's scene from ``mujoco.MjSpec``: the same compiled model as the first (text-template) MJCF.

tests/data/lite_<mode>.xml are the MJCF texts the template builder (``bar_policy/robot/mjcf.py`` up to
commit 8c508c3, ``lite_xml(mode)``) wrote, stored verbatim. The MjSpec build must compile to the very
same model: every numpy array of ``mujoco.MjModel``, every integer, float and bytes attribute (sizes,
``names``, ``signature``) and every field of ``opt``, ``vis`` and ``stat``, compared exactly. Exact,
not within a tolerance: the spec is given the same float64 numbers the XML parser reads from the decimal
text (Python's ``float`` literals and MuJoCo's ``strtod`` both round correctly), in the same order, so
the compiler runs the same arithmetic on the same inputs.

A deliberate change of the robot (new link numbers, a joint property) fails this test; then make the same
change to the reference MJCF text in the same commit and say why (``MjSpec.to_xml`` is no substitute: it
writes 6 significant digits).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import mujoco
import numpy as np
import pytest

from bar_policy.robot.constants import MODES
from bar_policy.robot.scene import load_model

REFERENCE = Path(__file__).parents[1] / "data"


def _fields(obj: Any, prefix: str = "", depth: int = 0) -> dict[str, Any]:
    """Public numeric data of a MuJoCo struct: arrays, numbers and bytes, recursing into sub-structs."""
    out: dict[str, Any] = {}
    for name in dir(obj):
        if name.startswith("_"):
            continue
        value = getattr(obj, name)
        key = f"{prefix}{name}"
        if isinstance(value, np.ndarray | int | float | bytes):
            out[key] = value
        elif type(value).__module__.startswith("mujoco") and not callable(value) and depth < 2:
            out.update(_fields(value, f"{key}.", depth + 1))
    return out


@pytest.mark.parametrize("mode", MODES)
def test_spec_model_equals_text_template_model(mode: str) -> None:
    ref = _fields(mujoco.MjModel.from_xml_path(str(REFERENCE / f"lite_{mode}.xml")))
    new = _fields(load_model(mode))
    assert ref.keys() == new.keys()
    # The comparison covers the model's arrays, its names and its options (not an empty walk).
    covered = {"body_mass", "jnt_range", "key_qpos", "names", "opt.timestep", "vis.global_.offwidth"}
    assert covered <= ref.keys()
    differ = []
    for key, a in ref.items():
        b = new[key]
        if isinstance(a, np.ndarray):
            nan = a.dtype.kind == "f"
            same = a.shape == b.shape and a.dtype == b.dtype and np.array_equal(a, b, equal_nan=nan)
        else:
            same = a == b
        if not same:
            differ.append(key)
    assert not differ, f"{mode}: fields differ from the text-template model: {differ}"
