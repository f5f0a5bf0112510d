"""Heading and limb swivel fitted to the silhouettes and the joint limits (analysis by synthesis).

Six cue points leave the body's pan and the swivel of each elbow and knee about its
shoulder->hand (hip->foot) line undetermined (seed digest A.5). ``BodyFitter.fit``
chooses them: each candidate is an analytic pose (``analytic._analytic``) scored by

    cost = limit violation (degrees, range-of-motion table; the shoulders as swing and twist,
           ``limb_geometry.joint_violation``)
           + ``silhouette_weight`` * chamfer cost of its capsule body (cm^2, ``body.silhouette``)
           + ``pan_change_cost`` * |pan turned| + per limb ``swivel_change_cost`` * |swivel changed|
           + ``swivel_prior_cost`` * |swivel away from the default pole|   (degrees)
           + ``foot_axis_weight`` * foot-axis cost of its shoes (cm^2, ``body.foot_axis``)

and searched coordinate-wise in numba: the pan over +-``pan_search_deg`` around the
given axes (``pan_step_deg``, then ``pan_refine`` halvings of the step around the best),
then each limb's swivel (of the limbs asked for) over +-``swivel_search_deg`` around its
previous value (the others held). A swivel moves only its own limb, so each swivel candidate poses that
limb alone on the rest of the best pose so far and scores its three capsules on top of the
others' chamfer sums, taken once per limb (``silhouette.add_capsules``): the same costs as
posing and scoring the whole body, at about half the work. The limits act as bounds through
the violation term, which dominates (a degree of violation costs as much as 1 cm^2 of
silhouette disagreement). A mirrored body cannot reach the silhouette's knees and elbows within the limits, which
is what makes ``score`` tell the identity hypotheses apart (``fusion.identity``).

Each candidate's elbows are measured too (``elbow_silhouette``): of the elbow poles turned
about shoulder -> hand (``AnalyticConfig.elbow_pole_candidates``), each arm takes the one of
least shoulder violation + twist + the silhouette distance of its upper arm, elbow and
forearm + ``AnalyticConfig.elbow_turn_cost`` per degree turned from the default pole
("backwards and down", a hanging arm's prior; ``limb_geometry._arm_pole``). Without views
the default pole stays.

``BodyFitter.refine_trunk`` then refines the pose the tracker publishes: the trunk hung from
the head cue (``AnalyticConfig.trunk_from_head``) and tilted forward and sideways to the
silhouettes (``_fit_torso``), kept where it costs less than the plain pose.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np
from numba import njit

from mocap_rt.body.analytic import (_LIMB_JOINTS, NO_VIEWS, AnalyticConfig, _analytic, _angle_from_frames,
                                    _angles_from_frames, limb_args)
from mocap_rt.body.foot_axis import FOOT_CUES, M2_TO_CM2, N_FOOT_COLS, foot_axis_cost
from mocap_rt.body.kinematics import fk_joint, fk_kernel
from mocap_rt.body.limb_geometry import _cross, _frame, _rot_about, joint_violation
from mocap_rt.body.silhouette import CAPSULE_RADII_M, N_CAPSULES, SWIVEL_CAPSULES, SWIVEL_OTHER_CAPSULES, \
    SilhouetteTargets, add_capsules, body_capsules, capsules_cost, new_partial, partial_cost, pose_points, reset_partial
from mocap_rt.body.skeleton import BodyModel
from mocap_rt.names import C_HEAD, C_TORSO
from mocap_rt.studio.body_map import POINT_NAMES


_NO_PARTIAL = np.zeros((1, 2))      # _evaluate without a partial silhouette sum


@dataclass(frozen=True)
class FitConfig:
    """Weights and search ranges of ``BodyFitter`` (degrees; silhouette cost in cm^2)."""

    silhouette_weight: float = 1.0     # per cm^2 of mean squared chamfer distance
    pan_search_deg: float = 30.0
    pan_step_deg: float = 15.0
    pan_refine: int = 2                # then halve the step this many times around the best (+-7.5, +-3.75 deg)
    pan_change_cost: float = 0.05      # per degree of pan turned from the given axes
    swivel_search_deg: float = 30.0
    swivel_step_deg: float = 15.0
    swivel_change_cost: float = 0.05   # per degree changed since the previous frame
    swivel_prior_cost: float = 0.1     # per degree away from the default pole
    foot_axis_weight: float = 1.0      # per cm^2 of shoe axis off the measured blob axes (body.foot_axis)
    elbow_silhouette: bool = True      # each arm's elbow pole chosen with the elbow on the silhouettes (module doc)
    torso_search_m: float = 0.04       # fit_torso (body.calibrate): the torso point moved within +- this forward and up
    torso_step_m: float = 0.02
    torso_refine: int = 1              # then halve the step this many times around the best
    torso_shift_cost: float = 0.1      # per cm the torso point moved from its cue
    refine_trunk: bool = True          # the published pose's trunk hung from the head cue and tilted to the
                                       # silhouettes where that fits them better (refine_trunk, the tracker)
    published_swivel_search_deg: float = 60.0   # the published pose's knees searched again this far around
    published_swivel_prior_cost: float = 0.0    # the state's, at this prior (0 = off; fusion.solver),
    published_arm_search_deg: float = 180.0     # its elbows this far (180: all round) at no change cost, then
    published_swivel_refine: int = 2            # the step halved this many times around the best
    published_pelvis_twist_deg: float = 45.0    # the published pose's pelvis turned to the knees' hinges, at
                                                # most this far (0 = off; body.pelvis, fusion.solver)
    pelvis_twist_prior: float = 0.3             # ... against this weight for no turn (a knee bent 90 deg: 1)

    def __post_init__(self) -> None:
        if not 0.0 <= self.published_pelvis_twist_deg <= 90.0:
            raise ValueError("FitConfig.published_pelvis_twist_deg must be in [0, 90] degrees (0 = off), got "
                             f"{self.published_pelvis_twist_deg}")
        if not self.pelvis_twist_prior >= 0.0:
            raise ValueError(f"FitConfig.pelvis_twist_prior must be >= 0, got {self.pelvis_twist_prior}")


def _search_offsets(search_deg: float, step_deg: float) -> np.ndarray:
    """The offsets (radians, ascending, 0 included) of a search within +-``search_deg`` in steps
    of ``step_deg`` (none but 0 for a step <= 0); a search of 180 deg or more goes all round once:
    -180 deg is +180, which is kept."""
    n = int(search_deg // step_deg) if step_deg > 0 else 0
    k = np.arange(-n, n + 1)
    return np.radians(step_deg * k[k * step_deg > -180.0])


@njit(cache=True, nogil=True)
def _evaluate(cues, axes, swivel, lengths, poles, arm_lim, foot_rest, limb_joints, parents, offsets, rest_local, dof,
              lo, hi, foot_pitch, rad, P, f, grid, dt, dt_off, outline, n_outline, feet, w_sil, w_foot, R, ang, pos,
              rot, points, A, B, jv, limb=-1, part=_NO_PARTIAL, work=_NO_PARTIAL):
    """(limit violation degrees, silhouette cost cm^2, foot-axis cost cm^2) of the analytic pose
    for ``axes``, ``swivel``; a term whose weight is 0 is not computed (0). With a ``limb``
    (0-3, the swivel slot) only that limb is posed anew (R holds the rest of the pose, ``_pose``)
    and its capsules added to ``part``, the partial silhouette sum of the others
    (``silhouette.add_capsules``; ``work`` its scratch copy): what a search that moves one
    limb's swivel pays (``_fit``)."""
    viol = _pose(cues, axes, swivel, lengths, poles, arm_lim, foot_rest, limb_joints, parents, offsets, rest_local,
                 dof, lo, hi, foot_pitch, (P, f, grid, dt, dt_off), w_sil * M2_TO_CM2, w_sil > 0.0 or w_foot > 0.0,
                 R, ang, pos, rot, points, A, B, jv, limb)
    sil = 0.0
    foot = 0.0
    if w_sil > 0.0:
        if limb < 0:
            sil = capsules_cost(A, B, rad, P, f, grid, dt, dt_off, outline, n_outline) * M2_TO_CM2
        else:
            work[:, :] = part
            add_capsules(A, B, rad, SWIVEL_CAPSULES[limb], P, f, grid, dt, dt_off, outline, n_outline, work)
            sil = partial_cost(f, grid, n_outline, work) * M2_TO_CM2
    if w_foot > 0.0:
        foot = foot_axis_cost(points, P, f, feet)
    return viol, sil, foot


