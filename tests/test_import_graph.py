"""No import cycles anywhere in bar_policy.

Read from the AST, so imports inside functions and under ``TYPE_CHECKING`` count, and so does a package's
``__init__`` importing its own modules. ``from bar_policy.x.y import z`` is an edge to ``bar_policy.x.y``
(or to ``bar_policy.x.y.z`` where z is a submodule) and to nothing above it.
"""

from __future__ import annotations

import ast
from pathlib import Path

import bar_policy

PKG = "bar_policy"
ROOT = Path(bar_policy.__file__).parent


def _modules() -> dict[str, Path]:
    out: dict[str, Path] = {}
    for path in ROOT.rglob("*.py"):
        parts = list(path.relative_to(ROOT.parent).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts.pop()
        out[".".join(parts)] = path
    return out


MODULES = _modules()


def _target(name: str) -> str | None:
    """The longest module of the package that ``name`` names, or None outside the package."""
    parts = name.split(".")
    while parts:
        mod = ".".join(parts)
        if mod in MODULES:
            return mod
        parts.pop()
    return None


def _deps(mod: str, path: Path) -> set[str]:
    is_pkg = path.name == "__init__.py"
    out: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = mod.split(".")
                if not is_pkg:
                    anchor = anchor[:-1]
                anchor = anchor[: len(anchor) - (node.level - 1)]
                base = ".".join([*anchor, *([base] if base else [])])
            names = [f"{base}.{a.name}" if f"{base}.{a.name}" in MODULES else base for a in node.names]
        else:
            continue
        out.update(t for t in map(_target, names) if t is not None)
    return out - {mod}


def graph() -> dict[str, set[str]]:
    """Module -> the package's modules it imports."""
    return {mod: _deps(mod, path) for mod, path in MODULES.items()}


def cycles(g: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components of more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    out: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in sorted(g[v]):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in sorted(g):
        if v not in index:
            visit(v)
    return out


def test_graph_sees_package() -> None:
    """The graph holds the edges the rules name: a package's own modules, lazy and relative-free imports."""
    g = graph()
    assert "bar_policy.envs.base" in g["bar_policy.envs"]  # a package's own module
    assert "bar_policy.envs.wrappers" in g["bar_policy.envs"]  # imported inside a function
    assert "bar_policy.tasks.interfaces" in g["bar_policy.deploy.tasks"]  # under TYPE_CHECKING
    assert "bar_policy.envs" not in g["bar_policy.tasks.reach.env"]  # from bar_policy.envs import rewards


def test_cycles_are_found() -> None:
    assert cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]


def test_no_import_cycles() -> None:
    g = graph()
    found = cycles(g)
    for comp in found:
        print("import cycle:", ", ".join(comp))
        for m in comp:
            print(f"  {m} -> {sorted(d for d in g[m] if d in comp)}")
    assert not found, found


LAYERS: tuple[tuple[str, ...], ...] = (
    (
        "bar_policy.robot",
        "bar_policy.task_records",
        "bar_policy._",
        "bar_policy.overrides",
        "bar_policy.provenance",
        "bar_policy.signals",
        "bar_policy.quality",
    ),
    ("bar_policy.obs", "bar_policy.envs", "bar_policy.robstride", "bar_policy.motion"),
    ("bar_policy.tasks",),
    ("bar_policy.training", "bar_policy.deploy", "bar_policy.export", "bar_policy.entry"),
)
"""From the ground up: the robot (and the task records, the helpers, the quality metrics); the observation
contract, the robot env, the driver and the motions; the tasks; training, the deploy runtime, the export and
the ``bar-deploy`` console entry point.
The package's ``__init__`` sits above them all (it installs the task records' loader)."""


def _layer(mod: str) -> int | None:
    for i, prefixes in enumerate(LAYERS):
        if any(mod == p or mod.startswith(p if p.endswith("_") else p + ".") for p in prefixes):
            return i
    return None


def test_layers_cover_the_package() -> None:
    assert [m for m in MODULES if m != PKG and _layer(m) is None] == []


def test_no_import_points_up() -> None:
    """No module imports a module of a higher layer (``LAYERS``), counting lazy and TYPE_CHECKING imports."""
    up = sorted(
        f"{m} -> {d}"
        for m, deps in graph().items()
        if m != PKG
        for d in deps
        if d != PKG and _layer(d) > _layer(m)  # type: ignore[operator]
    )
    assert not up, up
