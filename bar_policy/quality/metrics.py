"""Safety and smoothness of a policy, defined once for every place a policy is measured.

The MJX evaluation during training, ``bar-deploy eval`` (C MuJoCo and the emulated bus), the fidelity bench
and the summary at the end of every ``bar-deploy`` run all call these functions, so a figure means the same
wherever it is printed. Every function is plain array arithmetic: numpy in, numpy out (deploy, never jax);
jax in, jax out (inside jit / vmap / scan during training).

Per policy tick ``t`` of an episode (a clip, a reach episode, a deploy run's POLICY segment):

- **at the torque cap**: a joint's *unclipped* MIT torque demand ``|tau|`` reaches ``CAP_FRACTION`` of its
  firmware cap (the firmware clips it there: the joint is saturated) and, where the motor's torque is
  read back (the deploy side: ``JointState.tau``, the firmware's torque at its own reading), that torque is
  at least ``REPORTED_CAP_FRACTION`` of the cap too. The demand is the command the runtime sends at the
  state it has just read; with latency the motor applies an older command, and a demand over the cap while
  the motor reports a fraction of it is a lead, not a saturated joint. The deploy supervisor's saturation
  fault is the same test held for ``CAP_DWELL_S`` without a break (``cap_dwell_step``).
- **near a joint limit**: a joint's measured position is within ``LIMIT_MARGIN_RAD`` of its lower or upper
  limit.
- **action rate**: ``sum_j (a_t[j] - a_{t-1}[j])^2`` in action units (a in [-1, 1]), the quantity the
  ``action_rate`` reward term penalises; reported as the mean over the ticks that have a predecessor.
- **chatter**: the root mean square of the part of a joint's signal above ``CHATTER_CUTOFF_HZ``, in mrad,
  on the worst joint (``highpass_rms``: Welch's method, half-overlapping Hann-windowed segments of
  ``CHATTER_SEGMENT_S``). The signal is ``q_cmd - q_ref`` for tracking (the command minus the reference
  frame it targets: what the policy adds on top of the motion) and ``q_cmd`` itself for reach. A sine of
  amplitude A on a DFT bin at least one bin clear of the cutoff (and of Nyquist) has chatter
  ``A / sqrt(2)`` above it, 0 below it (the Hann window puts a sixth of the power into each neighbour bin);
  a slow drift leaks almost nothing above it (-73 dB for a linear ramp: the windows go to zero at their
  ends).
- **completion**: an episode completes when no fault (a supervisor fault on the robot and the sim targets; a
  termination or a would-be saturation fault in MJX) ended it before its end.
"""

from __future__ import annotations

import math

from bar_policy._array import Array, array_namespace

__all__ = [
    "CAP_DWELL_S",
    "CAP_FRACTION",
    "CHATTER_CUTOFF_HZ",
    "CHATTER_SEGMENT_S",
    "LIMIT_MARGIN_RAD",
    "MIN_CHATTER_TICKS",
    "REPORTED_CAP_FRACTION",
    "action_rate",
    "at_cap",
    "cap_dwell_step",
    "chatter_mrad",
    "dwell_exceeded",
    "highpass_rms",
    "near_limit",
]

