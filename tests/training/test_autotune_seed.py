"""Seeding XLA's per-fusion autotune cache from the shipped results (``training.startup.autotune``).

CPU only: the device kind, backend and jaxlib version are monkeypatched (``local_platform``), so a fake
H100 gets the seed and the real CPU backend does not. Expected counts are worked out from the files made
here (three entries) or read from the shipped manifest (868 entries of 95 bytes on average).
"""

from __future__ import annotations

import hashlib
import json
import subprocess
import sys
import tarfile
import threading
from pathlib import Path

import pytest

from bar_policy.training.startup import autotune as ats
from bar_policy.training.startup.autotune import (
    AUTOTUNE_DIR,
    SEED_DIR,
    SeedManifest,
    pack_seed,
    shipped_seeds,
)

REPO = Path(__file__).resolve().parents[2]
KIND = "NVIDIA Fake 80GB"
SUBDIR = "0123456789abcdef"
ENTRIES = {"aa.pb": b"\x0a\x01a", "bb.pb": b"\x0a\x01b", "cc.pb": b"\x0a\x01c"}


def _autotune_cache(root: Path, entries: dict[str, bytes] = ENTRIES) -> Path:
    """A compile cache dir holding ``AUTOTUNE_DIR/SUBDIR/<entries>``, as XLA leaves it."""
    d = root / AUTOTUNE_DIR / SUBDIR
    d.mkdir(parents=True)
    for name, data in entries.items():
        (d / name).write_bytes(data)
    return root


def _seeds(tmp_path: Path, jaxlib: str = "9.9.9") -> Path:
    out = tmp_path / "seeds"
    pack_seed(
        _autotune_cache(tmp_path / "made"),
        out,
        name="fake",
        device_kind=KIND,
        jax_version=jaxlib,
        jaxlib_version=jaxlib,
        commit="abc1234",
        programs=("reset", "epoch"),
        made_with="a test",
    )
    return out


@pytest.fixture
def gpu(monkeypatch):
    """This process looks like a fake GPU with jaxlib 9.9.9 and jax's default XLA-caches flag."""
    monkeypatch.setattr(ats, "local_platform", lambda: ("gpu", KIND, "9.9.9"))
    monkeypatch.setattr(ats, "_xla_caches_flag", lambda: AUTOTUNE_DIR)


def test_seeds_an_empty_cache_then_skips_what_is_there(tmp_path, gpu):
    seeds, cache = _seeds(tmp_path), tmp_path / "cache"
    first = ats.seed_autotune_cache(cache, seeds_dir=seeds)
    assert (first.seeded, first.present, first.refused, first.reason) == (3, 0, 0, "")
    assert first.source == "fake.tar.gz"
    target = cache / AUTOTUNE_DIR / SUBDIR
    (manifest,) = (m for _, m in shipped_seeds(seeds))
    stamp = f".seeded-{manifest.sha256}"
    # The entries, and the empty stamp of an archive copied whole; no temporary files left.
    assert {p.name: p.read_bytes() for p in target.iterdir()} == {**ENTRIES, stamp: b""}
    assert first.line().startswith("autotune seed: 3 entries seeded, 0 already present, from fake.tar.gz")
    again = ats.seed_autotune_cache(cache, seeds_dir=seeds)
    assert (again.seeded, again.present) == (0, 3)


def test_a_stamped_archive_is_not_read_again_and_a_removed_folder_is_seeded_again(tmp_path, gpu, monkeypatch):
    """2026-11-29: a warm start's seeding read every member again (0.6 s of Python beside the start)."""
    seeds, cache = _seeds(tmp_path), tmp_path / "cache"
    assert ats.seed_autotune_cache(cache, seeds_dir=seeds).seeded == 3
    real_open = tarfile.open

    def no_read(*args, **kwargs):
        raise AssertionError("the archive was read although its stamp is there")

    monkeypatch.setattr(ats.tarfile, "open", no_read)
    again = ats.seed_autotune_cache(cache, seeds_dir=seeds)
    assert (again.seeded, again.present, again.source) == (0, 3, "fake.tar.gz")
    monkeypatch.setattr(ats.tarfile, "open", real_open)
    for p in (cache / AUTOTUNE_DIR / SUBDIR).iterdir():  # a user clears XLA's folder: the stamp goes too
        p.unlink()
    assert ats.seed_autotune_cache(cache, seeds_dir=seeds).seeded == 3


