"""``bar_policy.quality.metrics`` and ``QualityMeter``/``summarise`` on signals worked out by hand.

Tolerances: float64 results get ``rel=1e-12`` (a few hundred rounded operations of ~1.1e-16 each);
float32 (jax, x64 off) gets ``rel=1e-5`` (eps 6e-8 times a 100-point FFT's ~log2(100) growth, with margin).
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from bar_policy.quality import metrics as qm
from bar_policy.quality.report import QualityMeter, summarise

DT = 0.02  # 50 Hz: a CHATTER_SEGMENT_S = 2 s segment is L = 100 ticks, bins 1 / (100 * 0.02) = 0.5 Hz apart
M = qm.LIMIT_MARGIN_RAD


def _sine(n: int, f_hz: float, amp: float, phase: float = 0.0) -> np.ndarray:
    return amp * np.sin(2 * np.pi * f_hz * np.arange(n) * DT + phase)


def test_at_cap_numpy_and_jax() -> None:
    cap = np.array([2.0, 5.0])  # per-joint caps
    below = np.nextafter(2.0, 0.0)  # one ulp under 2.0
    demand = np.array([[2.0, -5.0], [below, -4.999], [2.5, -7.0], [-2.0, 0.0]])
    want = [[True, True], [False, False], [True, True], [True, False]]  # |d| >= 1.0 * cap
    got = qm.at_cap(demand, cap)
    assert isinstance(got, np.ndarray) and got.tolist() == want
    # fraction 0.5: |1.0| >= 0.5 * 2 = 1.0 yes; |2.4| >= 0.5 * 5 = 2.5 no; |-2.5| >= 2.5 yes.
    assert qm.at_cap(np.array([[1.0, 2.4], [0.0, -2.5]]), cap, 0.5).tolist() == [[True, False], [False, True]]
    # float32 (x64 off): 2.0, 5.0, 2.5, 7.0 are exact; row 1 is skipped (one ulp under 2.0 rounds to 2.0).
    got_j = qm.at_cap(jnp.asarray(demand), jnp.asarray(cap))
    assert isinstance(got_j, jax.Array) and np.asarray(got_j)[[0, 2, 3]].tolist() == [want[0], *want[2:]]


def test_at_cap_with_the_reported_torque_needs_both() -> None:
    # Caps 4 and 10 N*m; the reported level 0.8 x cap is 3.2 and 8.0 N*m (dyadic-free but exact to compare:
    # the values below sit at least 0.1 N*m from each level).
    cap = np.array([4.0, 10.0])
    demand = np.array([[5.7, -12.0], [5.7, -12.0], [3.9, 10.0], [-4.0, 10.0]])
    reported = np.array([[0.2, -10.0], [4.0, -7.9], [4.0, 8.1], [-3.3, 7.0]])
    # row 0: wrist asked 5.7 but reports 0.2 (a lead under latency): no; joint 1 both: yes.
    # row 1: joint 0 both: yes; joint 1 reports 7.9 < 8.0: no. row 2: demand 3.9 < 4: no; 10 and 8.1: yes.
    # row 3: |-4| >= 4 and |-3.3| >= 3.2: yes; 7.0 < 8.0: no. The sign does not matter (bang-bang).
    want = [[False, True], [True, False], [False, True], [True, False]]
    assert qm.at_cap(demand, cap, reported=reported).tolist() == want
    got_j = qm.at_cap(jnp.asarray(demand), jnp.asarray(cap), reported=jnp.asarray(reported))
    assert np.asarray(got_j).tolist() == want
    assert qm.REPORTED_CAP_FRACTION == 0.8
    # reported_fraction 0: the demand alone, as without ``reported``.
    assert (
        qm.at_cap(demand, cap, reported=reported, reported_fraction=0.0).tolist()
        == qm.at_cap(demand, cap).tolist()
    )


def test_near_limit_numpy_and_jax() -> None:
    lo, hi = np.array([-1.0, 0.0]), np.array([1.0, 2.0])
    q = np.array(
        [
            [-1.0 + 0.01, 1.0],  # inside the margin at the lower limit (joint 0); 1.0 mid-range (joint 1)
            [0.0, 2.0 - 0.01],  # inside at the upper limit (joint 1)
            [-1.0 + M, 2.0 - M],  # exactly at the margin (same float operation as the module): counts
            [-1.0 + 0.03, 2.0 - 0.03],  # 0.03 > 0.02 clear of both: outside
            [-1.5, 2.5],  # past the limits: near
        ]
    )
    want = [[True, False], [False, True], [True, True], [False, False], [True, True]]
    assert qm.near_limit(q, lo, hi).tolist() == want
    # Dyadic margin 0.25: 0.75 >= 1 - 0.25 exactly; -0.75 <= -1 + 0.25 exactly; 0.5 neither.
    dyadic = qm.near_limit(np.array([0.75, -0.75, 0.5]), -np.ones(3), np.ones(3), 0.25)
    assert dyadic.tolist() == [True, True, False]
    got_j = qm.near_limit(jnp.asarray(q[[0, 1, 3, 4]]), jnp.asarray(lo), jnp.asarray(hi))
    assert np.asarray(got_j).tolist() == [want[0], want[1], want[3], want[4]]


def test_cap_dwell_accumulates_resets_and_faults_after_half_a_second() -> None:
    t = np.zeros(2)
    t = qm.cap_dwell_step(t, np.array([True, False]), DT)
    assert t.tolist() == [DT, 0.0]  # 0 + 0.02 exactly; joint 1 stays 0
    t = qm.cap_dwell_step(t, np.array([True, True]), DT)
    assert t[0] == pytest.approx(0.04, abs=1e-15) and t[1] == DT  # 0.02 + 0.02 (one rounding)
    t = qm.cap_dwell_step(t, np.array([False, True]), DT)
    assert t[0] == 0.0 and t[1] == pytest.approx(0.04, abs=1e-15)  # joint 0 left the cap: back to 0
    t = np.zeros(1)
    for _ in range(25):  # 25 ticks of 0.02 s at the cap = 0.5 s
        t = qm.cap_dwell_step(t, np.array([True]), DT)
    # 25 float64 additions: 0.5000000000000001 = 0.5 + 1 ulp (the docstring says ...0002, see the report).
    assert t[0] == 0.5000000000000001
    assert not qm.dwell_exceeded(t)[0]  # 0.5 + ~1e-16 <= 0.5 + 1e-6: not past the limit
    t = qm.cap_dwell_step(t, np.array([True]), DT)  # 26th tick: 0.52 > 0.500001
    assert qm.dwell_exceeded(t)[0]
    # Strictly past limit + 1e-6: 0.3 > 0.250001 yes; 0.25 (exactly the limit) no.
    assert qm.dwell_exceeded(np.array([0.3, 0.25]), limit=0.25).tolist() == [True, False]


def test_cap_dwell_jax_float32() -> None:
    t = jnp.zeros(2, dtype=jnp.float32)
    on = jnp.array([True, True])
    for _ in range(25):
        t = qm.cap_dwell_step(t, on, DT)
    # float32 sum of 25 x 0.02 = 0.50000006 (the docstring's figure): within the 1e-6 slack, no fault.
    assert np.asarray(t)[0] == np.float32(0.50000006) and not bool(qm.dwell_exceeded(t)[0])
    t = qm.cap_dwell_step(t, jnp.array([True, False]), DT)  # 26th tick on joint 0; joint 1 resets
    assert isinstance(t, jax.Array)
    assert np.asarray(qm.dwell_exceeded(t)).tolist() == [True, False] and float(t[1]) == 0.0


def test_action_rate_numpy_and_jax() -> None:
    a = np.array([[0.0, 0.0], [0.5, -0.5], [0.5, 0.5]])
    # tick 1: 0.5^2 + (-0.5)^2 = 0.5; tick 2: 0^2 + 1^2 = 1.0; mean over the 2 ticks with a predecessor 0.75
    rate = qm.action_rate(a)
    assert rate.tolist() == [0.5, 1.0] and float(np.mean(rate)) == 0.75  # dyadic: exact
    assert np.asarray(qm.action_rate(jnp.asarray(a))).tolist() == [0.5, 1.0]  # exact in float32 too
    # (T, envs, n) = (3, 2, 2): env 0 as above, env 1 = twice it -> 4x the squares: 2.0, 4.0.
    b = np.stack([a, 2 * a], axis=1)
    assert qm.action_rate(b).tolist() == [[0.5, 2.0], [1.0, 4.0]]
    assert qm.action_rate(a[:1]).shape == (0,)  # one tick: no predecessor


def test_segments_cover_the_window_and_end_at_its_end() -> None:
    assert qm._segments(100, 100) == [0]
    assert qm._segments(200, 100) == [0, 50, 100]  # half-overlapping, the last ends at 200
    assert qm._segments(230, 100) == [0, 50, 100, 130]  # 130 appended so the last ends at 230


def test_sine_on_a_bin_above_the_cutoff_gives_amplitude_over_sqrt2() -> None:
    # 10 Hz = bin 20 of L = 100; its Hann sidelobes land on bins 19, 21 (9.5, 10.5 Hz > 5): all counted.
    # Windowed power: (A L / 2)^2 (1/4 + 2/16) * 2 / (L * 3L/8) = A^2 / 2 -> RMS A / sqrt(2).
    # n = 230 gives segments 0, 50, 100, 130 (each spans exactly 20 cycles, so each is exact).
    x = np.stack([_sine(230, 10.0, 0.003, 0.3), _sine(230, 2.0, 0.05, 1.0), np.full(230, 0.3)], axis=1)
    rms = qm.highpass_rms(x, DT)
    assert isinstance(rms, np.ndarray) and rms.shape == (3,)
    assert rms[0] == pytest.approx(0.003 / math.sqrt(2), rel=1e-12)
    # 2 Hz = bin 4: it and its sidelobes (bins 3..5, <= 2.5 Hz) are all below 5 Hz -> 0 up to rounding:
    # ~1e-16 relative residue in each bin of a 0.05-amplitude sine -> far below 1e-14.
    assert rms[1] == pytest.approx(0.0, abs=1e-14)
    # A constant is removed with the segment mean; the residue is ~1 ulp of 0.3 (~5.6e-17) per tick.
    assert rms[2] == pytest.approx(0.0, abs=1e-14)
    # The worst joint is joint 0 (joint 1 is 16x larger, but below the cutoff); scaled to mrad:
    # 1000 * 0.003 / sqrt(2) = 2.1213203435596424 mrad.
    assert float(qm.chatter_mrad(x, DT)) == pytest.approx(2.1213203435596424, rel=1e-12)
    # cutoff 1.5 Hz: now 2 Hz (bins 3..5 = 1.5..2.5 Hz; bin 3 = 1.5 Hz is not > 1.5) is partly counted, and
    # joint 1 is worst: its bins 4, 5 carry (1/4 + 1/16) / (3/8) = 5/6 of A^2 / 2.
    want = 1000 * 0.05 / math.sqrt(2) * math.sqrt(5 / 6)
    assert float(qm.chatter_mrad(x, DT, cutoff_hz=1.5)) == pytest.approx(want, rel=1e-12)


def test_slow_drift_leaks_almost_nothing() -> None:
    # A ramp of D = 0.1 rad per 2 s segment, slope s = D / L per tick. Hann-windowed ramp bins for m >= 2
    # are (L s / 4) * second difference of 1 / (1 - e^{-i 2 pi m / L}), |.| ~= L^2 s / (4 pi m^3); summed over
    # m >= 11 (> 5 Hz): RMS ~= D * sqrt(sum_{m>=11} m^-6 / (3 pi^2)) ~= D * sqrt(1.6e-6 / 29.6) ~= 2.3e-4 D
    # (-73 dB): not exactly 0 as "leaks nothing" reads, so bound it at 3e-4 D (small-angle error ~2 %).
    d = 0.1
    x = (d / 100 * np.arange(230))[:, None]
    rms = float(qm.highpass_rms(x, DT)[0])
    assert 0.0 < rms < 3e-4 * d


def test_window_shorter_than_a_segment_and_too_short() -> None:
    # 16 ticks (MIN_CHATTER_TICKS): L = 16, bins 3.125 Hz apart; 12.5 Hz = bin 4, sidelobes 3, 5 (9.4, 15.6
    # Hz) above 5 Hz and away from Nyquist bin 8 -> exact A / sqrt(2). (T, envs, n) = (16, 2, 2).
    s = _sine(16, 12.5, 0.004)
    x = np.zeros((16, 2, 2))
    x[:, 0, 1], x[:, 1, 0] = s, 0.5 * s
    assert qm.chatter_mrad(x, DT) == pytest.approx([4 / math.sqrt(2), 2 / math.sqrt(2)], rel=1e-12)
    short = qm.highpass_rms(np.ones((qm.MIN_CHATTER_TICKS - 1, 3)), DT)
    assert short.shape == (3,) and np.isnan(short).all()
    assert np.isnan(qm.chatter_mrad(np.ones((15, 3)), DT))
    # jax (float32): same 16 x 2 signal, joint 1 worst.
    xj = jnp.asarray(np.stack([0.5 * s, s], axis=1))
    got = qm.chatter_mrad(xj, DT)
    assert isinstance(got, jax.Array) and float(got) == pytest.approx(4 / math.sqrt(2), rel=1e-5)
    assert np.isnan(np.asarray(qm.highpass_rms(jnp.ones((15, 2)), DT))).all()


def test_sines_next_to_the_cutoff_or_nyquist_are_not_exact() -> None:
    # The docstring says any on-bin sine above the cutoff gives A / sqrt(2). Hann moves a quarter of the
    # amplitude (1/16 of power, vs 3/8 in all) to each neighbour bin, so bins adjacent to 5 Hz / Nyquist
    # differ. These values are derived by hand and pin the actual behaviour (see the report).
    a, r = 0.002, 0.002 / math.sqrt(2)
    # 5.5 Hz = bin 11: its sidelobe on bin 10 (5.0 Hz, not > 5) is lost: (3/8 - 1/16) / (3/8) = 5/6.
    assert qm.highpass_rms(_sine(100, 5.5, a)[:, None], DT)[0] == pytest.approx(
        r * math.sqrt(5 / 6), rel=1e-12
    )
    # 5.0 Hz (at, not above, the cutoff) leaks 1/6 of its power into bin 11.
    assert qm.highpass_rms(_sine(100, 5.0, a)[:, None], DT)[0] == pytest.approx(
        r * math.sqrt(1 / 6), rel=1e-12
    )
    assert qm.highpass_rms(_sine(100, 4.5, a)[:, None], DT)[0] == pytest.approx(0.0, abs=1e-15)  # bin 9: 0
    # 24.5 Hz = bin 49: bins 48, 49 weight 2 carry (1/8)^2 + (1/4)^2 of (A L)^2; Nyquist bin 50 (weight 1)
    # gets both sidelobes coherently, (A L sin(phase) / 4)^2 -> mean square A^2 (5/12 + sin^2(phase) / 6).
    for phase, share in [(0.0, 5 / 12), (math.pi / 2, 7 / 12)]:
        got = qm.highpass_rms(_sine(100, 24.5, a, phase)[:, None], DT)[0]
        assert got == pytest.approx(a * math.sqrt(share), rel=1e-12)


def test_quality_meter_and_summary_on_two_episodes() -> None:
    cap, lo, hi = np.ones(2), -np.ones(2), np.ones(2)
    meter = QualityMeter(cap, lo, hi, DT, ("j0", "j1"))  # episode A: 100 ticks, completes
    sig = np.stack([_sine(100, 15.0, 0.001), _sine(100, 10.0, 0.002)], axis=1)
    demands = {20: [1.0, 0.0], 21: [0.0, -1.5], 22: [0.999, 0.0]}  # at cap: ticks 20, 21 (2 ticks)
    qs = {10: [0.99, 0.0], 11: [-0.985, 0.985], 12: [0.0, 1.0 - M], 13: [0.0, 0.97]}  # near: 10, 11, 12
    for t in range(100):
        act = [0.5, -0.5] if t == 50 else [0.0, 0.0]  # diffs at ticks 50, 51: 0.25 + 0.25 each -> sum 1.0
        meter.update(
            np.array(demands.get(t, [0.0, 0.0])), np.array(qs.get(t, [0.0, 0.0])), np.array(act), sig[t]
        )
    ep_a = meter.finish("A")
    # Bins 30 and 20 of L = 100, both well above 5 Hz: j0 0.001 / sqrt(2), j1 0.002 / sqrt(2) -> j1 worst.
    assert (ep_a.ticks, ep_a.cap_ticks, ep_a.limit_ticks, ep_a.faulted, ep_a.fault) == (100, 2, 3, False, "")
    assert ep_a.action_rate_sum == 1.0 and ep_a.chatter_joint == "j1"
    assert ep_a.chatter_mrad == pytest.approx(2 / math.sqrt(2), rel=1e-12)  # 1000 * 0.002 / sqrt 2

    meter = QualityMeter(cap, lo, hi, DT, ("j0", "j1"))  # episode B: 20 ticks, ended by a fault
    sig = _sine(20, 10.0, 0.01)  # L = 20: bins 2.5 Hz apart, 10 Hz = bin 4 (sidelobes 7.5, 12.5 Hz; Nyq 10)
    for t in range(20):
        demand = [0.0, 1.0] if t < 13 else [0.0, 0.0]  # 13 ticks at the cap
        q = [-1.0, 0.0] if t == 5 else [0.0, 0.0]  # 1 tick at the lower limit
        act = [0.25, 0.0] if t % 2 == 0 else [0.0, 0.0]  # 19 diffs of 0.25^2 = 0.0625 -> 1.1875
        meter.update(np.array(demand), np.array(q), np.array(act), np.array([sig[t], 0.0]))
    ep_b = meter.finish("B", fault="saturation")
    assert (ep_b.ticks, ep_b.cap_ticks, ep_b.limit_ticks, ep_b.faulted) == (20, 13, 1, True)
    assert ep_b.action_rate_sum == 1.1875 and ep_b.chatter_joint == "j0"
    assert ep_b.chatter_mrad == pytest.approx(10 / math.sqrt(2), rel=1e-12)  # kept in the record

    s = summarise([ep_a, ep_b])
    assert (s["episodes"], s["completed"], s["ticks"]) == (2, 1, 120)
    assert s["completion_pct"] == 50.0  # 100 * 1 / 2
    assert s["cap_share_pct"] == pytest.approx(12.5, rel=1e-15)  # 100 * (2 + 13) / 120
    assert s["limit_share_pct"] == pytest.approx(100 * 4 / 120, rel=1e-15)  # (3 + 1) / 120 = 3.333... %
    assert s["action_rate"] == pytest.approx(2.1875 / 118, rel=1e-15)  # (1.0 + 1.1875) / (99 + 19)
    # Chatter over completed episodes only: B (faulted, 7.07 mrad) is excluded and counted unmeasured.
    assert s["chatter_max_mrad"] == s["chatter_mean_mrad"] == pytest.approx(math.sqrt(2), rel=1e-12)
    assert (s["chatter_worst_episode"], s["chatter_unmeasured"]) == ("A", 1)
    assert math.isnan(summarise([])["completion_pct"])
