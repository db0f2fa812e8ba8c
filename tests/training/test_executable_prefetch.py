"""The prefetch of the last launch's executables: loaded on a thread, served only for the exact key asked.

Toy programs through the trainer's own ``Compiler`` (the patterns of ``test_executable_cache.py``): a cache
with a launch key writes the manifest; a second "run" (a fresh cache and ``Prefetch`` on the same directory)
is served its program from the prefetch, bit for bit what a fresh compile computes; another launch key
prefetches nothing; an executable prefetched for one key is never returned for another; a corrupt entry
falls back to the normal load (logged, deleted, replaced); the thread imports nothing.
"""

from __future__ import annotations

import json
import logging
import os
import sys
import time
from pathlib import Path

import jax
import numpy as np
import pytest
from test_executable_cache import CONTEXT, SMALL_BRAX, Toy, X, _entries, _run, _startup

from bar_policy.training import executable_cache as ec
from bar_policy.training import executable_prefetch as ep
from bar_policy.training.config import apply_overrides, preset
from bar_policy.training.executable_cache import ExecutableCache
from bar_policy.training.executable_manifest import manifest_path, read_manifest
from bar_policy.training.executable_prefetch import Prefetch, launch_key, prefetch_line, start_prefetch
from bar_policy.training.startup import Compiler, StartupTimer

LAUNCH = "1" * 64


@pytest.fixture(autouse=True)
def no_persistent_cache(restore_cache_config):
    """Every toy program compiles afresh (as in test_executable_cache.py: an executable jax's persistent
    cache served is not stored)."""
    from jax.experimental.compilation_cache import compilation_cache as cc

    jax.config.update("jax_enable_compilation_cache", False)
    cc.reset_cache()
    yield
    cc.reset_cache()


def _prefetched(directory: Path, launch: str = LAUNCH) -> Prefetch:
    """A ``Prefetch`` of ``launch`` on ``directory``, its thread done."""
    pf = Prefetch(directory, launch)
    assert pf.wait(60)
    return pf


def _second_run(directory: Path, toy: Toy, context: dict = CONTEXT, launch: str = LAUNCH) -> tuple:
    """A rerun: a fresh cache and prefetch on ``directory`` (the thread done first), the program submitted
    through a ``Compiler``; returns ``(outputs, ProgramTimes, Prefetch)``."""
    pf = _prefetched(directory, launch)
    cache = ExecutableCache(directory, dict(context), launch_key=launch)
    cache.prefetch = pf
    out, times = _run(cache, toy)
    return out, times, pf


def test_a_cache_with_a_launch_key_names_each_programs_key_in_its_manifest(tmp_path):
    cache = ExecutableCache(tmp_path, CONTEXT, launch_key=LAUNCH)
    a, inputs = cache.key("a", jax.jit(Toy().program), (X,))
    b, _ = cache.key("b", jax.jit(Toy().program), (X[:2],))
    path = manifest_path(tmp_path, LAUNCH)
    doc = json.loads(path.read_text())
    assert list(doc["programs"].items()) == [("a", a), ("b", b)]  # in the order they were keyed
    assert doc["libraries"] == inputs["libraries"] and doc["platform"] == inputs["platform"]
    written = path.stat().st_mtime_ns
    time.sleep(0.01)
    assert cache.key("a", jax.jit(Toy().program), (X,))[0] == a
    assert path.stat().st_mtime_ns == written  # a key already named: no write
    c, _ = cache.key("a", jax.jit(Toy().program), (X[:3],))  # a program's new key replaces the old one
    assert read_manifest(tmp_path, LAUNCH)["programs"] == {"a": c, "b": b}
    # Without a launch key (the default) no manifest is written.
    ExecutableCache(tmp_path / "plain", CONTEXT).key("a", jax.jit(Toy().program), (X,))
    assert not list((tmp_path / "plain").glob("launch-*"))


