"""Prefetch of the last launch's executables: loaded on a thread during the imports and the env build.

On a warm start every program comes from the executable cache (``executable_cache``), but a program's key
needs its argument shapes, so the first loads wait for the env and the programs: the brax ``reset`` and
``rollout`` load on the main thread (the next program's key needs their output shapes), 4.07 s of an
H100's warm start. What a run will load is guessable much earlier. Its *launch key* (``launch_key``) hashes
what fixes its programs and is known before the env is built: the training config less the fields no program
reads, the package's content and the ``XLA_*``/``JAX_*``/``LIBTPU_*`` environment. The run whose programs
had keys names them in that launch's manifest (``executable_manifest``). The next run with the same launch
key reads the manifest right after ``jax.distributed`` is up and loads those entries on a daemon thread while
the main thread imports and builds the env: jaxlib's ``deserialize_and_load`` releases the GIL as it loads.

**Why it cannot serve a wrong program.** The manifest only picks which entries to start loading. Each is
checked as ``ExecutableCache.load`` checks one (the entry's format, the key written inside it), and
``ExecutableCache.load(key)`` takes a prefetched executable only for the key it computed for the program
(``Prefetch.take``), and only while that key's entry is still stored. A wrong guess (another env config, an
env passed in) costs a wasted load, never a wrong program; a failed load falls back to the normal path, which
logs and deletes a bad entry. Nothing is loaded when the executable cache will be off (``off_reason``, the
crashed-run marker) or when the manifest was written by other library versions or for other devices: the
normal path never loads such an entry (they are in its key), so neither does the prefetch.

**The thread imports nothing.** An entry's tree definitions name the classes of the program's arguments and
results (brax's, MJX's, flax's, this package's). Unpickling them on the thread would import those modules
while the main thread imports them too, and concurrent imports of a package with an import cycle can fail
(a partially initialised module). So the thread resolves only modules already imported and tries an entry
again once the main thread has imported what it names; jax's kernel tables (``_init_lazy_kernels``, which
imports scipy) are filled by the thread that takes the executable. A program the trainer needs before the
thread began loading it is loaded by the trainer as without a prefetch (``take`` cancels it), so the trainer
never waits for a load that has not started.
"""

from __future__ import annotations

import atexit
import hashlib
import io
import json
import logging
import pickle
import sys
import threading
import time
from collections.abc import Callable
from concurrent.futures import Future
from pathlib import Path
from typing import Any

from bar_policy.training import executable_cache as ec
from bar_policy.training import executable_key as ek
from bar_policy.training.config import config_to_dict
from bar_policy.training.executable_manifest import read_manifest

__all__ = ["LAUNCH_FORMAT", "Prefetch", "launch_key", "prefetch_line", "start_prefetch"]

LAUNCH_FORMAT = 1
"""What the launch key hashes; part of it, bumped when that changes."""

IMPORT_WAIT_S = 120.0
"""How long the thread waits for the main thread to import what an entry names before giving it up."""

_POLL_S = 0.05
_log = logging.getLogger(__name__)


def launch_key(cfg: Any) -> str:
    """SHA-256 of what fixes the run's programs and is known before its env is built.

    The training config less ``OUTSIDE_PROGRAMS`` (a rerun under another run name or ``--max-minutes``
    prefetches), ``package_hash()`` and the ``XLA_*``/``JAX_*``/``LIBTPU_*`` environment (filtered as the
    executable key filters it). Not jax's config: the trainer sets some of it after the prefetch starts.
    """
    doc = {
        "format": LAUNCH_FORMAT,
        "train": ec._program_fields(config_to_dict(cfg)),
        "package": ek.package_hash(),
        "environment": ek.flag_environment(),
    }
    return hashlib.sha256(json.dumps(doc, sort_keys=True, default=repr).encode()).hexdigest()


class _NotImportedError(Exception):
    """An entry names a class whose module the main thread has not imported (yet)."""

    def __init__(self, module: str) -> None:
        super().__init__(module)
        self.module = module


def _imported(module: str) -> bool:
    """Whether ``module`` is imported and done initialising (using it then imports nothing)."""
    mod = sys.modules.get(module)
    return mod is not None and not getattr(getattr(mod, "__spec__", None), "_initializing", False)


class _ImportedOnly(pickle.Unpickler):
    """Unpickles from modules already imported; raises ``_NotImportedError`` for any other."""

    def find_class(self, module: str, name: str) -> Any:
        if not _imported(module):
            raise _NotImportedError(module)
        return super().find_class(module, name)


