"""Docstrings and docs that state what the code does: checked against the code itself."""

from __future__ import annotations

import dataclasses
import inspect
import re
from pathlib import Path

from bar_policy.obs.manager import SHIPPED_LAYOUTS, ObservationManager, ObsTerm

REPO = Path(__file__).resolve().parents[1]


def test_envs_helpers_show_their_real_signatures():
    from bar_policy import envs
    from bar_policy.envs import wrappers

    for name in ("make_batched_env", "wrap_for_brax_training"):
        shown = inspect.signature(getattr(envs, name)).parameters
        real = inspect.signature(getattr(wrappers, name)).parameters
        # Same names, kinds and defaults as the function it forwards to (no *args, **kwargs).
        assert [(p.name, p.kind, p.default) for p in shown.values()] == [
            (p.name, p.kind, p.default) for p in real.values()
        ], name


def test_shipped_layouts_print_readably():
    # The golden files under bar_policy/obs/schemas/, with their task and mode (the task records').
    expected = {
        "lite_reach_arms": ("reach", "arms"),
        "lite_reach_arms_neck": ("reach", "arms_neck"),
        "lite_track_arms": ("track", "arms"),
        "lite_piano_arms": ("piano", "arms"),
    }
    assert repr(SHIPPED_LAYOUTS) == f"SHIPPED_LAYOUTS({expected!r})"
    assert str(SHIPPED_LAYOUTS) == repr(SHIPPED_LAYOUTS)  # print() shows the mapping, not an address
    assert {p.stem for p in (REPO / "bar_policy/obs/schemas").glob("*.json")} == set(expected)


def test_term_docstring_promises_only_what_a_term_has():
    fields = {f.name for f in dataclasses.fields(ObsTerm)}
    assert fields == {"name", "size", "scale", "clip"}  # no offset field
    doc = ObservationManager.term.__doc__ or ""
    promised = set(re.findall(r"``(\w+)``", doc.split("\n")[0])) - {"ObsTerm"}
    assert promised == {"size", "scale", "clip"} and promised <= fields
    # The offset it describes is the schema's default pose, subtracted for the terms that ask for it.
    om = ObservationManager.golden("lite_reach_arms")
    assert "default_joint_pos" in doc and hasattr(om.schema, "default_joint_pos")


def test_from_json_names_the_metadata_key_it_reads():
    from bar_policy.deploy.metadata import BAR_KEYS

    doc = ObservationManager.from_json.__doc__ or ""
    (key,) = re.findall(r"``(bar\.\w+)``", doc)
    assert key == "bar.obs_schema" and key in BAR_KEYS


def test_deploy_doc_prints_the_shipped_reach_files_provenance():
    """docs/deploy.md's example is what ``bar-deploy`` prints for the shipped reach policy, word for word."""
    from bar_policy.deploy.policy import load_policy
    from bar_policy.provenance import describe

    doc = (REPO / "docs/deploy.md").read_text()
    for path in sorted((REPO / "checkpoints").glob("*.onnx")):
        meta = load_policy(path).metadata
        lines = describe(meta.provenance, meta.code_version)
        assert lines[0].startswith("provenance: commit "), path  # recorded, not "not recorded"
        if path.name == "lite_reach_arms.onnx":
            assert "\n".join(lines) in doc