def test_a_rerun_is_served_its_program_from_the_prefetch_bit_for_bit(tmp_path):
    toy = Toy()
    fresh, first = _run(ExecutableCache(tmp_path, CONTEXT, launch_key=LAUNCH), toy)
    assert first.executable == "stored" and toy.traces == 1
    (key,) = (p.stem for p in tmp_path.glob("*.bin"))

    out, times, pf = _second_run(tmp_path, toy)
    assert (pf.listed, pf.loaded, pf.used, pf.failed) == (1, 1, 1, 0)  # it came from the prefetch
    assert times.executable == "hit" and toy.traces == 1  # not traced again
    for k in fresh:
        np.testing.assert_array_equal(out[k], fresh[k])
    # The same bookkeeping as a normal load: the crash guard lists it.
    assert json.loads((tmp_path / f"inflight-{os.getpid()}.json").read_text()) == [key]
    ExecutableCache(tmp_path, CONTEXT).confirm()
    assert pf.take(key) is None  # handed out once
    line = pf.line()
    assert line.startswith("executable prefetch: 1 of 1 programs of the last launch loaded on a thread (")
    assert ", 1 used (" in line and "failed" not in line


def test_another_launch_key_prefetches_nothing(tmp_path):
    _run(ExecutableCache(tmp_path, CONTEXT, launch_key=LAUNCH), Toy())
    toy = Toy()
    _, times, pf = _second_run(tmp_path, toy, launch="2" * 64)
    assert (pf.listed, pf.loaded, pf.reason) == (0, 0, "no manifest for this launch")
    assert times.executable == "hit" and toy.traces == 0  # loaded the normal way
    assert pf.line() == "executable prefetch: none (no manifest for this launch)"


def test_an_executable_prefetched_for_one_key_is_never_served_for_another(tmp_path):
    """The manifest names the 0.3 program's key; the rerun's config makes the 0.6 program (same launch key,
    another real key). It is compiled (or loaded under its own key), never served the 0.3 program."""
    old, _ = _run(ExecutableCache(tmp_path, CONTEXT, launch_key=LAUNCH), Toy(0.3))
    (old_key,) = (p.stem for p in tmp_path.glob("*.bin"))
    changed = {**CONTEXT, "env": {"gain": 0.6}}
    expected, _ = _run(None, Toy(0.6))

    toy = Toy(0.6)
    out, times, pf = _second_run(tmp_path, toy, changed)
    assert pf.loaded == 1 and pf.used == 0  # loaded, but for a key nobody asked for
    assert times.executable == "stored" and toy.traces == 1  # a miss: traced and compiled
    np.testing.assert_array_equal(out["y"], expected["y"])
    assert not np.allclose(out["y"], old["y"])
    new_key = read_manifest(tmp_path, LAUNCH)["programs"]["toy"]
    assert new_key != old_key and {f"{new_key}.bin", f"{old_key}.bin"} == _entries(tmp_path)

    # Both entries stored, the manifest pointing at the old one: the new key loads its own entry.
    doc = json.loads(manifest_path(tmp_path, LAUNCH).read_text())
    manifest_path(tmp_path, LAUNCH).write_text(json.dumps({**doc, "programs": {"toy": old_key}}))
    pf = _prefetched(tmp_path)
    assert pf.loaded == 1, pf.reason
    cache = ExecutableCache(tmp_path, changed, launch_key="")
    cache.prefetch = pf
    loaded = cache.load(new_key, "toy")
    assert loaded is not None and pf.used == 0
    np.testing.assert_array_equal(np.asarray(loaded(X)["y"]), expected["y"])
    assert pf.take(new_key) is None and pf.take(old_key) is not None  # only ever for its own key
    cache.confirm()


def test_a_corrupt_listed_entry_falls_back_to_the_normal_load(tmp_path, caplog):
    fresh, _ = _run(ExecutableCache(tmp_path, CONTEXT, launch_key=LAUNCH), Toy())
    (entry,) = tmp_path.glob("*.bin")
    entry.write_bytes(entry.read_bytes()[:100])  # truncated
    toy = Toy()
    with caplog.at_level(logging.WARNING, logger=ec.__name__):
        out, times, pf = _second_run(tmp_path, toy)
    assert (pf.listed, pf.loaded, pf.failed, pf.used) == (1, 0, 1, 0)
    (line,) = [r.getMessage() for r in caplog.records if r.name == ec.__name__]
    assert entry.name in line and "compiling afresh" in line  # logged and deleted as without a prefetch
    assert toy.traces == 1 and times.executable == "bad entry replaced, stored"
    np.testing.assert_array_equal(out["y"], fresh["y"])
    assert "1 failed" in pf.line()
    _, again, pf = _second_run(tmp_path, toy)  # the replacement is prefetched next time
    assert again.executable == "hit" and pf.used == 1 and toy.traces == 1


