"""The driver package's imports point one way and never into bar_policy.deploy.

Read from the AST, so imports inside functions and under ``TYPE_CHECKING`` count, and so does the package's
``__init__`` importing its own modules.
"""

from __future__ import annotations

import ast
from pathlib import Path

import bar_policy.robstride

PKG = "bar_policy.robstride"
ROOT = Path(bar_policy.robstride.__file__).parent
MODULES = {p.stem: p for p in ROOT.glob("*.py")}


def _imported(path: Path) -> set[str]:
    out: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            out.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            assert node.level == 0, f"{path.name}: relative import"
            out.add(node.module or "")
            out.update(f"{node.module}.{a.name}" for a in node.names)
    return out


def _graph() -> dict[str, set[str]]:
    """Module -> the package's modules it imports (``__init__`` for names the package itself defines)."""
    graph: dict[str, set[str]] = {}
    for stem, path in MODULES.items():
        deps = set()
        for name in _imported(path):
            if not name.startswith(PKG + "."):
                continue
            part = name[len(PKG) + 1 :].split(".")
            deps.add(part[0] if part[0] in MODULES else "__init__")
        graph[stem] = deps - {stem}
    return graph


def test_no_import_of_deploy() -> None:
    bad = {
        stem: sorted(n for n in _imported(p) if n.split(".")[:2] == ["bar_policy", "deploy"])
        for stem, p in MODULES.items()
    }
    assert not any(bad.values()), bad


def test_imports_point_one_way() -> None:
    graph = _graph()
    done: set[str] = set()

    def visit(stem: str, path: tuple[str, ...]) -> None:
        if stem in path:
            raise AssertionError(f"import cycle: {' -> '.join((*path[path.index(stem) :], stem))}")
        if stem in done:
            return
        for dep in sorted(graph[stem]):
            visit(dep, (*path, stem))
        done.add(stem)

    for stem in sorted(graph):
        visit(stem, ())
