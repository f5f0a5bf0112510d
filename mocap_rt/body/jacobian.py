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
  ``ik_kernels.MAX_ACTIVE_SET_PASSES`` times): the other angles then take up its share
  instead of losing it to the clamp. Off by default (the plain baseline); the CCD's
  polish (``CcdConfig.polish_iterations``) turns it on.

The error ``e`` stacks, per effector, the position error (metres) and the rotation
vector of ``R_goal R^T`` times ``body_scale_m`` (so radians become commensurate metres).
This module owns the settings and the entry point; the kernel is ``ik_kernels.jacobian_iterations``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mocap_rt.body.ik_kernels import jacobian_iterations
from mocap_rt.body.ik_problem import IkResult, JacobianParams, build_problem
from mocap_rt.body.skeleton import BodyModel


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


def solve_jacobian(model: BodyModel, root_pos: np.ndarray, angles0: np.ndarray, effectors: np.ndarray,
                   goal_pos: np.ndarray, goal_rot: np.ndarray | None = None, *,
                   w_pos: np.ndarray | None = None, w_rot: np.ndarray | None = None,
                   reference: np.ndarray | None = None, solve_root: bool = False,
                   config: JacobianConfig = JacobianConfig()) -> IkResult:
    """Jacobian-transpose or damped-pseudo-inverse IK; arguments as ``ccd.solve_ccd``."""
    if config.method not in ("dls", "transpose"):
        raise ValueError(f"JacobianConfig.method must be 'dls' or 'transpose', got {config.method!r}")
    problem, angles = build_problem(model, root_pos, angles0, effectors, goal_pos, goal_rot, w_pos, w_rot,
                                    reference, solve_root, config.use_limits, config.angle_tolerance_deg)
    params = JacobianParams(
        max_iter=int(config.max_iterations), tol_p=float(config.tol_position_m),
        tol_o=float(np.radians(config.tol_orientation_deg)), use_dls=config.method == "dls",
        damping=float(config.damping), gain=float(config.null_space_gain), max_step=float(config.max_step_rad),
        scale=float(config.body_scale_m), active_set=bool(config.limit_active_set))
    perr = np.zeros(len(problem.effectors))
    oerr = np.zeros(len(problem.effectors))
    it, ok = jacobian_iterations(problem, params, angles, perr, oerr)
    return IkResult(angles, int(it), perr.copy(), np.degrees(oerr), bool(ok))
