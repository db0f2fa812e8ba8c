"""Hand-load compensation: what each hand carries, estimated online, and its gravity torque as ``tau_ff``.

A tool or a payload at the hand pulls the arm down by ``tau_load / Kp`` (0.5 kg at a fingertip: up to 0.05
rad at a shoulder), and how much changes with the pose, faster than an error average follows a moving
arm. The load is linear in four numbers: a rigid load of mass ``m`` with its centre ``c`` (m, in the hand's
frame) from the fingertip site is held by

    tau_load(q) = Phi(q) theta,   theta = (m, m c_x, m c_y, m c_z),
    Phi[:, 0] = g J_z(p_tip)^T,   Phi[:, i] = g (J_z(p_tip + arm_m R e_i) - J_z(p_tip))^T / arm_m

on the arm's joints (N*m; ``J_z``: the vertical row of a point's translational Jacobian on the hand
body, MuJoCo's ``mj_jac``; ``R`` the hand's orientation; the Jacobian is affine in the point, so this is
exact for any point mass on the hand). Each POLICY tick the motors' torque minus the model's gravity
torque at the measured state, ``tau - g(q)``, is the unmodelled torque: the load, plus the arm's inertia
and friction in motion, which average out. A least-squares fit of ``theta`` per hand with exponential
forgetting (time constant ``tau_s``; recursive: ``A <- lam A + Phi^T Phi``, ``b <- lam b + Phi^T r``,
``theta = (A + D)^-1 b``, ``D`` = diag(``ridge``, ``ridge_centre`` x3)) follows a load put on or taken off
within about ``tau_s``; the ridge pulls the centre toward the fingertip far harder than the mass toward
none, so a poorly excited centre (a still pose) reads as the fingertip, not as a wrong mass.
``Phi(q) theta`` is the next command's ``tau_ff``: the MIT law's feed-forward, which the firmware adds to
``Kp (q_cmd - q) + Kd (dq_cmd - dq)``. The policy's command is untouched: it sees the arm where the
nominal robot would be.

Why the motors' torque and not the law's ``Kp (q_cmd - q)`` from the command the runtime wrote: a command
acts one or two ticks late on the real bus, and a residual from the wrong command fed back into the
feed-forward diverged (2 ticks of action delay: -15 kg, every clip faulted); the torque the motor reports
is the one it applied. A weaker motor (it reports the torque it was asked, delivers less) and heavier links
read as load, and are compensated as such.

Bounds, never silent: a hand whose estimated mass ``m`` leaves ``+-max_kg`` is scaled back into it,
and a feed-forward beyond the firmware cap is clipped to it, each counted (``record``) and its first
occurrence logged.

The model and its gravity torque are ``deploy.gravity``'s (the robot alone). A tick whose measured state
or torque is not finite is not fitted (counted) and gets no feed-forward. Only a target that
measures the torque its motors apply (``Target.measures_torque``) can feed the fit; numpy and MuJoCo, no jax.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from typing import Any

import mujoco
import numpy as np

from bar_policy.deploy.gravity import CapClip, GravityTorque
from bar_policy.robot.constants import load_robot
from bar_policy.robot.index import RobotIndex

__all__ = ["HANDS", "HandLoadConfig", "HandLoadEstimator", "hand_arms"]

log = logging.getLogger(__name__)

GRAVITY = 9.81
"""m/s^2 (the model's ``opt.gravity``, checked at construction)."""

HANDS = (("left", "left_hand", "left_finger2_tip"), ("right", "right_hand", "right_finger2_tip"))
"""(joint-name prefix, hand body, fingertip site: the load's reference point) per arm."""


def hand_arms(joint_names: tuple[str, ...]) -> list[np.ndarray]:
    """Per hand of ``HANDS``, the indices of its arm's joints in ``joint_names`` (canonical order)."""
    return [np.array([i for i, j in enumerate(joint_names) if j.startswith(p + "_")]) for p, _, _ in HANDS]


@dataclass(frozen=True, kw_only=True)
class HandLoadConfig:
    """The fit's settings (module docstring)."""

    tau_s: float = 0.25
    """Forgetting time constant, s: the fit weighs a tick ``tau_s`` ago by 1/e (docs/robustness.md,
    "Hand-load compensation": 1 s and 2 s left the combined row over the gate)."""
    ridge: float = 1.0
    """Regularisation of the mass toward none, (N*m)^2 / kg^2: a tick's ``Phi^T Phi`` along the mass is ~35
    at the ready pose, its sum over the piano's 12-tick tare ~270, so the estimate keeps 99.6 % of the
    load; the first tick's (a reset's torque transient) may swing, within ``max_kg`` (counted)."""
    ridge_centre: float = 1000.0
    """Regularisation of ``m c`` toward 0 (the load at the fingertip), (N*m)^2 / (kg*m)^2. At one still pose
    the centre's columns (norms 3-17 N*m per kg*m) are mostly stronger than the mass's (6 N*m per kg) and
    nearly collinear with it (singular values 18, 14, 1.5, 0): one ridge of 10 on all four moved a third
    of a 0.5 kg fingertip load into a 0.16 m centre offset, the same torque at that pose, 0.33 kg to the
    inertia feed-forward (docs/robustness.md, "The tare's ridge"). A moving arm excites the centre (its
    columns' sums at ``tau_s`` reach ~3600 per parameter), and the data outweigh the ridge."""
    arm_m: float = 0.1
    """Step of the centre's finite difference along each hand axis, m (exact for any step: the Jacobian
    is affine in the point)."""
    max_kg: float = 1.5
    """Bound on each hand's estimated mass, kg."""

    def __post_init__(self) -> None:
        for name in ("tau_s", "ridge", "ridge_centre", "arm_m", "max_kg"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise ValueError(f"HandLoadConfig.{name} must be a finite number > 0, got {v}")


class HandLoadEstimator:
    """The per-hand load fit and its feed-forward (module docstring), one ``step`` per POLICY tick."""

    def __init__(self, mode: str, control_dt: float, config: HandLoadConfig | None = None) -> None:
        self.config = config or HandLoadConfig()
        robot = load_robot(mode)
        self._gravity = GravityTorque(mode)  # g(q), and the model state the Jacobians are read from
        self.model, self.data = self._gravity.model, self._gravity.data
        if not np.allclose(self.model.opt.gravity, (0.0, 0.0, -GRAVITY)):
            raise ValueError(f"the model's gravity {self.model.opt.gravity} is not (0, 0, -{GRAVITY})")
        self._dadr = RobotIndex.from_model(self.model, robot.joint_names).dof
        self.n = len(robot.joint_names)
        self.arms = hand_arms(robot.joint_names)
        self.bodies = [self.model.body(body).id for _, body, _ in HANDS]
        self.sites = [self.model.site(site).id for _, _, site in HANDS]
        self.forget = math.exp(-control_dt / self.config.tau_s)
        self._ridge = np.diag([self.config.ridge] + [self.config.ridge_centre] * 3)
        self._jac = np.zeros((3, self.model.nv))
        self.theta = np.zeros((2, 4))
        """Per hand ``(m, m c_x, m c_y, m c_z)``: kg, and kg*m of the centre from the fingertip site."""
        self._a = np.zeros((2, 4, 4))
        self._b = np.zeros((2, 4))
        self.updates = 0
        """Fits so far (POLICY ticks with a measured torque)."""
        self.mass_sum = np.zeros(2)
        """Sum of ``masses`` over the fits, kg (``mean_masses``)."""
        self.nonfinite_count = 0
        """Ticks not fitted because the measured state or torque was not finite."""
        self.motion_rad = 0.0
        """Largest joint excursion from the first fitted tick's pose over the fits, rad: where the arm
        moved into a pose and stuck, its friction is in the residual and reads as load (a still start's
        ``tare``; docs/robustness.md)."""
        self._q_first: np.ndarray | None = None
        self.mass_bound_count = 0
        """Fits whose estimated mass of a hand left ``+-max_kg`` and was scaled back."""
        self.clip = CapClip("hand-load feed-forward", robot.joint_names, robot.torque_cap)
        """The caps' clip of the feed-forward: ``clip_count``, ``max_abs`` (N*m per joint)."""
        self._logged: set[str] = set()

    @property
    def masses(self) -> np.ndarray:
        """Estimated mass per hand (left, right), kg."""
        return self.theta[:, 0].copy()

    @property
    def mean_masses(self) -> np.ndarray:
        """``masses`` averaged over the fits so far, kg, (2,) (0 before the first)."""
        return self.mass_sum / max(self.updates, 1)

    def regressors(self, q: np.ndarray) -> tuple[np.ndarray, list[np.ndarray]]:
        """``(g(q), [Phi_left, Phi_right])`` at ``q`` (rad, (n,)).

        ``g``: the model's gravity torque, N*m, (n,); ``Phi``: per hand the regressors of ``theta`` (module
        docstring), on that arm's joints, (7, 4).
        """
        m, d = self.model, self.data
        gravity = self._gravity.raw(q)  # leaves d at q, zero velocity
        phis = []
        step = self.config.arm_m
        for arm, body, site in zip(self.arms, self.bodies, self.sites, strict=True):
            tip, rot = d.site_xpos[site].copy(), d.xmat[body].reshape(3, 3)
            rows = []
            for k in range(4):
                point = tip if k == 0 else tip + step * rot[:, k - 1]
                mujoco.mj_jac(m, d, self._jac, None, point, body)
                rows.append(GRAVITY * self._jac[2, self._dadr[arm]])
            cols = [rows[0]] + [(r - rows[0]) / step for r in rows[1:]]
            phis.append(np.stack(cols, axis=1))
        return gravity, phis

    def step(self, q: np.ndarray, tau: np.ndarray) -> np.ndarray:
        """One fit, then the feed-forward at ``q``: ``Phi(q) w``, N*m, (n,), within the caps (counted).

        ``q``: the measured positions, rad; ``tau``: the torque the motors applied, N*m; both (n,).
        """
        q, tau = np.asarray(q, np.float64), np.asarray(tau, np.float64)
        if not (np.all(np.isfinite(q)) and np.all(np.isfinite(tau))):
            self.nonfinite_count += 1
            self._log_once(
                "nonfinite", "hand load: a non-finite state or torque, not fitted (further counted)"
            )
            return np.zeros(self.n)
        if self._q_first is None:
            self._q_first = q.copy()
        self.motion_rad = max(self.motion_rad, float(np.max(np.abs(q - self._q_first))))
        gravity, phis = self.regressors(q)
        residual = tau - gravity
        c = self.config
        for h, (arm, phi) in enumerate(zip(self.arms, phis, strict=True)):
            self._a[h] = self.forget * self._a[h] + phi.T @ phi
            self._b[h] = self.forget * self._b[h] + phi.T @ residual[arm]
            w = np.linalg.solve(self._a[h] + self._ridge, self._b[h])
            mass = float(w[0])
            if abs(mass) > c.max_kg:
                w = w * (c.max_kg / abs(mass))
                self.mass_bound_count += 1
                self._log_once(
                    f"mass{h}",
                    f"hand load estimate of the {HANDS[h][0]} hand {mass:.2f} kg beyond +-{c.max_kg} kg: "
                    "scaled back to it (further ones counted)",
                )
            self.theta[h] = w
        self.updates += 1
        self.mass_sum += self.masses
        return self._feedforward(phis)

    def torque(self, q: np.ndarray) -> np.ndarray:
        """The current estimate's feed-forward at ``q`` (rad, (n,)), no fit: N*m, (n,); 0 at non-finite q."""
        q = np.asarray(q, np.float64)
        if not np.all(np.isfinite(q)):
            return np.zeros(self.n)
        return self._feedforward(self.regressors(q)[1])

    def _feedforward(self, phis: list[np.ndarray]) -> np.ndarray:
        out = np.zeros(self.n)
        for arm, phi, w in zip(self.arms, phis, self.theta, strict=True):
            out[arm] = phi @ w
        return self.clip(out)

    def _log_once(self, key: str, message: str) -> None:
        if key not in self._logged:
            self._logged.add(key)
            log.warning(message)

    def record(self) -> dict[str, Any]:
        """For the run log: the settings, the last estimate, the fits and every bound's count."""
        c = self.config
        return {
            "tau_s": c.tau_s,
            "ridge": c.ridge,
            "ridge_centre": c.ridge_centre,
            "arm_m": c.arm_m,
            "max_kg": c.max_kg,
            "fits": self.updates,
            "mass_kg": {HANDS[h][0]: float(m) for h, m in enumerate(self.masses)},
            "mean_mass_kg": {HANDS[h][0]: float(m) for h, m in enumerate(self.mean_masses)},
            "motion_rad": self.motion_rad,
            "mass_bound_count": self.mass_bound_count,
            "nonfinite_count": self.nonfinite_count,
            "clipped_joint_evaluations": self.clip.clip_count,
            "max_abs_feedforward_nm": [float(v) for v in self.clip.max_abs],
        }
