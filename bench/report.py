"""A bench's report: printed, and written to ``--out`` when one is given (the benches' shared last step)."""

from __future__ import annotations

from pathlib import Path


def emit(text: str, out: str | Path | None) -> str:
    """Print ``text`` and, when ``out`` is set, write it there with a final newline; returns ``text``."""
    print(text)
    if out:
        Path(out).write_text(text + "\n")
    return text
