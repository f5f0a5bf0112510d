"""Left/right labels of the hands and feet, made to agree across views (``fix_left_right``).

A single view cannot be sure which hand (foot) is the left one: perception labels left and
right per view (a cold start assumes the person faces the camera). Per view, keep the labelling
that agrees with the 3D prediction, or at a cold start the combination of per-view labellings
that triangulates best (``_label_search``, all combinations in one batch).
"""

from __future__ import annotations

import numpy as np

from mocap_rt.fusion.views import RigProjector
from mocap_rt.geometry.ray_triangulator import RayTriangulator
from mocap_rt.names import LR_PAIRS

# Reprojection error cap (pixels) in the label search, so one bad blob cannot dominate.
LR_COST_CAP_PX = 40.0
# With a prediction, a view is relabelled only if the swapped labels are nearer by this
# margin (pixels) and this ratio.
LR_MARGIN_PX = 10.0
LR_RATIO = 0.5


def fix_left_right(tri: RayTriangulator, proj: RigProjector, uv: np.ndarray, weights: np.ndarray,
                   reference: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, int]:
    """Per camera, swap the left/right labels of hands and feet where the other is better.

    Perception labels left and right per view (a cold start assumes the person faces the
    camera); the views must agree. With a 3D ``reference`` (6, 3) (the filter's
    prediction) each view takes the labelling nearer the reference's projection (only when
    clearly nearer). For a pair with neither cue predicted, every combination of per-view
    swaps is tried and the one with the least (capped) reprojection error is kept; of the two
    mirror-image solutions the one keeping more views' original labels wins.

    uv : (C, 6, 2) pixels (NaN = not found), weights : (C, 6). Returns corrected copies
    and the number of views relabelled.
    """
    uv = uv.copy()
    w = weights.copy()
    n_fixed = 0
    have_ref = reference is not None
    ref_uv = proj.project(np.where(np.isfinite(reference), reference, 0.0))[0] if have_ref else None
    for a, b in LR_PAIRS:
        seen = np.isfinite(uv[:, [a, b]]).all(-1) & (w[:, [a, b]] > 0)        # (C, 2)
        cams = np.flatnonzero(seen.any(axis=1))
        if cams.size == 0:
            continue
        if have_ref and np.isfinite(reference[[a, b]]).all():
            ra, rb = ref_uv[:, a], ref_uv[:, b]                                  # (C, 2)
            pa, pb = uv[:, a], uv[:, b]
            d = lambda p, q: np.sqrt(np.sum((p - q) ** 2, axis=-1))            # noqa: E731
            both = seen.all(axis=1)
            keep = np.where(both, d(pa, ra) + d(pb, rb), 0.0)
            swap = np.where(both, d(pa, rb) + d(pb, ra), 0.0)
            # one cue seen: the other label only if that prediction is clearly nearer
            only_a, only_b = seen[:, 0] & ~seen[:, 1], seen[:, 1] & ~seen[:, 0]
            keep = np.where(only_a, d(pa, ra), np.where(only_b, d(pb, rb), keep))
            swap = np.where(only_a, d(pa, rb), np.where(only_b, d(pb, ra), swap))
            # relabel only when clearly better: predictions are uncertain, labels usually right
            for c in np.flatnonzero((swap + LR_MARGIN_PX < keep) & (swap < LR_RATIO * keep)):
                _swap(uv, w, c, a, b)
                n_fixed += 1
            continue
        if have_ref and np.isfinite(reference[[a, b]]).all(axis=1).any():
            continue  # one of the two is tracked: too little to go on, keep perception's labels
        if cams.size < 2 or cams.size > 8:
            continue
        swap = _label_search(tri, proj, uv, w, a, b, cams)
        if swap is None:
            continue
        for c in np.flatnonzero(swap):
            _swap(uv, w, c, a, b)
            n_fixed += 1
    return uv, w, n_fixed


def _label_search(tri: RayTriangulator, proj: RigProjector, uv: np.ndarray, w: np.ndarray, a: int, b: int,
                  cams: np.ndarray) -> np.ndarray | None:
    """Which of the views ``cams`` to swap the pair (a, b) in, with neither cue predicted: every
    combination of swaps (the first view's labels fixed: each stands for itself and its mirror
    image), triangulated and reprojected in one batch; the least capped reprojection error wins,
    as the mirror image that keeps more views' labels. (C,) bool, or None if no combination
    triangulates."""
    C, n = uv.shape[0], cams.size
    masks = np.arange(1 << (n - 1))
    M = masks.size
    flip = np.zeros((M, C), dtype=bool)                                          # (M, C)
    flip[:, cams[1:]] = (masks[:, None] >> np.arange(n - 1)) & 1
    pair_uv, pair_w = uv[:, [a, b]], w[:, [a, b]]
    t_uv = np.where(flip[..., None, None], pair_uv[None, :, ::-1], pair_uv[None])   # (M, C, 2, 2)
    t_w = np.where(flip[..., None], pair_w[None, :, ::-1], pair_w[None])
    t_w = np.where(np.isfinite(t_uv).all(-1), t_w, 0.0)
    X = tri(t_uv.transpose(1, 0, 2, 3).reshape(C, 2 * M, 2), t_w.transpose(1, 0, 2).reshape(C, 2 * M))
    ok = np.isfinite(X).reshape(M, 6).all(axis=1)
    p = proj.project(np.where(np.isfinite(X), X, 0.0))[0].reshape(C, M, 2, 2).transpose(1, 0, 2, 3)
    err = np.linalg.norm(p - t_uv, axis=-1)[:, cams]                               # (M, n, 2)
    cost = np.where(ok, np.nansum(np.minimum(err, LR_COST_CAP_PX), axis=(1, 2)), np.inf)
    if not ok.any():
        return None
    best = int(np.argmin(cost))
    n_flip = int(flip[best].sum())
    swap = np.zeros(C, dtype=bool)
    swap[cams] = flip[best, cams] != (n_flip > n - n_flip)    # of the two mirror images, the one keeping more labels
    return swap


def _swap(uv: np.ndarray, w: np.ndarray, c: int, a: int, b: int) -> None:
    uv[c, [a, b]] = uv[c, [b, a]]
    w[c, [a, b]] = w[c, [b, a]]
