"""Pins: every range in pyproject.toml is bounded, holds the tested versions, and constraints.txt is used."""

from __future__ import annotations

import tomllib
from pathlib import Path

from packaging.requirements import Requirement
from packaging.specifiers import SpecifierSet
from packaging.utils import canonicalize_name

REPO = Path(__file__).resolve().parents[1]

GPU_TESTED = {
    "jax": "0.11.2",
    "torch": "2.11.0",
    "numpy": "2.5.2",
    "onnx": "1.23.1",
    "onnxruntime": "1.30.0",
    "flax": "0.12.10",
    "optax": "0.2.8",
    "matplotlib": "3.11.2",
    "imageio": "2.38.0",
    "pytest": "9.1.1",
    "hypothesis": "6.168.3",
}
"""What the lent GPU machines run (``pip list`` there, 2026-11-23), besides the wheels shipped from here."""


def _requirements() -> list[Requirement]:
    project = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]
    reqs = [Requirement(r) for r in project["dependencies"]]
    for items in project["optional-dependencies"].values():
        reqs += [Requirement(r) for r in items if not r.startswith("bar-policy")]
    return reqs


def _constraints() -> dict[str, str]:
    out = {}
    for line in (REPO / "constraints.txt").read_text().splitlines():
        text = line.split("#", 1)[0].strip()
        if text:
            name, version = text.split("==")
            out[canonicalize_name(name)] = version
    return out


def test_every_range_is_bounded_and_holds_the_tested_versions():
    pins = _constraints()
    for req in _requirements():
        ops = {s.operator for s in req.specifier}
        assert ops == {"=="} or {">=", "<"} <= ops, f"{req}: needs a lower and an upper bound"
        name = canonicalize_name(req.name)
        assert name in pins, f"{req.name} is not in constraints.txt"
        assert req.specifier.contains(pins[name]), f"constraints.txt {name}=={pins[name]} is outside {req}"
        if name in GPU_TESTED:
            assert req.specifier.contains(GPU_TESTED[name]), f"the GPU's {name} {GPU_TESTED[name]} is outside"
    python = SpecifierSet(tomllib.loads((REPO / "pyproject.toml").read_text())["project"]["requires-python"])
    assert all(python.contains(v) for v in ("3.11.7", "3.12.3"))  # this machine, the GPU machines


def test_ci_and_the_readme_install_with_the_constraints():
    ci = (REPO / ".ci" / "run").read_text()
    assert 'python3 -m pip install -q -c constraints.txt -e ".[all]"' in ci
    readme = (REPO / "README.md").read_text()
    assert 'pip install -c constraints.txt -e ".[all]" && python -m pytest -q' in readme
    # torch is pinned without the local label, so the CPU build here and PyPI's build elsewhere both match.
    assert _constraints()["torch"].count("+") == 0
