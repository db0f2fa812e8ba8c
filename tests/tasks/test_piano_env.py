"""LitePiano in MJX: the bank, the observation, the key counts and the evaluation's F1 and per-colour recall,
worked out by hand.

One small env (2 random songs, no library songs, nominal physics) compiled once for the module. Its keys
are damped 50x critical, so a key pushed down stays down through a 20 ms step (the slow pole of the
overdamped hinge, ~omega / (2 * 50) with omega ~ 86 rad/s for a white key, moves it by ~2 % in 20 ms):
the counts of a step are then known by hand.
"""

from __future__ import annotations

import dataclasses
import queue
from types import SimpleNamespace

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from bar_policy.tasks.piano.bank import SONG_LEAD_STEPS, PlaybackConfig, song_bank
from bar_policy.tasks.piano.env import LitePiano, PianoEnvConfig, nominal_config
from bar_policy.tasks.piano.key_input import MidiKeys
from bar_policy.tasks.piano.keyboard import black_keys, compact_config, press_thresholds
from bar_policy.tasks.piano.songs import Note, Song
from bar_policy.tasks.piano.source import SongCommands
from bar_policy.tasks.piano.terms import PIANO_KEYS, TARGET_FRAMES
from bar_policy.training.startup.compile_cache import QUICK_COMPILE

NO_COUNT_IN = PlaybackConfig(count_in_s=0.0)


def test_bank_rows_by_hand() -> None:
    kb = compact_config()
    # C4 (60) from 0.10 to 0.30 s and E4 (64) from 0.30 to 0.50 s at dt 0.02: rows 5..14 and 15..24.
    song = Song(
        "two", (Note(60, 0.10, 0.30, "right"), Note(64, 0.30, 0.50, "right"), Note(62, 9.0, 9.2, "right"))
    )
    bank = song_bank([song], kb, 0.02, steps=40, lookahead=10, playback=NO_COUNT_IN)
    assert bank.down.shape == (1, 40 + 10 + 1, 49)
    c4, e4 = 60 - kb.lowest, 64 - kb.lowest
    np.testing.assert_array_equal(np.flatnonzero(bank.down[0, :, c4]), np.arange(5, 15))
    np.testing.assert_array_equal(np.flatnonzero(bank.down[0, :, e4]), np.arange(15, 25))
    assert bank.down.sum() == 20  # the note at 9 s starts after step 40: cut, and counted
    assert bank.cut_notes == 1 and bank.steps[0] == 25


def test_bank_count_in_and_lookahead_by_hand() -> None:
    """Count-in 0.5 s at dt 0.02 on C4 0.10-0.30 s and E4 0.30-0.50 s: the song moves by 0.4 s, so C4 is
    down at steps 25..34 (0.50-0.70 s) and E4 at 35..44 (0.70-0.90 s); the song is 45 steps long. With 10
    frames of lookahead, step t's window holds steps t..t+10: C4 enters it at step 15 (frame 10), so the
    count-in shows the first note 0.2 s before it sounds, and nothing before step 15."""
    kb = compact_config()
    c4, e4 = 60 - kb.lowest, 64 - kb.lowest
    song = Song("two", (Note(60, 0.10, 0.30, "right"), Note(64, 0.30, 0.50, "right")))
    bank = song_bank([song], kb, 0.02, steps=60, lookahead=10, playback=PlaybackConfig(count_in_s=0.5))
    down = bank.down[0]
    np.testing.assert_array_equal(np.flatnonzero(down[:, c4]), np.arange(25, 35))
    np.testing.assert_array_equal(np.flatnonzero(down[:, e4]), np.arange(35, 45))
    assert down.sum() == 20 and bank.steps[0] == 45 and bank.cut_notes == 0
    np.testing.assert_array_equal(np.flatnonzero(bank.hands[0, 1].any(axis=1)), np.arange(25, 45))
    assert not bank.hands[0, 0].any()  # no left-hand note
    # The env's target_keys at step t: down[t : t + 11], frame-major.
    windows = {t: down[t : t + TARGET_FRAMES] for t in (0, 14, 15, 20, 25, 30)}
    assert not windows[0].any() and not windows[14].any()  # the count-in's first 0.3 s: nothing in view
    frames = {
        t: (np.flatnonzero(w[:, c4]).tolist(), np.flatnonzero(w[:, e4]).tolist()) for t, w in windows.items()
    }
    assert frames[15] == ([10], [])  # C4 at step 25 = frame 10
    assert frames[20] == ([5, 6, 7, 8, 9, 10], [])  # steps 25..30
    assert frames[25] == (list(range(10)), [10])  # C4 now (steps 25..34), E4 from step 35
    assert frames[30] == ([0, 1, 2, 3, 4], [5, 6, 7, 8, 9, 10])
    # A song already starting after the count-in is played as written: C4 at 0.80 s -> steps 40..49.
    late = Song("late", (Note(60, 0.80, 1.00, "right"),))
    bank = song_bank([late], kb, 0.02, steps=60, lookahead=10)  # the default count-in, 0.5 s
    np.testing.assert_array_equal(np.flatnonzero(bank.down[0, :, c4]), np.arange(40, 50))


