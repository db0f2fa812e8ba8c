"""The MJX piano env's chatter reference (``LitePiano.task_reference``): the deploy side's key-pose reference.

The MJX evaluation measures chatter on ``q_cmd - task_reference`` (``env.quality_signals``); the piano's
reference is the key-pose prior's command for the step's goal-key window through the env's action path
(``tasks.piano.reference``, docs/piano.md "Chatter against the key-pose reference"). Expected values, each
worked apart from the code under test:

- the prior alone (a zero-MLP policy: ``tanh(0 + atanh(prior(obs)))``) commands the reference at every step,
  so its MJX chatter (``eval_quality.finish``'s ``quality/chatter_max_mrad``) is ~0 while its ``q_cmd``
  itself has the keystrokes;
- for a hand-made goal-key window and for the song's own windows, the reference is the blend worked out
  here from the key poses (``prior.key_poses``) through the first-order filter written out by hand;
- parity: for the same song, the env's reference is the deploy side's (``KeyPoseReference`` on
  ``SongCommands``' ``target_keys``) step by step from the same filter start; from the runtime's start
  (action 0, not the env's ``pose_action`` of the held pose) it differs by that start's decay alone;
- the reference feeds nothing else: the observation, reward, metrics and physics do not move when its
  filter state does (a bitwise comparison with the env before the change, 40 steps x 2 randomised
  episodes, was run once by hand and was equal; docs/piano.md).

One env (one library song, nominal physics) and one jitted rollout of ``T`` steps, shared by the module.
"""

from __future__ import annotations

import dataclasses
import math
from types import SimpleNamespace

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from piano_blend import hand_blend

from bar_policy.quality.metrics import chatter_mrad
from bar_policy.tasks.piano.env import LitePiano, nominal_config
from bar_policy.tasks.piano.prior import KeyPosePriorConfig, key_poses
from bar_policy.tasks.piano.reference import LEAD_STEPS, KeyPoseReference
from bar_policy.tasks.piano.source import SongCommands
from bar_policy.tasks.piano.terms import PIANO_KEYS, TARGET_FRAMES
from bar_policy.training import eval_quality
from bar_policy.training.parallel import AXIS

SONG = "c_major_scales_two_hands"
"""A training-library song with both hands: up to 22 goal entries on in a window of the first 6 s."""
T = 300
"""Steps of the rollout (6 s: the 0.5 s count-in and 5.5 s of the song; three 2 s chatter segments)."""
SCALE = 0.8
DT = 0.02
ALPHA = 1.0 - math.exp(-2.0 * math.pi * 3.0 * DT)
"""The env's 3 Hz action filter at 50 Hz, written out: 0.314."""
U = 2.0**-24
"""float32's unit roundoff."""
P_MAX = 0.75
"""Bound on the key poses' actions, |pose - default| / scale (0.73 on the compact keyboard; asserted)."""


def blend_tol(k: int) -> float:
    """Bound on the float32 blend's error against the exact one, action units, ``k`` goal entries on.

    The place blend, per action: ``num = sum_i x_i N_i + b``, ``den = sum_i x_i D_i + r`` over the ``k``
    entries on (the others add exact zeros), each stored entry rounded once (u), each product and sum once
    more: ``|d num| <= (k + 2) u sum|x_i N_i| <= (k + 2) u P den`` (``N_i = w_i p_i``, ``|p_i| <= P``, the
    weights ``w_i >= 0``) and ``|d den| <= (k + 2) u den``; the quotient ``a = num / den`` (``|a| <= P``)
    adds u: ``|d a| <= 2 (k + 2) u P + u``. The edge blend (linear, its denominator exactly 1): at most
    two entries per action are non-zero (a hand's key in frame 0 and in the lead frame), each
    ``|c (p_press - p_hover)| <= 0.45 * 2 P``, so ``|d e| <= (k + 2) u 1.8 P``; adding it to ``a``
    (``|a + e| <= 2.8 P``) rounds once more, ``2.8 u P``.
    """
    return 2.0 * (k + 2) * U * P_MAX + U + (k + 2) * U * 1.8 * P_MAX + 2.8 * U * P_MAX


def q_tol(k: int, inputs: float) -> float:
    """Bound on ``|d q|``, rad, of two filtered commands whose inputs differ by <= ``inputs`` action units.

    The filter ``f + alpha (a - f)`` passes an input difference with gain <= 1 and adds <= 2 u |f| <= 2 u per
    step where the two states round apart, contracted by 1 - alpha each step (<= 2 u / alpha in all);
    ``default + scale f`` rounds once more, half an ulp of |q| <= 4 rad (2.4e-7).
    """
    return SCALE * (inputs + 2.0 * U / ALPHA) + 2.4e-7


