"""Export: the parity gate gates, and the deploy loader refuses broken or metadata-less files."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import onnx
import pytest
from brax.training.acme import running_statistics, specs
from brax.training.agents.ppo import networks as ppo_networks

from bar_policy.deploy.policy import PolicyLoadError, load_policy
from bar_policy.export.graph import build_onnx_model
from bar_policy.export.parity import (
    PARITY_TOLERANCE,
    ParityError,
    _run_onnx,
    check_parity,
    parity_observations,
    parity_sigmas,
)
from bar_policy.export.policy import (
    brax_policy_reference,
    export_brax_policy,
    export_policy,
    mlp_policy_from_brax,
)
from bar_policy.training.brax.networks import make_networks
from bar_policy.training.config import NetworkConfig
from bar_policy.training.metadata import policy_metadata


@pytest.fixture(scope="module")
def brax_params():
    """Random brax PPO params (54 obs, 14 actions) with a non-trivial normaliser."""
    net = make_networks(54, 14, NetworkConfig(policy_hidden=(64, 64), value_hidden=(32,)), True)
    k1, k2, k3 = jax.random.split(jax.random.PRNGKey(3), 3)
    norm = running_statistics.init_state(specs.Array((54,), jnp.float32))
    scale = jnp.linspace(0.05, 3.0, 54)
    norm = running_statistics.update(norm, 0.5 + scale * jax.random.normal(k3, (4096, 54)))
    params = (norm, net.policy_network.init(k1), net.value_network.init(k2))
    return params, ppo_networks.make_inference_fn(net)


@pytest.fixture(scope="module")
def metadata(toy_env):
    return policy_metadata(toy_env, training={"backend": "test"})


def test_extracted_policy_is_brax_mode_by_hand(brax_params):
    """tanh(loc) with loc the first 14 outputs, swish hidden layers, (x - mean) / std: in numpy."""
    params, make_policy = brax_params
    pol = mlp_policy_from_brax(params, 14)
    obs = np.random.default_rng(0).standard_normal((5, 54)).astype(np.float32)
    layers = params[1]["params"]
    h = (obs - np.asarray(params[0].mean)) / np.asarray(params[0].std)
    for i in range(3):
        h = h @ np.asarray(layers[f"hidden_{i}"]["kernel"]) + np.asarray(layers[f"hidden_{i}"]["bias"])
        if i < 2:
            h = h / (1.0 + np.exp(-h))
    by_hand = np.tanh(h[:, :14])
    brax = brax_policy_reference(make_policy, params)(obs)
    np.testing.assert_allclose(brax, by_hand, atol=1e-5)
    assert pol.kernels[-1].shape == (64, 14)


@pytest.mark.numerics
def test_export_passes_gate_and_loads_in_deploy(brax_params, metadata, tmp_path):
    params, make_policy = brax_params
    path = tmp_path / "p.onnx"
    rec = export_brax_policy(params, make_policy, metadata, path)
    assert rec["max_abs_error"] <= 1e-5 and rec["num_parity_obs"] == 4096
    policy = load_policy(path)
    obs = np.zeros((1, 54), np.float32)
    assert policy(obs).shape in ((14,), (1, 14))


@pytest.mark.parametrize(
    "corrupt",
    [
        pytest.param(lambda p: _perturb(p, layer=1, delta=1e-3), id="one-weight-off-by-1e-3"),
        pytest.param(lambda p: dataclasses.replace(p, activation="elu"), id="wrong-activation"),
        pytest.param(lambda p: dataclasses.replace(p, obs_std=p.obs_std * 1.001), id="normaliser-off-0.1%"),
    ],
)
def test_parity_gate_refuses_a_corrupted_graph(brax_params, metadata, tmp_path, corrupt):
    params, make_policy = brax_params
    good = mlp_policy_from_brax(params, 14)
    path = tmp_path / "bad.onnx"
    with pytest.raises(ParityError, match="differs from the training framework"):
        export_policy(corrupt(good), metadata, path, brax_policy_reference(make_policy, params))
    assert not path.exists() and not list(tmp_path.iterdir())  # nothing written, no partial file


def _perturb(p, layer, delta):
    kernels = [k.copy() for k in p.kernels]
    kernels[layer][3, 5] += delta
    return dataclasses.replace(p, kernels=tuple(kernels))


def test_deploy_refuses_a_file_without_metadata(brax_params, tmp_path):
    params, _ = brax_params
    path = tmp_path / "bare.onnx"
    onnx.save(build_onnx_model(mlp_policy_from_brax(params, 14), None), str(path))
    with pytest.raises(PolicyLoadError, match="no metadata"):
        load_policy(path)


def test_deploy_refuses_a_file_missing_one_key(brax_params, metadata, tmp_path):
    params, _ = brax_params
    props = metadata.to_props()
    del props["joint_stiffness"]
    path = tmp_path / "partial.onnx"
    onnx.save(build_onnx_model(mlp_policy_from_brax(params, 14), props), str(path))
    with pytest.raises(PolicyLoadError, match="joint_stiffness"):
        load_policy(path)


def test_deploy_refuses_a_corrupted_file(brax_params, metadata, tmp_path):
    params, make_policy = brax_params
    good = tmp_path / "good.onnx"
    export_brax_policy(params, make_policy, metadata, good)
    data = good.read_bytes()
    truncated = tmp_path / "truncated.onnx"
    truncated.write_bytes(data[: len(data) // 2])
    with pytest.raises(PolicyLoadError, match="corrupted or truncated"):
        load_policy(truncated)


def test_parity_tolerance_grows_with_the_rows_sigma(brax_params, metadata):
    """A row at k sigma may differ by k * 1e-5 (rounding grows with the inputs' size): an offset of 5e-5
    passes on an 8-sigma row and is refused on a 1-sigma row, with the row and its tolerance named."""
    params, _ = brax_params
    policy = mlp_policy_from_brax(params, 14)
    data = build_onnx_model(policy, metadata.to_props()).SerializeToString()
    obs = parity_observations(policy, 8, seed=3)
    k = parity_sigmas(8)
    np.testing.assert_array_equal(k, [1, 1, 1, 1, 4, 4, 8, 8])
    exact = _run_onnx(data, obs)

    def shifted(row: int):
        def fn(o):
            out = exact.copy()
            out[row] += 5e-5
            return out

        return fn

    assert check_parity(data, shifted(7), obs, PARITY_TOLERANCE, k) == pytest.approx(5e-5, rel=1e-3)
    with pytest.raises(ParityError, match=r"by 5e-05 \(> 1e-05\) on row 0 of 8 observations"):
        check_parity(data, shifted(0), obs, PARITY_TOLERANCE, k)
