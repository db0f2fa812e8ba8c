"""``bar-train``: every option once in ``--help`` (grouped, with units); env overrides reach the env."""

from __future__ import annotations

import dataclasses
import os
import re
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

from bar_policy.training.cli import parse_config, preset_of
from bar_policy.training.config import PRESETS, PresetName, TrainConfig
from bar_policy.training.env_flags import env_default

REPO = Path(__file__).resolve().parents[2]


def _help(capsys, monkeypatch, argv=()) -> str:
    monkeypatch.setenv("COLUMNS", "80")  # one column of groups (tyro lays them side by side when wide)
    with pytest.raises(SystemExit) as exc:
        parse_config([*argv, "--help"])
    assert exc.value.code == 0
    return capsys.readouterr().out


def _flags(cls: type, prefix: str = "") -> set[str]:
    """The tyro flag of every leaf field: ``ppo.num_envs`` -> ``--ppo.num-envs``."""
    out = set()
    for f in dataclasses.fields(cls):
        default = f.default_factory() if callable(f.default_factory) else f.default
        if dataclasses.is_dataclass(default):
            out |= _flags(type(default), f"{prefix}{f.name.replace('_', '-')}.")
        else:
            out.add(f"--{prefix}{f.name.replace('_', '-')}")
    return out


def _listed(text: str) -> list[str]:
    """Option names where tyro lists them: a box line that starts with ``--`` (or ``-h, --help``)."""
    names = []
    for line in text.splitlines():
        body = line.strip("│ ").strip()
        if body.startswith("-"):
            # "--a INT", "--a, --no-a", "--env {..}, --env-name {..}": the option names of this entry.
            found = re.findall(r"(?<![\w-])(--?[a-z][\w.-]*)", body)
            names += [m for m in found if not m.rsplit(".", 1)[-1].removeprefix("--").startswith("no-")]
    return names


@pytest.mark.parametrize("preset", sorted(PRESETS))
def test_help_lists_every_option_once_grouped(preset, capsys, monkeypatch):
    text = _help(capsys, monkeypatch, ["--preset", preset])
    listed = _listed(text)
    # Booleans have a --no- twin on the same line; --env is the alias of --env-name on its line. The env's
    # settings are the --env.* group: the preset's env's config fields.
    env_config = type(env_default(PRESETS[preset]().env_name))
    expected = _flags(TrainConfig) | _flags(env_config, "env.") | {"-h", "--help", "--env"}
    assert sorted(listed) == sorted(expected), sorted(set(listed) ^ expected)
    assert text.count("--preset") == 1  # once: its own entry (it was listed twice)
    # Grouped: one box per nested config, with the group's own docstring.
    for group in ("ppo", "network", "eval", "rsl-rl", "distributed", "env", "env.reward.scales"):
        assert re.search(rf"^\W*{group} options", text, re.M), group
    # Units and the preset's defaults (the track preset's 8.9 min limit, the gpu preset's none).
    one = " ".join(text.split())
    assert "min (0 = no limit;" in one and "Total environment steps" in one
    assert "Episode length, s" in one and "--env.actuator.latency-steps" in one  # the env's, with units
    assert f"(default: {PRESETS[preset]().max_minutes})" in one
    assert f"Defaults shown: the {preset} preset's." in one


def test_preset_choices_are_the_presets():
    from typing import get_args

    assert set(get_args(PresetName)) == set(PRESETS)
    assert preset_of(["--preset", "tiny", "--seed", "1"]) == "tiny"
    assert preset_of(["--preset=cpu", "--preset", "track"]) == "track"  # the last one, as tyro
    assert preset_of(["--preset", "huge"]) == "gpu"  # tyro refuses it with the choices


def test_env_overrides_reach_the_env_config():
    from bar_policy import envs

    cfg = parse_config(
        ["--preset", "tiny", "--env-overrides", "reward.scales.action_rate=-0.1", "episode_length_s=4"]
    )
    env = envs.load(cfg.env_name, overrides=cfg.env_overrides)  # what training.run does
    assert env.config.reward.scales.action_rate == -0.1
    # 4 s at the 0.02 s control period = 200 steps.
    assert env.config.episode_length_s == 4.0 and env.episode_length == 200
    # The GPU session's tracker command: LiteTrack's own reward scales.
    cfg = parse_config(["--preset", "track", "--env-overrides", "reward.scales.action_rate=-0.1"])
    track = envs.apply_overrides(envs.default_config(cfg.env_name), cfg.env_overrides)
    assert cfg.env_name == "LiteTrack" and track.reward.scales.action_rate == -0.1


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (
            ["--env-overrides", "reward.scales.nope=1"],
            "bar-train: error: --env-overrides: override 'reward.scales.nope': no field 'nope' in "
            "RewardScales; valid fields: ['reach_coarse', 'reach_fine', 'success', 'action_rate', "
            "'action_accel', 'joint_limit', 'torque', 'torque_near_cap', 'joint_vel', 'wrist_posture']",
        ),
        (["--env", "LiteTrack", "--env-overrides", "motion.clip_set=mocap"], "clip sets"),
        (["--env-overrides", "episode_length_s=long"], "episode_length_s=long: expected a number"),
        (["--env-overrides", "episode_length_s"], "must look like 'dotted.path=value'"),
    ],
)
def test_bad_env_overrides_are_refused_before_training(argv, message, capsys):
    with pytest.raises(SystemExit) as exc:
        parse_config(argv)
    assert exc.value.code == 2
    assert message in " ".join(capsys.readouterr().err.split())


def test_bar_train_entry_point_and_train_ppo_py_are_one_command():
    scripts = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]["scripts"]
    assert scripts["bar-train"] == "bar_policy.training.cli:main"
    env = dict(os.environ, PYTHONPATH=str(REPO), COLUMNS="100")
    run = [sys.executable, "train/ppo.py", "--preset", "cpu", "--help"]
    via_script = subprocess.run(run, cwd=REPO, env=env, capture_output=True, text=True, timeout=120)
    entry = "from bar_policy.training.cli import main; main(['--preset', 'cpu', '--help'])"
    via_entry = subprocess.run(
        [sys.executable, "-c", entry], cwd=REPO, env=env, capture_output=True, text=True, timeout=120
    )
    assert via_script.returncode == via_entry.returncode == 0
    assert via_script.stdout == via_entry.stdout and via_script.stdout.startswith("usage: bar-train")


def test_help_into_a_reader_that_stops_reading_ends_without_a_traceback():
    # `bar-train --help | head -1`: the reader is gone while the help is written; the write fails with EPIPE
    # (Python ignores SIGPIPE, so a BrokenPipeError). Made certain here by closing the pipe's read end before
    # the process starts. Status 1, nothing on stderr (before: a BrokenPipeError traceback, status 1).
    env = dict(os.environ, PYTHONPATH=str(REPO), COLUMNS="100")
    read_end, write_end = os.pipe()
    os.close(read_end)
    try:
        proc = subprocess.run(
            [sys.executable, "train/ppo.py", "--help"],
            cwd=REPO,
            env=env,
            stdout=write_end,
            stderr=subprocess.PIPE,
            text=True,
            timeout=120,
        )
    finally:
        os.close(write_end)
    assert (proc.returncode, proc.stderr) == (1, "")
