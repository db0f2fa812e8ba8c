"""The rsl-rl ``train_cfg``: the field's reach/manipulation hyperparameters reach rsl-rl as stated."""

from __future__ import annotations

import dataclasses

import pytest

from bar_policy.training.brax.ignored_settings import brax_not_applied
from bar_policy.training.cli import parse_config
from bar_policy.training.config import preset
from bar_policy.training.rsl_rl.config import (
    FIELD_RSL_RL_PPO,
    RSL_RL_LR_BOUNDS,
    field_cli_flags,
    field_hyperparameters,
    field_overrides,
    not_applied,
    rsl_rl_train_cfg,
)


def test_field_hyperparameters_reach_rsl_rl_unchanged():
    f = FIELD_RSL_RL_PPO
    cfg = field_hyperparameters(dataclasses.replace(preset("gpu"), backend="rsl-rl"))
    train = rsl_rl_train_cfg(cfg)
    # 4096 envs: batch_size 1024 x 4 minibatches x unroll 24 = 98,304 env steps = 24 per env.
    assert cfg.ppo.num_envs == 4096 and cfg.ppo.steps_per_iteration == 4096 * 24
    assert train["num_steps_per_env"] == f["num_steps_per_env"] == 24
    alg = train["algorithm"]
    for name in ("learning_rate", "schedule", "desired_kl", "clip_param", "entropy_coef", "gamma", "lam"):
        assert alg[name] == f[name], name
    for name in ("num_learning_epochs", "num_mini_batches", "max_grad_norm", "value_loss_coef"):
        assert alg[name] == f[name], name
    for model in ("actor", "critic"):
        assert train[model]["hidden_dims"] == [256, 128, 64]
        assert train[model]["activation"] == "elu" and train[model]["obs_normalization"] is True
    assert train["actor"]["distribution_cfg"]["init_std"] == 1.0


def test_field_cli_flags_parse_to_the_same_config():
    flags = field_cli_flags(4096)
    assert flags[:2] == ["--ppo.unroll-length", "24"]
    parsed = parse_config(["--backend", "rsl-rl", *flags])
    want = field_hyperparameters(preset("gpu"))
    assert (parsed.ppo, parsed.network, parsed.rsl_rl) == (want.ppo, want.network, want.rsl_rl)
    # leave_out drops a path's flag with its values, and nothing else.
    i, j = flags.index("--network.policy-hidden"), flags.index("--ppo.update-precision")
    assert flags[i : i + 4] == ["--network.policy-hidden", "256", "128", "64"] and flags[j:] == [
        "--ppo.update-precision",
        "run",
    ]
    kept = field_cli_flags(4096, leave_out=("network.policy_hidden", "ppo.update_precision"))
    assert kept == flags[:i] + flags[i + 4 : j]


@pytest.mark.parametrize("num_envs", [0, 6, 4098])
def test_field_overrides_refuse_env_counts_the_minibatches_do_not_divide(num_envs):
    with pytest.raises(ValueError, match="multiple of 4"):
        field_overrides(num_envs)


def test_field_overrides_keep_24_steps_per_env_at_any_batch():
    for n in (32, 1024, 8192):
        o = field_overrides(n)
        assert o["ppo.batch_size"] * o["ppo.num_minibatches"] * o["ppo.unroll_length"] == 24 * n


def test_rsl_preset_is_the_gpu_preset_at_the_fields_values():
    """``--preset rsl`` (reach on rsl-rl as its users train it) = the gpu preset with ``FIELD_RSL_RL_PPO``."""
    cfg = preset("rsl")
    assert cfg.backend == "rsl-rl" and cfg.env_name == preset("gpu").env_name
    # Its evaluation cadence stays the one its targets were measured at (21); the gpu preset's is 24.
    assert (cfg.eval.num_evals, preset("gpu").eval.num_evals) == (21, 24)
    gpu_eval = dataclasses.replace(cfg.eval, num_evals=24)
    as_gpu = dataclasses.replace(cfg, preset="gpu", backend="brax", eval=gpu_eval)
    assert as_gpu == field_hyperparameters(preset("gpu"))
    assert parse_config(["--preset", "rsl"]) == cfg
    # rsl-rl's iteration: 4096 envs x 24 steps, 5 passes of 4 minibatches (FIELD_RSL_RL_PPO's values).
    train_cfg = rsl_rl_train_cfg(cfg)
    assert train_cfg["num_steps_per_env"] == 24
    alg = train_cfg["algorithm"]
    assert (alg["num_learning_epochs"], alg["num_mini_batches"]) == (5, 4)
    assert train_cfg["actor"]["hidden_dims"] == [256, 128, 64] and train_cfg["actor"]["activation"] == "elu"


