"""The robot-parameters file of an identification: ``bar-bus identify``'s fits written as ``RobotParams``.

``to_params``: each arm's fit (``robot.sysid_fit.ArmFit``) as the file's joints and payloads, with their 95 %
intervals and the run (``source``); an estimate the file cannot hold is written at its range's end and
listed. ``held_from``: a loaded run's file with the strength and armature its fit held, as the unloaded
run's file has them.
"""

from __future__ import annotations

import logging
from dataclasses import replace

import numpy as np

from bar_policy.robot.params import JOINT_KEYS, MASS_RANGE, Estimate, JointParams, Payload, RobotParams
from bar_policy.robot.sysid_fit import ArmFit

__all__ = ["held_from", "to_params"]

log = logging.getLogger(__name__)


def held_from(params: RobotParams, prior: RobotParams, path: object) -> RobotParams:
    """``params`` with each joint's strength and armature those of ``prior`` (an unloaded run's file).

    The loaded run held them in its fit (``fit_recording``'s ``strength`` and ``armature``); the file
    writes them as the unloaded run measured them, intervals included, and says so in ``source.notes``.
    """
    joints = {
        name: replace(jp, strength=prior.joints[name].strength, armature=prior.joints[name].armature)
        if name in prior.joints
        else jp
        for name, jp in params.joints.items()
    }
    src = dict(params.source)
    note = f"strength and armature held from {path} (sha256 {prior.sha256[:16]})"
    src["notes"] = f"{note}; {src['notes']}" if src.get("notes") else note
    return RobotParams(joints, dict(params.payload), src)


def _est(v: float, h: float) -> Estimate:
    return Estimate(float(v), (float(v - h), float(v + h)))


def to_params(fits: dict[str, ArmFit], source: dict[str, object]) -> RobotParams:
    """The params file of the fits.

    An estimate out of the file's range (a negative friction, damping, armature or mass; a strength
    outside 0.3..1.5; one above the range) is written at the range's end and listed in ``source.notes``
    and the log, with the value found (a value the file cannot hold; its interval, widened to hold what
    is written, says how sure the fit was). A payload held in the fit (half-width 0: a known one) is
    written as given, without an interval.
    """
    joints: dict[str, JointParams] = {}
    floored: list[str] = []

    def nonneg(name: str, v: float, h: float) -> Estimate:
        key = name.rsplit(".", 1)[-1]
        lo, hi = JOINT_KEYS.get(key, (*MASS_RANGE, ""))[:2]
        if not lo <= v <= hi:
            w = min(max(v, lo), hi)
            floored.append(f"{name}={v:.4g} (written as {w:g})")
            return Estimate(float(w), (min(w, float(v - h)), max(w, float(v + h))))
        return _est(v, h)

    for fit in fits.values():
        for c, name in enumerate(fit.joints):
            joints[name] = JointParams(
                friction_nm=nonneg(f"{name}.friction_nm", fit.friction[c], fit.half95["friction"][c]),
                damping=nonneg(f"{name}.damping", fit.damping[c], fit.half95["damping"][c]),
                armature=nonneg(f"{name}.armature", fit.armature[c], fit.half95["armature"][c]),
                strength=nonneg(f"{name}.strength", fit.strength[c], fit.half95["strength"][c])
                if fit.half95["strength"][c] > 1e-9
                else Estimate(float(fit.strength[c])),  # held, not fitted: no interval
            )
    payload: dict[str, Payload] = {}
    for arm, fit in fits.items():
        if fit.mass == 0.0 and fit.mass_half95 == 0.0:  # an unloaded run: no payload term was fitted
            continue
        if fit.mass_half95 == 0.0:  # held (a known payload): as given, no interval
            com = tuple(float(x) for x in fit.com)
            payload[arm] = Payload(Estimate(float(fit.mass)), com, None)  # type: ignore[arg-type]
            continue
        mass = nonneg(f"payload.{arm}.mass_kg", fit.mass, fit.mass_half95)
        com = tuple(float(x) for x in np.clip(fit.com, -0.5, 0.5))
        if mass.value == 0.0 or not np.allclose(com, fit.com):
            floored.append(f"payload.{arm}.com_m={np.round(fit.com, 3).tolist()} (written as [0, 0, 0])")
            com = (0.0, 0.0, 0.0)
            cis = None
        else:
            cis = tuple((c - h, c + h) for c, h in zip(com, fit.com_half95, strict=True))
        payload[arm] = Payload(mass, com, cis)  # type: ignore[arg-type]
    src = dict(source)
    if floored:
        log.warning(
            "identify: %d estimates out of range, written at its end: %s", len(floored), ", ".join(floored)
        )
        note = f"{len(floored)} estimates out of the file's range: " + ", ".join(floored)
        src["notes"] = f"{src['notes']}; {note}" if src.get("notes") else note
    return RobotParams(joints, payload, src)
