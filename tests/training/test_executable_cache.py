"""The executable cache: a hit skips the trace and serves the same program; anything else is a miss.

Toy programs through the trainer's own ``Compiler``, each cache in an empty directory. A miss traces (the
Python function runs) and stores; a hit loads without tracing and computes bit for bit what the freshly
compiled program did. A changed config, package content, jax version or argument signature is another key;
a corrupt entry is logged, deleted and replaced; the off switch writes and reads nothing.
"""

from __future__ import annotations

import logging
import os
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from bar_policy.training.config import apply_overrides, config_to_dict, preset
from bar_policy.training.startup import executable_cache as ec
from bar_policy.training.startup import executable_key as ek
from bar_policy.training.startup.breakdown import StartupTimer
from bar_policy.training.startup.compiler import Compiler
from bar_policy.training.startup.executable_cache import ExecutableCache, executable_cache_for

X = jnp.linspace(-2.0, 3.0, 24, dtype=jnp.float32).reshape(4, 6)


@pytest.fixture(autouse=True)
def no_persistent_cache(restore_cache_config):
    """Every toy program compiles afresh: the suite's shared persistent cache (tests/conftest.py) may hold it
    from an earlier run, and an executable it serves is not stored (the last test here)."""
    from jax.experimental.compilation_cache import compilation_cache as cc

    jax.config.update("jax_enable_compilation_cache", False)
    cc.reset_cache()  # jax decides once per process whether the cache is used: decide again
    yield
    cc.reset_cache()


CONTEXT = {"train": {"seed": 0, "ppo": {"learning_rate": 1e-3}}, "env": {"gain": 0.3}}


class Toy:
    """A program closing over a config value (as the trainer's close over the env and PPO configs), with a
    count of its traces."""

    def __init__(self, gain: float = 0.3) -> None:
        self.gain = gain
        self.traces = 0

    def program(self, x: jax.Array) -> dict[str, jax.Array]:
        self.traces += 1
        y = jnp.tanh(x @ x.T * self.gain) + jnp.sin(x).sum()
        return {"y": y, "norm": jnp.sqrt((y * y).sum())}


def _run(cache: ExecutableCache | None, toy: Toy, *args: object, name: str = "toy", background: bool = False):
    """Submit ``toy.program`` through a fresh ``Compiler`` (jax's in-memory caches cleared); returns the
    outputs as numpy and the program's ``ProgramTimes``."""
    jax.clear_caches()
    timer = StartupTimer()
    compiler = Compiler(timer, executable_cache=cache)
    compiler.submit(name, jax.jit(toy.program), *(args or (X,)), background=background)
    out = jax.tree.map(np.asarray, compiler.get(name)(*(args or (X,))))
    compiler.close()
    return out, timer.programs[name]


def _entries(directory: Path) -> set[str]:
    return {p.name for p in directory.glob("*.bin")}


def test_same_key_hits_without_tracing_bit_for_bit(tmp_path):
    toy = Toy()
    fresh, first = _run(ExecutableCache(tmp_path, CONTEXT), toy)
    assert toy.traces == 1 and first.executable == "stored" and first.trace_s > 0
    (entry,) = _entries(tmp_path)
    assert (tmp_path / entry.replace(".bin", ".json")).is_file()  # the sidecar, for humans

    for background in (False, True):  # loaded on the calling thread, or on the worker
        loaded, again = _run(ExecutableCache(tmp_path, dict(CONTEXT)), toy, background=background)
        assert toy.traces == 1  # not traced again
        assert again.executable == "hit" and again.cache == "exec cache hit" and again.exec_load_s > 0
        assert again.trace_s == again.lower_s == again.compile_s == 0.0
        for k in fresh:
            np.testing.assert_array_equal(loaded[k], fresh[k])  # bit for bit
    assert _entries(tmp_path) == {entry}
    timer = StartupTimer()
    timer.programs["toy"] = again
    rec = timer.finish(1.0, total_s=1.0)
    assert rec["programs"]["toy"]["executable"] == "hit"  # the run record keeps it
    lines = StartupTimer.lines(rec)
    assert any("exec cache hit" in line and "trace, lower, compile skipped" in line for line in lines)


