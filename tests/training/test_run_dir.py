"""A named run directory that already holds a run is refused unless the run resumes it."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest

from bar_policy.training.config import preset
from bar_policy.training.run import resolve_run_dir


def test_reused_run_dir_is_refused_without_resume(tmp_path: Path) -> None:
    cfg = dataclasses.replace(preset("tiny"), runs_dir=str(tmp_path), run_name="a")
    assert resolve_run_dir(cfg) == tmp_path / "a"  # fresh: fine
    (tmp_path / "a").mkdir()
    (tmp_path / "a" / "metrics.jsonl").write_text('{"kind": "eval", "step": 0}\n')
    with pytest.raises(ValueError, match="already holds a run; choose another --run-name or --resume it"):
        resolve_run_dir(cfg)
    resumed = dataclasses.replace(cfg, resume=str(tmp_path / "a"))
    assert resolve_run_dir(resumed) == tmp_path / "a"