def test_a_seed_packed_from_a_seeded_cache_holds_the_entries_not_the_stamp(tmp_path, gpu):
    cache = tmp_path / "cache"
    assert ats.seed_autotune_cache(cache, seeds_dir=_seeds(tmp_path)).seeded == 3
    pack_seed(
        cache / AUTOTUNE_DIR,
        tmp_path / "again",
        name="again",
        device_kind=KIND,
        jax_version="9.9.9",
        jaxlib_version="9.9.9",
        commit="abc1234",
        programs=("reset",),
        made_with="a test",
    )
    with tarfile.open(tmp_path / "again" / "again.tar.gz") as tar:
        names = sorted(t.name for t in tar if t.isfile())
    assert names == [f"{SUBDIR}/{n}" for n in sorted(ENTRIES)]


def test_seeding_runs_on_its_own_thread_and_gives_the_same_outcome(tmp_path, gpu, monkeypatch):
    """The trainer seeds in the background (``run.py``) and waits for the outcome before compiling."""
    seeds = _seeds(tmp_path)
    release, seen = threading.Event(), []
    real = ats.seed_autotune_cache

    def held(*args, **kwargs):
        seen.append(threading.current_thread().name)
        assert release.wait(30)
        return real(*args, **kwargs)

    monkeypatch.setattr(ats, "seed_autotune_cache", held)
    future = ats.seed_in_background(tmp_path / "c", seeds_dir=seeds)
    assert not future.done()  # the caller goes on while the copy waits
    release.set()
    out = future.result(timeout=30)
    assert seen[0].startswith("autotune-seed") and seen[0] != threading.current_thread().name
    assert (out.seeded, out.present, out.source) == (3, 0, "fake.tar.gz")


def test_never_overwrites_an_entry_xla_wrote(tmp_path, gpu):
    seeds, cache = _seeds(tmp_path), tmp_path / "cache"
    mine = cache / AUTOTUNE_DIR / SUBDIR / "bb.pb"
    mine.parent.mkdir(parents=True)
    mine.write_bytes(b"XLA's own result")
    out = ats.seed_autotune_cache(cache, seeds_dir=seeds)
    assert (out.seeded, out.present) == (2, 1)  # aa, cc copied; bb kept
    assert mine.read_bytes() == b"XLA's own result"


@pytest.mark.parametrize(
    ("platform", "flag", "enabled", "cache", "reason"),
    [
        (("gpu", "NVIDIA Other", "9.9.9"), AUTOTUNE_DIR, True, "c", "no seed for device 'NVIDIA Other'"),
        (("gpu", KIND, "9.9.8"), AUTOTUNE_DIR, True, "c", "made with jaxlib ['9.9.9'], this is 9.9.8"),
        (("cpu", "cpu", "9.9.9"), AUTOTUNE_DIR, True, "c", "CPU backend; XLA autotunes on GPUs only"),
        (("gpu", KIND, "9.9.9"), "xla_gpu_kernel_cache_file", True, "c", "leaves out"),
        (("gpu", KIND, "9.9.9"), AUTOTUNE_DIR, True, None, "compile cache off"),
        (("gpu", KIND, "9.9.9"), AUTOTUNE_DIR, False, "c", "switched off, --no-autotune-seed"),
    ],
)
def test_does_nothing_and_says_why(tmp_path, monkeypatch, platform, flag, enabled, cache, reason):
    seeds = _seeds(tmp_path)
    monkeypatch.setattr(ats, "local_platform", lambda: platform)
    monkeypatch.setattr(ats, "_xla_caches_flag", lambda: flag)
    out = ats.seed_autotune_cache(cache and tmp_path / cache, enabled=enabled, seeds_dir=seeds)
    assert out.seeded == 0 and reason in out.reason
    assert out.line().startswith("autotune seed: not used (")
    assert not (tmp_path / "c").exists()


def test_all_xla_caches_includes_the_autotune_dir(tmp_path, monkeypatch):
    monkeypatch.setattr(ats, "local_platform", lambda: ("gpu", KIND, "9.9.9"))
    monkeypatch.setattr(ats, "_xla_caches_flag", lambda: "all")
    assert ats.seed_autotune_cache(tmp_path / "c", seeds_dir=_seeds(tmp_path)).seeded == 3