def test_load_in_background_loads_a_hit_on_a_worker_and_traces_a_miss_here(tmp_path):
    """``load_in_background``: a stored program loads on a worker (``submit`` returns at once, None); one
    to compile is still traced on the calling thread (its trace holds the GIL either way)."""
    toy = Toy()
    fresh, _ = _run(None, toy)
    cache = ExecutableCache(tmp_path, CONTEXT)
    for expected_thread, expected_exe, traces in (("main", "stored", 2), ("worker", "hit", 2)):
        jax.clear_caches()
        timer = StartupTimer()
        compiler = Compiler(timer, executable_cache=cache)
        returned = compiler.submit("toy", jax.jit(toy.program), X, load_in_background=True)
        out = jax.tree.map(np.asarray, compiler.get("toy")(X))
        compiler.close()
        times = timer.programs["toy"]
        assert (times.thread, times.executable, toy.traces) == (expected_thread, expected_exe, traces)
        assert (returned is None) == (expected_thread == "worker")
        for k in fresh:
            np.testing.assert_array_equal(out[k], fresh[k])
        cache = ExecutableCache(tmp_path, dict(CONTEXT))  # a second process's view of the same store


def test_a_changed_config_is_not_served_the_stale_program(tmp_path):
    first, _ = _run(ExecutableCache(tmp_path, CONTEXT), Toy(0.3))
    changed = {**CONTEXT, "env": {"gain": 0.6}}
    toy = Toy(0.6)
    out, second = _run(ExecutableCache(tmp_path, changed), toy)
    assert toy.traces == 1 and second.executable == "stored"  # a miss: traced, compiled, stored
    assert len(_entries(tmp_path)) == 2
    expected, _ = _run(None, Toy(0.6))  # what the changed config computes, no cache involved
    np.testing.assert_array_equal(out["y"], expected["y"])
    assert not np.allclose(out["y"], first["y"])  # and not the 0.3 program's


def test_changed_package_content_or_jax_version_misses(tmp_path, monkeypatch):
    _run(ExecutableCache(tmp_path, CONTEXT), Toy())
    monkeypatch.setattr(ek, "package_hash", lambda: "0" * 64)
    toy = Toy()
    _, edited = _run(ExecutableCache(tmp_path, CONTEXT), toy)
    assert toy.traces == 1 and edited.executable == "stored"
    versions = {**ek.library_versions(), "jax": "0.0.0-other"}
    monkeypatch.setattr(ek, "library_versions", lambda: versions)
    _, other_jax = _run(ExecutableCache(tmp_path, CONTEXT), toy)
    assert toy.traces == 2 and other_jax.executable == "stored"
    assert len(_entries(tmp_path)) == 3


def test_changed_argument_shape_or_dtype_misses(tmp_path):
    toy = Toy()
    cache = ExecutableCache(tmp_path, CONTEXT)
    _run(cache, toy, X)
    _run(cache, toy, X[:3])  # another shape
    out, times = _run(cache, toy, X.astype(jnp.bfloat16))  # another dtype
    assert toy.traces == 3 and times.executable == "stored" and out["y"].dtype == jnp.bfloat16
    assert len(_entries(tmp_path)) == 3
    _run(cache, toy, X[:3])
    assert toy.traces == 3  # each signature has its own entry


def test_a_corrupt_entry_is_logged_deleted_and_replaced(tmp_path, caplog):
    fresh, _ = _run(ExecutableCache(tmp_path, CONTEXT), Toy())
    (entry,) = tmp_path.glob("*.bin")
    entry.write_bytes(entry.read_bytes()[:100])  # truncated
    toy = Toy()
    with caplog.at_level(logging.WARNING, logger=ec.__name__):
        out, times = _run(ExecutableCache(tmp_path, CONTEXT), toy)
    (line,) = [r.getMessage() for r in caplog.records if r.name == ec.__name__]
    assert entry.name in line and "compiling afresh" in line
    assert toy.traces == 1 and times.executable == "bad entry replaced, stored"
    np.testing.assert_array_equal(out["y"], fresh["y"])
    _, again = _run(ExecutableCache(tmp_path, CONTEXT), toy)  # the replacement loads
    assert again.executable == "hit" and toy.traces == 1


