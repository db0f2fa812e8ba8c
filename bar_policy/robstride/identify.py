"""``bar-bus identify``'s fit: the excitation's ``Recording`` to per-arm estimates for the params file.

The excitation over the bus (``robstride.excitation_run``) records one row per MIT round; here:

1. ``round_samples``: one sample per round, the law read as the firmware sees the wire.
2. ``fit_recording`` (``robot.sysid_fit``), per arm: the poses' part (strength, friction, damping,
   payload), then the fast single-joint segments (armature; the wrists' friction and damping); intervals
   the larger of the residual's Newey-West one and a delete-one-pose jackknife's (``widen_by_jackknife``).
   With a known payload (``known_payload``) the payload is part of the model and every strength is
   fitted, the wrists' on their single-joint segments and the lever phase's yaw sweep.
3. ``RobotParams`` with the values, their 95 % intervals and the run (``source``): ``robot.sysid_file``.

No jax, no torch.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field, replace

import mujoco
import numpy as np

from bar_policy.robot.constants import RobotSpec
from bar_policy.robot.mit import U16_MAX, MitCommand, firmware_torque, wire_ranges
from bar_policy.robot.params import Payload, RobotParams, apply_to_spec, scene_edit
from bar_policy.robot.scene import load_model, robot_spec
from bar_policy.robot.sysid_excitation import RAMP_S
from bar_policy.robot.sysid_fast import FastFit, fit_fast
from bar_policy.robot.sysid_fit import (
    HAC_LAG_S,
    Z95,
    ArmFit,
    ArmSamples,
    PayloadRegressor,
    fit_arm,
)
from bar_policy.robstride.excitation_run import Recording

__all__ = ["fit_recording", "round_samples"]

log = logging.getLogger(__name__)

HANDS = {"left": "left_hand", "right": "right_hand"}
PAYLOAD_JOINTS = 4
"""The first joints of each arm (shoulder pitch, roll, yaw, elbow) whose rows fit the payload."""


def merge_fits(a: ArmFit, b: ArmFit) -> ArmFit:
    """One arm's fit of two joint sets: ``a``'s joints then ``b``'s; the payload is ``a``'s."""
    cat = np.concatenate
    return ArmFit(
        joints=a.joints + b.joints,
        strength=cat([a.strength, b.strength]),
        friction=cat([a.friction, b.friction]),
        damping=cat([a.damping, b.damping]),
        armature=cat([a.armature, b.armature]),
        half95={k: cat([a.half95[k], b.half95[k]]) for k in a.half95},
        mass=a.mass,
        mass_half95=a.mass_half95,
        com=a.com,
        com_half95=a.com_half95,
        rows=a.rows + b.rows,
        rms=float(np.sqrt((a.rms**2 * a.rows + b.rms**2 * b.rows) / (a.rows + b.rows))),
    )


def round_samples(robot: RobotSpec, rec: Recording, period: float) -> ArmSamples:
    """One sample per round, at its middle: the round's mean state, the law's torque there, its acceleration.

    The mean of the states of replies ``k-1`` and ``k``, the torque command ``k`` asks for at that state,
    and the acceleration ``(dq_k - dq_{k-1}) / dt``.

    The torque is the MIT law's, ``Kp (q* - q) + Kd (dq* - dq) + ff``, not the reading of one instant, and at
    the round's mean state because the acceleration is the round's mean: a firmware that runs the law far
    faster than the bus applies, over the round, the law's mean, which is the law at the mean state to
    O(dt^2). The law at the start state instead reads the damping force's change over the round,
    ``Kd dt qdd / 2``, as armature: +0.002 kg*m^2 at Kd 2 and 2 ms rounds (the emulator run 0.25 ms at a
    time, the law every step: +0.002 on every joint, 40-100 % of the truth; docs/sysid.md). The
    emulator's default damping, ``trapezoid`` (``robstride.emulator_physics``), is this mean to second
    order; its ``explicit`` update holds the start's torque for the step, which this pairing reads as
    -0.002. A joint whose loop rings faster than a slower round (a wrist at Kp 50 on a few g*m^2 rings at
    ~20 Hz) would bias a fit of instantaneous readings. Strength is then the torque produced per torque
    the law asked for (the budget keeps the law off its cap: no saturation).

    The law is ``robot.mit.firmware_torque``, the firmware's own (the emulator's), on the wire: every
    command field as decoded after the official 16-bit truncation, in the motor frame ``raw = direction *
    joint + offset``, and the state at the middle of the feedback's least significant bit (the firmware
    truncates it too, so the true value lies in ``[reported, reported + LSB)``); the cap is the robot's
    (the budget keeps the law under half of it). Truncation is a bias, not noise: the host's own command and
    the raw reading put a constant ~``Kp * LSB`` (0.02 N*m at Kp 50) into every sample, which a fit without
    an intercept takes up in the strengths (measured: 0.976..1.024 for 1) and, through them, in the
    armatures (-87..+37 %); evaluated so, strengths 1.0000 and armatures within a few % on the emulator.
    """
    _, q, dq, _ = rec.arrays()
    q_cmd, dq_cmd, ff = np.array(rec.q_cmd), np.array(rec.dq_cmd), np.array(rec.ff)
    rg = wire_ranges(robot.models)
    d = np.asarray(robot.direction if rec.direction is None else rec.direction, dtype=np.float64)
    off = np.zeros(robot.num_joints) if rec.homing_offset is None else np.asarray(rec.homing_offset)
    q_mid = q + d * rg.p_max / U16_MAX  # half of the LSB 2 * p_max / 65535, in the motor frame
    dq_mid = dq + d * rg.v_max / U16_MAX
    # the firmware's own law (the emulator's and the sim target's) on the motor-frame command and state
    raw = MitCommand(d * q_cmd + off, d * dq_cmd, np.asarray(robot.kp), np.asarray(robot.kd), d * ff)
    # the round's mean state (the acceleration is the round's mean): the law's mean over it to O(dt^2)
    q_round, dq_round = (q_mid[:-1] + q_mid[1:]) / 2, (dq_mid[:-1] + dq_mid[1:]) / 2
    tau = d * firmware_torque(raw, d * q_round + off, d * dq_round, rg, robot.torque_cap)
    qdd = (dq[1:] - dq[:-1]) / period
    return ArmSamples(q_round, dq_round, qdd, tau)


@dataclass(frozen=True)
class _ArmContext:
    """What ``fit_recording``'s stages of one arm share: the samples, their ``ID`` and friction force."""

    robot: RobotSpec
    arm: str
    idx: list[int]
    reg: PayloadRegressor
    samples: ArmSamples
    """The poses' part, rows 0..n_slow of ``everything``."""
    everything: ArmSamples
    id_all: np.ndarray
    u_all: np.ndarray
    segs: list[tuple[slice, int]]
    known: np.ndarray | None
    payload: bool
    smooth: int
    lag: int
    armature: np.ndarray | None = None
    """Held armatures of the arm's joints (``idx`` order; an unloaded run's), or None: fitted."""
    wrist_strength: bool = False
    """Fit the wrists' strength (a known payload in the hand, in ``reg``'s model); False: held."""
    lever: list[tuple[slice, int]] = field(default_factory=list)
    """The lever segments (rows of ``everything``, joint): with the fast ones, the wrists' strength."""

    def stages(self, rows: np.ndarray | None) -> ArmFit:
        """Stages 1-3 on the poses' ``rows`` of ``samples`` (None: all of them)."""
        robot, idx, reg, known, payload = self.robot, self.idx, self.reg, self.known, self.payload
        sel = slice(0, len(self.samples.q)) if rows is None else rows
        smp = ArmSamples(
            *(x[sel] for x in (self.samples.q, self.samples.dq, self.samples.qdd, self.samples.tau))
        )
        id_base = self.id_all[sel]
        common = dict(
            id_base=id_base,
            smooth=self.smooth,
            friction_u=self.u_all[sel],
            v_min=0.0,
            iterations=6,
            hac_lag=self.lag,
        )
        # stage 1: shoulders and elbow, with the payload; stage 2: the wrists, with that payload's force
        # known (a wrist's few g*m^2 and its soft friction make its rows noisy: they would pull the mass)
        big, wrists = idx[:PAYLOAD_JOINTS], idx[PAYLOAD_JOINTS:]
        k_big = None if known is None else known[:PAYLOAD_JOINTS]
        # a wrist's strength is not resolvable from its own weight (its gravity torque is ~0.1 N*m, and its
        # inertia torque trades with its armature): held at the given value, else the model's 1 (fitted:
        # 0.08-0.81 for 0.9); with a known payload (``wrist_strength``), stage 3 fits it (below)
        k_wr = np.ones(len(wrists)) if known is None else known[PAYLOAD_JOINTS:]
        f1 = fit_arm(smp, big, robot.joint_names, reg if payload else None, strength=k_big, **common)
        base2 = id_base
        if payload:
            base2 = id_base + f1.mass * reg.columns(smp, id_base, f1.com)[:, :, 0]
        f2 = fit_arm(smp, wrists, robot.joint_names, None, strength=k_wr, **{**common, "id_base": base2})
        fit = merge_fits(f1, f2)
        if not self.segs:
            return fit
        # stage 3: each joint alone and fast: armature (all), friction and damping (wrists); with a known
        # payload also the wrists' strength, on their fast segments and the yaw's lever segment, where the
        # payload's gravity (0.4-1 N*m, known) is what the strength scales
        order = list(dict.fromkeys(j for _, j in self.segs))
        col = None
        if payload:  # the unit payload's column on the fast rows only (the others are never read)
            rows = np.concatenate([np.arange(r.start, r.stop) for r, _ in self.segs])
            e = self.everything
            fast = ArmSamples(e.q[rows], e.dq[rows], e.qdd[rows], e.tau[rows])
            col = np.zeros_like(self.id_all)
            col[rows] = reg.columns(fast, self.id_all[rows], fit.com)[:, :, 0]
        held_s = np.array([fit.strength[idx.index(j)] for j in order])
        if self.wrist_strength:  # fitted there (NaN), with each wrist's friction, damping and armature
            held_s[[c for c, j in enumerate(order) if idx.index(j) >= PAYLOAD_JOINTS]] = np.nan
        f3 = fit_fast(
            self.everything,
            self.segs + self.lever,
            robot.joint_names,
            self.id_all,
            self.u_all,
            held_s,
            payload_col=col,
            mass=fit.mass,
            fit_mass=payload,
            armature=None if self.armature is None else self.armature[[idx.index(j) for j in order]],
            smooth=self.smooth,
            hac_lag=self.lag,
        )
        log.info(
            "%s arm, fast segments: payload %.3f +- %.3f kg (slow: %.3f), residual %s N*m",
            self.arm,
            f3.mass,
            f3.mass_half95,
            fit.mass,
            np.round(f3.rms, 3),
        )
        return with_fast(fit, f3)