def test_the_real_cpu_backend_is_not_seeded(tmp_path):
    out = ats.seed_autotune_cache(tmp_path / "c")
    assert out.reason == "CPU backend; XLA autotunes on GPUs only" and not (tmp_path / "c").exists()


def test_a_tampered_archive_or_member_is_refused_and_counted(tmp_path, gpu):
    seeds = _seeds(tmp_path)
    archive = seeds / "fake.tar.gz"
    archive.write_bytes(archive.read_bytes() + b"\0")
    assert (
        "does not match its manifest's sha256"
        in ats.seed_autotune_cache(tmp_path / "c", seeds_dir=seeds).reason
    )
    # An archive with a member outside the subdir (and its manifest's hash updated): that member is refused.
    with tarfile.open(archive, "w:gz") as tar:
        tar.add(_autotune_cache(tmp_path / "m2") / AUTOTUNE_DIR / SUBDIR / "aa.pb", f"{SUBDIR}/aa.pb")
        tar.add(tmp_path / "m2" / AUTOTUNE_DIR / SUBDIR / "bb.pb", "../escape.pb")
    manifest = json.loads((seeds / "fake.json").read_text())
    manifest["sha256"] = hashlib.sha256(archive.read_bytes()).hexdigest()
    (seeds / "fake.json").write_text(json.dumps(manifest))
    out = ats.seed_autotune_cache(tmp_path / "c", seeds_dir=seeds)
    assert (out.seeded, out.refused) == (1, 1) and "1 malformed members refused" in out.line()
    assert (
        not (tmp_path / "escape.pb").exists() and not (tmp_path / "c" / AUTOTUNE_DIR / "escape.pb").exists()
    )


# The shipped seeds: archive -> (device kind, XLA's subdirectory, commit, programs, entries), from each cold
# run's pack (docs/training.md).
H100, H100_DIR = "NVIDIA H100 80GB HBM3", "699b92c0fb30cb16"
H200, H200_DIR = "NVIDIA H200", "ed0e56ab8b2a0ecb"
EPOCH = ("reset", "epoch", "init", "evaluate")
SPLIT = ("reset", "rollout", "update", "init", "evaluate")
SHIPPED = {
    "h100-80gb-hbm3-jaxlib-0.11.2-piano.tar.gz": (H100, H100_DIR, "e842f1c", EPOCH, 1072),
    "h100-80gb-hbm3-jaxlib-0.11.2-rsl.tar.gz": (H100, H100_DIR, "a27fd9d", ("train step", "eval step"), 749),
    "h100-80gb-hbm3-jaxlib-0.11.2-track.tar.gz": (H100, H100_DIR, "a27fd9d", EPOCH, 830),
    "h100-80gb-hbm3-jaxlib-0.11.2.tar.gz": (H100, H100_DIR, "c61072c", EPOCH, 868),
    # The gpu preset of 2026-11-27 (batch 256, 4 ms, training.brax.ppo_loss); the one above is the batch-512,
    # 2 ms preset's.
    "h100-80gb-hbm3-jaxlib-0.11.2-gpu.tar.gz": (H100, H100_DIR, "68897c4", SPLIT, 849),
    # The same preset on the H200 (2026-11-28: the lent machines are H200s now), then rsl and track
    # (2026-11-28) and piano (2026-11-28); the gpu preset again on 2026-11-29, with its TF32 update (13 of
    # its 853 entries differ from the first H200 seed's).
    "h200-jaxlib-0.11.2-gpu.tar.gz": (H200, H200_DIR, "fabc7da", SPLIT, 853),
    "h200-jaxlib-0.11.2-piano.tar.gz": (H200, H200_DIR, "280175b", SPLIT, 1053),
    "h200-jaxlib-0.11.2-rsl.tar.gz": (H200, H200_DIR, "968e856", ("train step", "eval step"), 757),
    # track again on 2026-11-29, for the preset's written-out Cholesky and TF32 update (bd258f3)
    "h200-jaxlib-0.11.2-track.tar.gz": (H200, H200_DIR, "bd258f3", SPLIT, 1028),
}
SHIPPED_MEMBERS = 1072 + 749 + 830 + 868 + 849
SHIPPED_UNION = 2819
"""The H100 archives' entries, all and distinct (a fusion two presets share is one name; counted with
``tarfile`` when they were added: 4368 members, 1549 of them repeats)."""
H200_MEMBERS = 853 + 1053 + 757 + 1028
H200_UNION = 2908
"""The same for the H200's four (``tarfile``, 2026-11-28: 3494 members, 802 of them repeats)."""


