"""The gate's ranking of held-out evaluations: total excess beyond the thresholds, then accuracy."""

from __future__ import annotations

import math

import pytest

import bar_policy.tasks.registry  # noqa: F401 - registers every task's gate
from bar_policy.quality.gate import excess, score


def _track(completion=100.0, cap=0.1, chatter=1.0, joint=0.01, tip=0.5) -> dict:
    q = {"completion_pct": completion, "cap_share_pct": cap, "chatter_max_mrad": chatter}
    return {"quality": q, "joint_error_rad": joint, "fingertip_error_cm": tip}


def test_excess_by_hand():
    assert excess("track", _track()) == 0.0  # passes every threshold
    # cap 1.0 % vs 0.5: +1; chatter 7.5 vs 5: +0.5; tip 1.5 vs 1: +0.5; completion 98 % vs 100: +0.02.
    assert excess("track", _track(completion=98.0, cap=1.0, chatter=7.5, tip=1.5)) == pytest.approx(2.02)
    # A figure not measured counts 1.
    assert excess("track", _track(chatter=math.nan)) == pytest.approx(1.0)
    # Reach: success 90 % against 95 %: 1 - 90 / 95; a median end distance of 0.9 cm against 0.6: +0.5;
    # none (the MJX evaluation's sums have no median): +1, the same for every iterate.
    reach = {"quality": _track()["quality"], "success_pct": 90.0, "median_end_cm": 0.3}
    assert excess("reach", reach) == pytest.approx(1 - 90 / 95)
    assert excess("reach", {**reach, "median_end_cm": 0.9}) == pytest.approx(1 - 90 / 95 + 0.5)
    assert excess("reach", {**reach, "median_end_cm": None}) == pytest.approx(1 - 90 / 95 + 1)


def test_a_barely_trained_calm_iterate_loses_to_a_precise_one_that_chatters_a_little():
    early = _track(cap=0.6, chatter=0.6, joint=0.105, tip=8.4)  # excess 0.2 + 4.25 + 7.4 = 11.85
    late = _track(cap=1.0, chatter=35.0, joint=0.022, tip=1.44)  # 1 + 6 + 0.1 + 0.44 = 7.54
    assert score("track", late) > score("track", early)
    # Among passing reports the more accurate wins.
    assert score("track", _track(joint=0.008)) > score("track", _track(joint=0.015))
