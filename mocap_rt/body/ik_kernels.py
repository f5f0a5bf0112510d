"""The numba kernels of both IK solvers (seed digest B.6-B.7): ``ccd_sweeps`` (the improved
CCD, ``ccd`` module docstring) and ``jacobian_iterations`` (transpose / damped pseudo-inverse,
``jacobian`` module docstring). Each takes an ``ik_problem.IkProblem`` and its solver's named
settings (``CcdParams`` / ``JacobianParams``) and updates the angles in place.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from mocap_rt.body.kinematics import fk_kernel, mul3


@njit(cache=True, nogil=True, inline="always")
def _dot(a, b):
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


@njit(cache=True, nogil=True)
def _axis_angle(a, phi, Q):
    c, s = np.cos(phi), np.sin(phi)
    t = 1.0 - c
    x, y, z = a[0], a[1], a[2]
    Q[0, 0], Q[0, 1], Q[0, 2] = c + t * x * x, t * x * y - s * z, t * x * z + s * y
    Q[1, 0], Q[1, 1], Q[1, 2] = t * x * y + s * z, c + t * y * y, t * y * z - s * x
    Q[2, 0], Q[2, 1], Q[2, 2] = t * x * z - s * y, t * y * z + s * x, c + t * z * z


@njit(cache=True, nogil=True)
def _evaluate(pb, angles, pos, rot, perr, oerr, axerr, tol_p, tol_o):
    """FK of ``angles`` into pos (J, 3) / rot (J, 3, 3); per-effector position error perr (E,)
    metres, orientation error oerr (E,) and per-axis axerr (E, 3) radians; True when every
    effector is within the tolerances."""
    fk_kernel(pb.parents, pb.offsets, pb.rest_local, pb.root_pos, angles, pos, rot)
    done = True
    for e in range(pb.effectors.shape[0]):
        j = pb.effectors[e]
        if pb.w_pos[e] > 0:
            d0 = pb.goal_pos[e, 0] - pos[j, 0]
            d1 = pb.goal_pos[e, 1] - pos[j, 1]
            d2 = pb.goal_pos[e, 2] - pos[j, 2]
            perr[e] = np.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
        else:
            perr[e] = 0.0
        if pb.w_rot[e] > 0:
            tr = 0.0
            for k in range(3):
                ck = pb.goal_rot[e, 0, k] * rot[j, 0, k] + pb.goal_rot[e, 1, k] * rot[j, 1, k] \
                    + pb.goal_rot[e, 2, k] * rot[j, 2, k]
                tr += ck
                axerr[e, k] = np.arccos(min(1.0, max(-1.0, ck)))
            oerr[e] = np.arccos(min(1.0, max(-1.0, (tr - 1.0) / 2.0)))
        else:
            oerr[e] = 0.0
            axerr[e, 0] = axerr[e, 1] = axerr[e, 2] = 0.0
        if perr[e] > tol_p or oerr[e] > tol_o:
            done = False
    return done


@njit(cache=True, nogil=True)
def _euler_axis(F, rot_j, angle_x, k, a):
    """World axis a (3,) of Euler angle k of a joint: X of its parent-and-rest frame F (3, 3),
    the once-rotated Y (``angle_x`` its X angle), its own Z (from its frame rot_j (3, 3))."""
    if k == 0:
        a[:] = F[:, 0]
    elif k == 1:
        c0, s0 = np.cos(angle_x), np.sin(angle_x)
        for i in range(3):  # (F @ Rx(ax))[:, 1]
            a[i] = F[i, 1] * c0 + F[i, 2] * s0
    else:
        a[:] = rot_j[:, 2]


@njit(cache=True, nogil=True)
def ccd_sweeps(pb, cp, angles, perr, oerr):
    """Improved CCD (``ccd`` module docstring) on ``pb`` (IkProblem) with settings ``cp``
    (CcdParams); updates angles (J, 3) in place, fills perr / oerr (E,). Returns
    (sweeps, converged)."""
    J = pb.parents.shape[0]
    E = pb.effectors.shape[0]
    pos = np.empty((J, 3))
    rot = np.empty((J, 3, 3))
    axerr = np.zeros((E, 3))
    wp = np.empty(E)
    wo = np.empty((E, 3))
    F = np.empty((3, 3))
    Q = np.empty((3, 3))
    tmp = np.empty((3, 3))
    a = np.empty(3)
    pc = np.empty(3)
    pd = np.empty(3)
    uc = np.empty(3)
    ud = np.empty(3)
    cx = np.empty(3)
    v = np.empty(3)
    it = 0
    for it in range(cp.max_iter + 1):
        done = _evaluate(pb, angles, pos, rot, perr, oerr, axerr, cp.tol_p, cp.tol_o)
        if done or it == cp.max_iter:
            return it, done
        for e in range(E):
            if cp.adaptive:
                wp[e] = pb.w_pos[e] * cp.wp0 * (1.0 + perr[e] / cp.d_ref) / (cp.scale * cp.scale)
                for k in range(3):
                    wo[e, k] = pb.w_rot[e] * cp.wo0 * (1.0 + axerr[e, k] / cp.th_ref)
            else:
                wp[e] = pb.w_pos[e] * cp.wp0 / (cp.scale * cp.scale)
                for k in range(3):
                    wo[e, k] = pb.w_rot[e] * cp.wo0
        for j in range(J - 1, -1, -1):  # leaves first; a parent after all its children
            for k in range(3):
                if not pb.active[j, k]:
                    continue
                p = pb.parents[j]
                if p >= 0:
                    mul3(rot[p], pb.rest_local[j], F)
                else:
                    F[:, :] = pb.rest_local[j]
                _euler_axis(F, rot[j], angles[j, 0], k, a)
                k1 = 0.0
                k2 = 0.0
                cx[:] = 0.0
                for e in range(E):
                    ew = pb.eff_weight[j, e]
                    if ew <= 0.0:
                        continue
                    je = pb.effectors[e]
                    if wp[e] > 0:
                        for i in range(3):
                            pc[i] = pos[je, i] - pos[j, i]
                            pd[i] = pb.goal_pos[e, i] - pos[j, i]
                        w = ew * wp[e]
                        k1 += w * _dot(pd, a) * _dot(pc, a)
                        k2 += w * _dot(pd, pc)
                        cx[0] += w * (pc[1] * pd[2] - pc[2] * pd[1])
                        cx[1] += w * (pc[2] * pd[0] - pc[0] * pd[2])
                        cx[2] += w * (pc[0] * pd[1] - pc[1] * pd[0])
                    for q in range(3):
                        w = ew * wo[e, q]
                        if w > 0:
                            for i in range(3):
                                uc[i] = rot[je, i, q]
                                ud[i] = pb.goal_rot[e, i, q]
                            k1 += w * _dot(ud, a) * _dot(uc, a)
                            k2 += w * _dot(ud, uc)
                            cx[0] += w * (uc[1] * ud[2] - uc[2] * ud[1])
                            cx[1] += w * (uc[2] * ud[0] - uc[0] * ud[2])
                            cx[2] += w * (uc[0] * ud[1] - uc[1] * ud[0])
                k3 = _dot(a, cx)
                phi = np.arctan2(k3, k2 - k1)
                lo_rel = pb.lo[j, k] - angles[j, k]
                hi_rel = pb.hi[j, k] - angles[j, k]
                if lo_rel <= cp.relax * phi <= hi_rel:
                    phi = cp.relax * phi  # over-relax only inside the limits (never drive into one)
                elif phi < lo_rel or phi > hi_rel:
                    g_lo = k1 * (1 - np.cos(lo_rel)) + k2 * np.cos(lo_rel) + k3 * np.sin(lo_rel)
                    g_hi = k1 * (1 - np.cos(hi_rel)) + k2 * np.cos(hi_rel) + k3 * np.sin(hi_rel)
                    phi = lo_rel if g_lo > g_hi else hi_rel
                if phi == 0.0:
                    continue
                angles[j, k] += phi
                _axis_angle(a, phi, Q)
                for c in range(j, J):  # the subtree of j has indices >= j
                    if pb.below[j, c]:
                        mul3(Q, rot[c], tmp)
                        rot[c] = tmp
                        if c != j:
                            for i in range(3):
                                v[i] = pos[c, i] - pos[j, i]
                            for i in range(3):
                                pos[c, i] = pos[j, i] + Q[i, 0] * v[0] + Q[i, 1] * v[1] + Q[i, 2] * v[2]
    return it, False


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


MAX_ACTIVE_SET_PASSES = 4       # re-solves per iteration with the blocked columns removed
BOUND_EPS_RAD = 1e-12           # an angle within this of a bound is "at" it


@njit(cache=True, nogil=True)
def _dls_step(Jac, err, angles, pb, jp, active_idx):
    """Damped pseudo-inverse step (n,) with the null-space pull towards the reference; with
    ``jp.active_set`` the columns of angles held at a bound are dropped and it is solved again."""
    n = active_idx.shape[0]
    free = np.ones(n, dtype=np.bool_)
    d = np.zeros(n)
    for _pass in range(MAX_ACTIVE_SET_PASSES if jp.active_set else 1):
        A = Jac @ Jac.T + jp.damping * jp.damping * np.eye(Jac.shape[0])
        y = np.linalg.solve(A, err)
        d = Jac.T @ y
        # null-space term: (I - J^T A^-1 J) k (ref - theta)
        z = np.empty(n)
        for col in range(n):
            z[col] = 0.0 if not free[col] else jp.gain * (pb.reference[active_idx[col, 0], active_idx[col, 1]]
                                                          - angles[active_idx[col, 0], active_idx[col, 1]])
        d += z - Jac.T @ np.linalg.solve(A, Jac @ z)
        if not jp.active_set:
            break
        blocked = False
        for col in range(n):
            j = active_idx[col, 0]
            k = active_idx[col, 1]
            if free[col] and ((d[col] < 0 and angles[j, k] <= pb.lo[j, k] + BOUND_EPS_RAD)
                              or (d[col] > 0 and angles[j, k] >= pb.hi[j, k] - BOUND_EPS_RAD)):
                free[col] = False
                Jac[:, col] = 0.0
                blocked = True
        if not blocked:
            break
    return d


@njit(cache=True, nogil=True)
def _linearise(pb, scale, angles, pos, rot, active_idx, Jac, err):
    """The weighted error err (6E,) (position metres, rotation vector times ``scale``) and its
    Jacobian Jac (6E, n) over the active angles ``active_idx`` (n, 2) at the pose pos / rot."""
    E = pb.effectors.shape[0]
    for e in range(E):
        je = pb.effectors[e]
        for i in range(3):
            err[6 * e + i] = pb.w_pos[e] * (pb.goal_pos[e, i] - pos[je, i])
        rv = _rotvec(pb.goal_rot[e] @ rot[je].T)
        for i in range(3):
            err[6 * e + 3 + i] = pb.w_rot[e] * scale * rv[i]
    Jac[:, :] = 0.0
    a = np.empty(3)
    for col in range(active_idx.shape[0]):
        j = active_idx[col, 0]
        p = pb.parents[j]
        # numba's BLAS product here (mul3 differs in the last bits: the baseline's figures)
        F = rot[p] @ pb.rest_local[j] if p >= 0 else pb.rest_local[j].copy()
        _euler_axis(F, rot[j], angles[j, 0], active_idx[col, 1], a)
        for e in range(E):
            if not pb.eff_weight[j, e] > 0.0:
                continue
            r = pos[pb.effectors[e]] - pos[j]
            Jac[6 * e + 0, col] = pb.w_pos[e] * (a[1] * r[2] - a[2] * r[1])
            Jac[6 * e + 1, col] = pb.w_pos[e] * (a[2] * r[0] - a[0] * r[2])
            Jac[6 * e + 2, col] = pb.w_pos[e] * (a[0] * r[1] - a[1] * r[0])
            for i in range(3):
                Jac[6 * e + 3 + i, col] = pb.w_rot[e] * scale * a[i]


@njit(cache=True, nogil=True)
def jacobian_iterations(pb, jp, angles, perr, oerr):
    """Jacobian-transpose or damped-pseudo-inverse IK (``jacobian`` module docstring) on ``pb``
    (IkProblem) with settings ``jp`` (JacobianParams); updates angles (J, 3) in place, fills
    perr / oerr (E,). Returns (iterations, converged)."""
    J = pb.parents.shape[0]
    E = pb.effectors.shape[0]
    active_idx = np.argwhere(pb.active)     # (n, 2) (joint, axis) of the active angles, row-major
    n = active_idx.shape[0]
    pos = np.empty((J, 3))
    rot = np.empty((J, 3, 3))
    axerr = np.zeros((E, 3))
    Jac = np.zeros((6 * E, n))
    err = np.zeros(6 * E)
    for it in range(jp.max_iter + 1):
        done = _evaluate(pb, angles, pos, rot, perr, oerr, axerr, jp.tol_p, jp.tol_o)
        if done or it == jp.max_iter:
            return it, done
        _linearise(pb, jp.scale, angles, pos, rot, active_idx, Jac, err)
        if jp.use_dls:
            d = _dls_step(Jac, err, angles, pb, jp, active_idx)
        else:
            g = Jac.T @ err
            jjte = Jac @ g
            den = jjte @ jjte
            alpha = (err @ jjte) / den if den > 0 else 0.0
            d = alpha * g
        for col in range(n):
            j = active_idx[col, 0]
            k = active_idx[col, 1]
            step = min(jp.max_step, max(-jp.max_step, d[col]))
            angles[j, k] = min(pb.hi[j, k], max(pb.lo[j, k], angles[j, k] + step))
    return jp.max_iter, False
