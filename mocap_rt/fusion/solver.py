"""The body of one subject: bone lengths -> models, and 3D cues + body axes -> pose.

``PoseSolver`` is stateless: given the frame's cues (6, 3), the body axes and the limb
swivels it solves the analytic two-link pose (seed digest A.5), optionally refined by the
improved CCD (B.7) on the 38-DOF model. The tracker (``fusion.tracker``) owns the state
(heading, swivels, filter) and builds a new solver when the bone lengths change.

The published pose (``solve``) is refined beyond the state's, in two steps that only the
silhouettes decide, so that perception, the identity and the calibration, which work on the
state, are unchanged by them:

1. the knee swivels searched again, ``FitConfig.published_swivel_search_deg`` around the
   state's at ``published_swivel_prior_cost`` a degree away from the default pole; then the
   elbow swivels, ``published_arm_search_deg`` (all round) on the silhouettes and limits alone;
   then every swivel refined by ``published_swivel_refine`` halvings of the step around the
   best, on the silhouettes and limits alone. The state's search keeps its narrower range and
   its prior (0.1 a degree), which hold the identity: a weaker prior there flipped clips and
   lost cues (docs/body.md, "The swivels' prior"). The knees keep the narrower search and its
   change cost: all four limbs searched all round mirrored more of the suite's frames (docs/body.md,
   "Experiments of the thirty-third stop"), the elbows alone fewer ("The published elbows searched
   all round");
2. the trunk hung from the head cue and tilted to the silhouettes (``BodyFitter.refine_trunk``)
   where that fits them better;
3. the pelvis turned about the spine to where the knees' hinges point (``body.pelvis``, at most
   ``FitConfig.published_pelvis_twist_deg``; with views, which placed the knees): the model's trunk
   is rigid, a person's pelvis turns against the shoulders.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from mocap_rt.body.analytic import analytic_pose
from mocap_rt.body.bvh_export import bvh_frame, bvh_skeleton
from mocap_rt.body.ccd import solve_ccd
from mocap_rt.body.fit import BodyFitter
from mocap_rt.body.kinematics import forward_kinematics
from mocap_rt.body.pelvis import twist_pelvis
from mocap_rt.body.silhouette import SilhouetteTargets
from mocap_rt.body.skeleton import END_EFFECTORS, BoneLengths, J, body_model
from mocap_rt.fusion.config import FusionConfig
from mocap_rt.fusion.identity import fill_missing
from mocap_rt.names import C_TORSO, CUE_INDEX, CUE_JOINT_INDEX

_EFFECTOR_CUES = np.array([CUE_INDEX[n] for n in END_EFFECTORS])
_EFFECTOR_JOINTS = np.array([J[n] for n in END_EFFECTORS])
_ARMS, _LEGS = (True, True, False, False), (False, False, True, True)       # swivel slots searched

Pose = tuple[np.ndarray, np.ndarray, np.ndarray]       # root (3,), angles (J, 3) rad, joints (J, 3) m


class PoseSolver:
    """Models, rest cues, the silhouette fitter and the pose solve for one set of bone lengths."""

    def __init__(self, lengths: BoneLengths, config: FusionConfig) -> None:
        self.lengths = lengths
        self.config = config
        self.model = body_model(lengths, "paper")
        self.model_full = body_model(lengths, "full")
        self.bvh = bvh_skeleton(self.model)
        self.rest_cues = self.model.rest_positions()[list(CUE_JOINT_INDEX)]
        self.rest_cues[C_TORSO, 2] += lengths.torso_cue_up_m      # the cue, not the joint (rest: Z up)
        self.fitter = BodyFitter(self.model, config.analytic, config.fit)
        fit = config.fit
        self._swivel_fitter = (BodyFitter(self.model, config.analytic, replace(
            fit, swivel_search_deg=fit.published_swivel_search_deg, swivel_prior_cost=fit.published_swivel_prior_cost))
            if fit.published_swivel_search_deg > 0 else None)
        self._swivel_refiner = (BodyFitter(self.model, config.analytic, replace(
            fit, swivel_prior_cost=0.0, swivel_change_cost=0.0))
            if fit.published_swivel_search_deg > 0 or fit.published_arm_search_deg > 0 else None)

    @property
    def pose_model(self):
        """The model the poses' angles are of (CCD refines on the full one)."""
        return self.model_full if self.config.ik == "ccd" else self.model

    def fill_missing(self, cues_ik: np.ndarray, axes: np.ndarray, held: np.ndarray | None = None) -> np.ndarray:
        """Cues (6, 3) with missing hands/feet put where ``held`` (6, 3) holds them (offsets from
        the torso cue in the body frame, NaN = none: the tracker's last estimates), else at the
        rest pose (arms hanging, legs straight), placed with the body axes at the torso
        (``identity.fill_missing``)."""
        rest = self.rest_cues
        if held is not None:
            rest = np.where(np.isfinite(held), rest[C_TORSO] + held, rest)
        return fill_missing(cues_ik, axes, rest)

    def solve(self, cues_ik: np.ndarray, axes: np.ndarray, swivel: np.ndarray | None = None,
              targets: SilhouetteTargets | None = None, plain: Pose | None = None,
              held: np.ndarray | None = None) -> Pose:
        """The published pose for given body axes and the state's ``swivel`` (module doc): the
        swivels searched again and the trunk refined (``hung``) where that fits the silhouettes
        better, else the plain pose (``plain`` if given: the plain pose of ``swivel``, solved
        already); then its pelvis turned to the knees (``twisted``). Missing hand/foot cues (NaN
        rows) are filled from ``held`` (``fill_missing``); with ``targets`` (views) the elbows are
        chosen on the silhouettes as the fit chose them (``FitConfig.elbow_silhouette``)."""
        searched = self.published_swivel(cues_ik, axes, swivel, targets, held)
        if searched is not None:
            swivel, plain = searched, None
        pose = self.hung(cues_ik, axes, swivel, targets, held)
        if pose is None:
            pose = plain if plain is not None else self.plain(cues_ik, axes, swivel, targets, held)
        return self.twisted(pose, targets)

    def twisted(self, pose: Pose, targets: SilhouetteTargets | None) -> Pose:
        """``pose`` with its pelvis turned to the knees' hinges (module doc, step 3; ``body.pelvis``):
        with views only, where the silhouettes placed the knees."""
        fit = self.config.fit
        if fit.published_pelvis_twist_deg <= 0 or targets is None or targets.n_views == 0:
            return pose
        root, angles, _ = pose
        angles, _ = twist_pelvis(self.pose_model, root, angles, fit.pelvis_twist_prior, fit.published_pelvis_twist_deg)
        return root, angles, forward_kinematics(self.pose_model, root, angles)[0]

    def published_swivel(self, cues_ik: np.ndarray, axes: np.ndarray, swivel: np.ndarray | None,
                         targets: SilhouetteTargets | None, held: np.ndarray | None = None) -> np.ndarray | None:
        """The swivels (4,) searched again around ``swivel`` on the silhouettes, then refined
        (module doc, step 1), the pan kept; None without views, a missing trunk cue or both
        searches off."""
        if self._swivel_refiner is None or targets is None or targets.n_views == 0:
            return None
        full = self.fill_missing(cues_ik, axes, held)
        if not np.isfinite(full).all():
            return None
        fit = self.config.fit
        sw = swivel
        if self._swivel_fitter is not None:
            sw = self._swivel_fitter.fit(full, axes, sw, targets, pan_search_deg=0.0, pan_refine=0,
                                         swivel_limbs=_LEGS).swivel
        if fit.published_arm_search_deg > 0:
            sw = self._swivel_refiner.fit(full, axes, sw, targets, pan_search_deg=0.0, pan_refine=0,
                                          swivel_search_deg=fit.published_arm_search_deg, swivel_limbs=_ARMS).swivel
        step = fit.swivel_step_deg
        for _ in range(fit.published_swivel_refine):
            step /= 2
            sw = self._swivel_refiner.fit(full, axes, sw, targets, pan_search_deg=0.0, pan_refine=0,
                                          swivel_search_deg=step, swivel_step_deg=step).swivel
        return sw

    def plain(self, cues_ik: np.ndarray, axes: np.ndarray, swivel: np.ndarray | None,
              targets: SilhouetteTargets | None, held: np.ndarray | None = None) -> Pose:
        """The pose with the trunk from the torso cue: the tracker's state."""
        return self._pose(self.fill_missing(cues_ik, axes, held), axes, swivel, targets, self.config.analytic)

    def hung(self, cues_ik: np.ndarray, axes: np.ndarray, swivel: np.ndarray | None,
             targets: SilhouetteTargets | None, held: np.ndarray | None = None) -> Pose | None:
        """The pose with its trunk hung from the head cue and tilted to the silhouettes, where
        that fits them better (``FitConfig.refine_trunk``, ``BodyFitter.refine_trunk``); else None."""
        if not self.config.fit.refine_trunk:
            return None
        full = self.fill_missing(cues_ik, axes, held)
        hung = self.fitter.refine_trunk(full, axes, swivel, targets) if np.isfinite(full).all() else None
        return None if hung is None else self._pose(*hung, swivel, targets, self.fitter.hung)

    def _pose(self, cues_ik: np.ndarray, axes: np.ndarray, swivel: np.ndarray | None,
              targets: SilhouetteTargets | None, config) -> Pose:
        """(root, angles, joints) of the analytic pose of the cues (6, 3, all finite) under
        ``config`` (then CCD with ``ik`` "ccd")."""
        root, angles = analytic_pose(self.model, cues_ik, axes, config, swivel, *self.fitter.elbow_views(targets))
        if self.config.ik == "ccd":
            angles = solve_ccd(self.model_full, root, angles, _EFFECTOR_JOINTS, cues_ik[_EFFECTOR_CUES],
                               reference=angles, config=self.config.ccd).angles
        joints = forward_kinematics(self.pose_model, root, angles)[0]
        return root, angles, joints

    def bvh_row(self, root: np.ndarray, angles: np.ndarray) -> np.ndarray:
        """BVH motion row of a pose of this model (both presets share the hierarchy)."""
        return bvh_frame(self.pose_model, root, angles)
