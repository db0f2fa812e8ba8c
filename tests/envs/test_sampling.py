"""Adaptive start sampling: bin table, counts, probabilities and the wrapper's use of them, by hand."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from bar_policy.envs.sampling import StartBins, pack, start_probabilities, unpack, update_counts


def test_bins_cover_every_start_frame_once():
    # Two clips of 7 and 3 frames at table offsets 0 and 7; starts are frames 0..5 and 0..1; bins of 4.
    b = StartBins.build(np.array([0, 7]), np.array([7, 3]), 4)
    assert b.size == 3
    np.testing.assert_array_equal(b.clip, [0, 0, 1])
    np.testing.assert_array_equal(b.first_phase, [0, 4, 0])
    np.testing.assert_array_equal(b.num_phases, [4, 2, 2])  # frames 0-3, 4-5 | 0-1
    # Frames 0-3 -> bin 0, 4-6 (6 is the last frame, never a start) -> bin 1, table frames 7-9 -> bin 2.
    np.testing.assert_array_equal(b.bin_of_frame, [0, 0, 0, 0, 1, 1, 1, 2, 2, 2])
    with pytest.raises(ValueError, match="bin_frames"):
        StartBins.build(np.array([0]), np.array([5]), 0)


def test_counts_decay_and_add_failures_and_visits():
    counts = jnp.array([[1.0, 0.0, 2.0], [10.0, 4.0, 8.0]])
    bins = jnp.array([0, 2, 2, 1])
    failed = jnp.array([0.0, 1.0, 0.0, 1.0])
    got = update_counts(counts, bins, failed, decay=0.5)
    # failures: 0.5 * [1, 0, 2] + [0, 1, 1] = [0.5, 1, 2]; visits: 0.5 * [10, 4, 8] + [1, 1, 2] = [6, 3, 6].
    np.testing.assert_allclose(got, [[0.5, 1.0, 2.0], [6.0, 3.0, 6.0]])


def test_probabilities_smooth_failures_back_within_a_clip_and_mix_uniform():
    clip = np.array([0, 0, 0, 1, 1])
    counts = jnp.array([[0.0, 0.0, 2.0, 1.0, 0.0], [1.0, 1.0, 4.0, 2.0, 1.0]])
    p = start_probabilities(counts, clip, uniform_share=0.5, kernel_bins=2, kernel_decay=0.5)
    # rates [0, 0, 0.5, 0.5, 0]; score_b = rate_b + 0.5 rate_{b+1} in the same clip:
    # [0, 0.25, 0.5, 0.5, 0] (bin 2's neighbour is in clip 1: not added); sum 1.25.
    score = np.array([0.0, 0.25, 0.5, 0.5, 0.0]) / 1.25
    np.testing.assert_allclose(p, 0.5 / 5 + 0.5 * score, rtol=1e-6)
    assert float(jnp.sum(p)) == pytest.approx(1.0)
    # No failure yet: uniform.
    np.testing.assert_allclose(start_probabilities(counts.at[0].set(0.0), clip, 0.5, 2, 0.5), 0.2, rtol=1e-6)


def test_pack_spreads_the_counts_over_the_env_axis():
    counts = jnp.arange(10.0).reshape(2, 5)
    packed = pack(counts, 3)  # ceil(5 / 3) = 2 bins per env, one pad
    assert packed.shape == (3, 2, 2)
    np.testing.assert_array_equal(unpack(packed, 5), counts)


@pytest.fixture(scope="module")
def sampled_env(track_clips):
    """LiteTrack on the session's two clips, bins of 1 frame, adaptive sampling on (no uniform share), and a
    1 mm termination distance (so a hard push ends an episode in one step)."""
    from bar_policy import envs

    base = envs.nominal_config(envs.default_config("LiteTrack"))
    cfg = dataclasses.replace(
        base,
        sampling=dataclasses.replace(base.sampling, enabled=True, bin_s=0.02, uniform_share=0.0),
        termination_distance=1e-3,
    )
    return envs.LiteTrack(cfg, clips=track_clips)


def test_reset_in_a_bin_starts_inside_it(sampled_env):
    env = sampled_env
    b = env.start_bins
    assert env.sampler_bins == b.size == 2 + (len(env.reference.joint_pos) - 3 - 1)
    last = b.size - 1  # the long clip's last start frame
    info, q, _ = jax.jit(env.task_reset_in_bin)(jax.random.PRNGKey(3), jnp.int32(last))
    assert int(info["clip"]) == 1 and int(info["frame"]) == 3 + int(b.first_phase[last])
    np.testing.assert_allclose(q, env.reference.joint_pos[int(info["frame"])])


def test_wrapper_counts_failures_where_they_happen_and_starts_there(sampled_env):
    from bar_policy.envs.wrappers import BatchedEnv

    env = sampled_env
    w = BatchedEnv(env, episode_length=env.episode_length)
    s = jax.jit(w.reset)(jax.random.split(jax.random.PRNGKey(0), 4))
    assert s.info["sampler"].shape == (4, 2, -(-env.sampler_bins // 4))
    # Hand-made counts: only bin 5 has failed; with uniform_share 0 every reset must start in bin 5.
    counts = jnp.zeros((2, env.sampler_bins)).at[0, 5].set(3.0).at[1, 5].set(3.0)
    s = s.replace(info={**s.info, "sampler": pack(counts, 4)})
    # Push every env far off its reference: the task terminates all four on this step.
    far = jnp.ones((4, env.action_size))
    s1 = jax.jit(w.step)(s, far)
    assert np.all(np.asarray(s1.done) == 1)
    got = unpack(s1.info["sampler"], env.sampler_bins)
    frames = np.minimum(np.asarray(s.info["frame"]) + 1, np.asarray(s.info["last_frame"]))  # where it failed
    bins = env.start_bins.bin_of_frame[frames]
    want = np.asarray(env.config.sampling.decay * counts)
    np.add.at(want[0], bins, 1.0)
    np.add.at(want[1], bins, 1.0)
    np.testing.assert_allclose(got, want, rtol=1e-6)
    # Every auto-reset drew its start from the new probabilities (failures only in `bins` and bin 5).
    p = np.asarray(env.start_probabilities(got))
    start_bins = env.start_bins.bin_of_frame[np.asarray(s1.info["frame"])]
    assert np.all(p[start_bins] > 0)
    assert set(start_bins) <= set(np.flatnonzero(p > 0))
