"""Pack a compile cache's XLA autotune results as a seed the trainer ships (``training.startup.autotune``).

Run on the GPU machine right after a cold training run (empty compile cache), so the device kind and the
jax/jaxlib versions are read from the running jax; elsewhere give them as flags (``--device-kind``,
``--jax``, ``--jaxlib``). The commit defaults to ``git rev-parse --short HEAD``.

Usage::

    python3 train/ppo.py --compile-cache-dir /tmp/cold --no-export-onnx --max-minutes 1.8   # cold run
    python bench/autotune_seed.py --from /tmp/cold --name h100-80gb-hbm3-jaxlib-0.11.2

    # elsewhere, from a copied directory:
    python bench/autotune_seed.py --from /tmp/c2/cA --name h100-80gb-hbm3-jaxlib-0.11.2 \\
        --device-kind "NVIDIA H100 80GB HBM3" --jax 0.11.2 --jaxlib 0.11.2 --commit c61072c

Writes ``<out>/<name>.tar.gz`` and ``<out>/<name>.json`` (``--out`` defaults to the package's
``bar_policy/data/autotune``) and prints the manifest.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
from pathlib import Path

from bar_policy.training.startup.autotune import SEED_DIR, pack_seed

PROGRAMS = ("reset", "rollout", "update", "init", "evaluate")
"""The brax backend's programs (``startup.compiler.Compiler`` names; "epoch" in the seeds made before session
34)."""


def _commit() -> str:
    """``git rev-parse --short HEAD``, else ``BAR_POLICY_GIT_COMMIT`` (the GPU machine's copy has no .git)."""
    given = os.environ.get("BAR_POLICY_GIT_COMMIT", "")
    if given:
        return given[:7]
    try:
        cmd = ["git", "rev-parse", "--short", "HEAD"]
        out = subprocess.run(cmd, capture_output=True, text=True, check=True)
    except (OSError, subprocess.CalledProcessError):
        return "unknown"
    return out.stdout.strip()


def _running(flag: str | None, what: str) -> str:
    """``flag`` if given, else ``what`` read from the running jax."""
    if flag:
        return flag
    import jax
    import jaxlib

    if what == "device_kind":
        if jax.default_backend() != "gpu":
            raise SystemExit(f"no GPU here ({jax.default_backend()} backend): pass --device-kind")
        return jax.local_devices()[0].device_kind
    return jax.__version__ if what == "jax" else jaxlib.__version__


def main(argv: list[str] | None = None) -> int:
    """Parse the flags, pack, print the manifest."""
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--from", dest="source", required=True, help="compile cache dir, or its autotune dir")
    p.add_argument("--out", default=str(SEED_DIR), help="folder for the archive and manifest")
    p.add_argument("--name", required=True, help="file name stem, e.g. h100-80gb-hbm3-jaxlib-0.11.2")
    p.add_argument("--subdir", default="", help="XLA's subdirectory to pack ('' = the only one)")
    p.add_argument("--device-kind", default=None, help="default: the running GPU's device_kind")
    p.add_argument("--jax", default=None, help="default: the running jax's version")
    p.add_argument("--jaxlib", default=None, help="default: the running jaxlib's version")
    p.add_argument("--commit", default=None, help="default: git rev-parse --short HEAD")
    p.add_argument("--programs", nargs="+", default=list(PROGRAMS), help="the programs compiled")
    p.add_argument(
        "--made-with",
        default="python3 train/ppo.py (LiteReach, brax backend, gpu preset), empty compile cache",
        help="the command that compiled them",
    )
    a = p.parse_args(argv)
    try:
        manifest = pack_seed(
            Path(a.source),
            Path(a.out),
            name=a.name,
            device_kind=_running(a.device_kind, "device_kind"),
            jax_version=_running(a.jax, "jax"),
            jaxlib_version=_running(a.jaxlib, "jaxlib"),
            commit=a.commit or _commit(),
            programs=tuple(a.programs),
            made_with=a.made_with,
            subdir=a.subdir,
        )
    except ValueError as e:
        print(f"autotune_seed: error: {e}", file=sys.stderr)
        return 2
    print(manifest.to_json(), end="")
    print(f"wrote {Path(a.out) / manifest.archive} ({manifest.entries} entries)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
