"""Per-frame fusion: camera cues -> 3D cues -> body pose, with explicit state.

``BodyTracker.step(frame, cues)`` runs, for one frame, in this order:

1. silhouettes: the views' compact silhouettes prepared for the fit (``body.silhouette``);
2. triangulate: the 2D cues of the cameras present, their left/right labels made to agree
   (``labels.fix_left_right``), triangulated by ``FusionConfig.views`` (``"all"``: every
   view that sees a cue, with reprojection outlier rejection; ``"pair"``: the frontal
   pair of seed digest A.6); then the 3D cues that cannot be what they claim dropped
   (``fusion.cue_checks``);
3. filter: a constant-velocity Kalman filter per cue (``fusion.filter``), gating and coasting;
4. ik: the pan and limb swivels fitted to the silhouettes, the shoe blobs' axes
   (``body.foot_axis``) and the joint limits (``body.fit``), the analytic two-link IK
   (A.5), optionally refined by the improved CCD (B.7) on the 38-DOF model, the published
   pose's trunk hung from the head cue (``fusion.solver.PoseSolver``); then a
   ``FusionResult`` (3D cues, joints, BVH row, timings);
5. identify: the frame's labelling against its alternatives (hands / feet exchanged, the
   body mirrored), switched on clear evidence (``fusion.identity``) for the frames that
   follow. Stages 1-4 are ``fit_frame``, stage 5 ``identify_frame``: the service publishes
   the pose between the two, so the identity (a third of a frame's work, and all of a cold
   start's search round the circle) is not in its latency; a switch shows there from the next
   frame on (it takes several frames of evidence). ``step`` (offline) returns the frame that
   switched refitted with its new labels (``fusion.relabel``).

``predict(frame)`` extrapolates the filter to a coming frame and gives every camera the
predicted 2D cues with Z-buffer visibility and blob radius (A.4), and where the last pose's
head and hands show their centres (``body.visible``).

Settings: ``FusionConfig`` (``fusion.config``).

Bone lengths: ``FusionConfig.bone_lengths`` if given; else a default adult until
``calibration_s`` of cues have been seen, then those of ``fusion.calibration.LengthCalibration``
(``tracker.calibrated`` turns True and ``bvh_skeleton`` changes): the cues' estimate with its
proportions fitted to the silhouettes of those seconds; with ``background_calibration`` (the
service) the estimate first, and the fitted lengths (``bvh_skeleton`` changes again) from the
first frame after the other process's fit is done. The state moves a body whose foot is pitched
at ``FusionConfig.tracking_foot_pitch_deg`` (``solver``), the published pose the subject's
(``published``, ``lengths``): the given lengths, or the fitted ones with their foot at
``FusionConfig.subject_foot_pitch_deg``, the legs reaching as far (``BoneLengths.with_foot_pitch``).
The two fits differ too: the state's keeps the prior toward the cues' estimate, the published
one fits the trunk and arms without it (``calibrate.fit_state_and_published``).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Mapping

import numpy as np

from mocap_rt.body.analytic import body_axes, pan_angle, refine_pan, refine_swivel
from mocap_rt.body.bvh_export import bvh_frame
from mocap_rt.body.foot_axis import axes_only, follow_relabelling, foot_axes
from mocap_rt.body.silhouette import SilhouetteTargets, rig_projection
from mocap_rt.body.skeleton import N_JOINTS, BoneLengths, J
from mocap_rt.body.visible import (CUE_CAPSULES, OFFSET_CAPSULES, SHOE_CAPSULES, part_offsets, part_shapes,
                                  pose_visible_parts, rig_rays, shoe_offsets)
from mocap_rt.cues import CameraCues, CuePrediction
from mocap_rt.fusion.calibration import LengthCalibration, Lengths
from mocap_rt.fusion.config import FusionConfig
from mocap_rt.fusion.filter import CueFilter
from mocap_rt.fusion.identity import (ALTERNATIVE_PAIRS, ALTERNATIVES, IdentityState, decide, feet_told_apart,
                                      frame_costs, hold_limbs, swap_pairs)
from mocap_rt.fusion.result import FusionResult, joint_validity
from mocap_rt.fusion.solver import PoseSolver
from mocap_rt.fusion.labels import fix_left_right
from mocap_rt.fusion.relabel import relabelled, with_labels
from mocap_rt.fusion.cue_checks import (RETURN_S, beyond_reach, blob_areas, pair_area_reference, pair_areas,
                                        reject_duplicates, seen_twice, torso_reach_m)
from mocap_rt.fusion.views import (CUE_RADII_M, RigProjector, cue_pixels, frontal_pair, hands_on_head, head_on_trunk,
                                   near_parallel_from_prior, predict_views, triangulate_cues)
from mocap_rt.geometry.ray_triangulator import RayTriangulator
from mocap_rt.geometry.rig import Rig
from mocap_rt.io.bvh import BvhSkeleton
from mocap_rt.names import C_FOOT_L, C_FOOT_R, C_HEAD, C_TORSO, LR_PAIRS, N_CUES

log = logging.getLogger(__name__)

# cues whose views may be chosen by consensus (the torso's 2D points are silhouette
# centres that disagree across views by design; it keeps the plain drop-worst rejection)
_CONSENSUS_CUES = np.arange(N_CUES) != C_TORSO
# weight of the filter's last estimate in a near-parallel cue's triangulation
# (views.near_parallel_from_prior): the rays keep the directions they measure to within this
# fraction of the estimate's distance
PRIOR_WEIGHT = 0.05
_NO_CUES = np.zeros(N_CUES, dtype=bool)
_HIPS = [J["hip_l"], J["hip_r"]]


class BodyTracker:
    """Stateful fusion for one rig (see the module doc). Not thread-safe."""

    def __init__(self, rig: Rig, config: FusionConfig = FusionConfig(), background_calibration: bool = False) -> None:
        self.rig = rig
        self.config = config
        self.cameras = tuple(rig.cameras)
        self._names = list(rig.names)
        self._index = {n: i for i, n in enumerate(self._names)}
        self._tri = RayTriangulator(self.cameras)
        self._proj = RigProjector(self.cameras)
        self._centers = np.array([c.center for c in self.cameras])
        self._sil_projection = rig_projection(self.cameras)
        self._rays = rig_rays(self.cameras)                 # the visible centres of the predictions
        self.filter = CueFilter(N_CUES, config.filter)
        self.calibration = LengthCalibration(config, background_calibration)
        self.calibrated = config.bone_lengths is not None
        given = config.bone_lengths
        self._set_lengths(given or BoneLengths(), subject_pitch_deg=None if given is None else given.foot_pitch_deg)
        self._right: np.ndarray | None = None
        self._axes: np.ndarray | None = None      # the last frame's body axes
        self._last_pose: tuple[np.ndarray, np.ndarray] | None = None       # the state: the trunk unrefined
        self._published: tuple[np.ndarray, np.ndarray] | None = None       # the last published (root, angles)
        self._hips: np.ndarray | None = None      # the last pose's hips (2, 3), for the legs' crossing
        self._pair: tuple[int, int] | None = None
        self._vel: np.ndarray | None = None
        self._swivel = np.zeros(4)   # elbow/knee pole swivels (analytic.refine_swivel)
        self._held = np.full((N_CUES, 3), np.nan)   # hands/feet last estimated: offsets from the torso, body frame
        self._pair_area = np.full((len(self.cameras), len(LR_PAIRS)), np.nan)   # one limb's blob (m^2) per view
        self.relabelled = 0   # views whose left/right labels fix_left_right swapped so far
        self.identity = IdentityState()
        self._pending = None          # fit_frame -> identify_frame: what the identity scores

    # ------------------------------------------------------------------ model
    def _set_lengths(self, lengths: BoneLengths, published: BoneLengths | None = None,
                     subject_pitch_deg: float | None = None) -> None:
        """The body the state moves (``solver``, of ``lengths``) and the subject's (``published``,
        of ``published``, default ``lengths``), the subject's foot at ``subject_pitch_deg`` (None:
        ``FusionConfig.subject_foot_pitch_deg``)."""
        cfg = self.config
        self.solver = PoseSolver(lengths.with_foot_pitch(cfg.tracking_foot_pitch_deg), cfg)
        pitch = cfg.subject_foot_pitch_deg if subject_pitch_deg is None else subject_pitch_deg
        subject = (lengths if published is None else published).with_foot_pitch(pitch)
        self.published = self.solver if subject == self.solver.lengths else PoseSolver(subject, cfg)
        self._reach = torso_reach_m(subject)

    @property
    def lengths(self) -> BoneLengths:
        """The subject's bone lengths (the published pose's and the BVH's)."""
        return self.published.lengths

    @property
    def bvh_skeleton(self) -> BvhSkeleton:
        """The BVH hierarchy matching ``FusionResult.bvh_frame`` (changes at calibration, and again
        when a background fit hands over its lengths)."""
        return self.published.bvh

    # ------------------------------------------------------------------ 2D -> 3D
    def triangulate(self, uv: np.ndarray, w: np.ndarray, prior: np.ndarray | None = None
                    ) -> tuple[np.ndarray, np.ndarray]:
        """3D cues (6, 3) and the used views (C, 6) from pixels (C, 6, 2) and weights (C, 6); a cue
        whose views' rays meet near parallel takes its place along them from ``prior`` (6, 3), the
        filter's last estimate (``views.near_parallel_from_prior``, ``FusionConfig.min_ray_angle_deg``)."""
        thr = np.full(N_CUES, self.config.max_reproj_px)
        thr[C_TORSO] = self.config.torso_max_reproj_px
        X, used, _ = triangulate_cues(self._tri, self._proj, uv, w, thr,
                                      _CONSENSUS_CUES if self.config.consensus_views else _NO_CUES)
        if not self.config.consensus_views:
            X, used = head_on_trunk(self._tri, self._proj, uv, w, thr, X, used,
                                    self.lengths.trunk_m / 2 + self.lengths.neck_head_m)
        if self.config.views == "pair" and self._pair is not None:
            a, b = self._pair
            wp = np.zeros_like(w)
            wp[[a, b]] = w[[a, b]]
            both = (np.isfinite(uv[[a, b]]).all(-1) & (wp[[a, b]] > 0)).all(axis=0)
            if both.any():
                Xp = self._tri(uv, wp)
                X = np.where(both[:, None], Xp, X)
                used = np.where(both[None, :], wp > 0, used)
        if self.config.min_ray_angle_deg > 0:
            X, used = near_parallel_from_prior(self.cameras, self._proj.centers, uv, w, X, used, prior,
                                               self.config.min_ray_angle_deg, PRIOR_WEIGHT)
        return X, used

    # ------------------------------------------------------------------ body
    def solve_pose(self, cues_ik: np.ndarray, velocity: np.ndarray | None = None,
                   targets: SilhouetteTargets | None = None, feet: np.ndarray | None = None
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Body pose from six 3D cues (6, 3) (head and torso finite), updating the pan state.

        With silhouettes (``targets`` with views) the pan and the limb swivels are fitted to
        them, the shoe axes ``feet`` (6, C, 5) (``foot_axis.foot_axes``, labelled like the cues)
        and the joint limits (``BodyFitter``); without, to the limits alone
        (``refine_pan``, ``refine_swivel``). Returns the tracker's own pose, its trunk unrefined:
        (root (3,), angles (J, 3) radians, joints (J, 3) metres, axes (3, 3)).
        """
        cfg, solver = self.config.analytic, self.solver
        axes = body_axes(cues_ik, self._right, velocity, cfg)
        if targets is not None and targets.n_views > 0:
            res = solver.fitter.fit(solver.fill_missing(cues_ik, axes), axes, self._swivel, targets,
                                    feet=axes_only(feet))
            axes, self._swivel = res.axes, res.swivel
        else:
            if cfg.pan_search_deg > 0:
                axes = refine_pan(solver.model, solver.fill_missing(cues_ik, axes), axes, cfg, self._swivel)
            if cfg.swivel_search_deg > 0:
                self._swivel = refine_swivel(solver.model, solver.fill_missing(cues_ik, axes), axes, self._swivel, cfg)
        self._right = axes[:, 0]
        self._axes = axes
        root, angles, joints = solver.plain(cues_ik, axes, self._swivel, targets, self._held)
        return root, angles, joints, axes

    def _solve_and_keep(self, cues_ik: np.ndarray, targets: SilhouetteTargets | None,
                        feet: np.ndarray | None) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The frame's pose (``solve_pose`` with the smoothed torso velocity), kept as the last
        pose and its hips (the next frame's predictions and identity input); returned, and its
        BVH row kept for the frames without a pose, refined (``PoseSolver.solve``)."""
        root, angles, joints, axes = self.solve_pose(cues_ik, self._vel, targets, feet)
        self._last_pose, self._hips = (root, angles), joints[_HIPS].copy()
        plain = (root, angles, joints) if self.published is self.solver else None
        root, angles, joints = self.published.solve(cues_ik, axes, self._swivel, targets, plain=plain, held=self._held)
        self._published = (root, angles)
        self._held = hold_limbs(self._held, cues_ik, axes)
        return root, angles, joints, axes

    def finish_calibration(self) -> bool:
        """Estimate the bone lengths now from the frames seen so far (e.g. a clip shorter
        than ``calibration_s``); True if the lengths are (now) calibrated."""
        if not self.calibrated:
            self._calibrated_to(self.calibration.finish())
        return self.calibrated

    def _maybe_calibrate(self, X: np.ndarray, axes: np.ndarray | None, cues_ik: np.ndarray | None = None,
                         targets: SilhouetteTargets | None = None) -> None:
        """A frame for the calibration window (``LengthCalibration.add``) until calibrated."""
        if not self.calibrated:
            self._calibrated_to(self.calibration.add(X, axes, cues_ik, targets))

    def _calibrated_to(self, lengths: Lengths | None) -> None:
        if lengths is not None:
            self._set_lengths(*lengths)
            self.calibrated = True

    def _poll_fitted(self) -> None:
        """Take the background fit's lengths once it is done (a failed fit keeps the estimate)."""
        lengths = self.calibration.poll()
        if lengths is not None:
            self._set_lengths(*lengths)

    # ------------------------------------------------------------------ API
    def step(self, frame: int, cues: Mapping[str, CameraCues]) -> FusionResult:
        """Fuse one frame (see the module doc): ``fit_frame`` then ``identify_frame``."""
        return self.identify_frame(self.fit_frame(frame, cues))

    def fit_frame(self, frame: int, cues: Mapping[str, CameraCues]) -> FusionResult:
        """Stages 1-4 of one frame (module doc): the frame's pose, with the labels the earlier
        frames decided. ``identify_frame`` must follow before the next frame (the service
        publishes the pose in between: the identity is off the latency path)."""
        t0 = time.perf_counter()
        self._poll_fitted()
        timings: dict[str, float] = {}
        t_s = frame / self.config.fps
        pred = self.filter.predict_at(t_s)          # (6, 3), NaN for tracks not alive
        cfg = self.config
        resting = hands_on_head(self._proj, pred, np.linalg.norm(self.filter.vel, axis=1), cfg.duplicate_m,
                                cfg.hand_on_head_m, cfg.hand_rest_mps)
        uv, w, kept = cue_pixels(cues, self._index, len(self.cameras), cfg.min_confidence, resting)
        targets = (SilhouetteTargets.from_cues(self.cameras, cues, self._sil_projection)
                   if self.config.silhouettes else None)
        feet = (foot_axes(cues, self._names, w) if targets is not None and self.config.fit.foot_axis_weight > 0
                else None)
        ts = time.perf_counter()
        timings["silhouettes"] = (ts - t0) * 1e3
        if self.config.fix_left_right:
            ref = pred if self.filter.alive.any() else None
            uv0, (uv, w, n_fixed) = uv, fix_left_right(self._tri, self._proj, uv, w, ref)
            self.relabelled += n_fixed
            feet = follow_relabelling(feet, uv0, uv) if (feet is not None and n_fixed) else feet
        X, used = self.triangulate(uv, w, self.filter.estimates())
        X = beyond_reach(X, self._reach)
        valid = np.isfinite(X).all(axis=1)
        X = reject_duplicates(X, valid, used, pred, cfg.duplicate_m)
        areas = pair_areas(self._proj, blob_areas(cues, self._index, w), uv, X)
        returning = ~self.filter.alive | (t_s - self.filter.started_s < RETURN_S)
        seen = np.isfinite(X).all(axis=1)
        X = seen_twice(X, used, returning, areas, self._pair_area, cfg.duplicate_m)
        self.filter.end(seen & ~np.isfinite(X).all(axis=1))      # its track was on the other limb
        self._pair_area = pair_area_reference(self._pair_area, areas, X, cfg.duplicate_m)
        valid = np.isfinite(X).all(axis=1)
        t_id = time.perf_counter()
        timings["triangulate"] = (t_id - ts) * 1e3
        right_before = self._right          # the heading reference this frame's fit starts from
        scored = self._identity_input(X, valid, pred, targets, feet, bool((used & kept).any()))
        t1 = time.perf_counter()
        timings["identify"] = (t1 - t_id) * 1e3
        accepted = self.filter.update(t_s, np.where(valid[:, None], X, np.nan))
        valid &= accepted
        filt = self.filter.estimates()
        measured = np.where(valid[:, None], filt if self.config.use_filtered else X, np.nan)
        cues_ik = np.where(valid[:, None], measured, filt)
        t2 = time.perf_counter()
        timings["filter"] = (t2 - t1) * 1e3
        joints = np.full((N_JOINTS, 3), np.nan)
        joint_valid = np.zeros(N_JOINTS, dtype=bool)
        root, angles, pan, axes = np.full(3, np.nan), np.zeros((N_JOINTS, 3)), float("nan"), None
        have = np.isfinite(cues_ik).all(axis=1)
        if have[C_TORSO] and have[C_HEAD]:
            v = self.filter.vel[C_TORSO]
            a = self.config.velocity_smoothing
            self._vel = v.copy() if self._vel is None else a * self._vel + (1 - a) * v
            root, angles, joints, axes = self._solve_and_keep(cues_ik, targets, feet)
            pan = pan_angle(axes)
            joint_valid = joint_validity(have)
        calib_sample = (np.where(valid[:, None], X, np.nan), axes)
        if scored is None:
            self._maybe_calibrate(*calib_sample)
        t3 = time.perf_counter()
        timings["ik"] = (t3 - t2) * 1e3
        row = (self.published.bvh_row(*self._published) if self._published is not None
               else bvh_frame(self.published.model, np.zeros(3), np.zeros((N_JOINTS, 3))))
        self._update_pair(cues_ik)
        self._pending = None if scored is None else (scored, cues_ik, right_before, calib_sample)
        timings["total"] = (time.perf_counter() - t0) * 1e3
        cams_used = tuple(self._names[c] for c in range(len(self._names)) if used[c].any())
        pair = tuple(self._names[i] for i in self._pair) if (self.config.views == "pair" and self._pair) else ()
        return FusionResult(int(frame), measured, valid, joints, row, cams_used, timings,
                            root, angles, pan, pair, cues_ik, axes, joint_valid, self._swivel.copy(), targets)

    def _identity_input(self, X: np.ndarray, valid: np.ndarray, pred: np.ndarray, targets: SilhouetteTargets | None,
                        feet: np.ndarray | None, hands_on_head: bool = False) -> tuple | None:
        """What the identity scores, taken before the frame changes the state: the cues (6, 3)
        (measured, else the filter's prediction ``pred`` (6, 3)), the previous frame's body axes,
        the silhouettes, the shoe measurements ``feet``, the previous pose's hips and
        ``hands_on_head`` (a hand was measured from a view that found it on the head's blob,
        ``views.hands_on_head``); None when there is nothing to score.
        A body that (re)starts acquires afresh."""
        if not self.filter.alive[[C_HEAD, C_TORSO]].all():
            self.identity.reset()        # the body (re)starts: acquire afresh, heading unknown
            self._axes = None
            self._hips = None
        if not self.config.identity.enabled:
            return None
        cues = np.where(valid[:, None], X, pred)
        if not np.isfinite(cues[[C_HEAD, C_TORSO]]).all():
            return None
        return cues, self._axes, targets, feet, self._hips, hands_on_head

    def identify_frame(self, result: FusionResult) -> FusionResult:
        """Stage 5 of the frame ``fit_frame`` just fitted (``result``, whose timings it adds its
        ``identify`` stage to): its labelling against the alternatives (``fusion.identity``). On
        clear evidence the filter's tracks, the heading and the limb swivels switch, and the
        frame is refitted with the new labels, so the next frame (its prediction first) starts
        from the state it would have had if this frame had been labelled so. Returns ``result``,
        or on a switch the frame refitted with the new labels: what ``step`` (offline) keeps; the
        service has published ``result`` already and shows the switch from the next frame."""
        t0 = time.perf_counter()
        pending, self._pending = self._pending, None
        if pending is not None:
            scored, cues_ik, right_before, (X, axes) = pending
            _, _, targets, feet, _, _ = scored
            k = self._score_identity(*scored)
            X = X if k < 0 else swap_pairs(X, k)
            if k >= 0 and np.isfinite(cues_ik[[C_HEAD, C_TORSO]]).all():
                # refit from the heading reference the frame's fit started from (turned for a
                # mirror; none at a cold start)
                self._right = (None if right_before is None else
                               -right_before if ALTERNATIVES[k] == "mirror" else right_before)
                cues_ik = swap_pairs(cues_ik, k)
                root, angles, joints, axes = self._solve_and_keep(cues_ik, targets,
                                                                  None if feet is None else swap_pairs(feet, k))
                result = relabelled(result, k, cues_ik, self.published,
                                    (root, angles, joints, axes, self._swivel.copy()))
            self._maybe_calibrate(X, axes, cues_ik, targets)      # the bone-length sample, with the labels settled
        ms = (time.perf_counter() - t0) * 1e3
        result.timings_ms["identify"] = result.timings_ms.get("identify", 0.0) + ms
        result.timings_ms["total"] = result.timings_ms.get("total", 0.0) + ms
        return result

    def with_labels(self, result: FusionResult, k: int) -> FusionResult:
        """A past frame's ``result`` with alternative k's labels (``relabel.with_labels``, on
        this tracker's solvers): what ``fusion.offline`` applies to the frames a switch reaches
        back to (``IdentityState.last_switch``)."""
        return with_labels(result, k, self.solver, self.published)

    def _score_identity(self, cues: np.ndarray, prev_axes: np.ndarray | None, targets: SilhouetteTargets | None,
                        feet: np.ndarray | None, hips: np.ndarray | None, hands_on_head: bool = False) -> int:
        """Score the hypotheses on ``cues`` (``_identity_input``); on a switch relabel the
        filter's tracks, turn the heading for a mirror and reset the limb swivels. Returns the
        alternative switched to (index into ALTERNATIVES) or -1 (``identity.frame_costs``, with
        ``hands_on_head``)."""
        cfg = self.config.identity
        acquiring = self.identity.frames < cfg.acquire_frames     # the legs score the facing only then
        costs = frame_costs(self.solver.fitter, cues, self.solver.rest_cues, prev_axes, targets, cfg, feet, hips,
                            acquiring, hands_on_head)
        k = decide(self.identity, costs, cfg)
        self.identity.feet_decided |= feet_told_apart(hips, cues, cfg.feet_together_hips)   # identity module doc
        if k < 0:
            return k
        self._hips = None                # fitted on the labels just found wrong
        for a, b in ALTERNATIVE_PAIRS[k]:
            self.filter.swap(a, b)
        if ALTERNATIVES[k] == "mirror" and self._right is not None:
            self._right = -self._right
            if self._axes is not None:
                self._axes = self._axes * [-1.0, -1.0, 1.0]
        self._swivel = np.zeros(4)
        self._held[:] = np.nan           # held under the labels just found wrong
        log.info("identity: switched to the %s alternative (costs %s)", ALTERNATIVES[k], np.round(costs, 1))
        return k

    def _update_pair(self, cues_ik: np.ndarray) -> None:
        if self.config.views != "pair":
            return
        fwd = None
        if self._right is not None:
            up = np.array([0.0, 0, 1])
            fwd = np.cross(up, self._right)
        pair = frontal_pair(self._centers, cues_ik[C_FOOT_L], cues_ik[C_FOOT_R], cues_ik[C_TORSO], fwd)
        if pair is not None:
            self._pair = pair

    def predict(self, frame: int) -> dict[str, CuePrediction]:
        """Predicted cues of every rig camera for ``frame`` (A.4)."""
        X = self.filter.predict_at(frame / self.config.fps)
        xy, vis, rad = predict_views(self._proj, X, CUE_RADII_M)
        off = shape = [None] * len(self._names)
        if self.config.visible_offsets and self._last_pose is not None:
            # the shoes' shapes (docs/perception.md, Blobs, step 9): once the facing is acquired
            # (while it is open the shoe blobs' legs decide it, and a split shaped by a body
            # facing the wrong way kept it so), and while both feet stand (a moving foot's
            # prediction lags, and a shape centred on it takes the other shoe)
            speed = np.linalg.norm(self.filter.vel[[C_FOOT_L, C_FOOT_R]], axis=1).max()
            shapes = (self.identity.frames >= self.config.identity.acquire_frames
                      and speed < self.config.shoe_shapes_max_speed_mps)
            parts = pose_visible_parts(self.solver.pose_model, *self._last_pose, *self._rays,
                                       CUE_CAPSULES if shapes else OFFSET_CAPSULES)
            off = part_offsets(parts)
            if shapes:
                shape = part_shapes(parts)
                if self.config.shoe_offsets and self._published is not None:
                    # and the shoes' visible centres, on the published feet (pitched as the
                    # subject's; the state's flatter foot puts its trouser leg over too much shoe)
                    pub = pose_visible_parts(self.published.pose_model, *self._published, *self._rays, SHOE_CAPSULES)
                    off = np.where(np.isfinite(off), off, shoe_offsets(pub))
        return {name: CuePrediction(name, int(frame), xy[c], vis[c], rad[c], off[c], shape[c])
                for c, name in enumerate(self._names)}
