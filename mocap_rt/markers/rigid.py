"""Rigid preprocessing of a segment's markers (seed digest C, step A) and marker choice (step D).

Skin and cloth make a segment's markers slide, so the k markers of one segment over F
frames are not a rigid body.  We find a noise-free template Z (k, 3) and per frame a
similarity (c_i, R_i, t_i) minimising

    F(Z, c, R, t) = sum_i sum_j w_ij || x_ij - (c_i R_i z_j + t_i) ||^2      (digest C eq. 1)

by generalised Procrustes analysis: absolute orientation per frame (Umeyama 1991, SVD
with the reflection fix; Arun et al. 1987 for the rigid case) alternated with the
closed-form template update.  w_ij = 0 where a marker is missing (NaN), so gaps are
tolerated: a frame keeps a pose while >= 3 of its markers are seen, and the corrected
markers c_i R_i z_j + t_i then fill that frame's gaps.

Frames: the template lives in the segment's local frame; p_world = c R p_local + t.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

log = logging.getLogger(__name__)

MIN_MARKERS_FOR_POSE = 3
GPA_MAX_ITER = 50
GPA_REL_TOL = 1e-7  # relative decrease of the objective that ends the alternation
MIN_OFF_LINE_FRAC = 0.15  # step D: third marker's distance from the line of the first two, / their distance


def absolute_orientation(target: np.ndarray, source: np.ndarray, weights: np.ndarray | None = None,
                         similarity: bool = False) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per-frame least-squares similarity/rigid transform taking ``source`` onto ``target``.

    Minimises sum_j w_j || target_j - (c R source_j + t) ||^2 (Umeyama 1991, with
    det(R) = +1 enforced: the reflection fix).

    target : (F, k, 3) or (k, 3) float64 points; NaN rows count as missing.
    source : (F, k, 3) or (k, 3) float64 points (e.g. a template), same units.
    weights : (F, k) or (k,) non-negative, or None for 1 where both points are finite.
    similarity : estimate the scale c; otherwise c = 1 (rigid).
    Returns c (F,), R (F, 3, 3), t (F, 3); NaN for frames with < 3 usable points
    (or, with weights, zero total weight).  For (k, 3) inputs F = 1.
    """
    tgt = np.asarray(target, dtype=np.float64)
    src = np.asarray(source, dtype=np.float64)
    if tgt.ndim == 2:
        tgt = tgt[None]
    n_frames = max(tgt.shape[0], src.shape[0] if src.ndim == 3 else 1)
    tgt = np.broadcast_to(tgt, (n_frames,) + tgt.shape[1:])
    src = np.broadcast_to(src, tgt.shape)
    if tgt.shape[-1] != 3:
        raise ValueError(f"points must be (..., k, 3), got target {tgt.shape}, source {src.shape}")
    valid = np.all(np.isfinite(tgt), axis=2) & np.all(np.isfinite(src), axis=2)  # (F, k)
    w = valid.astype(np.float64)
    if weights is not None:
        w = w * np.broadcast_to(np.asarray(weights, dtype=np.float64), w.shape)
    x = np.where(valid[..., None], src, 0.0)  # (F, k, 3)
    y = np.where(valid[..., None], tgt, 0.0)
    wsum = w.sum(axis=1)  # (F,)
    ok = (valid.sum(axis=1) >= MIN_MARKERS_FOR_POSE) & (wsum > 0)
    wn = w / np.where(wsum > 0, wsum, 1.0)[:, None]  # (F, k) normalised weights
    mu_x = np.matmul(wn[:, None, :], x)[:, 0]  # (F, 3)
    mu_y = np.matmul(wn[:, None, :], y)[:, 0]
    xc = x - mu_x[:, None]
    yc = y - mu_y[:, None]
    cov = np.matmul((yc * wn[..., None]).transpose(0, 2, 1), xc)  # (F, 3, 3) Sigma_xy of Umeyama eq. 38
    u, d, vt = np.linalg.svd(cov)
    sign = np.sign(np.linalg.det(u) * np.linalg.det(vt))
    sign[sign == 0] = 1.0
    s = np.ones((n_frames, 3))
    s[:, 2] = sign  # reflection fix: S = diag(1, 1, det(U) det(V))
    rot = np.matmul(u * s[:, None, :], vt)
    if similarity:
        var_x = np.sum(wn * np.sum(xc * xc, axis=2), axis=1)
        scale = np.sum(d * s, axis=1) / np.where(var_x > 0, var_x, np.nan)
    else:
        scale = np.ones(n_frames)
    trans = mu_y - scale[:, None] * np.matmul(rot, mu_x[..., None])[..., 0]
    scale = np.where(ok, scale, np.nan)
    rot[~ok] = np.nan
    trans[~ok] = np.nan
    return scale, rot, trans