def test_only_an_update_precision_torch_lacks_is_said_not_applied_on_rsl_rl():
    """``--backend rsl-rl`` applies the gpu and track presets' TF32 SGD passes to torch's update
    (``rsl_rl.torch_precision``), so nothing is said of it; the three-pass bfloat16 product, which torch
    lacks, gets one line naming it and what torch applies; ``--preset rsl`` and the field's values set
    ``run``."""
    gpu_on_rsl = field_hyperparameters(dataclasses.replace(preset("gpu"), backend="rsl-rl"))
    assert gpu_on_rsl.ppo.update_precision == "run" and not_applied(gpu_on_rsl) == []
    tf32 = dataclasses.replace(
        gpu_on_rsl, ppo=dataclasses.replace(gpu_on_rsl.ppo, update_precision="tensorfloat32")
    )
    assert not_applied(tf32) == []
    bf16x3 = dataclasses.replace(
        gpu_on_rsl, ppo=dataclasses.replace(gpu_on_rsl.ppo, update_precision="BF16_BF16_F32_X3")
    )
    assert not_applied(bf16x3) == [
        "ppo.update_precision=BF16_BF16_F32_X3 not applied: rsl-rl updates in torch, which has no such "
        "product (it applies run, tensorfloat32)"
    ]
    assert not_applied(preset("rsl")) == []


def test_the_track_preset_on_rsl_rl_says_each_brax_setting_it_runs_without():
    """The tracker's rsl-rl command of docs/training.md (the track preset plus the field's rsl-rl flags)
    runs rsl-rl's PPO, so four of the preset's brax choices do not reach it; each gets its line (values read
    off the track preset: fixed rate, minibatch targets, obs_std_eps 0, value weight 0.5 against rsl-rl's 1;
    rsl-rl's normaliser divides by std + 0.01). The field's values set the brax side as rsl-rl runs it."""
    flags = [
        *["--backend", "rsl-rl", "--ppo.unroll-length", "24", "--ppo.num-minibatches", "4"],
        *["--ppo.batch-size", "2048", "--rsl-rl.schedule", "adaptive", "--rsl-rl.desired-kl", "0.01"],
        *["--rsl-rl.value-loss-coef", "1.0", "--network.init-noise-std", "0.3"],
    ]
    cfg = parse_config(["--preset", "track", *flags])
    assert not_applied(cfg) == [
        "ppo.schedule=fixed not applied: rsl-rl's learning rate follows rsl_rl.schedule=adaptive "
        "(--rsl-rl.schedule)",
        "ppo.value_targets=minibatch not applied: rsl-rl computes the value targets and advantages once per "
        "iteration (as ppo.value_targets=iteration)",
        "ppo.vf_loss_coefficient=0.5 not applied: rsl-rl weighs its value loss by rsl_rl.value_loss_coef=1 "
        "(--rsl-rl.value-loss-coef)",
        "ppo.obs_std_eps=0 not applied: rsl-rl's normaliser divides by its running std + 0.01 (as "
        "ppo.obs_std_eps=0.0001)",
    ]
    # Under both schedules adaptive, the KL target and the rate's bounds are compared too; reward scaling
    # has no rsl-rl counterpart at all.
    ppo = dataclasses.replace(
        cfg.ppo, schedule="adaptive", desired_kl=0.02, max_learning_rate=1e-3, reward_scaling=2.0
    )
    lines = not_applied(dataclasses.replace(cfg, ppo=ppo))
    assert lines[0] == (
        "ppo.desired_kl=0.02 not applied: rsl-rl's adaptive rate targets rsl_rl.desired_kl=0.01 "
        "(--rsl-rl.desired-kl)"
    )
    assert lines[1] == (
        "ppo.min_learning_rate=1e-05, ppo.max_learning_rate=0.001 not applied: rsl-rl's adaptive rate stays "
        "within [1e-05, 0.01]"
    )
    assert lines[-1] == "ppo.reward_scaling=2 not applied: rsl-rl's loss takes the env's rewards unscaled"
    # With the field's values on top (what `bash bench/gpu_session.sh recipe track rsl` runs), only the track
    # preset's own normaliser setting is left to say.
    field = parse_config(["--preset", "track", "--backend", "rsl-rl", *field_cli_flags(8192)])
    assert not_applied(field) == [not_applied(cfg)[3]]


