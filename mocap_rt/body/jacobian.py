"""Jacobian IK baselines for the CCD comparison (seed digest B.6).

Both solvers use the same joint axes as the CCD (one column per active Euler angle:
the X axis of the parent-and-rest frame, the once-rotated Y axis, the joint's Z axis),
the same goals and the same limits (angles are clamped after each step).

* Jacobian transpose (Wolovich & Elliott 1984): ``dtheta = alpha J^T e`` with Buss's
  step ``alpha = <e, J J^T e> / |J J^T e|^2``.
* Damped pseudo-inverse with a null-space term:
  ``dtheta = J^T (J J^T + lambda^2 I)^-1 e + (I - J^+ J) k (theta_ref - theta)``,
  the secondary goal pulling towards the reference (measured) pose.
  With ``limit_active_set`` an angle sitting on a bound whose step would push it
  further out gets its column removed and the step is solved again (at most
  ``_MAX_ACTIVE_SET_PASSES`` times): the other angles then take up its share
  instead of losing it to the clamp. Off by default (the plain baseline); the CCD's
  polish (``CcdConfig.polish_iterations``) turns it on.

The error ``e`` stacks, per effector, the position error (metres) and the rotation
vector of ``R_goal R^T`` times ``body_scale_m`` (so radians become commensurate metres).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

from mocap_rt.body.ccd import IkResult, _errors, _fk3, _goal_arrays, _within, allowed_intervals, subtree_masks
from mocap_rt.body.skeleton import N_JOINTS, BodyModel


@dataclass(frozen=True)
class JacobianConfig:
    """Settings (units in the names)."""

    method: str = "dls"                  # "dls" (damped pseudo-inverse + null space) or "transpose"
    max_iterations: int = 200
    tol_position_m: float = 5e-4
    tol_orientation_deg: float = 0.25
    damping: float = 0.02                # lambda, metres
    null_space_gain: float = 0.1         # k, per iteration
    max_step_rad: float = 0.3            # clamp of each angle change per iteration
    body_scale_m: float = 0.5
    use_limits: bool = True
    angle_tolerance_deg: float = 45.0
    limit_active_set: bool = False       # dls: drop the columns of angles held at a bound (see below)


@njit(cache=True, nogil=True)
def _rotvec(M):
    """Rotation vector (3,) of a rotation matrix."""
    c = min(1.0, max(-1.0, (M[0, 0] + M[1, 1] + M[2, 2] - 1.0) / 2.0))
    ang = np.arccos(c)
    v = np.array([M[2, 1] - M[1, 2], M[0, 2] - M[2, 0], M[1, 0] - M[0, 1]])
    s = np.sin(ang)
    if s > 1e-9:
        return v * (ang / (2.0 * s))
    if ang < 1e-6:
        return v / 2.0
    # near pi: axis from the diagonal
    ax = np.sqrt(np.maximum(0.0, (np.diag(M) + 1.0) / 2.0))
    k = np.argmax(ax)
    for i in range(3):
        if i != k and (M[i, k] + M[k, i]) < 0:
            ax[i] = -ax[i]
    return ax * ang


_MAX_ACTIVE_SET_PASSES = 4      # re-solves per iteration with the blocked columns removed
_BOUND_EPS_RAD = 1e-12          # an angle within this of a bound is "at" it


@njit(cache=True, nogil=True)
def _jacobian_solve(parents, offsets, rest_local, root_pos, angles, active_idx, lo, hi, effectors, goal_pos,
                    goal_rot, w_pos, w_rot, below, eff_below, max_iter, tol_p, tol_o, use_dls, damping, gain,
                    max_step, scale, reference, active_set, perr, oerr):
    J = parents.shape[0]
    E = effectors.shape[0]
    n = active_idx.shape[0]
    pos = np.empty((J, 3))
    rot = np.empty((J, 3, 3))
    tmp = np.empty((3, 3))
    tmp2 = np.empty((3, 3))
    axerr = np.zeros((E, 3))
    Jac = np.zeros((6 * E, n))
    err = np.zeros(6 * E)
    it = 0
    for it in range(max_iter + 1):
        _fk3(parents, offsets, rest_local, root_pos, angles, pos, rot, tmp, tmp2)
        _errors(pos, rot, effectors, goal_pos, goal_rot, w_pos, w_rot, perr, oerr, axerr)
        done = _within(perr, oerr, tol_p, tol_o)
        if done or it == max_iter:
            return it, done
        for e in range(E):
            je = effectors[e]
            for i in range(3):
                err[6 * e + i] = w_pos[e] * (goal_pos[e, i] - pos[je, i])
            rv = _rotvec(goal_rot[e] @ rot[je].T)
            for i in range(3):
                err[6 * e + 3 + i] = w_rot[e] * scale * rv[i]
        Jac[:, :] = 0.0
        for col in range(n):
            j = active_idx[col, 0]
            k = active_idx[col, 1]
            p = parents[j]
            F = rot[p] @ rest_local[j] if p >= 0 else rest_local[j].copy()
            if k == 0:
                a = F[:, 0].copy()
            elif k == 1:
                c0, s0 = np.cos(angles[j, 0]), np.sin(angles[j, 0])
                a = F[:, 1] * c0 + F[:, 2] * s0
            else:
                a = rot[j][:, 2].copy()
            for e in range(E):
                if not eff_below[j, e]:
                    continue
                r = pos[effectors[e]] - pos[j]
                Jac[6 * e + 0, col] = w_pos[e] * (a[1] * r[2] - a[2] * r[1])
                Jac[6 * e + 1, col] = w_pos[e] * (a[2] * r[0] - a[0] * r[2])
                Jac[6 * e + 2, col] = w_pos[e] * (a[0] * r[1] - a[1] * r[0])
                for i in range(3):
                    Jac[6 * e + 3 + i, col] = w_rot[e] * scale * a[i]
        if use_dls:
            free = np.ones(n, dtype=np.bool_)
            d = np.zeros(n)
            for _pass in range(_MAX_ACTIVE_SET_PASSES if active_set else 1):
                A = Jac @ Jac.T + damping * damping * np.eye(6 * E)
                y = np.linalg.solve(A, err)
                d = Jac.T @ y
                # null-space term: (I - J^T A^-1 J) k (ref - theta)
                z = np.empty(n)
                for col in range(n):
                    z[col] = 0.0 if not free[col] else gain * (reference[active_idx[col, 0], active_idx[col, 1]]
                                                               - angles[active_idx[col, 0], active_idx[col, 1]])
                d += z - Jac.T @ np.linalg.solve(A, Jac @ z)
                if not active_set:
                    break
                blocked = False
                for col in range(n):
                    j = active_idx[col, 0]
                    k = active_idx[col, 1]
                    if free[col] and ((d[col] < 0 and angles[j, k] <= lo[j, k] + _BOUND_EPS_RAD)
                                      or (d[col] > 0 and angles[j, k] >= hi[j, k] - _BOUND_EPS_RAD)):
                        free[col] = False
                        Jac[:, col] = 0.0
                        blocked = True
                if not blocked:
                    break
        else:
            g = Jac.T @ err
            jjte = Jac @ g
            den = jjte @ jjte
            alpha = (err @ jjte) / den if den > 0 else 0.0
            d = alpha * g
        for col in range(n):
            j = active_idx[col, 0]
            k = active_idx[col, 1]
            step = min(max_step, max(-max_step, d[col]))
            angles[j, k] = min(hi[j, k], max(lo[j, k], angles[j, k] + step))
    return it, False


def solve_jacobian(model: BodyModel, root_pos: np.ndarray, angles0: np.ndarray, effectors: np.ndarray,
                   goal_pos: np.ndarray, goal_rot: np.ndarray | None = None, *,
                   w_pos: np.ndarray | None = None, w_rot: np.ndarray | None = None,
                   reference: np.ndarray | None = None, solve_root: bool = False,
                   config: JacobianConfig = JacobianConfig()) -> IkResult:
    """Jacobian-transpose or damped-pseudo-inverse IK; arguments as ``ccd.solve_ccd``."""
    if config.method not in ("dls", "transpose"):
        raise ValueError(f"JacobianConfig.method must be 'dls' or 'transpose', got {config.method!r}")
    effectors, gp, gr, wpv, wrv = _goal_arrays(effectors, goal_pos, goal_rot, w_pos,
                                               w_rot if goal_rot is not None else np.zeros(len(effectors)))
    angles = np.array(angles0, dtype=np.float64).reshape(N_JOINTS, 3)
    ref = angles.copy() if reference is None else np.ascontiguousarray(reference, dtype=np.float64)
    active, lo, hi = allowed_intervals(model, ref, config.use_limits, config.angle_tolerance_deg, solve_root)
    angles = np.where(active, np.clip(angles, lo, hi), angles)
    active_idx = np.argwhere(active).astype(np.int64)
    below, eff_below = subtree_masks(model, effectors)
    perr = np.zeros(len(effectors))
    oerr = np.zeros(len(effectors))
    it, ok = _jacobian_solve(model.parents, model.offsets, model.rest_local,
                             np.ascontiguousarray(root_pos, dtype=np.float64).reshape(3), angles, active_idx, lo, hi,
                             effectors, gp, gr, wpv, wrv, below, eff_below, int(config.max_iterations),
                             config.tol_position_m, np.radians(config.tol_orientation_deg), config.method == "dls",
                             config.damping, config.null_space_gain, config.max_step_rad, config.body_scale_m,
                             ref, config.limit_active_set, perr, oerr)
    return IkResult(angles, int(it), perr.copy(), np.degrees(oerr), bool(ok))