def test_entries_a_crashed_process_loaded_are_deleted_and_banned(tmp_path, caplog):
    import subprocess
    import sys

    cache = ExecutableCache(tmp_path, CONTEXT)
    _run(cache, Toy())
    _, hit = _run(ExecutableCache(tmp_path, CONTEXT), Toy())
    assert hit.executable == "hit" and (tmp_path / f"inflight-{os.getpid()}.json").exists()
    ExecutableCache(tmp_path, CONTEXT).confirm()  # ran fine: no longer in flight
    assert not list(tmp_path.glob("inflight-*"))

    # A process that loaded the entry and died before confirming (what a segfault leaves behind).
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True)
    (key,) = (p.stem for p in tmp_path.glob("*.bin"))
    (tmp_path / f"inflight-{int(dead.stdout)}.json").write_text(f'["{key}"]')
    with caplog.at_level(logging.WARNING, logger=ec.__name__):
        cache = ExecutableCache(tmp_path, CONTEXT)
    assert any("died running programs" in r.getMessage() for r in caplog.records)
    assert not _entries(tmp_path) and not list(tmp_path.glob("inflight-*"))
    toy = Toy()
    _, again = _run(cache, toy)
    assert toy.traces == 1 and again.executable == "not stored: a process crashed running it"
    assert not _entries(tmp_path)
    # And the trainer's cache stays off on this backend and jaxlib from then on (one crashed run, not one
    # per config), until the marker is deleted.
    (marker,) = tmp_path.glob("crashed-*")
    cfg = apply_overrides(preset("tiny"), ["executable_cache=True"])
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv(ec.CPU_ENV, "1")
        run_cache = tmp_path / "run"
        assert executable_cache_for(cfg, run_cache, {"train": {}, "env": {}}, Toy()) is not None
        marker.rename(run_cache / "executables" / marker.name)
        assert executable_cache_for(cfg, run_cache, {"train": {}, "env": {}}, Toy()) is None


def test_loads_on_several_threads_keep_every_key_in_the_in_flight_record(tmp_path):
    """The crash guard's record lists every entry this process loaded, whichever thread loaded it (the
    evaluation loads on a worker while the main thread loads the epoch). Without the lock, 64 threads lost
    a key in 11 of 20 such trials on the 2-core CPU."""
    import json
    import threading

    keys = [f"k{i:03d}" for i in range(64)]
    for _ in range(5):
        cache = ExecutableCache(tmp_path, CONTEXT)
        threads = [threading.Thread(target=cache._record_loaded, args=(k,)) for k in keys]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        assert sorted(json.loads((tmp_path / f"inflight-{os.getpid()}.json").read_text())) == keys
        cache.confirm()


def test_an_entry_under_another_key_is_refused(tmp_path, caplog):
    cache = ExecutableCache(tmp_path, CONTEXT)
    _run(cache, Toy())
    (entry,) = tmp_path.glob("*.bin")
    entry.rename(tmp_path / ("f" * 64 + ".bin"))
    assert cache.load("f" * 64, "toy") is None and not (tmp_path / ("f" * 64 + ".bin")).exists()


def test_default_is_on_for_gpus_and_several_processes_off_on_cpus(tmp_path, monkeypatch):
    """The default decision (docs/training.md, "Switches"), the backend given explicitly.

    Several processes keep it on since 2026-11-27: each stores and loads its own entries, and a program is
    loaded only when all hold it (``test_distributed.py`` runs that path)."""
    cfg = preset("tiny")
    assert cfg.executable_cache is True and preset("gpu").executable_cache is True
    monkeypatch.delenv(ec.CPU_ENV, raising=False)
    assert ec.off_reason(cfg, tmp_path, "gpu") == ""  # on
    assert ec.off_reason(cfg, tmp_path, "cpu") == f"CPU backend; {ec.CPU_ENV}=1 turns it on"
    assert ec.off_reason(cfg, tmp_path, "tpu") == "tpu backend, unmeasured there"
    several = apply_overrides(cfg, ["distributed.num_processes=2"])
    assert ec.off_reason(several, tmp_path, "gpu") == ""
    assert ec.off_reason(cfg, None, "gpu") == "compile cache off"
    off = apply_overrides(cfg, ["executable_cache=False"])
    assert ec.off_reason(off, tmp_path, "gpu") == "switched off, --no-executable-cache"
    monkeypatch.setenv(ec.CPU_ENV, "1")
    assert ec.off_reason(cfg, tmp_path, "cpu") == ""  # the CPU opt-in
    assert ec.off_reason(several, tmp_path, "cpu") == ""  # several processes too
    # The run's log line names the reason (this process is a CPU).
    monkeypatch.delenv(ec.CPU_ENV)
    line = ec.executable_cache_line(cfg, tmp_path, None)
    assert line == f"executable cache: off (CPU backend; {ec.CPU_ENV}=1 turns it on)"
    record = {"train": {"seed": 0}, "env": {}}
    assert executable_cache_for(cfg, tmp_path, record, Toy()) is None  # this CPU, no opt-in
    import jax

    monkeypatch.setattr(jax, "default_backend", lambda: "gpu")  # what run.py asks: a GPU gets one
    cache = executable_cache_for(cfg, tmp_path, record, Toy())
    assert cache is not None and cache.directory == tmp_path / "executables"
    assert (
        ec.executable_cache_line(cfg, tmp_path, cache)
        == f"executable cache: {cache.directory} (docs/training.md)"
    )