@pytest.fixture(scope="module")
def env() -> LitePiano:
    cfg = dataclasses.replace(nominal_config(), songs=0, library=(SONG,))
    env = LitePiano(cfg)
    assert (
        env.config.prior == KeyPosePriorConfig() and LEAD_STEPS == 2
    )  # the policy's prior = the reference's
    assert float(env.action_scale[0]) == pytest.approx(SCALE) and env.dt == DT
    return env


@pytest.fixture(scope="module")
def k_max(env: LitePiano) -> int:
    """The most goal entries on in a window of the rollout (the ``k`` of ``blend_tol``)."""
    down = env.bank.down[0]
    k = max(int(down[t : t + TARGET_FRAMES].sum()) for t in range(T))
    assert 0 < k <= 2 * TARGET_FRAMES  # a key per hand and frame, overlaps aside
    return k


@pytest.fixture(scope="module")
def rollout(env: LitePiano):
    """``run(state0) -> (final state, per step: dict)``, jitted once: the prior alone drives the env.

    Per step ``t`` (from the state before the step): ``q_cmd`` (this step's command), ``ref``
    (``task_reference``), ``signal`` (``quality_signals``' chatter signal), ``target_keys`` (the observation's
    term), ``key_pressed`` (the observation's keys down, which the prior's release blend reads), and after
    the step ``obs``, ``reward``, ``metrics``, ``qpos``, ``ref_act``.
    """
    prior = env.action_prior(LEAD_STEPS)
    sl = env.obs_manager.term_slice("target_keys")
    kp = env.obs_manager.term_slice("key_pressed")

    def body(s, _):
        a = jnp.tanh(0.0 + prior.pre_tanh(s.obs))  # a zero MLP under the tanh_loc head
        out = {
            "q_cmd": env.q_command(env.filtered_action(s.info["last_act"], a)),
            "ref": env.task_reference(s.info),
            "signal": env.quality_signals(s, a)["signal"],
            "target_keys": s.obs[sl],
            "key_pressed": s.obs[kp],
        }
        ns = env.step(s, a)
        out.update(
            obs=ns.obs, reward=ns.reward, metrics=ns.metrics, qpos=ns.data.qpos, ref_act=ns.info["ref_act"]
        )
        return ns, out

    return jax.jit(lambda s0: jax.lax.scan(body, s0, None, length=T))


@pytest.fixture(scope="module")
def start(env: LitePiano):
    return jax.jit(env.reset)(jax.random.PRNGKey(0))


@pytest.fixture(scope="module")
def prior_run(rollout, start) -> dict:
    _, out = rollout(start)
    return jax.tree.map(np.asarray, out)


def _frames(window: np.ndarray, kb) -> dict[int, list[int]]:
    """``{frame: [midi, ...]}`` of a (TARGET_FRAMES, keys) goal window."""
    w = np.asarray(window).reshape(TARGET_FRAMES, PIANO_KEYS)
    return {j: [kb.lowest + int(i) for i in np.flatnonzero(w[j])] for j in range(TARGET_FRAMES)}


