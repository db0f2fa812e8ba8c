"""LiteReach's step outputs are bit-identical to the recording made before the robot env / task split.

``tests/data/reach_golden.npz`` was written by ``tests/data/make_reach_golden.py`` from the unsplit env
(commit bec536f). Both rollouts replay with the session fixtures' compiled functions (no extra compile):
the nominal env unbatched, and the training config (randomisation on, 1 s episodes) batched through the
randomised wrapper across an auto-reset. Every array must match exactly (atol = 0): obs, reward, done,
metrics, qpos, qvel and every info leaf.
"""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest
from env_support import BATCH

_DATA = Path(__file__).parents[1] / "data"


def _maker():
    spec = importlib.util.spec_from_file_location("make_reach_golden", _DATA / "make_reach_golden.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


MAKER = _maker()


@pytest.fixture(scope="module")
def golden() -> dict[str, np.ndarray]:
    with np.load(MAKER.GOLDEN_PATH) as f:
        return {k: f[k] for k in f.files}


def _compare(run: str, got: dict[str, np.ndarray], golden: dict[str, np.ndarray]) -> None:
    want = {k.split("/", 1)[1]: v for k, v in golden.items() if k.startswith(f"{run}/")}
    assert sorted(got) == sorted(want), f"{run}: keys differ: {sorted(set(got) ^ set(want))}"
    for key, w in want.items():
        g = got[key]
        assert (g.dtype, g.shape) == (w.dtype, w.shape), f"{run}/{key}: {g.dtype}{g.shape}"
        np.testing.assert_array_equal(g, w, err_msg=f"{run}/{key}")


def test_nominal_step_identical_to_golden(nominal_fns, golden):
    reset, step = nominal_fns
    _compare("nominal", MAKER.record_nominal(reset, step), golden)


def test_randomised_batched_step_identical_to_golden(wrapped, dr_env, golden):
    # The fixture is the recorded configuration: batch, 1 s episodes, 0.5 s segments.
    assert BATCH == MAKER.BATCH and MAKER.DR_OVERRIDES == ("episode_length_s=1.0", "resample_period_s=0.5")
    assert (dr_env.config.episode_length_s, dr_env.config.resample_period_s) == (1.0, 0.5)
    assert dr_env.episode_length < MAKER.WRAPPED_STEPS  # the rollout crosses an auto-reset
    _, reset, step = wrapped
    _compare("wrapped", MAKER.record_wrapped(reset, step), golden)
