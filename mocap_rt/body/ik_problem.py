"""The IK problem both solvers share: the named structures their kernels take (``IkProblem``:
body arrays, effector goals, allowed intervals; ``CcdParams`` / ``JacobianParams``: the scalar
settings), their construction from a ``BodyModel`` and goals (``build_problem``) and ``IkResult``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from mocap_rt.body.skeleton import N_JOINTS, BodyModel


@dataclass(frozen=True)
class IkResult:
    """Solver output. angles (J, 3) radians; errors per effector (E,) metres / degrees."""

    angles: np.ndarray
    iterations: int
    position_error_m: np.ndarray
    orientation_error_deg: np.ndarray
    converged: bool


class IkProblem(NamedTuple):
    """One IK problem as the kernels read it (every array C-contiguous, float64 unless said)."""

    parents: np.ndarray      # (J,) int64 parent joint, -1 for the root
    offsets: np.ndarray      # (J, 3) metres, child position in the parent's frame
    rest_local: np.ndarray   # (J, 3, 3) rest rotation relative to the parent
    root_pos: np.ndarray     # (3,) metres, world: the pelvis (fixed)
    effectors: np.ndarray    # (E,) int64 joint indices
    goal_pos: np.ndarray     # (E, 3) metres, world (0 where the goal is missing)
    goal_rot: np.ndarray     # (E, 3, 3) desired world frames (identity where missing)
    w_pos: np.ndarray        # (E,) position weights (0 disables)
    w_rot: np.ndarray        # (E,) orientation weights (0 disables)
    active: np.ndarray       # (J, 3) bool: the angles the solver may change
    lo: np.ndarray           # (J, 3) radians, allowed interval of each angle
    hi: np.ndarray           # (J, 3)
    below: np.ndarray        # (J, J) bool: below[j, c] when c is in j's subtree (j included)
    eff_weight: np.ndarray   # (J, E) weight of effector e when joint j moves (0: not below j)
    reference: np.ndarray    # (J, 3) radians, the measured pose (Jacobian null-space goal)


class CcdParams(NamedTuple):
    """The scalar settings of ``ccd_sweeps`` (from ``ccd.CcdConfig``; radians, metres)."""

    max_iter: int
    tol_p: float             # metres
    tol_o: float             # radians
    adaptive: bool           # improvement 3: re-weight the effectors every sweep
    wp0: float               # position weight
    wo0: float               # orientation weight
    d_ref: float             # metres
    th_ref: float            # radians
    scale: float             # body scale, metres
    relax: float             # over-relaxation of each 1-DOF step


class JacobianParams(NamedTuple):
    """The scalar settings of ``jacobian_iterations`` (from ``jacobian.JacobianConfig``)."""

    max_iter: int
    tol_p: float             # metres
    tol_o: float             # radians
    use_dls: bool            # damped pseudo-inverse (else Jacobian transpose)
    damping: float           # lambda, metres
    gain: float              # null-space gain per iteration
    max_step: float          # radians per angle and iteration
    scale: float             # body scale, metres
    active_set: bool         # dls: drop the columns of angles held at a bound


def subtree_masks(model: BodyModel, effectors: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(J, J) bool ``below[j, c]`` (c in j's subtree, j included) and (J, E) effector mask."""
    below = np.zeros((N_JOINTS, N_JOINTS), dtype=np.bool_)
    parents = model.parents.tolist()
    for c in range(N_JOINTS):
        j = c
        while j >= 0:
            below[j, c] = True
            j = parents[j]
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
    out = np.ascontiguousarray(eff_below, dtype=np.float64)
    n_dof = active.sum(axis=1).tolist()
    parents = model.parents.tolist()
    for e, je in enumerate(np.asarray(effectors).tolist()):
        j, dof_below = je, 0       # walk effector ... root; dof_below: active DOF strictly below j
        while j >= 0:
            if dof_below >= 6:
                out[j, e] = redundant_weight
            dof_below += n_dof[j]
            j = parents[j]
    return out


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


def _goal_arrays(effectors, goal_pos, goal_rot, w_pos, w_rot):
    effectors = np.ascontiguousarray(effectors, dtype=np.int64)
    E = effectors.shape[0]
    goal_pos = np.ascontiguousarray(goal_pos, dtype=np.float64).reshape(E, 3)
    goal_rot = (np.broadcast_to(np.eye(3), (E, 3, 3)).copy() if goal_rot is None
                else np.ascontiguousarray(goal_rot, dtype=np.float64).reshape(E, 3, 3))
    w_pos = np.ones(E) if w_pos is None else np.ascontiguousarray(w_pos, dtype=np.float64).reshape(E)
    w_rot = np.ascontiguousarray(w_rot, dtype=np.float64).reshape(E)
    # NaN goals are dropped (weight 0)
    bad_p = ~np.isfinite(goal_pos).all(axis=1)
    bad_r = ~np.isfinite(goal_rot).all(axis=(1, 2))
    w_pos = np.where(bad_p, 0.0, w_pos)
    w_rot = np.where(bad_r, 0.0, w_rot)
    goal_pos = np.where(bad_p[:, None], 0.0, goal_pos)
    goal_rot = np.where(bad_r[:, None, None], np.eye(3), goal_rot)
    return effectors, goal_pos, goal_rot, w_pos, w_rot


def build_problem(model: BodyModel, root_pos: np.ndarray, angles0: np.ndarray, effectors: np.ndarray,
                  goal_pos: np.ndarray, goal_rot: np.ndarray | None, w_pos: np.ndarray | None,
                  w_rot: np.ndarray | None, reference: np.ndarray | None, solve_root: bool, use_limits: bool,
                  angle_tolerance_deg: float, redundant_chain_weight: float = 1.0) -> tuple[IkProblem, np.ndarray]:
    """The kernels' ``IkProblem`` and the start angles (J, 3) radians, clipped to the allowed
    intervals (a new array the kernels update in place). Arguments as ``ccd.solve_ccd``;
    ``redundant_chain_weight`` as ``chain_weights`` (1: every effector below a joint counts fully)."""
    if w_rot is None:
        w_rot = np.zeros(len(effectors)) if goal_rot is None else np.ones(len(effectors))
    elif goal_rot is None:
        w_rot = np.zeros(len(effectors))
    effectors, gp, gr, wpv, wrv = _goal_arrays(effectors, goal_pos, goal_rot, w_pos, w_rot)
    angles = np.array(angles0, dtype=np.float64).reshape(N_JOINTS, 3)
    ref = angles.copy() if reference is None else np.ascontiguousarray(reference, dtype=np.float64)
    active, lo, hi = allowed_intervals(model, ref, use_limits, angle_tolerance_deg, solve_root)
    angles = np.where(active, np.clip(angles, lo, hi), angles)
    below, eff_below = subtree_masks(model, effectors)
    eff_weight = (np.ascontiguousarray(eff_below, dtype=np.float64) if redundant_chain_weight == 1.0
                  else chain_weights(model, effectors, active, redundant_chain_weight))
    problem = IkProblem(model.parents, model.offsets, model.rest_local,
                        np.ascontiguousarray(root_pos, dtype=np.float64).reshape(3), effectors, gp, gr, wpv, wrv,
                        active, lo, hi, below, eff_weight, np.ascontiguousarray(ref.reshape(N_JOINTS, 3)))
    return problem, angles
