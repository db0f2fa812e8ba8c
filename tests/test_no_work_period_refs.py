"""No text of the project points at a work period (a session or an issue by number) instead of saying what it
means.

A reader has no such sessions or issues: a figure cites its device, commit and date; a decision gives its
reason. This scans the tracked text files of the package, the tests, the benches, the training scripts,
the docs and the README, and names every hit (file, line, text).
"""

from __future__ import annotations

import re
import subprocess
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
SCANNED = ("bar_policy", "tests", "bench", "train", "docs", "README.md")
"""The project's text: package, tests, benches, training scripts, docs, README (paths from the root)."""
WORK_PERIOD = re.compile(r"\b(session|issue)s? [0-9]+", re.IGNORECASE)
"""A work period's name: the word session or issue (or their plurals), a space, a number. The examples in this
file are assembled from parts (``_S``, ``_I``) so that the file itself passes the scan."""
_S, _I = "sess" + "ion", "iss" + "ue"


def _tracked_files() -> list[Path]:
    """The tracked files under ``SCANNED`` (``git ls-files``), or every file there outside a git checkout."""
    try:
        out = subprocess.run(
            ["git", "ls-files", "-z", "--", *SCANNED], cwd=REPO, capture_output=True, check=True, text=True
        ).stdout
        return [REPO / p for p in out.split("\0") if p]
    except (OSError, subprocess.CalledProcessError):
        found = []
        for name in SCANNED:
            path = REPO / name
            found += [path] if path.is_file() else [p for p in path.rglob("*") if p.is_file()]
        return [p for p in found if "__pycache__" not in p.parts]


def hits(paths: list[Path], root: Path = REPO) -> list[str]:
    """``path:line: text`` (from ``root``) of each line of a text file in ``paths`` naming a work period."""
    out = []
    for path in paths:
        try:
            text = path.read_text(encoding="utf-8")
        except (UnicodeDecodeError, FileNotFoundError):  # binary data (npz, onnx, png), or deleted unstaged
            continue
        for number, line in enumerate(text.splitlines(), 1):
            if WORK_PERIOD.search(line):
                out.append(f"{path.relative_to(root).as_posix()}:{number}: {line.strip()[:120]}")
    return out


def test_the_pattern_finds_work_periods_and_nothing_else(tmp_path):
    """Hand-made lines: the names of work periods are found, a figure's device/commit/date is not."""
    f = tmp_path / "a.md"
    f.write_text(
        f"measured in {_S} 45\n{_S.title()}s 41-44 answered it\n({_I} 19: time to a policy)\n"
        "one H200, commit 280175b, 2026-11-28\nthe session fixtures\nan issue with 3 causes\n",
        encoding="utf-8",
    )
    (tmp_path / "b.bin").write_bytes(
        b"\xff\xfe " + _S.encode() + b" 3"
    )  # not UTF-8: skipped, as the npz files are
    found = hits([f, tmp_path / "b.bin"], root=tmp_path)
    assert [h.split(":")[1] for h in found] == ["1", "2", "3"]


def test_no_text_names_a_work_period():
    files = _tracked_files()
    assert len(files) > 100, len(files)  # the tree was found
    found = hits(files)
    assert not found, f"{len(found)} lines name a work period:\n" + "\n".join(found)
