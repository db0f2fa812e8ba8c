"""LiteReach's step outputs match the recording made before the robot env / task split, on any x86-64 CPU.

``tests/data/reach_golden.npz`` was written by ``tests/data/make_reach_golden.py`` from the unsplit env
(commit bec536f) on a machine with AVX-512, and re-recorded on an AVX2 machine when the reach recipe changed
on purpose (the smoothness terms and action filter; the maker's docstring). Both rollouts replay
with the session fixtures' compiled functions (no extra compile): the nominal env unbatched, and the
training config (randomisation on, 1 s episodes) batched through the randomised wrapper across an
auto-reset.

XLA emits different CPU code for different instruction sets (SSE4.2, AVX, AVX2, AVX-512: fused
multiply-adds, vector widths and reduction orders differ), so a float32 result can differ in its last bits
between machines. ``XLA_FLAGS=--xla_cpu_max_isa=AVX2`` (or ``SSE4_2``) reproduces another machine on one
that has more. The comparison is therefore:

- **Integer and boolean leaves exactly** (done, episode step counters, latency, PRNG keys): they carry the
  episode structure (when the auto-reset fires, which target segment is active), and no rounding reaches
  them.
- **Float leaves within the float32 rounding bound of the rollout's length.** Each physics substep
  rounds the state once at relative size ``eps32 = 2**-23 ~ 1.19e-7``; the MIT-law arm is damped (Kd, the
  implicit joint damping), so an error is not amplified between steps in the smooth regime and at most
  adds up: after ``t`` control steps of ``N_SUB = 10`` substeps the error is at most
  ``(N_SUB * t + R_RESET) * eps32 * S``, with ``S`` the largest magnitude of that leaf in the recording and
  ``R_RESET = 4`` the roundings of the reset itself (a per-episode sample such as Kp is four float32
  operations from exact key bits: to [0, 1), times the width, plus the low end, times the nominal).
  Measured against this recording (commit 5a90292 code): AVX2, AVX and SSE4.2 code stay 7-30x inside it on
  every nominal leaf.
- **The randomised rollout is chaotic mid-episode**, so only what is stable is compared per element: the
  first ``SHORT_STEPS`` control steps after the reset and after the auto-reset (each a short horizon from a
  state rebuilt from exact keys). Between them a discrete event (a joint's torque saturating one ulp
  earlier, which moves its Kd term between the implicit damping and the applied force; a frictionloss
  constraint switching) amplifies a rounding difference about 100x for a few steps (measured: 2.4e-3 rad/s
  on one wrist at step 21, decaying within 10 steps). There the test compares statistics: each float
  leaf's mean over the batch and the whole rollout, within the bound at the rollout's length (averaging
  over 8 x 56 samples dilutes a local excursion; measured 30-8000x inside on every leaf and ISA).

- **The distance kernels amplify the state's rounding.** ``1 - tanh(d / std)`` has slope up to ``1 / std``
  in the fingertip distance ``d``, whose own rounding is relative to the fingertip coordinates (up to
  ``REACH_M`` = 0.75 m, the shoulder-to-fingertip length plus the shoulder offset): a reward leaf that
  holds a kernel is bounded with the scale ``max(S, sum_k |w_k| REACH_M / std_k)`` (25 for ``reach_fine``
  at 3 cm, 5 for ``reach_coarse``, 30 for ``reward``) instead of its own magnitude ``S``. Measured on this
  recording (commit after 8c508c3, AVX2): SSE4.2 and AVX code differ on ``reach_fine`` by 25 eps32 S at
  step 1 (S = 0.81), outside the plain bound and 12x inside this one; XLA's ``tanh`` itself also differs
  between instruction sets by a few ulps.

A real change (a reward weight, the law, a randomisation range) moves these figures by orders of magnitude
more than the bound (a 1 % change of the smallest reward weight, 0.5, moves ``reward`` by ~1e-3 on a
step; the bound on ``reward`` is ~1e-5 over 10 steps).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from env_support import BATCH
from script_modules import load_script

pytestmark = pytest.mark.numerics  # compares XLA floats with another implementation / a recording

_DATA = Path(__file__).parents[1] / "data"

EPS32 = float(np.finfo(np.float32).eps)
"""float32 machine epsilon, 2**-23."""
N_SUB = 10
"""Physics substeps per control step (ctrl_dt 20 ms / sim_dt 2 ms): one rounding of the state each."""
R_RESET = 4
"""Roundings in the reset (see the module docstring)."""
SHORT_STEPS = 10
"""Control steps compared element by element after each (auto-)reset of the randomised rollout."""
REACH_M = 0.75
"""Largest fingertip coordinate magnitude, m (module docstring)."""


def _kernel_gains() -> dict[str, float]:
    """Slope bound ``|w| REACH_M / std`` of each kernel reward leaf, from the env's own weights and widths."""
    from bar_policy.tasks.reach.env import RewardConfig

    rc = RewardConfig()
    fine = abs(rc.scales.reach_fine) * REACH_M / rc.fine_std
    coarse = abs(rc.scales.reach_coarse) * REACH_M / rc.coarse_std
    return {"reward/reach_fine": fine, "reward/reach_coarse": coarse, "reward": fine + coarse}


KERNEL_GAINS = _kernel_gains()


