"""The frozen ObservationManager: layout, numpy/jax parity, golden schemas, and refusals."""

from __future__ import annotations

import json
from importlib import resources

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from bar_policy.obs import SHIPPED_LAYOUTS, ObservationManager, ObservationSchema
from bar_policy.robot import load_robot


def inputs(batch: tuple[int, ...] = (), n: int = 14, seed: int = 0) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(seed)
    shapes = {
        "joint_pos": n,
        "joint_vel": n,
        "actions": n,
        "fingertip_pos_left": 3,
        "fingertip_pos_right": 3,
        "target_pos_left": 3,
        "target_pos_right": 3,
    }
    return {k: rng.normal(size=(*batch, s)) for k, s in shapes.items()}


def test_layout_of_reach_arms() -> None:
    om = ObservationManager.for_task("reach", "arms")
    assert om.size == 14 * 3 + 4 * 3 == 54
    assert om.term_names == (
        "joint_pos",
        "joint_vel",
        "actions",
        "fingertip_pos_left",
        "fingertip_pos_right",
        "target_pos_left",
        "target_pos_right",
    )
    assert om.term_slice("actions") == slice(28, 42)
    assert om.command_names == ("target_pos_left", "target_pos_right")
    assert ObservationManager.for_task("reach", "arms_neck").size == 17 * 3 + 12 == 63


def test_compute_by_hand() -> None:
    om = ObservationManager.for_task("reach", "arms")
    default = load_robot("arms").pose("piano_ready")
    x = {
        "joint_pos": default + 0.1,  # -> 0.1 after the default pose is subtracted
        "joint_vel": np.full(14, 2.0),  # scale 0.1 -> 0.2
        "actions": np.linspace(-1, 1, 14),  # scale 1
        "fingertip_pos_left": np.array([0.3, 0.2, 0.1]),
        "fingertip_pos_right": np.array([0.3, -0.2, 0.1]),
        "target_pos_left": np.array([0.4, 0.1, 0.2]),
        "target_pos_right": np.array([0.4, -0.1, 0.2]),
    }
    obs = om.compute(x)
    assert obs.dtype == np.float32 and obs.shape == (54,)
    np.testing.assert_allclose(obs[:14], 0.1, atol=1e-6)
    np.testing.assert_allclose(obs[14:28], 0.2, atol=1e-6)
    np.testing.assert_allclose(obs[28:42], np.linspace(-1, 1, 14), atol=1e-6)
    np.testing.assert_allclose(
        obs[42:], [0.3, 0.2, 0.1, 0.3, -0.2, 0.1, 0.4, 0.1, 0.2, 0.4, -0.1, 0.2], atol=1e-6
    )
    # Clip at 100 after scaling: a 5000 rad/s reading becomes 500 -> 100.
    x["joint_vel"] = np.full(14, 5000.0)
    assert om.compute(x)[14] == 100.0


def test_batched_and_broadcast() -> None:
    om = ObservationManager.for_task("reach", "arms")
    x = inputs((4, 3))
    obs = om.compute(x)
    assert obs.shape == (4, 3, 54)
    np.testing.assert_allclose(obs[2, 1], om.compute({k: v[2, 1] for k, v in x.items()}))
    # A single target broadcasts against a batch of states.
    x["target_pos_left"] = np.array([0.1, 0.2, 0.3], dtype=np.float32)
    assert om.compute(x).shape == (4, 3, 54)


@pytest.mark.numerics
def test_numpy_jax_parity_under_jit_and_vmap() -> None:
    om = ObservationManager.for_task("reach", "arms")
    x = inputs((16,), seed=3)
    want = om.compute(x)
    got = jax.jit(jax.vmap(om.compute))({k: jnp.asarray(v) for k, v in x.items()})
    assert isinstance(got, jax.Array)
    # jax float32 vs numpy float64: each term is (x - offset) * scale with |x| <= 4, two float32 roundings
    # of at most eps32 * 4 = 4.8e-7 each: <= 1e-6.
    np.testing.assert_allclose(np.asarray(got), want, rtol=0, atol=1e-6)


@pytest.mark.parametrize("name", sorted(SHIPPED_LAYOUTS))
def test_code_matches_golden_schema(name: str) -> None:
    """A layout change must be deliberate: bump the version and rewrite the golden file."""
    task, mode = SHIPPED_LAYOUTS[name]
    code = ObservationManager.for_task(task, mode)
    path = resources.files("bar_policy.obs").joinpath("schemas", f"{name}.json")
    golden = json.loads(path.read_text())
    assert code.schema.to_dict() == golden
    assert code.fingerprint == ObservationManager.golden(name).fingerprint


def test_fingerprint_is_stable_and_sensitive() -> None:
    om = ObservationManager.for_task("reach", "arms")
    again = ObservationManager.from_json(om.to_json())
    assert again.fingerprint == om.fingerprint and len(om.fingerprint) == 16
    d = om.schema.to_dict()
    d["terms"][1]["scale"] = 0.05
    assert ObservationSchema.from_dict(d).fingerprint != om.fingerprint
    d = om.schema.to_dict()
    d["version"] = 2
    assert ObservationSchema.from_dict(d).fingerprint != om.fingerprint


def _bad(**changes: object) -> dict:
    d = ObservationManager.for_task("reach", "arms").schema.to_dict()
    d.update(changes)
    return d