def test_track_rsl_preset_is_the_track_preset_at_the_fields_values_but_its_measured_departures():
    """``--preset track-rsl`` = the track preset with the field's rsl-rl values (``field_overrides(8192)``)
    but the track preset's networks and TF32 SGD passes, and the departures 2026-11-29 measured: initial
    std 0.3, a fixed rate of 3e-4 (the field's adaptive one chatters), entropy cost 1e-3, gamma 0.98 (the
    track preset's); ``obs_std_eps`` 1e-4 states rsl-rl's normaliser, so nothing goes unapplied."""
    track = preset("track")
    field = field_hyperparameters(dataclasses.replace(track, backend="rsl-rl"))
    expected = dataclasses.replace(
        field,
        preset="track-rsl",
        network=dataclasses.replace(
            field.network,
            policy_hidden=track.network.policy_hidden,
            value_hidden=track.network.value_hidden,
            init_noise_std=0.3,
        ),
        ppo=dataclasses.replace(
            field.ppo,
            update_precision="tensorfloat32",
            schedule="fixed",
            learning_rate=3e-4,
            entropy_cost=1e-3,
            discounting=0.98,
            obs_std_eps=1e-4,
        ),
        rsl_rl=dataclasses.replace(field.rsl_rl, schedule="fixed"),
    )
    cfg = preset("track-rsl")
    assert cfg == expected
    assert not_applied(cfg) == []
    alg = rsl_rl_train_cfg(cfg)["algorithm"]
    assert (alg["schedule"], alg["learning_rate"], alg["entropy_coef"]) == ("fixed", 3e-4, 1e-3)
    assert (alg["num_learning_epochs"], alg["num_mini_batches"], alg["gamma"]) == (5, 4, 0.98)
    assert track.ppo.discounting == 0.98 and field.ppo.discounting == 0.99
    assert rsl_rl_train_cfg(cfg)["num_steps_per_env"] == 24


def test_the_clipped_value_loss_is_rsl_rls_default_and_can_be_turned_off():
    """``rsl_rl.clipped_value_loss`` reaches rsl-rl's PPO as ``use_clipped_value_loss``; its default is
    rsl-rl's own (read from its signature, so a new rsl-rl that changes it fails here), which the field's
    configs and ``track-rsl`` keep."""
    import inspect

    from rsl_rl.algorithms import ppo as rsl_ppo

    default = inspect.signature(rsl_ppo.PPO).parameters["use_clipped_value_loss"].default
    for cfg in (preset("track-rsl"), field_hyperparameters(preset("gpu"))):
        assert rsl_rl_train_cfg(cfg)["algorithm"]["use_clipped_value_loss"] is default is True
    plain = parse_config(["--preset", "track-rsl", "--rsl-rl.no-clipped-value-loss"])
    assert rsl_rl_train_cfg(plain)["algorithm"]["use_clipped_value_loss"] is False
    assert not_applied(plain) == []  # an rsl-rl setting on an rsl-rl run: nothing to say


def test_rsl_rl_lr_bounds_are_rsl_rls_own():
    """``RSL_RL_LR_BOUNDS`` is what rsl-rl's PPO clamps its adaptive rate to (read from its source, so a
    new rsl-rl that moves them fails here), and brax's defaults match them."""
    import inspect
    import re

    from rsl_rl.algorithms import ppo as rsl_ppo

    src = inspect.getsource(rsl_ppo.PPO.update)
    lo = re.search(r"max\(([0-9.eE+-]+), self\.learning_rate / 1\.5\)", src)
    hi = re.search(r"min\(([0-9.eE+-]+), self\.learning_rate \* 1\.5\)", src)
    assert lo and hi, "rsl-rl's adaptive rule no longer reads as max(lo, lr / 1.5), min(hi, lr * 1.5)"
    assert (float(lo.group(1)), float(hi.group(1))) == RSL_RL_LR_BOUNDS
    ppo = preset("gpu").ppo
    assert (ppo.min_learning_rate, ppo.max_learning_rate) == RSL_RL_LR_BOUNDS


