"""Pack the ``berkeley_humanoid`` meshes that MuJoCo Playground's Berkeley Humanoid env needs, for carrying.

Playground (``mujoco_playground._src.mjx_env.MENAGERIE_PATH``) reads the robot's meshes from
``<menagerie>/berkeley_humanoid/assets/*.stl`` and, when that folder is missing, clones mujoco_menagerie
at run time, which neither this machine nor the GPU machine can do. This script writes the meshes into one
``.tar.xz`` (about 4 MB; the meshes are about 27 MB unpacked, too much to carry next to ``.whl``) with
members ``berkeley_humanoid/assets/<name>.stl``; ``bench/peer_playground.py --menagerie ARCHIVE`` unpacks
it into a temporary folder and points Playground there. Nothing of it is committed (``.peer_assets/`` is
ignored).

Source: a git directory of the robot's upstream description (the fetch tool's snapshot of
``HybridRobotics/berkeley_humanoid_description``, ``meshs/*.stl``: the URDF package that Menagerie's
``berkeley_humanoid`` was derived from, same file names, BSD-3-Clause). Menagerie's own snapshot is over
the fetch tool's size limit. A snapshot leaves out files of 4 MiB and more, and ``torso.stl`` is one:
when it is missing, a box of the torso's collision-box size stands in for it. Every mesh of this robot is
visual only in Playground's model (class ``visual``: ``contype=0 conaffinity=0 density=0``; explicit
``<inertial>`` on every body), so the physics does not depend on the mesh bytes: collisions, masses and
inertias are the same with the stand-in. ``PROVENANCE.txt`` in the archive says which file is which.

    python bench/peer_assets.py --git-dir /work/.mirror/HybridRobotics+berkeley_humanoid_description/repo \\
        --out .peer_assets/berkeley_humanoid.tar.xz
"""

from __future__ import annotations

import argparse
import hashlib
import io
import struct
import subprocess
import tarfile
import time
from pathlib import Path

import numpy as np

MESHES = (
    "torso",
    *(f"{side}_{part}" for side in ("ll", "lr") for part in ("hr", "haa", "hfe", "kfe", "ffe", "faa")),
)
"""The 13 meshes of ``berkeley_humanoid_mjx_feetonly.xml`` (Playground 0.2.0), by name without ``.stl``."""

TORSO_BOX = ((0.02, 0.0, 0.12), (0.09, 0.125, 0.125))
"""The torso's collision box in Menagerie's ``berkeley_humanoid.xml``: centre and half sizes, m."""


def box_stl(center: tuple[float, float, float], half: tuple[float, float, float]) -> bytes:
    """A binary STL of an axis-aligned box: 12 triangles, outward normals, 684 bytes."""
    c, h = np.asarray(center, np.float32), np.asarray(half, np.float32)
    corners = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], np.float32) * h + c
    # Each face: 4 corner indices (counter-clockwise seen from outside) and its normal.
    faces = (
        ((0, 1, 3, 2), (-1, 0, 0)),
        ((4, 6, 7, 5), (1, 0, 0)),
        ((0, 4, 5, 1), (0, -1, 0)),
        ((2, 3, 7, 6), (0, 1, 0)),
        ((0, 2, 6, 4), (0, 0, -1)),
        ((1, 5, 7, 3), (0, 0, 1)),
    )
    out = io.BytesIO()
    out.write(b"box stand-in for berkeley_humanoid torso.stl".ljust(80, b" "))
    out.write(struct.pack("<I", 12))
    for (a, b, cc, d), n in faces:
        for tri in ((a, b, cc), (a, cc, d)):
            out.write(struct.pack("<3f", *n))
            for i in tri:
                out.write(struct.pack("<3f", *corners[i]))
            out.write(b"\0\0")
    return out.getvalue()


def _git_blob(git_dir: Path, path: str) -> bytes | None:
    """The bytes of ``HEAD:path`` in a bare git directory, or None when the snapshot lacks the file."""
    res = subprocess.run(
        ["git", f"--git-dir={git_dir}", "cat-file", "blob", f"HEAD:{path}"], capture_output=True
    )
    return res.stdout if res.returncode == 0 else None


def _git_head(git_dir: Path) -> str:
    res = subprocess.run(["git", f"--git-dir={git_dir}", "rev-parse", "HEAD"], capture_output=True, text=True)
    return res.stdout.strip() or "unknown"


def build(git_dir: Path, out: Path) -> list[str]:
    """Write the archive; returns one provenance line per mesh."""
    files: dict[str, bytes] = {}
    lines = [
        "berkeley_humanoid meshes for MuJoCo Playground's BerkeleyHumanoidJoystick* envs "
        "(bench/peer_assets.py)",
        f"source: {git_dir} (HybridRobotics/berkeley_humanoid_description) at commit {_git_head(git_dir)}, "
        "meshs/*.stl, BSD-3-Clause (its package.xml)",
        "every mesh is a visual-only geom in Playground's model: the physics does not depend on these bytes",
        "",
    ]
    for name in MESHES:
        blob = _git_blob(git_dir, f"meshs/{name}.stl")
        if blob is None:
            if name != "torso":
                raise SystemExit(f"meshs/{name}.stl is missing from {git_dir}; only torso.stl has a stand-in")
            blob = box_stl(*TORSO_BOX)
            origin = "STAND-IN: box of the torso collision box (the snapshot lacks files >= 4 MiB)"
        else:
            origin = "upstream"
        files[f"berkeley_humanoid/assets/{name}.stl"] = blob
        lines.append(
            f"{name}.stl  {len(blob):>9} bytes  sha256 {hashlib.sha256(blob).hexdigest()[:16]}  {origin}"
        )
    files["berkeley_humanoid/PROVENANCE.txt"] = ("\n".join(lines) + "\n").encode()
    out.parent.mkdir(parents=True, exist_ok=True)
    with tarfile.open(out, "w:xz") as tf:
        for name, data in files.items():
            info = tarfile.TarInfo(name)
            info.size, info.mtime = len(data), int(time.time())
            tf.addfile(info, io.BytesIO(data))
    return lines


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument(
        "--git-dir", required=True, type=Path, help="bare git dir of berkeley_humanoid_description"
    )
    p.add_argument("--out", default=Path(".peer_assets/berkeley_humanoid.tar.xz"), type=Path)
    args = p.parse_args(argv)
    for line in build(args.git_dir, args.out):
        print(line)
    print(f"wrote {args.out} ({args.out.stat().st_size / 1e6:.1f} MB)")


if __name__ == "__main__":
    main()
