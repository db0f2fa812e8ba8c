"""The CPU-thread setting against jaxlib 0.10's LAPACK deadlock, XLA's scheduling flag and jax's GPU memory
pool on a GPU (``training.startup.backend_env``).

The decision is a pure function of the conditions; the subprocess test runs, on a machine where the run
would set it (jaxlib < 0.11, at most ``SMALL_CPU`` cores), the smallest program that deadlocked here:
four independent batched Choleskys of 256 14x14 matrices in a loop. Without the setting it stopped in 6 of
6 runs within 150 calls (docs/performance.md, 2026-11-27); with it the process keeps one XLA thread.
"""

from __future__ import annotations

import dataclasses
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import jaxlib
import pytest

from bar_policy.training.startup import backend_env
from bar_policy.training.startup.backend_env import (
    GRAPHED_LOOPS,
    MEMORY_VARS,
    PREALLOCATE,
    SCHEDULING,
    SMALL_CPU,
    cpu_threads_decision,
    loops_decision,
    memory_decision,
    scheduling_decision,
)

REPO = Path(__file__).resolve().parents[2]


def test_decision_table():
    base = {"cpu_only": True, "jaxlib_version": "0.10.2", "cores": 2, "user_set": False}
    base["backend_started"] = False
    assert cpu_threads_decision(**base) == "set"
    assert cpu_threads_decision(**{**base, "cores": 1}) == "set"
    assert cpu_threads_decision(**{**base, "backend_started": True}) == "note"  # too late to set
    assert cpu_threads_decision(**{**base, "user_set": True}) == "none"  # the user's pool size stays
    assert cpu_threads_decision(**{**base, "cpu_only": False}) == "none"  # a GPU run
    assert cpu_threads_decision(**{**base, "jaxlib_version": "0.11.2"}) == "none"  # fixed upstream
    assert cpu_threads_decision(**{**base, "jaxlib_version": "1.0.0"}) == "none"
    assert cpu_threads_decision(**{**base, "cores": SMALL_CPU + 1}) == "none"  # a larger pool


def test_scheduling_decision_table():
    base = {"cpu_only": False, "xla_flags": "", "backend_started": False}
    assert scheduling_decision(**base) == "set"
    assert scheduling_decision(**{**base, "xla_flags": "--xla_gpu_autotune_level=0"}) == "set"
    assert scheduling_decision(**{**base, "backend_started": True}) == "note"  # too late to set
    assert scheduling_decision(**{**base, "cpu_only": True}) == "none"  # no command buffers on a CPU
    for mode in ("LHS", "SERIALIZE", "CONCURRENT"):  # the user's mode stays, whichever it is
        flags = f"--xla_gpu_autotune_level=0 --xla_gpu_command_buffer_scheduling_mode={mode}"
        assert scheduling_decision(**{**base, "xla_flags": flags}) == "none"
    # A flag whose name merely starts the same is another flag.
    other = "--xla_gpu_command_buffer_scheduling_mode_x=1"
    assert scheduling_decision(**{**base, "xla_flags": other}) == "set"


def test_loops_decision_table():
    """Only a written-out Cholesky asks for while loops in command buffers; the last override wins, as it
    does for the env's config; a user's own command-buffer set stays."""
    base = {"cpu_only": False, "xla_flags": "", "backend_started": False}
    base["env_overrides"] = ("cholesky=columns",)
    assert loops_decision(**base) == "set"
    assert loops_decision(**{**base, "env_overrides": ("sim_dt=0.004", "cholesky = scalar")}) == "set"
    assert loops_decision(**{**base, "backend_started": True}) == "note"
    assert loops_decision(**{**base, "cpu_only": True}) == "none"
    assert loops_decision(**{**base, "env_overrides": ()}) == "none"  # the env's default, library
    assert loops_decision(**{**base, "env_overrides": ("cholesky=library",)}) == "none"
    assert loops_decision(**{**base, "env_overrides": ("cholesky=columns", "cholesky=library")}) == "none"
    assert loops_decision(**{**base, "env_overrides": ("sim_dt=0.004",)}) == "none"
    for user in ("--xla_gpu_enable_command_buffer=", "--xla_gpu_enable_command_buffer=+WHILE,+CONDITIONAL"):
        assert loops_decision(**{**base, "xla_flags": f"{SCHEDULING} {user}"}) == "none"
    assert loops_decision(**{**base, "xla_flags": SCHEDULING}) == "set"
    # The forms it asks for are the env's written-out ones, whatever the env adds later.
    from bar_policy.envs.physics_step import CHOLESKY

    assert set(backend_env.WRITTEN_OUT) == set(CHOLESKY) - {"library"}


