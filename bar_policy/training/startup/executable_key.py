"""The executable cache's key parts: the run's context, package content, versions, platform, flags, signature.

Each is described the same way in every process (``executable_cache`` hashes them). The run's context
(``run_context``) is its record less what no program reads (``program_fields``, ``weights_by_name``) and its
env's class and source.

Seeding XLA's autotune cache (``autotune``) changes none of these parts but ``package_hash`` (its
archive is a package file: replacing it misses once): a seed only changes which implementation XLA picks
for a fusion, not what a program computes, so the key rightly ignores whether a seed was applied, and
``runtime_flags`` leaves out jax's ``jax_persistent_cache_*`` settings (``..._enable_xla_caches`` among them).
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import json
import os
from collections.abc import Mapping
from importlib import metadata
from pathlib import Path
from typing import Any

import numpy as np

from bar_policy._files import PACKAGE_ROOT, package_hash

__all__ = [
    "OUTSIDE_PROGRAMS",
    "library_versions",
    "package_hash",
    "platform",
    "program_fields",
    "run_context",
    "runtime_flags",
    "signature",
    "source_hash",
    "weights_by_name",
]

LIBRARIES = (
    "jax",
    "jaxlib",
    "jax-cuda12-plugin",
    "jax-cuda12-pjrt",
    "jax-cuda13-plugin",
    "jax-cuda13-pjrt",
    "libtpu",
    "mujoco",
    "mujoco-mjx",
    "brax",
    "flax",
    "optax",
    "numpy",
)
"""Distributions whose version is part of the key (None when not installed)."""


def source_hash(obj: Any) -> str | None:
    """SHA-256 of the source file defining ``obj``'s class.

    None when the file lies in ``bar_policy`` (``package_hash`` covers it) or there is none.
    """
    import inspect

    cls = obj if isinstance(obj, type) else type(obj)
    try:
        path = Path(inspect.getfile(cls)).resolve()
    except (TypeError, OSError):
        return None
    if path.is_relative_to(PACKAGE_ROOT) or not path.is_file():
        return None
    return hashlib.sha256(path.read_bytes()).hexdigest()


@functools.cache
def library_versions() -> dict[str, str | None]:
    """Installed versions of ``LIBRARIES`` (``jax.__version__``/``jaxlib.__version__`` for those two)."""
    import jax
    import jaxlib

    out: dict[str, str | None] = {}
    for name in LIBRARIES:
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            out[name] = None
    out["jax"], out["jaxlib"] = jax.__version__, jaxlib.__version__
    return out


def platform() -> dict[str, Any]:
    """The default backend and its devices, the process count and index."""
    import jax

    devices = jax.devices()
    return {
        "backend": jax.default_backend(),
        "platform_version": devices[0].client.platform_version,
        "devices": [[d.id, d.device_kind, d.process_index] for d in devices],
        "local_devices": [d.id for d in jax.local_devices()],
        "process_count": jax.process_count(),
        "process_index": jax.process_index(),
    }


def runtime_flags() -> dict[str, str]:
    """Every jax config value but the compilation cache's own, and the XLA/JAX/LIBTPU environment."""
    import jax

    flags = {
        k: repr(v)
        for k, v in jax.config.values.items()
        if "compilation_cache" not in k and "persistent_cache" not in k
    }
    env = {
        k: v
        for k, v in os.environ.items()
        if k.startswith(("XLA_", "JAX_", "LIBTPU_")) and "COMPILATION_CACHE" not in k
    }
    return {**flags, **{f"env:{k}": v for k, v in env.items()}}


def _sharding(s: Any) -> Any:
    if s is None:
        return None
    mesh = getattr(s, "mesh", None)
    devices = getattr(mesh, "devices", None)
    if devices is not None:
        ids = [int(d.id) for d in devices.flat]
    else:
        ids = sorted(int(d.id) for d in getattr(s, "device_set", ()))
    return [repr(s), ids, getattr(s, "memory_kind", None)]


def _name(t: type) -> str:
    return f"{t.__module__}.{t.__qualname__}"


def _stable(x: Any, depth: int = 0) -> Any:
    """A description of ``x`` that is the same in every process for equal content (a tree's static data).

    Containers, numpy arrays (by content), dataclasses and objects (by their fields) are described by
    value; whatever else falls back to ``repr``, which may hold an address: then the key differs in every
    run (a miss each time), it never matches a program built for other content.
    """
    if x is None or isinstance(x, bool | int | float | complex | str | bytes):
        return repr(x)
    if isinstance(x, np.generic):
        return f"{type(x).__name__}({x!r})"
    if isinstance(x, np.ndarray):
        digest = hashlib.sha256(np.ascontiguousarray(x).tobytes()).hexdigest()
        return ["ndarray", list(x.shape), str(x.dtype), digest]
    if isinstance(x, type):
        return _name(x)
    if depth > 12:
        return repr(x)
    if isinstance(x, tuple | list):
        return [type(x).__name__, [_stable(v, depth + 1) for v in x]]
    if isinstance(x, dict):
        return ["dict", [[_stable(k, depth + 1), _stable(v, depth + 1)] for k, v in x.items()]]
    if isinstance(x, set | frozenset):
        return [type(x).__name__, sorted(json.dumps(_stable(v, depth + 1), default=repr) for v in x)]
    if dataclasses.is_dataclass(x):
        state = {f.name: getattr(x, f.name, None) for f in dataclasses.fields(x)}
    elif hasattr(x, "__dict__") and not callable(x):
        state = dict(vars(x))
    elif getattr(type(x), "__slots__", None):
        state = {k: getattr(x, k, None) for k in type(x).__slots__}
    else:
        return repr(x)
    return [_name(type(x)), _stable(state, depth + 1)]