def test_refusals_name_the_problem() -> None:
    good = _bad()
    names = good["joint_names"]
    with pytest.raises(ValueError, match="unknown observation term 'base_lin_vel'; known terms"):
        ObservationSchema.from_dict(_bad(terms=[*good["terms"], {"name": "base_lin_vel", "size": 3}]))
    with pytest.raises(ValueError, match="duplicate joints in joint_names"):
        ObservationSchema.from_dict(_bad(joint_names=[*names[:13], names[0]]))
    with pytest.raises(ValueError, match=r"misses joints of mode 'arms': \['right_wrist_pitch'\]"):
        ObservationSchema.from_dict(_bad(joint_names=names[:13], default_joint_pos=[0.0] * 13))
    with pytest.raises(ValueError, match="differs from the canonical order"):
        ObservationSchema.from_dict(_bad(joint_names=[names[1], names[0], *names[2:]]))
    with pytest.raises(ValueError, match="term 'joint_vel' has size 13, expected 14"):
        terms = [dict(t) for t in good["terms"]]
        terms[1]["size"] = 13
        ObservationSchema.from_dict(_bad(terms=terms))
    with pytest.raises(ValueError, match="unknown joints in joint_names"):
        ObservationSchema.from_dict(_bad(joint_names=[*names[:13], "tail"]))
    with pytest.raises(ValueError, match="lacks keys"):
        ObservationSchema.from_dict({k: v for k, v in good.items() if k != "terms"})
    with pytest.raises(ValueError, match="not valid JSON"):
        ObservationManager.from_json("{not json")
    with pytest.raises(ValueError, match="valid tasks"):
        ObservationManager.for_task("walk")


def test_compute_refuses_missing_or_misshaped_inputs() -> None:
    om = ObservationManager.for_task("reach", "arms")
    x = inputs()
    del x["target_pos_right"]
    with pytest.raises(ValueError, match=r"missing for terms \['target_pos_right'\]"):
        om.compute(x)
    x = inputs()
    x["joint_pos"] = np.zeros(17)
    with pytest.raises(ValueError, match="last dim must be 14"):
        om.compute(x)


def test_fingerprint_command_prints_each_layout(capsys: pytest.CaptureFixture[str]) -> None:
    from bar_policy.obs.__main__ import main

    assert main([]) == 0
    out = capsys.readouterr().out
    for name in SHIPPED_LAYOUTS:
        fp = ObservationManager.golden(name).fingerprint
        assert f"{name}  v1" in out and f"fingerprint={fp}  matches golden" in out


# ---------------------------------------------------------------------------------------------------
# The tracking layout: lookahead sizes, body names, schema keys
# ---------------------------------------------------------------------------------------------------
def test_layout_of_track_arms() -> None:
    om = ObservationManager.for_task("track", "arms")
    k, b = 5, 4
    assert om.schema.lookahead_steps == k and len(om.schema.body_names) == b
    # K*n + K*B*3 + K*B*6 + 3n = 70 + 60 + 120 + 42.
    assert om.size == 70 + 60 + 120 + 42 == 292
    assert om.term_slice("motion_body_pos_b") == slice(70, 130)
    assert om.term_slice("joint_pos") == slice(250, 264)
    assert om.command_names == ("motion_joint_pos", "motion_body_pos_b", "motion_body_ori_b")
    assert om.fingerprint == ObservationManager.golden("lite_track_arms").fingerprint
    # Reach's JSON has no tracking keys (its fingerprint predates them); the tracking JSON round-trips them.
    assert "body_names" not in ObservationManager.for_task("reach", "arms").schema.to_dict()
    again = ObservationManager.from_json(om.to_json())
    assert again.schema == om.schema and again.schema.body_names == om.schema.body_names
    # The default pose offsets joint_pos only, never the reference terms.
    x = {name: np.zeros(om.schema.terms[i].size) for i, name in enumerate(om.term_names)}
    x["motion_joint_pos"] = np.tile(np.asarray(om.schema.default_joint_pos), k)
    obs = om.compute(x)
    np.testing.assert_allclose(obs[:70], x["motion_joint_pos"], atol=1e-6)
    np.testing.assert_allclose(obs[250:264], -np.asarray(om.schema.default_joint_pos), atol=1e-6)


def test_track_schema_refusals() -> None:
    good = ObservationManager.for_task("track", "arms").schema.to_dict()
    with pytest.raises(ValueError, match="lookahead_steps = 0: it must be >= 1 exactly when"):
        ObservationSchema.from_dict({**good, "lookahead_steps": 0})
    with pytest.raises(ValueError, match=r"body_names \[\] must be given exactly when a body term is used"):
        ObservationSchema.from_dict({**good, "body_names": []})
    with pytest.raises(ValueError, match="term 'motion_body_pos_b' has size 60, expected 45"):
        ObservationSchema.from_dict({**good, "body_names": good["body_names"][:3]})
    with pytest.raises(ValueError, match="distinct non-empty names"):
        ObservationSchema.from_dict({**good, "body_names": ["left_hand"] * 4})
    reach = ObservationManager.for_task("reach", "arms").schema.to_dict()
    with pytest.raises(ValueError, match="lookahead_steps = 3: it must be >= 1 exactly when"):
        ObservationSchema.from_dict({**reach, "lookahead_steps": 3})
