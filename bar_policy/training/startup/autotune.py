"""XLA's GPU autotuning results, shipped with the package and seeded into the compile cache at start-up.

On a GPU, XLA times several implementations (tilings, cuBLAS or Triton) of each fusion while it compiles,
and keeps the fastest. jax points XLA's *per-fusion autotune cache* at
``<compile cache dir>/xla_gpu_per_fusion_autotune_cache_dir`` (jax config
``jax_persistent_cache_enable_xla_caches``, default ``"xla_gpu_per_fusion_autotune_cache_dir"``): one small
``.pb`` file per autotuned fusion, in a subdirectory per device and XLA version ("Persisted autotuning"
in XLA's docs). A cold start on an H100 (LiteReach, ``gpu`` preset, 2026-11-27, commit c61072c) spent about
30 s of its 99 s before the first evaluation autotuning: with a previous run's autotune directory copied
into an empty compile cache the first evaluation came at 68.6 s instead of 99.4 s (epoch compile 42.7 s
instead of 71 s, evaluate 31.2 s instead of 54 s) and training ran at the same speed (143.3k vs 144.7k
env steps/s, noise).

This module ships such directories (``bar_policy/data/autotune/<name>.tar.gz``, each with a ``<name>.json``
manifest naming the device kind, the jax/jaxlib versions and the commit it was made with) and, at start-up,
copies every one matching this machine into the compile cache (``seed_autotune_cache``; one seed per preset
whose programs were compiled cold: reach (the gpu preset at batch 512 and 2 ms, and at batch 256 and 4 ms),
rsl, track and piano for the H100, and reach's gpu preset (2026-11-28, remade on 2026-11-29 with its TF32
update), rsl and track (2026-11-28) and piano (2026-11-28) for the H200, all with jaxlib 0.11.2; the trainer
runs it on a thread, ``seed_in_background``). It never overwrites a file already there (XLA's own results win)
and counts what it skipped.

**Why a seed cannot give a wrong program.** An entry's file name and content hold the key of one fusion
(its HLO, hashed, and the device); XLA looks an entry up only for a fusion with that key and ignores the
rest. A seed therefore only lets XLA skip timing a fusion it has already timed on the same device kind and
XLA version; the program computes the same thing whichever implementation it picks. Neither jax's
persistent cache key nor the executable cache's key (``executable_key``) reads the autotune directory, so
both keep their meaning; the shipped archive is a file under ``bar_policy/``, so changing it changes
``executable_key.package_hash`` once (a miss, never a wrong hit).

``bench/autotune_seed.py`` packs a seed from a compile cache (``pack_seed``); ``--no-autotune-seed``
(``TrainConfig.autotune_seed``) turns seeding off.
"""

from __future__ import annotations

import gzip
import hashlib
import io
import json
import logging
import os
import tarfile
import tempfile
import time
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from bar_policy._files import PACKAGE_ROOT

__all__ = [
    "AUTOTUNE_DIR",
    "SEED_DIR",
    "SeedManifest",
    "SeedOutcome",
    "local_platform",
    "pack_seed",
    "seed_autotune_cache",
    "seed_in_background",
    "shipped_seeds",
]

AUTOTUNE_DIR = "xla_gpu_per_fusion_autotune_cache_dir"
"""The per-fusion cache's folder under jax's compile cache dir (and its name in jax's config flag)."""

SEED_DIR = PACKAGE_ROOT / "data" / "autotune"
"""Where the shipped seeds live: ``<name>.json`` manifests next to their ``.tar.gz`` archives."""

FORMAT = 1
"""Layout of a manifest and its archive (``<subdir>/<entry>.pb`` members)."""

_log = logging.getLogger(__name__)