@njit(cache=True, nogil=True)
def _pose(cues, axes, swivel, lengths, poles, arm_lim, foot_rest, limb_joints, parents, offsets, rest_local, dof, lo,
          hi, foot_pitch, views, w_elbow, capsules, R, ang, pos, rot, points, A, B, jv, limb=-1):
    """The analytic pose for ``axes``, ``swivel`` in R, ang, jv (each joint's limit violation,
    radians) and, with ``capsules``, its joints, body points and capsules (pos, rot, points, A,
    B); returns its limit violation (degrees). With a ``limb`` (0-3) only that limb's frames,
    angles, violations and joints are written anew (``_analytic``): R, ang, jv, pos and rot must
    hold the rest of the pose (the last pose with ``capsules``, for pos and rot)."""
    pelvis = _analytic(cues, axes, lengths, poles, arm_lim, foot_rest, limb_joints, swivel, R, views, w_elbow, limb)
    # with a limb, its four joints (shoulder to hand, or hip to foot; parents first): the others'
    # frames, hence their angles, violations and joints, are unchanged
    moved = limb_joints[limb % 2, 0:4] if limb < 2 else limb_joints[limb % 2, 4:8]
    F = np.empty((3, 3))
    M = np.empty((3, 3))
    if limb < 0:
        _angles_from_frames(parents, rest_local, dof, R, ang)
        for j in range(1, parents.shape[0]):
            jv[j] = joint_violation(ang, lo, hi, dof, j)
    else:
        for j in moved:
            _angle_from_frames(parents, rest_local, dof, R, ang, j, F, M)
            jv[j] = joint_violation(ang, lo, hi, dof, j)
    viol = 0.0
    for j in range(1, parents.shape[0]):
        viol += jv[j]
    if capsules:
        if limb < 0:
            fk_kernel(parents, offsets, rest_local, pelvis, ang, pos, rot)
        else:
            for j in moved:
                fk_joint(parents, offsets, rest_local, ang, pos, rot, j, M)
        pose_points(pos, rot, foot_pitch, points)
        body_capsules(points, A, B)
    return np.degrees(viol)