def test_prior_alone_commands_the_reference(env, prior_run, start, k_max) -> None:
    """Every step's q_cmd is the reference within ``q_tol``: the policy's prior and the reference's are the
    same float32 blend on the same entries (each within ``blend_tol`` of the exact one, so 2x apart), plus
    ``tanh(atanh(p))``'s few ulps (1e-6); the MJX metric (``quality_signals`` -> ``eval_quality.finish``)
    of the prior alone is then ~0, while chatter of ``q_cmd`` itself counts the keystrokes."""
    poses = key_poses(env.config.keyboard)
    default = env.default_pose.astype(np.float64)
    assert max(np.abs((p - default) / SCALE).max() for p in (poses.press, poses.hover)) <= P_MAX
    q_cmd, ref, sig = prior_run["q_cmd"], prior_run["ref"], prior_run["signal"]
    tol = q_tol(k_max, 2.0 * blend_tol(k_max) + 1e-6)
    err = np.abs(q_cmd - ref).max()
    assert err <= tol, (err, tol)  # measured 1.2e-7 rad (an ulp of ~1 rad); tol 4.9e-6 at k = 22
    np.testing.assert_allclose(sig, q_cmd - ref, rtol=0, atol=2.4e-7)  # the signal is q_cmd - ref
    assert (ref >= env.robot.lower).all() and (ref <= env.robot.upper).all()  # q_cmd's clip is idle
    # The training evaluation's figure: chatter of the signal over the episode, worst joint, mrad. A seminorm
    # no larger than the largest deviation from a segment's mean: |signal| <= tol gives <= 2e3 tol mrad.
    counts = eval_quality.init(1, 14)
    fig = jax.vmap(lambda c, s: eval_quality.finish(c, s, DT), axis_name=AXIS)(
        jax.tree.map(lambda x: x[None], counts), jnp.asarray(sig)[None, :, None, :]
    )
    chatter = float(fig["quality/chatter_max_mrad"][0])
    assert chatter == pytest.approx(chatter_mrad(sig, DT), rel=1e-4, abs=1e-6)
    assert chatter < 2e3 * tol  # measured 2.6e-5 mrad (bound 9.7e-3)
    assert chatter_mrad(q_cmd, DT) > 5.0  # q_cmd itself: the keystrokes (6.65 mrad on these 6 s)


def test_reference_of_hand_made_windows(env, start) -> None:
    """``reference_action`` of the two hand-made windows of tests/tasks/test_piano_reference.py is the hand
    blend (tick 1: C3 frame 0 press, C4 frame 3 hover; tick 2: C4 frame 2 press, E4 frame 5 hover), and the
    hook's filter step from a given state is ``f + alpha (a - f)``."""
    kb = env.config.keyboard
    default = env.default_pose.astype(np.float64)

    def window(frames: dict[int, list[int]]) -> np.ndarray:
        w = np.zeros((TARGET_FRAMES, PIANO_KEYS), np.float32)
        for j, midis in frames.items():
            w[j, [m - kb.lowest for m in midis]] = 1.0
        return w.reshape(-1)

    action = jax.jit(env.reference_action)
    f = np.asarray(start.info["ref_act"], np.float64)  # the env's start: pose_action of the held pose
    for frames in ({0: [48], 3: [60]}, {2: [60], 5: [64]}):
        a = hand_blend(frames, default, kb, SCALE)
        np.testing.assert_allclose(np.asarray(action(window(frames))), a, rtol=0, atol=blend_tol(2))
        f = f + ALPHA * (a - f)
    assert np.abs(f * SCALE)[:7].max() > 1e-3 and np.abs(f * SCALE)[7:].max() > 1e-3  # both arms moved


def test_reference_hook_on_the_songs_windows(env, start, k_max) -> None:
    """``task_reference`` at song steps with goal keys, from a given filter state ``f``: ``default +
    scale (f + alpha (a - f))``, ``a`` the hand blend of the bank's window at that step (the observation's
    ``target_keys``: the window from the step plus the playback's lead)."""
    kb = env.config.keyboard
    lead = env.config.playback.lead_steps
    assert lead == 2
    default = env.default_pose.astype(np.float64)
    hook = jax.jit(env.task_reference)
    rng = np.random.default_rng(0)
    steps = [t for t in range(25, T, 23) if env.bank.down[0, t + lead : t + lead + TARGET_FRAMES].any()]
    assert len(steps) >= 8
    for t in steps:
        f = rng.uniform(-0.5, 0.5, 14).astype(np.float32)
        info = {**start.info, "step": jnp.int32(t), "ref_act": jnp.asarray(f)}
        a = hand_blend(_frames(env.bank.down[0, t + lead : t + lead + TARGET_FRAMES], kb), default, kb, SCALE)
        want = default + SCALE * (f + ALPHA * (a - f))
        tol = q_tol(k_max, blend_tol(k_max))
        np.testing.assert_allclose(np.asarray(hook(info)), want, rtol=0, atol=tol, err_msg=f"step {t}")


def _deploy_reference(env: LitePiano) -> KeyPoseReference:
    """The deploy side's reference, built by ``for_policy`` from a policy with the env's metadata."""
    meta = SimpleNamespace(
        action_joint_names=env.robot.joint_names,
        joint_stiffness=tuple(float(x) for x in env.kp),  # the file's gains: the prior's springs
        action_scale=tuple(float(x) for x in env.action_scale),
        action_filter_hz=env.action_filter_hz,
    )
    policy = SimpleNamespace(
        metadata=meta,
        robot=env.robot,
        default_joint_pos=tuple(float(x) for x in env.default_pose),
        obs_manager=env.obs_manager,
        policy_dt=env.dt,
        action_clip=1.0,
    )
    return KeyPoseReference.for_policy(policy, env.config.keyboard)  # type: ignore[arg-type]