def test_off_switch_writes_and_reads_nothing(tmp_path, monkeypatch):
    cfg = apply_overrides(preset("tiny"), ["executable_cache=True"])
    record = {"train": {"seed": 0}, "env": {}}
    monkeypatch.delenv(ec.CPU_ENV, raising=False)
    assert executable_cache_for(cfg, tmp_path, record, Toy()) is None  # off on CPUs unless asked for
    monkeypatch.setenv(ec.CPU_ENV, "1")
    assert executable_cache_for(cfg, tmp_path, record, Toy()) is not None  # on with the compile cache
    off = apply_overrides(preset("tiny"), ["executable_cache=False"])
    assert executable_cache_for(off, tmp_path, record, Toy()) is None
    assert executable_cache_for(cfg, None, record, Toy()) is None  # --no-compile-cache
    several = apply_overrides(preset("tiny"), ["distributed.num_processes=2"])
    # jax.distributed runs get one too (since 2026-11-27: each process its own entries, loaded when all hold
    # them; tests/training/test_distributed.py).
    assert executable_cache_for(several, tmp_path, record, Toy()) is not None

    _run(ExecutableCache(tmp_path / "on", CONTEXT), Toy())  # an entry the off run could have read
    before = {p: p.stat().st_mtime_ns for p in (tmp_path / "on").iterdir()}
    toy = Toy()
    _, times = _run(None, toy)
    assert toy.traces == 1 and times.executable == "off" and times.cache != "exec cache hit"
    assert {p: p.stat().st_mtime_ns for p in (tmp_path / "on").iterdir()} == before


def test_run_name_budget_and_paths_stay_out_of_the_key(tmp_path, monkeypatch):
    """A rerun under another run name, runs directory, wall-clock budget, export path, cache directory or
    step-0 evaluation time compiles the same programs: the same context. A changed PPO value or
    evaluation size does not (a different context)."""
    monkeypatch.setenv(ec.CPU_ENV, "1")
    cfg = apply_overrides(preset("tiny"), ["executable_cache=True"])
    base = config_to_dict(cfg)
    moved = config_to_dict(
        apply_overrides(
            cfg,
            [
                "run_name=warm",
                "runs_dir=/elsewhere",
                "max_minutes=1.0",
                "onnx_path=x.onnx",
                "export_onnx=False",
                "autotune_seed=False",  # changes XLA's choice of implementation, not what is computed
                "eval.initial=off",  # a section's field
            ],
        )
    )
    tuned = config_to_dict(apply_overrides(cfg, ["ppo.learning_rate=0.000123"]))
    bigger = config_to_dict(apply_overrides(cfg, ["eval.num_eval_envs=32"]))  # the field beside it
    assert {k for k in base if base[k] != moved[k]} == {
        "run_name",
        "runs_dir",
        "max_minutes",
        "onnx_path",
        "export_onnx",
        "autotune_seed",
        "eval",
    }
    assert {k for k in base["eval"] if base["eval"][k] != moved["eval"][k]} == {"initial"}
    ctx = [
        executable_cache_for(cfg, tmp_path, {"train": t, "env": {}}, Toy()).context
        for t in (base, moved, tuned, bigger)
    ]
    assert ctx[0] == ctx[1]
    assert ctx[0] != ctx[2] and ctx[0] != ctx[3]
    assert "initial" in base["eval"] and "initial" not in ctx[0]["train"]["eval"]
    assert base["eval"]["initial"] == "end"  # the record itself is left whole
    for name in ek.OUTSIDE_PROGRAMS:  # every name left out is a real field (of a section, when dotted)
        section, _, leaf = name.partition(".")
        assert section in base and (not leaf or leaf in base[section]), name