@dataclass(frozen=True, kw_only=True)
class SeedManifest:
    """What a shipped seed holds and where it came from (the ``.json`` next to its archive)."""

    format: int = FORMAT
    device_kind: str
    """``jax.Device.device_kind`` it was made on, e.g. ``NVIDIA H100 80GB HBM3``; must match to seed."""
    jax: str
    """jax version it was made with."""
    jaxlib: str
    """jaxlib version it was made with; must match to seed (XLA's autotune keys change between versions)."""
    commit: str
    """bar_policy commit whose programs were compiled."""
    programs: tuple[str, ...]
    """The compiled programs whose fusions it holds (a description; any program may use an entry)."""
    made_with: str
    """The command (env, backend, preset) that compiled them."""
    subdir: str
    """XLA's subdirectory under ``AUTOTUNE_DIR`` (a device/version hash); the archive's top folder."""
    entries: int
    """Number of ``.pb`` files in the archive."""
    archive: str
    """File name of the archive, next to this manifest."""
    sha256: str
    """SHA-256 of the archive's bytes."""

    def __post_init__(self) -> None:
        if self.format != FORMAT:
            raise ValueError(f"autotune seed manifest format {self.format}, this code reads {FORMAT}")
        if not self.subdir or "/" in self.subdir or self.subdir.startswith("."):
            raise ValueError(f"autotune seed subdir must be one plain folder name, got {self.subdir!r}")

    @classmethod
    def read(cls, path: Path) -> SeedManifest:
        """Parse a manifest file; ``ValueError`` naming the missing or unknown fields."""
        data = json.loads(path.read_text())
        names = set(cls.__dataclass_fields__)
        if set(data) != names:
            raise ValueError(
                f"{path}: fields missing {sorted(names - set(data))}, unknown {sorted(set(data) - names)}"
            )
        return cls(**{**data, "programs": tuple(data["programs"])})

    def to_json(self) -> str:
        """The manifest as written next to the archive (sorted keys, one field a line)."""
        return json.dumps({**asdict(self), "programs": list(self.programs)}, indent=1, sort_keys=True) + "\n"


@dataclass
class SeedOutcome:
    """What ``seed_autotune_cache`` did: entries copied and already present, or why it did nothing."""

    seeded: int = 0
    """Entries copied into the cache."""
    present: int = 0
    """Entries skipped because a file of that name was already there (never overwritten)."""
    refused: int = 0
    """Archive members that are not ``<subdir>/<name>.pb`` regular files (not copied)."""
    source: str = ""
    """The archive seeded from (file name), '' when none."""
    reason: str = ""
    """Why nothing was seeded ('' when a seed was applied)."""
    seconds: float = 0.0
    """Wall time of the decision and the copy, s."""

    def line(self) -> str:
        """The one log line: ``autotune seed: ...``."""
        if self.reason:
            return f"autotune seed: not used ({self.reason})"
        refused = f", {self.refused} malformed members refused" if self.refused else ""
        return (
            f"autotune seed: {self.seeded} entries seeded, {self.present} already present{refused}, "
            f"from {self.source} ({self.seconds:.2f} s; --no-autotune-seed turns it off)"
        )

    def as_dict(self) -> dict[str, Any]:
        """JSON form for the run record (seconds rounded to ms)."""
        return {**asdict(self), "seconds": round(self.seconds, 3)}


def local_platform() -> tuple[str, str, str]:
    """``(backend, device kind of the first local device, jaxlib version)`` of this process."""
    import jax
    import jaxlib

    return jax.default_backend(), jax.local_devices()[0].device_kind, jaxlib.__version__


def _xla_caches_flag() -> str:
    import jax

    return str(jax.config.jax_persistent_cache_enable_xla_caches or "")


def shipped_seeds(directory: Path = SEED_DIR) -> list[tuple[Path, SeedManifest]]:
    """``(manifest path, manifest)`` of every seed in ``directory``, sorted by file name."""
    return [(p, SeedManifest.read(p)) for p in sorted(Path(directory).glob("*.json"))]


def seed_autotune_cache(
    cache_dir: Path | None, *, enabled: bool = True, seeds_dir: Path = SEED_DIR
) -> SeedOutcome:
    """Copy every shipped seed matching this machine into ``<cache_dir>/AUTOTUNE_DIR/<subdir>/``.

    Does nothing (and says why in ``reason``) when switched off, without a compile cache, on a backend
    other than a GPU, when jax's ``jax_persistent_cache_enable_xla_caches`` leaves the per-fusion cache
    out, or when no shipped manifest has this device kind and jaxlib version. Call after
    ``jax.distributed`` is initialised: it asks jax for the backend. Never raises for a bad seed: an
    unreadable manifest or archive is the ``reason`` and training goes on without it.

    Args:
        cache_dir: jax's compile cache directory (``compile_cache.configure_compile_cache``), None when off.
        enabled: ``TrainConfig.autotune_seed``.
        seeds_dir: where the manifests and archives are (the package's ``autotune/`` folder).
    """
    t0 = time.monotonic()
    out = _seed(cache_dir, enabled, Path(seeds_dir))
    out.seconds = time.monotonic() - t0
    if out.refused:
        _log.warning("autotune seed: %d malformed members of %s refused", out.refused, out.source)
    return out


