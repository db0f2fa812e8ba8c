"""Per-joint fit of the fast single-joint segments of an identification run: armature, friction, damping.

After the held poses (``sysid_fit.fit_arm``: the whole arm, payload and strength), the excitation moves each
joint alone on two fast sines (``sysid_excitation``). There the joint's own inertia torque dominates, so its
equation alone, with the links' inertia from ``mj_inverse`` held (``id_base``) and the strength held,
separates the armature from the links' inertia, and a wrist's Coulomb friction from the soft friction loss
that holds a slow wrist (samples above its sliding speed only). Intervals: ``sysid_fit.hac_cov``.

No jax, no torch.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from bar_policy.robot.sysid_fit import (
    Z95,
    ArmSamples,
    hac_cov,
    min_window,
    moving_average,
)

__all__ = ["FastFit", "fit_fast"]


@dataclass(frozen=True)
class FastFit:
    """Per-joint fit of the fast single-joint segments: values and 95 % half-widths, shape (joints,)."""

    joints: tuple[str, ...]
    friction: np.ndarray
    damping: np.ndarray
    armature: np.ndarray
    strength: np.ndarray
    """Fitted, or the strengths given (held: half-width 0)."""
    half95: dict[str, np.ndarray]
    """Key (``friction``, ``damping``, ``armature``, ``strength``) -> 95 % half-widths, shape (joints,)."""
    mass: float
    """The payload's mass refitted on these segments (its centre held), kg; the given one when held."""
    mass_half95: float
    rows: np.ndarray
    """Rows used per joint, shape (joints,)."""
    rms: np.ndarray
    """Residual RMS per joint, N*m, shape (joints,)."""


