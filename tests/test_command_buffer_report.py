"""bench/command_buffers.py: what of a GPU program runs outside XLA's command buffers, read from its HLO.

The GPU-shaped module below is written by hand in XLA's HLO text format (what
``--xla_dump_hlo_as_text`` writes after ``command-buffer-scheduling``), so every count it must give is known:
the entry calls one command buffer holding two fusions and a while loop (whose body's cuBLAS call is
recorded with it), then runs a while loop from the host whose body holds a cuSOLVER call outside any
command buffer and a second command buffer. The CPU module is a real XLA dump (a jitted while loop on
this machine), which has no command buffers at all.
"""

from __future__ import annotations

import importlib.util
import os
import subprocess
import sys
from pathlib import Path

BENCH = Path(__file__).resolve().parents[1] / "bench"
sys.path.insert(0, str(BENCH))  # the script imports its sibling report.py, as when run from bench/
spec = importlib.util.spec_from_file_location("command_buffers", BENCH / "command_buffers.py")
cb = importlib.util.module_from_spec(spec)
sys.modules["command_buffers"] = cb
spec.loader.exec_module(cb)

GPU_HLO = """HloModule jit_rollout, entry_computation_layout={(f32[8]{0})->f32[8]{0}}

%fused_a (p: f32[8]) -> f32[8] {
  %p = f32[8]{0} parameter(0)
  ROOT %t = f32[8]{0} tanh(%p)
}

%inner_body (arg: (s32[], f32[8])) -> (s32[], f32[8]) {
  %arg = (s32[], f32[8]{0}) parameter(0)
  %g = f32[8]{0} get-tuple-element(%arg), index=1
  %gemm = (f32[8]{0}, s8[0]{0}) custom-call(%g, %g), custom_call_target="__cublas$gemm"
  %i = s32[] get-tuple-element(%arg), index=0
  %inc = s32[] fusion(%i), kind=kLoop, calls=%fused_a
  ROOT %r = (s32[], f32[8]{0}) tuple(%inc, %g)
}

%inner_cond (arg: (s32[], f32[8])) -> pred[] {
  %arg = (s32[], f32[8]{0}) parameter(0)
  ROOT %c = pred[] fusion(%arg), kind=kLoop, calls=%fused_a
}

%command_buffer (p0: f32[8]) -> f32[8] {
  %p0 = f32[8]{0} parameter(0)
  %f1 = f32[8]{0} fusion(%p0), kind=kLoop, calls=%fused_a
  %f2 = f32[8]{0} fusion(%f1), kind=kInput, calls=%fused_a
  %tup = (s32[], f32[8]{0}) tuple(%f1, %f2)
  ROOT %w = (s32[], f32[8]{0}) while(%tup), condition=%inner_cond, body=%inner_body, TRIP5
}

%command_buffer.1 (p0: f32[8]) -> f32[8] {
  %p0 = f32[8]{0} parameter(0)
  ROOT %f3 = f32[8]{0} fusion(%p0), kind=kLoop, calls=%fused_a
}

%newton_body (arg: (s32[], f32[8])) -> (s32[], f32[8]) {
  %arg = (s32[], f32[8]{0}) parameter(0)
  %x = f32[8]{0} get-tuple-element(%arg), index=1
  %potrf = (f32[8]{0}, s32[]) custom-call(%x), custom_call_target="cusolver_potrf_ffi"
  %cb = f32[8]{0} call(%x), to_apply=%command_buffer.1
  ROOT %r = (s32[], f32[8]{0}) tuple(%x, %cb)
}

%newton_cond (arg: (s32[], f32[8])) -> pred[] {
  %arg = (s32[], f32[8]{0}) parameter(0)
  %x = f32[8]{0} get-tuple-element(%arg), index=1
  ROOT %done = pred[] fusion(%x), kind=kLoop, calls=%fused_a
}

ENTRY %main (x: f32[8]) -> f32[8] {
  %x = f32[8]{0} parameter(0)
  %k = f32[] constant(1)
  %cb0 = (s32[], f32[8]{0}) call(%x), to_apply=%command_buffer
  %t = (s32[], f32[8]{0}) tuple(%x, %x)
  %loop = (s32[], f32[8]{0}) while(%t), condition=%newton_cond, body=%newton_body
  ROOT %out = f32[8]{0} get-tuple-element(%loop), index=1
}
""".replace("TRIP5", 'backend_config={"known_trip_count":{"n":"5"}}')


def test_a_gpu_module_s_graphs_and_what_runs_outside_them():
    mod = cb.parse(GPU_HLO)
    assert mod.entry == "main"
    rep = cb.analyse(mod)
    # Two command-buffer calls: the entry's and the one in the host loop's body.
    assert rep.graphs == 2
    # Recorded: f1, f2, the inner while, its body's gemm and increment, its condition's fusion; then f3.
    assert rep.in_graphs == {
        "fusion kLoop": 4,  # f1, the inner increment, the inner condition, f3
        "fusion kInput": 1,  # f2
        "while": 1,
        "custom-call __cublas$gemm": 1,
    }
    # One loop runs from the host, with no known trip count (a solver's convergence loop).
    assert rep.host_loops == [("entry / loop", "unknown")]
    # Outside any command buffer: the cuSOLVER call in that loop's body and its condition's fusion.
    assert rep.outside == {
        ("custom-call cusolver_potrf_ffi", "entry / loop"): 1,
        ("fusion kLoop", "entry / loop"): 1,
    }
    text = "\n".join(cb.render("jit_rollout", rep, True))
    assert "command buffers: 2, recording 7 instructions (1 of them while loops)" in text
    assert "while loops run from the host: 1; other instructions outside a command buffer: 2" in text


def test_a_real_cpu_dump_has_no_command_buffer(tmp_path):
    """A jitted 3-step while loop dumped by this machine's XLA: no graphs; the loop runs from the host."""
    code = (
        "import jax, jax.numpy as jnp\n"
        "def f(x):\n"
        "    body = lambda c: (c[0] + 1, jnp.tanh(c[1] @ c[1]))\n"
        "    return jax.lax.while_loop(lambda c: c[0] < 3, body, (0, x))[1].sum()\n"
        "jax.jit(f)(jnp.ones((4, 4))).block_until_ready()\n"
    )
    env = {
        **os.environ,
        "JAX_PLATFORMS": "cpu",
        "XLA_FLAGS": f"--xla_dump_to={tmp_path} --xla_dump_hlo_as_text",
    }
    subprocess.run([sys.executable, "-c", code], check=True, env=env, timeout=120)
    out = tmp_path / "report.md"
    assert cb.main([str(tmp_path), "--module", "jit_f", "--out", str(out)]) == 0
    text = out.read_text()
    assert "No `command_buffer` computation in this HLO" in text
    assert "command buffers: 0, recording 0 instructions" in text
    assert "while loops run from the host: 1" in text
    assert "| entry / while.0 | 3 |" in text  # XLA knows the trip count of a fori-style loop
    # The loop body's work (the matmul and tanh; how XLA's CPU backend emits the matmul may differ between
    # machines) is counted inside the loop, outside any graph.
    assert any(line.endswith("| entry / while.0 | 1 |") for line in text.splitlines())