def fit_recording(
    robot: RobotSpec,
    rec: Recording,
    arms: tuple[str, ...],
    period: float,
    *,
    trim: int = 5,
    smooth_s: float = 0.02,
    strength: dict[str, np.ndarray] | None = None,
    armature: dict[str, np.ndarray] | None = None,
    payload: bool = True,
    known_payload: dict[str, Payload] | None = None,
    jackknife: bool = True,
) -> dict[str, ArmFit]:
    """Fit each arm of ``arms`` to ``rec``.

    ``trim`` rounds are dropped at both ends; ``smooth_s``: the moving average of ``fit_arm``, s (the wire's
    16-bit quantization of q and dq averaged down).

    Strength and payload: both scale the torque a pose needs, and for a slow excitation the payload's
    gravity has nearly the shape of the arm's own on every joint (the payload sits on the line of the
    forearm's and hand's centres), so one run cannot tell a weak motor from a loaded hand. They are
    separated by two runs: an unloaded one (``payload=False``: the mass is known to be 0) fits the
    strengths; a loaded one with those strengths known (``strength``: arm -> per-joint values) fits the
    payload. With neither, the strengths are held at the model's 1. ``armature`` (arm -> per-joint values,
    an unloaded run's) is held in the fast stage the same way: with a payload in the hand its inertia
    about a joint is 4-12x the joint's armature, and a few % of payload error would go into it whole.

    ``known_payload`` (arm -> ``Payload``: a calibration mass of known mass and centre in the hand frame):
    the payload is part of the model (its gravity and inertia in ``ID``, its inertia in the soft friction's
    impedance) and held; every joint's strength is fitted, the wrists' included (the payload's gravity is a
    known torque of its own pose dependence, ~1 N*m on the wrist roll and pitch: what the strength scales),
    and with it their friction and armature. Not with ``strength``, ``armature`` or ``payload=False``.
    """
    if known_payload is not None and (strength is not None or armature is not None or not payload):
        raise ValueError("a known payload fits every strength and armature: not with held ones or unloaded")
    if known_payload is not None and set(arms) - set(known_payload):
        raise ValueError(f"known payload of {sorted(known_payload)}: give every arm of {list(arms)}")
    full = round_samples(robot, rec, period)
    sl = slice(trim, len(full.q) - trim)
    everything = ArmSamples(full.q[sl], full.dq[sl], full.qdd[sl], full.tau[sl])
    # the poses' part (stages 1, 2) and the fast single-joint segments (stage 3), in rows of `everything`
    fast = [
        (slice(round(t0 / period) - trim, round(t1 / period) - trim), j) for t0, t1, j in rec.fast_segments
    ]
    n_slow = fast[0][0].start - round(RAMP_S / period) if fast else len(everything.q)
    samples = ArmSamples(*(x[:n_slow] for x in (everything.q, everything.dq, everything.qdd, everything.tau)))
    held = RobotParams({}, dict(known_payload or {}))

    def spec_factory() -> mujoco.MjSpec:
        spec = robot_spec(robot.mode)
        apply_to_spec(spec, held)
        return spec

    model = load_model(robot.mode, scene_edit(held) if known_payload else None)
    fits: dict[str, ArmFit] = {}
    id_all: np.ndarray | None = None
    u_all: np.ndarray | None = None
    smooth = max(1, round(smooth_s / period))
    lag = max(1, round(HAC_LAG_S / period))
    poses = [
        np.arange(max(round(t0 / period) - trim, 0), min(round(t1 / period) - trim, n_slow))
        for t0, t1 in rec.pose_segments
    ]
    for arm in arms:
        idx = [j.index for j in robot.joints if j.group == f"{arm}_arm"]
        reg = PayloadRegressor(model, spec_factory, robot.joint_names, HANDS[arm])
        if id_all is None:
            id_all = reg.inverse(everything)
            u_all = reg.friction_force(everything)
        load = (known_payload or {}).get(arm)
        fit_payload = payload and known_payload is None
        known = None if not fit_payload else (strength or {}).get(arm, np.ones(len(idx)))
        segs = [(r, j) for r, j in fast if j in idx]
        lever = [
            (slice(round(t0 / period) - trim, round(t1 / period) - trim), j)
            for t0, t1, j in rec.lever_segments
            if j in idx
        ]
        arm_held = None if armature is None else armature.get(arm)
        ctx = _ArmContext(
            robot,
            arm,
            idx,
            reg,
            samples,
            everything,
            id_all,
            u_all,
            segs,
            known,
            fit_payload,
            smooth,
            lag,
            arm_held,
            wrist_strength=load is not None and load.mass_kg.value > 0,
            lever=lever,
        )
        fit = ctx.stages(None)
        if jackknife and len(poses) >= 3:  # each pose left out in turn: the spread between poses
            keep = [np.concatenate([p for i, p in enumerate(poses) if i != k]) for k in range(len(poses))]
            reps = [ctx.stages(rows) for rows in keep]
            fit = widen_by_jackknife(fit, reps)
        if load is not None:  # held, not fitted: no interval
            fit = replace(fit, mass=load.mass_kg.value, com=np.array(load.com_m), com_half95=np.zeros(3))
        fits[arm] = fit
    return fits


