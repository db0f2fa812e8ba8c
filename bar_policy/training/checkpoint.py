"""Resumable checkpoints as msgpack (flax.serialization), never pickle.

A checkpoint ``<run>/checkpoints/step_<env_steps>.msgpack`` holds a state tree (for the brax backend:
normaliser, policy and value params, optimizer state) plus the step count and iteration; a small JSON
sidecar of the same name records the step count and the config for humans. ``latest_checkpoint(run_dir)``
finds the newest one, so ``--resume runs/<name>`` works.

A run writes them through its logger (``records.SaveCheckpoint``, from either trainer) and reads the one it
resumes before its trainer starts (``read_checkpoint``); the brax trainer restores the state into its
training state's structure (``restore_state``), the rsl-rl trainer into its torch modules.
"""

from __future__ import annotations

import dataclasses
import json
import os
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from flax import serialization

from bar_policy._files import write_atomic
from bar_policy.training.startup.executable_key import program_fields

__all__ = [
    "Checkpoint",
    "latest_checkpoint",
    "load_checkpoint",
    "read_checkpoint",
    "restore_state",
    "resume_changes",
    "save_checkpoint",
]

_NAME = re.compile(r"step_(\d+)\.msgpack$")

_STEPS = "ppo.num_timesteps"
"""How far a run goes: a resume is expected to change it (not listed by ``resume_changes``)."""


@dataclass(frozen=True, kw_only=True)
class Checkpoint:
    """What a checkpoint restores."""

    state: Any
    """State tree (restored into the caller's template structure)."""
    env_steps: int
    """Environment steps trained so far (summed over envs and devices)."""
    iteration: int
    """Training iterations done so far."""
    path: Path
    """File it came from."""
    changes: tuple[str, ...] = ()
    """What a resume trains differently from the checkpoint's run (``resume_changes``; ``read_checkpoint``
    with the resuming run's record)."""


def save_checkpoint(
    directory: str | os.PathLike[str],
    state: Any,
    *,
    env_steps: int,
    iteration: int,
    extra: dict[str, Any] | None = None,
) -> Path:
    """Write ``step_<env_steps>.msgpack`` (+ ``.json`` sidecar) into ``directory``; returns the msgpack path.

    Args:
        directory: checkpoint folder (created).
        state: a pytree of arrays (flax structs, dicts, optax named tuples); host or device arrays.
        env_steps: environment steps so far.
        iteration: training iterations so far.
        extra: JSON-able record for the sidecar (e.g. the config).
    """
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    payload = {
        "state": serialization.to_state_dict(state),
        "env_steps": int(env_steps),
        "iteration": int(iteration),
    }
    path = directory / f"step_{int(env_steps):012d}.msgpack"
    write_atomic(path, serialization.msgpack_serialize(payload))
    sidecar = {"env_steps": int(env_steps), "iteration": int(iteration), **(extra or {})}
    write_atomic(path.with_suffix(".json"), json.dumps(sidecar, indent=2, sort_keys=True).encode())
    return path


def latest_checkpoint(path: str | os.PathLike[str]) -> Path:
    """The newest checkpoint file: ``path`` itself if it is one, else the highest step under it.

    Accepts a checkpoint file, a ``checkpoints/`` folder or a run directory.

    Raises:
        FileNotFoundError: nothing to resume from (the message names the places searched).
    """
    path = Path(path)
    if path.is_file():
        if not _NAME.search(path.name):
            raise FileNotFoundError(f"{path} is not a checkpoint (expected step_<N>.msgpack)")
        return path
    candidates = [*path.glob("step_*.msgpack"), *path.glob("checkpoints/step_*.msgpack")]
    candidates = [c for c in candidates if _NAME.search(c.name)]
    if not candidates:
        raise FileNotFoundError(f"no step_<N>.msgpack checkpoint in {path} or {path / 'checkpoints'}")
    return max(candidates, key=lambda c: int(_NAME.search(c.name).group(1)))  # type: ignore[union-attr]


