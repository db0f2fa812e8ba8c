"""A task stays in its folder: outside ``bar_policy/tasks/<task>/`` only the registration list imports it.

Read from the AST (imports inside functions and under ``TYPE_CHECKING`` count). The only other importers
allowed are the old-path re-exports that ``docs/tasks.md`` ("Old paths") lists for reach and track, each a
module whose whole body re-exports one task module. The piano, written after the seam, has none: removing
its folder and its line in ``TASK_PACKAGES`` leaves the rest of the package whole (docs/tasks.md, "The
piano's footprint").
"""

from __future__ import annotations

import ast
from pathlib import Path

import bar_policy
from bar_policy.tasks.registry import TASK_PACKAGES

ROOT = Path(bar_policy.__file__).parent
REGISTRY = "tasks/registry.py"
OLD_PATHS = {  # docs/tasks.md, "Old paths": module -> the task it re-exports
    "deploy/commands.py": "reach",
    "deploy/command_transition.py": "reach",
    "deploy/sim2sim.py": "reach",
    "deploy/tasks/reach.py": "reach",
    "deploy/tasks/track.py": "track",
    "deploy/tasks/track_eval.py": "track",
    "deploy/tasks/track_reference.py": "track",
}


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
        allowed = {REGISTRY} | {m for m, t in OLD_PATHS.items() if t == task}
        stray = {m: sorted(n) for m, n in _importers(task).items() if m not in allowed}
        assert not stray, f"{task} is imported from outside its folder: {stray}"


def test_the_registration_list_is_the_piano_s_only_importer() -> None:
    """The registry names each task as a string (``importlib``): no module outside the folder imports it."""
    assert _importers("piano") == {}
    assert "bar_policy.tasks.piano" in TASK_PACKAGES


def test_old_paths_only_re_export() -> None:
    """Each old path is a re-export of its task's module: every statement an import or ``__all__``."""
    for rel, task in OLD_PATHS.items():
        tree = ast.parse((ROOT / rel).read_text(encoding="utf-8"))
        body = [n for n in tree.body if not (isinstance(n, ast.Expr) and isinstance(n.value, ast.Constant))]
        assert body, rel
        for node in body:
            assert isinstance(node, (ast.Import, ast.ImportFrom)), f"{rel}: {ast.dump(node)[:80]}"
            mod = node.module if isinstance(node, ast.ImportFrom) else node.names[0].name
            assert mod and mod.startswith(f"bar_policy.tasks.{task}"), (rel, mod)