def test_the_key_holds_reward_weights_by_name(tmp_path, monkeypatch):
    """Every program that steps the env takes the reward weights as an argument (the brax rollout and
    evaluation, the rsl-rl steps): a run that changes only a weight has the same context, on either
    backend, so it loads the compiled programs. Any other env field still changes it.
    """
    import dataclasses
    import json

    from bar_policy import envs

    monkeypatch.setenv(ec.CPU_ENV, "1")

    def env_record(overrides: list[str]) -> dict:
        cfg = envs.load("LiteReach", overrides=overrides or None).config
        return json.loads(json.dumps(dataclasses.asdict(cfg), default=list))

    # The last two spell one setting two ways: one env config.
    weight, field = ["reward.scales.success=0.6"], ["reward.fine_std=0.04"]
    overrides = ([], weight, field, ["sim_dt=0.004"], ["sim_dt=4e-3"])
    records = [env_record(o) for o in overrides]
    assert records[0]["reward"]["scales"]["success"] != 0.6  # the override is a change
    assert records[3] == records[4] != records[0]
    for backend in ("brax", "rsl-rl"):
        ctx = []
        for o, r in zip(overrides, records, strict=True):  # the run's config holds them too
            cfg = apply_overrides(preset("tiny"), ["executable_cache=True", f"backend={backend}"])
            cfg = dataclasses.replace(cfg, env_overrides=(*cfg.env_overrides, *o))
            record = {"train": config_to_dict(cfg), "env": r}
            ctx.append(executable_cache_for(cfg, tmp_path, record, Toy()).context)
        assert ctx[0] == ctx[1], backend
        assert ctx[0] != ctx[2], backend
        assert ctx[3] == ctx[4] != ctx[0], backend  # one env config, one key, however it was spelt
    train = {"seed": 0, "env_overrides": ["sim_dt=0.004", "reward.scales.success=0.6"]}
    t, e = ek.weights_by_name(train, records[1])
    assert e["reward"]["scales"] == sorted(records[1]["reward"]["scales"])  # the names stay
    assert t == {"seed": 0}  # the env record holds what the overrides did
    assert records[1]["reward"]["scales"]["success"] == 0.6  # the record itself is left whole
    assert ek.weights_by_name(train, {"gain": 0.3}) == ({"seed": 0}, {"gain": 0.3})  # no weights
    assert ek.weights_by_name(train, None) == (train, None)  # a stand-in env: the overrides stay


def test_key_covers_config_code_versions_platform_and_signature():
    cache = ExecutableCache.__new__(ExecutableCache)
    cache.context = CONTEXT
    key, inputs = cache.key("toy", jax.jit(Toy().program), (X,))
    assert len(key) == 64 and inputs["context"] == CONTEXT and inputs["package"] == ek.package_hash()
    assert {"jax", "jaxlib", "mujoco", "mujoco-mjx", "brax", "flax", "optax"} <= set(inputs["libraries"])
    assert inputs["platform"]["backend"] == jax.default_backend() and inputs["platform"]["process_count"] == 1
    assert "jax_default_matmul_precision" in inputs["flags"]
    assert inputs["args"]["leaves"][0][:2] == [[4, 6], "float32"]
    assert cache.key("toy", jax.jit(Toy().program), (X,))[0] == key  # deterministic
    assert cache.key("other", jax.jit(Toy().program), (X,))[0] != key  # the name is part of it


class Wrapped:
    """Static tree data as MJX keeps it (``_NumPyArrayHashWrapper``): a numpy array, repr with an address."""

    __slots__ = ("array",)

    def __init__(self, array: np.ndarray) -> None:
        self.array = array

    def __eq__(self, other: object) -> bool:
        return isinstance(other, Wrapped) and np.array_equal(self.array, other.array)

    def __hash__(self) -> int:
        return hash(self.array.tobytes())


@jax.tree_util.register_pytree_node_class
class Node:
    def __init__(self, x: jax.Array, meta: Wrapped) -> None:
        self.x, self.meta = x, meta

    def tree_flatten(self) -> tuple:
        return (self.x,), self.meta

    @classmethod
    def tree_unflatten(cls, meta: Wrapped, children: tuple) -> Node:
        return cls(children[0], meta)