def _scale(key: str, w: np.ndarray) -> float:
    """The leaf's scale ``S`` for the bound: its largest magnitude, or a kernel's slope bound if larger.

    Per-step leaves only (``reward``, ``metrics/reward/...``); episode sums (``info/episode_metrics/...``)
    are large enough on their own.
    """
    s = float(np.abs(w).max())
    if key.startswith("info/"):
        return s
    for suffix, gain in KERNEL_GAINS.items():
        if key == suffix or key.endswith("/" + suffix):
            return max(s, gain)
    return s


MAKER = load_script(_DATA / "make_reach_golden.py", "make_reach_golden")


@pytest.fixture(scope="module")
def golden() -> dict[str, np.ndarray]:
    with np.load(MAKER.GOLDEN_PATH) as f:
        return {k: f[k] for k in f.files}


def _bound(scale: float, steps: np.ndarray) -> np.ndarray:
    """Rounding bound after ``steps`` control steps from a reset: ``(N_SUB * t + R_RESET) * eps32 * S``."""
    return (N_SUB * steps + R_RESET) * EPS32 * scale


def _split(run: str, got: dict[str, np.ndarray], golden: dict[str, np.ndarray]) -> dict:
    """{key: (got, want)}; keys, dtypes and shapes must match exactly."""
    want = {k.split("/", 1)[1]: v for k, v in golden.items() if k.startswith(f"{run}/")}
    assert sorted(got) == sorted(want), f"{run}: keys differ: {sorted(set(got) ^ set(want))}"
    pairs = {}
    for key, w in want.items():
        g = got[key]
        assert (g.dtype, g.shape) == (w.dtype, w.shape), (
            f"{run}/{key}: {g.dtype}{g.shape}, not {w.dtype}{w.shape}"
        )
        pairs[key] = (g, w)
    return pairs


def _check_exact(run: str, pairs: dict) -> list[str]:
    """Integer and boolean leaves bit for bit; returns the float keys left to compare."""
    floats = []
    for key, (g, w) in pairs.items():
        if w.dtype.kind == "f":
            floats.append(key)
        else:
            np.testing.assert_array_equal(g, w, err_msg=f"{run}/{key} (integer/boolean: exact)")
    return floats


def _check_window(
    run: str, key: str, g: np.ndarray, w: np.ndarray, first: int, stop: int, t0: int = 0
) -> None:
    """Steps [first, stop) of a leaf (time on axis 0); step ``first`` is ``t0`` steps after a reset."""
    scale = _scale(key, w)
    t = t0 + np.arange(stop - first).reshape((-1,) + (1,) * (w.ndim - 1))
    err = np.abs(g[first:stop].astype(np.float64) - w[first:stop])
    tol = np.broadcast_to(_bound(scale, t), err.shape)
    bad = err > tol
    if bad.any():
        i = np.argwhere(bad)[0]
        raise AssertionError(
            f"{run}/{key} step {first + i[0]}: |got - golden| = {err[tuple(i)]:.3g} > "
            f"(10 t + 4) eps32 S = {tol[tuple(i)].item():.3g} (t = {t0 + i[0]}, S = {scale:.3g})"
        )


def test_nominal_step_matches_golden(nominal_fns, golden):
    """Unbatched nominal env, 30 control steps of uniform random actions: every leaf, every step."""
    reset, step = nominal_fns
    pairs = _split("nominal", MAKER.record_nominal(reset, step), golden)
    for key in _check_exact("nominal", pairs):
        g, w = pairs[key]
        _check_window("nominal", key, g, w, 0, len(w))


def test_randomised_batched_step_matches_golden(wrapped, dr_env, golden):
    # The fixture is the recorded configuration: batch, 1 s episodes, 0.5 s segments.
    assert BATCH == MAKER.BATCH and MAKER.DR_OVERRIDES == (
        "episode_length_s=1.0",
        "resample_period_s=0.5",
        "target_transition_s=0.2",
    )
    assert (dr_env.config.episode_length_s, dr_env.config.resample_period_s) == (1.0, 0.5)
    assert dr_env.episode_length < MAKER.WRAPPED_STEPS  # the rollout crosses an auto-reset
    _, reset, step = wrapped
    pairs = _split("wrapped", MAKER.record_wrapped(reset, step), golden)
    floats = _check_exact("wrapped", pairs)  # done pattern exact: every env auto-resets at the same step
    n = dr_env.episode_length  # the step at which every env auto-resets (done at n, index n of the record)
    assert pairs["done"][1][n].all() and not pairs["done"][1][:n].any()
    total = len(pairs["done"][1])
    for key in floats:
        g, w = pairs[key]
        _check_window("wrapped", key, g, w, 0, SHORT_STEPS + 1)  # from the reset
        # From the auto-reset: the record at step n holds the new episode's state (obs, data, info) but
        # the ended episode's last transition (reward, metrics, the episode sums), so those restart at n + 1.
        ended = key in ("reward",) or key.startswith(("metrics/", "info/episode_metrics/"))
        first = n + 1 if ended else n
        _check_window("wrapped", key, g, w, first, min(n + SHORT_STEPS + 1, total), t0=first - n)
        # Statistics over the whole rollout: the mean within the bound at its length.
        err = abs(float(g.astype(np.float64).mean()) - float(w.astype(np.float64).mean()))
        tol = float(_bound(_scale(key, w), np.array(total - 1)))
        assert err <= tol, f"wrapped/{key}: |mean(got) - mean(golden)| = {err:.3g} > {tol:.3g}"
