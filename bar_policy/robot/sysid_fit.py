"""Least-squares fit of an arm's friction, damping, armature, strength and hand payload against the model.

The equation, per arm joint ``j`` and sample ``k`` (joint frame, N*m), with ``tau`` the motor's torque
reading (the firmware's own estimate, what it was told to produce) and ``ID`` the model's rigid-body inverse
dynamics of the measured ``q, dq, qdd`` (``M_links(q) qdd + bias(q, dq)``: the links only, no armature,
no passive forces, no payload)::

    s_j tau_jk - f_j sign(dq_jk) - b_j dq_jk - a_j qdd_jk - Y_jk(c) theta = ID_jk

Unknowns: per joint the strength ``s_j`` (torque produced per torque read), the total Coulomb friction
``f_j``, the total damping ``b_j``, the total armature ``a_j``; per hand ``theta = (m, m dc)``, the payload's
mass and the shift of its centre from the current estimate ``c``. ``Y(c)``: the generalized force a unit
point mass at ``c`` (hand frame) needs (gravity and its own acceleration, ``mj_inverse`` of the model with
a unit payload minus without) and, for ``m dc``, the gravity force's sensitivity to the centre
(``Jr^T [g]x R``). The fit iterates ``c <- c + dc`` (three passes): linear in every unknown at a fixed
``c``, exact at the fixed point.

Why strength and payload separate: both scale how much torque a pose needs, but strength scales the
*whole* measured torque of one joint (the links' gravity and inertia, known from the model, included)
while the payload adds a term with its own pose dependence (its lever arm differs from the links'), shared
by all the joints of the arm. Excitation at several held poses of the whole arm (gravity acting in
different directions on each joint) makes the columns ``tau_j`` and ``Y_j`` independent; a single pose
would not. Friction separates by the sign of the velocity, damping by its size, armature by the
acceleration (the chirps).

Rows where ``|dq_j| < v_min`` are left out for that joint (static friction there is not ``f sign(dq)``).
Armature is a few % of a shoulder's link inertia: ``sysid_fast.fit_fast`` fits it per joint from segments
where that joint alone moves fast (inertia-dominated), its own equation only, the links' inertia from
``mj_inverse`` held.

Confidence intervals: with ``hac_lag``, ``hac_cov``'s Newey-West covariance (the residuals of neighbouring
samples are correlated); without, the ordinary least-squares ``1.96 sigma sqrt(diag((A^T A)^-1))``
(independent residuals assumed: several times too narrow on 2 ms samples).

No jax, no torch.
"""

from __future__ import annotations

import copy
import logging
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import mujoco
import numpy as np

from bar_policy.robot.index import RobotIndex

__all__ = [
    "ArmFit",
    "ArmSamples",
    "PayloadRegressor",
    "fit_arm",
    "hac_cov",
    "min_window",
    "moving_average",
    "rigid_model",
    "unit_payload_model",
]

log = logging.getLogger(__name__)

PAYLOAD_RADIUS = 0.01
"""The unit payload's inertia is a 1 cm sphere's, as the perturbed model's and the params file's."""
COM_SEARCH_M = 0.5
"""The centre iteration stays within this of the hand's origin, m (a hand is ~0.2 m long)."""
Z95 = 1.959963984540054
"""Two-sided 95 % normal quantile."""
HAC_LAG_S = 0.25
"""Newey-West bandwidth of the intervals, s: residuals of neighbouring samples are correlated over the
moving average's window and the loop's response (tens of ms); a quarter second holds both with room."""


def hac_cov(a: np.ndarray, resid: np.ndarray, blocks: np.ndarray, lag: int) -> np.ndarray:
    """Heteroscedasticity- and autocorrelation-consistent covariance of a least-squares solution.

    ``a``: the design, shape (n, p); ``resid``: the residual ``b - a x``, shape (n,); ``blocks``: an id per
    row, shape (n,): rows of one block are consecutive in time (one joint's samples, one segment), rows of
    different blocks are taken as independent; ``lag``: the Newey-West bandwidth, rows. Returns the
    (p, p) covariance ``(A^T A)^-1 S (A^T A)^-1`` with ``S = sum_blocks sum_|l|<=lag (1 - |l|/(lag+1))
    sum_k g_k g_{k-l}^T``, ``g_k = a_k r_k`` (Bartlett weights: ``S`` stays positive semi-definite),
    times ``n / (n - p)``. For independent residuals of equal spread it tends to the ordinary
    ``sigma^2 (A^T A)^-1``; for residuals correlated over ``m`` rows it is ~``m`` times larger, where the
    ordinary one would claim ``m`` times more independent information than the data hold.
    """
    n, p = a.shape
    g = a * resid[:, None]
    s = np.zeros((p, p))
    for blk in np.unique(blocks):
        gb = g[blocks == blk]
        s += gb.T @ gb
        for lag_k in range(1, min(lag, len(gb) - 1) + 1):
            gam = gb[lag_k:].T @ gb[:-lag_k]
            s += (1.0 - lag_k / (lag + 1)) * (gam + gam.T)
    inv = np.linalg.pinv(a.T @ a)
    return inv @ s @ inv * (n / max(n - p, 1))


