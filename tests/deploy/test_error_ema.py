"""``joint_error_ema`` on the deploy side: the runtime's inputs keep the average over POLICY ticks.

A policy file of the reach layout's opt-in next version (``obs.robot_layout.with_error_ema``) runs on the
sim target; the logged observation's term must equal the average worked out here from the logged states
and commands: 0 on the first POLICY tick, then ``z_k = z_{k-1} + 0.04 ((q_cmd_{k-1} - q_k) - z_{k-1})``
(alpha = 0.02 s / 0.5 s), times the term's scale 10. The shipped layouts stay what their golden files say.
"""

from __future__ import annotations

import numpy as np
import pytest
from policy_factory import default_metadata, make_policy_file

from bar_policy.deploy.cli import main
from bar_policy.deploy.log.read import load_log
from bar_policy.obs.manager import SHIPPED_LAYOUTS, ObservationManager, shipped_managers
from bar_policy.obs.robot_layout import with_error_ema
from bar_policy.robot.error_ema import error_ema_alpha


def test_shipped_layouts_are_the_golden_ones_and_the_term_is_opt_in() -> None:
    for name, om in shipped_managers().items():
        golden = ObservationManager.golden(name)
        assert om.schema == golden.schema and om.fingerprint == golden.fingerprint, name
        assert "joint_error_ema" not in om.term_names
    v2 = with_error_ema(ObservationManager.golden("lite_reach_arms").schema)
    assert (v2.name, v2.version, v2.terms[-1].name, v2.terms[-1].size) == (
        "lite_reach_arms",
        2,
        "joint_error_ema",
        14,
    )
    assert ObservationManager(v2).size == ObservationManager.golden("lite_reach_arms").size + 14
    assert "lite_reach_arms" in SHIPPED_LAYOUTS


def test_runtime_term_is_the_average_of_the_logged_states(tmp_path) -> None:
    om = ObservationManager(with_error_ema(ObservationManager.for_task("reach", "arms").schema))
    meta = default_metadata(obs_schema=om.schema.to_json(), obs_fingerprint=om.fingerprint)
    policy = make_policy_file(tmp_path / "ema.onnx", metadata=meta, bias=0.3)  # a constant action: a step
    logs = tmp_path / "runs"
    argv = [
        "--policy",
        str(policy),
        "--target",
        "sim",
        "--start",
        "policy",
        "--duration",
        "0.6",
        "--log",
        str(logs),
    ]
    assert main(argv) == 0
    (run,) = logs.iterdir()
    arrays, _ = load_log(run)
    z_logged = om.split(arrays["obs"])["joint_error_ema"] / 10.0
    policy_tick = arrays["mode"] == arrays["mode"][-1]  # POLICY from the first tick to the end
    assert policy_tick.all() and len(z_logged) >= 25
    alpha = error_ema_alpha(0.02)
    assert alpha == pytest.approx(0.04)
    z = np.zeros(14)
    for k in range(len(z_logged)):
        if k > 0:
            z = z + alpha * ((arrays["q_cmd"][k - 1] - arrays["q"][k]) - z)
        # The logged observation is float32: |z| * 10 < 10 reads to 1e-6 (ulp 9.5e-7 below 8), / 10.
        np.testing.assert_allclose(z_logged[k], z, rtol=0, atol=2e-7, err_msg=f"tick {k}")
    assert np.abs(z).max() > 1e-3  # the step left a visible error to average
