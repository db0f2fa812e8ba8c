"""Record LiteReach's step outputs at fixed seeds, so a refactor of the env can prove it changed nothing.

Run from the repository root (writes ``tests/data/reach_golden.npz``)::

    PYTHONPATH=$PWD python tests/data/make_reach_golden.py

Two rollouts, both with seeded uniform random actions in [-1, 1] (float32):

- ``nominal/*``: the nominal config (``envs.nominal_config()``), unbatched ``jit(env.reset)`` at
  ``PRNGKey(0)`` then ``NOMINAL_STEPS`` ``jit(env.step)`` calls.
- ``wrapped/*``: the training config with every randomisation on (1 s episodes and 0.5 s target segments,
  as the ``dr_env`` test fixture, so the rollout crosses an auto-reset and two resamplings), through
  ``wrap_for_brax_training`` with the model randomiser at ``BATCH`` envs (keys ``PRNGKey(42)``), reset at
  ``PRNGKey(7)``, then ``WRAPPED_STEPS`` steps.

Each record holds, per step (index 0 = the reset state): obs, reward, done, every metric, qpos, qvel and
every info leaf (the wrapper's ``episode_metrics`` included), under ``<run>/<field>`` keys. The functions
below take the jitted reset/step so the test (tests/envs/test_reach_golden.py) replays them with the
session fixtures' compiled functions.

First recorded from the unsplit env (bar_policy/envs/reach.py at commit bec536f); re-recorded when the reach
recipe changed on purpose (the 3 Hz action filter, the ``action_accel`` and ``torque_near_cap``
terms and ``action_rate`` -0.1, which add an info leaf and two reward metrics), on an AVX2 machine, from the
commit after 9897af8; and again for the command transition (the commanded target moves to each new
goal along a minimum-jerk path, adding the ``from_*`` and ``goal_*`` info leaves), on an AVX2 machine, from
the commit after 8c508c3; and again for the ``wrist_posture`` term (against the ship gate's torque-cap misses:
a new reward metric), on an AVX2 machine, from the commit after 79b5390. That time every leaf the earlier file
held was bit for bit the same except ``reward`` and the episode reward sum, whose change equals the new
term within 7e-8.
"""

from __future__ import annotations

import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

NOMINAL_STEPS = 30
WRAPPED_STEPS = 55
BATCH = 8
DR_OVERRIDES = ("episode_length_s=1.0", "resample_period_s=0.5", "target_transition_s=0.2")
GOLDEN_PATH = Path(__file__).with_name("reach_golden.npz")


def _leaves(prefix: str, tree: Any) -> dict[str, np.ndarray]:
    out = {}
    for path, leaf in jax.tree_util.tree_flatten_with_path(tree)[0]:
        key = "/".join(str(getattr(p, "key", getattr(p, "name", p))) for p in path)
        out[f"{prefix}/{key}"] = np.asarray(leaf)
    return out


def _snapshot(state: Any) -> dict[str, np.ndarray]:
    snap = {
        "obs": np.asarray(state.obs),
        "reward": np.asarray(state.reward),
        "done": np.asarray(state.done),
        "qpos": np.asarray(state.data.qpos),
        "qvel": np.asarray(state.data.qvel),
    }
    snap.update(_leaves("metrics", state.metrics))
    snap.update(_leaves("info", state.info))
    return snap


def _rollout(state: Any, step: Callable, actions: np.ndarray) -> dict[str, np.ndarray]:
    snaps = [_snapshot(state)]
    for a in actions:
        state = step(state, jnp.asarray(a, dtype=jnp.float32))
        snaps.append(_snapshot(state))
    return {k: np.stack([s[k] for s in snaps]) for k in snaps[0]}


def nominal_actions() -> np.ndarray:
    """Shape (NOMINAL_STEPS, 14), float32."""
    return np.random.default_rng(1234).uniform(-1, 1, (NOMINAL_STEPS, 14)).astype(np.float32)


def wrapped_actions() -> np.ndarray:
    """Shape (WRAPPED_STEPS, BATCH, 14), float32."""
    return np.random.default_rng(5678).uniform(-1, 1, (WRAPPED_STEPS, BATCH, 14)).astype(np.float32)


def record_nominal(reset: Callable, step: Callable) -> dict[str, np.ndarray]:
    """Rollout of the nominal env with ``jit(env.reset)`` / ``jit(env.step)``."""
    return _rollout(reset(jax.random.PRNGKey(0)), step, nominal_actions())


def record_wrapped(reset: Callable, step: Callable) -> dict[str, np.ndarray]:
    """Rollout of the randomised batched env with its jitted reset/step."""
    keys = jax.random.split(jax.random.PRNGKey(7), BATCH)
    return _rollout(reset(keys), step, wrapped_actions())


def main() -> int:
    import functools

    from bar_policy import envs

    nominal = envs.load("LiteReach", config=envs.nominal_config())
    rec = record_nominal(jax.jit(nominal.reset), jax.jit(nominal.step))
    rec = {f"nominal/{k}": v for k, v in rec.items()}
    dr = envs.load("LiteReach", overrides=list(DR_OVERRIDES))
    keys = jax.random.split(jax.random.PRNGKey(42), BATCH)
    rand = functools.partial(envs.get_randomizer("LiteReach", dr.config), rng=keys)
    w = envs.wrap_for_brax_training(dr, episode_length=dr.episode_length, randomization_fn=rand)
    rec.update({f"wrapped/{k}": v for k, v in record_wrapped(jax.jit(w.reset), jax.jit(w.step)).items()})
    np.savez_compressed(GOLDEN_PATH, **rec)
    print(f"wrote {GOLDEN_PATH} ({GOLDEN_PATH.stat().st_size / 1024:.0f} KiB, {len(rec)} arrays)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