def test_an_entry_not_stored_is_counted_and_loads_nothing(tmp_path):
    """A program keyed but not stored (jax's persistent cache served it) is listed; a name that is not a
    key never becomes a file name."""
    key, _ = ExecutableCache(tmp_path, CONTEXT, launch_key=LAUNCH).key("toy", jax.jit(Toy().program), (X,))
    doc = json.loads(manifest_path(tmp_path, LAUNCH).read_text())
    doc["programs"]["bad"] = "../x"
    manifest_path(tmp_path, LAUNCH).write_text(json.dumps(doc))
    pf = _prefetched(tmp_path)
    assert (pf.listed, pf.loaded, pf.absent, pf.failed) == (1, 0, 1, 0), pf.as_dict()
    assert pf.take(key) is None
    assert "1 not stored" in pf.line()


def test_launch_key_ignores_fields_no_program_reads(monkeypatch):
    cfg = preset("tiny")
    key = launch_key(cfg)
    assert launch_key(cfg) == key and len(key) == 64
    for outside in ("max_minutes=1.0", "run_name=other", "runs_dir=/elsewhere", "eval.initial=off"):
        assert launch_key(apply_overrides(cfg, [outside])) == key, outside
    assert launch_key(apply_overrides(cfg, ["ppo.learning_rate=0.000123"])) != key
    assert launch_key(apply_overrides(cfg, ["seed=7"])) != key
    monkeypatch.setenv("XLA_FLAGS", "--xla_some_flag_for_this_test")
    assert launch_key(cfg) != key  # the XLA/JAX/LIBTPU environment is in it
    monkeypatch.setenv("JAX_COMPILATION_CACHE_DIR", "/another/cache")
    monkeypatch.delenv("XLA_FLAGS")
    assert launch_key(cfg) == key  # as in the executable key: the cache's own variable is not


def test_start_prefetch_follows_the_executable_cache_switch(tmp_path, monkeypatch):
    cfg = preset("tiny")
    assert start_prefetch(cfg, None) is None  # --no-compile-cache
    assert start_prefetch(apply_overrides(cfg, ["executable_cache=False"]), tmp_path) is None
    assert start_prefetch(apply_overrides(cfg, ["distributed.num_processes=2"]), tmp_path) is None

    directory = tmp_path / "executables"
    _run(ExecutableCache(directory, CONTEXT, launch_key=launch_key(cfg)), Toy())
    monkeypatch.delenv(ec.CPU_ENV, raising=False)
    pf = start_prefetch(cfg, tmp_path)  # the backend is asked on the thread: a CPU without the opt-in
    assert pf is not None and pf.wait(60)
    assert (pf.listed, pf.loaded, pf.reason) == (1, 0, "executable cache off")
    assert (
        pf.line() == "executable prefetch: none of the last launch's 1 programs loaded (executable cache off)"
    )
    monkeypatch.setenv(ec.CPU_ENV, "1")
    pf = start_prefetch(cfg, tmp_path)
    assert pf.wait(60) and (pf.loaded, pf.reason) == (1, "")
    ec._crashed_marker(directory).touch()  # a run crashed after loading: the cache, and so this, stay off
    pf = start_prefetch(cfg, tmp_path)
    assert pf.wait(60) and pf.loaded == 0 and "crashed" in pf.reason


def test_other_library_versions_or_devices_load_nothing(tmp_path):
    _run(ExecutableCache(tmp_path, CONTEXT, launch_key=LAUNCH), Toy())
    path = manifest_path(tmp_path, LAUNCH)
    doc = json.loads(path.read_text())
    for part, value, reason in (
        ("libraries", {**doc["libraries"], "jaxlib": "0.0.0-other"}, "other library versions"),
        ("platform", {**doc["platform"], "devices": [[0, "another device", 0]]}, "other devices"),
    ):
        path.write_text(json.dumps({**doc, part: value}))
        pf = _prefetched(tmp_path)
        assert pf.loaded == 0 and reason in pf.reason, pf.reason