def fit_fast(
    samples: ArmSamples,
    segments: Sequence[tuple[slice, int]],
    names: Sequence[str],
    id_base: np.ndarray,
    friction_u: np.ndarray,
    strength: np.ndarray | None,
    *,
    payload_col: np.ndarray | None = None,
    mass: float = 0.0,
    fit_mass: bool = False,
    armature: np.ndarray | None = None,
    smooth: int = 1,
    iterations: int = 6,
    hac_lag: int | None = None,
) -> FastFit:
    """Friction, damping and armature of each joint from the segments where it moves alone.

    ``segments``: ``(rows, j)``: the slice of ``samples`` where canonical joint ``j`` alone is excited (a
    joint may have several); only ``j``'s own equation is used there, so each joint's armature is fitted
    against its own acceleration with the links' inertia from ``mj_inverse`` held (the fit's unknowns per
    joint: ``f_j``, ``b_j``, ``a_j``)::

        s_j tau_j - F_j - b_j dq_j - a_j qdd_j - m Y_j = ID_j

    ``F_j``: MuJoCo's soft friction loss as in ``fit_arm`` (``+-f_j`` where the unclamped force
    ``friction_u`` exceeds the estimate, that force itself elsewhere, rows held by it dropped);
    ``strength``: the joints' strengths, held (shape (joints,), in the order of first appearance in
    ``segments``; NaN: that joint's fitted), or None: all fitted (a strength scales the links' inertia
    torque, known from the model, so an error of it moves the armature by that fraction of the links'
    inertia: held, it must be exact; fitted, a known torque that is not an inertia's must be in ``id_base``,
    such as a known payload's gravity);
    ``payload_col``: the unit payload's column at its centre (``PayloadRegressor.columns``'s first, shape
    (N, num_joints)); ``mass``: its mass, subtracted (``fit_mass``: one mass shared by all the segments
    refitted: a payload's inertia about a joint is ``m r^2``, larger than a shoulder's armature, and its
    gravity stiffness ``m g r`` at two frequencies tells it from an armature, so a few % error of
    a held mass would be the whole armature); ``armature``: the joints' armatures, held (shape (joints,),
    in ``strength``'s order; an unloaded run's, given to a loaded one: with a payload its inertia is 4-12x
    a joint's armature and the two trade), or None: fitted. ``smooth``, ``hac_lag``: as ``fit_arm``.
    """
    order: list[int] = []
    for _, j in segments:
        if j not in order:
            order.append(j)
    nj = len(order)
    n_p = 1 if fit_mass and payload_col is not None else 0
    fitted = np.ones(nj, dtype=bool) if strength is None else ~np.isfinite(strength)
    w = 4 if fitted.any() else 3  # unknowns per joint: f, b, a (and s)
    fric = np.zeros(nj)
    for _ in range(iterations):
        blocks, rhs, ids, which = [], [], [], []
        for k, (sl, j) in enumerate(segments):
            c = order.index(j)
            u = friction_u[sl, j]
            a = np.zeros((len(u), w * nj + n_p))
            y = id_base[sl, j].copy()
            if fitted[c]:
                a[:, w * c + 3] = samples.tau[sl, j]
            else:  # held (``strength`` is not None here)
                y -= strength[c] * samples.tau[sl, j]  # type: ignore[index]
            slide = np.abs(u) > fric[c]
            a[slide, w * c] = np.sign(u[slide])
            y[~slide] -= u[~slide]
            a[:, w * c + 1] = -samples.dq[sl, j]
            if armature is None:
                a[:, w * c + 2] = -samples.qdd[sl, j]
            else:  # held: its torque moves to the known side (the column stays 0: its unknown is 0)
                y += armature[c] * samples.qdd[sl, j]
            if payload_col is not None:
                if n_p:
                    a[:, w * nj] = -payload_col[sl, j]
                else:
                    y -= mass * payload_col[sl, j]
            a, y = moving_average(a, smooth), moving_average(y[:, None], smooth)[:, 0]
            keep = np.ones(len(u), dtype=bool)
            if fric[c] > 0:  # rows held by the constraint say nothing of the motor (fit_arm)
                keep &= min_window(slide.astype(np.float64), smooth) > 0
            blocks.append(a[keep])
            rhs.append(y[keep])
            ids.append(np.full(int(keep.sum()), k))
            which.append(np.full(int(keep.sum()), c))
        a_mat, b = np.concatenate(blocks), np.concatenate(rhs)
        scale = np.linalg.norm(a_mat, axis=0)
        scale[scale == 0] = 1.0
        x, *_ = np.linalg.lstsq(a_mat / scale, b, rcond=None)
        x = x / scale
        fric = np.maximum(x[0 : w * nj : w], 0.0)
    resid = b - a_mat @ x
    block_id, col = np.concatenate(ids), np.concatenate(which)
    if hac_lag is None:
        sigma2 = float(resid @ resid) / max(len(b) - len(x), 1)
        cov = sigma2 * np.linalg.pinv((a_mat / scale).T @ (a_mat / scale)) / np.outer(scale, scale)
    else:
        cov = hac_cov(a_mat / scale, resid, block_id, hac_lag) / np.outer(scale, scale)
    half = Z95 * np.sqrt(np.clip(np.diag(cov), 0.0, None))
    per, hper = x[: w * nj].reshape(nj, w), half[: w * nj].reshape(nj, w)
    rows = np.array([int((col == c).sum()) for c in range(nj)])
    rms = np.array([float(np.sqrt(np.mean(resid[col == c] ** 2))) if rows[c] else np.nan for c in range(nj)])
    return FastFit(
        joints=tuple(names[j] for j in order),
        friction=per[:, 0],
        damping=per[:, 1],
        armature=per[:, 2] if armature is None else np.asarray(armature, dtype=np.float64),
        strength=per[:, 3] if strength is None else np.where(fitted, per[:, -1], strength),
        half95={
            "friction": hper[:, 0],
            "damping": hper[:, 1],
            "armature": hper[:, 2] if armature is None else np.zeros(nj),
            "strength": np.where(fitted, hper[:, -1], 0.0),
        },
        mass=float(x[w * nj]) if n_p else float(mass),
        mass_half95=float(half[w * nj]) if n_p else 0.0,
        rows=rows,
        rms=rms,
    )