class Prefetch:
    """Loads the entries of ``launch_key``'s manifest on a daemon thread; ``take`` hands each out once.

    The manifest is read here (absent or unreadable: nothing to do, no thread); the rest happens on the
    thread, in the manifest's order. The counts and seconds are what the start-up report prints
    (``as_dict``, ``prefetch_line``).

    Args:
        directory: the executable cache's directory (``<cache dir>/executables``).
        launch_key: this run's ``launch_key``.
        gate: run first on the thread; a non-empty answer is why nothing is loaded (``start_prefetch``'s
            asks jax for the backend, which would delay the main thread).
    """

    def __init__(self, directory: Path, launch_key: str, gate: Callable[[], str] | None = None) -> None:
        self.directory = Path(directory)
        self.launch_key = launch_key
        self.listed = self.loaded = self.used = self.failed = self.absent = self.preempted = self.gave_up = 0
        self.seconds = self.load_s = self.waited_s = 0.0
        self.reason = ""
        self._t0 = time.monotonic()
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._done = threading.Event()
        manifest = read_manifest(self.directory, launch_key)
        if manifest is None:
            self.reason = "no manifest for this launch"
            self._done.set()
            self._futures: dict[str, Future] = {}
            return
        self._futures = {key: Future() for key in dict.fromkeys(manifest["programs"].values())}
        self._all = dict(self._futures)
        self.listed = len(self._futures)
        # Imported here: the thread imports nothing. The versions are computed once per process anyway.
        from jax.experimental.serialize_executable import deserialize_and_load

        self._deserialize_and_load = deserialize_and_load
        self._libraries = ek.library_versions()
        args = (manifest, gate)
        self._thread = threading.Thread(target=self._work, args=args, name="executable-prefetch", daemon=True)
        atexit.register(self._shutdown)  # never end the interpreter in the middle of a load
        self._thread.start()

    def take(self, key: str) -> Any | None:
        """The executable prefetched for ``key`` (waits for its load), once; None when there is none.

        None when ``key`` was not listed, was taken already, failed to load or was not loaded (the caller
        loads it as without a prefetch), or its load had not started: that load is cancelled, so the caller
        never waits behind the thread. Never raises.
        """
        with self._lock:
            future = self._futures.pop(key, None)
        if future is None:
            return None
        if future.cancel():
            with self._lock:
                self.preempted += 1
            return None
        t = time.monotonic()
        try:
            compiled = future.result()
        except Exception:  # the thread resolves every future with a value; this is belt and braces
            compiled = None
        with self._lock:
            self.waited_s += time.monotonic() - t
            self.used += compiled is not None
        return compiled

    def wait(self, timeout: float | None = None) -> bool:
        """Wait until the thread is done; whether it is."""
        return self._done.wait(timeout)

    def _work(self, manifest: dict[str, Any], gate: Callable[[], str] | None) -> None:
        try:
            self.reason = (gate() if gate is not None else "") or self._foreign(manifest)
            if not self.reason:
                self._load_all()
        except Exception as e:  # never let the prefetch stop training: what was not loaded loads normally
            self.reason = f"{type(e).__name__}: {str(e)[:160]}"
        finally:
            for key in self._all:
                self._resolve(key, None)  # not loaded: the trainer loads it itself
            self.seconds = time.monotonic() - self._t0
            self._done.set()
            atexit.unregister(self._shutdown)

    def _foreign(self, manifest: dict[str, Any]) -> str:
        """Why the manifest's entries are not this process's to load ('' when they are)."""
        libraries = json.loads(json.dumps(self._libraries, default=repr))
        platform = json.loads(json.dumps(ek.platform(), default=repr))
        if manifest.get("libraries") != libraries:
            return "the last launch ran other library versions"
        if manifest.get("platform") != platform:
            return "the last launch ran on other devices"
        return ""

    def _load_all(self) -> None:
        """Load each listed entry, in order, once the modules it names are imported."""
        pending: dict[str, str | None] = dict.fromkeys(self._all)  # key -> the module it waits for
        deadline = time.monotonic() + IMPORT_WAIT_S
        while not self._stop.is_set():
            for key in [k for k in pending if self._all[k].cancelled()]:  # the trainer needed it first
                del pending[key]
            if not pending:
                return
            ready = next((k for k, m in pending.items() if m is None or _imported(m)), None)
            if ready is None:
                if time.monotonic() > deadline:
                    self.gave_up = len(pending)
                    return
                self._stop.wait(_POLL_S)
                continue
            try:
                entry = _ImportedOnly(io.BytesIO((self.directory / f"{ready}.bin").read_bytes())).load()
            except _NotImportedError as e:
                pending[ready] = e.module
                continue
            except Exception as e:  # absent (not stored), unreadable, corrupt
                entry = e
            del pending[ready]
            if self._all[ready].set_running_or_notify_cancel():  # from here on, take waits for it
                self._all[ready].set_result(self._load(ready, entry))

    def _load(self, key: str, entry: Any) -> Any | None:
        """``deserialize_and_load`` of an unpickled ``entry``, checked as ``ExecutableCache.load`` does."""
        try:
            if isinstance(entry, Exception):
                raise entry
            if not isinstance(entry, dict) or entry.get("format") != ec.FORMAT or entry.get("key") != key:
                raise ValueError("not an entry of this format for this key")
            t = time.monotonic()
            compiled = self._deserialize_and_load(entry["executable"], entry["in_tree"], entry["out_tree"])
            self.load_s += time.monotonic() - t
            self.loaded += 1
            return compiled
        except FileNotFoundError:
            self.absent += 1
        except Exception as e:  # the normal load of this key logs it and deletes the entry
            self.failed += 1
            _log.debug("executable prefetch: entry %s not loaded (%s: %s)", key, type(e).__name__, e)
        return None

    def _resolve(self, key: str, value: Any) -> None:
        """Settle ``key``'s future with ``value`` unless it is settled or cancelled."""
        future = self._all[key]
        if future.running() or (not future.done() and future.set_running_or_notify_cancel()):
            future.set_result(value)

    def _shutdown(self) -> None:
        """At exit: stop waiting for imports and let a load in progress end.

        A daemon thread stopped inside jaxlib's C++ at interpreter shutdown can abort the process.
        """
        self._stop.set()
        self._thread.join(timeout=60.0)

    def as_dict(self) -> dict[str, Any]:
        """What happened so far, for the run record (seconds rounded to ms)."""
        done = self._done.is_set()
        seconds = self.seconds if done else time.monotonic() - self._t0
        return {
            "launch_key": self.launch_key[:16],
            "listed": self.listed,
            "loaded": self.loaded,
            "used": self.used,
            "failed": self.failed,
            "not_stored": self.absent,
            "needed_first": self.preempted,
            "gave_up": self.gave_up,
            "reason": self.reason,
            "done": done,
            "seconds": round(seconds, 3),
            "load_s": round(self.load_s, 3),
            "waited_s": round(self.waited_s, 3),
        }

    def line(self) -> str:
        """The start-up report's line (``prefetch_line``)."""
        return prefetch_line(self.as_dict())