@njit(cache=True, nogil=True)
def _scratch(nj):
    """``_evaluate``'s work arrays for a body of nj joints: R, ang, pos, rot, points, A, B, jv."""
    return (np.empty((nj, 3, 3)), np.empty((nj, 3)), np.empty((nj, 3)), np.empty((nj, 3, 3)),
            np.empty((len(POINT_NAMES), 3)), np.empty((N_CAPSULES, 3)), np.empty((N_CAPSULES, 3)), np.zeros(nj))


@njit(cache=True, nogil=True)
def _fit(cues, axes0, swivel_prev, lengths, poles, arm_lim, foot_rest, limb_joints, parents, offsets, rest_local, dof,
         lo, hi, foot_pitch, rad, P, f, grid, dt, dt_off, outline, n_outline, feet, w, pan_offsets, n_refine, sw_offsets,
         sw_limbs, out_axes, out_swivel, out_terms):
    """Coordinate search (see the module doc); writes the best axes (3, 3), swivel (4,)
    and terms (total, violation, silhouette, foot axis) into the ``out_*`` arrays."""
    R, ang, pos, rot, points, A, B, jv = _scratch(parents.shape[0])
    axc = np.empty((3, 3))
    up = axes0[:, 2].copy()
    right0 = axes0[:, 0].copy()
    sw = swivel_prev.copy()
    w_sil, c_pan, c_change, c_prior, w_foot = w[0], w[1], w[2], w[3], w[4]
    base = 0.0
    for i in range(4):
        base += c_prior * abs(np.degrees(sw[i]))
    best = np.inf
    best_a = 0.0
    # the offsets, then n_refine times the best +- half the previous spacing
    step = abs(pan_offsets[1] - pan_offsets[0]) if pan_offsets.shape[0] > 1 else 0.0
    cands = pan_offsets.copy()
    for it in range(n_refine + 1):
        if it > 0:
            step *= 0.5
            cands = np.array([best_a - step, best_a + step])
        for k in range(cands.shape[0]):
            a = cands[k]
            r = _rot_about(up, a, right0)
            fw = _cross(up, r)
            for i in range(3):
                axc[i, 0], axc[i, 1], axc[i, 2] = r[i], fw[i], up[i]
            viol, sil, foot = _evaluate(cues, axc, sw, lengths, poles, arm_lim, foot_rest, limb_joints, parents,
                                        offsets, rest_local, dof, lo, hi, foot_pitch, rad, P, f, grid, dt, dt_off,
                                        outline, n_outline, feet, w_sil, w_foot, R, ang, pos, rot, points, A, B, jv)
            cost = viol + w_sil * sil + w_foot * foot + c_pan * abs(np.degrees(a)) + base
            if cost < best:
                best = cost
                best_a = a
                out_axes[:, :] = axc
                out_terms[0], out_terms[1], out_terms[2], out_terms[3] = cost, viol, sil, foot
    pan_cost = best - out_terms[1] - w_sil * out_terms[2] - w_foot * out_terms[3] - base
    out_swivel[:] = sw
    if sw_offsets.shape[0] == 0:
        return
    # a limb's swivel moves only that limb: each candidate poses only its limb anew (R holds the
    # best pose so far) and adds its capsules to the other capsules' silhouette sums, taken once
    # per limb
    part = new_partial(P.shape[0], outline.shape[1])
    work = np.empty_like(part)
    last = -1                   # the limb searched last (-1: none yet, the whole pose is posed anew)
    for limb in range(4):
        if not sw_limbs[limb]:
            continue
        # the best pose so far: the pan's whole, then only the limb just searched comes back to its best
        _pose(cues, out_axes, out_swivel, lengths, poles, arm_lim, foot_rest, limb_joints, parents, offsets,
              rest_local, dof, lo, hi, foot_pitch, (P, f, grid, dt, dt_off), w_sil * M2_TO_CM2,
              w_sil > 0.0 or w_foot > 0.0, R, ang, pos, rot, points, A, B, jv, last)
        last = limb
        if w_sil > 0.0:
            reset_partial(part)
            add_capsules(A, B, rad, SWIVEL_OTHER_CAPSULES[limb], P, f, grid, dt, dt_off, outline, n_outline, part)
        for k in range(sw_offsets.shape[0]):
            sw[:] = out_swivel
            sw[limb] = swivel_prev[limb] + sw_offsets[k]
            viol, sil, foot = _evaluate(cues, out_axes, sw, lengths, poles, arm_lim, foot_rest, limb_joints, parents,
                                        offsets, rest_local, dof, lo, hi, foot_pitch, rad, P, f, grid, dt, dt_off,
                                        outline, n_outline, feet, w_sil, w_foot, R, ang, pos, rot, points, A, B, jv,
                                        limb, part, work)
            cost = viol + w_sil * sil + w_foot * foot + pan_cost
            for i in range(4):
                cost += c_prior * abs(np.degrees(sw[i])) + c_change * abs(np.degrees(sw[i] - swivel_prev[i]))
            if cost < best:
                best = cost
                out_swivel[limb] = sw[limb]
                out_terms[0], out_terms[1], out_terms[2], out_terms[3] = cost, viol, sil, foot


