"""A script prefix that blocks the training stack: run after it, importing jax, torch, brax, flax or MJX
raises ImportError (``tests/test_task_registry.py``, ``tests/deploy/test_shipped_policies.py``)."""

from __future__ import annotations

BLOCK_HEAVY = r"""
import importlib.abc, sys

BLOCKED = ("jax", "jaxlib", "torch", "brax", "flax", "mujoco.mjx")


class Blocked(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        if name in BLOCKED or name.startswith(tuple(b + "." for b in BLOCKED)):
            raise ImportError(f"{name} is blocked in this test")
        return None


sys.meta_path.insert(0, Blocked())
"""
"""Prepended to a subprocess script (a meta-path finder that refuses the blocked names)."""
