"""Where a policy or a run came from: git commit and dirty flag, library versions, the exact command.

``collect()`` returns a plain-JSON record, written into every training run record (``config.json``, a
``provenance`` line of ``metrics.jsonl``, ``final_eval.json``, checkpoint sidecars, and the
``checkpoints/*.json`` that ``train/ship.py`` publishes) and into every exported ONNX file
(``bar.provenance``)::

    {"git_commit": "5a90292...", "git_dirty": false, "git_source": "git",
     "versions": {"jax": "0.10.2", ..., "torch": "absent"}, "argv": ["train/ppo.py", "--preset", "tiny"],
     "cwd": "/work/main", "python": "3.11.7", "created_utc": "2026-01-01T12:00:00Z"}

Nothing here fails: without git, outside a git checkout, or when git times out, the commit and the dirty
flag read ``"unknown"``, unless ``BAR_POLICY_GIT_COMMIT`` (and ``BAR_POLICY_GIT_DIRTY``) state them for a
copied work tree (the lent GPU machines get no ``.git``), recorded as ``git_source: "environment"``. Where
git answers, it wins; a ``BAR_POLICY_GIT_COMMIT`` it contradicts is kept as ``stated_commit`` and shown (a
copied tree can carry a stale ``.git``: a file trained so once recorded an older commit). A library that is
not installed reads ``"absent"``. ``describe(record)`` gives the one or two lines
``bar-deploy`` prints at start; it informs and never refuses. numpy-free and jax-free (the
deploy runtime imports it).
"""

from __future__ import annotations

import importlib.metadata
import importlib.util
import json
import os
import platform
import subprocess
import sys
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

__all__ = [
    "ABSENT",
    "COMMIT_ENV",
    "DIRTY_ENV",
    "LIBRARIES",
    "UNKNOWN",
    "collect",
    "commit_text",
    "describe",
    "git_state",
    "library_versions",
    "read_record",
]

UNKNOWN = "unknown"
"""The commit / dirty flag when git cannot tell (no git, not a checkout, timeout)."""
ABSENT = "absent"
"""The version of a library that is not installed."""

LIBRARIES: tuple[tuple[str, str], ...] = (
    ("jax", "jax"),
    ("jaxlib", "jaxlib"),
    ("mujoco", "mujoco"),
    ("mujoco-mjx", "mujoco"),
    ("brax", "brax"),
    ("rsl-rl-lib", "rsl_rl"),
    ("torch", "torch"),
    ("onnxruntime", "onnxruntime"),
    ("onnx", "onnx"),
    ("numpy", "numpy"),
)
"""(distribution, top-level module) pairs whose versions a record carries."""

COMMIT_ENV = "BAR_POLICY_GIT_COMMIT"
"""Environment variable giving the commit when git cannot (a copied work tree without ``.git``)."""
DIRTY_ENV = "BAR_POLICY_GIT_DIRTY"
"""Environment variable giving the dirty flag with ``COMMIT_ENV``: ``1``/``true`` or ``0``/``false``."""

_GIT_TIMEOUT_S = 5.0
"""Longest wait for one git command, s (a network file system can stall)."""
_PACKAGE_ROOT = Path(__file__).resolve().parent.parent
"""The directory holding the ``bar_policy`` package (a checkout's root when installed editable)."""


def _git(args: Sequence[str], cwd: Path) -> str | None:
    """The stdout of ``git <args>`` in ``cwd``; None when git is missing, fails or times out."""
    try:
        r = subprocess.run(
            ["git", *args], cwd=cwd, capture_output=True, text=True, timeout=_GIT_TIMEOUT_S, check=False
        )
    except (OSError, subprocess.SubprocessError):
        return None
    return r.stdout.strip() if r.returncode == 0 else None


def git_state(root: str | os.PathLike[str] | None = None) -> tuple[str, bool | str]:
    """``(commit, dirty)`` of the checkout at ``root`` (default: the one holding this package).

    ``commit`` is the full hash of HEAD and ``dirty`` whether the work tree differs from it: a tracked file
    changed (staged or not) or an untracked file that git does not ignore (a new module that the run
    imported is not in the commit either). Both are ``"unknown"`` when git is absent, ``root`` is not the
    top of a git work tree (an installed copy inside someone else's repository does not count), or git
    fails.
    """
    root = Path(root) if root is not None else _PACKAGE_ROOT
    top = _git(["rev-parse", "--show-toplevel"], root)
    if top is None or Path(top).resolve() != root.resolve():
        return UNKNOWN, UNKNOWN
    commit = _git(["rev-parse", "HEAD"], root)
    status = _git(["status", "--porcelain"], root)
    if commit is None or status is None:
        return UNKNOWN, UNKNOWN
    return commit, bool(status)


