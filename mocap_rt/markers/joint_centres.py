"""Functional joint centres from the markers of two adjacent segments.

Every method has the same signature so that callers and the bench can loop over them::

    method(parent (F, kp, 3), child (F, kc, 3)) -> JointCentreFit

Markers are metres, world frame, NaN where missing, **ordered by stability** (the chosen
triple of digest C step D first; :func:`estimate_joint_centre` does that ordering and the
optional rigid preprocessing).  Methods:

* ``linear``  - the patent's 3+3 linear solution (digest C step C).
* ``patent31`` / ``patent32`` - the patent's nonlinear 3+1 / 3+2 objective (step B),
  started from the linear solution, solved with ``scipy.optimize.least_squares``; the
  centre is the parent-fixed point P1 + A [a b c]^T.
* ``patent`` (default) - the same objective used symmetrically, as the patent notes that
  parent and child are interchangeable for the rotation centre: step B with the parent's
  triple and *every* child marker, then with the child's triple and every parent marker,
  each started from step C; the centre is the midpoint of the two.  (Our choice, see
  docs/joint-centres.md: the one-sided 3+2 form was less accurate than SCoRE.)
* ``score``   - SCoRE (Ehrig et al. 2006): the point fixed in both segments' least-squares
  poses (Soderkvist & Wedin 1993 poses from all markers), linear least squares.
* ``obrien``  - O'Brien et al. 2000: the same "fixed in both frames" equation, but each
  segment frame is the orthonormal triad of its first three markers, as the magnetic
  sensors of the original gave one frame per segment.
* ``sphere``  - Gamage & Lasenby 2002 closed-form sphere fit of all child markers
  expressed in the parent frame.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import least_squares

from mocap_rt.markers.rigid import absolute_orientation, fit_rigid_segment, select_markers

log = logging.getLogger(__name__)

MIN_FRAMES = 4  # the 3+3 system is over-determined from 4 frames on (digest C step C)


@dataclass(frozen=True)
class JointCentreFit:
    """centre : (F, 3) metres, world; NaN where the method could not place it.
    residual_m : RMS of the method's own objective, in metres (see each method).
    local_parent : (3,) the centre's fixed coordinates in the method's parent parameterisation.
    method : name; info : extra diagnostics (condition number, iterations, ...).
    """

    centre: np.ndarray
    residual_m: float
    local_parent: np.ndarray
    method: str
    info: dict = field(default_factory=dict)


def _basis(p: np.ndarray) -> np.ndarray:
    """Patent regression basis A_i = [P1-P2, P1-P3, (P1-P2)x(P1-P3)]: p (F, 3, 3) -> (F, 3, 3)."""
    u = p[:, 0] - p[:, 1]
    v = p[:, 0] - p[:, 2]
    return np.stack([u, v, np.cross(u, v)], axis=2)  # columns


def _frames_ok(*arrays: np.ndarray) -> np.ndarray:
    ok = None
    for a in arrays:
        m = np.all(np.isfinite(a.reshape(a.shape[0], -1)), axis=1)
        ok = m if ok is None else ok & m
    return ok


def _lstsq(lhs: np.ndarray, rhs: np.ndarray) -> tuple[np.ndarray, float]:
    """Least squares via the (column-scaled) normal equations; min-norm if rank deficient.

    lhs (N, n) with N >> n = 6: forming the n x n normal matrix is ~50x faster than a QR/SVD
    of the tall matrix; columns are scaled to unit norm first so the squared condition
    number stays harmless.  Returns (solution (n,), condition number of scaled lhs).
    """
    col = np.linalg.norm(lhs, axis=0)
    col[col == 0] = 1.0
    a = lhs / col
    normal = a.T @ a
    sol, _, _, sv = np.linalg.lstsq(normal, a.T @ rhs, rcond=1e-12)
    cond = float(np.sqrt(sv[0] / sv[-1])) if sv[-1] > 0 else np.inf
    return sol / col, cond


def _check_pair(parent: np.ndarray, child: np.ndarray, method: str) -> None:
    """Both (F, k>=3, 3) with the same F, else a ValueError naming the method and shapes."""
    ok = (parent.ndim == 3 and child.ndim == 3 and parent.shape[2] == 3 and child.shape[2] == 3
          and parent.shape[0] == child.shape[0] and parent.shape[1] >= 3 and child.shape[1] >= 3)
    if not ok:
        raise ValueError(f"{method}: parent and child must be (F, k>=3, 3) with the same F, "
                         f"got {parent.shape} and {child.shape}")


def _need_frames(n: int, method: str) -> None:
    if n < MIN_FRAMES:
        raise ValueError(f"{method}: only {n} frames with the needed markers (need >= {MIN_FRAMES})")


def linear_33(parent: np.ndarray, child: np.ndarray) -> JointCentreFit:
    """Patent 3+3 linear solution: P1 + A [a b c]^T = C1 + B [d e f]^T over all frames.

    Residual: RMS distance between the parent- and child-defined centres.  The centre is
    their midpoint (the parent one alone where the child markers are missing).
    """
    _check_pair(parent, child, "linear")
    p, c = parent[:, :3], child[:, :3]
    a_mat, b_mat = _basis(p), _basis(c)
    ok = _frames_ok(p, c)
    _need_frames(int(ok.sum()), "linear")
    # (3F, 6) [A, -B] [abc; def] = C1 - P1; columns scaled to unit norm for conditioning
    lhs = np.concatenate([a_mat[ok], -b_mat[ok]], axis=2).reshape(-1, 6)
    rhs = (c[ok, 0] - p[ok, 0]).reshape(-1)
    sol, cond = _lstsq(lhs, rhs)
    jp = p[:, 0] + np.einsum("fab,b->fa", a_mat, sol[:3])
    jc = c[:, 0] + np.einsum("fab,b->fa", b_mat, sol[3:])
    gap = np.linalg.norm(jp - jc, axis=1)
    centre = np.where(np.isfinite(jc), 0.5 * (jp + jc), jp)
    return JointCentreFit(centre, float(np.sqrt(np.nanmean(gap[ok] ** 2))), sol[:3], "linear",
                          {"child_coeffs": sol[3:], "cond": cond})


def _patent_nonlinear(parent: np.ndarray, child: np.ndarray, n_child: int, name: str) -> JointCentreFit:
    """Patent step B: min sum_i sum_k (||J_i - C_k,i||^2 - r_k^2)^2 over (a, b, c, r_k).

    J_i = P1_i + A_i [a b c]^T.  Initial value: the linear 3+3 solution (step C).
    Residual reported: RMS of (||J_i - C_k,i|| - r_k), metres.
    """
    _check_pair(parent, child, name)
    init = linear_33(parent, child)
    p = parent[:, :3]
    ck = child[:, :n_child]  # (F, m, 3) the most stable child markers
    a_mat = _basis(p)
    ok = _frames_ok(p, ck)
    _need_frames(int(ok.sum()), name)
    a_ok, p1, cc = a_mat[ok], p[ok, 0], ck[ok]
    j0 = p1 + np.einsum("fab,b->fa", a_ok, init.local_parent)
    r0 = np.linalg.norm(j0[:, None] - cc, axis=2).mean(axis=0)  # (m,)

    n_ok = int(ok.sum())
    rows = np.arange(n_ok * n_child)
    cols = np.tile(np.arange(n_child), n_ok)
    jac_buf = np.zeros((n_ok * n_child, 3 + n_child))

    def fun(x):
        d = (p1 + a_ok @ x[:3])[:, None] - cc  # (F, m, 3)
        return (np.sum(d * d, axis=2) - x[3:] ** 2).ravel()

    def jac(x):
        d = (p1 + a_ok @ x[:3])[:, None] - cc  # (F, m, 3)
        jac_buf[:, :3] = 2.0 * np.matmul(d, a_ok).reshape(-1, 3)  # d/d(abc) of ||J - C||^2
        jac_buf[rows, 3 + cols] = -2.0 * x[3:][cols]  # d/dr_k of -r_k^2
        return jac_buf.copy()  # MINPACK may keep the array it is given

    sol = least_squares(fun, np.concatenate([init.local_parent, r0]), jac=jac, method="lm", x_scale="jac")
    coeffs = sol.x[:3]
    centre = p[:, 0] + np.einsum("fab,b->fa", a_mat, coeffs)
    dist = np.linalg.norm(centre[ok][:, None] - cc, axis=2)
    res = float(np.sqrt(np.mean((dist - np.abs(sol.x[3:])) ** 2)))
    return JointCentreFit(centre, res, coeffs, name,
                          {"radii_m": np.abs(sol.x[3:]), "nfev": sol.nfev, "linear_init": init.local_parent})


def patent_31(parent: np.ndarray, child: np.ndarray) -> JointCentreFit:
    """Patent 3+1: three parent markers, the most stable child marker."""
    return _patent_nonlinear(parent, child, 1, "patent31")


def patent_32(parent: np.ndarray, child: np.ndarray) -> JointCentreFit:
    """Patent 3+2: three parent markers, the two most stable child markers."""
    return _patent_nonlinear(parent, child, 2, "patent32")


def patent_symmetric(parent: np.ndarray, child: np.ndarray) -> JointCentreFit:
    """Patent step B in both directions with all markers (3+k), midpoint of the two centres."""
    _check_pair(parent, child, "patent")
    fwd = _patent_nonlinear(parent, child, child.shape[1], "patent")
    bwd = _patent_nonlinear(child, parent, parent.shape[1], "patent")
    a, b = fwd.centre, bwd.centre
    centre = np.where(np.isfinite(a) & np.isfinite(b), 0.5 * (a + b), np.where(np.isfinite(a), a, b))
    res = float(np.sqrt(0.5 * (fwd.residual_m ** 2 + bwd.residual_m ** 2)))
    return JointCentreFit(centre, res, fwd.local_parent, "patent",
                          {"child_coeffs": bwd.local_parent, "nfev": fwd.info["nfev"] + bwd.info["nfev"],
                           "halves_gap_m": float(np.sqrt(np.nanmean(np.sum((a - b) ** 2, axis=1))))})


def _ls_poses(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares rigid poses of every frame onto a reference configuration.

    The reference is the first frame that sees every marker (SCoRE's usual choice); if
    there is none, a one-pass Procrustes template.  Returns R (F, 3, 3), t (F, 3).
    """
    full = np.flatnonzero(np.all(np.isfinite(points), axis=(1, 2)))
    if full.size:
        ref = points[full[0]] - points[full[0]].mean(axis=0)
    else:
        ref = fit_rigid_segment(points, max_iter=1).template
    _, rot, trans = absolute_orientation(points, ref)
    return rot, trans


