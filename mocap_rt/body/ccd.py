"""The improved CCD inverse-kinematics solver over the whole body tree (seed digest B.7).

Each active joint angle is a 1-DOF rotation about a world axis ``a`` (the X axis of
the parent-and-rest frame for the joint's X angle, the once-rotated Y axis for its Y
angle, the joint's own Z axis for its Z angle: exactly the axes of its Rx Ry Rz
decomposition, so each step changes one Euler angle and its limit is applied
exactly, instead of the thesis' decompose-and-clamp after each sweep). For every end
effector ``e`` below the joint, with ``P_ic = E_c - J_i``, ``P_id = E_d - J_i`` and the
effector's current/desired frame axes ``u_kc``, ``u_kd``:

    g(phi) = k1 (1 - cos phi) + k2 cos phi + k3 sin phi                    (B.7)
    k1 = sum_e w_p (P_id . a)(P_ic . a) + sum_k w_ok (u_kd . a)(u_kc . a)
    k2 = sum_e w_p (P_id . P_ic)       + sum_k w_ok (u_kd . u_kc)
    k3 = a . [ sum_e w_p (P_ic x P_id) + sum_k w_ok (u_kc x u_kd) ]

is maximised in closed form: ``phi* = atan2(k3, k2 - k1)``; if ``phi*`` leaves the
allowed interval the better of the two interval ends is taken. The allowed interval is
the range-of-motion limit intersected (improvement 2) with ``reference +- tolerance``
(the measured pose). Joints are visited from the leaves to the root, a joint only
after all its children (reverse topological order). Improvement 3 re-weights each
effector every sweep: ``w_p = w_p0 (1 + d / d_ref) / s^2`` (``d`` its distance to the
goal, ``s`` the body scale, so position and orientation terms are commensurate) and
``w_ok = w_o0 (1 + theta_k / theta_ref)`` per axis.

Hybrid (``CcdConfig.polish``, on by default; off = the pure thesis CCD): CCD can stall
in a local optimum with an angle held at a limit (a shoulder or a foot) or converge
slowly. If it has not converged after ``polish_after_iterations`` sweeps (and
``max_iterations`` is larger, i.e. the caller allowed a longer solve), up to
``polish_iterations`` damped-pseudo-inverse steps (``jacobian.solve_jacobian``, same
axes, limits and angle tolerance, with the limit active set) start from the CCD
result, and if that does not converge either, from ``angles0`` (the CCD's stall basin
is sometimes one the pseudo-inverse cannot leave). The best of the attempts (worst
effector error in units of the tolerances) is kept. A caller capping ``max_iterations``
at or below ``polish_after_iterations`` gets the pure CCD: the fusion tracker's
per-frame refinement (30 sweeps on noisy, often unreachable cue goals) keeps its
behaviour and cost (with the polish it measured ~1.3 ms slower and 0.1-0.4 mm worse).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

from mocap_rt.body.kinematics import euler_xyz_matrix
from mocap_rt.body.skeleton import N_JOINTS, BodyModel


@dataclass(frozen=True)
class CcdConfig:
    """Solver settings (units in the names). The switches reproduce the thesis' ablation."""

    max_iterations: int = 400
    tol_position_m: float = 5e-4
    tol_orientation_deg: float = 0.25
    use_limits: bool = True                  # improvement 1: range-of-motion limits
    angle_tolerance_deg: float = 45.0        # improvement 2: <= 0 disables it
    adaptive_weights: bool = True            # improvement 3
    position_weight: float = 1.0             # w_p0
    orientation_weight: float = 0.3          # w_o0
    weight_ref_distance_m: float = 0.01      # d_ref
    weight_ref_angle_deg: float = 1.0        # theta_ref
    body_scale_m: float = 0.5                # s
    relaxation: float = 1.5                  # over-relaxation of each 1-DOF step (1 = plain CCD)
    redundant_chain_weight: float = 0.1      # see chain_weights (1 = plain CCD)
    polish: bool = True                      # hybrid: damped-least-squares steps if CCD has not converged
    polish_after_iterations: int = 60        # CCD sweeps before the polish takes over (only if max_iterations
                                             # is larger: a smaller sweep cap means pure CCD, see module doc)
    polish_iterations: int = 15              # DLS iterations per polish attempt


