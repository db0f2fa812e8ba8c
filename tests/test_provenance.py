"""Provenance: the git state of a checkout, library versions, and the optional ``bar.provenance`` key."""

from __future__ import annotations

import hashlib
import importlib.metadata
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from bar_policy import provenance
from bar_policy.deploy.metadata import BAR_KEYS, HC_KEYS, OPTIONAL_BAR_KEYS, PolicyMetadata

sys.path.insert(0, str(Path(__file__).parent))
from test_metadata import make

REPO = Path(__file__).resolve().parents[1]

RECORD = {
    "git_commit": "0123456789abcdef0123456789abcdef01234567",
    "git_dirty": True,
    "versions": {"jax": "0.10.2", "torch": "absent"},
    "argv": ["train/ppo.py", "--preset", "tiny"],
    "cwd": "/x",
    "python": "3.11.7",
    "created_utc": "2026-01-01T00:00:00Z",
}


# --------------------------------------------------------------------------------------------------------
# bar.provenance in the ONNX metadata
# --------------------------------------------------------------------------------------------------------
def test_metadata_round_trip_with_provenance():
    md = make(provenance=RECORD)
    props = md.to_props()
    assert set(props) == set(BAR_KEYS) | set(HC_KEYS) | {"bar.provenance"}
    assert "bar.provenance" in OPTIONAL_BAR_KEYS
    assert json.loads(props["bar.provenance"]) == RECORD
    back = PolicyMetadata.from_props(props)
    assert back.provenance == RECORD
    assert back == make(provenance=RECORD, obs_schema=json.dumps(json.loads(md.obs_schema), sort_keys=True))


def test_a_file_without_provenance_loads_and_says_so():
    props = make().to_props()
    assert "bar.provenance" not in props  # nothing recorded, nothing written (the shipped files' form)
    assert PolicyMetadata.from_props(props).provenance == {}
    # A file exported before provenance (the form of every file made before it) says so, naming its version.
    meta = PolicyMetadata.from_props(props)
    (line,) = provenance.describe(meta.provenance, meta.code_version)
    assert line.startswith("provenance: not recorded") and meta.code_version in line


def test_the_shipped_reach_policy_says_what_trained_it():
    """The reach policy shipped from the robust run (docs/robust_training.md, "Reach: shipped"): its commit,
    the tree flagged dirty (the only difference: the untracked script that launched the run on the GPU host),
    the command, and the 1 s command transition it was trained with."""
    from bar_policy.deploy.policy import load_policy

    meta = load_policy(REPO / "checkpoints" / "lite_reach_arms.onnx").metadata
    assert meta.provenance["git_commit"].startswith("6b82b70") and meta.provenance["git_dirty"] is True
    head, command = provenance.describe(meta.provenance, meta.code_version)
    assert head.startswith("provenance: commit 6b82b701df30 (dirty tree") and "jax 0.11.2" in head
    assert "train/ppo.py --preset reach-robust" in command and "--seed 0" in command
    assert meta.command_transition_s == 1.0 and meta.action_filter_hz == 3.0


def test_the_shipped_tracker_says_what_trained_it():
    """The tracker shipped from the 2026-12-05 run (docs/tracking.md, "The shipped tracker", one H200): its
    commit, a clean tree, the versions and the exact training command (the track preset, seed 1), and in
    its record the written-out Cholesky and TF32 SGD passes that the preset carries, and the iterate
    shipped (the best evaluated one)."""
    from bar_policy.deploy.policy import load_policy

    meta = load_policy(REPO / "checkpoints" / "lite_track_arms.onnx").metadata
    assert meta.provenance["git_commit"].startswith("af5dad9") and meta.provenance["git_dirty"] is False
    head, command = provenance.describe(meta.provenance, meta.code_version)
    assert head.startswith("provenance: commit af5dad91e8bf (clean tree, as given by BAR_POLICY_GIT_COMMIT)")
    assert "jax 0.11.2" in head
    assert "--preset track --seed 1" in command and "--max-minutes 8.3" in command
    record = json.loads((REPO / "checkpoints" / "lite_track_arms.json").read_text())
    train = record["config"]["train"]
    assert train["ppo"]["update_precision"] == "tensorfloat32"
    assert train["env_overrides"] == ["cholesky=columns"]
    assert record["iterate"] == "best" and record["provenance"]["git_commit"] == meta.provenance["git_commit"]