@njit(cache=True, nogil=True)
def _fit_torso(cues, axes0, swivel, lengths, poles, arm_lim, foot_rest, limb_joints, parents, offsets, rest_local, dof,
               lo, hi, foot_pitch, rad, P, f, grid, dt, dt_off, outline, n_outline, w, n_steps, step, n_refine,
               out_torso, out_axes):
    """The torso point moved forward then up (``axes0``'s columns; the trunk's up axis turned
    to keep pointing at the head cue) by k * ``step`` (0 < |k| <= n_steps), then ``n_refine``
    halvings around the best, at the cost of ``_fit``'s limit and silhouette terms + w[1] per cm
    moved; writes the best torso point (3,) and axes (3, 3) and returns its cost. With the trunk
    hung from the head (``lengths[10]``, ``AnalyticConfig.trunk_from_head``) a move up would
    change nothing: it moves forward then right, tilting the trunk about the head."""
    R, ang, pos, rot, points, A, B, jv = _scratch(parents.shape[0])
    c = cues.copy()
    axc = np.empty((3, 3))
    torso0 = cues[C_TORSO].copy()
    right0 = axes0[:, 0].copy()
    second = 0 if lengths[10] > 0.0 else 2          # the second move's axis: right, or up
    shift = np.zeros(2)
    best = np.inf
    for it in range(n_refine + 1):
        st = step * 0.5 ** it
        n = n_steps if it == 0 else 1
        for d in range(2):
            start = shift[d]
            for k in range(-n, n + 1):
                if k == 0 and best < np.inf:      # the current point, scored already
                    continue
                trial = shift.copy()
                trial[d] = start + k * st
                for i in range(3):
                    c[C_TORSO, i] = torso0[i] + trial[0] * axes0[i, 1] + trial[1] * axes0[i, second]
                _frame(cues[C_HEAD] - c[C_TORSO], right0, axc)     # (right, forward, up): Z up to the head
                viol, sil, _ = _evaluate(c, axc, swivel, lengths, poles, arm_lim, foot_rest, limb_joints, parents,
                                         offsets, rest_local, dof, lo, hi, foot_pitch, rad, P, f, grid, dt, dt_off,
                                         outline, n_outline, _NO_FEET, w[0], 0.0, R, ang, pos, rot, points, A, B, jv)
                cost = viol + w[0] * sil + w[1] * 100.0 * np.sqrt(trial[0] ** 2 + trial[1] ** 2)
                if cost < best:
                    best = cost
                    shift[:] = trial
                    out_torso[:] = c[C_TORSO]
                    out_axes[:, :] = axc
    return best


