"""A fused frame given the labels of an identity alternative (``fusion.identity``): its cues
exchanged and its pose solved again. Stateless, on the solvers given: what the tracker does to
the frame whose identity switches, and ``fusion.offline`` to the frames the switch reaches back to."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from mocap_rt.body.analytic import pan_angle
from mocap_rt.fusion.identity import ALTERNATIVES, swap_pairs
from mocap_rt.fusion.result import FusionResult, joint_validity
from mocap_rt.fusion.solver import PoseSolver
from mocap_rt.names import C_HEAD, C_TORSO


def relabelled(result: FusionResult, k: int, cues_ik: np.ndarray, published: PoseSolver,
               pose: tuple | None = None) -> FusionResult:
    """``result`` with alternative k's labels (index into ALTERNATIVES) on its cues and
    ``cues_ik`` (exchanged already), and ``pose`` = (root, angles, joints, axes, swivel) solved
    on them (None: no pose), its BVH row from the ``published`` solver."""
    out = replace(result, cues_3d=swap_pairs(result.cues_3d, k), cue_valid=swap_pairs(result.cue_valid, k),
                  cues_ik=cues_ik, joint_valid=joint_validity(np.isfinite(cues_ik).all(axis=1)))
    if pose is None:
        return out
    root, angles, joints, axes, swivel = pose
    return replace(out, root_pos=root, angles=angles, joints=joints, bvh_frame=published.bvh_row(root, angles),
                   pan_rad=pan_angle(axes), axes=axes, swivel=swivel)


def with_labels(result: FusionResult, k: int, solver: PoseSolver, published: PoseSolver) -> FusionResult:
    """A past frame's ``result`` with alternative k's labels: its cues exchanged and its pose
    fitted again from its axes (turned by 180 deg for a mirror), as the tracker refits the frame
    that switches; on its silhouettes when it kept them (``solver``'s fitter), solved by
    ``published``."""
    cues_ik = swap_pairs(result.cues_ik, k)
    if result.axes is None or not np.isfinite(cues_ik[[C_HEAD, C_TORSO]]).all():
        return relabelled(result, k, cues_ik, published)
    axes = result.axes * [-1.0, -1.0, 1.0] if ALTERNATIVES[k] == "mirror" else result.axes
    swivel = np.zeros(4)
    targets = result.targets
    if targets is not None and targets.n_views > 0:
        fit = solver.fitter.fit(solver.fill_missing(cues_ik, axes), axes, swivel, targets)
        axes, swivel = fit.axes, fit.swivel
    root, angles, joints = published.solve(cues_ik, axes, swivel, targets)
    return relabelled(result, k, cues_ik, published, (root, angles, joints, axes, swivel))
