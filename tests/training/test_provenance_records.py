"""Every record of a training run carries one provenance: run files, checkpoints, ONNX, shipped JSON."""

from __future__ import annotations

import json
import sys

import onnx

from bar_policy import provenance
from bar_policy.deploy.policy import load_policy


def test_every_run_record_carries_the_runs_provenance(brax_run, tmp_path):
    _, summary = brax_run
    run_dir = summary.run_dir
    config = json.loads((run_dir / "config.json").read_text())
    prov = config["provenance"]
    # This process trained (the session fixture): its command line, checkout and libraries.
    assert prov["argv"] == sys.argv
    commit, dirty = provenance.git_state()
    assert (prov["git_commit"], prov["git_dirty"]) == (commit, dirty)
    assert set(prov["versions"]) == {d for d, _ in provenance.LIBRARIES}
    import jax

    assert prov["versions"]["jax"] == jax.__version__  # the jax that trained
    lines = [json.loads(x) for x in (run_dir / "metrics.jsonl").read_text().splitlines()]
    assert [r["provenance"] for r in lines if r["kind"] == "provenance"] == [prov]
    final = json.loads((run_dir / "final_eval.json").read_text())
    assert final["provenance"] == prov and final["config"]["provenance"] == prov
    sidecars = sorted((run_dir / "checkpoints").glob("step_*.json"))
    assert sidecars and all(json.loads(p.read_text())["provenance"] == prov for p in sidecars)
    props = {p.key: p.value for p in onnx.load(str(summary.onnx_path)).metadata_props}
    assert json.loads(props["bar.provenance"]) == prov
    assert load_policy(summary.onnx_path).metadata.provenance == prov

    from bar_policy.training.publish import publish

    docs = tmp_path / "docs"
    paths = publish(run_dir, checkpoints_dir=tmp_path / "ck", docs_dir=docs)
    assert json.loads(paths["json"].read_text())["provenance"] == prov
    md = paths["docs"].read_text()
    # The results block names the exact command and the commit.
    import shlex

    assert f"| command | `{shlex.join(sys.argv)}` (backend brax) |" in md
    assert f"| commit | {provenance.commit_text(prov)} |" in md