def _no_memory_choice(monkeypatch: pytest.MonkeyPatch) -> None:
    """Neither memory variable in the environment, and both restored after the test (``set_backend_env``
    writes ``os.environ`` itself: a variable that was absent is recorded first, so it is removed again)."""
    for var in MEMORY_VARS:
        monkeypatch.setenv(var, "")
        monkeypatch.delenv(var)


def test_memory_decision_table():
    """GPU runs of either backend grow jax's pool on demand; rsl-rl on any platform (torch's share); a
    CPU-only brax run has no pool; a user's variable wins; a backend already up gets a note on a GPU."""
    base = {"cpu_only": False, "backend": "brax", "user_set": False, "backend_started": False}
    assert memory_decision(**base) == "set"
    assert memory_decision(**{**base, "backend": "rsl-rl"}) == "set"
    assert memory_decision(**{**base, "cpu_only": True}) == "none"
    assert memory_decision(**{**base, "cpu_only": True, "backend": "rsl-rl"}) == "set"
    assert memory_decision(**{**base, "user_set": True}) == "none"
    assert memory_decision(**{**base, "user_set": True, "backend": "rsl-rl"}) == "none"
    assert memory_decision(**{**base, "backend_started": True}) == "note"
    late_cpu_rsl = {**base, "backend_started": True, "cpu_only": True, "backend": "rsl-rl"}
    assert memory_decision(**late_cpu_rsl) == "set"  # jax's CPU backend has no GPU pool: set for torch's sake


def test_a_gpu_brax_run_grows_the_memory_pool_unless_the_user_chose(monkeypatch):
    monkeypatch.setattr(backend_env, "_cpu_only", lambda: False)
    monkeypatch.setattr("jax._src.xla_bridge.backends_are_initialized", lambda: False)
    monkeypatch.setenv("XLA_FLAGS", SCHEDULING)  # the scheduling part has nothing to add
    _no_memory_choice(monkeypatch)
    from bar_policy.training.config import preset

    notes = backend_env.set_backend_env(preset("tiny"))
    assert os.environ[PREALLOCATE] == "false"
    assert len(notes) == 1 and f"{PREALLOCATE}=false" in notes[0]
    assert backend_env.set_backend_env(preset("tiny")) == []  # now the environment holds a choice
    for var, value in ((PREALLOCATE, "true"), ("XLA_PYTHON_CLIENT_MEM_FRACTION", "0.5")):
        _no_memory_choice(monkeypatch)
        monkeypatch.setenv(var, value)
        assert backend_env.set_backend_env(preset("tiny")) == []
        assert os.environ[var] == value and all(v == var or v not in os.environ for v in MEMORY_VARS)
    _no_memory_choice(monkeypatch)
    monkeypatch.setattr("jax._src.xla_bridge.backends_are_initialized", lambda: True)
    notes = backend_env.set_backend_env(preset("tiny"))
    assert PREALLOCATE not in os.environ and len(notes) == 1 and "already runs" in notes[0]


def test_a_written_out_cholesky_run_appends_both_flags(monkeypatch):
    monkeypatch.setattr(backend_env, "_cpu_only", lambda: False)
    monkeypatch.setattr("jax._src.xla_bridge.backends_are_initialized", lambda: False)
    monkeypatch.delenv("XLA_FLAGS", raising=False)
    _no_memory_choice(monkeypatch)
    from bar_policy.training.config import preset

    cfg = dataclasses.replace(preset("tiny"), env_overrides=("cholesky=columns",))
    notes = backend_env.set_backend_env(cfg)
    assert os.environ["XLA_FLAGS"] == f"{SCHEDULING} {GRAPHED_LOOPS}"
    assert len(notes) == 3 and GRAPHED_LOOPS in notes[1] and PREALLOCATE in notes[2]
    assert backend_env.set_backend_env(cfg) == []  # nothing twice
    assert backend_env.set_backend_env(preset("tiny")) == []  # library: nothing to add


