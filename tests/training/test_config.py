from __future__ import annotations

import dataclasses

import pytest

from bar_policy.training.cli import parse_config
from bar_policy.training.config import (
    PRESETS,
    PPOConfig,
    TrainConfig,
    apply_overrides,
    config_from_dict,
    config_to_dict,
    preset,
)


@pytest.mark.parametrize("name", sorted(PRESETS))
def test_presets_are_consistent(name):
    cfg = preset(name)
    assert cfg.preset == name
    # brax's layout: whole unrolls per iteration.
    assert (cfg.ppo.batch_size * cfg.ppo.num_minibatches) % cfg.ppo.num_envs == 0


def test_gpu_preset_divides_over_one_two_and_eight_devices():
    ppo = preset("gpu").ppo
    for devices in (1, 2, 4, 8):
        assert ppo.num_envs % devices == 0 and ppo.batch_size % devices == 0


def test_overrides_keep_types_and_reject_unknown_fields():
    cfg = apply_overrides(
        TrainConfig(), ["ppo.learning_rate=1e-3", "ppo.num_envs=256", "network.policy_hidden=(64, 64)"]
    )
    assert cfg.ppo.learning_rate == 1e-3 and isinstance(cfg.ppo.num_envs, int) and cfg.ppo.num_envs == 256
    assert cfg.network.policy_hidden == (64, 64)
    with pytest.raises(ValueError, match=r"no field 'learning_rat'.*learning_rate"):
        apply_overrides(TrainConfig(), ["ppo.learning_rat=1"])


def test_config_validation_names_the_values():
    with pytest.raises(ValueError, match=r"multiple of ppo\.num_envs = 3000"):
        PPOConfig(num_envs=3000)
    with pytest.raises(ValueError, match="unknown preset 'huge'"):
        preset("huge")


def test_config_json_round_trip():
    cfg = apply_overrides(preset("cpu"), ["env_overrides=('episode_length_s=4.0',)", "resume=runs/x"])
    assert config_from_dict(config_to_dict(cfg)) == cfg


def test_cli_applies_preset_then_flags():
    cfg = parse_config(
        [
            "--preset",
            "tiny",
            "--ppo.learning-rate",
            "0.002",
            "--env-overrides",
            "reward.scales.success=1",
            "episode_length_s=4",
        ]
    )
    assert cfg.preset == "tiny"
    assert cfg.ppo.learning_rate == 0.002
    assert cfg.ppo.num_envs == preset("tiny").ppo.num_envs
    assert cfg.env_overrides == ("reward.scales.success=1", "episode_length_s=4")


def test_cli_help_lists_every_option_with_its_docstring(capsys):
    with pytest.raises(SystemExit) as exc:
        parse_config(["--help"])
    assert exc.value.code == 0
    out = " ".join(capsys.readouterr().out.split())
    for section, cls in [("ppo", PPOConfig), ("", TrainConfig)]:
        for f in dataclasses.fields(cls):
            if dataclasses.is_dataclass(f.default_factory() if callable(f.default_factory) else None):
                continue
            flag = f"--{section + '.' if section else ''}{f.name.replace('_', '-')}"
            assert flag in out, flag
    # Units and meanings come from the attribute docstrings.
    assert "Total environment steps" in out and "Adam learning rate" in out and "min (0 = no limit;" in out


def test_cli_env_alias_and_cache_flags():
    cfg = parse_config(["--preset", "tiny", "--env", "LiteTrack", "--no-compile-cache"])
    assert cfg.env_name == "LiteTrack" and cfg.compile_cache is False
    cfg = parse_config(["--env=LiteReachNeck", "--compile-cache-dir", "/tmp/c"])
    assert cfg.env_name == "LiteReachNeck" and cfg.compile_cache and cfg.compile_cache_dir == "/tmp/c"
    # --env-overrides is not mistaken for the alias (it adds to the gpu preset's own item).
    assert parse_config(["--env-overrides", "init_noise=0"]).env_overrides == ("sim_dt=0.004", "init_noise=0")
    # One process per GPU: the GPU ids parse to a tuple.
    assert parse_config(["--distributed.local-device-ids", "1"]).distributed.local_device_ids == (1,)


def test_distributed_config_validation_names_the_values():
    from bar_policy.training.config import DistributedConfig

    with pytest.raises(ValueError, match=r"process_id=2, num_processes=2"):
        DistributedConfig(num_processes=2, process_id=2)
    with pytest.raises(ValueError, match=r"max_devices_per_host must be positive or None, got 0"):
        DistributedConfig(max_devices_per_host=0)


def test_merge_overrides_keeps_the_base_items_the_extra_ones_do_not_set():
    from bar_policy.overrides import merge_overrides

    base = ("sim_dt=0.004", "episode_length_s=4")
    assert merge_overrides(base, ()) == base
    assert merge_overrides(base, base) == base
    assert merge_overrides(base, ["reward.scales.success=1"]) == (*base, "reward.scales.success=1")
    # A path given again replaces the base's value for it, wherever it stood.
    assert merge_overrides(base, ["sim_dt = 0.002"]) == ("episode_length_s=4", "sim_dt = 0.002")


def test_cli_env_overrides_add_to_the_gpu_presets_own(capsys):
    """The reach gpu preset trains at a 4 ms physics step; --env-overrides adds to it, not replaces it."""
    assert parse_config([]).env_overrides == ("sim_dt=0.004",)
    cfg = parse_config(["--env-overrides", "reward.scales.success=1"])
    assert cfg.env_overrides == ("sim_dt=0.004", "reward.scales.success=1")
    assert parse_config(["--env-overrides", "sim_dt=0.002"]).env_overrides == ("sim_dt=0.002",)
    # The preset's settings are the reach task's: the neck variant keeps them, another task's env does not,
    # and the run says so.
    assert parse_config(["--env", "LiteReachNeck"]).env_overrides == ("sim_dt=0.004",)
    capsys.readouterr()
    assert parse_config(["--env", "LitePiano"]).env_overrides == ()
    assert "['sim_dt=0.004'] are the reach task's; not applied to LitePiano" in capsys.readouterr().err
    assert parse_config(["--preset", "tiny"]).env_overrides == ()


def test_gpu_presets_first_evaluation_follows_the_measured_crossing():
    """40M steps / 40,960 per iteration = 977 iterations; 23 periods x 2 lines -> 22-iteration epochs, an
    evaluation every 44 iterations = 1,802,240 env steps, just past the 1.64M at which five runs of five
    crossed 95 % (docs/performance.md, 2026-11-27)."""
    from bar_policy.training.brax.state import epoch_iterations

    cfg = preset("gpu")
    assert cfg.ppo.steps_per_iteration == 256 * 16 * 10 == 40_960
    assert epoch_iterations(cfg) == 22
    assert 2 * 22 * cfg.ppo.steps_per_iteration == 1_802_240
