"""The launch manifest: the executables the last run of a launch key used, for the next one to prefetch.

``<cache dir>/executables/launch-<launch key>.json`` holds ``{"programs": {name: key, ...}, "libraries":
..., "platform": ...}``: the executable-cache key (``ExecutableCache.key``) of each program of the run, in
the order the run keyed them (the order the next run needs them), and the library versions and platform that
went into those keys. ``ExecutableCache.key`` records each program here (``LaunchManifest.record``);
``executable_prefetch.Prefetch`` reads it (``read_manifest``) before the next run's env is built. Apart from
both so that neither module imports the other.
"""

from __future__ import annotations

import contextlib
import json
import re
import threading
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from bar_policy._files import write_atomic

__all__ = ["LaunchManifest", "manifest_path", "read_manifest"]

_KEY = re.compile(r"[0-9a-f]{64}")
"""An executable-cache key (SHA-256, hex); a manifest's other strings never become file names."""


def manifest_path(directory: Path, launch_key: str) -> Path:
    """``<directory>/launch-<launch_key>.json`` (``directory``: the executable cache's)."""
    return Path(directory) / f"launch-{launch_key}.json"


class LaunchManifest:
    """The writer: one per executable cache of a run with a launch key.

    Args:
        directory: the executable cache's directory.
        launch_key: ``executable_prefetch.launch_key`` of the run.
    """

    def __init__(self, directory: Path, launch_key: str) -> None:
        self.path = manifest_path(directory, launch_key)
        self.programs: dict[str, str] = {}
        self._lock = threading.Lock()

    def record(self, name: str, key: str, inputs: Mapping[str, Any]) -> None:
        """Program ``name`` has ``key`` (``inputs``: what was hashed): rewrite the file when that is new.

        A few small atomic writes per run (one per program); a reader sees the old file or the new one. A
        file that cannot be written is left as it is: a manifest only saves the next run time.
        """
        with self._lock:  # programs are keyed on more than one thread
            if self.programs.get(name) == key:
                return
            self.programs[name] = key
            doc = {
                "programs": self.programs,
                "libraries": inputs["libraries"],
                "platform": inputs["platform"],
            }
            with contextlib.suppress(OSError):
                write_atomic(self.path, json.dumps(doc, indent=1, default=repr).encode())


def read_manifest(directory: Path, launch_key: str) -> dict[str, Any] | None:
    """The manifest of ``launch_key``: its programs (keys checked to be keys), libraries and platform.

    None when there is none, or it cannot be read or parsed, or lists no program: nothing to prefetch.
    """
    try:
        doc = json.loads(manifest_path(directory, launch_key).read_text())
    except (OSError, ValueError):
        return None
    programs = doc.get("programs") if isinstance(doc, dict) else None
    if not isinstance(programs, dict):
        return None
    programs = {n: k for n, k in programs.items() if isinstance(k, str) and _KEY.fullmatch(k)}
    if not programs:
        return None
    return {"programs": programs, "libraries": doc.get("libraries"), "platform": doc.get("platform")}