@dataclass(frozen=True)
class IkResult:
    """Solver output. angles (J, 3) radians; errors per effector (E,) metres / degrees."""

    angles: np.ndarray
    iterations: int
    position_error_m: np.ndarray
    orientation_error_deg: np.ndarray
    converged: bool


def subtree_masks(model: BodyModel, effectors: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(J, J) bool ``below[j, c]`` (c in j's subtree, j included) and (J, E) effector mask."""
    below = np.zeros((N_JOINTS, N_JOINTS), dtype=np.bool_)
    for c in range(N_JOINTS):
        j = c
        while j >= 0:
            below[j, c] = True
            j = model.parents[j]
    return below, below[:, effectors]


def chain_weights(model: BodyModel, effectors: np.ndarray, active: np.ndarray,
                  redundant_weight: float) -> np.ndarray:
    """(J, E) float weight of effector e when joint j is corrected.

    1 where e is below j and the joints strictly between j and e have fewer than six
    active DOF; ``redundant_weight`` where they have six or more (that chain can correct
    its effector on its own, so it should not pull the shared joint, e.g. the hands on
    the spine while the head needs it); 0 where e is not below j.
    """
    _, eff_below = subtree_masks(model, effectors)
    out = eff_below.astype(np.float64)
    n_dof = active.sum(axis=1)
    for e, je in enumerate(effectors):
        path = []
        j = int(je)
        while j >= 0:
            path.append(j)
            j = int(model.parents[j])
        # path: effector ... root; DOF strictly below path[i] = sum over path[:i]
        for i, j in enumerate(path):
            if n_dof[path[:i]].sum() >= 6:
                out[j, e] = redundant_weight
    return out


@njit(cache=True, nogil=True, inline="always")
def _dot(a, b):
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


@njit(cache=True, nogil=True)
def _mm(A, B, out):
    """out = A @ B for 3x3 (out may not alias)."""
    for i in range(3):
        for j in range(3):
            out[i, j] = A[i, 0] * B[0, j] + A[i, 1] * B[1, j] + A[i, 2] * B[2, j]


@njit(cache=True, nogil=True)
def _fk3(parents, offsets, rest_local, root_pos, angles, pos, rot, tmp, tmp2):
    """Forward kinematics without BLAS calls (same result as kinematics._fk)."""
    for j in range(parents.shape[0]):
        E = euler_xyz_matrix(angles[j, 0], angles[j, 1], angles[j, 2])
        p = parents[j]
        _mm(rest_local[j], E, tmp)
        if p < 0:
            rot[j] = tmp
            pos[j] = root_pos
        else:
            _mm(rot[p], tmp, tmp2)
            rot[j] = tmp2
            for i in range(3):
                pos[j, i] = pos[p, i] + rot[p, i, 0] * offsets[j, 0] + rot[p, i, 1] * offsets[j, 1] \
                    + rot[p, i, 2] * offsets[j, 2]


@njit(cache=True, nogil=True)
def _axis_angle(a, phi, Q):
    c, s = np.cos(phi), np.sin(phi)
    t = 1.0 - c
    x, y, z = a[0], a[1], a[2]
    Q[0, 0], Q[0, 1], Q[0, 2] = c + t * x * x, t * x * y - s * z, t * x * z + s * y
    Q[1, 0], Q[1, 1], Q[1, 2] = t * x * y + s * z, c + t * y * y, t * y * z - s * x
    Q[2, 0], Q[2, 1], Q[2, 2] = t * x * z - s * y, t * y * z + s * x, c + t * z * z


@njit(cache=True, nogil=True)
def _errors(pos, rot, effectors, goal_pos, goal_rot, w_pos, w_rot, perr, oerr, axerr):
    for e in range(effectors.shape[0]):
        j = effectors[e]
        if w_pos[e] > 0:
            d0 = goal_pos[e, 0] - pos[j, 0]
            d1 = goal_pos[e, 1] - pos[j, 1]
            d2 = goal_pos[e, 2] - pos[j, 2]
            perr[e] = np.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
        else:
            perr[e] = 0.0
        if w_rot[e] > 0:
            tr = 0.0
            for k in range(3):
                ck = goal_rot[e, 0, k] * rot[j, 0, k] + goal_rot[e, 1, k] * rot[j, 1, k] \
                    + goal_rot[e, 2, k] * rot[j, 2, k]
                tr += ck
                axerr[e, k] = np.arccos(min(1.0, max(-1.0, ck)))
            oerr[e] = np.arccos(min(1.0, max(-1.0, (tr - 1.0) / 2.0)))
        else:
            oerr[e] = 0.0
            axerr[e, 0] = axerr[e, 1] = axerr[e, 2] = 0.0


@njit(cache=True, nogil=True)
def _within(perr, oerr, tol_p, tol_o):
    """True when every effector is within the position and orientation tolerances."""
    for e in range(perr.shape[0]):
        if perr[e] > tol_p or oerr[e] > tol_o:
            return False
    return True


@njit(cache=True, nogil=True)
def _ccd(parents, offsets, rest_local, root_pos, angles, active, lo, hi, effectors, goal_pos, goal_rot,
         w_pos, w_rot, below, eff_below, max_iter, tol_p, tol_o, adaptive, wp0, wo0, d_ref, th_ref, scale,
         relax, perr, oerr):
    J = parents.shape[0]
    E = effectors.shape[0]
    pos = np.empty((J, 3))
    rot = np.empty((J, 3, 3))
    axerr = np.zeros((E, 3))
    wp = np.empty(E)
    wo = np.empty((E, 3))
    F = np.empty((3, 3))
    Q = np.empty((3, 3))
    tmp = np.empty((3, 3))
    tmp2 = np.empty((3, 3))
    a = np.empty(3)
    pc = np.empty(3)
    pd = np.empty(3)
    uc = np.empty(3)
    ud = np.empty(3)
    cx = np.empty(3)
    v = np.empty(3)
    it = 0
    for it in range(max_iter + 1):
        _fk3(parents, offsets, rest_local, root_pos, angles, pos, rot, tmp, tmp2)
        _errors(pos, rot, effectors, goal_pos, goal_rot, w_pos, w_rot, perr, oerr, axerr)
        done = _within(perr, oerr, tol_p, tol_o)
        if done or it == max_iter:
            return it, done
        for e in range(E):
            if adaptive:
                wp[e] = w_pos[e] * wp0 * (1.0 + perr[e] / d_ref) / (scale * scale)
                for k in range(3):
                    wo[e, k] = w_rot[e] * wo0 * (1.0 + axerr[e, k] / th_ref)
            else:
                wp[e] = w_pos[e] * wp0 / (scale * scale)
                for k in range(3):
                    wo[e, k] = w_rot[e] * wo0
        for j in range(J - 1, -1, -1):  # leaves first; a parent after all its children
            p = parents[j]
            for k in range(3):
                if not active[j, k]:
                    continue
                # world axis of this Euler angle
                if p >= 0:
                    _mm(rot[p], rest_local[j], F)
                else:
                    F[:, :] = rest_local[j]
                if k == 0:
                    a[:] = F[:, 0]
                elif k == 1:
                    c0, s0 = np.cos(angles[j, 0]), np.sin(angles[j, 0])
                    for i in range(3):  # (F @ Rx(ax))[:, 1]
                        a[i] = F[i, 1] * c0 + F[i, 2] * s0
                else:
                    a[:] = rot[j, :, 2]
                k1 = 0.0
                k2 = 0.0
                cx[:] = 0.0
                for e in range(E):
                    ew = eff_below[j, e]
                    if ew <= 0.0:
                        continue
                    je = effectors[e]
                    if wp[e] > 0:
                        for i in range(3):
                            pc[i] = pos[je, i] - pos[j, i]
                            pd[i] = goal_pos[e, i] - pos[j, i]
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
                                ud[i] = goal_rot[e, i, q]
                            k1 += w * _dot(ud, a) * _dot(uc, a)
                            k2 += w * _dot(ud, uc)
                            cx[0] += w * (uc[1] * ud[2] - uc[2] * ud[1])
                            cx[1] += w * (uc[2] * ud[0] - uc[0] * ud[2])
                            cx[2] += w * (uc[0] * ud[1] - uc[1] * ud[0])
                k3 = _dot(a, cx)
                phi = np.arctan2(k3, k2 - k1)
                lo_rel = lo[j, k] - angles[j, k]
                hi_rel = hi[j, k] - angles[j, k]
                if lo_rel <= relax * phi <= hi_rel:
                    phi = relax * phi  # over-relax only inside the limits (never drive into one)
                elif phi < lo_rel or phi > hi_rel:
                    g_lo = k1 * (1 - np.cos(lo_rel)) + k2 * np.cos(lo_rel) + k3 * np.sin(lo_rel)
                    g_hi = k1 * (1 - np.cos(hi_rel)) + k2 * np.cos(hi_rel) + k3 * np.sin(hi_rel)
                    phi = lo_rel if g_lo > g_hi else hi_rel
                if phi == 0.0:
                    continue
                angles[j, k] += phi
                _axis_angle(a, phi, Q)
                for c in range(j, J):  # the subtree of j has indices >= j
                    if below[j, c]:
                        _mm(Q, rot[c], tmp)
                        rot[c] = tmp
                        if c != j:
                            for i in range(3):
                                v[i] = pos[c, i] - pos[j, i]
                            for i in range(3):
                                pos[c, i] = pos[j, i] + Q[i, 0] * v[0] + Q[i, 1] * v[1] + Q[i, 2] * v[2]
    return it, False


def _goal_arrays(effectors, goal_pos, goal_rot, w_pos, w_rot):
    effectors = np.ascontiguousarray(effectors, dtype=np.int64)
    E = effectors.shape[0]
    goal_pos = np.ascontiguousarray(goal_pos, dtype=np.float64).reshape(E, 3)
    goal_rot = (np.broadcast_to(np.eye(3), (E, 3, 3)).copy() if goal_rot is None
                else np.ascontiguousarray(goal_rot, dtype=np.float64).reshape(E, 3, 3))
    w_pos = np.ones(E) if w_pos is None else np.ascontiguousarray(w_pos, dtype=np.float64).reshape(E)
    if w_rot is None:
        w_rot = np.zeros(E) if goal_rot is None else np.ones(E)
    w_rot = np.ascontiguousarray(w_rot, dtype=np.float64).reshape(E)
    # NaN goals are dropped (weight 0)
    bad_p = ~np.isfinite(goal_pos).all(axis=1)
    bad_r = ~np.isfinite(goal_rot).all(axis=(1, 2))
    w_pos = np.where(bad_p, 0.0, w_pos)
    w_rot = np.where(bad_r, 0.0, w_rot)
    goal_pos = np.where(bad_p[:, None], 0.0, goal_pos)
    goal_rot = np.where(bad_r[:, None, None], np.eye(3), goal_rot)
    return effectors, goal_pos, goal_rot, w_pos, w_rot


def allowed_intervals(model: BodyModel, reference: np.ndarray, use_limits: bool,
                      angle_tolerance_deg: float, solve_root: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(active (J,3) bool, lo (J,3), hi (J,3) radians) for the solvers."""
    active = model.dof.copy()
    if not solve_root:
        active[0] = False
    big = 1e3
    lo = np.where(use_limits, model.limits[..., 0], -big)
    hi = np.where(use_limits, model.limits[..., 1], big)
    lo[0], hi[0] = -big, big
    if angle_tolerance_deg > 0:
        tol = np.radians(angle_tolerance_deg)
        lo = np.maximum(lo, reference - tol)
        hi = np.minimum(hi, reference + tol)
        hi = np.maximum(hi, lo)
    return active, np.ascontiguousarray(lo), np.ascontiguousarray(hi)


def solve_ccd(model: BodyModel, root_pos: np.ndarray, angles0: np.ndarray, effectors: np.ndarray,
              goal_pos: np.ndarray, goal_rot: np.ndarray | None = None, *,
              w_pos: np.ndarray | None = None, w_rot: np.ndarray | None = None,
              reference: np.ndarray | None = None, solve_root: bool = False,
              config: CcdConfig = CcdConfig()) -> IkResult:
    """Improved CCD from ``angles0`` (J, 3) radians towards the effector goals.

    effectors : (E,) int joint indices. goal_pos : (E, 3) metres, world (NaN rows = no
    position goal). goal_rot : (E, 3, 3) desired world frames of the effectors, or None
    (positions only). w_pos, w_rot : (E,) per-goal weights (0 disables). reference :
    (J, 3) the measured pose for the angle-change tolerance (default ``angles0``).
    solve_root : also rotate the pelvis (its translation stays ``root_pos``).
    With ``config.polish`` (default) and ``max_iterations > polish_after_iterations``, an
    unconverged CCD is finished by damped least squares (module docstring);
    ``iterations`` then counts CCD sweeps + DLS iterations.
    """
    effectors, gp, gr, wpv, wrv = _goal_arrays(effectors, goal_pos, goal_rot, w_pos,
                                               w_rot if goal_rot is not None else np.zeros(len(effectors)))
    angles = np.array(angles0, dtype=np.float64).reshape(N_JOINTS, 3)
    ref = angles.copy() if reference is None else np.asarray(reference, dtype=np.float64)
    active, lo, hi = allowed_intervals(model, ref, config.use_limits, config.angle_tolerance_deg, solve_root)
    angles = np.where(active, np.clip(angles, lo, hi), angles)
    below, _ = subtree_masks(model, effectors)
    eff_w = chain_weights(model, effectors, active, config.redundant_chain_weight)
    perr = np.zeros(len(effectors))
    oerr = np.zeros(len(effectors))
    it, ok = _ccd(model.parents, model.offsets, model.rest_local,
                  np.ascontiguousarray(root_pos, dtype=np.float64).reshape(3), angles, active, lo, hi,
                  effectors, gp, gr, wpv, wrv, below, eff_w,
                  int(config.polish_after_iterations if _polish_enabled(config) else config.max_iterations),
                  config.tol_position_m, np.radians(config.tol_orientation_deg), config.adaptive_weights,
                  config.position_weight, config.orientation_weight, config.weight_ref_distance_m,
                  np.radians(config.weight_ref_angle_deg), config.body_scale_m,
                  config.relaxation, perr, oerr)
    res = IkResult(angles, int(it), perr.copy(), np.degrees(oerr), bool(ok))
    if ok or not _polish_enabled(config):
        return res
    return _polish(model, root_pos, angles0, effectors, goal_pos, goal_rot, w_pos, w_rot, ref, solve_root,
                   config, res)


def _polish_enabled(config: CcdConfig) -> bool:
    return config.polish and config.max_iterations > config.polish_after_iterations


def _score(res: IkResult, config: CcdConfig) -> float:
    """Worst effector error in units of the tolerances (<= 1: converged)."""
    return float(max(np.max(res.position_error_m, initial=0.0) / config.tol_position_m,
                     np.max(res.orientation_error_deg, initial=0.0) / config.tol_orientation_deg))


def _polish(model, root_pos, angles0, effectors, goal_pos, goal_rot, w_pos, w_rot, reference, solve_root,
            config: CcdConfig, ccd_res: IkResult) -> IkResult:
    """The hybrid's damped-least-squares polish (see the module docstring)."""
    from mocap_rt.body.jacobian import JacobianConfig, solve_jacobian  # jacobian imports this module

    jcfg = JacobianConfig(method="dls", max_iterations=int(config.polish_iterations),
                          tol_position_m=config.tol_position_m, tol_orientation_deg=config.tol_orientation_deg,
                          body_scale_m=config.body_scale_m, use_limits=config.use_limits,
                          angle_tolerance_deg=config.angle_tolerance_deg, limit_active_set=True)
    best = ccd_res
    iterations = ccd_res.iterations
    for start in (ccd_res.angles, angles0):
        r = solve_jacobian(model, root_pos, start, effectors, goal_pos, goal_rot, w_pos=w_pos, w_rot=w_rot,
                           reference=reference, solve_root=solve_root, config=jcfg)
        iterations += r.iterations
        if _score(r, config) < _score(best, config):
            best = r
        if best.converged:
            break
    return IkResult(best.angles, iterations, best.position_error_m, best.orientation_error_deg, best.converged)