class _EnvKeys:
    """A key source replaying the env's observed keys down, one row per control step."""

    def __init__(self, rows: np.ndarray) -> None:
        self.counts: dict = {}
        self.rows = np.asarray(rows) > 0.5
        assert self.rows.shape[1] == PIANO_KEYS

    def read(self, t: float) -> np.ndarray:
        return self.rows[min(round(t / DT), len(self.rows) - 1)]

    def close(self) -> None:
        pass


def test_parity_with_the_deploy_reference(env, prior_run, start, k_max) -> None:
    """The song through ``SongCommands`` (the robot's side): its ``target_keys`` are the env's observation's
    at every step, and ``KeyPoseReference`` stepped on them from the env's filter start is the env's
    reference within ``q_tol`` of both blends' bounds. ``SongCommands.target_q`` itself starts at action 0
    (the runtime's HOLD target): the difference is the start's, ``-scale (1 - alpha)^(t+1) f0``, below 2e-6
    rad by the first note (step 25, after the 0.5 s count-in, during which the prior rests at action 0)."""
    ref = _deploy_reference(env)
    assert ref.alpha == pytest.approx(ALPHA, rel=1e-12)
    assert ref.prior.label == env.reference_prior.label
    (song,) = env.songs
    keys = _EnvKeys(prior_run["key_pressed"])
    src = SongCommands(song, env.config.keyboard, DT, keys, env.config.playback, reference=ref)  # type: ignore[arg-type]
    src.begin(0.0)
    f0 = np.asarray(start.info["ref_act"])
    state = f0
    tol = q_tol(k_max, 2.0 * blend_tol(k_max))
    worst, worst_start = 0.0, 0.0
    for t in range(T):
        terms = src(t * DT)
        np.testing.assert_array_equal(terms["target_keys"], prior_run["target_keys"][t], f"step {t}")
        np.testing.assert_array_equal(terms["key_pressed"], prior_run["key_pressed"][t], f"step {t}")
        state = ref.filtered(state, terms["target_keys"], terms["key_pressed"])
        env_ref = prior_run["ref"][t]
        worst = max(worst, np.abs(ref.q(state) - env_ref).max())
        decay = -SCALE * (1.0 - ALPHA) ** (t + 1) * f0.astype(np.float64)
        worst_start = max(worst_start, np.abs(src.target_q() - env_ref - decay).max())
        if t >= 25:
            assert np.abs(src.target_q() - env_ref).max() < 2e-6, t
    assert worst <= tol and worst_start <= tol, (worst, worst_start, tol)  # measured 7.6e-8, 7.6e-8 rad
    # The filter state the env carries is the one the hook used: step t's ref_act gives step t's reference.
    np.testing.assert_allclose(
        env.default_pose + SCALE * prior_run["ref_act"], prior_run["ref"], rtol=0, atol=2.4e-7
    )


def test_reference_feeds_nothing_else(env, rollout, prior_run, start) -> None:
    """The same episode from a filter state moved by 0.3: observation, reward, metrics and physics are
    bitwise those of the prior's run; the reference moves by ``scale (1 - alpha)^(t+1) 0.3`` at step ``t``."""
    moved = start.replace(info={**start.info, "ref_act": start.info["ref_act"] + 0.3})
    _, out = rollout(moved)
    out = jax.tree.map(np.asarray, out)
    for k in ("obs", "reward", "qpos", "q_cmd", "target_keys"):
        np.testing.assert_array_equal(out[k], prior_run[k], k)
    for k, v in out["metrics"].items():
        np.testing.assert_array_equal(v, prior_run["metrics"][k], k)
    shift = SCALE * 0.3 * (1.0 - ALPHA) ** (np.arange(T) + 1.0)
    np.testing.assert_allclose(
        out["ref"] - prior_run["ref"], np.repeat(shift[:, None], 14, 1), rtol=0, atol=1e-6
    )
    assert set(start.info) == {
        "rng",
        "step",
        "song",
        "ref_act",
        "ref_keys",
        "last_act",
        "act_prev",
        "act_buf",
        "latency",
        "kp",
        "kd",
        "encoder_offset",
    }
    np.testing.assert_array_equal(start.info["ref_act"], start.info["last_act"])  # started with the policy's
