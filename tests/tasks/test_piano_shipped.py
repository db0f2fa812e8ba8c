"""The shipped piano policy, ``checkpoints/lite_piano_arms.onnx``: what it declares, and what it plays on the
C MuJoCo sim target with the held-out songs (the path ``bar-deploy eval`` runs).

The thresholds are the piano's targets: F1 >= 0.9 on the held-out songs on the sim target (RoboPianist's step
mean over each song's window), black and white recall >= 0.85 on them and on random songs, and the piano's
ship gate (``bar_policy.tasks.piano.gate``: every song completed, at most 0.5 % of ticks at a torque cap,
chatter against the key-pose reference at most 5 mrad). The file scored F1 0.913 when it shipped (all ticks;
0.908 over the songs' windows) on the library's held-out songs and misses the per-colour rows (docs/piano.md):
it awaits a retrain. The sim target steps C MuJoCo in float64 and the policy runs in onnxruntime's float32 on
the CPU, so the figures move by far less than the room between machines.
"""

from __future__ import annotations

import json
from pathlib import Path

import onnx
import pytest

from bar_policy.deploy.cli import main
from bar_policy.obs import ObservationManager
from bar_policy.quality.gate import check
from bar_policy.tasks.piano.heldout import EVAL_HELDOUT, RANDOM_EVAL_SEED
from bar_policy.tasks.piano.song_library import HELDOUT

PIANO = Path(__file__).resolve().parents[2] / "checkpoints" / "lite_piano_arms.onnx"


def test_shipped_piano_declares_its_task_for_humanoid_control() -> None:
    md = {p.key: p.value for p in onnx.load(str(PIANO)).metadata_props}
    assert md["task_type"] == "piano"
    # Humanoid Control's piano terms, in its order (lite-model.md, "Policy deployment").
    assert md["observation_names"].split(",") == [
        "target_keys",
        "progress",
        "key_pressed",
        "joint_pos",
        "joint_vel",
        "actions",
    ]
    assert json.loads(md["bar.obs_fingerprint"]) == ObservationManager.golden("lite_piano_arms").fingerprint
    # Trained on the bank of 256 random songs and the training library, never the held-out songs.
    assert md["dataset_repo_id"].startswith("bar_policy.piano:random256-seed0-")
    assert not {name for name in EVAL_HELDOUT if name in md["dataset_repo_id"]}
    assert f"-seed{RANDOM_EVAL_SEED}-" not in md["dataset_repo_id"]  # the random evaluation songs' seed


def test_shipped_piano_is_small() -> None:
    # 0.94M float32 weights: the 631-input 512-256-128 network and the key-pose prior's tables.
    assert PIANO.stat().st_size < 4_000_000


@pytest.mark.xfail(
    strict=True,
    reason="the shipped file predates the gate's per-colour recall rows and the black-key held-out songs: "
    "held-out F1 0.812, black recall 0.494 held out and 0.509 on random songs (docs/piano.md); a retrain "
    "must pass this gate, and then this marker goes",
)
@pytest.mark.slow
def test_shipped_piano_plays_the_held_out_songs_on_the_sim_target(tmp_path) -> None:
    out = tmp_path / "eval.json"
    assert main(["eval", "--policy", str(PIANO), "--json", str(out)]) == 0
    res = json.loads(out.read_text())
    assert [s["song"] for s in res["songs"] if s["group"] == "held-out"] == list(EVAL_HELDOUT)
    assert sum(s["group"] == "random" for s in res["songs"]) == 32
    assert res["f1"] >= 0.9
    assert check("piano", res["gate_report"]) == []  # completion, caps, chatter, F1, per-colour recall


def test_shipped_piano_still_plays_the_library_held_out_songs(tmp_path) -> None:
    """The gate of the file's day on the library's held-out songs, F1 over each song's window: every song
    completed, caps and chatter within the gate, F1 >= 0.9 (0.908 on 2026-12-02). Its only misses are the
    per-colour recall rows: black 0.792 of 48 key-ticks here, and no random song played (not measured)."""
    out = tmp_path / "eval.json"
    songs = ",".join(HELDOUT)
    assert (
        main(["eval", "--policy", str(PIANO), "--songs", songs, "--random-songs", "0", "--json", str(out)])
        == 0
    )
    res = json.loads(out.read_text())
    assert [s["song"] for s in res["songs"]] == list(HELDOUT)
    assert res["f1"] >= 0.9
    misses = check("piano", res["gate_report"])
    assert {m.metric for m in misses} == {"min_recall_pct"} and not any(m.safety for m in misses)