def _tree(tree: Any) -> Any:
    """``tree`` (a ``PyTreeDef``) described with ``_stable`` node data (``str`` of it shows addresses)."""
    node = tree.node_data()
    if node is None:
        return "*"
    kind, aux = node
    return [_name(kind), _stable(aux), [_tree(c) for c in tree.children()]]


def _leaf(x: Any) -> list[Any]:
    if hasattr(x, "shape") and hasattr(x, "dtype"):
        weak = getattr(x, "weak_type", None)
        if weak is None:
            weak = getattr(getattr(x, "aval", None), "weak_type", False)
        return [list(x.shape), str(x.dtype), bool(weak), _sharding(getattr(x, "sharding", None))]
    return ["static", _name(type(x)), _stable(x)]


def signature(args: Any) -> dict[str, Any]:
    """The abstract signature of ``args``: its tree and each leaf's shape, dtype, weak type, sharding."""
    import jax

    leaves, tree = jax.tree_util.tree_flatten(args)
    return {"tree": _tree(tree), "leaves": [_leaf(x) for x in leaves]}


OUTSIDE_PROGRAMS = (
    "run_name",
    "runs_dir",
    "resume",
    "max_minutes",
    "export_onnx",
    "onnx_path",
    "compile_cache",
    "compile_cache_dir",
    "executable_cache",
    "autotune_seed",
    "eval.initial",
    "distributed.coordinator_address",
)
"""Training-config fields no compiled program reads (where the run is written, when it stops, what is
exported, where caches live, whether XLA's autotune cache is seeded: that changes which implementation
XLA picks for a fusion, never what the program computes; when the step-0 evaluation runs; where the
coordinator listens: the process count and index are in the key's platform part): left out of the
key (a dotted name: a field of a section), so a rerun under another run name or wall-clock budget is
served. Until stop 31 they were in it, and the GPU's warm runs missed (docs/training.md)."""


def program_fields(train: Mapping[str, Any]) -> dict[str, Any]:
    """``train`` (a ``config_to_dict`` record) less ``OUTSIDE_PROGRAMS``.

    The key's part of it, and what ``checkpoint.resume_changes`` compares.
    """
    out = {k: v for k, v in train.items() if k not in OUTSIDE_PROGRAMS}
    for name in OUTSIDE_PROGRAMS:
        section, _, leaf = name.partition(".")
        if leaf and isinstance(out.get(section), Mapping):
            out[section] = {k: v for k, v in out[section].items() if k != leaf}
    return out


def weights_by_name(
    train: Mapping[str, Any], env: Mapping[str, Any] | None
) -> tuple[Mapping[str, Any], Mapping[str, Any] | None]:
    """The key's training and env config parts: the env by its resolved record, reward weights by name only.

    Every program that steps the env takes the weights as an argument (the brax rollout and evaluation,
    ``training.brax.programs``; the rsl-rl steps, ``rsl_rl.programs``), so their values are left out: the env
    record keeps the terms' names, and a run that changes only a weight is served. With an env record the
    training config's ``env_overrides`` go too: the record holds their effect, so two spellings of one
    setting (``sim_dt=0.004``, ``sim_dt=4e-3``) are one key. Without one (a stand-in env) they stay.
    """
    if not isinstance(env, Mapping):
        return train, env
    train = {k: v for k, v in train.items() if k != "env_overrides"}
    reward = env.get("reward")
    scales = reward.get("scales") if isinstance(reward, Mapping) else None
    if isinstance(scales, Mapping):
        env = {**env, "reward": {**reward, "scales": sorted(scales)}}
    return train, env


def run_context(record: Mapping[str, Any], env: Any) -> dict[str, Any]:
    """What a run's programs close over that their code does not say: the key's ``context`` part.

    ``record``: the run's record (``run_dir.open_run``): its ``train`` config less ``OUTSIDE_PROGRAMS`` and
    its ``env`` config, both with the reward weights by name only (``weights_by_name``); ``env``: the env
    trained on: its class, and its source file's hash (``source_hash``; None for ``bar_policy``'s own, which
    the package hash covers).
    """
    cls = type(env)
    env_source = source_hash(env)
    train = program_fields(record["train"])
    train, env_record = weights_by_name(train, record["env"])
    return {
        "train": train,
        "env": env_record or repr(getattr(env, "config", None)),
        "env_class": f"{cls.__module__}.{cls.__qualname__}",
        "env_source": env_source,
    }