@njit(cache=True, nogil=True)
def _pose_cost(cues, axes, swivel, lengths, poles, arm_lim, foot_rest, limb_joints, parents, offsets, rest_local, dof,
               lo, hi, foot_pitch, rad, P, f, grid, dt, dt_off, outline, n_outline, w_sil):
    """Limit violation + ``w_sil`` * silhouette cost of one analytic pose (``_fit_torso``'s terms
    without the shift)."""
    R, ang, pos, rot, points, A, B, jv = _scratch(parents.shape[0])
    viol, sil, _ = _evaluate(cues, axes, swivel, lengths, poles, arm_lim, foot_rest, limb_joints, parents, offsets,
                             rest_local, dof, lo, hi, foot_pitch, rad, P, f, grid, dt, dt_off, outline, n_outline,
                             _NO_FEET, w_sil, 0.0, R, ang, pos, rot, points, A, B, jv)
    return viol + w_sil * sil


@dataclass(frozen=True)
class FitResult:
    """axes (3, 3) columns right, forward, up; swivel (4,) radians (arm_l, arm_r, leg_l,
    leg_r); cost, violation_deg, silhouette_cm2, foot_axis_cm2 the terms of the chosen
    candidate (foot_axis_cm2 unweighted, 0 without measured axes)."""

    axes: np.ndarray
    swivel: np.ndarray
    cost: float
    violation_deg: float
    silhouette_cm2: float
    foot_axis_cm2: float = 0.0


