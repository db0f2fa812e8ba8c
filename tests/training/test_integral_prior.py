"""The reference prior's integral term: ``error_gain`` times the error average ``joint_error_ema`` added to
the command, by hand, in a closed loop worked out by hand, through the ONNX graph, and its refusals.

Expected values: the prior's command is ``q_ref + G z`` (``obs.action_prior``, "Integral term"); in a
quasi-static loop where the P-law's spring carries a constant load ``tau_l`` (``q = q_cmd - tau_l / Kp``, the
arm settled within each 20 ms step), the average's step ``z_k = z_{k-1} + alpha ((q_cmd_{k-1} - q_k) -
z_{k-1})`` sees ``q_cmd - q = tau_l / Kp`` every step, so from ``z_1 = 0`` (the policy's first tick)
``z_k = (tau_l / Kp)(1 - (1 - alpha)^(k - 1))`` and at gain 1 the error ``q_ref - q_k = (tau_l / Kp)(1 -
alpha)^(k - 1)``: it decays at 1 / tau (alpha = 0.02 / 0.5 = 0.04) where the reference prior alone holds
``tau_l / Kp`` for ever.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from bar_policy.export.graph import MlpPolicy, build_onnx_model
from bar_policy.export.parity import _run_onnx
from bar_policy.obs import ObservationManager
from bar_policy.obs.action_prior import ActionPrior, reference_prior
from bar_policy.obs.robot_layout import with_error_ema
from bar_policy.robot.constants import load_robot
from bar_policy.robot.error_ema import ERROR_EMA_SCALE, error_ema_alpha, error_ema_step
from bar_policy.tasks.track import track_action_scale, track_default_pose
from bar_policy.training.config import NetworkConfig

N = 14
K = 5  # the tracking layout's lookahead frames


@pytest.fixture(scope="module")
def v2():
    """The tracking layout with the error average (its v2, the robust presets' layout)."""
    return ObservationManager(with_error_ema(ObservationManager.for_task("track", "arms").schema))


@pytest.fixture(scope="module")
def pose_scale():
    return np.asarray(track_default_pose(), np.float64), np.asarray(track_action_scale("arms"), np.float64)


def _obs(layout: ObservationManager, q_ref: np.ndarray, z: np.ndarray, rng=None) -> np.ndarray:
    """An observation whose reference frames all hold ``q_ref`` (N,) and whose error average is ``z`` (rad);
    every other term random (``rng``) or 0."""
    inputs = {}
    for t in layout.schema.terms:
        inputs[t.name] = (
            np.zeros(t.size, np.float32) if rng is None else rng.uniform(-0.5, 0.5, t.size).astype(np.float32)
        )
    inputs["motion_joint_pos"] = np.tile(q_ref, K).astype(np.float32)
    inputs["joint_error_ema"] = np.asarray(z, np.float32)
    return np.asarray(layout.compute(inputs), np.float32)


def test_integral_term_adds_gain_times_the_error_average(v2, pose_scale):
    """prior(obs) = (q_ref - default) / scale + G z / scale, by hand for G = 0, 0.5, 1 (the term's obs entry
    is 10 z, its gain G / (10 scale)); at G = 0 the prior is the plain one. float32: actions below 1 through
    two multiply-adds, a few ulps (6e-8 each): 1e-6."""
    default, scale = pose_scale
    rng = np.random.default_rng(0)
    q_ref = default + scale * rng.uniform(-0.5, 0.5, N)
    z = rng.uniform(-0.03, 0.03, N)
    obs = _obs(v2, q_ref, z, rng)
    for gain in (0.0, 0.5, 1.0):
        prior = reference_prior(v2, default, scale, 3, error_gain=gain)
        want = (q_ref - default + gain * z) / scale
        np.testing.assert_allclose(prior.apply(obs), want, atol=1e-6, err_msg=f"gain {gain}")
    plain = reference_prior(v2, default, scale, 3)
    assert not plain.has_error_term and plain == reference_prior(v2, default, scale, 3, error_gain=0.0)
    ema = v2.term_slice("joint_error_ema")
    full = reference_prior(v2, default, scale, 3, error_gain=1.0)
    assert full.error_index == tuple(range(ema.start, ema.stop))
    np.testing.assert_allclose(full.error_gain, 1.0 / (ERROR_EMA_SCALE * scale), rtol=1e-12)
    assert full.to_dict()["error_index"] == list(full.error_index)


def test_integral_term_cancels_a_steady_load_in_a_closed_loop(v2, pose_scale):
    """The quasi-static loop of the module docstring, 50 steps, a load worth 0.5-2 N*m per joint: at gain 1
    the error is (tau_l / Kp) 0.96^(k - 1) (0.135 of the sag at k = 50), at gain 0 the sag itself. The loop
    runs the prior in float32 (1e-7 rad per step, damped by 0.96 a step: 2.5e-6 at most), so 5e-6 rad."""
    default, scale = pose_scale
    kp = np.asarray(load_robot("arms").kp, np.float64)
    alpha = error_ema_alpha(0.02)
    assert alpha == pytest.approx(0.04)
    sag = np.linspace(0.5, 2.0, N) / kp  # tau_l / Kp, rad: 0.01-0.04
    q_ref = default + 0.3 * scale
    for gain, want in ((1.0, sag * (1 - alpha) ** 49), (0.0, sag)):
        prior = reference_prior(v2, default, scale, 1, error_gain=gain)
        z, q_cmd = np.zeros(N), q_ref.copy()
        q = q_cmd - sag
        for k in range(1, 51):
            z = error_ema_step(z, q_cmd, q, alpha) if k > 1 else z  # z_1 = 0: the policy's first tick
            q_cmd = default + scale * prior.apply(_obs(v2, q_ref, z)).astype(np.float64)
            q = q_cmd - sag  # the spring carries the load within the step
        # after 50 commands z is z_49 = sag (1 - 0.96^49) and q = q_ref + G z_49 - sag
        np.testing.assert_allclose(q_ref - q, want, atol=5e-6, err_msg=f"gain {gain}")


def test_onnx_graph_carries_the_integral_term(v2, pose_scale):
    """A zero MLP with the integral prior: the graph's actions equal the prior's numpy ``apply`` on random
    observations (float32 through the same ops, tanh(atanh(a)) for |a| < 0.99: 1e-5); the term adds one
    Gather of the error entries; a prior without it exports the one Gather it always had."""
    default, scale = pose_scale
    rng = np.random.default_rng(1)
    obs = np.stack(
        [
            _obs(v2, default + scale * rng.uniform(-0.6, 0.6, N), rng.uniform(-0.04, 0.04, N), rng)
            for _ in range(8)
        ]
    )

    def graph(prior: ActionPrior):
        return build_onnx_model(MlpPolicy.prior_only(v2.size, prior))

    with_term = reference_prior(v2, default, scale, 5, error_gain=1.0)
    model = graph(with_term)
    np.testing.assert_allclose(_run_onnx(model.SerializeToString(), obs), with_term.apply(obs), atol=1e-5)
    gathers = [n for n in model.graph.node if n.op_type == "Gather"]
    assert [g.input[1] for g in gathers] == ["prior_index", "prior_error_index"]
    plain = graph(reference_prior(v2, default, scale, 5))
    assert [n.input[1] for n in plain.graph.node if n.op_type == "Gather"] == ["prior_index"]


def test_integral_term_refusals(v2, pose_scale):
    default, scale = pose_scale
    v1 = ObservationManager.for_task("track", "arms")
    with pytest.raises(ValueError, match=r"error_gain 1.0: layout lite_track_arms v1 has no joint_error_ema"):
        reference_prior(v1, default, scale, 5, error_gain=1.0)
    with pytest.raises(ValueError, match=r"error_gain must be a finite number >= 0, got -0.5"):
        reference_prior(v2, default, scale, 5, error_gain=-0.5)
    with pytest.raises(
        ValueError, match=r"error_index and error_gain need one entry per action \(2\) or none"
    ):
        ActionPrior(index=(0, 1), gain=(1.0, 1.0), offset=(0.0, 0.0), error_index=(3,), error_gain=(1.0,))
    with pytest.raises(ValueError, match="reads observation entry 400"):
        ActionPrior(
            index=(0,), gain=(1.0,), offset=(0.0,), error_index=(400,), error_gain=(1.0,)
        ).check_observation_size(292)
    with pytest.raises(ValueError, match=r"prior_error_gain must be a finite number >= 0, got -1.0"):
        NetworkConfig(action_prior="reference", prior_error_gain=-1.0)
    with pytest.raises(ValueError, match=r"prior_error_gain > 0 needs an action prior"):
        NetworkConfig(prior_error_gain=1.0)


@pytest.mark.slow
def test_tiny_track_run_trains_and_exports_the_integral_prior(tmp_path, pose_scale):
    """A tiny rsl-rl tracker run (``test_rsl_rl_prior``'s, two iterations) on the v2 layout with
    ``network.prior_error_gain=1``: the env adds the prior in JAX, the export's parity gate (torch actor plus
    the numpy prior against the file) passes, and the file with a zeroed residual commands
    ``(q_ref[4] - default + z) / scale``, z read from the observation's error entries (float32 Gathers, Muls
    and Adds on |a| < 1: 1e-6)."""
    import dataclasses

    import onnx
    from test_rsl_rl_prior import TINY_TRACK_RSL
    from toy_configs import toy_config

    from bar_policy import envs
    from bar_policy.deploy.metadata import PolicyMetadata
    from bar_policy.motion import Clip, gesture
    from bar_policy.training.run import run

    default, scale = pose_scale
    piano = load_robot("arms").pose("piano_ready")
    clips = (Clip.make("tiny", 50.0, piano + 0.01 * np.arange(3)[:, None]), gesture("hanging_to_piano_ready"))
    env_cfg = dataclasses.replace(
        envs.nominal_config(envs.default_config("LiteTrack")), episode_length_s=0.4, joint_error_ema=True
    )
    env = envs.LiteTrack(env_cfg, clips=clips)
    cfg = toy_config(tmp_path, "track-integral", [*TINY_TRACK_RSL, "network.prior_error_gain=1.0"])
    summary = run(cfg, env=env)
    prior = summary.result.prior
    assert prior is not None and prior.has_error_term
    assert summary.export["max_abs_error"] <= 1e-5

    layout = env.obs_manager
    assert "joint_error_ema" in layout.term_names
    rng = np.random.default_rng(3)
    q_refs = [default + scale * rng.uniform(-0.6, 0.6, (K, N)) for _ in range(4)]
    zs = [rng.uniform(-0.04, 0.04, N) for _ in range(4)]
    obs = np.stack(
        [
            np.asarray(
                layout.compute(
                    {
                        **{t.name: rng.uniform(-0.5, 0.5, t.size) for t in layout.schema.terms},
                        "motion_joint_pos": q.reshape(-1),
                        "joint_error_ema": z,
                    }
                ),
                np.float32,
            )
            for q, z in zip(q_refs, zs, strict=True)
        ]
    )
    by_hand = np.stack([(q[4] - default + z) / scale for q, z in zip(q_refs, zs, strict=True)])
    state = {k: v.clone() for k, v in summary.result.actor.state_dict().items()}
    last = max(k for k in state if k.startswith("mlp.") and k.endswith(".weight"))
    state[last].zero_()
    state[last.replace("weight", "bias")].zero_()
    props = {p.key: p.value for p in onnx.load(str(summary.onnx_path)).metadata_props}
    summary.result.at(state).export_onnx(PolicyMetadata.from_props(props), tmp_path / "zero.onnx")
    np.testing.assert_allclose(_run_onnx((tmp_path / "zero.onnx").read_bytes(), obs), by_hand, atol=1e-6)


def test_track_prior_bench_writes_the_integral_prior_alone(tmp_path, pose_scale):
    """``bench/track_prior.py --error-gain 1``: a file of the v2 layout that the deploy side loads, whose
    actions are ``(q_ref[4] - default + z) / scale`` (lead 5) by hand; without a gain, the v1 layout and
    ``(q_ref[4] - default) / scale`` (float32 through the graph: 1e-6)."""
    from script_modules import load_bench

    from bar_policy.deploy.policy import load_policy

    bench = load_bench("track_prior")
    default, scale = pose_scale
    rng = np.random.default_rng(5)
    q_ref = default + scale * rng.uniform(-0.5, 0.5, N)
    z = rng.uniform(-0.03, 0.03, N)
    for gain, version, want in ((1.0, 2, (q_ref - default + z) / scale), (0.0, 1, (q_ref - default) / scale)):
        path = tmp_path / f"prior_{gain}.onnx"
        bench.write_prior_policy(path, 5, gain)
        policy = load_policy(str(path))
        layout = policy.obs_manager
        assert layout.schema.version == version
        assert ("joint_error_ema" in layout.term_names) == (gain > 0)
        inputs = {t.name: np.zeros(t.size) for t in layout.schema.terms}
        inputs["motion_joint_pos"] = np.tile(q_ref, K)
        if gain:
            inputs["joint_error_ema"] = z
        np.testing.assert_allclose(policy(layout.compute(inputs)), want, atol=1e-6, err_msg=f"gain {gain}")


def test_brax_network_and_its_export_carry_the_integral_prior(v2, pose_scale, tmp_path):
    """The brax backend (the presets'): the deterministic action is tanh(mlp_loc(normalised obs) +
    atanh(prior(raw obs))), the MLP computed by brax's own network without the prior on the same params
    (float32, 1e-5 as in ``test_action_prior``), and the exported file passes the parity gate with the term
    in its graph."""
    import jax
    import jax.numpy as jnp
    from brax.training.acme import running_statistics, specs
    from brax.training.agents.ppo import networks as ppo_networks

    from bar_policy.export.policy import export_brax_policy
    from bar_policy.training.brax.networks import make_networks

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "deploy"))
    from policy_factory import default_metadata

    default, scale = pose_scale
    prior = reference_prior(v2, default, scale, 5, error_gain=1.0)
    cfg = NetworkConfig(
        policy_hidden=(32, 32), value_hidden=(16,), action_prior="reference", prior_error_gain=1.0
    )
    net = make_networks(v2.size, N, cfg, True, prior)
    k1, k2, k3 = jax.random.split(jax.random.PRNGKey(11), 3)
    norm = running_statistics.init_state(specs.Array((v2.size,), jnp.float32))
    norm = running_statistics.update(norm, 0.3 * jax.random.normal(k3, (2048, v2.size)))
    params = (norm, net.policy_network.init(k1), net.value_network.init(k2))
    rng = np.random.default_rng(6)
    obs = np.stack(
        [
            _obs(v2, default + scale * rng.uniform(-0.6, 0.6, N), rng.uniform(-0.04, 0.04, N), rng)
            for _ in range(4)
        ]
    )
    plain = make_networks(v2.size, N, NetworkConfig(policy_hidden=(32, 32), value_hidden=(16,)), True)
    loc = np.asarray(plain.policy_network.apply(params[0], params[1], obs))[:, :N]
    want = np.tanh(loc + np.arctanh(prior.apply(obs)))
    got, _ = ppo_networks.make_inference_fn(net)(params, deterministic=True)(obs, jax.random.PRNGKey(0))
    np.testing.assert_allclose(np.asarray(got), want, atol=1e-5)

    meta = default_metadata(obs_schema=v2.schema.to_json(), obs_fingerprint=v2.fingerprint, task="track")
    info = export_brax_policy(
        params,
        ppo_networks.make_inference_fn(net),
        meta,
        tmp_path / "p.onnx",
        activation="swish",
        num_parity_obs=256,
        prior=prior,
    )
    assert info["max_abs_error"] <= 1e-5