def test_signature_describes_static_tree_data_by_content_not_address():
    """A tree's static data is described by content: equal in every process, changed with the content
    (``str(treedef)`` shows the wrapper's address, which made every rerun of the epoch a miss)."""
    a = ek.signature((Node(X, Wrapped(np.arange(3))),))
    assert ek.signature((Node(X, Wrapped(np.arange(3))),)) == a
    assert ek.signature((Node(X, Wrapped(np.arange(4))),)) != a
    assert " at 0x" not in str(a)


def test_cli_switch():
    from bar_policy.training.cli import parse_config

    assert parse_config(["--preset", "tiny"]).executable_cache is True  # used where off_reason allows
    assert parse_config(["--preset", "tiny", "--no-executable-cache"]).executable_cache is False
    assert parse_config(["--preset", "tiny", "--executable-cache"]).executable_cache is True
    assert parse_config(["--preset", "tiny"]).autotune_seed is True
    assert parse_config(["--preset", "tiny", "--no-autotune-seed"]).autotune_seed is False


def test_an_executable_the_persistent_cache_served_is_not_stored(tmp_path):
    """On a CPU an executable jax's persistent cache loaded re-serialises without its fused functions (the
    reload fails, "Function ... not found"), so the executable cache leaves it out; a fresh compile of the
    same program is stored."""
    from jax.experimental.compilation_cache import compilation_cache as cc

    jax.config.update("jax_enable_compilation_cache", True)
    jax.config.update("jax_compilation_cache_dir", str(tmp_path / "jax"))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", -1)
    cc.reset_cache()
    fresh, first = _run(ExecutableCache(tmp_path / "a", CONTEXT), Toy())  # compiled: into both caches
    assert first.cache_hits == 0 and first.executable == "stored"
    served, second = _run(ExecutableCache(tmp_path / "b", CONTEXT), Toy())  # from jax's cache
    assert second.cache_hits == 1 and second.executable == "not stored: served by jax's persistent cache"
    assert not _entries(tmp_path / "b")
    np.testing.assert_array_equal(served["y"], fresh["y"])


if __name__ == "__main__":  # pragma: no cover
    pytest.main([__file__, "-q"])


def _startup(run_dir: Path) -> dict:
    """The run's start-up record (``metrics.jsonl``)."""
    import json

    recs = [json.loads(x) for x in (Path(run_dir) / "metrics.jsonl").read_text().splitlines()]
    return next(r for r in recs if r["kind"] == "startup")


SMALL_BRAX = [
    "ppo.num_envs=16",
    "ppo.batch_size=16",
    "ppo.num_minibatches=2",
    "ppo.unroll_length=4",
    "ppo.num_updates_per_batch=1",
    "ppo.num_timesteps=128",
    "eval.num_evals=2",
    "eval.num_eval_envs=16",
    "export_onnx=False",
    "executable_cache=True",
    "seed=0",
]
"""The smallest brax run on the stand-in env: two iterations of 64 env steps, two evaluations."""


