"""The package's size rules: a module over 500 lines says why it is one unit; no sub-package over 40 %.

Size is a review judgement, not a cut: a module is split where its contents part (a seam), never to get
under a count. A module that grows past ``LONG_MODULE_LINES`` keeps a paragraph in its module docstring that
starts ``One unit:`` and says why it is not split (what would be cut in two). Lines are physical lines
(``wc -l``). The package's total counts every ``.py`` file under ``bar_policy/``; a sub-package is a folder
directly under it, with everything beneath.
"""

from __future__ import annotations

import ast
from pathlib import Path

import bar_policy

ROOT = Path(bar_policy.__file__).parent
LONG_MODULE_LINES = 500
UNIT_REASON = "One unit:"
MAX_FOLDER_SHARE = 0.40


def _lines(path: Path) -> int:
    return len(path.read_text(encoding="utf-8").splitlines())


SIZES = {p.relative_to(ROOT): _lines(p) for p in ROOT.rglob("*.py")}


def _says_why_one_unit(path: Path) -> bool:
    """Whether the module docstring has a paragraph starting ``One unit:`` with a reason after it."""
    doc = ast.get_docstring(ast.parse(path.read_text(encoding="utf-8"))) or ""
    paragraphs = [p.strip() for p in doc.split("\n\n")]
    return any(p.startswith(UNIT_REASON) and len(p) > len(UNIT_REASON) + 20 for p in paragraphs)


def test_long_modules_say_why_they_are_one_unit() -> None:
    unexplained = sorted(
        str(p) for p, n in SIZES.items() if n > LONG_MODULE_LINES and not _says_why_one_unit(ROOT / p)
    )
    assert not unexplained, (
        f"modules over {LONG_MODULE_LINES} lines without a {UNIT_REASON!r} paragraph in their docstring "
        f"(why they are not split along a seam): {unexplained}"
    )


def test_unit_reason_is_read_from_the_docstring(tmp_path: Path) -> None:
    # The check itself, on three hand-written modules: a reason paragraph counts; the words in a comment,
    # or a bare "One unit:" with no reason, do not.
    with_reason = tmp_path / "a.py"
    with_reason.write_text('"""Summary.\n\nOne unit: the loop and its state are one protocol machine."""\n')
    in_comment = tmp_path / "b.py"
    in_comment.write_text('"""Summary."""\n# One unit: the loop and its state are one protocol machine.\n')
    bare = tmp_path / "c.py"
    bare.write_text('"""Summary.\n\nOne unit:\n"""\n')
    assert _says_why_one_unit(with_reason)
    assert not _says_why_one_unit(in_comment)
    assert not _says_why_one_unit(bare)


def test_no_folder_over_40_percent() -> None:
    total = sum(SIZES.values())
    folders: dict[str, int] = {}
    for p, n in SIZES.items():
        if len(p.parts) > 1:
            folders[p.parts[0]] = folders.get(p.parts[0], 0) + n
    assert total > 10_000, total  # the whole package was read
    share = {f: n / total for f, n in folders.items()}
    over = {f: round(s, 3) for f, s in share.items() if s > MAX_FOLDER_SHARE}
    assert not over, f"folders over {MAX_FOLDER_SHARE:.0%} of {total} lines: {over}"