def test_count_in_refusals() -> None:
    with pytest.raises(ValueError, match=r"count_in_s = -0\.5"):
        PlaybackConfig(count_in_s=-0.5)
    with pytest.raises(ValueError, match=r"leaves no song in an episode of 10\.0 s"):
        PianoEnvConfig(playback=PlaybackConfig(count_in_s=10.0))


def test_env_and_song_commands_play_songs_alike() -> None:
    """Parity: for every song of a small env's bank (a library song and a random one), ``SongCommands`` (the
    robot's side) with the env's playback gives the env's ``target_keys`` and ``progress``
    (``LitePiano.task_obs``) at every step of the episode, count-in included; the songs start no earlier than
    the count-in on both sides. The lead, by definition: ``target_keys`` at step t are the bank's rows
    t + 2 .. t + 12 (``SONG_LEAD_STEPS`` = 2), while the tick's goal (``goal_now``, what is scored) is
    row t."""
    cfg = dataclasses.replace(nominal_config(), songs=1, library=("c_major_arpeggio_right",))
    env = LitePiano(cfg)
    count_in = cfg.playback.count_in_s
    assert count_in == PlaybackConfig().count_in_s == 0.5
    lead = cfg.playback.lead_steps
    assert lead == SONG_LEAD_STEPS == 2 and PlaybackConfig().lead_steps == 0
    data = SimpleNamespace(qpos=jnp.zeros(env.mj_model.nq))  # keys at rest: key_pressed all 0
    obs = jax.jit(lambda step, song: env.task_obs(None, data, None, {"step": step, "song": song}))
    for i, song in enumerate(env.songs):
        src = SongCommands(song, cfg.keyboard, env.dt, MidiKeys(queue.Queue(), cfg.keyboard), cfg.playback)
        assert song.duration_s + count_in <= cfg.episode_length_s  # the random song fits after the count-in
        first = round(max(count_in, song.notes[0].start_s) / env.dt)
        assert np.flatnonzero(env.bank.down[i].any(axis=1))[0] == first
        assert np.flatnonzero(src.down.any(axis=1))[0] == first
        assert first >= round(count_in / env.dt) == 25
        src.begin(0.0)
        for t in range(env.episode_length + 1):
            want = obs(jnp.int32(t), jnp.int32(i))
            got = src(t * env.dt)
            np.testing.assert_array_equal(got["target_keys"], np.asarray(want["target_keys"]), f"step {t}")
            rows = env.bank.down[i, t + lead : t + lead + TARGET_FRAMES].reshape(-1)
            np.testing.assert_array_equal(got["target_keys"], rows, f"step {t}")
            np.testing.assert_array_equal(src.goal_now(), env.bank.down[i, t] > 0.5, f"step {t}")
            # Within a float32 ulp (the jitted division may round the other way): 1e-7; a step is 0.002.
            np.testing.assert_allclose(got["progress"], np.asarray(want["progress"]), rtol=0, atol=1e-7)
            if t >= src.song_steps:
                break


@pytest.fixture(scope="module")
def env() -> LitePiano:
    kb = dataclasses.replace(compact_config(), damping_ratio=50.0)
    cfg = dataclasses.replace(nominal_config(), songs=2, library=(), keyboard=kb)
    return LitePiano(cfg)


@pytest.fixture(scope="module")
def fns(env: LitePiano):
    # Quick compiles (LLVM at -O1, as the tiny training preset): the same programs, compiled sooner.
    quick = {"compiler_options": QUICK_COMPILE}
    return jax.jit(env.reset, **quick), jax.jit(env.step, **quick)


