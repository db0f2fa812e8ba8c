"""Lines that say what a start-up is doing while its programs trace, compile or load.

A cold start on a CPU spends minutes in XLA, and without these lines the terminal showed nothing but the
run header (and, past two minutes of one compile, XLA's own ``slow_operation_alarm`` "Very slow compile?",
which reads like a fault). ``Heartbeat`` keeps each program's stage (``STAGES``), set by
``compiler.Compiler`` as it works, and:

- prints one line when a program is done (``rollout: compiled in 35.1 s``, ``... loaded from the compile
  cache in 0.4 s``, ``... loaded from the executable cache in 0.2 s``);
- every ``interval_s`` while any program is unfinished, one line of what each unfinished program is doing
  and for how long: ``start-up 23 s: rollout compiling (XLA, 12 s), evaluate tracing (3 s); done: reset``.

Its lines start with ``start-up`` or ``  program`` so a reader (and tests/training/test_smoke_run.py) can
tell them from the progress lines. The printing thread stops once every program is done (``close``).
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

__all__ = ["STAGES", "Heartbeat"]

STAGES = ("queued", "tracing", "lowering", "compiling", "loading", "done", "failed")
"""A program's stages in order: ``compiling`` is XLA's compile (or jax's persistent-cache lookup and load:
which of the two is known only once it ends), ``loading`` an executable-cache load."""

_SAY_STAGE = {
    "queued": "queued",
    "tracing": "tracing",
    "lowering": "lowering",
    "compiling": "compiling (XLA)",
    "loading": "loading from the executable cache",
}


@dataclass
class _Stage:
    stage: str = "queued"
    since: float = 0.0


class Heartbeat:
    """Stages of a run's programs and the lines about them (module docstring).

    Args:
        say: prints one line (the run logger's ``print``).
        clock_origin: ``time.monotonic()`` the ``start-up N s`` figure counts from (the timer's origin).
        interval_s: seconds between two status lines while a program is unfinished.
    """

    def __init__(self, say: Callable[[str], None], clock_origin: float, interval_s: float = 5.0) -> None:
        self.say = say
        self.origin = clock_origin
        self.interval_s = interval_s
        self._stages: dict[str, _Stage] = {}
        self._lock = threading.Lock()
        self._wake = threading.Event()
        self._stop = False
        self._thread: threading.Thread | None = None

    def set(self, name: str, stage: str) -> None:
        """Program ``name`` entered ``stage`` (one of ``STAGES``); starts the printing thread at first use."""
        if stage not in STAGES:
            raise ValueError(f"unknown stage {stage!r}; valid: {list(STAGES)}")
        with self._lock:
            self._stages[name] = _Stage(stage, time.monotonic())
            if self._thread is None and not self._stop:
                self._thread = threading.Thread(target=self._loop, name="startup-heartbeat", daemon=True)
                self._thread.start()

    def finished(self, name: str, how: str) -> None:
        """Program ``name`` is ready: ``how`` it got so (``compiled in 35.1 s``); prints that line."""
        self.set(name, "done")
        self.say(f"  program {name}: {how}")
        if self.all_done():
            self._wake.set()

    def failed(self, name: str, error: BaseException) -> None:
        """Program ``name`` failed (its error is raised where the program is read)."""
        self.set(name, "failed")
        self.say(f"  program {name}: failed ({type(error).__name__})")

    def all_done(self) -> bool:
        """Whether every program known so far is done or failed."""
        with self._lock:
            return all(s.stage in ("done", "failed") for s in self._stages.values())

    def status_line(self, now: float | None = None) -> str | None:
        """The line about the unfinished programs (None when every one is done)."""
        now = time.monotonic() if now is None else now
        with self._lock:
            items = list(self._stages.items())
        busy = [
            f"{n} {_SAY_STAGE[s.stage]} ({now - s.since:.0f} s)"
            for n, s in items
            if s.stage not in ("done", "failed")
        ]
        if not busy:
            return None
        done = [n for n, s in items if s.stage == "done"]
        tail = f"; done: {', '.join(done)}" if done else ""
        return f"start-up {now - self.origin:.0f} s: {', '.join(busy)}{tail}"

    def close(self) -> None:
        """Stop the printing thread (its last line is not printed)."""
        self._stop = True
        self._wake.set()

    def _loop(self) -> None:
        while not self._stop:
            self._wake.wait(self.interval_s)
            self._wake.clear()
            if self._stop or self.all_done():
                return
            line = self.status_line()
            if line is not None:
                self.say(line)
