"""The MJX evaluation's quality accounting equals the deploy side's (``QualityMeter`` + ``summarise``).

Three hand-made episodes of 3 joints, 60 ticks at 50 Hz (caps 10 N*m, limits +-1 rad):
- ``calm``: a 1 Hz sine (no chatter), never at a cap; completes;
- ``buzz``: a 0.02 rad 12.5 Hz square wave on joint 2 on top (chatter 20 mrad), joint 0 at its cap for 10
  ticks (0.2 s: no fault), joint 1 within the 0.02 rad limit margin for 5 ticks; completes;
- ``stuck``: joint 1 at its cap from tick 20 on: the 26th tick at the cap (tick 45) makes the unbroken time
  0.52 s > 0.5 s, a fault; it counts up to and including that tick.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from bar_policy.quality import QualityMeter, summarise
from bar_policy.training import eval_quality
from bar_policy.training.parallel import AXIS

T, N, DT = 60, 3, 0.02
CAP = np.full(N, 10.0)
LOWER, UPPER = np.full(N, -1.0), np.full(N, 1.0)


def _episodes() -> dict[str, dict[str, np.ndarray]]:
    t = np.arange(T) * DT
    base = 0.3 * np.sin(2 * np.pi * 1.0 * t)[:, None] * np.ones(N)
    out = {}
    for name in ("calm", "buzz", "stuck"):
        demand = np.zeros((T, N))
        q = 0.5 * base.copy()
        signal = base.copy()
        if name == "buzz":
            signal[:, 2] += 0.02 * np.where((np.arange(T) // 2) % 2 == 0, 1.0, -1.0)
            demand[10:20, 0] = 11.0
            q[30:35, 1] = 0.99
        if name == "stuck":
            demand[20:, 1] = -10.0
        out[name] = {"demand": demand, "q": q, "action": signal / 2, "signal": signal}
    return out


def _mjx(episodes: dict) -> dict[str, float]:
    """The evaluation's accounting over the episodes as env slots (one device: axis of size 1)."""
    names = list(episodes)
    stack = {
        k: jnp.asarray(np.stack([episodes[n][k] for n in names], axis=1), jnp.float32)
        for k in ("demand", "q", "action", "signal")
    }
    f32 = lambda x: jnp.asarray(x, jnp.float32)  # noqa: E731

    def run(_: jax.Array) -> dict:
        c = eval_quality.init(len(names), N)
        alive = jnp.ones(len(names))
        for k in range(T):
            sig = {key: v[k] for key, v in stack.items()}
            c, _ = eval_quality.update(
                c,
                sig,
                alive,
                jnp.zeros(len(names)),
                k == 0,
                cap=f32(CAP),
                lower=f32(LOWER),
                upper=f32(UPPER),
                dt=DT,
            )
        return eval_quality.finish(c, stack["signal"], DT)

    out = jax.vmap(run, axis_name=AXIS)(jnp.zeros(1))
    return {k: float(v[0]) for k, v in out.items()}


def _deploy(episodes: dict) -> dict[str, float]:
    records = []
    for name, ep in episodes.items():
        meter = QualityMeter(CAP, LOWER, UPPER, DT, ("j0", "j1", "j2"))
        fault = ""
        for k in range(T):
            meter.update(ep["demand"][k], ep["q"][k], ep["action"][k], ep["signal"][k])
            at = np.abs(ep["demand"][: k + 1]) >= CAP
            run = np.array([np.argmin(at[::-1, j]) if not at[:, j].all() else k + 1 for j in range(N)])
            if np.any(run > 25):  # 25 ticks of 0.02 s = 0.5 s: the 26th faults
                fault = "torque_saturation"
                break
        records.append(meter.finish(name, fault))
    return summarise(records)


def test_mjx_accounting_equals_the_deploy_meter():
    eps = _episodes()
    mjx, dep = _mjx(eps), _deploy(eps)
    # Hand values: 2 of 3 complete; ticks 60 + 60 + 46 = 166; at a cap: 10 (buzz) + 26 (stuck, ticks
    # 20..45) = 36; near a limit: 5 (buzz).
    assert dep["completed"] == 2 and dep["ticks"] == 166
    assert mjx["quality/completion_pct"] == pytest.approx(100 * 2 / 3)
    assert mjx["quality/cap_share_pct"] == pytest.approx(100 * 36 / 166, rel=1e-6)
    assert mjx["quality/limit_share_pct"] == pytest.approx(100 * 5 / 166, rel=1e-6)
    for key in ("completion_pct", "cap_share_pct", "limit_share_pct"):
        assert mjx[f"quality/{key}"] == pytest.approx(dep[key], rel=1e-6), key
    # The action rate: float32 on device against float64; signals <= 0.32 rad, so 1e-6 relative.
    assert mjx["quality/action_rate"] == pytest.approx(dep["action_rate"], rel=1e-5)
    # Chatter on the completed episodes: the square wave's RMS, 20 mrad, on buzz (its 1.2 s window holds 15
    # whole periods; the 1 Hz sine's Hann leakage above 5 Hz, ~0.2 mrad, adds in quadrature: < 0.01 mrad).
    # float32 FFT of 0.3 rad signals against float64: ~1e-6 rad of rounding, 1e-3 mrad.
    assert dep["chatter_max_mrad"] == pytest.approx(20.0, abs=0.05)
    assert mjx["quality/chatter_max_mrad"] == pytest.approx(dep["chatter_max_mrad"], abs=1e-3)
    assert mjx["quality/chatter_mean_mrad"] == pytest.approx(dep["chatter_mean_mrad"], abs=1e-3)
    assert mjx["quality/chatter_unmeasured"] == 1 == dep["chatter_unmeasured"]