def test_layout_and_sizes(env: LitePiano) -> None:
    om = env.obs_manager
    assert (
        om.schema.name == "lite_piano_arms"
        and om.size == TARGET_FRAMES * PIANO_KEYS + 1 + PIANO_KEYS + 3 * 14
    )
    assert om.fingerprint == type(om).golden("lite_piano_arms").fingerprint
    assert env.mj_model.nq == 14 + PIANO_KEYS  # the robot's joints, then one hinge per key
    np.testing.assert_array_equal(env.robot_index.qpos, np.arange(14))


def test_registered_env_sizes() -> None:
    """LitePiano as the env registry builds it: the piano task, 11 frames of the 49 target keys, progress, 49
    key_pressed, q, dq, a (tests/envs/test_registry.py traces it; its sizes are pinned here)."""
    from bar_policy import envs

    env = envs.load("LitePiano")
    assert env.task_name == "piano"
    assert (env.observation_size, env.action_size) == (11 * 49 + 1 + 49 + 3 * 14, 14)


@pytest.mark.slow
def test_observation_counts_and_f1(env: LitePiano, fns) -> None:
    reset, step = fns
    s = reset(jax.random.PRNGKey(0))
    song = int(s.info["song"])
    parts = env.obs_manager.split(np.asarray(s.obs))
    # target_keys at reset: the bank's rows 0..10 of the episode's song; progress 0; no key down.
    np.testing.assert_array_equal(parts["target_keys"], env.bank.down[song, :TARGET_FRAMES].reshape(-1))
    assert parts["progress"][0] == 0.0 and not parts["key_pressed"].any()
    a = jnp.zeros(14, jnp.float32)
    s1 = step(s, a)
    parts = env.obs_manager.split(np.asarray(s1.obs))
    np.testing.assert_array_equal(
        parts["target_keys"], env.bank.down[song, 1 : 1 + TARGET_FRAMES].reshape(-1)
    )
    assert parts["progress"][0] == pytest.approx(1 / env.episode_length)
    # Counts of step 0: no key down, so tp = fp = 0 and fn = the goal keys of row 0.
    goal0 = env.bank.down[song, 0]
    assert float(s1.metrics["true_pos"]) == 0 and float(s1.metrics["false_pos"]) == 0
    assert float(s1.metrics["false_neg"]) == goal0.sum() == float(s1.metrics["goal_keys"])
    # Push two keys past their thresholds: one goal key of row 1 (if any) and one that is not a goal.
    goal1 = env.bank.down[song, 1]
    thr = press_thresholds(env.config.keyboard)
    angles = np.zeros(PIANO_KEYS, np.float32)
    wrong = int(np.flatnonzero(goal1 == 0)[0])
    angles[wrong] = 1.5 * thr[wrong]
    hit = np.flatnonzero(goal1 > 0)
    if hit.size:
        angles[hit[0]] = 1.5 * thr[hit[0]]
    qpos = s1.data.qpos.at[env._key_qpos].set(jnp.asarray(angles))
    s1 = s1.replace(data=s1.data.replace(qpos=qpos, qvel=jnp.zeros_like(s1.data.qvel)))
    s2 = step(s1, a)
    after = np.asarray(env.key_angles(s2.data)) >= thr
    goal = goal1 > 0.5
    expected = np.zeros(PIANO_KEYS, bool)
    expected[wrong] = True
    expected[hit[:1]] = True
    np.testing.assert_array_equal(after, expected)  # the pushed keys, and only they, are still down
    assert float(s2.metrics["false_pos"]) == 1 and float(s2.metrics["true_pos"]) == min(hit.size, 1)
    assert float(s2.metrics["true_pos"]) == np.sum(after & goal)
    assert float(s2.metrics["false_pos"]) == np.sum(after & ~goal)
    assert float(s2.metrics["false_neg"]) == np.sum(~after & goal)
    np.testing.assert_array_equal(
        env.obs_manager.split(np.asarray(s2.obs))["key_pressed"], after.astype(np.float32)
    )
    # The evaluation's F1 is RoboPianist's: the mean over steps of each step's 2 tp / (2 tp + fp + fn)
    # (1 for a step with nothing asked and nothing down); the pooled F1 sums the counts first. By hand from
    # the two steps' counts:
    keys = ("true_pos", "false_pos", "false_neg", "precision", "recall", "f1")
    m = {k: jnp.stack([s1.metrics[k], s2.metrics[k]]) for k in env.metric_keys}
    ratios = env.eval_ratios(m)
    counts = [tuple(float(s.metrics[k]) for k in keys[:3]) for s in (s1, s2)]
    per_step = [2 * tp / (2 * tp + fp + fn) if 2 * tp + fp + fn else 1.0 for tp, fp, fn in counts]
    num, den = (float(np.sum(np.asarray(x))) for x in ratios["f1"])
    assert den == 2 and num == pytest.approx(sum(per_step), abs=1e-6)
    tp, fp, fn = (sum(c[i] for c in counts) for i in range(3))
    num, den = (float(np.sum(np.asarray(x))) for x in ratios["f1_pooled"])
    assert (num, den) == (2 * tp, 2 * tp + fp + fn)
    assert ratios["success_rate"] is ratios["f1"]