@dataclass(frozen=True)
class ArmSamples:
    """Measured samples of the whole robot, canonical joint order: each array shape (N, num_joints)."""

    q: np.ndarray
    """Positions, rad."""
    dq: np.ndarray
    """Velocities, rad/s."""
    qdd: np.ndarray
    """Accelerations, rad/s^2 (differentiated by the caller)."""
    tau: np.ndarray
    """Torque readings, N*m."""


@dataclass(frozen=True)
class ArmFit:
    """One arm's fit: per joint (the ``joints`` order) value and 95 % half-width; the payload likewise."""

    joints: tuple[str, ...]
    strength: np.ndarray
    friction: np.ndarray
    damping: np.ndarray
    armature: np.ndarray
    half95: dict[str, np.ndarray]
    """Key (``strength``, ``friction``, ``damping``, ``armature``) -> 95 % half-widths, shape (joints,)."""
    mass: float
    mass_half95: float
    com: np.ndarray
    """Payload centre, m, hand frame, shape (3,) (meaningless when the mass is ~0)."""
    com_half95: np.ndarray
    rows: int
    rms: float
    """Residual RMS, N*m."""


def rigid_model(model: mujoco.MjModel) -> mujoco.MjModel:
    """A copy of ``model`` whose ``mj_inverse`` is the links' rigid-body dynamics only.

    Armature, damping, friction loss and constraints off: what the fit's unknowns stand for.
    """
    m = copy.deepcopy(model)
    m.dof_armature[:] = 0.0
    m.dof_damping[:] = 0.0
    m.dof_frictionloss[:] = 0.0
    m.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_CONSTRAINT)
    return m


def unit_payload_model(
    spec_factory: Callable[[], mujoco.MjSpec], hand: str, com: Sequence[float]
) -> mujoco.MjModel:
    """``rigid_model`` of the spec ``spec_factory()`` with a 1 kg point mass on ``hand`` at ``com`` (m)."""
    spec = spec_factory()
    i = 0.4 * PAYLOAD_RADIUS**2
    body = spec.body(hand).add_body(name=f"{hand}_unit_payload", pos=[float(x) for x in com])
    body.explicitinertial = True
    body.mass = 1.0
    body.ipos = [0.0, 0.0, 0.0]
    body.fullinertia = [i, i, i, 0.0, 0.0, 0.0]
    return rigid_model(spec.compile())


