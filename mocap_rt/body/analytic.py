"""Real-time analytic IK from the six 3D cues (seed digest A.5), plus the body's pan.

Input: ``cues (6, 3)`` metres, world, in ``CUE_NAMES`` order (head, hand_l, hand_r,
foot_l, foot_r, torso). Output: a pose of the ``BodyModel`` (root position and
angles) whose hands, feet and head lie on the cues when they are reachable.

* Torso orientation (A.5): the body axis is parallel to head - torso.
* Pan (not in the paper, which fixed it): the body's right axis is estimated from the
  left->right vectors of the feet and of the hands (feet weighted more), made
  perpendicular to the body axis; when the torso moves faster than
  ``walk_speed_mps`` the walking line is blended in, on the side the labels say (a
  person may walk backwards: the velocity never decides which way the body faces), and
  the along-track components of the feet and hands vectors (steps, arm swing) are removed. The
  caller passes the previous right axis so the estimate can be smoothed. ``refine_pan``
  then turns it (+-90 deg in 15 deg steps) to the heading whose analytic pose violates
  the range-of-motion limits least (a wrong pan makes the limbs twist out of range).
* Limbs (A.5): a goal is a direction and a clamped distance: the limb always points at
  its cue; the distance is clamped into ``[|L1 - L2|, L1 + L2]`` (fully stretched
  outside the reachable range). The elbow/knee lies in the plane of the limb and a
  pole direction; ``elbow_raise_deg`` / ``knee_open_deg`` rotate that pole about the
  limb axis (the paper's experimental constants for Rz^l1). An arm that this fixed pole
  (the hanging arm's) puts out of its shoulder's range (a hand at the face, on the head) is
  re-bent by ``limb_geometry._arm_pole`` in ``analytic_pose``; the pan and swivel searches
  (``refine_pan``, ``refine_swivel``, ``fit.BodyFitter``) score the fixed poles.
* The closed-form angles of eq. (6) are obtained by building each bone frame (Z along
  the bone, X the flexion axis normal to the limb plane) and reading the model's
  X-Y-Z angles between adjacent frames (B.5), so the result is exact for any preset.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

from mocap_rt.body.kinematics import euler_xyz_from_matrix
from mocap_rt.body.limb_geometry import _arm_pole, _cross, _frame, _nunit, _rot_about, _two_link, joint_violation
from mocap_rt.body.skeleton import BodyModel
from mocap_rt.names import C_FOOT_L, C_FOOT_R, C_HAND_L, C_HAND_R, C_HEAD, C_TORSO, N_JOINTS, J

@dataclass(frozen=True)
class AnalyticConfig:
    """Parameters of the analytic IK (angles in degrees, speeds in m/s)."""

    elbow_raise_deg: float = 0.0    # pole of the elbow rotated outwards about the body axis
    elbow_down_deg: float = 60.0    # pole of the elbow tilted from backwards towards down
    knee_open_deg: float = 5.0      # pole of the knee rotated outwards from straight forward
    elbow_pole_candidates: int = 12  # an arm out of range: its pole turned in 360/N deg steps (0 = off), _arm_pole
    elbow_twist_cost: float = 0.1    # ... per degree of shoulder twist (Euler Z) vs degrees of limit violation
    elbow_turn_cost: float = 0.7     # ... per degree the pole turned, where the elbow is measured on the silhouettes
    feet_weight: float = 0.5        # weight of the feet's left->right vector for the pan
    hands_weight: float = 1.0       # weight of the hands' left->right vector
    walk_speed_mps: float = 0.4     # above this torso speed the walking direction counts
    walk_weight: float = 2.0        # weight of the walking direction at twice that speed
    pan_smoothing: float = 0.5      # 0 = no memory, -> 1 = keep the previous pan (walking)
    still_pan_smoothing: float = 0.5  # the same when standing (feet/hands only: less reliable)
    pan_search_deg: float = 90.0    # refine the pan within +- this (0 = off), see refine_pan
    pan_search_step_deg: float = 15.0
    pan_change_cost: float = 0.2    # cost per degree of pan change vs degrees of limit violation
    swivel_search_deg: float = 60.0  # refine each elbow/knee pole within +- this (0 = off)
    swivel_step_deg: float = 15.0
    swivel_change_cost: float = 0.1  # per degree changed since the previous frame
    swivel_prior_cost: float = 0.2   # per degree away from the default pole
    snap_standing: bool = False     # standing: take the feet/hands line modulo 90 deg near the previous pan
    walk_sign_from_labels: bool = True  # the walking direction gives the heading's line, the labels its sign
                                        # (False: the body faces where it walks, the issue-5 behaviour)
    trunk_from_head: bool = False   # the trunk hung from the head cue (the head joint on it) along the
                                    # axes' up, not placed on the torso cue (``body.fit.refine_trunk``)


def _unit(v: np.ndarray, fallback: np.ndarray) -> np.ndarray:
    n = float(np.linalg.norm(v))
    return v / n if n > 1e-9 and np.isfinite(n) else fallback


def body_axes(cues: np.ndarray, prev_right: np.ndarray | None = None, velocity: np.ndarray | None = None,
              config: AnalyticConfig = AnalyticConfig()) -> np.ndarray:
    """(3, 3) body frame in the world, columns (right, forward, up) (A.5 + pan estimate).

    cues : (6, 3) metres, world; missing cues NaN (then the previous/default axes are used).
    prev_right : (3,) previous right axis, for smoothing. velocity : (3,) torso m/s.
    """
    up = _unit(cues[C_HEAD] - cues[C_TORSO], np.array([0.0, 0, 1]))
    prev = np.array([1.0, 0, 0]) if prev_right is None else np.asarray(prev_right, dtype=np.float64)
    v = np.zeros(3)
    feet = cues[C_FOOT_R] - cues[C_FOOT_L]
    hands = cues[C_HAND_R] - cues[C_HAND_L]
    heading = None
    w_walk = 0.0
    if velocity is not None and np.isfinite(velocity).all():
        vh = velocity - up * (velocity @ up)
        speed = float(np.linalg.norm(vh))
        if speed > config.walk_speed_mps:
            heading = vh / speed
            w_walk = config.walk_weight * min(1.0, (speed - config.walk_speed_mps) / config.walk_speed_mps)
    for vec, weight in ((feet, config.feet_weight), (hands, config.hands_weight)):
        if not np.isfinite(vec).all():
            continue
        if heading is not None:  # while walking, feet and hands separate along the track
            vec = vec - heading * (vec @ heading)
        elif prev_right is not None and config.snap_standing:
            # standing: the feet may be side by side or staggered, so the feet line gives
            # the pan modulo 90 degrees; take the candidate nearest the previous right axis
            vec = vec - up * (vec @ up)
            cands = (vec, -vec, _cross(up, vec), -_cross(up, vec))
            vec = max(cands, key=lambda c: float(c @ prev))
        v += weight * vec / max(np.linalg.norm(vec), 0.05)
    if heading is not None:
        # the walking line gives the heading's axis; which way along it the body faces is the
        # labels' (left/right) business unless ``walk_sign_from_labels`` is off (facing = velocity)
        walk_right = _cross(heading, up)
        side = float(v @ walk_right)
        if config.walk_sign_from_labels and abs(side) < 1e-9:
            side = float(prev @ walk_right)
        v = v + w_walk * (-1.0 if (config.walk_sign_from_labels and side < 0) else 1.0) * walk_right
    v = v - up * (v @ up)
    right = _unit(v, prev)
    keep = config.pan_smoothing if heading is not None else config.still_pan_smoothing
    if prev_right is not None and keep > 0:
        right = _unit((1 - keep) * right + keep * prev, right)
    right = _unit(right - up * (right @ up), _cross(np.array([0.0, 1, 0]), up))
    forward = _cross(up, right)
    return np.column_stack([right, forward, up])


def pan_angle(axes: np.ndarray) -> float:
    """Heading (radians) of the body's forward axis about world +Z; 0 = facing +Y."""
    f = axes[:, 1]
    return float(np.arctan2(-f[0], f[1]))


