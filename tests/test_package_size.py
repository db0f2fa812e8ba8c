"""The package's size targets: no module over 400 lines, no sub-package over 40 % of the lines.

Lines are physical lines (``wc -l``). The package's total counts every ``.py`` file under ``bar_policy/``;
a sub-package is a folder directly under it, with everything beneath.
"""

from __future__ import annotations

from pathlib import Path

import bar_policy

ROOT = Path(bar_policy.__file__).parent
MAX_MODULE_LINES = 400
MAX_FOLDER_SHARE = 0.40


def _lines(path: Path) -> int:
    return len(path.read_text(encoding="utf-8").splitlines())


SIZES = {p.relative_to(ROOT): _lines(p) for p in ROOT.rglob("*.py")}


def test_no_module_over_400_lines() -> None:
    over = {str(p): n for p, n in SIZES.items() if n > MAX_MODULE_LINES}
    assert not over, f"modules over {MAX_MODULE_LINES} lines: {over}"


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