CHATTER_CUTOFF_HZ = 5.0
"""Frequencies above this count as chatter, Hz (a tracked motion's content is below: the generator's clips
are bounded at 2.5 rad/s and 12.5 rad/s^2, whose ratio puts their energy under 0.8 Hz)."""
CAP_FRACTION = 1.0
"""A joint is at its torque cap when ``|unclipped demand| >= CAP_FRACTION * cap`` (the supervisor's
``SafetyConfig.saturation_fraction`` default)."""
REPORTED_CAP_FRACTION = 0.8
"""Where the motor's torque is read back, a joint is at its cap only while ``|reported| >=
REPORTED_CAP_FRACTION * cap`` as well (the supervisor's ``SafetyConfig.saturation_reported_fraction``
default). Below 1 because a real motor's torque reading ripples around its limit (and the feedback codec
rounds it), and a motor weakened to this share of its nominal torque still reads as saturated: the reading
is the firmware's current times its nominal torque constant."""
CAP_DWELL_S = 0.5
"""Unbroken time at the cap that the deploy supervisor turns into a fault, s."""
LIMIT_MARGIN_RAD = 0.02
"""A joint within this of a limit counts as near it, rad (1.1 degrees: inside the encoder offset's and
calibration's uncertainty of a real joint, so nearer is at the limit for practical purposes)."""
MIN_CHATTER_TICKS = 16
"""Shortest window chatter is computed over, ticks (shorter windows give NaN: at 50 Hz, 0.32 s resolves
3.1 Hz bins, the coarsest that still separates content below 5 Hz from above)."""
CHATTER_SEGMENT_S = 2.0
"""Length of the segments chatter is averaged over, s (0.5 Hz bins: a 1 Hz motion's Hann leakage at 5 Hz
is below -70 dB)."""


def at_cap(
    demand: Array,
    cap: Array,
    fraction: float = CAP_FRACTION,
    reported: Array | None = None,
    reported_fraction: float = REPORTED_CAP_FRACTION,
) -> Array:
    """Whether each joint is at its torque cap: the demand beyond it (and the motor's torque near it).

    Args:
        demand: unclipped MIT torque, N*m, shape ``(..., n)``.
        cap: firmware torque cap, N*m, shape ``(n,)``.
        fraction: share of the cap the demand must reach.
        reported: the torque the motor reports, N*m, shape ``(..., n)``; None: the demand alone (the MJX
            evaluation, whose demand is the applied command's: its clipped value is the motor's torque).
        reported_fraction: share of the cap the reported torque must reach.

    Returns:
        Boolean, shape ``(..., n)``.
    """
    hit = abs(demand) >= fraction * cap
    if reported is None:
        return hit
    return hit & (abs(reported) >= reported_fraction * cap)


def near_limit(q: Array, lower: Array, upper: Array, margin: float = LIMIT_MARGIN_RAD) -> Array:
    """Whether each joint is within ``margin`` rad of its lower or upper limit.

    Shapes: ``q`` ``(..., n)``, ``lower``/``upper`` ``(n,)`` rad; returns boolean ``(..., n)``.
    """
    return (q <= lower + margin) | (q >= upper - margin)


def cap_dwell_step(time_at_cap: Array, at_cap_now: Array, dt: float) -> Array:
    """One tick of the saturation rule: per joint, the unbroken time at the cap, s.

    Grows by ``dt`` on a tick at the cap and returns to 0 on the first tick below it, so only an unbroken
    run counts (a bang-bang between +cap and -cap stays at the cap). A fault is ``dwell_exceeded``.

    Args:
        time_at_cap: the time so far, s, shape ``(..., n)``.
        at_cap_now: this tick's ``at_cap``, shape ``(..., n)``.
        dt: tick length, s.
    """
    return (time_at_cap + dt) * at_cap_now  # 0 where below the cap, in the time's dtype


def dwell_exceeded(time_at_cap: Array, limit: float = CAP_DWELL_S) -> Array:
    """Whether each joint's unbroken time at the cap is past ``limit`` s: the saturation fault.

    ``time > limit + 1e-6``: the microsecond absorbs the rounding of a time summed tick by tick (25 ticks of
    0.02 s sum to 0.50000006 in float32 and 0.5000000000000001 in float64), so 25 ticks at 50 Hz are 0.5 s
    (no fault) and the 26th tick faults, in jax and numpy alike.
    """
    return time_at_cap > limit + 1e-6


def action_rate(actions: Array) -> Array:
    """Per tick ``sum_j (a_t - a_{t-1})^2`` (action units squared) for the ticks that have a predecessor.

    Args:
        actions: shape ``(T, n)`` (or ``(T, ..., n)``), consecutive policy ticks along axis 0.

    Returns:
        Shape ``(T - 1, ...)``; its mean is the reported action rate.
    """
    d = actions[1:] - actions[:-1]
    return (d * d).sum(axis=-1)