# ``_analytic``'s ``views`` when there are none (``silhouette.SilhouetteTargets.args``' first five)
NO_VIEWS = (np.zeros((1, 3, 4)), np.ones(1), np.zeros((1, 8), np.int64), np.zeros(1, np.float32), np.zeros(1, np.int64))


@njit(cache=True, nogil=True)
def _analytic(cues, axes, lengths, poles, arm_lim, foot_rest, limb_joints, swivel, R, views, w_elbow, limb=-1):
    """Fill the joint frames R (J, 3, 3); return the pelvis position (see analytic_pose).
    With a ``limb`` (0-3, the swivel slot: arm_l, arm_r, leg_l, leg_r) only the trunk's and that
    limb's frames are written: the others keep R's (a search that moves one limb's swivel).

    poles : (6,) elbow_raise, elbow_down, knee_open (radians), elbow pole candidates (a
    count, 0 = the fixed pole), twist cost and turn cost (``limb_args``); arm_lim : (2, 3, 2) radians,
    the shoulders' (lo, hi) X-Y-Z limits (left, right). swivel : (4,) radians, extra
    rotation of each limb's pole about the root -> goal line (arm_l, arm_r, leg_l, leg_r),
    relative to the fixed pole; then an arm still out of range takes ``_arm_pole``'s, or with
    ``w_elbow`` > 0 every arm takes the pole ``_arm_pole`` chooses with its elbow measured
    against the silhouettes ``views`` (P, f, grid, dt, dt_off; ``NO_VIEWS``: none), weighted
    ``w_elbow`` per m^2 of mean squared distance outside them.
    """
    elbow_raise, elbow_down, knee_open = poles[0], poles[1], poles[2]
    n_poles = int(poles[3])
    trunk, sh_half, upper_len, fore_len, hip_half, thigh, shank, foot_len, torso_cue_up, neck_head, from_head = lengths
    right = axes[:, 0].copy()
    forward = axes[:, 1].copy()
    up = axes[:, 2].copy()
    if from_head > 0.0:     # the head joint on the head cue (AnalyticConfig.trunk_from_head)
        torso = cues[C_HEAD] - up * (neck_head + trunk / 2)
    else:
        torso = cues[C_TORSO] - up * torso_cue_up
    pelvis = torso - up * (trunk / 2)
    neck = torso + up * (trunk / 2)
    for j in range(4):  # pelvis, torso, neck, head
        R[j] = axes
    # knee -> foot centre with a straight ankle: shank + foot at rest (body frame)
    eff1 = foot_len * foot_rest[1]
    eff2 = -shank + foot_len * foot_rest[2]
    L2_leg = np.sqrt(eff1 * eff1 + eff2 * eff2)
    gamma = np.arctan2(eff1, -eff2)                   # foot centre ahead of the shank axis
    beta = np.arctan2(foot_rest[1], -foot_rest[2])    # foot direction ahead of the shank
    for s in range(2):
        sx = -1.0 if s == 0 else 1.0
        hand_c = C_HAND_L if s == 0 else C_HAND_R
        foot_c = C_FOOT_L if s == 0 else C_FOOT_R
        jsh, jel, jwr, jha, jhi, jkn, jan, jft = limb_joints[s]
        if limb >= 0 and limb % 2 != s:
            continue
        if limb < 2:
            # arm: shoulder -> elbow -> hand (hand collinear with the forearm at zero wrist angles)
            shoulder = neck + right * (sx * sh_half)
            back_down = -forward * np.cos(elbow_down) - up * np.sin(elbow_down)
            pole = _rot_about(up, -sx * elbow_raise, back_down)
            d = cues[hand_c] - shoulder
            if swivel[s] != 0.0 and d @ d > 1e-12:
                pole = _rot_about(d, swivel[s], pole)
            if n_poles > 1 and d @ d > 1e-12:
                pole = _arm_pole(shoulder, cues[hand_c], upper_len, fore_len, pole, axes, arm_lim[s], n_poles, poles[4],
                                 views, w_elbow, poles[5])
            elbow, hand, u, w = _two_link(shoulder, cues[hand_c], upper_len, fore_len, pole)
            x = _cross(w, u)  # flexion axis: the elbow bends the forearm towards -w
            _frame(elbow - shoulder, x, R[jsh])
            _frame(hand - elbow, x, R[jel])
            R[jwr] = R[jel]
            R[jha] = R[jel]
        if limb < 0 or limb >= 2:
            # leg: hip -> knee -> foot centre; the foot is rigid on the shank (paper model)
            hip = pelvis + right * (sx * hip_half)
            pole = _rot_about(up, sx * knee_open, forward)
            d = cues[foot_c] - hip
            if swivel[2 + s] != 0.0 and d @ d > 1e-12:
                pole = _rot_about(d, swivel[2 + s], pole)
            knee, foot, u, w = _two_link(hip, cues[foot_c], thigh, L2_leg, pole)
            n = _cross(u, w)  # flexion axis (the body's right for a straight standing leg)
            u2 = _nunit(foot - knee, -up)
            _frame(knee - hip, n, R[jhi])
            _frame(_rot_about(n, -gamma, u2), n, R[jkn])
            _frame(_rot_about(n, beta - gamma, u2), n, R[jan])
            R[jft] = R[jan]
    return pelvis


