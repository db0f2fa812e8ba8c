"""Fixtures of the deploy tests: policy files built with ``policy_factory``."""

from __future__ import annotations

import logging
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).parent))

from policy_factory import make_policy_file

from bar_policy.deploy.policy import OnnxPolicy, load_policy


@pytest.fixture
def policy_path(tmp_path: Path) -> Path:
    """A valid linear policy with W = 0, b = 0 (action 0: q_cmd = default pose)."""
    return make_policy_file(tmp_path / "zero.onnx")


@pytest.fixture
def make_policy(tmp_path: Path):
    """Factory: ``make_policy(name="p.onnx", **make_policy_file kwargs) -> Path``."""

    def build(name: str = "p.onnx", **kwargs) -> Path:
        return make_policy_file(tmp_path / name, **kwargs)

    return build


@pytest.fixture
def zero_policy(policy_path: Path) -> OnnxPolicy:
    """The loaded zero policy."""
    return load_policy(policy_path)


@pytest.fixture(autouse=True)
def _deploy_logging(caplog: pytest.LogCaptureFixture) -> None:
    caplog.set_level(logging.INFO, logger="bar_policy.deploy")
    caplog.set_level(logging.INFO, logger="bar_policy.robstride")  # the real target's driver