PROBE_MODULE = """
import collections
import jax

Pair = collections.namedtuple("Pair", "a b")
"""


def test_the_thread_imports_nothing_and_waits_for_the_main_thread(tmp_path, monkeypatch):
    """An entry naming a class of a module not imported yet is loaded once the main thread imports it, never
    imported by the thread (concurrent imports of a cyclic package can fail). A program the trainer asks for
    before its load began is cancelled and left to the trainer."""
    import importlib

    (tmp_path / "pf_probe_mod.py").write_text(PROBE_MODULE)
    monkeypatch.syspath_prepend(str(tmp_path))
    mod = importlib.import_module("pf_probe_mod")
    directory = tmp_path / "cache"

    def program(p: object) -> object:
        return mod.Pair(p.a * 2.0, p.b + p.a.sum())

    args = (mod.Pair(X, X[0]),)
    cache = ExecutableCache(directory, CONTEXT, launch_key=LAUNCH)
    key, inputs = cache.key("pair", jax.jit(program), args)
    assert cache.store(key, inputs, jax.jit(program).lower(*args).compile()) == "stored"
    del sys.modules["pf_probe_mod"]

    for trainer_first in (True, False):
        pf = Prefetch(directory, LAUNCH)
        assert not pf.wait(0.3)  # waiting for the module
        assert "pf_probe_mod" not in sys.modules and pf.loaded == 0
        if trainer_first:
            assert pf.take(key) is None and pf.preempted == 1  # cancelled: the trainer loads it itself
            assert pf.wait(10) and pf.loaded == 0 and "needed before the thread reached them" in pf.line()
            continue
        again = importlib.import_module("pf_probe_mod")  # what the trainer's own imports do
        assert pf.wait(10) and pf.loaded == 1
        compiled = pf.take(key)
        out = compiled(again.Pair(X, X[0]))
        assert type(out) is again.Pair
        np.testing.assert_array_equal(np.asarray(out.a), np.asarray(X * 2.0))
        del sys.modules["pf_probe_mod"]


def test_the_start_up_report_has_the_prefetch_line(tmp_path):
    _run(ExecutableCache(tmp_path, CONTEXT, launch_key=LAUNCH), Toy())
    pf = _prefetched(tmp_path)
    timer = StartupTimer()
    timer.executable_prefetch = pf
    cache = ExecutableCache(tmp_path, CONTEXT)
    cache.prefetch = pf
    compiler = Compiler(timer, executable_cache=cache)
    compiler.submit("toy", jax.jit(Toy().program), X)
    compiler.close()
    rec = timer.finish(1.0, total_s=1.0)
    assert {k: rec["executable_prefetch"][k] for k in ("listed", "loaded", "used", "done")} == {
        "listed": 1,
        "loaded": 1,
        "used": 1,
        "done": True,
    }
    lines = StartupTimer.lines(rec)
    assert lines[-1] == f"  {prefetch_line(rec['executable_prefetch'])}"
    assert "1 of 1 programs of the last launch loaded on a thread" in lines[-1] and ", 1 used" in lines[-1]
    assert "executable_prefetch" not in StartupTimer().finish(1.0)  # not started: not recorded
    cache.confirm()


