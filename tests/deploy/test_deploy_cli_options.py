"""``bar-deploy --help``: every option once, the real target's too, with units; ``--seed``: one meaning."""

from __future__ import annotations

import argparse
import re

import numpy as np
import pytest

from bar_policy.deploy.cli import main
from bar_policy.tasks.reach import evaluate as sim2sim

REAL_OPTIONS = {
    # option: a fragment of its help that states the unit or the form of the value
    "--can-interface": "{socketcan,virtual}",
    "--channels": "'can0,can1' in that order, or 'can0=vcan0,can1=vcan1'",
    "--calibration": "calibration JSON written by bar-bus calibrate --calibration PATH",
    "--dry-run": "write no caps, enable nothing",
    "--emulate": "{auto,none,realtime,lockstep}",
    "--emulate-dt": "physics s per command round",
    "--reply-timeout": "deadline for each motor's reply, s",
    "--can-timeout": "(0x7028), s:",
    "--damping-kd": "N*m*s/rad",
    "--scan-to": "1..127",
}


def _help(argv: list[str], capsys) -> str:
    with pytest.raises(SystemExit) as e:
        main([*argv, "--help"])
    assert e.value.code == 0
    return capsys.readouterr().out


def _listed(text: str) -> list[str]:
    """Option names of the help's entries (a line starting with two spaces and a dash)."""
    names = []
    for line in text.splitlines():
        if line.startswith("  -"):
            invocation = re.split(r"\s{2,}", line.strip())[0]
            names += [part.split(" ")[0] for part in invocation.split(", ")]
    return names


def _expected(parser: argparse.ArgumentParser) -> list[str]:
    return [s for a in parser._actions if a.help != argparse.SUPPRESS for s in a.option_strings]


def test_run_help_lists_every_option_once_with_the_real_target(capsys):
    from bar_policy.deploy import cli
    from bar_policy.deploy.targets import real

    text = _help([], capsys)
    listed = _listed(text)
    parser = cli._run_parser()
    real.add_arguments(parser)
    assert sorted(listed) == sorted(_expected(parser))
    assert len(listed) == len(set(listed))  # once each
    flat = " ".join(text.split())
    for option, unit in REAL_OPTIONS.items():
        assert option in listed
        entry = flat.split(f" {option} ", 1)[1][:400]  # its entry in the real-target group
        assert unit in entry, (option, entry)
    assert "real target (Robstride over CAN):" in text
    # Every timed option of the loop states its unit.
    for option in ("--control-dt S", "--duration S|inf", "--ramp-time S", "--stale-timeout S"):
        assert option in text
    # --target real --help shows the same list.
    assert sorted(_listed(_help(["--target", "real"], capsys))) == sorted(listed)


def test_eval_help_lists_every_option_once(capsys):
    listed = _listed(_help(["eval"], capsys))
    assert len(listed) == len(set(listed))
    for option in ("--policy", "--episodes", "--seed", "--clips", "--hold-s", "--json", "--episode-length"):
        assert option in listed


def test_seed_draws_the_same_targets_in_run_and_eval(policy_path, monkeypatch):
    """``bar-deploy --seed N`` and episode 0 of ``bar-deploy eval --seed N``: one target sampler."""
    import argparse as ap

    from bar_policy.deploy.policy import load_policy
    from bar_policy.deploy.tasks import get_task

    made = []

    class Recording(sim2sim.SampledCommands):
        def __init__(self, *args, **kwargs):
            super().__init__(*args, **kwargs)
            made.append(self)

    monkeypatch.setattr(sim2sim, "SampledCommands", Recording)
    assert (
        main(
            [
                "eval",
                "--policy",
                str(policy_path),
                "--seed",
                "7",
                "--episodes",
                "1",
                "--episode-length",
                "0.1",
            ]
        )
        == 0
    )
    (episode0,) = made
    policy = load_policy(policy_path)
    run_source = get_task(policy.task).command_source(policy, ap.Namespace(seed=7, commands=None))
    assert (run_source.seed, run_source.period) == (episode0.seed, episode0.period) == (7, 2.5)
    # Episode 0 drew its targets for t < 0.1 s (draw 0); draws 0 and 1 (t = 0 s and 3 s at a 2.5 s
    # period) of both sources must be the same numbers.
    for t in (0.0, 3.0):
        a, b = run_source(t), episode0(t)
        assert all(np.array_equal(a[k], b[k]) for k in a)