def apply_pose(scale: np.ndarray, rot: np.ndarray, trans: np.ndarray, local: np.ndarray) -> np.ndarray:
    """World points c_i R_i p + t_i.  local (k, 3) or (F, k, 3) -> (F, k, 3)."""
    local = np.asarray(local, dtype=np.float64)
    # (F, k, 3) = local @ R^T per frame
    return scale[:, None, None] * np.matmul(local, rot.transpose(0, 2, 1)) + trans[:, None, :]


def to_local(scale: np.ndarray, rot: np.ndarray, trans: np.ndarray, world: np.ndarray) -> np.ndarray:
    """Inverse of :func:`apply_pose`: (F, k, 3) world points -> (F, k, 3) local points."""
    return np.matmul(world - trans[:, None, :], rot) / scale[:, None, None]


@dataclass(frozen=True)
class RigidFit:
    """Result of :func:`fit_rigid_segment` for one segment of k markers over F frames.

    template : (k, 3) metres, segment local frame (centroid at the origin).
    scale : (F,) similarity scale c_i (1 for rigid); NaN where the frame has no pose.
    rotation : (F, 3, 3) local -> world; NaN where no pose.
    translation : (F, 3) metres, world; NaN where no pose.
    corrected : (F, k, 3) metres, world: c_i R_i z_j + t_i (fills gaps where a pose exists).
    marker_error : (k,) mean squared distance (m^2) between raw and corrected marker over the
        frames where it was seen (step D's e_j, divided by the frame count to be gap-fair).
    rms_m : overall RMS marker deviation from the rigid model, metres.
    iterations : alternations run.
    """

    template: np.ndarray
    scale: np.ndarray
    rotation: np.ndarray
    translation: np.ndarray
    corrected: np.ndarray
    marker_error: np.ndarray
    rms_m: float
    iterations: int

    @property
    def has_pose(self) -> np.ndarray:
        """(F,) bool."""
        return np.isfinite(self.scale)


def _initial_template(x: np.ndarray, seen: np.ndarray) -> np.ndarray:
    """Template guess: the frame seeing the most markers, gaps filled from aligned frames."""
    ref = int(np.argmax(seen.sum(axis=1)))
    z = x[ref].copy()
    if not np.all(seen[ref]):
        c, r, t = absolute_orientation(x, z, similarity=False)  # align every frame onto ref
        local = to_local(np.ones_like(c), r, t, x)  # (F, k, 3) in ref's frame
        with np.errstate(invalid="ignore"):
            fill = np.nanmean(np.where(seen[..., None], local, np.nan), axis=0)
        z = np.where(seen[ref][:, None], z, fill)
    return z - np.nanmean(z, axis=0)