def test_a_brax_run_says_which_rsl_rl_settings_it_ignores():
    """``rsl_rl.*`` on a brax run: each one set away from ``RslRlConfig``'s default gets a line naming the
    brax field that decides instead (values read off the gpu preset: fixed rate, value weight 0.5); the
    presets and the field's flags (defaults on the rsl-rl side) get none, and an rsl-rl run none of these."""
    flags = ["--rsl-rl.schedule", "fixed", "--rsl-rl.value-loss-coef", "2.0", "--rsl-rl.device", "cpu"]
    cfg = parse_config(["--preset", "gpu", *flags, "--rsl-rl.no-clipped-value-loss"])
    assert brax_not_applied(cfg) == [
        "rsl_rl.schedule=fixed not applied: an rsl-rl backend setting; the brax backend's is "
        "ppo.schedule=fixed",
        "rsl_rl.value_loss_coef=2.0 not applied: an rsl-rl backend setting; the brax backend's is "
        "ppo.vf_loss_coefficient=0.5",
        "rsl_rl.clipped_value_loss=False not applied: an rsl-rl backend setting; brax's value loss is never "
        "clipped",
        "rsl_rl.device=cpu not applied: an rsl-rl backend setting; the brax backend runs on jax's devices",
    ]
    for name in ("gpu", "track", "piano", "cpu", "tiny"):
        assert brax_not_applied(preset(name)) == [], name
    assert brax_not_applied(parse_config(field_cli_flags(4096))) == []
    assert brax_not_applied(dataclasses.replace(cfg, backend="rsl-rl")) == []


def test_the_run_logger_says_and_records_the_settings_a_backend_runs_without(tmp_path):
    """``RunLogger.not_applied`` (both trainers call it with their backend's list): each line on the
    terminal, and the list as one ``not_applied`` record in metrics.jsonl; an empty list writes nothing."""
    import io
    import json

    from bar_policy.training.progress import RunLogger

    out = io.StringIO()
    logger = RunLogger(tmp_path, 100, stream=out)
    lines = ["a not applied: x", "b not applied: y"]
    logger.not_applied(lines)
    logger.not_applied([])
    logger.close()
    assert out.getvalue().splitlines() == lines
    (record,) = [json.loads(x) for x in (tmp_path / "metrics.jsonl").read_text().splitlines()]
    assert record["kind"] == "not_applied" and record["settings"] == lines


def test_backend_rsl_rl_alone_runs_the_rsl_preset_at_a_fixed_rate():
    """``bar-train --backend rsl-rl`` (no ``--preset``) runs ``gpu-rsl``: ``--preset rsl``'s sizes (24 steps
    per env, 5 epochs x 4 minibatches: 98,304 env steps and 20 Adam steps per iteration, where its speed
    comes from) with a fixed rate of 1e-3 and entropy cost 1e-3 in place of the field's adaptive rate and
    5e-3; nothing else differs and nothing goes unapplied. A ``--preset`` given wins."""
    rsl = preset("rsl")
    expected = dataclasses.replace(
        rsl,
        preset="gpu-rsl",
        ppo=dataclasses.replace(rsl.ppo, schedule="fixed", learning_rate=1e-3, entropy_cost=1e-3),
        rsl_rl=dataclasses.replace(rsl.rsl_rl, schedule="fixed"),
    )
    for argv in (["--backend", "rsl-rl"], ["--backend=rsl-rl"]):
        assert parse_config(argv) == expected
    cfg = expected
    assert not_applied(cfg) == []
    train_cfg = rsl_rl_train_cfg(cfg)
    alg = train_cfg["algorithm"]
    assert (alg["schedule"], alg["learning_rate"], alg["entropy_coef"]) == ("fixed", 1e-3, 1e-3)
    assert train_cfg["num_steps_per_env"] * cfg.ppo.num_envs == 98_304 == rsl.ppo.steps_per_iteration
    assert alg["num_learning_epochs"] * alg["num_mini_batches"] == 20
    assert parse_config(["--backend", "rsl-rl", "--preset", "rsl"]).preset == "rsl"
    assert parse_config(["--preset", "tiny", "--backend", "rsl-rl"]).preset == "tiny"
    assert parse_config([]).preset == "gpu" and parse_config(["--backend", "brax"]).preset == "gpu"
