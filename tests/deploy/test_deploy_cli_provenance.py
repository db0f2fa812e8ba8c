"""``bar-deploy`` prints a policy's provenance at start and refuses nothing because of it."""

from __future__ import annotations

import dataclasses

from policy_factory import default_metadata, make_policy_file

from bar_policy.deploy.cli import main

RECORD = {
    "git_commit": "fedcba9876543210fedcba9876543210fedcba98",
    "git_dirty": False,
    "versions": {"jax": "0.11.2", "mujoco": "3.17.0", "brax": "0.14.2", "torch": "absent"},
    "argv": ["bar-train", "--preset", "tiny"],
    "cwd": "/home/u/bar_policy",
}

RUN = ["--target", "mock", "--duration", "0.1", "--ramp-time", "0", "--max-overruns", "0", "--no-log"]


def _stdout_lines(capsys) -> list[str]:
    return capsys.readouterr().out.splitlines()


def test_run_and_eval_print_the_provenance_first(tmp_path, capsys):
    meta = dataclasses.replace(default_metadata(), provenance=RECORD)
    path = make_policy_file(tmp_path / "p.onnx", metadata=meta)
    assert main(["--policy", str(path), *RUN]) == 0
    lines = _stdout_lines(capsys)
    assert lines[:2] == [
        "provenance: commit fedcba987654 (clean tree); jax 0.11.2, mujoco 3.17.0, brax 0.14.2, torch absent",
        "  command: bar-train --preset tiny  (in /home/u/bar_policy)",
    ]
    assert lines[2].startswith(f"policy {path}")
    assert main(["eval", "--policy", str(path), "--episodes", "1", "--episode-length", "0.1"]) == 0
    assert _stdout_lines(capsys)[0].startswith("provenance: commit fedcba987654 (clean tree); ")


def test_files_without_or_with_broken_provenance_still_run(tmp_path, capsys):
    old = make_policy_file(tmp_path / "old.onnx")  # the metadata of files exported before provenance
    assert main(["--policy", str(old), *RUN]) == 0
    assert _stdout_lines(capsys)[0] == (
        "provenance: not recorded (a file exported before provenance, or not by bar_policy; its code "
        "version: test)"
    )
    broken = make_policy_file(tmp_path / "broken.onnx", props={"bar.provenance": "[1, 2]"})
    assert main(["--policy", str(broken), *RUN]) == 0
    assert _stdout_lines(capsys)[0] == "provenance: unreadable (a JSON list, not an object)"