def test_the_shipped_seeds_match_their_manifests():
    seeds = shipped_seeds()
    assert {m.archive for _, m in seeds} == set(SHIPPED)
    for path, m in seeds:
        kind, subdir, commit, programs, entries = SHIPPED[m.archive]
        assert (m.device_kind, m.subdir) == (kind, subdir)
        assert (m.jax, m.jaxlib, m.commit) == ("0.11.2", "0.11.2", commit)
        assert m.programs == programs
        archive = path.parent / m.archive
        assert hashlib.sha256(archive.read_bytes()).hexdigest() == m.sha256
        with tarfile.open(archive) as tar:
            names = [t.name for t in tar if t.isfile()]
        assert len(names) == m.entries == entries
        assert all(n.startswith(f"{m.subdir}/") and n.endswith(".pb") for n in names)
        assert archive.stat().st_size < 64 * 1024  # it ships in the wheel: keep it small


def test_the_shipped_seed_is_package_data():
    text = (REPO / "pyproject.toml").read_text()
    rel = SEED_DIR.relative_to(REPO / "bar_policy").as_posix()
    assert f'"{rel}/*.json"' in text and f'"{rel}/*.tar.gz"' in text


def test_the_shipped_seed_applies_on_its_own_device(tmp_path, monkeypatch):
    monkeypatch.setattr(ats, "_xla_caches_flag", lambda: AUTOTUNE_DIR)
    monkeypatch.setattr(ats, "local_platform", lambda: ("gpu", H100, "0.11.2"))
    out = ats.seed_autotune_cache(tmp_path / "h100")
    # Every H100 seed applies, the H200's do not; a name two seeds share is written once, then counted
    # as present.
    assert (out.seeded, out.present, out.refused) == (SHIPPED_UNION, SHIPPED_MEMBERS - SHIPPED_UNION, 0)
    assert [p.name for p in (tmp_path / "h100" / AUTOTUNE_DIR).iterdir()] == [H100_DIR]
    names = [p.name for p in (tmp_path / "h100" / AUTOTUNE_DIR / H100_DIR).iterdir()]
    assert sum(n.endswith(".pb") for n in names) == SHIPPED_UNION
    h100 = [m for _, m in shipped_seeds(SEED_DIR) if m.device_kind == H100]
    assert sorted(n for n in names if n.startswith(".")) == sorted(f".seeded-{m.sha256}" for m in h100)
    monkeypatch.setattr(ats, "local_platform", lambda: ("gpu", H200, "0.11.2"))
    out = ats.seed_autotune_cache(tmp_path / "h200")
    assert (out.seeded, out.present, out.refused) == (H200_UNION, H200_MEMBERS - H200_UNION, 0)
    assert out.source == ", ".join(f"h200-jaxlib-0.11.2-{p}.tar.gz" for p in ("gpu", "piano", "rsl", "track"))
    assert [p.name for p in (tmp_path / "h200" / AUTOTUNE_DIR).iterdir()] == [H200_DIR]


def test_pack_script_round_trips(tmp_path):
    """bench/autotune_seed.py packs a cache; seeding another cache from it gives the same files back."""
    _autotune_cache(tmp_path / "made")
    cmd = [sys.executable, str(REPO / "bench" / "autotune_seed.py"), "--from", str(tmp_path / "made")]
    flags = ["--out", str(tmp_path / "s"), "--name", "fake", "--device-kind", KIND, "--jax", "9.9.9"]
    flags += ["--jaxlib", "9.9.9", "--commit", "abc1234"]
    run = subprocess.run([*cmd, *flags], capture_output=True, text=True, cwd=REPO, timeout=120)
    assert run.returncode == 0, run.stderr
    m = SeedManifest.read(tmp_path / "s" / "fake.json")
    assert (m.device_kind, m.subdir, m.entries, m.archive) == (KIND, SUBDIR, 3, "fake.tar.gz")
    assert m.programs == ("reset", "rollout", "update", "init", "evaluate")  # the trainer's, since 2026-11-27
    first = (tmp_path / "s" / "fake.tar.gz").read_bytes()
    # Reproducible: packing again gives the same bytes.
    pack_seed(
        tmp_path / "made" / AUTOTUNE_DIR,
        tmp_path / "s2",
        name="fake",
        device_kind=KIND,
        jax_version="9.9.9",
        jaxlib_version="9.9.9",
        commit="abc1234",
        programs=m.programs,
        made_with=m.made_with,
    )
    assert (tmp_path / "s2" / "fake.tar.gz").read_bytes() == first


