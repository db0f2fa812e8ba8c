"""LiteTrack's start-up cache: the random clips and the reference kinematics come from disk
(``bar_policy._array_cache``) bit for bit, and a config field they depend on is another entry, never a stale
hit. Small clip sets (2 clips of 2 s) keep each build under a second on the CPU."""

from __future__ import annotations

import numpy as np
import pytest

from bar_policy import envs
from bar_policy.motion import generator
from bar_policy.robot.kinematics import Kinematics

SMALL = ("motion.num_clips=2", "motion.clip_length_s=2.0")
TABLE = ("joint_pos", "body_pos", "body_ori", "fingertip_pos", "clip_start", "clip_length")
DEVICE = ("_ref_q", "_ref_dq", "_ref_pos", "_ref_ori", "_ref_tip", "_clip_start", "_clip_length")


def _build(*overrides: str) -> envs.MjxEnv:
    return envs.load("LiteTrack", overrides=[*SMALL, *overrides])


def _snapshot(env: envs.MjxEnv) -> dict:
    """Everything the env derives from its clips: the table, its device copies, the clip names and set id."""
    out = {k: getattr(env.reference, k) for k in TABLE}
    out |= {k: np.asarray(getattr(env, k)) for k in DEVICE}
    return {**out, "names": env.reference.clip_names, "id": env.clip_set_id}


def _assert_identical(a: dict, b: dict) -> None:
    assert a.keys() == b.keys()
    for k, x in a.items():
        if isinstance(x, np.ndarray):
            y = b[k]
            assert (x.dtype, x.shape) == (y.dtype, y.shape), k
            assert x.tobytes() == y.tobytes(), k  # bit for bit, not merely equal
        else:
            assert x == b[k], k


def _entries(tmp_path) -> list[str]:
    return sorted(p.name.split("-")[0] for p in (tmp_path / "arrays").glob("*.npz"))


@pytest.fixture
def cache(tmp_path, monkeypatch):
    """The array cache switched on, in an empty directory of its own."""
    monkeypatch.setenv("BAR_POLICY_CACHE_DIR", str(tmp_path))
    monkeypatch.setenv("BAR_POLICY_ARRAY_CACHE", "1")
    return tmp_path


def _forbid_computing(monkeypatch) -> None:
    """Make clip generation and the table's forward kinematics fail: what follows must load both."""

    def fail(*_, **__):
        raise AssertionError("computed although a cache entry was there")

    monkeypatch.setattr(generator, "random_clip", fail)
    monkeypatch.setattr(Kinematics, "trajectory", fail)


def test_a_cached_build_is_the_uncached_build_bit_for_bit(cache, monkeypatch):
    monkeypatch.setenv("BAR_POLICY_ARRAY_CACHE", "0")
    off = _build()
    uncached, uncached_eval = _snapshot(off), _snapshot(off.evaluation_env())
    assert _entries(cache) == []  # switched off: nothing written
    monkeypatch.setenv("BAR_POLICY_ARRAY_CACHE", "1")
    miss = _build()
    _assert_identical(uncached, _snapshot(miss))
    _assert_identical(uncached_eval, _snapshot(miss.evaluation_env()))
    # One entry of random clips and one of kinematics for each of the training and the held-out set.
    assert _entries(cache) == ["motion_random_clips"] * 2 + ["track_reference"] * 2
    _forbid_computing(monkeypatch)
    hit = _build()
    _assert_identical(uncached, _snapshot(hit))
    _assert_identical(uncached_eval, _snapshot(hit.evaluation_env()))
    assert len(_entries(cache)) == 4


def test_a_field_the_clips_depend_on_is_another_entry(cache, monkeypatch):
    base = _snapshot(_build())
    assert _entries(cache) == ["motion_random_clips", "track_reference"]
    # Longer clips: both entries miss (2 s -> 101 frames at 50 Hz; 3 s rounds up to whole 0.4 s knots,
    # 3.2 s -> 161 frames).
    longer = _snapshot(_build("motion.clip_length_s=3.0"))
    assert list(longer["clip_length"]) == [161, 161] and list(base["clip_length"]) == [101, 101]
    assert longer["id"] != base["id"] and len(_entries(cache)) == 4
    # Another control rate (25 Hz): the same clips (a hit), resampled, so other kinematics (a miss).
    slower = _snapshot(_build("ctrl_dt=0.04", "episode_length_s=4.0"))
    assert slower["id"] == base["id"] and list(slower["clip_length"]) == [51, 51]
    assert _entries(cache) == ["motion_random_clips"] * 2 + ["track_reference"] * 3
    # A field the clips do not depend on (a reward width) loads both entries: nothing is computed.
    _forbid_computing(monkeypatch)
    _assert_identical(base, _snapshot(_build("reward.joint_std=0.1")))
    assert len(_entries(cache)) == 5
    with pytest.raises(AssertionError, match="computed although"):  # one more clip: a miss
        _build("motion.num_clips=3")
