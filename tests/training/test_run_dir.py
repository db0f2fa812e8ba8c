"""A named run directory that already holds a run is refused unless the run resumes it."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest

from bar_policy.training.config import preset
from bar_policy.training.run_dir import resolve_run_dir


def test_reused_run_dir_is_refused_without_resume(tmp_path: Path) -> None:
    cfg = dataclasses.replace(preset("tiny"), runs_dir=str(tmp_path), run_name="a")
    assert resolve_run_dir(cfg) == tmp_path / "a"  # fresh: fine
    (tmp_path / "a").mkdir()
    (tmp_path / "a" / "metrics.jsonl").write_text('{"kind": "eval", "step": 0}\n')
    with pytest.raises(ValueError, match="already holds a run; choose another --run-name or --resume it"):
        resolve_run_dir(cfg)
    resumed = dataclasses.replace(cfg, resume=str(tmp_path / "a"))
    assert resolve_run_dir(resumed) == tmp_path / "a"


def test_a_resume_lists_the_settings_that_differ_from_the_resumed_run(tmp_path: Path) -> None:
    """A default that changed between two runs (2026-11-27: the gpu preset's batch and physics step) must
    not change a resumed training without a word; where the run writes and how far it goes may change."""
    import json

    from bar_policy.training.checkpoint import resume_changes

    ckpt = tmp_path / "step_000000000100.msgpack"
    old = {
        "train": {
            "run_name": "a",
            "max_minutes": 0,
            "export_onnx": True,
            "env_overrides": [],
            "ppo": {"batch_size": 512, "num_timesteps": 100, "learning_rate": 5e-4},
        },
        "env": {"sim_dt": 0.002, "reward": {"scales": {"success": 0.5}}},
    }
    ckpt.with_suffix(".json").write_text(json.dumps({"env_steps": 100, "iteration": 1, **old}))
    assert resume_changes(ckpt, old) == []
    assert resume_changes(ckpt, None) == []
    new = {
        "train": {
            "run_name": "b",
            "max_minutes": 5,
            "export_onnx": False,
            "env_overrides": ["sim_dt=0.004"],
            "ppo": {"batch_size": 256, "num_timesteps": 900, "learning_rate": 5e-4},
        },
        "env": {"sim_dt": 0.004, "reward": {"scales": {"success": 0.5}}},
    }
    assert resume_changes(ckpt, new) == [
        "resume: 3 settings differ from the resumed run's (step_000000000100.json):",
        "  train env_overrides: [] -> ['sim_dt=0.004']",
        "  train ppo.batch_size: 512 -> 256",
        "  env sim_dt: 0.002 -> 0.004",
    ]
    lines = resume_changes(tmp_path / "step_000000000200.msgpack", new)
    assert len(lines) == 1 and lines[0].startswith("resume: no config record to compare with")