@pytest.mark.parametrize(
    ("text", "error"),
    [("{not json", "not valid JSON"), ("[1, 2]", "a JSON list, not an object")],
    ids=["bad-json", "list"],
)
def test_malformed_provenance_is_reported_not_refused(text, error):
    props = {**make().to_props(), "bar.provenance": text}
    meta = PolicyMetadata.from_props(props)  # no MetadataError: provenance informs only
    assert error in meta.provenance["error"]
    assert provenance.describe(meta.provenance)[0].startswith("provenance: unreadable (")


def test_describe_gives_commit_tree_versions_and_command():
    lines = provenance.describe(RECORD)
    assert lines == [
        "provenance: commit 0123456789ab (dirty tree); jax 0.10.2, torch absent",
        "  command: train/ppo.py --preset tiny  (in /x)",
    ]
    assert provenance.commit_text({**RECORD, "git_dirty": "unknown"}) == "0123456789ab (tree state unknown)"


# --------------------------------------------------------------------------------------------------------
# Git state
# --------------------------------------------------------------------------------------------------------
AUTHOR = "A <a@example.com> 1700000000 +0000"


def _git(repo: Path, *args: str) -> str:
    env = {
        "PATH": os.environ["PATH"],
        "HOME": str(repo),  # no user config
        "GIT_CONFIG_NOSYSTEM": "1",
        "GIT_AUTHOR_NAME": "A",
        "GIT_AUTHOR_EMAIL": "a@example.com",
        "GIT_AUTHOR_DATE": "1700000000 +0000",
        "GIT_COMMITTER_NAME": "A",
        "GIT_COMMITTER_EMAIL": "a@example.com",
        "GIT_COMMITTER_DATE": "1700000000 +0000",
    }
    return subprocess.run(
        ["git", "-c", "core.hooksPath=/dev/null", "-c", "commit.gpgsign=false", *args],
        cwd=repo,
        env=env,
        capture_output=True,
        text=True,
        check=True,
    ).stdout


def _expected_commit(content: bytes, message: str) -> str:
    """The commit hash by git's object format, worked out without git.

    blob = sha1("blob <len>\\0" + content); tree = sha1("tree <len>\\0" + "100644 a.txt\\0" + blob bytes);
    commit = sha1("commit <len>\\0" + "tree <tree>\\nauthor ...\\ncommitter ...\\n\\n<message>\\n").
    """

    def obj(kind: bytes, body: bytes) -> bytes:
        return hashlib.sha1(kind + b" %d\0" % len(body) + body).digest()

    blob = obj(b"blob", content)
    tree = obj(b"tree", b"100644 a.txt\0" + blob)
    body = f"tree {tree.hex()}\nauthor {AUTHOR}\ncommitter {AUTHOR}\n\n{message}\n".encode()
    return obj(b"commit", body).hex()


@pytest.fixture
def repo(tmp_path: Path) -> Path:
    r = tmp_path / "repo"
    r.mkdir()
    _git(r, "init", "-q")
    (r / "a.txt").write_bytes(b"hello\n")
    _git(r, "add", "a.txt")
    _git(r, "commit", "-q", "-m", "first")
    return r