T95 = {2: 4.303, 3: 3.182, 4: 2.776, 5: 2.571}
"""Two-sided 95 % Student t quantiles by degrees of freedom (the jackknife's: replicates - 1)."""


def widen_by_jackknife(fit: ArmFit, reps: list[ArmFit]) -> ArmFit:
    """``fit`` with each half-width at least the delete-one-pose jackknife's.

    ``reps``: the fit with each pose left out in turn (``g`` of them). The jackknife's standard error is
    ``sqrt((g-1)/g sum (x_i - mean)^2)``, times the t quantile at ``g-1`` degrees of freedom. It holds
    what the residual's covariance cannot: a model error that differs from pose to pose (the soft
    friction, the payload's and strength's trade-off) shows as a spread of the replicates, where the
    residual only shows noise. An error common to every pose is in neither.
    """
    g = len(reps)
    t = T95.get(g - 1, Z95)

    def jk(values: list[np.ndarray]) -> np.ndarray:
        v = np.array(values, dtype=np.float64)
        return t * np.sqrt((g - 1) / g * ((v - v.mean(axis=0)) ** 2).sum(axis=0))

    half = {
        k: np.maximum(fit.half95[k], jk([getattr(r, k) for r in reps]) * (fit.half95[k] > 0))
        for k in fit.half95
    }
    return replace(
        fit,
        half95=half,
        mass_half95=max(fit.mass_half95, float(jk([r.mass for r in reps])) if fit.mass_half95 > 0 else 0.0),
        com_half95=np.maximum(fit.com_half95, jk([r.com for r in reps])),
    )


def with_fast(fit: ArmFit, fast: FastFit) -> ArmFit:
    """``fit`` with the fast segments' values where the slow excitation cannot resolve them.

    The armature of every joint they cover; the friction and damping of the wrists (``PAYLOAD_JOINTS``
    onward: a wrist slides through MuJoCo's soft friction loss only above ~2 rad/s).
    """
    est = {k: getattr(fit, k).copy() for k in ("strength", "friction", "damping", "armature")}
    half = {k: v.copy() for k, v in fit.half95.items()}
    for c, name in enumerate(fit.joints):
        if name not in fast.joints:
            continue
        i = fast.joints.index(name)
        keys = ("armature",) if c < PAYLOAD_JOINTS else ("armature", "friction", "damping")
        if fast.half95["strength"][i] > 0:  # fitted there (a wrist with a known payload)
            keys = (*keys, "strength")
        for k in keys:
            est[k][c] = getattr(fast, k)[i]
            half[k][c] = fast.half95[k][i]
    return replace(
        fit,
        strength=est["strength"],
        friction=est["friction"],
        damping=est["damping"],
        armature=est["armature"],
        half95=half,
    )
