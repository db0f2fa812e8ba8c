"""Robstride actuator models rs-00 .. rs-06: MIT wire ranges, limits and identified dynamics.

One table, one place. The MIT ranges are the official manuals' values (the ones Berkeley's
Actuator-Control library switched to in commit d74dd3f, which the Lite team uses); see
``../shared/reference/robstride-protocol.md`` section 4.1 for the conflict with the vendor ROS sample.
Every other module (the MIT quantiser, the CAN codec, the env's actuator model) reads this table.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = [
    "GAIN_DAMPING_RATIO",
    "GAIN_NATURAL_HZ",
    "ROBSTRIDE_MODELS",
    "RobstrideSpec",
    "armature_gains",
    "robstride_spec",
]

P_MAX = 4.0 * math.pi
"""MIT position range of every model, rad (the feedback wraps within +-4*pi)."""


@dataclass(frozen=True, kw_only=True)
class RobstrideSpec:
    """Per-model constants of a Robstride actuator.

    The ``*_max`` fields are the symmetric (position, velocity, torque) or one-sided (Kp, Kd) ranges that
    the 16-bit fields of an MIT (type 1) command and a type-2 feedback frame are scaled to.
    """

    model: str
    """Model key, ``rs-00`` .. ``rs-06``."""
    p_max: float
    """Position range +-p_max, rad."""
    v_max: float
    """Velocity range +-v_max, rad/s."""
    t_max: float
    """Torque range +-t_max, N*m (also the datasheet peak torque)."""
    kp_max: float
    """Kp range [0, kp_max], N*m/rad."""
    kd_max: float
    """Kd range [0, kd_max], N*m*s/rad."""
    velocity_limit: float
    """Joint velocity limit used for checks, rad/s (Robot-Descriptions actuator table)."""
    effort_limit: float
    """Continuous-peak effort limit, N*m (Robot-Descriptions actuator table)."""
    armature_nominal: float
    """Nominal reflected rotor inertia from the description tables, kg*m^2."""
    armature_identified: float | None
    """Armature identified on an unloaded shaft (T-K-233/Robstride-SysID), kg*m^2; None when not measured."""
    frictionloss_identified: float | None
    """Coulomb friction identified with the armature above, N*m; None when not measured."""

    def __post_init__(self) -> None:
        for name in ("p_max", "v_max", "t_max", "kp_max", "kd_max", "velocity_limit", "effort_limit"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"{self.model}: {name} must be a positive finite number, got {value!r}")


def _spec(
    model: str,
    v: float,
    t: float,
    kp: float,
    kd: float,
    vlim: float,
    elim: float,
    arm: float,
    arm_id: float | None,
    fc_id: float | None,
) -> RobstrideSpec:
    return RobstrideSpec(
        model=model,
        p_max=P_MAX,
        v_max=v,
        t_max=t,
        kp_max=kp,
        kd_max=kd,
        velocity_limit=vlim,
        effort_limit=elim,
        armature_nominal=arm,
        armature_identified=arm_id,
        frictionloss_identified=fc_id,
    )


# ---------------------------------------------------------------------------------------------------
# The table. MIT ranges: manuals (RS0xUM section 4.1.2 / 4.4). Limits and nominal armature:
# Robot-Descriptions actuators/robstride.py. Identified J and Fc: Robstride-SysID README (means of 3 runs).
# ---------------------------------------------------------------------------------------------------
ROBSTRIDE_MODELS: dict[str, RobstrideSpec] = {
    s.model: s
    for s in (
        #     model    V_max  T_max  Kp_max  Kd_max  vel_lim  eff_lim  J_nom   J_id     Fc_id
        _spec("rs-00", 33.0, 14.0, 500.0, 5.0, 32.987, 14.0, 0.001, 0.0149, 0.233),
        _spec("rs-01", 44.0, 17.0, 500.0, 5.0, 50.13, 17.0, 0.0042, None, None),
        _spec("rs-02", 44.0, 17.0, 500.0, 5.0, 65.25, 17.0, 0.0042, 0.01369, 0.159),
        _spec("rs-03", 20.0, 60.0, 5000.0, 100.0, 31.83, 60.0, 0.02, None, None),
        _spec("rs-04", 15.0, 120.0, 5000.0, 100.0, 31.83, 120.0, 0.04, None, None),
        _spec("rs-05", 50.0, 5.5, 500.0, 5.0, 76.39, 5.5, 0.001, 0.00678, 0.309),
        _spec("rs-06", 50.0, 36.0, 5000.0, 100.0, 76.39, 36.0, 0.015, 0.01647, 0.169),
    )
}


def robstride_spec(model: str) -> RobstrideSpec:
    """Return the spec of a Robstride model, or raise ``ValueError`` naming the valid models."""
    try:
        return ROBSTRIDE_MODELS[model]
    except KeyError:
        raise ValueError(
            f"unknown Robstride model {model!r}; valid models: {sorted(ROBSTRIDE_MODELS)}"
        ) from None


GAIN_NATURAL_HZ = 10.0
"""Natural frequency of the armature-derived PD gains, Hz (lite_description's ``func.py``, BeyondMimic)."""
GAIN_DAMPING_RATIO = 2.0
"""Damping ratio of the armature-derived PD gains (the same sources)."""


def armature_gains(
    armature: np.ndarray, natural_hz: float = GAIN_NATURAL_HZ, damping_ratio: float = GAIN_DAMPING_RATIO
) -> tuple[np.ndarray, np.ndarray]:
    """PD gains from the reflected rotor inertia J: ``Kp = J w^2``, ``Kd = 2 zeta J w``, ``w = 2 pi f``.

    The recipe of Berkeley-Humanoids/Lite-Description ``robot_assets/actuators/func.py`` (BeyondMimic's):
    the rotor alone would ring at ``f`` with damping ratio ``zeta``; with the link's inertia added the joint
    is softer. For the Lite's MJCF armature (0.005 kg*m^2 on rs-02, 0.002 elsewhere) that is Kp 19.74 / 7.90
    N*m/rad and Kd 1.257 / 0.503 N*m*s/rad (lite-model.md section 2.1).

    Args:
        armature: J per joint, kg*m^2, shape (n,).
        natural_hz: f, Hz.
        damping_ratio: zeta.

    Returns:
        ``(kp, kd)``, shape (n,) each, N*m/rad and N*m*s/rad.
    """
    w = 2.0 * math.pi * natural_hz
    j = np.asarray(armature, dtype=float)
    return j * w * w, 2.0 * damping_ratio * j * w