def test_git_commit_and_dirty_flag_on_a_temporary_repository(repo):
    commit = _expected_commit(b"hello\n", "first")
    assert provenance.git_state(repo) == (commit, False)
    (repo / "a.txt").write_bytes(b"changed\n")  # a tracked file changed
    assert provenance.git_state(repo) == (commit, True)
    _git(repo, "add", "a.txt")  # staged counts too
    assert provenance.git_state(repo) == (commit, True)
    _git(repo, "checkout", "-q", "HEAD", "--", "a.txt")
    assert provenance.git_state(repo) == (commit, False)
    (repo / "new_module.py").write_text("x = 1\n")  # untracked, not ignored: not in the commit either
    assert provenance.git_state(repo) == (commit, True)
    (repo / ".git" / "info" / "exclude").write_text("new_module.py\n")  # ignored: clean again
    assert provenance.git_state(repo) == (commit, False)


def test_git_state_is_unknown_without_git_or_outside_a_checkout(repo, tmp_path, monkeypatch):
    outside = tmp_path / "plain"
    outside.mkdir()
    assert provenance.git_state(outside) == ("unknown", "unknown")
    # A copy installed inside someone else's repository is not that repository's commit.
    (repo / "sub").mkdir()
    assert provenance.git_state(repo / "sub") == ("unknown", "unknown")
    monkeypatch.setenv("PATH", str(tmp_path / "empty-bin"))  # no git executable at all
    assert provenance.git_state(repo) == ("unknown", "unknown")
    monkeypatch.delenv("BAR_POLICY_GIT_COMMIT", raising=False)
    record = provenance.collect(argv=["bar-train", "--preset", "tiny"], root=repo)
    assert (record["git_commit"], record["git_dirty"], record["git_source"]) == ("unknown", "unknown", "none")
    assert record["argv"] == ["bar-train", "--preset", "tiny"]
    assert provenance.describe(record)[0].startswith("provenance: commit unknown (tree state unknown); ")


def test_a_copied_work_tree_takes_the_commit_from_the_environment(repo, tmp_path, monkeypatch):
    copy = tmp_path / "copy"  # the work tree without .git, as the lent GPU machines receive it
    copy.mkdir()
    monkeypatch.setenv("BAR_POLICY_GIT_COMMIT", "abcdef0123456789abcdef0123456789abcdef01")
    monkeypatch.setenv("BAR_POLICY_GIT_DIRTY", "0")
    record = provenance.collect(root=copy)
    assert (record["git_commit"], record["git_dirty"], record["git_source"]) == (
        "abcdef0123456789abcdef0123456789abcdef01",
        False,
        "environment",
    )
    assert provenance.commit_text(record) == "abcdef012345 (clean tree, as given by BAR_POLICY_GIT_COMMIT)"
    monkeypatch.setenv("BAR_POLICY_GIT_DIRTY", "maybe")  # not a flag: unknown, not guessed
    assert provenance.collect(root=copy)["git_dirty"] == "unknown"
    # In a real checkout git wins over the variable; a variable git contradicts is kept beside it and shown.
    record = provenance.collect(root=repo)
    head = _expected_commit(b"hello\n", "first")
    assert record["git_source"] == "git" and record["git_commit"] == head
    assert record["stated_commit"] == "abcdef0123456789abcdef0123456789abcdef01"
    assert provenance.commit_text(record).endswith(
        "; BAR_POLICY_GIT_COMMIT said abcdef012345: a stale .git?)"
    )
    monkeypatch.setenv("BAR_POLICY_GIT_COMMIT", head[:7])  # a short hash of HEAD agrees: nothing extra
    assert "stated_commit" not in provenance.collect(root=repo)


def test_library_versions_installed_or_absent():
    got = provenance.library_versions((("numpy", "numpy"), ("no-such-dist-3f9", "no_such_module_3f9")))
    assert got == {"numpy": importlib.metadata.version("numpy"), "no-such-dist-3f9": "absent"}
    record = provenance.collect()
    assert set(record["versions"]) == {d for d, _ in provenance.LIBRARIES}
    assert record["argv"] == sys.argv and record["cwd"] == os.getcwd()
