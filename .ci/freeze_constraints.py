"""Write ``constraints.txt``: the exact installed versions of the project's whole dependency tree.

    python .ci/freeze_constraints.py            # rewrite constraints.txt from this environment
    python .ci/freeze_constraints.py --check    # exit 1 when constraints.txt differs from it

The tree is walked from ``pyproject.toml``'s dependencies and its ``all`` extra (deploy, train, dev, video)
through each installed distribution's own requirements (markers evaluated for this interpreter), so it is
``pip freeze`` filtered to what the project pulls in, nothing else of the environment. A local version label
(``torch 2.13.0+cpu``) is written without it, with the label in a comment: ``torch==2.13.0`` matches the
CPU build here and the PyPI build elsewhere. ``.ci/run`` installs with ``pip install -c constraints.txt``.
"""

from __future__ import annotations

import argparse
import importlib.metadata as md
import platform
import sys
import tomllib
from pathlib import Path

from packaging.requirements import Requirement
from packaging.utils import canonicalize_name

ROOT = Path(__file__).resolve().parents[1]


def _root_requirements() -> list[Requirement]:
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    extras = project["optional-dependencies"]
    reqs, todo, seen = [Requirement(r) for r in project["dependencies"]], ["all"], set()
    while todo:
        extra = todo.pop()
        if extra in seen:
            continue
        seen.add(extra)
        for text in extras[extra]:
            r = Requirement(text)
            if canonicalize_name(r.name) == canonicalize_name(project["name"]):
                todo += sorted(r.extras)
            else:
                reqs.append(r)
    return reqs


def _applies(req: Requirement, extras: set[str]) -> bool:
    if req.marker is None:
        return True
    return any(req.marker.evaluate({"extra": e}) for e in (extras or {""}))


def dependency_tree() -> dict[str, str]:
    """Canonical name -> installed version of every distribution the project needs, transitively."""
    versions: dict[str, str] = {}
    queue = [(r, set(r.extras)) for r in _root_requirements()]
    done: set[tuple[str, frozenset[str]]] = set()
    while queue:
        req, extras = queue.pop()
        name = canonicalize_name(req.name)
        if (name, frozenset(extras)) in done:
            continue
        done.add((name, frozenset(extras)))
        try:
            dist = md.distribution(req.name)
        except md.PackageNotFoundError:
            continue  # an optional requirement that is not installed here
        versions[name] = dist.version
        for text in dist.requires or []:
            sub = Requirement(text)
            if _applies(sub, extras):
                queue.append((sub, set(sub.extras)))
    return versions


def render(versions: dict[str, str]) -> str:
    """The constraints file's text (sorted, one ``name==version`` a line)."""
    lines = [
        "# The exact set the project was tested with (pip constraints), by .ci/freeze_constraints.py",
        f"# from the installed dependency tree of bar-policy[all] on Python {platform.python_version()}, "
        f"{platform.machine()}.",
        '# .ci/run and the README\'s test command install with: pip install -c constraints.txt -e ".[all]"',
    ]
    for name in sorted(versions):
        version = versions[name]
        public, plus, _ = version.partition("+")
        lines.append(f"{name}=={public}" + (f"  # installed here as {version}" if plus else ""))
    return "\n".join(lines) + "\n"


def main() -> int:
    """Write (or ``--check``) ``constraints.txt`` at the project root."""
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--check", action="store_true", help="compare instead of writing; exit 1 on a difference")
    args = p.parse_args()
    text = render(dependency_tree())
    path = ROOT / "constraints.txt"
    if args.check:
        same = path.exists() and path.read_text().splitlines()[3:] == text.splitlines()[3:]
        print("constraints.txt matches this environment" if same else "constraints.txt differs")
        return 0 if same else 1
    path.write_text(text)
    print(f"wrote {path} ({len(text.splitlines()) - 3} packages)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
