"""Import ``mujoco.mjx`` without its notice that the optional Warp backend is not installed.

mujoco 3.x's ``mujoco/mjx/warp/__init__.py`` tries ``import warp`` (NVIDIA Warp: the optional backend of
``mjx`` with ``impl="warp"``, which this project does not use) and, when that fails, *prints* (to stdout:
no log record or warning a filter could catch) ``Failed to import warp: No module named 'warp'`` and
``Failed to import mujoco_warp: No module named 'warp'``. Every training start showed the two lines, and
they read like an error. Importing ``mujoco.mjx`` here first, with stdout captured, drops exactly those
two lines (a "Failed to import" with any other cause, such as a broken Warp install, is kept); anything
else printed during the import is passed on.

Imported for its effect, first, by ``bar_policy.envs``, which is what pulls ``mujoco.mjx`` into a training
run (``training.run`` imports it before brax).
"""

from __future__ import annotations

import contextlib
import io
import sys

__all__ = ["drop_warp_notice"]

_NOTICES = ("Failed to import warp: ", "Failed to import mujoco_warp: ")
_CAUSE = "No module named 'warp'"


def drop_warp_notice(text: str) -> str:
    """``text`` less the lines that only say Warp is not installed (``_NOTICES`` for ``_CAUSE``)."""
    return "".join(
        line
        for line in text.splitlines(keepends=True)
        if not (line.startswith(_NOTICES) and line.rstrip("\n").endswith(_CAUSE))
    )


def _import_mjx() -> None:
    if "mujoco.mjx" in sys.modules:
        return
    captured = io.StringIO()
    try:
        with contextlib.redirect_stdout(captured):
            import mujoco.mjx  # noqa: F401
    finally:
        sys.stdout.write(drop_warp_notice(captured.getvalue()))


_import_mjx()
