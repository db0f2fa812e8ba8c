"""Drop the coordinator's own task-watch warnings from its stderr once its coordination service has stopped.

On a GPU host (jax 0.11.2) the GPU client of ``jax.distributed``'s process 0 keeps a watch call open on the
coordination service that the same process hosts. Stopping the service (the last step of
``training.distributed.shutdown_distributed``) ends that watch, and XLA's C++ logging writes one absl record
straight to fd 2 from a gRPC thread: ``WatchTasksAsync failed for task 0`` with ``UNAVAILABLE: Cancelling all
calls`` or ``CANCELLED`` while the stop runs, or, when the client calls again after it, ``UNAVAILABLE:
failed to connect to all addresses ... Connection refused`` (an H100 pair on 2026-11-27, after the run had
finished). Both say only that the service this process stopped is gone.

``install(process_id)`` sends this process's fd 2, from then until the process ends, through a child
process that runs this file as a script (standard library only, so it starts in tens of ms and imports
neither the package nor jax): it drops those records of this process's own task and forwards every other
byte unchanged and in order, so a later record or line, a real failure of another task included, still
reaches the terminal or log. The child ends when the last copy of the pipe's write end closes, that is
after the process itself has exited.

A record is its header line (``HEADER``: ``W1125 09:40:40.413933   676 file.cc:1605] message``) and the
lines after it up to the next header or up to its first empty line (gRPC's records end with one, so a
plain line written after a dropped record is kept).
"""

from __future__ import annotations

import logging
import os
import re
import subprocess
import sys
from collections.abc import Iterable, Iterator

__all__ = ["HEADER", "drop_own_watch_records", "install"]

HEADER = re.compile(r"^[IWEF]\d{4} \d\d:\d\d:\d\d\.\d+ ")
"""The first line of an absl log record."""

_log = logging.getLogger(__name__)

_ENDED = ("Cancelling all calls", "CANCELLED", "failed to connect to all addresses")
"""What the record of a watch ended by its own service's stop says (module docstring)."""


def _is_own_watch_end(header: str, process_id: int) -> bool:
    """Whether an absl header line is this process's task watch ended by its own service's stop."""
    return f"WatchTasksAsync failed for task {process_id}:" in header and any(s in header for s in _ENDED)


def drop_own_watch_records(lines: Iterable[str], process_id: int) -> Iterator[str]:
    """``lines`` (each with its newline) less the records that ``_is_own_watch_end`` names; lazily.

    Everything else (other records, other tasks' watches, lines before any record or after a dropped
    record's empty line) is yielded unchanged, so the filter can run on a stream.
    """
    drop = False
    for line in lines:
        if HEADER.match(line):
            drop = _is_own_watch_end(line, process_id)
        elif drop and not line.strip():
            drop = False  # the record's closing empty line: dropped with it, and the record is over
            continue
        if not drop:
            yield line


def install(process_id: int) -> bool:
    """Route this process's fd 2 through the filter child from now until the process ends.

    Returns False (stderr unchanged, a warning logged) if the child cannot start.
    """
    sys.stderr.flush()
    read_end, write_end = os.pipe()
    try:
        subprocess.Popen(
            [sys.executable, "-I", os.path.abspath(__file__), str(process_id)],
            stdin=read_end,
            stdout=2,
            close_fds=True,
        )
    except OSError as e:
        os.close(read_end)
        os.close(write_end)
        _log.warning("stderr filter not started (%s); gRPC shutdown warnings may follow", e)
        return False
    os.close(read_end)
    os.dup2(write_end, 2)
    os.close(write_end)
    return True


def _main(argv: list[str]) -> int:
    """The child: stdin -> stdout, line by line, flushed at once (binary, undecodable bytes kept)."""
    process_id = int(argv[1])
    out = sys.stdout.buffer
    lines = (raw.decode("utf-8", "surrogateescape") for raw in sys.stdin.buffer)
    for line in drop_own_watch_records(lines, process_id):
        out.write(line.encode("utf-8", "surrogateescape"))
        out.flush()
    return 0


if __name__ == "__main__":
    raise SystemExit(_main(sys.argv))