def seed_in_background(
    cache_dir: Path | None, *, enabled: bool = True, seeds_dir: Path = SEED_DIR
) -> Future[SeedOutcome]:
    """``seed_autotune_cache`` on a thread of its own; wait for its result before compiling anything.

    The copy (about 2 s for 2,729 small files on the H100 machine, 2026-11-27) then overlaps the imports
    and the env build. A fusion that XLA times before its entry is copied keeps XLA's own file
    (``_write_new`` never overwrites), so an early compile is never served a half-written entry.
    """
    pool = ThreadPoolExecutor(1, thread_name_prefix="autotune-seed")
    try:
        return pool.submit(seed_autotune_cache, cache_dir, enabled=enabled, seeds_dir=seeds_dir)
    finally:
        pool.shutdown(wait=False)


def _seed(cache_dir: Path | None, enabled: bool, seeds_dir: Path) -> SeedOutcome:
    if not enabled:
        return SeedOutcome(reason="switched off, --no-autotune-seed")
    if cache_dir is None:
        return SeedOutcome(reason="compile cache off")
    backend, kind, jaxlib_version = local_platform()
    if backend != "gpu":
        return SeedOutcome(reason=f"{backend.upper()} backend; XLA autotunes on GPUs only")
    flag = _xla_caches_flag()
    if flag != "all" and AUTOTUNE_DIR not in flag:
        return SeedOutcome(
            reason=f"jax_persistent_cache_enable_xla_caches={flag!r} leaves out {AUTOTUNE_DIR}"
        )
    try:
        seeds = shipped_seeds(seeds_dir)
    except (OSError, ValueError, TypeError) as e:
        return SeedOutcome(reason=f"unreadable manifest in {seeds_dir}: {type(e).__name__}: {e}")
    same_kind = [(p, m) for p, m in seeds if m.device_kind == kind]
    match = [(p, m) for p, m in same_kind if m.jaxlib == jaxlib_version]
    if not match:
        if same_kind:
            made = sorted({m.jaxlib for _, m in same_kind})
            return SeedOutcome(
                reason=f"seeds for {kind!r} were made with jaxlib {made}, this is {jaxlib_version}"
            )
        kinds = sorted({m.device_kind for _, m in seeds})
        return SeedOutcome(reason=f"no seed for device {kind!r}; shipped: {kinds}")
    # Every matching seed is applied (one per task or backend whose programs were compiled cold): entries
    # of one fusion are the same file name in every seed, and the first copy wins.
    total, failures = SeedOutcome(), []
    for path, manifest in match:
        try:
            blob = (path.parent / manifest.archive).read_bytes()  # verified, then extracted from these bytes
            if hashlib.sha256(blob).hexdigest() != manifest.sha256:
                failures.append(f"{manifest.archive} does not match its manifest's sha256")
                continue
            one = _extract(blob, manifest, Path(cache_dir) / AUTOTUNE_DIR)
        except (OSError, tarfile.TarError) as e:
            failures.append(f"{manifest.archive} unreadable: {type(e).__name__}: {e}")
            continue
        total.seeded += one.seeded
        total.present += one.present
        total.refused += one.refused
        total.source = f"{total.source}, {one.source}" if total.source else one.source
    for failure in failures:
        _log.warning("autotune seed: %s; not used", failure)
    if not total.source:
        return SeedOutcome(reason="; ".join(failures))
    return total


