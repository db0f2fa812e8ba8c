"""``bar-train``'s env settings as typed flags: parsed into ``env_overrides``, one error style, the header.

The ``--env.*`` group is the chosen env's config dataclass; a changed field becomes a ``path=value`` item of
``TrainConfig.env_overrides`` after the preset's and ``--env-overrides``' items. A preset alone resolves to
the config (and env config) it did before the flags existed: its own items, nothing added.
"""

from __future__ import annotations

import dataclasses
import re

import pytest

from bar_policy import envs
from bar_policy.training.cli import env_of, parse_config
from bar_policy.training.config import PRESETS, TrainConfig
from bar_policy.training.run_header import setting_lines


def _refused(argv, capsys) -> str:
    with pytest.raises(SystemExit) as exc:
        parse_config(argv)
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("bar-train: error: "), err  # one line
    assert "----" not in err and "──" not in err and "helptext" not in err, err  # no frame, no pointers
    return err.strip()


def test_a_mistyped_env_flag_gets_did_you_mean_and_its_group(capsys):
    err = _refused(["--preset", "tiny", "--env.reward.scales.action-rat", "-0.5"], capsys)
    flag = "--env.reward.scales.action-rat"
    assert f"unknown option {flag}; did you mean {flag}e?" in err
    # The valid choices: every reach reward scale (ReachEnvConfig.reward.scales's fields).
    from bar_policy.tasks.reach.term_table import RewardScales

    for f in dataclasses.fields(RewardScales):
        assert f"--env.reward.scales.{f.name.replace('_', '-')}" in err


def test_a_mistyped_override_path_gets_did_you_mean(capsys):
    err = _refused(["--preset", "tiny", "--env-overrides", "reward.scales.action_rat=-0.5"], capsys)
    assert "no field 'action_rat' in RewardScales" in err and "did you mean 'action_rate'?" in err


def test_a_mistyped_training_flag_gets_did_you_mean(capsys):
    err = _refused(["--ppo.num-envz", "16"], capsys)
    assert "did you mean --ppo.num-envs?" in err and "--ppo.learning-rate" in err


@pytest.mark.parametrize(
    ("argv", "words"),
    [
        (["--env.episode-length-s", "long"], ("--env.episode-length-s", "'long'")),
        (["--backend", "torch"], ("'--backend'", "'brax', 'rsl-rl'")),
        (["--env.init-noise", "-1"], ("init_noise must be >= 0 rad", "-1.0")),
        (["--env.actuator.latency-steps", "1"], ("--env.actuator.latency-steps", "2 values")),
    ],
)
def test_bad_values_are_one_line_naming_the_field(argv, words, capsys):
    err = _refused(["--preset", "tiny", *argv], capsys)
    for word in words:
        assert word in err, err


def test_typed_env_flags_reach_the_env_config():
    cfg = parse_config(
        [
            "--preset",
            "tiny",
            "--env.reward.scales.action-rate",
            "-0.5",
            "--env.actuator.latency-steps",
            "0",
            "1",
            "--env.actuator.no-quantize-wire",
        ]
    )
    assert cfg.env_overrides == (
        "actuator.quantize_wire=false",
        "actuator.latency_steps=(0, 1)",
        "reward.scales.action_rate=-0.5",
    )
    config = envs.apply_overrides(envs.default_config("LiteReach"), cfg.env_overrides)
    assert config.reward.scales.action_rate == -0.5 and config.actuator.latency_steps == (0, 1)
    assert config.actuator.quantize_wire is False


def test_a_flag_wins_over_the_shorthand_and_the_preset_items_stay():
    cfg = parse_config(
        [
            "--preset",
            "gpu",
            "--env-overrides",
            "reward.scales.action_rate=-0.2",
            "episode_length_s=4",
            "--env.reward.scales.action-rate",
            "-0.3",
        ]
    )
    # The gpu preset's sim_dt=0.004 first, the shorthand's items, then the flag replacing its path's item.
    assert cfg.env_overrides == ("sim_dt=0.004", "episode_length_s=4", "reward.scales.action_rate=-0.3")


def test_the_flags_defaults_are_the_preset_env_config(capsys, monkeypatch):
    # The gpu preset's reach items set sim_dt=0.004: the --env.sim-dt default shown is 0.004, and giving
    # that value back adds nothing.
    cfg = parse_config(["--preset", "gpu", "--env.sim-dt", "0.004"])
    assert cfg.env_overrides == ("sim_dt=0.004",)
    monkeypatch.setenv("COLUMNS", "80")  # one column
    with pytest.raises(SystemExit):
        parse_config(["--preset", "gpu", "--help"])
    text = " ".join(capsys.readouterr().out.replace("│", " ").split())
    entry = text.split("--env.sim-dt FLOAT", 1)[1].split(" --", 1)[0].strip()
    assert entry.startswith("Physics timestep, s") and entry.endswith("(default: 0.004)"), entry


@pytest.mark.parametrize("name", sorted(PRESETS))
def test_a_preset_resolves_as_before(name):
    """A preset alone: the same TrainConfig as ``preset(name)`` and the same env config as its own items."""
    cfg = parse_config(["--preset", name])
    before = PRESETS[name]()
    assert cfg == before
    env_config = envs.apply_overrides(envs.default_config(cfg.env_name), cfg.env_overrides)
    assert env_config == envs.apply_overrides(envs.default_config(before.env_name), before.env_overrides)