@njit(cache=True, nogil=True)
def _angles_from_frames(parents, rest_local, dof, R, out):
    """Euler X-Y-Z angles (J, 3) of each frame relative to parent @ rest (3x3 products
    written out: numba's ``@`` on 3x3 goes through BLAS and costs more than the maths)."""
    F = np.empty((3, 3))
    M = np.empty((3, 3))
    for j in range(parents.shape[0]):
        _angle_from_frames(parents, rest_local, dof, R, out, j, F, M)


@njit(cache=True, nogil=True)
def _angle_from_frames(parents, rest_local, dof, R, out, j, F, M):
    """``_angles_from_frames`` for joint j alone; F, M (3, 3) scratch."""
    p = parents[j]
    if p < 0:
        F[:, :] = rest_local[j]
    else:
        for a in range(3):
            for b in range(3):
                F[a, b] = R[p, a, 0] * rest_local[j, 0, b] + R[p, a, 1] * rest_local[j, 1, b] \
                    + R[p, a, 2] * rest_local[j, 2, b]
    for a in range(3):
        for b in range(3):
            M[a, b] = F[0, a] * R[j, 0, b] + F[1, a] * R[j, 1, b] + F[2, a] * R[j, 2, b]
    ang = euler_xyz_from_matrix(M)
    for k in range(3):
        out[j, k] = ang[k] if dof[j, k] else 0.0


