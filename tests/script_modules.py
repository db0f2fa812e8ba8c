"""Load a script of the repository (``bench/``, ``train/``, ``tests/data/``) as a module, for its tests.

The scripts are not in a package; each is loaded from its path once, under the given name in
``sys.modules`` (a dataclass defined in it looks its module up there).
"""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path
from types import ModuleType

REPO = Path(__file__).resolve().parents[1]
BENCH = REPO / "bench"


def load_script(path: Path, name: str) -> ModuleType:
    """The script at ``path`` executed as module ``name`` (registered in ``sys.modules``)."""
    spec = importlib.util.spec_from_file_location(name, path)
    assert spec is not None and spec.loader is not None, path
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    spec.loader.exec_module(module)
    return module


def load_bench(name: str) -> ModuleType:
    """``bench/<name>.py`` as module ``name``."""
    return load_script(BENCH / f"{name}.py", name)