def _triad_poses(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Orthonormal frame of the first three markers: origin P1, x to P2, z normal to the plane."""
    p1, p2, p3 = points[:, 0], points[:, 1], points[:, 2]
    ex = p2 - p1
    ex /= np.linalg.norm(ex, axis=1, keepdims=True)
    ez = np.cross(ex, p3 - p1)
    ez /= np.linalg.norm(ez, axis=1, keepdims=True)
    ey = np.cross(ez, ex)
    return np.stack([ex, ey, ez], axis=2), p1


def _fixed_in_both(rp, tp, rc, tc, name: str) -> JointCentreFit:
    """Solve R_p c_p + t_p = R_c c_c + t_c for (c_p, c_c) in least squares; centre = midpoint."""
    ok = _frames_ok(rp, tp, rc, tc)
    _need_frames(int(ok.sum()), name)
    lhs = np.concatenate([rp[ok], -rc[ok]], axis=2).reshape(-1, 6)  # (3F, 6)
    rhs = (tc[ok] - tp[ok]).reshape(-1)
    sol, cond = _lstsq(lhs, rhs)
    jp = np.einsum("fab,b->fa", rp, sol[:3]) + tp
    jc = np.einsum("fab,b->fa", rc, sol[3:]) + tc
    gap = np.linalg.norm(jp - jc, axis=1)
    centre = np.where(np.isfinite(jp) & np.isfinite(jc), 0.5 * (jp + jc), np.where(np.isfinite(jp), jp, jc))
    return JointCentreFit(centre, float(np.sqrt(np.mean(gap[ok] ** 2))), sol[:3], name,
                          {"child_local": sol[3:], "cond": cond})


def score(parent: np.ndarray, child: np.ndarray) -> JointCentreFit:
    """SCoRE (Ehrig et al. 2006) with least-squares segment poses; residual: RMS gap."""
    _check_pair(parent, child, "score")
    rp, tp = _ls_poses(parent)
    rc, tc = _ls_poses(child)
    return _fixed_in_both(rp, tp, rc, tc, "score")


def obrien(parent: np.ndarray, child: np.ndarray) -> JointCentreFit:
    """O'Brien et al. 2000 with one orthonormal triad per segment; residual: RMS gap."""
    _check_pair(parent, child, "obrien")
    rp, tp = _triad_poses(parent)
    rc, tc = _triad_poses(child)
    return _fixed_in_both(rp, tp, rc, tc, "obrien")


def sphere(parent: np.ndarray, child: np.ndarray) -> JointCentreFit:
    """Gamage & Lasenby 2002 closed-form least-squares sphere centre.

    Child markers v_ik are expressed in the parent's least-squares frame; the common
    centre solves  2 (sum_k C_k) c = sum_k (mean(|v|^2 v) - mean(|v|^2) mean(v)),
    C_k = covariance of marker k.  Residual: RMS of (||v_ik - c|| - r_k), metres.
    """
    _check_pair(parent, child, "sphere")
    rp, tp = _ls_poses(parent)
    v = np.einsum("fba,fkb->fka", rp, child - tp[:, None, :])  # (F, k, 3) parent frame
    lhs = np.zeros((3, 3))
    rhs = np.zeros(3)
    used = 0
    for k in range(v.shape[1]):
        vk = v[:, k][np.all(np.isfinite(v[:, k]), axis=1)]
        if len(vk) < MIN_FRAMES:
            continue
        used += 1
        mean = vk.mean(axis=0)
        sq = np.sum(vk * vk, axis=1)
        lhs += (vk - mean).T @ (vk - mean) / len(vk)
        rhs += (sq[:, None] * vk).mean(axis=0) - sq.mean() * mean
    if used == 0:
        raise ValueError(f"sphere: no child marker seen in >= {MIN_FRAMES} frames with the parent")
    c_local = 0.5 * np.linalg.lstsq(lhs, rhs, rcond=None)[0]
    dist = np.linalg.norm(v - c_local, axis=2)  # (F, k)
    radius = np.nanmean(dist, axis=0)
    res = float(np.sqrt(np.nanmean((dist - radius) ** 2)))
    centre = np.einsum("fab,b->fa", rp, c_local) + tp
    return JointCentreFit(centre, res, c_local, "sphere", {"radii_m": radius, "cond": float(np.linalg.cond(lhs))})


MethodFn = Callable[[np.ndarray, np.ndarray], JointCentreFit]
METHODS: dict[str, MethodFn] = {
    "patent": patent_symmetric,
    "patent32": patent_32,
    "patent31": patent_31,
    "linear": linear_33,
    "score": score,
    "sphere": sphere,
    "obrien": obrien,
}


@dataclass(frozen=True)
class PreparedSegment:
    """A segment's markers ready for the methods.

    points : (F, k, 3) metres, reordered so the step-D triple comes first; corrected
        markers with rigid preprocessing, raw ones without.
    order : (k,) indices into the segment's marker list.
    rms_m : RMS deviation of the raw markers from the rigid model.
    rotation : (F, 3, 3) the segment's local -> world rotation from the rigid fit (NaN: no pose).
    """

    points: np.ndarray
    order: np.ndarray
    rms_m: float
    rotation: np.ndarray | None = None


def prepare_segment(markers: np.ndarray, rigid: bool = True, similarity: bool = False) -> PreparedSegment:
    """Rigid preprocessing (step A, optional) and marker ordering (step D) of one segment.

    markers : (F, k, 3) metres, NaN where missing.
    """
    fit = fit_rigid_segment(markers, similarity=similarity)
    order = select_markers(fit.template, fit.marker_error)
    pts = fit.corrected if rigid else np.asarray(markers, dtype=np.float64)
    return PreparedSegment(np.ascontiguousarray(pts[:, order]), order, fit.rms_m, fit.rotation)


def estimate_joint_centre(parent: np.ndarray, child: np.ndarray, method: str = "patent", rigid: bool = True,
                          similarity: bool = False) -> JointCentreFit:
    """Joint centre between two segments from their raw markers ((F, k, 3) metres each)."""
    if method not in METHODS:
        raise ValueError(f"unknown joint-centre method {method!r} (choose from {sorted(METHODS)})")
    p = prepare_segment(parent, rigid, similarity)
    c = prepare_segment(child, rigid, similarity)
    return METHODS[method](p.points, c.points)