def _segments(n: int, length: int) -> list[int]:
    """Start ticks of half-overlapping segments of ``length`` covering ``n`` ticks, the last at the end."""
    starts = list(range(0, n - length + 1, max(length // 2, 1)))
    if starts[-1] != n - length:
        starts.append(n - length)
    return starts


def highpass_rms(x: Array, dt: float, cutoff_hz: float = CHATTER_CUTOFF_HZ) -> Array:
    """Root mean square of each joint's signal above ``cutoff_hz`` (Welch's method; the module docstring).

    The window is cut into half-overlapping segments of ``CHATTER_SEGMENT_S`` (the whole window when it is
    shorter), the last one aligned with the end; each segment's mean is removed and it is multiplied by a
    periodic Hann window ``w_k = (1 - cos(2 pi k / L)) / 2`` (its ends go to zero, so a slow drift across the
    segment leaks almost nothing above the cutoff: -73 dB for a ramp), and its power above the cutoff is
    ``sum_f 2 |X_f|^2 / (L sum_k w_k^2)`` over the one-sided DFT bins ``f > cutoff`` (the Nyquist bin counted
    once). By Parseval's theorem that is the ``w^2``-weighted mean square of the segment's content above the
    cutoff, and the half-overlapping Hann windows weigh every tick alike. The result is the square root of
    the mean over segments. Exact for a sine on a DFT bin whose neighbours lie on the same side of the
    cutoff (and below Nyquist): amplitude A above the cutoff gives A / sqrt(2), below it 0; next to the
    cutoff the neighbour's sixth of the power falls on the other side (tests/quality/test_metrics.py).

    Args:
        x: signal, shape ``(T, ...)`` with time along axis 0 (e.g. ``(T, n)`` or ``(T, envs, n)``).
        dt: sample period, s.
        cutoff_hz: bins strictly above this frequency count, Hz.

    Returns:
        Shape ``x.shape[1:]``, in the signal's units; NaN when ``T < MIN_CHATTER_TICKS``.
    """
    xp = array_namespace(x)
    n = x.shape[0]
    if n < MIN_CHATTER_TICKS:
        return xp.full(x.shape[1:], math.nan)
    length = min(n, round(CHATTER_SEGMENT_S / dt))
    k = xp.arange(length)
    w = 0.5 - 0.5 * xp.cos(2.0 * math.pi * k / length)
    bins = xp.arange(length // 2 + 1)
    weight = xp.where(bins / (length * dt) > cutoff_hz, 2.0, 0.0)
    if length % 2 == 0:
        weight = xp.where(bins == length // 2, weight / 2.0, weight)
    expand = (1,) * (x.ndim - 1)
    w = w.reshape((length, *expand)).astype(x.dtype)
    weight = weight.reshape((-1, *expand))
    norm = length * float(0.375 * length)  # sum_k w_k^2 = 3 L / 8 for the periodic Hann window (L >= 3)
    total = 0.0
    starts = _segments(n, length)
    for s in starts:
        seg = x[s : s + length]
        seg = (seg - xp.mean(seg, axis=0)) * w
        spec = xp.fft.rfft(seg, axis=0)
        total = total + xp.sum(weight * (spec.real * spec.real + spec.imag * spec.imag), axis=0) / norm
    return xp.sqrt(total / len(starts))


def chatter_mrad(x: Array, dt: float, cutoff_hz: float = CHATTER_CUTOFF_HZ) -> Array:
    """Chatter of one window: ``1000 * max_j highpass_rms`` of a ``(T, ..., n)`` rad signal, mrad.

    Returns shape ``x.shape[1:-1]`` (a scalar for ``(T, n)``); NaN for a window too short to tell.
    """
    xp = array_namespace(x)
    return 1000.0 * xp.max(highpass_rms(x, dt, cutoff_hz), axis=-1)