def test_a_rerun_of_the_trainer_is_served_every_stored_program_from_the_prefetch(
    tmp_path, toy_env, restore_cache_config, monkeypatch
):
    """End to end through ``run``: the first run writes the launch's manifest, the second prefetches every
    stored program, uses them and trains the same."""
    monkeypatch.setenv(ec.CPU_ENV, "1")
    from jax.experimental.compilation_cache import compilation_cache as cc
    from toy_configs import toy_config

    from bar_policy.training.run import run

    cache = tmp_path / "jax"
    cfg = toy_config(tmp_path / "runs", "", [*SMALL_BRAX, f"compile_cache_dir={cache}"])
    cc.reset_cache()
    try:
        first = run(cfg, env=toy_env)
        jax.clear_caches()
        second = run(cfg, env=toy_env)
    finally:
        cc.reset_cache()
    cold, warm = (_startup(s.run_dir) for s in (first, second))
    assert cold["executable_prefetch"]["reason"] == "no manifest for this launch"
    programs = read_manifest(cache / "executables", ep.launch_key(cfg))["programs"]
    assert list(programs) == list(cold["programs"])  # every program, in the order they were keyed
    pf = warm["executable_prefetch"]
    # In this process the env is built at once, so the trainer may ask for a program before the thread
    # began loading it: the trainer then loads that one itself (the thread's load is cancelled). Every
    # program the first epoch ran (all but the evaluation, loaded on a worker meanwhile) was asked for
    # before the record was made: served by the prefetch or needed first.
    assert pf["listed"] == len(cold["programs"]) and pf["failed"] == pf["gave_up"] == 0, pf
    assert 1 <= pf["used"] <= pf["loaded"] and pf["used"] + pf["needed_first"] >= pf["listed"] - 1, pf
    assert {p["executable"] for p in warm["programs"].values()} == {"hit"}
    for a, b in zip(jax.tree.leaves(first.params), jax.tree.leaves(second.params), strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


LAPACK_CHILD = """
import sys
import jax, jax.numpy as jnp, numpy as np
jax.config.update("jax_enable_compilation_cache", False)
from bar_policy.training.executable_cache import ExecutableCache
from bar_policy.training.executable_prefetch import Prefetch

def program(a):  # a Cholesky factorisation and a triangular solve: LAPACK potrf and trsm on a CPU
    c = jnp.linalg.cholesky(a)
    return c, jax.scipy.linalg.solve_triangular(c, jnp.ones(a.shape[0], a.dtype), lower=True)

a = jnp.asarray(np.eye(5) * 2 + 0.1, jnp.float32)
launch = "3" * 64
if sys.argv[1] == "store":
    cache = ExecutableCache(sys.argv[2], {"test": "lapack"}, launch_key=launch)
    jitted = jax.jit(program)
    key, inputs = cache.key("chol", jitted, (a,))
    print(cache.store(key, inputs, jitted.lower(a).compile()))
else:  # this process lowers nothing: the thread deserialises, the kernel tables are filled on take
    pf = Prefetch(sys.argv[2], launch)
    assert pf.wait(60) and pf.loaded == 1, pf.as_dict()
    cache = ExecutableCache(sys.argv[2], {"test": "lapack"}, launch_key=launch)
    cache.prefetch = pf
    key, _ = cache.key("chol", jax.jit(program), (a,))
    compiled = cache.load(key, "chol")
    assert compiled is not None and pf.used == 1, pf.as_dict()
    c, x = compiled(a)
    np.testing.assert_allclose(np.asarray(c), np.linalg.cholesky(np.asarray(a)), rtol=1e-5)
    np.testing.assert_allclose(np.asarray(c) @ np.asarray(x), np.ones(5), rtol=1e-4)
    cache.confirm()
    print("ran")
"""


def test_a_prefetched_lapack_program_runs_in_a_process_that_lowered_none(tmp_path):
    """The thread deserialises without filling jax's LAPACK tables (that imports scipy, and the thread
    imports nothing); ``load`` fills them before handing the program out. Each step in its own process, so a
    segfault (exit -11, the CPU crash of docs/startup.md) fails this test instead of killing pytest."""
    import subprocess

    env = {k: v for k, v in os.environ.items() if k != "JAX_COMPILATION_CACHE_DIR"}
    env |= {"JAX_PLATFORMS": "cpu", "PYTHONPATH": str(Path(__file__).resolve().parents[2])}
    for step, expected in (("store", "stored"), ("load", "ran")):
        argv = [sys.executable, "-c", LAPACK_CHILD, step, str(tmp_path)]
        child = subprocess.run(argv, env=env, capture_output=True, text=True, timeout=120)
        assert child.returncode == 0, (step, child.returncode, child.stderr[-2000:])
        assert child.stdout.split()[-1:] == [expected], (step, child.stdout[-500:])
