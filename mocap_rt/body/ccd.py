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
behaviour and cost (docs/body.md). This module owns the settings and the entry point;
the kernel is ``ik_kernels.ccd_sweeps``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mocap_rt.body.ik_kernels import ccd_sweeps
from mocap_rt.body.ik_problem import CcdParams, IkResult, build_problem
from mocap_rt.body.jacobian import JacobianConfig, solve_jacobian
from mocap_rt.body.skeleton import BodyModel


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
    redundant_chain_weight: float = 0.1      # see ik_problem.chain_weights (1 = plain CCD)
    polish: bool = True                      # hybrid: damped-least-squares steps if CCD has not converged
    polish_after_iterations: int = 60        # CCD sweeps before the polish takes over (only if max_iterations
                                             # is larger: a smaller sweep cap means pure CCD, see module doc)
    polish_iterations: int = 15              # DLS iterations per polish attempt


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
    problem, angles = build_problem(model, root_pos, angles0, effectors, goal_pos, goal_rot, w_pos, w_rot,
                                    reference, solve_root, config.use_limits, config.angle_tolerance_deg,
                                    config.redundant_chain_weight)
    params = CcdParams(
        max_iter=int(config.polish_after_iterations if _polish_enabled(config) else config.max_iterations),
        tol_p=float(config.tol_position_m), tol_o=float(np.radians(config.tol_orientation_deg)),
        adaptive=bool(config.adaptive_weights), wp0=float(config.position_weight),
        wo0=float(config.orientation_weight), d_ref=float(config.weight_ref_distance_m),
        th_ref=float(np.radians(config.weight_ref_angle_deg)), scale=float(config.body_scale_m),
        relax=float(config.relaxation))
    perr = np.zeros(len(problem.effectors))
    oerr = np.zeros(len(problem.effectors))
    it, ok = ccd_sweeps(problem, params, angles, perr, oerr)
    res = IkResult(angles, int(it), perr.copy(), np.degrees(oerr), bool(ok))
    if ok or not _polish_enabled(config):
        return res
    return _polish(model, root_pos, angles0, effectors, goal_pos, goal_rot, w_pos, w_rot, problem.reference,
                   solve_root, config, res)


def _polish_enabled(config: CcdConfig) -> bool:
    return config.polish and config.max_iterations > config.polish_after_iterations


def _score(res: IkResult, config: CcdConfig) -> float:
    """Worst effector error in units of the tolerances (<= 1: converged)."""
    return float(max(np.max(res.position_error_m, initial=0.0) / config.tol_position_m,
                     np.max(res.orientation_error_deg, initial=0.0) / config.tol_orientation_deg))


def _polish(model, root_pos, angles0, effectors, goal_pos, goal_rot, w_pos, w_rot, reference, solve_root,
            config: CcdConfig, ccd_res: IkResult) -> IkResult:
    """The hybrid's damped-least-squares polish (see the module docstring)."""
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