def test_a_gpu_run_appends_the_flag_and_keeps_the_users(monkeypatch):
    """The GPU branch with the platform faked (this machine has no GPU): the user's flags are kept in front,
    a second call adds nothing, and a run that already runs jax's backend gets the note only."""
    monkeypatch.setattr(backend_env, "_cpu_only", lambda: False)
    monkeypatch.setattr("jax._src.xla_bridge.backends_are_initialized", lambda: False)
    monkeypatch.setenv("PJRT_NPROC", "2")
    monkeypatch.setenv("XLA_FLAGS", "--xla_gpu_autotune_level=0")
    monkeypatch.setenv("XLA_PYTHON_CLIENT_MEM_FRACTION", "0.75")  # the memory part stays out of this test
    from bar_policy.training.config import preset

    notes = backend_env.set_backend_env(preset("tiny"))
    assert os.environ["XLA_FLAGS"] == f"--xla_gpu_autotune_level=0 {SCHEDULING}"
    assert len(notes) == 1 and SCHEDULING in notes[0]
    assert backend_env.set_backend_env(preset("tiny")) == []
    assert os.environ["XLA_FLAGS"] == f"--xla_gpu_autotune_level=0 {SCHEDULING}"
    monkeypatch.delenv("XLA_FLAGS")
    monkeypatch.setattr("jax._src.xla_bridge.backends_are_initialized", lambda: True)
    notes = backend_env.set_backend_env(preset("tiny"))
    assert "XLA_FLAGS" not in os.environ and "already runs" in notes[0]


AFFECTED = (
    tuple(int(p) for p in jaxlib.__version__.split(".")[:2]) < (0, 11)
    and len(os.sched_getaffinity(0)) <= SMALL_CPU
)


@pytest.mark.slow
@pytest.mark.skipif(not AFFECTED, reason="this machine's run would not set PJRT_NPROC (jaxlib or cores)")
def test_batched_choleskys_that_deadlocked_run_with_the_setting():
    script = textwrap.dedent(
        """
        import dataclasses, os
        from pathlib import Path
        from bar_policy.training.startup.backend_env import set_backend_env
        from bar_policy.training.config import preset
        notes = set_backend_env(preset("tiny"))
        assert os.environ["PJRT_NPROC"] == "1" and "PJRT_NPROC=1" in notes[0], notes
        import jax, jax.numpy as jnp
        B, N, K = 256, 14, 4  # 256 x 14^3 / 3 = 234k >= 200k: jaxlib 0.10 splits each call over the pool
        x = jax.random.normal(jax.random.PRNGKey(0), (B, N, N))
        spd = x @ jnp.swapaxes(x, -1, -2) + N * jnp.eye(N)

        @jax.jit
        def f(a):
            def body(i, c):
                outs = []
                for k in range(K):  # independent inputs: XLA may run the K factorisations at once
                    big = jnp.tanh(jnp.broadcast_to(c[k][:, None], (B, 64, N, N)) * 1e-3).sum(1)
                    outs.append(jnp.linalg.cholesky(a + k + 1e-3 * big @ jnp.swapaxes(big, -1, -2)))
                return outs
            return jax.lax.fori_loop(0, 20, body, [a] * K)

        for _ in range(150):
            out = jax.block_until_ready(f(spd))
        names = [p.read_text().strip() for p in Path("/proc/self/task").glob("*/comm")]
        pool = sum(n == "tf_XLAEigen" for n in names)
        print("xla threads", pool, "finite", bool(jnp.isfinite(out[0]).all()))
        """
    )
    env = {**os.environ, "JAX_PLATFORMS": "cpu", "PYTHONPATH": str(REPO)}
    env.pop("PJRT_NPROC", None)
    r = subprocess.run([sys.executable, "-c", script], env=env, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-3000:]
    assert "xla threads 1 finite True" in r.stdout, r.stdout