class PayloadRegressor:
    """``ID`` of the rigid model and the payload columns of one hand at a centre estimate."""

    def __init__(
        self, base: mujoco.MjModel, spec_factory: Callable[[], mujoco.MjSpec], names: Sequence[str], hand: str
    ) -> None:
        self.base = rigid_model(base)
        self.friction_model = copy.deepcopy(base)
        """The model with every joint's friction loss unbounded: its inverse gives the soft friction
        constraint's force before the clamp to ``+-f`` (``friction_force``)."""
        self.friction_model.dof_damping[:] = 0.0
        self.friction_model.dof_frictionloss[:] = 1e6
        self.friction_model.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_CONTACT)
        self.spec_factory = spec_factory
        self.names = tuple(names)
        self.hand = hand

    def inverse(self, s: ArmSamples) -> np.ndarray:
        """Rigid-body ``ID``, shape (N, num_joints), N*m."""
        m, out = self.base, np.zeros_like(s.q)
        d = mujoco.MjData(m)
        idx = RobotIndex.from_model(m, self.names)
        for k in range(len(s.q)):
            d.qpos[idx.qpos], d.qvel[idx.dof], d.qacc[idx.dof] = s.q[k], s.dq[k], s.qdd[k]
            mujoco.mj_inverse(m, d)
            out[k] = d.qfrc_inverse[idx.dof]
        return out

    def friction_force(self, s: ArmSamples) -> np.ndarray:
        """The friction constraint's force at each sample before its clamp, shape (N, num_joints), N*m.

        MuJoCo's friction loss is a soft constraint: in inverse dynamics each dof's force is
        ``-(qdd - aref) / R`` (``aref = -b dq``, ``R`` from the solver's impedance and the dof's inertia),
        clamped to ``+-frictionloss``. A joint slides (force ``+-f``) only when this exceeds ``f``; below it
        the joint is held by a force that is not ``f sign(dq)`` (light joints like the wrists are held up
        to speeds of rad/s). The fit uses it to tell the two apart.
        """
        m = self.friction_model
        d = mujoco.MjData(m)
        idx = RobotIndex.from_model(m, self.names)
        out = np.zeros_like(s.q)
        col = np.full(m.nv, -1)
        col[idx.dof] = np.arange(len(self.names))
        for k in range(len(s.q)):
            d.qpos[idx.qpos], d.qvel[idx.dof], d.qacc[idx.dof] = s.q[k], s.dq[k], s.qdd[k]
            mujoco.mj_inverse(m, d)
            rows = np.flatnonzero(d.efc_type[: d.nefc] == int(mujoco.mjtConstraint.mjCNSTR_FRICTION_DOF))
            dofs = col[d.efc_id[rows]]
            ok = dofs >= 0
            out[k, dofs[ok]] = d.efc_force[rows[ok]]
        return out

    def columns(self, s: ArmSamples, id_base: np.ndarray, com: np.ndarray) -> np.ndarray:
        """Payload columns at centre ``com``: shape (N, num_joints, 4): unit mass, then d/d(m c) (x, y, z)."""
        m = unit_payload_model(self.spec_factory, self.hand, com)
        d = mujoco.MjData(m)
        idx = RobotIndex.from_model(m, self.names)
        body = m.body(self.hand).id
        g = np.asarray(m.opt.gravity, dtype=np.float64)
        gx = np.array([[0, -g[2], g[1]], [g[2], 0, -g[0]], [-g[1], g[0], 0]])
        jr = np.zeros((3, m.nv))
        out = np.zeros((*s.q.shape, 4))
        for k in range(len(s.q)):
            d.qpos[idx.qpos], d.qvel[idx.dof], d.qacc[idx.dof] = s.q[k], s.dq[k], s.qdd[k]
            mujoco.mj_inverse(m, d)
            out[k, :, 0] = d.qfrc_inverse[idx.dof] - id_base[k]
            mujoco.mj_jacBody(m, d, None, jr, body)
            r = d.xmat[body].reshape(3, 3)
            out[k, :, 1:] = (jr.T @ gx @ r)[idx.dof]
        return out


