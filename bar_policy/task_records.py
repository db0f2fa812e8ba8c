"""What a task registers, and the registered tasks: the records every layer reads.

A task's record (``TaskRecord``) says, as data, what the rest of the package needs to know about it: its
MJX envs, its observation terms and layout, its training presets, its ship gate and its deploy part. Every
code reference is a ``"module:attr"`` string, imported only when used (``resolve``), so reading the records
imports no jax, no torch and no deploy runtime. A task declares its record as ``RECORD`` in its package's
``__init__.py`` (``bar_policy/tasks/reach/__init__.py`` is the example) and is listed once in
``bar_policy.tasks.registry``, which publishes the records here (``publish``) when it is imported.

This module sits at the ground, below everything that reads the records: the observation contract
(``obs``: a task's terms and layouts), the env registry (``envs``), training and ``bar-deploy``. It names no
task and imports nothing of the package. The first read (``records``, ``get_record``) before the registry
was imported calls the loader that the package's ``__init__`` installs (``install_loader``: it imports
the registry), so ``from bar_policy.obs import ObservationManager`` alone knows the shipped layouts.
"""

from __future__ import annotations

import importlib
import re
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

__all__ = [
    "EnvEntry",
    "TaskRecord",
    "default_env",
    "get_record",
    "install_loader",
    "publish",
    "records",
    "resolve",
]

_REF = re.compile(r"^[A-Za-z_][\w.]*:[A-Za-z_]\w*$")
"""``package.module:attribute``."""


def _check_ref(label: str, ref: str) -> None:
    if not _REF.match(ref):
        raise ValueError(f"{label} must be a 'package.module:attribute' string, got {ref!r}")


def resolve(ref: str) -> Any:
    """The object a ``"module:attr"`` string names (imports the module)."""
    module, _, attr = ref.partition(":")
    return getattr(importlib.import_module(module), attr)


@dataclass(frozen=True, kw_only=True)
class EnvEntry:
    """One MJX training env of a task (an entry of ``bar_policy.envs.ALL_ENVS``)."""

    name: str
    """Registered env name, e.g. ``LiteReach`` (``bar_policy.envs.load(name)``, ``bar-train --env``)."""
    env: str
    """The env class, ``"module:attr"``; called as ``cls(config)``."""
    config: str
    """Zero-argument factory of the env's default (training) config, ``"module:attr"``."""
    action_prior: str = ""
    """The ``network.action_prior`` value this env serves besides ``none`` (its ``action_prior(lead_steps)``
    builds it), ``""`` for none. ``bar-train`` reads its valid values here without importing the env."""

    def __post_init__(self) -> None:
        _check_ref(f"env {self.name!r}: env", self.env)
        _check_ref(f"env {self.name!r}: config", self.config)
        if self.action_prior and (not self.action_prior.isidentifier() or self.action_prior == "none"):
            raise ValueError(
                f"env {self.name!r}: action_prior must be an identifier other than 'none' (or '' for no "
                f"prior), got {self.action_prior!r}"
            )