def _extract(blob: bytes, manifest: SeedManifest, autotune_dir: Path) -> SeedOutcome:
    """Copy the archive ``blob``'s ``<subdir>/<name>.pb`` members into ``autotune_dir``, never overwriting.

    An archive copied whole leaves a stamp ``.seeded-<sha256>`` in its folder, so a later start reads
    nothing (reading every member again took 0.6 s of Python on an H200 host, 2026-11-29, beside the main
    thread's start). XLA opens entries by key only, so the stamp is never read as one; removing the folder
    removes the stamp.
    """
    out = SeedOutcome(source=manifest.archive)
    target = autotune_dir / manifest.subdir
    stamp = target / f".seeded-{manifest.sha256}"
    if stamp.exists():
        out.present = manifest.entries
        return out
    target.mkdir(parents=True, exist_ok=True)
    with tarfile.open(fileobj=io.BytesIO(blob), mode="r:gz") as tar:
        for member in tar:
            if member.isdir() and member.name.rstrip("/") == manifest.subdir:
                continue
            folder, _, name = member.name.partition("/")
            ok = member.isfile() and folder == manifest.subdir and name.endswith(".pb")
            if not ok or "/" in name or name.startswith("."):
                out.refused += 1
                continue
            f = tar.extractfile(member)
            data = f.read() if f is not None else b""
            if _write_new(target / name, data):
                out.seeded += 1
            else:
                out.present += 1
    if not out.refused:
        _write_new(stamp, b"")
    return out


def _write_new(path: Path, data: bytes) -> bool:
    """Write ``path`` unless it exists (False when it was there); atomic and never overwriting.

    The bytes go to a temporary file that is then hard-linked to ``path``: the link fails if XLA (or
    another process) created ``path`` in the meantime, and a reader never sees half a file.
    """
    if path.exists():
        return False
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}", suffix=".partial", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
        try:
            os.link(tmp, path)
        except FileExistsError:
            return False
        return True
    finally:
        Path(tmp).unlink(missing_ok=True)


def pack_seed(
    source: Path,
    out_dir: Path,
    *,
    name: str,
    device_kind: str,
    jax_version: str,
    jaxlib_version: str,
    commit: str,
    programs: tuple[str, ...],
    made_with: str,
    subdir: str = "",
) -> SeedManifest:
    """Pack a per-fusion autotune directory as ``out_dir/<name>.tar.gz`` with its ``<name>.json`` manifest.

    The archive is reproducible: members sorted, owner and times zeroed, gzip without a time stamp.

    Args:
        source: a compile cache dir (holding ``AUTOTUNE_DIR``) or the ``AUTOTUNE_DIR`` folder itself.
        out_dir: where the two files go (created).
        name: their file name stem, e.g. ``h100-80gb-hbm3-jaxlib-0.11.2``.
        device_kind: the manifest's ``device_kind`` (``jax.Device.device_kind`` where it was made).
        jax_version: the jax version it was made with.
        jaxlib_version: the jaxlib version it was made with.
        commit: the bar_policy commit whose programs were compiled.
        programs: the compiled programs' names.
        made_with: the command that compiled them.
        subdir: XLA's subdirectory to pack; '' = the only one there (``ValueError`` naming them if several).
    """
    source = Path(source)
    root = source / AUTOTUNE_DIR if (source / AUTOTUNE_DIR).is_dir() else source
    subdirs = sorted(p.name for p in root.iterdir() if p.is_dir()) if root.is_dir() else []
    if not subdir:
        if len(subdirs) != 1:
            raise ValueError(f"{root}: expected one subdirectory to pack, found {subdirs}; pass subdir")
        subdir = subdirs[0]
    elif subdir not in subdirs:
        raise ValueError(f"{root}: no subdirectory {subdir!r}; found {subdirs}")
    files = sorted(p for p in (root / subdir).iterdir() if p.is_file() and p.suffix == ".pb")
    if not files:
        raise ValueError(f"{root / subdir}: no .pb entries to pack")
    buf = io.BytesIO()
    with (
        gzip.GzipFile(fileobj=buf, mode="wb", mtime=0, compresslevel=9) as gz,
        tarfile.open(fileobj=gz, mode="w", format=tarfile.PAX_FORMAT) as tar,
    ):
        for p in files:
            data = p.read_bytes()
            info = tarfile.TarInfo(f"{subdir}/{p.name}")
            info.size, info.mode, info.mtime = len(data), 0o644, 0
            tar.addfile(info, io.BytesIO(data))
    blob = buf.getvalue()
    manifest = SeedManifest(
        device_kind=device_kind,
        jax=jax_version,
        jaxlib=jaxlib_version,
        commit=commit,
        programs=tuple(programs),
        made_with=made_with,
        subdir=subdir,
        entries=len(files),
        archive=f"{name}.tar.gz",
        sha256=hashlib.sha256(blob).hexdigest(),
    )
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    (out_dir / manifest.archive).write_bytes(blob)
    (out_dir / f"{name}.json").write_text(manifest.to_json())
    return manifest