def read_checkpoint(path: str | os.PathLike[str], record: dict[str, Any] | None = None) -> Checkpoint:
    """The newest checkpoint at ``path``, its state as saved (a state dict: ``restore_state`` shapes it).

    What a resume reads first (``training.run``), before its trainer has the structure to restore into.

    Args:
        path: a checkpoint file, its folder, or a run directory (the newest checkpoint is used).
        record: the resuming run's record: the checkpoint's ``changes`` are then what it trains differently
            (``resume_changes``).

    Raises:
        FileNotFoundError: no checkpoint found.
        ValueError: the file is not a checkpoint.
    """
    file = latest_checkpoint(path)
    try:
        payload = serialization.msgpack_restore(file.read_bytes())
        state, env_steps, iteration = payload["state"], int(payload["env_steps"]), int(payload["iteration"])
    except (KeyError, ValueError, TypeError) as e:
        raise ValueError(f"cannot restore {file}: {e} (was it written by another network/config?)") from e
    changes = tuple(resume_changes(file, record))
    return Checkpoint(state=state, env_steps=env_steps, iteration=iteration, path=file, changes=changes)


def restore_state(checkpoint: Checkpoint, template: Any) -> Any:
    """A read checkpoint's state in the structure of ``template`` (same tree as the one saved).

    Raises:
        ValueError: the state is not of this structure or these shapes (e.g. another network size).
    """
    try:
        state = serialization.from_state_dict(template, checkpoint.state)
    except (KeyError, ValueError, TypeError) as e:
        raise ValueError(
            f"cannot restore {checkpoint.path}: {e} (was it written by another network/config?)"
        ) from e
    import jax
    import numpy as np

    shapes_ok = jax.tree_util.tree_all(
        jax.tree_util.tree_map(lambda a, b: np.shape(a) == np.shape(b), template, state)
    )
    if not shapes_ok:
        raise ValueError(f"cannot restore {checkpoint.path}: array shapes differ from this run's networks")
    return state


def load_checkpoint(path: str | os.PathLike[str], template: Any) -> Checkpoint:
    """Read a checkpoint into the structure of ``template`` (``read_checkpoint``, then ``restore_state``).

    Args:
        path: a checkpoint file, its folder, or a run directory (the newest checkpoint is used).
        template: a state tree of the right structure (e.g. a freshly initialised training state).

    Raises:
        FileNotFoundError: no checkpoint found.
        ValueError: the file is not a checkpoint of this structure (e.g. another network size).
    """
    checkpoint = read_checkpoint(path)
    return dataclasses.replace(checkpoint, state=restore_state(checkpoint, template))


def _flat(tree: Any, prefix: str = "") -> dict[str, Any]:
    """``{"a": {"b": 1}}`` -> ``{"a.b": 1}``."""
    if not isinstance(tree, dict):
        return {prefix: tree}
    out: dict[str, Any] = {}
    for k, v in tree.items():
        out.update(_flat(v, f"{prefix}.{k}" if prefix else str(k)))
    return out


def resume_changes(checkpoint: str | os.PathLike[str], record: dict[str, Any] | None) -> list[str]:
    """Lines naming what a resume trains differently from the run it resumes, for the log.

    A resume trains under the command's own config, which is what it should do (a longer run, a changed
    reward weight). But a default that changed between the two runs (the reach gpu preset's batch and
    physics step on 2026-11-27) would change the training without a word, so every difference between the
    checkpoint's sidecar record and this run's (``train`` and ``env`` sections, flattened to dotted names)
    is listed, except the fields a resume is expected to change: those no program reads (where it writes,
    when it stops, what it exports, its caches: ``executable_key.program_fields`` leaves them out) and the
    step count. ``[]`` when both agree or when ``record`` is None; one line when the checkpoint has no
    readable sidecar.

    Args:
        checkpoint: the checkpoint file resumed (its ``.json`` sidecar holds the run's record).
        record: this run's record (``{"train": config_to_dict(cfg), "env": ...}``).
    """
    if record is None:
        return []
    sidecar = Path(checkpoint).with_suffix(".json")
    try:
        old = json.loads(sidecar.read_text())
    except (OSError, ValueError) as e:
        return [f"resume: no config record to compare with ({sidecar}: {e})"]
    lines = []
    for section, kept in (("train", program_fields), ("env", dict)):
        before, now = (_flat(kept(r.get(section, {}))) for r in (old, record))
        for name in sorted((set(before) | set(now)) - {_STEPS}):
            if before.get(name) != now.get(name):
                lines.append(f"  {section} {name}: {before.get(name)!r} -> {now.get(name)!r}")
    if lines:
        return [f"resume: {len(lines)} settings differ from the resumed run's ({sidecar.name}):", *lines]
    return []
