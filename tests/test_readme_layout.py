"""The README's layout block lists every folder of the package and each folder's files, as ``ls`` shows them.

The block is the fenced code block after the README's ``## Layout`` heading. Each entry starts at the left
margin with a folder path (``bar_policy/deploy/``) followed by that folder's file names; an indented line
continues the entry above. A folder without Python modules (data: ``bar_policy/data/autotune/``,
``bar_policy/obs/schemas/``) gives a description in parentheses instead of its file names. On a mismatch
the test prints the block as the tree stands (``expected_block``), to paste in.
"""

from __future__ import annotations

import re
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
PACKAGE = REPO / "bar_policy"
WIDTH = 110
"""Line length of the block (the project's)."""
SKIPPED = {"__pycache__"}


def _folders() -> list[Path]:
    """Every folder of the package (itself included), sorted, without caches."""
    found = [PACKAGE, *(p for p in PACKAGE.rglob("*") if p.is_dir())]
    return sorted(p for p in found if not SKIPPED & set(p.relative_to(REPO).parts))


def _files(folder: Path) -> list[str]:
    """The files directly in ``folder`` (no compiled bytecode), sorted as ``ls`` sorts them (C locale)."""
    return sorted(f.name for f in folder.iterdir() if f.is_file() and not f.name.endswith(".pyc"))


def _is_data(folder: Path) -> bool:
    return not any(name.endswith(".py") for name in _files(folder))


def readme_entries(text: str) -> dict[str, list[str]]:
    """``{folder path: the words after it}`` from the fenced block under ``## Layout``."""
    section = text.split("\n## Layout", 1)[1].split("\n## ", 1)[0]
    block = re.search(r"```[a-z]*\n(.*?)```", section, re.S)
    assert block, "README's Layout section has no fenced block"
    entries: dict[str, list[str]] = {}
    current = None
    for line in block.group(1).splitlines():
        if not line.strip():
            continue
        words = line.split()
        if not line[0].isspace():
            current = words[0]
            assert current not in entries, f"{current} listed twice"
            entries[current] = words[1:]
        else:
            assert current is not None, f"continuation line before any folder: {line!r}"
            entries[current].extend(words)
    return entries


def expected_block() -> str:
    """The block as the tree stands (data folders with a placeholder description to edit)."""
    rel = [f"{p.relative_to(REPO).as_posix()}/" for p in _folders()]
    col = max(len(r) for r in rel) + 2
    lines = []
    for folder, name in zip(_folders(), rel, strict=True):
        words = ["(data files: describe them)"] if _is_data(folder) else _files(folder)
        line = name.ljust(col)
        for w in words:
            if len(line) + len(w) + 1 > WIDTH and line.strip() != name.strip():
                lines.append(line.rstrip())
                line = " " * col
            line += w + " "
        lines.append(line.rstrip())
    return "\n".join(lines)


def test_readme_layout_matches_the_tree() -> None:
    entries = readme_entries((REPO / "README.md").read_text(encoding="utf-8"))
    folders = {f"{p.relative_to(REPO).as_posix()}/": p for p in _folders()}
    problems = []
    if set(entries) != set(folders):
        problems.append(
            f"folders missing from the README: {sorted(set(folders) - set(entries))}; "
            f"listed but absent: {sorted(set(entries) - set(folders))}"
        )
    for name, folder in folders.items():
        if name not in entries:
            continue
        words = entries[name]
        if _is_data(folder):
            if not (words and words[0].startswith("(") and words[-1].endswith(")")):
                problems.append(f"{name}: a data folder takes a description in parentheses, got {words}")
        elif words != _files(folder):
            problems.append(f"{name}: README lists {words}, the folder holds {_files(folder)}")
    assert not problems, "\n".join(problems) + "\n\nThe block as the tree stands:\n" + expected_block()


def test_parser_reads_entries_and_continuations() -> None:
    # A hand-written README: one entry wrapped over two lines, one data folder; text outside the block and
    # after the next heading is ignored.
    text = (
        "# x\n\n## Layout\n\nprose\n\n```\n"
        "a/      one.py two.py\n        three.py\na/d/    (seeds: .json)\n```\n"
        "\n## Next\n\n```\nz/ no.py\n```\n"
    )
    assert readme_entries(text) == {"a/": ["one.py", "two.py", "three.py"], "a/d/": ["(seeds:", ".json)"]}