class BodyFitter:
    """Pan and swivel search of one body model (see the module doc)."""

    def __init__(self, model: BodyModel, analytic: AnalyticConfig = AnalyticConfig(),
                 config: FitConfig = FitConfig()) -> None:
        if model.preset != "paper":
            raise ValueError("BodyFitter works on the analytic ('paper') model")
        self.config = config
        # lengths, poles (searched with the elbow on the silhouettes, or the fixed pole), arm limits,
        # foot rest direction (analytic.limb_args), then the model's arrays; without views the fixed pole
        model_arrays = (_LIMB_JOINTS, model.parents, model.offsets, model.rest_local, model.dof,
                        np.ascontiguousarray(model.limits[..., 0]), np.ascontiguousarray(model.limits[..., 1]),
                        float(np.radians(model.lengths.foot_pitch_deg)), CAPSULE_RADII_M)
        self._fixed_args = (*limb_args(model, analytic, elbow_pole_search=False), *model_arrays)
        self._model_args = (*limb_args(model, analytic, elbow_pole_search=config.elbow_silhouette), *model_arrays)
        self.hung = replace(analytic, trunk_from_head=True)        # refine_trunk's poses
        self._hung_args = (*limb_args(model, self.hung, elbow_pole_search=config.elbow_silhouette), *model_arrays)

    def fit(self, cues: np.ndarray, axes: np.ndarray, swivel: np.ndarray | None,
            targets: SilhouetteTargets | None, search_swivel: bool = True, pan_search_deg: float | None = None,
            pan_step_deg: float | None = None, pan_refine: int | None = None,
            feet: np.ndarray | None = None, measured_elbows: bool = True, swivel_search_deg: float | None = None,
            swivel_step_deg: float | None = None, swivel_limbs: Sequence[bool] | None = None) -> FitResult:
        """Best pan and swivels for cues (6, 3) (all finite, metres, world) from ``axes``
        (3, 3) and the previous ``swivel`` (4,) radians; ``targets`` None = limits only.
        The pan is searched within +-``pan_search_deg`` in steps of ``pan_step_deg``, then
        refined ``pan_refine`` times; each limb's swivel within +-``swivel_search_deg`` in steps of
        ``swivel_step_deg`` (defaults: the config's; a search of 180 deg goes all round), of the limbs that
        ``swivel_limbs`` (4 bools: arm_l, arm_r, leg_l, leg_r; default all) names. ``feet`` (6, C, N_FOOT_COLS): the
        measured shoe axes of ``targets``' cameras labelled like ``cues``
        (``foot_axis.foot_axes``); used with ``targets`` only (they carry the projection).
        ``measured_elbows`` False: the fixed elbow pole even with views (``elbow_silhouette``)."""
        c = self.config
        pan_deg = c.pan_search_deg if pan_search_deg is None else pan_search_deg
        step = c.pan_step_deg if pan_step_deg is None else pan_step_deg
        offsets = _search_offsets(pan_deg, step)
        out_axes, out_sw, terms = np.empty((3, 3)), np.zeros(4), np.zeros(4)
        have = targets is not None and targets.n_views > 0
        use_feet = targets is not None and feet is not None and c.foot_axis_weight > 0
        sil_args = targets.args() if (have or use_feet) else _NO_VIEWS
        if use_feet and np.shape(feet) != (len(cues), targets.P.shape[0], N_FOOT_COLS):
            raise ValueError(f"feet must be (cues, cameras, {N_FOOT_COLS}) = ({len(cues)}, {targets.P.shape[0]}, "
                             f"{N_FOOT_COLS}), got {np.shape(feet)}")
        feet2 = np.ascontiguousarray(feet[list(FOOT_CUES)], np.float64) if use_feet else _NO_FEET
        w = np.array([c.silhouette_weight if have else 0.0, c.pan_change_cost, c.swivel_change_cost,
                      c.swivel_prior_cost, c.foot_axis_weight if use_feet else 0.0])
        sw_deg = c.swivel_search_deg if swivel_search_deg is None else swivel_search_deg
        sw_step = c.swivel_step_deg if swivel_step_deg is None else swivel_step_deg
        sw_offsets = _search_offsets(sw_deg, sw_step if search_swivel else 0.0)
        sw_offsets = sw_offsets[sw_offsets != 0.0]
        sw_limbs = np.ones(4, np.bool_) if swivel_limbs is None else np.asarray(swivel_limbs, np.bool_)
        sw0 = np.zeros(4) if swivel is None else np.asarray(swivel, np.float64)
        model_args = self._model_args if (have and measured_elbows) else self._fixed_args
        _fit(np.ascontiguousarray(cues, np.float64), np.ascontiguousarray(axes, np.float64), sw0, *model_args,
             *sil_args, feet2, w, offsets,
             c.pan_refine if pan_refine is None else pan_refine, sw_offsets, sw_limbs, out_axes, out_sw,
             terms)
        return FitResult(out_axes, out_sw, float(terms[0]), float(terms[1]), float(terms[2]), float(terms[3]))

    def fit_torso(self, cues: np.ndarray, axes: np.ndarray, swivel: np.ndarray,
                  targets: SilhouetteTargets) -> tuple[np.ndarray, np.ndarray, float]:
        """The torso point (3,) and body axes (3, 3) that fit ``targets`` best near the torso
        cue, the trunk's up axis kept on the head cue (``_fit_torso``), and their cost (limit
        violation + silhouette + ``torso_shift_cost``); cues (6, 3) all finite, ``axes`` and
        ``swivel`` as ``fit`` chose them. What ``body.calibrate`` scores a subject's
        proportions with."""
        return self._torso_search(np.ascontiguousarray(cues, np.float64), np.ascontiguousarray(axes, np.float64),
                                  np.asarray(swivel, np.float64), self._model_args, targets)

    def _torso_search(self, cues: np.ndarray, axes: np.ndarray, swivel: np.ndarray, model_args: tuple,
                      targets: SilhouetteTargets) -> tuple[np.ndarray, np.ndarray, float]:
        """``_fit_torso`` under this config's search (the plain body's or the hung one's
        ``model_args``): (torso point (3,), axes (3, 3), cost)."""
        c = self.config
        n = int(round(c.torso_search_m / c.torso_step_m)) if c.torso_step_m > 0 else 0
        torso, out_axes = np.empty(3), np.empty((3, 3))
        cost = _fit_torso(cues, axes, swivel, *model_args, *targets.args(),
                          np.array([c.silhouette_weight, c.torso_shift_cost]), n, c.torso_step_m, c.torso_refine,
                          torso, out_axes)
        return torso, out_axes, float(cost)

    def refine_trunk(self, cues: np.ndarray, axes: np.ndarray, swivel: np.ndarray | None,
                     targets: SilhouetteTargets | None) -> tuple[np.ndarray, np.ndarray] | None:
        """The trunk hung from the head cue and tilted to ``targets``: (cues (6, 3) with the
        torso point moved, axes (3, 3)) to pose with ``analytic_pose(..., self.hung, ...)``, when
        that pose costs less (limit violation + silhouette + ``torso_shift_cost``) than the plain
        pose of ``cues``, ``axes`` (limits and silhouette); None when it does not or there is
        nothing to see. cues all finite; ``axes``, ``swivel`` as ``fit`` chose them (None: 0).

        The head cue is 2 mm off the head joint at the median, while the torso cue is the trunk's
        visible centre, 4-5 cm off its joint and jittering 6-27 mm a frame along the trunk; hung
        from the head, the trunk takes its height from the head and its tilt from the
        silhouettes, which the torso cue's line only starts (docs/body.md, "The published
        trunk hung from the head"). Where the spine bends, the plain pose fits better and stays.
        """
        if targets is None or targets.n_views == 0:
            return None
        cues = np.ascontiguousarray(cues, np.float64)
        axes = np.ascontiguousarray(axes, np.float64)
        swivel = np.zeros(4) if swivel is None else np.asarray(swivel, np.float64)
        plain = _pose_cost(cues, axes, swivel, *self._model_args, *targets.args(), self.config.silhouette_weight)
        torso, hung_axes, cost = self._torso_search(cues, axes, swivel, self._hung_args, targets)
        if not cost < plain:
            return None
        out = cues.copy()
        out[C_TORSO] = torso
        return out, hung_axes

    def elbow_views(self, targets: SilhouetteTargets | None) -> tuple:
        """``analytic_pose``'s (views, w_elbow) that measure the elbows on ``targets`` as this
        fitter scores them (``elbow_silhouette``), or () for the fixed pole."""
        if not (self.config.elbow_silhouette and targets is not None and targets.n_views > 0):
            return ()
        return targets.args()[:5], self.config.silhouette_weight * M2_TO_CM2


_NO_FEET = np.zeros((2, 1, N_FOOT_COLS))
_NO_VIEWS = (*NO_VIEWS, np.zeros((1, 1, 2)), np.zeros(1, np.int64))    # + outline, n_outline
