"""bench/action_jacobian.py: the last-action Jacobian of a policy file, against matrices known by hand."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "bench"))
from action_jacobian import last_action_jacobian, probe
from policy_factory import default_metadata, make_policy_file

from bar_policy.obs import ObservationManager


def test_jacobian_of_a_quadratic_is_exact() -> None:
    """f(x) = A x + b * x^2 (elementwise) on the slice: J = A + 2 diag(b x); central differences are exact
    for a quadratic, so only float64 rounding (~1e-16 / 2e-3 per entry) separates them."""
    rng = np.random.default_rng(0)
    n, size = 4, 9
    cols = slice(3, 7)
    a = rng.standard_normal((n, n))
    b = rng.standard_normal(n)
    obs = rng.standard_normal(size)

    def act(o: np.ndarray) -> np.ndarray:
        x = o[cols]
        return a @ x + b * x * x + o[:3].sum()

    expected = a + 2.0 * np.diag(b * obs[cols])
    np.testing.assert_allclose(last_action_jacobian(act, obs, cols), expected, atol=1e-9)


def test_probe_reads_the_files_last_action_block(tmp_path: Path) -> None:
    """A linear track policy ``actions = obs @ W`` whose last-action rows of W hold an upper-triangular M:
    the Jacobian is M^T, its eigenvalues M's diagonal, whatever the other rows and the state."""
    meta = default_metadata(task="track")
    om = ObservationManager.from_json(meta.obs_schema)
    cols = om.term_slice("actions")
    n = len(meta.action_joint_names)
    rng = np.random.default_rng(1)
    diag = np.linspace(-3.0, 0.5, n)
    m = np.triu(0.2 * rng.standard_normal((n, n)), k=1) + np.diag(diag)
    w = 0.01 * rng.standard_normal((om.size, n))
    w[cols] = m
    path = make_policy_file(tmp_path / "lin.onnx", metadata=meta, weight=w)
    obs_rows = 0.3 * rng.standard_normal((3, om.size))
    r = probe(str(path), obs_rows)
    # float32 inference: half an ulp of an action of size <= ~3 is 1.8e-7, over 2 eps = 2e-3 that is ~1e-4 per
    # entry; an eigenvalue of a triangular-plus-rounding matrix moves by about that much.
    np.testing.assert_allclose(r["most_negative_real_per_state"], [-3.0] * 3, atol=1e-3)
    assert abs(r["spectral_radius_mean"] - 3.0) < 1e-3
