"""A dry run (commands never sent) does not fault on a torque demand the joints cannot follow.

``--dry-run`` on the emulated bus used to end with ``fault torque_saturation`` 1.5 s into the start-up
ramp: the motors stay disabled, so the measured pose never follows the ramp and ``Kp * (q_cmd - q)`` grows
to the cap. The saturation rule is about commands the joints receive; a target that applies none
(``Target.applies_commands`` False) has its would-be saturation counted and logged once instead.
"""

from __future__ import annotations

import json
import logging

import numpy as np
from fault_targets import SteppedMock

from bar_policy.deploy.cli import main
from bar_policy.deploy.runtime import Runtime, RuntimeConfig
from bar_policy.deploy.safety import SafetyConfig
from bar_policy.tasks.reach.commands import SampledCommands


def _run(policy, target):
    cfg = RuntimeConfig(duration=1.0, start_mode="policy", safety=SafetyConfig(ramp_time=0.0))
    rt = Runtime(policy, target, SampledCommands(policy.obs_manager.command_names, seed=0), cfg)
    return rt, rt.run()


def _behind(applies: bool) -> SteppedMock:
    # left_shoulder_pitch reported 1 rad below its command: demand Kp * 1 = 50 N*m >= cap 17 every tick.
    off = np.zeros(14)
    off[0] = -1.0
    target = SteppedMock(offset_from=0, offset=off)
    target.applies_commands = applies
    return target


def test_saturation_is_a_fault_when_commands_apply(zero_policy):
    _, res = _run(zero_policy, _behind(True))
    assert res.fault_count == 1 and res.end_reason.startswith("fault torque_saturation")


def test_dry_run_counts_the_saturation_it_cannot_cause(zero_policy, caplog):
    caplog.set_level(logging.WARNING, logger="bar_policy.deploy.runtime")
    rt, res = _run(zero_policy, _behind(False))
    assert res.fault_count == 0 and res.end_reason.startswith("duration reached"), res.end_reason
    # 1.0 s at 0.02 s: ticks 0..49. Time at the cap after tick k is (k + 1) * 0.02 s, past 0.5 s from
    # k = 25 on: ticks 25..49 are counted, 25 of them.
    assert rt.dry_saturations == 25
    warned = [r.getMessage() for r in caplog.records if "commands are not applied" in r.getMessage()]
    assert len(warned) == 1 and "left_shoulder_pitch" in warned[0]


def test_cli_dry_run_on_the_emulated_bus_ends_as_asked(policy_path, tmp_path):
    """The issue's case end to end: the start-up ramp (3 s) is where the fault came, at 1.5 s."""
    argv = [
        "--policy",
        str(policy_path),
        "--target",
        "real",
        "--can-interface",
        "virtual",
        "--dry-run",
        "--duration",
        "2",
        "--log",
        str(tmp_path / "runs"),
    ]
    assert main(argv) == 0
    (run,) = (tmp_path / "runs").iterdir()
    record = json.loads((run / "run.json").read_text())
    assert record["end_reason"].startswith("duration reached"), record["end_reason"]
    assert "torque_saturation" not in json.dumps(record)