def moving_average(x: np.ndarray, n: int) -> np.ndarray:
    """Centred moving average of ``n`` samples along axis 0, shape kept (the edges average fewer)."""
    if n <= 1:
        return x
    c = np.cumsum(np.vstack([np.zeros((1, x.shape[1])), x]), axis=0)
    lo = np.clip(np.arange(len(x)) - n // 2, 0, len(x))
    hi = np.clip(np.arange(len(x)) - n // 2 + n, 0, len(x))
    return (c[hi] - c[lo]) / (hi - lo)[:, None]


def min_window(x: np.ndarray, n: int) -> np.ndarray:
    """Centred running minimum of ``n`` samples, shape kept."""
    if n <= 1:
        return x
    pad = np.pad(x, (n // 2, n - 1 - n // 2), mode="edge")
    return np.lib.stride_tricks.sliding_window_view(pad, n).min(axis=1)


def fit_arm(
    samples: ArmSamples,
    joints: Sequence[int],
    names: Sequence[str],
    regressor: PayloadRegressor | None,
    *,
    v_min: float = 0.05,
    iterations: int = 3,
    id_base: np.ndarray | None = None,
    smooth: int = 1,
    friction_u: np.ndarray | None = None,
    strength: np.ndarray | None = None,
    hac_lag: int | None = None,
) -> ArmFit:
    """Fit one arm (module docstring).

    ``joints``: canonical indices of the arm's joints; ``regressor``: the arm's hand payload (None: no
    payload term, mass 0); ``id_base``: precomputed ``ID`` (else computed); ``smooth``: a moving
    average of this many samples on every column and the target alike (the equation holds sample by sample,
    so it holds for the averages exactly, with the measurement noise averaged down: noise in the torque
    column would bias the strength toward 0). Rows are kept where the averaged speed is ``>= v_min`` and
    no sample of the window is below ``v_min / 2`` (no sign change of the friction inside a window).
    ``friction_u``: ``PayloadRegressor.friction_force`` of the samples: MuJoCo's soft friction (each pass
    classifies a sample as sliding where ``|u| >`` the friction estimate, the force ``+-f`` there, ``u``
    itself elsewhere); None: Coulomb ``f sign(dq)`` on every moving sample. ``strength``: known strengths
    of the joints, shape (joints,) (from an unloaded run): fitted otherwise. ``hac_lag``: the intervals'
    Newey-West bandwidth, rows (``hac_cov``: residuals correlated in time); None: the ordinary
    least-squares intervals (independent residuals assumed).
    """
    joints = list(joints)
    nj = len(joints)
    if id_base is None:
        if regressor is None:
            raise ValueError("fit_arm needs id_base or a regressor")
        id_base = regressor.inverse(samples)
    com = np.zeros(3)
    n_p = 4 if regressor is not None else 0
    u = friction_u
    fric = np.full(nj, np.inf) if u is None else np.zeros(nj)
    for _ in range(iterations):
        cols = regressor.columns(samples, id_base, com) if regressor is not None else None
        blocks, rhs = [], []
        for c, j in enumerate(joints):
            a = np.zeros((len(samples.q), 4 * nj + n_p))
            y = id_base[:, j].copy()
            if strength is None:
                a[:, 4 * c + 0] = samples.tau[:, j]
            else:  # known: its torque moves to the right-hand side (the column stays 0, its value fixed)
                y -= strength[c] * samples.tau[:, j]
            if u is None:  # Coulomb: sliding wherever the joint moves
                a[:, 4 * c + 1] = -np.sign(samples.dq[:, j])
            else:  # the soft constraint: slides where its unclamped force exceeds the friction estimate
                slide = np.abs(u[:, j]) > fric[c]
                a[slide, 4 * c + 1] = np.sign(u[slide, j])
                y[~slide] -= u[~slide, j]
                held = ~slide
            a[:, 4 * c + 2] = -samples.dq[:, j]
            a[:, 4 * c + 3] = -samples.qdd[:, j]
            if cols is not None:
                a[:, 4 * nj :] = -cols[:, j, :]
            if smooth > 1:  # the same linear filter on both sides keeps every sample's equation exact
                a, y = moving_average(a, smooth), moving_average(y[:, None], smooth)[:, 0]
            keep = np.abs(moving_average(samples.dq[:, j : j + 1], smooth)[:, 0]) >= v_min
            keep &= min_window(np.abs(samples.dq[:, j]), smooth) >= v_min / 2
            if u is not None and np.isfinite(fric[c]) and fric[c] > 0:
                # a joint held by the constraint says nothing of the motor: its force is the constraint's,
                # as stiff as the solver's impedance (a wrist's: ~0.3 N*m per rad/s), so drop those rows
                keep &= min_window((~held).astype(np.float64), smooth) > 0
            blocks.append(a[keep])
            rhs.append(y[keep])
        a_mat, b = np.concatenate(blocks), np.concatenate(rhs)
        block_id = np.concatenate([np.full(len(r), c) for c, r in enumerate(rhs)])
        scale = np.linalg.norm(a_mat, axis=0)
        scale[scale == 0] = 1.0
        x, *_ = np.linalg.lstsq(a_mat / scale, b, rcond=None)
        x = x / scale
        fric = np.maximum(x[1 : 4 * nj : 4], 0.0)
        if regressor is None:
            continue
        m = x[4 * nj]
        dc = x[4 * nj + 1 :] / m if abs(m) > 1e-6 else np.zeros(3)
        if np.abs(com + dc).max() > COM_SEARCH_M:  # no payload to place (m ~ 0): keep the last centre
            log.warning("payload centre left +-%.1f m (mass %.3g kg): kept at %s", COM_SEARCH_M, m, com)
            dc = np.zeros(3)
        com = com + dc
    resid = b - a_mat @ x
    if hac_lag is None:
        dof = max(len(b) - len(x), 1)
        sigma2 = float(resid @ resid) / dof
        cov = sigma2 * np.linalg.pinv((a_mat / scale).T @ (a_mat / scale)) / np.outer(scale, scale)
    else:
        cov = hac_cov(a_mat / scale, resid, block_id, hac_lag) / np.outer(scale, scale)
    half = Z95 * np.sqrt(np.clip(np.diag(cov), 0.0, None))
    per = x[: 4 * nj].reshape(nj, 4).copy()
    if strength is not None:
        per[:, 0] = strength
    hper = half[: 4 * nj].reshape(nj, 4)
    if regressor is not None:
        m = float(x[4 * nj])
        m_half = float(half[4 * nj])
        # c = c_est + (m dc)/m: its half-width from m dc's (m's own spread is second order at dc ~ 0)
        com_half = half[4 * nj + 1 :] / max(abs(m), 1e-6)
    else:
        m, m_half, com_half = 0.0, 0.0, np.zeros(3)
    return ArmFit(
        joints=tuple(names[j] for j in joints),
        strength=per[:, 0],
        friction=per[:, 1],
        damping=per[:, 2],
        armature=per[:, 3],
        half95={
            "strength": hper[:, 0],
            "friction": hper[:, 1],
            "damping": hper[:, 2],
            "armature": hper[:, 3],
        },
        mass=m,
        mass_half95=m_half,
        com=com,
        com_half95=com_half,
        rows=len(b),
        rms=float(np.sqrt(resid @ resid / len(b))),
    )