@pytest.mark.slow
def test_a_rerun_loads_every_program_and_trains_the_same(
    tmp_path, toy_env, restore_cache_config, monkeypatch
):
    """End to end: the second run of one config traces nothing and ends with the same parameters."""
    monkeypatch.setenv(ec.CPU_ENV, "1")  # the stand-in env's programs load and run on a CPU
    from jax.experimental.compilation_cache import compilation_cache as cc
    from toy_configs import toy_config

    from bar_policy.training.run import run
    from bar_policy.training.startup import breakdown as sb

    cache = tmp_path / "jax"
    # No run name: each run gets its own directory, the config (part of the key) stays the same.
    cfg = toy_config(tmp_path / "runs", "", [*SMALL_BRAX, f"compile_cache_dir={cache}"])
    cc.reset_cache()  # jax opens its cache once per process: close the suite's
    try:
        first = run(cfg, env=toy_env)
        jax.clear_caches()
        second = run(cfg, env=toy_env)
    finally:
        cc.reset_cache()
    cold, warm = (_startup(s.run_dir) for s in (first, second))
    assert {p["executable"] for p in cold["programs"].values()} == {"stored"}
    assert {p["executable"] for p in warm["programs"].values()} == {"hit"}, warm["programs"]
    assert warm["phases"][sb.TRACE] == warm["phases"][sb.LOWER] == 0.0
    assert len(list((cache / "executables").glob("*.bin"))) == len(cold["programs"])
    for a, b in zip(jax.tree.leaves(first.params), jax.tree.leaves(second.params), strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


MESH_CHILD = """
import json, sys
sys.path.insert(0, sys.argv[1])
import jax, numpy as np
from toy_configs import toy_config
from toy_env import ToyReach
from bar_policy.training.run import run

runs, cache, n, overrides = sys.argv[2], sys.argv[3], int(sys.argv[4]), json.loads(sys.argv[5])
assert jax.local_device_count() == n, jax.devices()
s = run(toy_config(runs, "", [*overrides, f"compile_cache_dir={cache}"]), env=ToyReach())
np.savez(f"{runs}/params.npz", *(np.asarray(x) for x in jax.tree.leaves(s.params)))
print("RUN_DIR", s.run_dir)
"""


def _mesh_run(tmp_path: Path, name: str, devices: int) -> Path:
    """A fresh process of the smallest brax run on ``devices`` forced CPU devices (the mesh spans all of
    them), on the cache in ``tmp_path/jax``; returns its run directory (``params.npz`` one level up)."""
    import json
    import subprocess
    import sys

    runs = tmp_path / name
    runs.mkdir()
    env = {k: v for k, v in os.environ.items() if k != "XLA_FLAGS"}
    env |= {"JAX_PLATFORMS": "cpu", ec.CPU_ENV: "1", "PYTHONPATH": str(Path(__file__).resolve().parents[2])}
    if devices > 1:  # the device count is fixed when jax starts: hence a process per run
        env["XLA_FLAGS"] = f"--xla_force_host_platform_device_count={devices}"
    tests = str(Path(__file__).parent)
    argv = [sys.executable, "-c", MESH_CHILD, tests, str(runs), str(tmp_path / "jax"), str(devices)]
    child = subprocess.run(
        [*argv, json.dumps(SMALL_BRAX)], env=env, capture_output=True, text=True, timeout=300
    )
    assert child.returncode == 0, (name, child.returncode, child.stderr[-3000:])
    return Path(child.stdout.split("RUN_DIR", 1)[1].split()[0])


def _curves(run_dir: Path) -> list[dict]:
    """The run's train, evaluation and final records less their wall-clock fields."""
    import json

    recs = [json.loads(x) for x in (run_dir / "metrics.jsonl").read_text().splitlines()]
    drop = {"time_s", "sps"}
    return [
        {k: v for k, v in r.items() if k not in drop} for r in recs if r["kind"] in ("train", "eval", "final")
    ]


@pytest.mark.slow
def test_a_two_device_mesh_program_is_stored_loaded_in_a_fresh_process_and_trains_the_same(tmp_path):
    """Two GPUs of one host, played by 2 forced CPU devices: the data-parallel programs (arguments
    sharded over the 2-device mesh) are stored by one process and loaded by the next, which traces nothing
    and trains bit for bit the same; a 1-device run on the same cache misses every entry and compiles.

    Three processes of the smallest brax run (about 20 s on 2 cores: two compiling runs, one loading)."""
    import json

    from bar_policy.training.startup import breakdown as sb

    first = _mesh_run(tmp_path, "first", 2)
    second = _mesh_run(tmp_path, "second", 2)
    assert len(json.loads((first / "config.json").read_text())["device"]["devices"]) == 2  # a 2-device mesh
    cold, warm = _startup(first), _startup(second)
    assert {p["executable"] for p in cold["programs"].values()} == {"stored"}, cold["programs"]
    assert {p["cache"] for p in warm["programs"].values()} == {"exec cache hit"}, warm["programs"]
    assert {p["executable"] for p in warm["programs"].values()} == {"hit"}
    assert warm["phases"][sb.TRACE] == warm["phases"][sb.LOWER] == 0.0
    entries = tmp_path / "jax" / "executables"
    assert len(list(entries.glob("*.bin"))) == len(cold["programs"])
    # The same computation, not merely a loadable one: same parameters and curves bit for bit (the loaded
    # executable is the stored one, run on the same devices with the same inputs).
    a, b = np.load(tmp_path / "first" / "params.npz"), np.load(tmp_path / "second" / "params.npz")
    assert a.files == b.files and a.files
    for k in a.files:
        np.testing.assert_array_equal(a[k], b[k])
    assert _curves(first) == _curves(second) and _curves(first)

    single = _startup(_mesh_run(tmp_path, "single", 1))
    assert {p["executable"] for p in single["programs"].values()} == {"stored"}, single["programs"]
    assert single["phases"][sb.TRACE] > 0  # traced and compiled, not served a 2-device program
    # Every program now has two entries, with the same argument tree, shapes and dtypes: they differ in the
    # device list and in each argument's sharding (its mesh and device ids), not only in XLA_FLAGS.
    sides = [json.loads(p.read_text()) for p in entries.glob("*.json")]
    assert len(sides) == 2 * len(cold["programs"])
    for name in cold["programs"]:
        two, one = sorted(
            (s for s in sides if s["name"] == name), key=lambda s: -len(s["platform"]["devices"])
        )
        assert len(two["platform"]["devices"]) == 2 and len(one["platform"]["devices"]) == 1
        assert two["args"]["tree"] == one["args"]["tree"]
        arrays = [
            (leaf2, leaf1)
            for leaf2, leaf1 in zip(two["args"]["leaves"], one["args"]["leaves"], strict=True)
            if leaf2[0] != "static"  # [shape, dtype, weak type, sharding]; static leaves are described apart
        ]
        assert arrays, name
        for leaf2, leaf1 in arrays:
            assert leaf2[:3] == leaf1[:3]
            assert (leaf2[3][1], leaf1[3][1]) == ([0, 1], [0])  # each sharding's device ids


def test_least_recently_used_entries_go_over_the_size_limit(tmp_path):
    cache = ExecutableCache(tmp_path, CONTEXT)
    _run(cache, Toy(), X)
    (old,) = tmp_path.glob("*.bin")
    os.utime(old, (1, 1))  # long unused
    cache.max_bytes = old.stat().st_size * 3 // 2  # room for one entry
    _run(cache, Toy(), X[:2])
    assert not old.exists() and not old.with_suffix(".json").exists()
    assert len(_entries(tmp_path)) == 1


LAPACK_CHILD = """
import sys
import jax, jax.numpy as jnp, numpy as np
jax.config.update("jax_enable_compilation_cache", False)
from bar_policy.training.startup.executable_cache import ExecutableCache

def program(a):  # a Cholesky factorisation and a triangular solve: LAPACK potrf and trsm on a CPU
    c = jnp.linalg.cholesky(a)
    return c, jax.scipy.linalg.solve_triangular(c, jnp.ones(a.shape[0], a.dtype), lower=True)

a = jnp.asarray(np.eye(5) * 2 + 0.1, jnp.float32)
cache = ExecutableCache(sys.argv[2], {"test": "lapack"})
jitted = jax.jit(program)
key, inputs = cache.key("chol", jitted, (a,))
if sys.argv[1] == "store":
    print(cache.store(key, inputs, jitted.lower(a).compile()))
else:  # this process lowers nothing: it only loads and runs
    compiled = cache.load(key, "chol")
    assert compiled is not None, "entry not loaded"
    c, x = compiled(a)
    np.testing.assert_allclose(np.asarray(c), np.linalg.cholesky(np.asarray(a)), rtol=1e-5)
    np.testing.assert_allclose(np.asarray(c) @ np.asarray(x), np.ones(5), rtol=1e-4)
    cache.confirm()
    print("ran")
"""


def test_a_loaded_lapack_program_runs_in_a_process_that_lowered_none(tmp_path):
    """The CPU epoch crash: jaxlib fills its LAPACK function pointers only while lowering a linalg op, so a
    process that only loaded an executable calling LAPACK jumped to address 0 (exit -11). Each step in its
    own process, so a segfault fails this test instead of killing pytest."""
    import subprocess
    import sys

    env = {k: v for k, v in os.environ.items() if k != "JAX_COMPILATION_CACHE_DIR"}
    env |= {"JAX_PLATFORMS": "cpu", "PYTHONPATH": str(Path(__file__).resolve().parents[2])}
    for step, expected in (("store", "stored"), ("load", "ran")):
        argv = [sys.executable, "-c", LAPACK_CHILD, step, str(tmp_path)]
        child = subprocess.run(argv, env=env, capture_output=True, text=True, timeout=120)
        assert child.returncode == 0, (step, child.returncode, child.stderr[-2000:])
        assert child.stdout.split()[-1:] == [expected], (step, child.stdout[-500:])