@dataclass(frozen=True, kw_only=True)
class TaskRecord:
    """Everything outside a task's folder needs to know about the task."""

    name: str
    """Task name: the layout's task (``ObservationManager.for_task``), the env's ``task_name``, the ONNX
    file's ``bar.task`` and the ``bar-deploy`` task."""
    summary: str
    """One line for listings."""
    envs: tuple[EnvEntry, ...]
    """Its MJX training envs, in registry order."""
    layout: str
    """``"module:attr"`` of ``(mode) -> ObservationSchema``: the task's current observation layout."""
    terms: str = ""
    """``"module:attr"`` of the observation terms the task adds (``{name: obs.terms.TermKind}``, read into
    ``obs.terms.TERM_CATALOG``); empty: none."""
    shipped_layouts: tuple[tuple[str, str], ...] = ()
    """Golden layouts committed under ``bar_policy/obs/schemas/``: (layout name, mode)."""
    command_terms: tuple[str, ...] = ()
    """Observation terms its deploy command source feeds (category ``command`` in ``obs.terms``)."""
    implied_by: tuple[str, ...] = ()
    """Observation terms that make an HC-only file this task's (``deploy.task_registry.implied_task``)."""
    hc_only: bool = False
    """Whether an HC-only file (no ``bar.*`` keys) may run as this task."""
    metadata_keys: tuple[str, ...] = ()
    """Keys of the env's ``task_metadata()`` (written into the ONNX file by the export)."""
    metric: str = ""
    """What ``bar-deploy eval`` reports for it (one line)."""
    presets: tuple[tuple[str, str], ...] = ()
    """Training presets: (name, ``"module:attr"`` of a ``{dotted.path: value}`` mapping applied to
    ``TrainConfig()``, see ``training.config.preset``)."""
    gate: str = ""
    """``"module:attr"`` of its ship gate (a ``quality.gate.GateThresholds``: what a file must reach on
    held-out data to ship); empty: no gate, so no file of the task ships."""
    deploy: str = ""
    """Module of its deploy task (a ``TASK`` attribute, a ``DeployTask``); imports neither jax nor torch."""

    def __post_init__(self) -> None:
        if not re.match(r"^[a-z][a-z0-9_]*$", self.name):
            raise ValueError(f"task name must be lower_snake_case, got {self.name!r}")
        if not self.envs:
            raise ValueError(f"task {self.name!r} registers no env")
        _check_ref(f"task {self.name!r}: layout", self.layout)
        if self.terms:
            _check_ref(f"task {self.name!r}: terms", self.terms)
        for preset_name, ref in self.presets:
            _check_ref(f"task {self.name!r}: preset {preset_name!r}", ref)
        if self.gate:
            _check_ref(f"task {self.name!r}: gate", self.gate)
        if self.deploy and not re.match(r"^[A-Za-z_][\w.]*$", self.deploy):
            raise ValueError(f"task {self.name!r}: deploy must be a module path, got {self.deploy!r}")


_RECORDS: tuple[TaskRecord, ...] | None = None
"""The published records, in registry order (None until ``publish``)."""
_LOADER: Callable[[], None] | None = None
"""Imports the task registry, which publishes (``install_loader``)."""


def install_loader(loader: Callable[[], None]) -> None:
    """Make ``loader`` what the first read calls when nothing is published yet (``bar_policy/__init__``)."""
    global _LOADER
    _LOADER = loader


def publish(tasks: tuple[TaskRecord, ...]) -> None:
    """Make ``tasks`` the registered records (``bar_policy.tasks.registry`` calls it once).

    Raises ``ValueError`` when two records share a task name or an env name.
    """
    global _RECORDS
    names = [r.name for r in tasks]
    if len(set(names)) != len(names):
        raise ValueError(f"two task packages register the same name: {names}")
    env_names = [e.name for r in tasks for e in r.envs]
    if len(set(env_names)) != len(env_names):
        raise ValueError(f"two tasks register the same env name: {env_names}")
    _RECORDS = tuple(tasks)


def records() -> tuple[TaskRecord, ...]:
    """Every registered task's record, in registry order (loads the registry on the first read)."""
    if _RECORDS is None and _LOADER is not None:
        _LOADER()
    if _RECORDS is None:
        raise RuntimeError("no task records are published: import bar_policy.tasks.registry")
    return _RECORDS


def default_env() -> str:
    """The env a caller gets when it names none: the first registered task's first env (``LiteReach``)."""
    return records()[0].envs[0].name


def get_record(name: str) -> TaskRecord:
    """The record of task ``name``; raises ``ValueError`` listing the tasks."""
    by_name = {r.name: r for r in records()}
    if name not in by_name:
        raise ValueError(f"unknown task {name!r}; valid tasks: {sorted(by_name)}")
    return by_name[name]
