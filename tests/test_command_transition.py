"""The reach command transition: the minimum-jerk path, its deploy wrapper, its metadata key.

The env's side (the commanded target after each step) is checked by hand in
``tests/envs/test_env.py::test_step_reward_metrics_and_resampling``; its parity with the deploy wrapper is
``tests/envs/test_reach_transition_parity.py``.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from bar_policy.deploy.metadata import MetadataError, PolicyMetadata
from bar_policy.tasks.reach import min_jerk, transition_point
from bar_policy.tasks.reach.commands import FileCommands, SampledCommands
from bar_policy.tasks.reach.transition import TransitionCommands
from tests.test_metadata import make

NAMES = ("target_pos_left", "target_pos_right")
INITIAL = {"target_pos_left": np.array([0.36, 0.16, 0.21]), "target_pos_right": np.array([0.36, -0.16, 0.21])}


def test_min_jerk_by_hand() -> None:
    s = np.array([-0.5, 0.0, 0.25, 0.5, 1.0, 2.0])
    # 10/64 - 15/256 + 6/1024 = 0.103515625 at 1/4; 10/8 - 15/16 + 6/32 = 0.5 at 1/2; clipped outside [0, 1].
    np.testing.assert_array_equal(min_jerk(s), [0.0, 0.0, 0.103515625, 0.5, 1.0, 1.0])
    # Zero slope at both ends: a step of 1e-4 in s moves it by ~10 s^3 = 1e-11.
    assert min_jerk(np.array(1e-4)) < 1e-11 and 1 - min_jerk(np.array(1 - 1e-4)) < 1e-11


def test_transition_point() -> None:
    a, b = np.array([0.0, 1.0, 2.0]), np.array([1.0, 1.0, 0.0])
    np.testing.assert_allclose(transition_point(a, b, 0.25, 0.5), [0.5, 1.0, 1.0])  # half-way at half time
    np.testing.assert_array_equal(transition_point(a, b, 0.0, 0.5), a)
    np.testing.assert_array_equal(transition_point(a, b, 9.0, 0.5), b)
    np.testing.assert_array_equal(transition_point(a, b, 0.0, 0.0), b)  # 0 s: a step


class _Scripted(SampledCommands):
    """Goals from a table: ``goals[k]`` from ``t = times[k]`` on."""

    def __init__(self, times: list[float], goals: list[tuple[np.ndarray, np.ndarray]]) -> None:
        super().__init__(NAMES)
        self.times, self.goals = times, goals

    def _values(self, t: float) -> dict[str, np.ndarray]:
        k = max(i for i, t0 in enumerate(self.times) if t >= t0 - 1e-9)
        return dict(zip(NAMES, (g.copy() for g in self.goals[k]), strict=True))


def test_wrapper_moves_from_where_it_is() -> None:
    g1 = (np.array([0.30, 0.20, 0.30]), np.array([0.30, -0.20, 0.30]))
    g2 = (np.array([0.25, 0.10, 0.15]), np.array([0.25, -0.10, 0.15]))
    src = TransitionCommands(_Scripted([0.0, 0.5], [g1, g2]), 1.0, INITIAL)
    assert src.names == NAMES and src.task == "reach"
    src.begin(0.0)
    out = {}
    for k in range(0, 151):
        out[k] = src(k * 0.02)
    # Tick 0: the initial targets (elapsed 0); tick 12 (0.24 s): min_jerk(0.24) of the way to g1.
    np.testing.assert_array_equal(out[0]["target_pos_left"], INITIAL["target_pos_left"])
    s = 10 * 0.24**3 - 15 * 0.24**4 + 6 * 0.24**5
    expected = INITIAL["target_pos_left"] + (g1[0] - INITIAL["target_pos_left"]) * s
    np.testing.assert_allclose(out[12]["target_pos_left"], expected, rtol=0, atol=1e-15)
    # g2 arrives at tick 25 (0.5 s): the new move starts at the tick-24 target and takes 1 s from there.
    np.testing.assert_array_equal(out[25]["target_pos_left"], out[24]["target_pos_left"])
    s = 10 * 0.5**3 - 15 * 0.5**4 + 6 * 0.5**5
    mid = out[24]["target_pos_right"] + (g2[1] - out[24]["target_pos_right"]) * s
    np.testing.assert_allclose(out[50]["target_pos_right"], mid, rtol=0, atol=1e-15)
    np.testing.assert_array_equal(out[75]["target_pos_left"], g2[0])  # 1 s after the change: the goal
    assert src.moves == 2
    rec = src.record()
    np.testing.assert_array_equal(rec["target_pos_left_goal"], g2[0])
    assert set(src.log_fields) == {*NAMES, "target_pos_left_goal", "target_pos_right_goal"}
    assert src.metadata()["transition_s"] == 1.0 and "1 s minimum-jerk" in src.describe()
    # begin() restarts at the initial targets (a second POLICY segment after HOLD).
    src.begin(3.0)
    np.testing.assert_array_equal(src(3.0)["target_pos_left"], INITIAL["target_pos_left"])
    assert src.hold_pose is None and src.target_q() is None


def test_wrapper_counts_outside_targets_and_delegates(tmp_path) -> None:
    path = tmp_path / "c.json"
    far = [2.0, 0.2, 0.2]  # x = 2 m: outside the workspace box (x <= 0.42 m)
    path.write_text(json.dumps([{"t": 0.0, "target_pos_left": far, "target_pos_right": [0.3, -0.2, 0.2]}]))
    src = TransitionCommands(FileCommands(NAMES, path), 0.5, INITIAL)
    src(0.0)
    assert src.outside_count == 1  # counted by the inner source (never clipped)
    assert src.path == path  # other attributes are the inner source's
    with pytest.raises(ValueError, match="must last > 0 s"):
        TransitionCommands(FileCommands(NAMES, path), 0.0, INITIAL)
    with pytest.raises(ValueError, match=r"initial targets lack \['target_pos_right'\]"):
        TransitionCommands(FileCommands(NAMES, path), 0.5, {"target_pos_left": np.zeros(3)})


def test_metadata_key_round_trip_and_refusals() -> None:
    md = make(command_transition_s=1.0)
    props = md.to_props()
    assert json.loads(props["bar.command_transition"]) == {"duration_s": 1.0, "profile": "min_jerk"}
    assert PolicyMetadata.from_props(props).command_transition_s == 1.0
    assert "bar.command_transition" not in make().to_props()  # 0 s: no key, as in older files
    del props["bar.command_transition"]
    assert PolicyMetadata.from_props(props).command_transition_s == 0.0
    for bad in (
        '{"duration_s": 1.0}',
        '{"duration_s": 1.0, "profile": "cubic"}',
        '{"duration_s": true, "profile": "min_jerk"}',
    ):
        props["bar.command_transition"] = bad
        with pytest.raises(MetadataError, match=r"'bar\.command_transition' must be"):
            PolicyMetadata.from_props(props)
    props["bar.command_transition"] = '{"duration_s": -1.0, "profile": "min_jerk"}'
    with pytest.raises(MetadataError, match=r"command transition must be a number of s >= 0, got -1\.0"):
        PolicyMetadata.from_props(props)