def prefetch_line(d: dict[str, Any]) -> str:
    """``executable prefetch: ...`` of an ``as_dict`` record: what was loaded and used, or why nothing."""
    if not d["listed"]:
        return f"executable prefetch: none ({d['reason']})"
    if d["reason"]:
        return f"executable prefetch: none of the last launch's {d['listed']} programs loaded ({d['reason']})"
    when = f"{d['seconds']:.2f} s" if d["done"] else f"still loading at {d['seconds']:.2f} s"
    text = (
        f"executable prefetch: {d['loaded']} of {d['listed']} programs of the last launch loaded on a thread "
        f"({when}), {d['used']} used ({d['waited_s']:.2f} s waited for)"
    )
    extra = {
        "failed": d["failed"],
        "not stored": d["not_stored"],
        "needed before the thread reached them": d["needed_first"],
        "given up (their classes never imported)": d["gave_up"],
    }
    return text + "".join(f", {n} {what}" for what, n in extra.items() if n)


def start_prefetch(cfg: Any, cache_dir: Path | None) -> Prefetch | None:
    """The run's prefetch (``Prefetch``), started; None when the executable cache is off whatever the backend.

    Call after ``jax.distributed`` is initialised. Whether the backend turns the cache off (a CPU without the
    opt-in, several processes) and the crashed-run marker are checked on the thread: asking jax for its
    backend starts it, which the main thread need not wait for.
    """
    if cache_dir is None or ec.off_reason(cfg, cache_dir, "gpu", 1):  # switched off, no compile cache...
        return None
    directory = Path(cache_dir) / "executables"

    def gate() -> str:
        import jax

        if ec.off_reason(cfg, cache_dir, jax.default_backend(), jax.process_count()):
            return "executable cache off"
        if ec._crashed_marker(directory).exists():
            return "executable cache off: a run crashed after loading from it"
        return ""

    return Prefetch(directory, launch_key(cfg), gate)