def test_preset_items_by_hand():
    # The presets' own env items (bar_policy/tasks/reach/preset.py, track/preset.py).
    assert parse_config(["--preset", "gpu"]).env_overrides == ("sim_dt=0.004",)
    assert parse_config(["--preset", "track"]).env_overrides == ("cholesky=columns",)
    assert parse_config(["--preset", "tiny"]).env_overrides == ()


def test_env_of():
    assert env_of(["--env", "LiteTrack", "--env.sim-dt", "0.004"], "LiteReach") == "LiteTrack"
    assert env_of(["--env-name=LitePiano"], "LiteReach") == "LitePiano"
    assert env_of(["--env", "Nope"], "LiteReach") == "LiteReach"  # tyro refuses it with the choices


def test_the_header_prints_every_non_default_setting():
    cfg = parse_config(["--preset", "tiny", "--seed", "3", "--env.reward.scales.action-rate", "-0.5"])
    config = envs.apply_overrides(envs.default_config("LiteReach"), cfg.env_overrides)
    lines = setting_lines(cfg, config, envs.default_config("LiteReach"))
    text = " ".join(" ".join(lines).split())
    expected_train = [
        f"{p}"
        for p in (
            "preset=tiny",
            "seed=3",
            f"ppo.num_envs={cfg.ppo.num_envs}",
            f"eval.num_evals={cfg.eval.num_evals}",
        )
    ]
    for item in expected_train:
        assert item in text
    assert text.endswith("env settings (LiteReach, not its defaults): reward.scales.action_rate=-0.5")
    # Every line fits the width, and a default config says so.
    assert all(len(x) <= 110 for x in lines)
    assert setting_lines(TrainConfig(), None) == ["settings (not the defaults): none"]


@pytest.mark.parametrize("env_name", ["LiteReach", "LiteTrack", "LitePiano"])
def test_every_env_setting_is_listed_with_its_help(env_name, capsys, monkeypatch):
    """``bar-train --env X --help`` lists each field of X's config with its docstring (units are there)."""
    from bar_policy.training.env_flags import env_default, option_names

    monkeypatch.setenv("COLUMNS", "80")
    with pytest.raises(SystemExit):
        parse_config(["--env", env_name, "--help"])
    text = " ".join(capsys.readouterr().out.replace("│", " ").split())
    flags = [f for f in option_names(env_default(env_name), "env.") if ".no-" not in f and "--no-" not in f]
    assert len(flags) > 40  # the robot's settings and the task's own
    for flag in flags:
        after = re.split(re.escape(flag) + r"(?=[ ,])", text, maxsplit=1)[1]
        entry = re.split(r" --(?!no-|env\.\S*no-)", after, maxsplit=1)[0]
        # Without the metavar ({None}|FLOAT, INT INT, {implicit,explicit}), a help text is left.
        words = re.sub(r"\{[^}]*\}", "", entry.split("(default:", 1)[0])
        assert re.search(r"[a-z]{3,}", words), (flag, entry)


def test_the_run_header_carries_the_settings(tmp_path, capsys):
    """The run's header (``run_dir.open_run``): the run line, then the settings lines, env included."""
    from types import SimpleNamespace

    from bar_policy.training.run_dir import open_run
    from bar_policy.training.startup.session import StartUp

    argv = ["--preset", "tiny", "--runs-dir", str(tmp_path), "--run-name", "h", "--env.init-noise", "0.02"]
    cfg = parse_config(argv)
    config = envs.apply_overrides(envs.default_config("LiteReach"), cfg.env_overrides)
    env = SimpleNamespace(config=config, observation_size=54, action_size=14, dt=0.02)
    open_run(cfg, env, StartUp(), True)
    out = capsys.readouterr().out
    assert "env settings (LiteReach, not its defaults): init_noise=0.02" in out
    assert "settings (not the defaults): preset=tiny " in out and f"runs_dir={tmp_path}" in out


def test_a_failed_check_of_the_root_names_its_config(capsys):
    err = _refused(["--preset", "tiny", "--max-minutes", "-1"], capsys)
    assert (
        err.startswith("bar-train: error: Error parsing TrainConfig: ")
        and "max_minutes" in err
        and "-1.0" in err
    )


def test_condense_reads_both_of_tyros_layouts():
    from bar_policy.training.env_flags import condense

    boxed = (
        "╭─ Value error ──────────────╮\n│ Error parsing env: init_noise must │\n│ be >= 0 rad, got -1.0 │\n"
        "│ ──────────────────────────── │\n│ For full helptext, see bar-train --help │\n╰──────────────╯\n"
    )
    plain = (
        " Value error   \n ---------------- \n  Error parsing env: init_noise must   \n"
        "  be >= 0 rad, got -1.0 \n  ----------------\n  For full helptext, see bar-train --help   \n      \n"
    )
    want = "Error parsing env: init_noise must be >= 0 rad, got -1.0"
    assert condense(boxed) == condense(plain) == want
