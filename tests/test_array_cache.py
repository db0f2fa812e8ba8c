"""The disk cache of computed arrays (``bar_policy._array_cache``) and the piano's key poses through it."""

from __future__ import annotations

import logging

import numpy as np
import pytest

from bar_policy import _array_cache as ac
from bar_policy._array_cache import cached_arrays

NAMES = ("a", "b")


class Counter:
    """A ``compute`` that counts its calls and returns fresh arrays of two dtypes each time."""

    def __init__(self, seed: int = 0) -> None:
        self.calls = 0
        self.seed = seed

    def __call__(self) -> dict[str, np.ndarray]:
        self.calls += 1
        rng = np.random.default_rng(self.seed)
        return {"a": rng.standard_normal((5, 3)), "b": rng.integers(0, 9, size=7)}


def test_a_second_call_loads_bit_for_bit_without_computing(tmp_path):
    compute = Counter()
    first = cached_arrays("thing", {"x": 1}, NAMES, compute, tmp_path)
    again = cached_arrays("thing", {"x": 1}, NAMES, compute, tmp_path)
    assert compute.calls == 1
    expected = Counter()()  # the same seed, worked out again
    for k in NAMES:
        assert again[k].dtype == expected[k].dtype and np.array_equal(again[k], expected[k])
        assert np.array_equal(first[k], expected[k])
    assert len(list(tmp_path.glob("thing-*.npz"))) == 1


def test_other_parts_or_another_package_are_other_entries(tmp_path, monkeypatch):
    compute = Counter()
    cached_arrays("thing", {"x": 1}, NAMES, compute, tmp_path)
    cached_arrays("thing", {"x": 2}, NAMES, compute, tmp_path)
    assert compute.calls == 2
    monkeypatch.setattr(ac, "package_hash", lambda: "f" * 64)  # an edited package
    cached_arrays("thing", {"x": 1}, NAMES, compute, tmp_path)
    assert compute.calls == 3 and len(list(tmp_path.glob("thing-*.npz"))) == 3


def test_past_the_cap_the_least_recently_used_entries_go(tmp_path):
    """Three entries of one size under a cap of two: a store evicts the oldest, a hit counts as a use."""
    import os

    compute = Counter()
    cached_arrays("thing", {"x": 1}, NAMES, compute, tmp_path)
    size = next(tmp_path.glob("*.npz")).stat().st_size  # every entry: the same arrays, the same size
    cap = 2 * size
    cached_arrays("thing", {"x": 2}, NAMES, compute, tmp_path, max_bytes=cap)
    paths = {p.name for p in tmp_path.glob("*.npz")}
    assert len(paths) == 2 and compute.calls == 2
    # Age both, then use x=1: it is now the newer of the two.
    for i, p in enumerate(sorted(tmp_path.glob("*.npz"))):
        os.utime(p, (1_000_000 + i, 1_000_000 + i))
    cached_arrays("thing", {"x": 1}, NAMES, compute, tmp_path, max_bytes=cap)
    assert compute.calls == 2  # a hit
    x1 = max(tmp_path.glob("*.npz"), key=lambda p: p.stat().st_mtime)
    cached_arrays("thing", {"x": 3}, NAMES, compute, tmp_path, max_bytes=cap)  # a store: over the cap
    left = {p.name for p in tmp_path.glob("*.npz")}
    assert len(left) == 2 and x1.name in left  # x=2, the least recently used, went
    cached_arrays("thing", {"x": 2}, NAMES, compute, tmp_path, max_bytes=cap)
    assert compute.calls == 4  # evicted: computed again
    # A cap below one entry keeps the entry just stored and nothing else.
    cached_arrays("thing", {"x": 5}, NAMES, compute, tmp_path, max_bytes=1)
    assert len(list(tmp_path.glob("*.npz"))) == 1


def test_a_corrupt_or_foreign_entry_is_recomputed_and_replaced(tmp_path, caplog):
    compute = Counter()
    cached_arrays("thing", {}, NAMES, compute, tmp_path)
    (entry,) = tmp_path.glob("thing-*.npz")
    entry.write_bytes(b"not an npz")
    with caplog.at_level(logging.WARNING, logger=ac.__name__):
        cached_arrays("thing", {}, NAMES, compute, tmp_path)
    assert compute.calls == 2 and "unreadable cache entry" in caplog.text
    cached_arrays("thing", {}, NAMES, compute, tmp_path)
    assert compute.calls == 2  # replaced by a good entry
    np.savez(entry, a=np.zeros(2))  # a well-formed file without "b"
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger=ac.__name__):
        out = cached_arrays("thing", {}, NAMES, compute, tmp_path)
    assert compute.calls == 3 and "holds ['a'], not ['a', 'b']" in caplog.text
    assert np.array_equal(out["b"], Counter()()["b"])


def test_switched_off_it_computes_every_time_and_writes_nothing(tmp_path, monkeypatch):
    monkeypatch.setenv(ac.SWITCH, "0")
    compute = Counter()
    cached_arrays("thing", {}, NAMES, compute, tmp_path)
    cached_arrays("thing", {}, NAMES, compute, tmp_path)
    assert compute.calls == 2 and not list(tmp_path.iterdir())


def test_an_unwritable_path_returns_the_arrays_and_says_so(tmp_path, caplog):
    blocker = tmp_path / "file"
    blocker.write_text("a file where the directory should be")
    with caplog.at_level(logging.WARNING, logger=ac.__name__):
        out = cached_arrays("thing", {}, NAMES, Counter(), blocker / "arrays")
    assert np.array_equal(out["b"], Counter()()["b"]) and "not cached" in caplog.text


def test_compute_must_return_the_named_arrays(tmp_path):
    with pytest.raises(ValueError, match=r"returned arrays \['a'\], expected \['a', 'b'\]"):
        cached_arrays("thing", {}, NAMES, lambda: {"a": np.zeros(1)}, tmp_path)


def test_the_directory_follows_the_environment(tmp_path, monkeypatch):
    monkeypatch.delenv("BAR_POLICY_CACHE_DIR", raising=False)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    assert ac.cache_dir() == tmp_path / "xdg" / "bar_policy" / "arrays"
    monkeypatch.setenv("BAR_POLICY_CACHE_DIR", str(tmp_path / "mine"))
    assert ac.cache_dir() == tmp_path / "mine" / "arrays"


def test_key_poses_are_served_from_their_entry(tmp_path, monkeypatch):
    """``key_poses`` asks the cache under its keyboard, mode and config: an entry made for exactly those is
    returned without any IK (the solver is replaced by one that fails)."""
    from bar_policy.tasks.piano import prior
    from bar_policy.tasks.piano.keyboard import default_config

    monkeypatch.setenv("BAR_POLICY_CACHE_DIR", str(tmp_path))
    keyboard, pc = default_config(), prior.KeyPosePriorConfig()
    marker = {"hover": np.full((2, 14), 0.25), "press": np.full((2, 14), -0.5), "hand": np.array([0, 1])}
    parts = {"keyboard": repr(keyboard), "mode": "arms", "config": repr(pc)}
    cached_arrays("piano_key_poses", parts, ("hover", "press", "hand"), lambda: marker)

    def no_ik(*_):
        raise AssertionError("the IK ran although the entry was there")

    monkeypatch.setattr(prior, "_solve_key_poses", no_ik)
    poses = prior.key_poses.__wrapped__(keyboard, "arms", None)
    assert all(np.array_equal(getattr(poses, k), v) for k, v in marker.items())
    with pytest.raises(AssertionError, match="the IK ran"):  # another mode is another entry
        prior.key_poses.__wrapped__(keyboard, "full", None)