def test_round_trip_through_the_seeder(tmp_path, gpu):
    out = ats.seed_autotune_cache(tmp_path / "c", seeds_dir=_seeds(tmp_path))
    back = {p.name: p.read_bytes() for p in (tmp_path / "c" / AUTOTUNE_DIR / SUBDIR).iterdir()}
    stamps = {n for n in back if n.startswith(".seeded-")}
    assert out.seeded == 3 and len(stamps) == 1
    assert {n: b for n, b in back.items() if n not in stamps} == ENTRIES


def test_pack_refuses_an_ambiguous_or_empty_source(tmp_path):
    two = _autotune_cache(tmp_path / "two")
    (two / AUTOTUNE_DIR / "fedcba9876543210").mkdir()
    kw = dict(
        name="x", device_kind=KIND, jax_version="1", jaxlib_version="1", commit="c", programs=(), made_with=""
    )
    with pytest.raises(
        ValueError, match=r"expected one subdirectory.*'0123456789abcdef', 'fedcba9876543210'"
    ):
        pack_seed(two, tmp_path / "o", **kw)
    with pytest.raises(ValueError, match=r"no \.pb entries"):
        pack_seed(two, tmp_path / "o", subdir="fedcba9876543210", **kw)


def test_a_manifest_with_missing_fields_names_them(tmp_path):
    (tmp_path / "bad.json").write_text(json.dumps({"device_kind": KIND}))
    with pytest.raises(ValueError, match=r"fields missing.*'jaxlib'"):
        shipped_seeds(tmp_path)


def test_seed_outcome_is_in_the_startup_record_and_table():
    from bar_policy.training.startup.breakdown import StartupTimer

    timer = StartupTimer()
    timer.autotune_seed = ats.SeedOutcome(seeded=868, source="h100.tar.gz", seconds=0.0123)
    rec = timer.finish(1.0)
    assert rec["autotune_seed"] == {
        "seeded": 868,
        "present": 0,
        "refused": 0,
        "source": "h100.tar.gz",
        "reason": "",
        "seconds": 0.012,
    }
    lines = StartupTimer.lines(rec)
    assert lines[-1].startswith("  autotune seed: 868 entries seeded, 0 already present, from h100.tar.gz")
    assert "autotune_seed" not in StartupTimer().finish(1.0)  # not tried: not recorded


def test_every_matching_seed_is_applied_and_a_bad_one_is_skipped(tmp_path, gpu, caplog):
    # Two seeds of the same device and jaxlib (e.g. two tasks' programs), sharing one fusion (bb): the
    # first seed copies aa, bb, cc (3); the second brings dd and finds bb there (1 seeded, 1 present).
    seeds = _seeds(tmp_path)
    pack_seed(
        _autotune_cache(tmp_path / "made2", {"bb.pb": b"\x0a\x01b", "dd.pb": b"\x0a\x01d"}),
        seeds,
        name="other",
        device_kind=KIND,
        jax_version="9.9.9",
        jaxlib_version="9.9.9",
        commit="abc1234",
        programs=("train step",),
        made_with="a test",
    )
    out = ats.seed_autotune_cache(tmp_path / "cache", seeds_dir=seeds)
    assert (out.seeded, out.present, out.reason) == (4, 1, "")
    assert out.source == "fake.tar.gz, other.tar.gz"  # the manifests in name order
    # The second archive tampered with: it is skipped with a warning, the first still applies.
    (seeds / "other.tar.gz").write_bytes(b"not the packed bytes")
    out = ats.seed_autotune_cache(tmp_path / "cache2", seeds_dir=seeds)
    assert (out.seeded, out.present, out.source) == (3, 0, "fake.tar.gz")
    assert "other.tar.gz does not match its manifest's sha256" in caplog.text
