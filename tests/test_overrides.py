"""The one override syntax (``bar_policy.overrides``): paths, typed values, refusals naming the choices."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import pytest

from bar_policy.overrides import (
    OverrideError,
    apply_overrides,
    changed_overrides,
    did_you_mean,
    field_paths,
    split_override,
)


@dataclass(frozen=True, kw_only=True)
class Scales:
    action_rate: float = -0.01
    steps: int = 3


@dataclass(frozen=True, kw_only=True)
class Cfg:
    scales: Scales = field(default_factory=Scales)
    latency: tuple[int, int] = (0, 2)
    hidden: tuple[int, ...] = (64, 64)
    kind: Literal["swish", "elu"] = "swish"
    flag: bool = True
    name: str = "run"
    resume: str | None = None
    scale: float | tuple[float, ...] | None = 0.8

    def __post_init__(self) -> None:
        if self.latency[0] > self.latency[1]:
            raise ValueError(f"latency must be (min, max), got {self.latency}")


def test_values_are_read_by_the_field_types():
    cfg = apply_overrides(
        Cfg(),
        [
            "scales.action_rate=-0.1",
            "scales.steps=5",
            "latency=[1, 3]",
            "hidden=(32,)",
            "kind=elu",
            "flag=FALSE",
            "name=123",  # a string field keeps the text as typed
            "resume=runs/x",
            "scale=[0.5, 0.25]",
        ],
    )
    assert cfg.scales == Scales(action_rate=-0.1, steps=5)
    assert (cfg.latency, cfg.hidden, cfg.kind, cfg.flag) == ((1, 3), (32,), "elu", False)
    assert (cfg.name, cfg.resume, cfg.scale) == ("123", "runs/x", (0.5, 0.25))
    # An int where a float is wanted becomes a float; one number fills a variable-length tuple.
    cfg = apply_overrides(Cfg(), ["scales.action_rate=2", "hidden=16", "scale=1", "flag=true"])
    assert cfg.scales.action_rate == 2.0 and isinstance(cfg.scales.action_rate, float)
    assert (cfg.hidden, cfg.scale, cfg.flag) == ((16,), 1.0, True)
    # None and JSON's null for an optional field.
    assert apply_overrides(Cfg(resume="x"), ["resume=None"]).resume is None
    assert apply_overrides(Cfg(), ["scale=null"]).scale is None


@pytest.mark.parametrize(
    ("item", "message"),
    [
        ("scales.nope=1", "no field 'nope' in Scales; valid fields: ['action_rate', 'steps']"),
        ("nope.x=1", "no field 'nope' in Cfg; valid fields: ['scales', 'latency', 'hidden', 'kind'"),
        ("scales=1", "'scales' is a group; set one of its fields ['action_rate', 'steps']"),
        ("scales.steps=2.5", "expected an integer, got '2.5'"),
        ("scales.action_rate=fast", "expected a number, got 'fast'"),
        ("kind=relu", "expected one of ['swish', 'elu'], got 'relu'"),
        ("flag=yes", "expected a boolean (true or false), got 'yes'"),
        ("latency=[1, 2, 3]", "expected a sequence of 2 values (an integer, an integer)"),
        ("hidden=[64, x]", "expected a sequence of an integer like [1, 2]"),
        ("no-equals-sign", "must look like 'dotted.path=value'"),
    ],
)
def test_refusals_name_the_problem_and_the_choices(item, message):
    with pytest.raises(OverrideError) as info:
        apply_overrides(Cfg(), [item])
    assert message in str(info.value)


def test_all_items_apply_together_then_validate():
    from bar_policy.training.config import PPOConfig

    # 512 x 16 = 8192 segments are not a multiple of 3000 envs, so num_envs=3000 alone is refused; with
    # batch_size 375 x 8 minibatches = 3000 segments, applied in the same replace, it is valid.
    with pytest.raises(ValueError, match=r"= 8192 must be a multiple of ppo.num_envs = 3000"):
        apply_overrides(PPOConfig(), ["num_envs=3000"])
    cfg = apply_overrides(PPOConfig(), ["num_envs=3000", "batch_size=375", "num_minibatches=8"])
    assert (cfg.num_envs, cfg.batch_size, cfg.num_minibatches) == (3000, 375, 8)
    with pytest.raises(ValueError, match=r"latency must be \(min, max\), got \(3, 2\)"):
        apply_overrides(Cfg(), ["latency=[3, 2]"])


def test_mapping_values_are_used_as_given_and_paths_listed():
    cfg = apply_overrides(Cfg(), {"scales.steps": 7, "name": "x"})
    assert cfg.scales.steps == 7 and cfg.name == "x"
    assert field_paths(Cfg())[:3] == ["scales.action_rate", "scales.steps", "latency"]
    assert split_override(" a.b = 1 ") == ("a.b", "1")


def test_env_and_training_use_the_same_function():
    from bar_policy import envs, overrides
    from bar_policy.training import config

    assert envs.apply_overrides is overrides.apply_overrides
    assert config.apply_overrides is overrides.apply_overrides


def test_changed_overrides_are_the_items_that_rebuild_a_config():
    base = Cfg()
    changed = Cfg(
        scales=Scales(action_rate=0.1 + 0.2, steps=3),  # 0.30000000000000004: repr round-trips it exactly
        latency=(1, 1),
        hidden=(7,),
        flag=False,
        resume=None,
        scale=None,
        name="a b",
    )
    items = changed_overrides(changed, base)
    # Field order, leaves only, one item per changed leaf (steps and kind kept theirs).
    assert items == (
        "scales.action_rate=0.30000000000000004",
        "latency=(1, 1)",
        "hidden=(7,)",
        "flag=false",
        "name=a b",
        "scale=None",
    )
    assert apply_overrides(base, items) == changed
    assert changed_overrides(base, base) == ()


def test_did_you_mean():
    assert did_you_mean("action_rat", ["action_rate", "torque"]) == "; did you mean 'action_rate'?"
    assert did_you_mean("zzz", ["action_rate", "torque"]) == ""
    with pytest.raises(
        OverrideError, match=r"valid fields: \['action_rate', 'steps'\]; did you mean 'steps'"
    ):
        apply_overrides(Cfg(), ["scales.step=1"])
