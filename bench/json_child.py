"""Run a bench script again in a fresh process and read its answer: the last stdout line, a JSON dict.

For benches whose measurement must not share a process with another (XLA keeps in-process caches:
autotuning results, compiled kernels): ``compile_options.py``, ``program_split.py``.
"""

from __future__ import annotations

import json
import subprocess
import sys
from typing import Any


def json_child(
    script: str, argv: list[str], *, timeout: float, env: dict[str, str] | None = None
) -> dict[str, Any]:
    """``python script *argv`` in a fresh process; its last stdout line parsed, or ``{"error": why}``."""
    cmd = [sys.executable, script, *argv]
    try:
        out = subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=timeout, check=False)
    except subprocess.TimeoutExpired:
        return {"error": f"timed out after {timeout:.0f} s"}
    try:
        return json.loads(out.stdout.strip().splitlines()[-1])
    except (IndexError, json.JSONDecodeError):
        return {"error": f"exit {out.returncode}: {(out.stderr.strip().splitlines() or ['?'])[-1][:200]}"}
