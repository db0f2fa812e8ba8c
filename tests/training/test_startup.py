"""Start-up pieces: the compilation cache's location and switch, concurrent compiles, the breakdown."""

from __future__ import annotations

import os

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from bar_policy.training.startup import breakdown as sb
from bar_policy.training.startup.breakdown import StartupTimer
from bar_policy.training.startup.compile_cache import configure_compile_cache, default_cache_dir
from bar_policy.training.startup.compiler import Compiler, CompileStats


def test_default_cache_dir_follows_xdg(monkeypatch, tmp_path):
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    assert default_cache_dir() == tmp_path / "xdg" / "bar_policy" / "jax"
    monkeypatch.delenv("XDG_CACHE_HOME")
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    assert default_cache_dir() == tmp_path / "home" / ".cache" / "bar_policy" / "jax"


def test_cache_dir_precedence_and_switch(monkeypatch, tmp_path, restore_cache_config):
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    monkeypatch.delenv("JAX_COMPILATION_CACHE_DIR", raising=False)
    # Default: the XDG location, created, every program cached.
    assert configure_compile_cache() == tmp_path / "xdg" / "bar_policy" / "jax"
    assert (tmp_path / "xdg" / "bar_policy" / "jax").is_dir()
    assert jax.config.jax_persistent_cache_min_compile_time_secs == 0.0
    assert jax.config.jax_compilation_cache_dir == str(tmp_path / "xdg" / "bar_policy" / "jax")
    # The environment variable wins over XDG, an explicit directory over both.
    monkeypatch.setenv("JAX_COMPILATION_CACHE_DIR", str(tmp_path / "env"))
    assert configure_compile_cache() == tmp_path / "env"
    assert configure_compile_cache(directory=str(tmp_path / "flag")) == tmp_path / "flag"
    # Off: no directory, jax's switch off.
    assert configure_compile_cache(enabled=False) is None
    assert jax.config.jax_enable_compilation_cache is False


def test_compiler_runs_programs_compiled_on_threads():
    timer = StartupTimer()
    compiler = Compiler(timer)
    x = jnp.arange(6.0)
    compiler.submit("double", jax.jit(lambda a: 2.0 * a), x)
    lowered = compiler.submit("total", jax.jit(lambda a: a.sum()), x)
    assert lowered.out_info.shape == ()
    np.testing.assert_allclose(compiler.get("double")(x), [0, 2, 4, 6, 8, 10])
    assert float(compiler.get("total")(x)) == 15.0
    assert set(timer.programs) == {"double", "total"}
    for name in ("double", "total"):
        p = timer.programs[name]
        assert p.thread == "main" and p.trace_s > 0 and p.lower_s > 0 and p.compile_s > 0
    # The main thread's trace and lower seconds are its phases too.
    main_trace = sum(p.trace_s for p in timer.programs.values())
    assert timer.phases[sb.TRACE] == pytest.approx(main_trace)
    assert timer.phases[sb.LOWER] == pytest.approx(sum(p.lower_s for p in timer.programs.values()))
    with pytest.raises(KeyError):
        compiler.get("never submitted")
    # Traced on the worker too: nothing returned now, the executable and its times later, and no
    # main-thread phase grows (the worker's seconds overlap the main thread's).
    assert compiler.submit("cube", jax.jit(lambda a: a**3), x, background=True) is None
    np.testing.assert_allclose(compiler.get("cube")(x), [0, 1, 8, 27, 64, 125])
    cube = timer.programs["cube"]
    assert compiler.done("cube") and cube.thread == "worker" and cube.trace_s > 0 and cube.compile_s > 0
    assert timer.phases[sb.TRACE] == pytest.approx(main_trace)
    # A trace error on the worker surfaces at get().
    compiler.submit("bad", jax.jit(lambda a: a @ a), jnp.ones((2, 3)), background=True)
    with pytest.raises(TypeError, match="dot_general"):
        compiler.get("bad")
    compiler.close()


def test_compile_stats_count_a_fresh_compile():
    stats = CompileStats.get()
    before = stats.snapshot()
    jax.jit(lambda a: a * 3.0 + float(np.pi))(np.ones(7, np.float32)).block_until_ready()  # a new program
    after = stats.snapshot()
    assert after["compiles"] == before["compiles"] + 1
    assert after["jax_trace_s"] > before["jax_trace_s"] and after["jax_lower_s"] > before["jax_lower_s"]
    assert CompileStats.get() is stats


def test_rsl_rl_runs_let_torch_have_the_gpu_memory(monkeypatch):
    import dataclasses

    from bar_policy.training.config import preset
    from bar_policy.training.startup.backend_env import set_backend_env

    for var in ("XLA_PYTHON_CLIENT_PREALLOCATE", "XLA_PYTHON_CLIENT_MEM_FRACTION"):
        monkeypatch.delenv(var, raising=False)
    monkeypatch.setenv("PJRT_NPROC", "2")  # the user's choice: the CPU-thread part leaves it alone
    brax, rsl = preset("tiny"), dataclasses.replace(preset("tiny"), backend="rsl-rl")
    assert set_backend_env(brax) == []
    assert "XLA_PYTHON_CLIENT_PREALLOCATE" not in os.environ
    set_backend_env(rsl)
    assert os.environ["XLA_PYTHON_CLIENT_PREALLOCATE"] == "false"
    # A user's own setting wins.
    monkeypatch.delenv("XLA_PYTHON_CLIENT_PREALLOCATE")
    monkeypatch.setenv("XLA_PYTHON_CLIENT_MEM_FRACTION", "0.3")
    set_backend_env(rsl)
    assert "XLA_PYTHON_CLIENT_PREALLOCATE" not in os.environ
    assert os.environ["PJRT_NPROC"] == "2"


def test_runs_compile_with_gspmd_unless_the_user_chose(monkeypatch):
    """The multi-GPU segfault is in Shardy's pipeline (bisect on 2 H200s): runs turn it off, users decide."""
    from bar_policy.training.parallel import choose_partitioner as _set_partitioner

    before = jax.config.jax_use_shardy_partitioner
    try:
        monkeypatch.delenv("JAX_USE_SHARDY_PARTITIONER", raising=False)
        jax.config.update("jax_use_shardy_partitioner", True)
        assert _set_partitioner() == "gspmd" and not jax.config.jax_use_shardy_partitioner
        monkeypatch.setenv("JAX_USE_SHARDY_PARTITIONER", "true")
        jax.config.update("jax_use_shardy_partitioner", True)
        assert _set_partitioner() == "shardy"
    finally:
        jax.config.update("jax_use_shardy_partitioner", before)