def library_versions(libraries: Sequence[tuple[str, str]] = LIBRARIES) -> dict[str, str]:
    """Distribution -> installed version, ``"absent"`` when it is not installed or not importable.

    A module already imported reports its own ``__version__`` (the code that actually ran, even when
    ``PYTHONPATH`` shadows the installed copy); otherwise the installed distribution's metadata is read,
    without importing anything.
    """
    out = {}
    for dist, module in libraries:
        mod = sys.modules.get(module) if dist == module.replace("_", "-") else None
        version = getattr(mod, "__version__", None) if mod is not None else None
        if version is None:
            try:
                found = importlib.util.find_spec(module) is not None
            except (ImportError, ValueError):
                found = False
            try:
                version = importlib.metadata.version(dist) if found else None
            except importlib.metadata.PackageNotFoundError:
                version = None
        out[dist] = str(version) if version else ABSENT
    return out


def collect(argv: Sequence[str] | None = None, root: str | os.PathLike[str] | None = None) -> dict[str, Any]:
    """The provenance record of this process (see the module docstring for its keys).

    Args:
        argv: the command (default ``sys.argv``: the process's own command line, whatever the caller
            parsed).
        root: the checkout to read git from (default: the one holding this package).
    """
    commit, dirty = git_state(root)
    source = "git" if commit != UNKNOWN else "none"
    stated = os.environ.get(COMMIT_ENV, "").strip()
    if commit == UNKNOWN and stated:
        # A copy of a checkout without .git (the lent GPU machines get the work tree only): the commit as
        # the person who copied it states it, recorded as such.
        commit, source = stated, "environment"
        dirty = {"1": True, "true": True, "0": False, "false": False}.get(
            os.environ.get(DIRTY_ENV, "").strip().lower(), UNKNOWN
        )
    # git wins, but a stated commit it contradicts is kept beside it: a copied tree can carry a stale .git.
    disagrees = source == "git" and stated and not commit.startswith(stated.lower())
    return {
        "git_commit": commit,
        "git_dirty": dirty,
        "git_source": source,
        **({"stated_commit": stated} if disagrees else {}),
        "versions": library_versions(),
        "argv": list(sys.argv if argv is None else argv),
        "cwd": os.getcwd(),
        "python": platform.python_version(),
        "created_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
    }


def read_record(text: str | None) -> dict[str, Any]:
    """A stored record (``bar.provenance``) as a dict: ``{}`` when absent, ``{"error": ...}`` when malformed.

    Never raises: provenance informs and refuses nothing.
    """
    if text is None:
        return {}
    try:
        value = json.loads(text)
    except json.JSONDecodeError as e:
        return {"error": f"not valid JSON: {e}"}
    if not isinstance(value, dict):
        return {"error": f"a JSON {type(value).__name__}, not an object"}
    return value


def commit_text(record: Mapping[str, Any]) -> str:
    """``5a90292abc12 (clean tree)``, ``unknown (tree state unknown)``, or ``not recorded`` (no record)."""
    if not record:
        return "not recorded"
    commit = str(record.get("git_commit", UNKNOWN))
    tree = {True: "dirty tree", False: "clean tree"}.get(record.get("git_dirty"), "tree state unknown")
    given = f", as given by {COMMIT_ENV}" if record.get("git_source") == "environment" else ""
    stated = record.get("stated_commit")
    against = f"; {COMMIT_ENV} said {str(stated)[:12]}: a stale .git?" if stated else ""
    return f"{commit[:12]} ({tree}{given}{against})"


def describe(record: Mapping[str, Any] | None, code_version: str = "") -> list[str]:
    """One or two lines for a terminal: commit, dirty flag and versions; then the training command.

    Never raises: a missing record says so (with ``code_version``, the short form older files carry),
    and fields of the wrong type are shown as found.
    """
    if not record:
        known = f"; its code version: {code_version}" if code_version else ""
        return [f"provenance: not recorded (a file exported before provenance, or not by bar_policy{known})"]
    if "error" in record:
        return [f"provenance: unreadable ({record['error']})"]
    versions = record.get("versions", {})
    if isinstance(versions, Mapping):  # in LIBRARIES' order (a stored record's keys come back sorted)
        order = [d for d, _ in LIBRARIES]
        names = sorted(versions, key=lambda k: (order.index(k) if k in order else len(order), k))
        libs = ", ".join(f"{k} {versions[k]}" for k in names)
    else:
        libs = str(versions)
    head = f"provenance: commit {commit_text(record)}; {libs}"
    lines = [head]
    argv = record.get("argv")
    if argv:
        command = " ".join(str(a) for a in argv) if isinstance(argv, list | tuple) else str(argv)
        lines.append(f"  command: {command}" + (f"  (in {record['cwd']})" if record.get("cwd") else ""))
    return lines