_LIMB_JOINTS = np.array([[J[f"{n}_{s}"] for n in ("shoulder", "elbow", "wrist", "hand", "hip", "knee", "ankle", "foot")]
                         for s in ("l", "r")], dtype=np.int64)


def limb_args(model: BodyModel, config: AnalyticConfig,
              elbow_pole_search: bool = True) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The arrays ``_analytic`` takes: lengths (11,) metres (trunk, shoulder half width,
    upper arm, forearm + hand, hip half width, thigh, shank, foot, the torso cue above the
    torso joint, neck -> head; then 1.0 with ``trunk_from_head``, else 0.0), poles (6,) (elbow
    raise, elbow down, knee open radians; elbow pole candidates, 0 without
    ``elbow_pole_search``; twist cost; turn cost), arm_lim (2, 3, 2) radians (the shoulders' limits,
    left then right) and foot_rest (3,) (the foot's rest direction, body frame)."""
    L = model.lengths
    lengths = np.array([L.trunk_m, L.shoulder_half_width_m, L.upper_arm_m, L.forearm_m + L.hand_m,
                        L.hip_half_width_m, L.thigh_m, L.shank_m, L.foot_m, L.torso_cue_up_m, L.neck_head_m,
                        float(config.trunk_from_head)])
    poles = np.array([np.radians(config.elbow_raise_deg), np.radians(config.elbow_down_deg),
                      np.radians(config.knee_open_deg),
                      float(config.elbow_pole_candidates) if elbow_pole_search else 0.0, config.elbow_twist_cost,
                      config.elbow_turn_cost])
    arm_lim = np.ascontiguousarray(model.limits[_LIMB_JOINTS[:, 0]])
    return lengths, poles, arm_lim, np.ascontiguousarray(model.rest_world[J["ankle_r"]][:, 2])


def analytic_pose(model: BodyModel, cues: np.ndarray, axes: np.ndarray,
                  config: AnalyticConfig = AnalyticConfig(),
                  swivel: np.ndarray | None = None, views: tuple = NO_VIEWS,
                  w_elbow: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Pose from the six cues: ``(root_pos (3,), angles (J, 3) radians)``.

    swivel : (4,) radians about each limb's root -> goal line (arm_l, arm_r, leg_l, leg_r)
    added to the fixed poles (see ``refine_swivel``); default none. An arm then out of its
    shoulder's range is re-bent (``AnalyticConfig.elbow_pole_candidates``, ``_arm_pole``);
    with ``views`` (``SilhouetteTargets.args()[:5]``) and ``w_elbow`` > 0 (per m^2) every arm
    takes its elbow on the silhouettes, as ``BodyFitter`` scores it.

    cues : (6, 3) metres, world, all finite (the tracker fills gaps from its filter).
    axes : (3, 3) body frame from ``body_axes`` (columns right, forward, up).
    """
    R = np.empty((N_JOINTS, 3, 3))
    pelvis = _analytic(np.ascontiguousarray(cues, dtype=np.float64), np.ascontiguousarray(axes, dtype=np.float64),
                       *limb_args(model, config), _LIMB_JOINTS,
                       np.zeros(4) if swivel is None else np.asarray(swivel, np.float64), R, views, w_elbow)
    angles = np.empty((N_JOINTS, 3))
    _angles_from_frames(model.parents, model.rest_local, model.dof, R, angles)
    return pelvis, angles


@njit(cache=True, nogil=True)
def _pan_search(cues, axes, lengths, poles, arm_lim, foot_rest, limb_joints, swivel, parents,
                rest_local, dof, lo, hi, step, n_steps, change_cost, out_axes):
    J = parents.shape[0]
    R = np.empty((J, 3, 3))
    ang = np.empty((J, 3))
    axc = np.empty((3, 3))
    up = axes[:, 2].copy()
    right0 = axes[:, 0].copy()
    best = np.inf
    for k in range(-n_steps, n_steps + 1):
        a = step * k
        r = _rot_about(up, a, right0)
        f = _cross(up, r)
        for i in range(3):
            axc[i, 0], axc[i, 1], axc[i, 2] = r[i], f[i], up[i]
        _analytic(cues, axc, lengths, poles, arm_lim, foot_rest, limb_joints, swivel, R, NO_VIEWS, 0.0)
        _angles_from_frames(parents, rest_local, dof, R, ang)
        viol = 0.0
        for j in range(1, J):
            viol += joint_violation(ang, lo, hi, dof, j)
        cost = np.degrees(viol) + change_cost * abs(np.degrees(a))
        if cost < best:
            best = cost
            out_axes[:, :] = axc
    return best


def refine_pan(model: BodyModel, cues: np.ndarray, axes: np.ndarray,
               config: AnalyticConfig = AnalyticConfig(), swivel: np.ndarray | None = None) -> np.ndarray:
    """Body axes (3, 3) with the pan turned (within +-``pan_search_deg``) to the heading
    whose analytic pose violates the joint limits (B.7 table) least, plus
    ``pan_change_cost`` per degree turned.

    The pan from the hands/feet/walking is a guess; a wrong pan puts the shoulders and
    hips where the limbs must twist beyond their range of motion to reach the cues.
    cues : (6, 3) all finite, metres, world. axes : (3, 3) from ``body_axes``.
    """
    if config.pan_search_deg <= 0 or config.pan_search_step_deg <= 0:
        return axes
    out = np.empty((3, 3))
    n = int(config.pan_search_deg // config.pan_search_step_deg)
    _pan_search(np.ascontiguousarray(cues, dtype=np.float64), np.ascontiguousarray(axes, dtype=np.float64),
                *limb_args(model, config, elbow_pole_search=False), _LIMB_JOINTS,
                np.zeros(4) if swivel is None else np.asarray(swivel, np.float64),
                model.parents, model.rest_local, model.dof,
                np.ascontiguousarray(model.limits[..., 0]), np.ascontiguousarray(model.limits[..., 1]),
                np.radians(config.pan_search_step_deg), n, config.pan_change_cost, out)
    return out


@njit(cache=True, nogil=True)
def _swivel_search(cues, axes, lengths, poles, arm_lim, foot_rest, limb_joints, parents,
                   rest_local, dof, lo, hi, step, n_steps, prev, change_cost, prior_cost, out):
    J = parents.shape[0]
    R = np.empty((J, 3, 3))
    ang = np.empty((J, 3))
    sw = np.empty(4)
    best = np.full(4, np.inf)
    for k in range(-n_steps, n_steps + 1):
        for i in range(4):
            sw[i] = prev[i] + step * k
        _analytic(cues, axes, lengths, poles, arm_lim, foot_rest, limb_joints, sw, R, NO_VIEWS, 0.0)
        _angles_from_frames(parents, rest_local, dof, R, ang)
        for limb in range(4):
            side = limb % 2
            first = 0 if limb < 2 else 4
            viol = 0.0
            for m in range(first, first + 3):
                viol += joint_violation(ang, lo, hi, dof, limb_joints[side, m])
            cost = np.degrees(viol) + change_cost * abs(np.degrees(step * k)) + prior_cost * abs(np.degrees(sw[limb]))
            if cost < best[limb]:
                best[limb] = cost
                out[limb] = sw[limb]


def refine_swivel(model: BodyModel, cues: np.ndarray, axes: np.ndarray, previous: np.ndarray | None = None,
                  config: AnalyticConfig = AnalyticConfig()) -> np.ndarray:
    """(4,) swivel angles (radians) of the elbows' and knees' poles about their limb lines.

    Around ``previous`` (default 0), within +-``swivel_search_deg``, each limb takes the
    swivel whose pose violates its joints' range-of-motion limits least, plus
    ``swivel_change_cost`` per degree changed and ``swivel_prior_cost`` per degree away
    from the default pole (the paper's fixed elbow-raise / knee-open constants).
    """
    prev = np.zeros(4) if previous is None else np.asarray(previous, dtype=np.float64)
    if config.swivel_search_deg <= 0 or config.swivel_step_deg <= 0:
        return prev.copy()
    out = prev.copy()
    _swivel_search(np.ascontiguousarray(cues, dtype=np.float64), np.ascontiguousarray(axes, dtype=np.float64),
                   *limb_args(model, config, elbow_pole_search=False), _LIMB_JOINTS, model.parents,
                   model.rest_local, model.dof,
                   np.ascontiguousarray(model.limits[..., 0]), np.ascontiguousarray(model.limits[..., 1]),
                   np.radians(config.swivel_step_deg), int(config.swivel_search_deg // config.swivel_step_deg),
                   prev, config.swivel_change_cost, config.swivel_prior_cost, out)
    return out