@pytest.mark.slow
def test_key_counts_and_recall_per_colour(env: LitePiano, fns) -> None:
    """The step's TP and FN over the black and over the white goal keys, and the evaluation's pooled
    ``recall_black`` / ``recall_white`` of them (the observation is untouched: a metric, not an input)."""
    reset, step = fns
    black = black_keys(env.config.keyboard)
    s = reset(jax.random.PRNGKey(0))
    song = int(s.info["song"])
    rows = env.bank.down[song] > 0.5
    # A step whose goal row holds black and white keys (the random songs have them from the count-in's
    # end, row 25), with nb black and nw white goal keys.
    t = int(np.flatnonzero((rows & black).any(1) & (rows & ~black).any(1))[0])
    goal = rows[t]
    nb, nw = int(np.sum(goal & black)), int(np.sum(goal & ~black))
    thr = press_thresholds(env.config.keyboard)
    a = jnp.zeros(14, jnp.float32)

    def step_with_down(key: int) -> dict[str, float]:
        """Row ``t``'s step from the reset state with ``key`` pushed past its threshold (and held down)."""
        angles = np.zeros(PIANO_KEYS, np.float32)
        angles[key] = 1.5 * thr[key]
        qpos = s.data.qpos.at[env._key_qpos].set(jnp.asarray(angles))
        s0 = s.replace(data=s.data.replace(qpos=qpos), info={**s.info, "step": jnp.int32(t)})
        out = step(s0, a)
        assert np.flatnonzero(np.asarray(env.key_angles(out.data)) >= thr).tolist() == [key]
        return {k: float(v) for k, v in out.metrics.items()}

    # Step A: the lowest black goal key down: black TP 1, FN nb - 1; white TP 0, FN nw.
    ma = step_with_down(int(np.flatnonzero(goal & black)[0]))
    assert (ma["true_pos_black"], ma["false_neg_black"]) == (1, nb - 1)
    assert (ma["true_pos_white"], ma["false_neg_white"]) == (0, nw)
    # Step B: the lowest white goal key down: black TP 0, FN nb; white TP 1, FN nw - 1.
    mb = step_with_down(int(np.flatnonzero(goal & ~black)[0]))
    assert (mb["true_pos_black"], mb["false_neg_black"]) == (0, nb)
    assert (mb["true_pos_white"], mb["false_neg_white"]) == (1, nw - 1)
    for m in (ma, mb):  # the colours split the keyboard's counts
        assert m["true_pos_black"] + m["true_pos_white"] == m["true_pos"] == 1
        assert m["false_neg_black"] + m["false_neg_white"] == m["false_neg"] == nb + nw - 1
    # Pooled over both steps (sums, then one division): recall_black = 1 / (2 nb), recall_white = 1 / (2 nw),
    # recall_pooled = 2 / (2 nb + 2 nw).
    ratios = env.eval_ratios({k: jnp.asarray([ma[k], mb[k]]) for k in env.metric_keys})
    sums = {k: tuple(float(np.sum(np.asarray(x))) for x in v) for k, v in ratios.items()}
    assert sums["recall_black"] == (1, 2 * nb) and sums["recall_white"] == (1, 2 * nw)
    assert sums["recall_pooled"] == (2, 2 * nb + 2 * nw)
    # The reset's metrics (zeros, as a count-in step with nothing asked): no goal key of either colour. The
    # evaluators divide sum(num) / max(sum(den), 1): 0, not NaN (brax.evaluation, evaluate_torch_policy).
    for k in ("recall_black", "recall_white"):
        num, den = (float(np.sum(np.asarray(x))) for x in env.eval_ratios(s.metrics)[k])
        assert (num, den) == (0, 0) and num / max(den, 1.0) == 0.0