def fit_rigid_segment(markers: np.ndarray, similarity: bool = False, max_iter: int = GPA_MAX_ITER,
                      rel_tol: float = GPA_REL_TOL) -> RigidFit:
    """Generalised Procrustes fit of one segment (digest C step A).

    markers : (F, k, 3) float64 metres, NaN where missing; k >= 3.
    similarity : per-frame scale c_i too (the patent's similarity model); else rigid.
    """
    x = np.asarray(markers, dtype=np.float64)
    if x.ndim != 3 or x.shape[2] != 3 or x.shape[1] < MIN_MARKERS_FOR_POSE:
        raise ValueError(f"markers must be (F, k>=3, 3), got {x.shape}")
    seen = np.all(np.isfinite(x), axis=2)  # (F, k)
    if np.sum(seen.sum(axis=1) >= MIN_MARKERS_FOR_POSE) == 0:
        raise ValueError("no frame sees >= 3 markers of this segment")
    if np.any(seen.sum(axis=0) == 0):
        raise ValueError(f"marker(s) {np.flatnonzero(seen.sum(axis=0) == 0).tolist()} never seen")
    z = _initial_template(x, seen)
    prev = np.inf
    it = 0
    for it in range(1, max_iter + 1):
        c, r, t = absolute_orientation(x, z, similarity=similarity)
        has = np.isfinite(c)
        # objective at the current (template, poses): the alternation never increases it
        d2 = np.sum((x - apply_pose(c, r, t, z)) ** 2, axis=2)
        err = float(np.sum(np.where(seen & np.isfinite(d2), d2, 0.0)))
        if prev - err <= rel_tol * max(err, 1e-300):
            break  # (c, r, t) are the poses for the current template
        prev = err
        # template update: z_j = sum_i c_i R_i^T (x_ij - t_i) / sum_i c_i^2 over frames seeing j
        w = (seen & has[:, None]).astype(np.float64)  # (F, k)
        cc = np.where(has, c, 0.0)
        local = np.einsum("fba,fkb->fka", np.where(has[:, None, None], r, 0.0),
                          np.where(w[..., None] > 0, x - np.where(has[:, None], t, 0.0)[:, None], 0.0))
        num = np.einsum("f,fk,fka->ka", cc, w, local)
        den = np.einsum("f,fk->k", cc * cc, w)
        z = num / den[:, None]
        z -= z.mean(axis=0)
        if similarity:  # fix the scale gauge: mean per-frame scale 1
            z *= np.mean(c[has])
    else:  # max_iter reached right after a template update
        c, r, t = absolute_orientation(x, z, similarity=similarity)
    corrected = apply_pose(c, r, t, z)
    d2 = np.sum((x - corrected) ** 2, axis=2)  # (F, k), NaN where unseen/no pose
    use = seen & np.isfinite(d2)
    marker_error = np.where(use, d2, 0.0).sum(axis=0) / np.maximum(use.sum(axis=0), 1)
    rms = float(np.sqrt(np.where(use, d2, 0.0).sum() / max(use.sum(), 1)))
    return RigidFit(z, c, r, t, corrected, marker_error, rms, it)


def select_markers(template: np.ndarray, marker_error: np.ndarray,
                   min_off_line_frac: float = MIN_OFF_LINE_FRAC) -> np.ndarray:
    """Digest C step D: marker order with the chosen stable, non-collinear triple first.

    The two markers with the smallest rigid-fit error come first, then the most stable
    marker whose distance from their line exceeds ``min_off_line_frac`` times their
    separation (or, if none does, the one farthest from the line); the remaining markers
    follow by increasing error.

    template : (k, 3) local marker positions; marker_error : (k,) e_j.
    Returns (k,) int indices.
    """
    z = np.asarray(template, dtype=np.float64)
    order = list(np.argsort(np.asarray(marker_error), kind="stable"))
    a, b = order[0], order[1]
    ab = z[b] - z[a]
    length = float(np.linalg.norm(ab))
    off = np.linalg.norm(np.cross(z - z[a], ab / max(length, 1e-300)), axis=1)  # (k,)
    rest = order[2:]
    good = [j for j in rest if off[j] > min_off_line_frac * length]
    third = good[0] if good else max(rest, key=lambda j: off[j])
    return np.array([a, b, third] + [j for j in rest if j != third], dtype=int)
