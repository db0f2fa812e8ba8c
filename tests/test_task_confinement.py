"""A task stays in its folder: outside ``bar_policy/tasks/<task>/`` only the registration list imports it.

Read from the AST (imports inside functions and under ``TYPE_CHECKING`` count); no other importer is
allowed. Removing a task's folder and its line in ``TASK_PACKAGES`` leaves the rest of the package whole
(docs/tasks.md, "The piano's footprint").
"""

from __future__ import annotations

import ast
from pathlib import Path

import bar_policy
from bar_policy.tasks.registry import TASK_PACKAGES

ROOT = Path(bar_policy.__file__).parent
REGISTRY = "tasks/registry.py"


def _imported(tree: ast.AST) -> set[str]:
    names: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names.add(node.module)
            names.update(f"{node.module}.{a.name}" for a in node.names)
    return names


def _importers(task: str) -> dict[str, set[str]]:
    """Modules outside ``tasks/<task>/`` importing ``bar_policy.tasks.<task>``, with what they name."""
    pkg = f"bar_policy.tasks.{task}"
    out: dict[str, set[str]] = {}
    for path in ROOT.rglob("*.py"):
        rel = path.relative_to(ROOT).as_posix()
        if rel.startswith(f"tasks/{task}/"):
            continue
        hits = {
            n
            for n in _imported(ast.parse(path.read_text(encoding="utf-8")))
            if n == pkg or n.startswith(pkg + ".")
        }
        if hits:
            out[rel] = hits
    return out


def test_every_task_is_confined_to_its_folder() -> None:
    tasks = [p.rsplit(".", 1)[1] for p in TASK_PACKAGES]
    assert tasks[:3] == ["reach", "track", "piano"], tasks
    for task in tasks:
        stray = {m: sorted(n) for m, n in _importers(task).items() if m != REGISTRY}
        assert not stray, f"{task} is imported from outside its folder: {stray}"


def test_the_registration_list_is_the_piano_s_only_importer() -> None:
    """The registry names each task as a string (``importlib``): no module outside the folder imports it."""
    assert _importers("piano") == {}
    assert "bar_policy.tasks.piano" in TASK_PACKAGES
