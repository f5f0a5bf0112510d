"""Numba kernels of the blob stage (seed digest A.2): labelling moments and the deformable ellipse.

All coordinates are pixels of the array passed in (OpenCV convention: pixel (x, y) has its
centre at integer (x, y)). ``skin`` maps are float32 in [0, 1] or uint8 {0, 1} (1 = pixel of the colour;
the pipeline's are uint8).
Each kernel has a plain NumPy reference in ``tests/perception`` that it is tested against.
"""

from __future__ import annotations

import math

import numba
import numpy as np

# Moment vector layout: n, sum x, sum y, sum xx, sum xy, sum yy.
N_MOMENTS = 6

# The settings of ``label_and_refine`` (from ``blobs.BlobParams``; ``track_kernels.GATE_PARAMS``
# likewise), a (1,) structured array: the kernels read the fields by name, and numba
# dispatches it as one array argument (cheaper per call than a NamedTuple of scalars).
REFINE_PARAMS = np.dtype([("min_area_px", "f8"), ("ellipse_scale", "f8"), ("n_contour_pts", "i8"),
                          ("search_frac", "f8"), ("search_min_px", "f8"), ("window_half_px", "i8"),
                          ("mirror_iters", "i8"), ("max_refine_shift_frac", "f8"), ("exclusive_pixels", "?")])


def params_record(dtype: np.dtype, source, **override) -> np.ndarray:
    """(1,) array of ``dtype`` with each field taken from the attribute of ``source`` of the same
    name, or from ``override``."""
    out = np.zeros(1, dtype)
    for name in dtype.names:
        out[name] = override[name] if name in override else getattr(source, name)
    return out


# px^2 added to each axis of a shape's covariance (``label_moments``), beyond the 1/12 px^2 of
# pixel extent the moments already hold: a blob one pixel thin still has a finite inverse
SHAPE_PIXEL_VAR = 1.0


@numba.njit(cache=True, nogil=True)
def label_moments(skin, x0, y0, x1, y1, centers, gate2, inv_scale2, sums, shape):  # pragma: no cover - numba
    """Initial labelling (A.2): each colour pixel to the predicted centre nearest in units of
    the blobs' sizes, within its gate.

    skin (h, w) float32 or uint8, pixels with value >= 0.5 count; scan the box [x0, x1) x [y0, y1).
    centers (K, 2) float64 pixels (NaN = not tracked), gate2 (K,) squared gate radius px^2,
    inv_scale2 (K,) 1 / squared (relative) blob size: a pixel goes to the blob of least
    ``d^2 * inv_scale2`` among those whose gate holds it, so where a hand touches the head
    the split lies where the two predicted discs touch, not halfway between the centres
    (issue 12: a merged skin region is split by the predicted blobs). Equal sizes: nearest.
    sums (K, 6) float64 is overwritten with the moments of each blob's pixels.
    shape (K, 2, 2) float64 (or (0, 2, 2): none): each blob's expected covariance, px^2
    (widened by ``SHAPE_PIXEL_VAR``); when every tracked blob has one (positive trace) a
    pixel goes instead to the blob of least Mahalanobis distance + log det of its covariance
    (the Gaussian discriminant: the likeliest blob), so two elongated blobs that touch side by
    side, e.g. two shoes, are split along their seam rather than across their length.
    """
    K = centers.shape[0]
    for k in range(K):
        for j in range(N_MOMENTS):
            sums[k, j] = 0.0
    by_shape = shape.shape[0] == K
    inv = np.zeros((K, 4))                  # i_xx, i_xy, i_yy, log det of each blob's covariance
    if by_shape:
        for k in range(K):
            if math.isfinite(centers[k, 0]):
                cxx = shape[k, 0, 0] + SHAPE_PIXEL_VAR
                cxy = shape[k, 0, 1]
                cyy = shape[k, 1, 1] + SHAPE_PIXEL_VAR
                det = cxx * cyy - cxy * cxy
                if not (shape[k, 0, 0] + shape[k, 1, 1] > 0.0 and det > 0.0):
                    by_shape = False
                else:
                    inv[k, 0] = cyy / det
                    inv[k, 1] = -cxy / det
                    inv[k, 2] = cxx / det
                    inv[k, 3] = math.log(det)
    for y in range(y0, y1):
        # the row as a slice indexed from 0: a loop over range(x0, x1) indexes with a signed
        # offset numba checks for wrap-around, and the compiler does not vectorise it. A
        # vectorised count first skips rows without a colour pixel and ends a row at its last
        # (a person box's skin map is ~5 % skin; 25 -> 16 us for the head and hands' gates)
        row = skin[y, x0:x1]
        n_row = 0
        for i in range(row.shape[0]):
            n_row += row[i] >= 0.5
        for i in range(row.shape[0]):
            if n_row == 0:
                break
            if row[i] < 0.5:
                continue
            n_row -= 1
            x = x0 + i
            best = -1
            bd = 1e300
            for k in range(K):
                dx = x - centers[k, 0]
                dy = y - centers[k, 1]
                d = dx * dx + dy * dy
                if d < gate2[k]:
                    if by_shape:
                        m = inv[k, 0] * dx * dx + 2.0 * inv[k, 1] * dx * dy + inv[k, 2] * dy * dy + inv[k, 3]
                    else:
                        m = d * inv_scale2[k]
                    if m < bd:
                        bd = m
                        best = k
            if best >= 0:
                sums[best, 0] += 1.0
                sums[best, 1] += x
                sums[best, 2] += y
                sums[best, 3] += x * x
                sums[best, 4] += x * y
                sums[best, 5] += y * y


@numba.njit(cache=True, nogil=True, inline="always")
def _own(img, x, y, sites, k):  # pragma: no cover - numba
    """Colour value of pixel (x, y) for blob k: 0 if a pixel of the colour is nearer another
    blob's centre (``sites`` (K, 2), NaN = absent): the initial labelling's assignment."""
    v = img[y, x]
    if v <= 0.0 or sites.shape[0] < 2:
        return v
    dk = _mahal2(x, y, sites, k)
    for j in range(sites.shape[0]):
        if j != k and math.isfinite(sites[j, 0]):
            if _mahal2(x, y, sites, j) < dk:
                return 0.0
    return v


@numba.njit(cache=True, nogil=True, inline="always")
def _mahal2(x, y, sites, k):  # pragma: no cover - numba
    """Squared Mahalanobis distance of (x, y) to site k: sites rows (mx, my, i_xx, i_xy, i_yy)."""
    dx = x - sites[k, 0]
    dy = y - sites[k, 1]
    if sites.shape[1] < 5:
        return dx * dx + dy * dy
    return sites[k, 2] * dx * dx + 2.0 * sites[k, 3] * dx * dy + sites[k, 4] * dy * dy


@numba.njit(cache=True, nogil=True, inline="always")
def _bilinear(src, x, y, w, h, ox, oy):  # pragma: no cover - numba
    """Bilinear sample at point (x, y) of an (h, w) image whose pixels from (ox, oy) on are
    ``src`` (it must hold every pixel the sample reads); 0 outside the image."""
    if x < 0.0 or y < 0.0 or x > w - 1.0 or y > h - 1.0 or w < 2 or h < 2:
        return 0.0
    xi = min(int(x), w - 2)
    yi = min(int(y), h - 2)
    fx = x - xi
    fy = y - yi
    # unsigned indices: numba checks a signed one for wrap-around (the deformable ellipse
    # samples ~1300 points a blob; 9.9 -> 9.0 us a head)
    r0 = src[np.uintp(yi - oy)]
    r1 = src[np.uintp(yi - oy + 1)]
    c0 = np.uintp(xi - ox)
    c1 = np.uintp(xi - ox + 1)
    a = r0[c0] * (1.0 - fx) + r0[c1] * fx
    b = r1[c0] * (1.0 - fx) + r1[c1] * fx
    return a * (1.0 - fy) + b * fy


@numba.njit(cache=True, nogil=True)
def ellipse_frame(cov):  # pragma: no cover - numba
    """Principal axes of a 2x2 covariance: (sd1, sd2, c, s) with axis 1 = (c, s)."""
    a = cov[0, 0]
    b = cov[0, 1]
    d = cov[1, 1]
    tr = 0.5 * (a + d)
    disc = math.sqrt(max(0.25 * (a - d) * (a - d) + b * b, 0.0))
    l1 = max(tr + disc, 1e-6)
    l2 = max(tr - disc, 1e-6)
    ang = 0.5 * math.atan2(2.0 * b, a - d)
    return math.sqrt(l1), math.sqrt(l2), math.cos(ang), math.sin(ang)


@numba.njit(cache=True, nogil=True)
def deform_ellipse(skin, sil, mean, cov, kp, contour, sites, k_site):  # pragma: no cover
    """Deformable-ellipse boundary (A.2, eq. 3-4) and the centroid of the region it encloses.
    Settings from kp, a (1,) ``REFINE_PARAMS`` record: ``ellipse_scale`` (scale below),
    ``n_contour_pts`` (n_pts), ``search_frac``, ``search_min_px``, ``window_half_px``
    (win_half_px), ``mirror_iters``.

    The initial ellipse is ``{mean + scale * Sigma^(1/2) u, |u| = 1}`` (scale 2 = the edge of a
    uniform ellipse). At each of ``n_pts`` perimeter points the boundary offset ``d`` along the
    outward normal maximises J = 1 / |N_W/2 - sum_W p + eps|: the window W (length
    2*win_half_px along the normal, 3 px wide, bilinear samples) is half colour. The crossing
    of ``sum_W p - N_W/2`` nearest the initial ellipse is interpolated to sub-pixel. Search
    range +-max(search_min_px, search_frac * local radius).

    Occlusion completion (our addition; the studio's truth showed the plain centroid shifted
    away from the adjacent limb by 1-2 px): a boundary point whose outside (2.5 px further
    along the normal) is silhouette (``sil`` > 0) borders another body part, which may hide
    part of the blob; when the opposite point borders the background, the point is replaced
    by the opposite point mirrored through the current centre (head, hand and shoe are
    centrally symmetric shapes). ``mirror_iters`` rounds (0 = the paper's plain centroid).

    sites (K, 2) means or (K, 5) means + inverse covariances (i_xx, i_xy, i_yy), k_site: the
    blobs of the same colour (NaN = absent): colour pixels nearer (Mahalanobis) another
    blob's Gaussian do not count as this blob's (exact pixel assignment, A.2), so two
    touching hands or shoes do not merge.

    contour (n_pts, 2) float64 receives the (completed) boundary. Returns (cx, cy, area_px2),
    the centroid and area of the polygon (the region inside the deformed contour).
    """
    q = kp[0]
    scale = q.ellipse_scale
    n_pts = q.n_contour_pts
    search_frac = q.search_frac
    search_min_px = q.search_min_px
    win_half_px = q.window_half_px
    mirror_iters = q.mirror_iters
    sd1, sd2, c, s = ellipse_frame(cov)
    contact = np.zeros(n_pts, np.bool_)
    mx = mean[0]
    my = mean[1]
    L = 2 * win_half_px                      # window samples along the normal
    nw_half = 0.5 * 3.0 * L                  # N_W / 2
    d_max = int(max(search_min_px, search_frac * scale * max(sd1, sd2)) + 0.5) + 1   # > any D below
    prof = np.empty(2 * d_max + L)
    f = np.empty(2 * d_max + 1)
    h, w = skin.shape
    if sites.shape[0] >= 2:
        # blob k's pixels (``_own``) around the ellipse, each tested once instead of per
        # sample: every sample lies within ``reach`` of the mean (point + offset + tangent)
        reach = scale * max(sd1, sd2) + d_max + win_half_px + 1.0
        ox = max(0, int(math.floor(mx - reach)) - 1)
        oy = max(0, int(math.floor(my - reach)) - 1)
        ex = min(w, int(math.floor(mx + reach)) + 3)
        ey = min(h, int(math.floor(my + reach)) + 3)
        src = np.zeros((max(ey - oy, 0), max(ex - ox, 0)), skin.dtype)
        for y in range(oy, ey):
            s_row = skin[y, ox:ex]
            d_row = src[y - oy]
            for i in range(s_row.shape[0]):
                if s_row[i] != 0:                  # src is 0 elsewhere, as _own gives there
                    d_row[i] = _own(skin, ox + i, y, sites, k_site)
    else:
        ox = 0
        oy = 0
        src = skin
    for k in range(n_pts):
        t = 2.0 * math.pi * k / n_pts
        u1 = math.cos(t)
        u2 = math.sin(t)
        # point on the ellipse, in image coordinates
        px = mx + scale * (sd1 * u1 * c - sd2 * u2 * s)
        py = my + scale * (sd1 * u1 * s + sd2 * u2 * c)
        # outward normal = Sigma^-1 (p - mean) direction
        n1 = u1 / sd1
        n2 = u2 / sd2
        nx = n1 * c - n2 * s
        ny = n1 * s + n2 * c
        nn = math.sqrt(nx * nx + ny * ny)
        nx /= nn
        ny /= nn
        tx = -ny
        ty = nx
        r_loc = math.sqrt((px - mx) ** 2 + (py - my) ** 2)
        D = int(max(search_min_px, search_frac * r_loc) + 0.5)
        D = min(D, int(0.8 * r_loc) + win_half_px) if r_loc > 1.0 else D
        # profile along the normal: samples at offsets q = -D - win_half + 0.5 ... D + win_half - 0.5
        n_prof = 2 * D + L
        for i in range(n_prof):
            q = -D - win_half_px + 0.5 + i
            sx = px + q * nx
            sy = py + q * ny
            prof[i] = (_bilinear(src, sx - tx, sy - ty, w, h, ox, oy) + _bilinear(src, sx, sy, w, h, ox, oy)
                       + _bilinear(src, sx + tx, sy + ty, w, h, ox, oy))
        # window sums for d = -D..D: samples i = d + D .. d + D + L - 1
        acc = 0.0
        for i in range(L):
            acc += prof[i]
        f[0] = acc - nw_half
        for j in range(1, 2 * D + 1):
            acc += prof[j + L - 1] - prof[j - 1]
            f[j] = acc - nw_half
        # crossing from colour (f > 0) to not (f <= 0) nearest d = 0
        best = 1e9
        dstar = 0.0
        found = False
        for j in range(2 * D):
            if f[j] > 0.0 and f[j + 1] <= 0.0:
                dj = (j - D) + f[j] / (f[j] - f[j + 1])
                if abs(dj) < abs(best):
                    best = dj
                    dstar = dj
                    found = True
        if not found:
            # no half-colour window: all colour -> grow, none -> shrink (argmax J at the end)
            dstar = float(D) if f[D] > 0.0 else -float(D)
        if dstar < -0.9 * r_loc:
            dstar = -0.9 * r_loc
        contour[k, 0] = px + dstar * nx
        contour[k, 1] = py + dstar * ny
        qx = int(contour[k, 0] + 2.5 * nx + 0.5)
        qy = int(contour[k, 1] + 2.5 * ny + 0.5)
        hs, ws = sil.shape
        contact[k] = 0 <= qx < ws and 0 <= qy < hs and sil[qy, qx] > 0
    cx, cy, area = _polygon_centroid(contour, n_pts, mx, my)
    if mirror_iters > 0 and n_pts % 2 == 0:
        free = contour.copy()
        half = n_pts // 2
        for _ in range(mirror_iters):
            for k in range(n_pts):
                j = (k + half) % n_pts
                if contact[k] and not contact[j]:
                    contour[k, 0] = 2.0 * cx - free[j, 0]
                    contour[k, 1] = 2.0 * cy - free[j, 1]
            prev_cx, prev_cy = cx, cy
            cx, cy, area = _polygon_centroid(contour, n_pts, mx, my)
            if cx == prev_cx and cy == prev_cy:      # converged: further rounds change nothing
                break
    return cx, cy, area


@numba.njit(cache=True, nogil=True)
def _polygon_centroid(contour, n_pts, mx, my):  # pragma: no cover - numba
    """Centroid and area of a polygon (shoelace, relative to (mx, my) for precision)."""
    a2 = 0.0
    cx = 0.0
    cy = 0.0
    for k in range(n_pts):
        x0 = contour[k, 0] - mx
        y0 = contour[k, 1] - my
        x1 = contour[(k + 1) % n_pts, 0] - mx
        y1 = contour[(k + 1) % n_pts, 1] - my
        cr = x0 * y1 - x1 * y0
        a2 += cr
        cx += (x0 + x1) * cr
        cy += (y0 + y1) * cr
    if abs(a2) < 1e-9:
        return mx, my, 0.0
    return mx + cx / (3.0 * a2), my + cy / (3.0 * a2), 0.5 * abs(a2)


@numba.njit(cache=True, nogil=True)
def label_and_refine(skin, sil, x0, y0, x1, y1, centers, gate, size, visible, kp, sums, xy, cov, area,
                     contours, has_contour, shape):  # pragma: no cover - numba
    """One tracker frame in one call: labelling (``label_moments``) + Gaussian blobs +
    deformable ellipse of each visible blob. Python per-blob overhead was most of the
    blob stage's time.

    centers (K, 2) ROI px (NaN = none), gate (K,) px, size (K,) relative blob sizes (labelling
    weights, ``label_moments``), visible (K,) bool. Outputs (K rows):
    sums (K, 6) moments, xy (K, 2) cue (NaN if < min_area pixels), cov (K, 2, 2), area (K,),
    contours (K, n_pts, 2), has_contour (K,) bool (False: occluded or refinement rejected).
    kp: (1,) ``REFINE_PARAMS`` record (one array: numba's dispatch costs per argument).
    """
    q = kp[0]
    min_area = q.min_area_px
    max_shift_frac = q.max_refine_shift_frac
    exclusive = q.exclusive_pixels
    K = centers.shape[0]
    lox = 1e18
    loy = 1e18
    hix = -1e18
    hiy = -1e18
    for k in range(K):
        if math.isfinite(centers[k, 0]) and math.isfinite(centers[k, 1]):
            lox = min(lox, centers[k, 0] - gate[k])
            loy = min(loy, centers[k, 1] - gate[k])
            hix = max(hix, centers[k, 0] + gate[k])
            hiy = max(hiy, centers[k, 1] + gate[k])
    gate2 = gate * gate
    if hix < lox:
        for k in range(K):
            for j in range(N_MOMENTS):
                sums[k, j] = 0.0
    else:
        sx0 = max(x0, int(math.floor(lox)))
        sy0 = max(y0, int(math.floor(loy)))
        sx1 = max(sx0, min(x1, int(math.ceil(hix)) + 1))
        sy1 = max(sy0, min(y1, int(math.ceil(hiy)) + 1))
        label_moments(skin, sx0, sy0, sx1, sy1, centers, gate2, 1.0 / (size * size), sums, shape)
    mean = np.empty(2)
    c2 = np.empty((2, 2))
    sites = np.full((K, 5), np.nan)      # mean + inverse covariance of each found blob
    for k in range(K):
        n = sums[k, 0]
        if exclusive and n >= min_area:
            mx = sums[k, 1] / n
            my = sums[k, 2] / n
            cxx = sums[k, 3] / n - mx * mx + 1.0 / 12.0
            cxy = sums[k, 4] / n - mx * my
            cyy = sums[k, 5] / n - my * my + 1.0 / 12.0
            det = max(cxx * cyy - cxy * cxy, 1e-9)
            sites[k, 0] = mx
            sites[k, 1] = my
            sites[k, 2] = cyy / det
            sites[k, 3] = -cxy / det
            sites[k, 4] = cxx / det
    for k in range(K):
        has_contour[k] = False
        n = sums[k, 0]
        if n < min_area:
            xy[k, 0] = np.nan
            xy[k, 1] = np.nan
            area[k] = 0.0
            for i in range(2):
                for j in range(2):
                    cov[k, i, j] = np.nan
            continue
        mx = sums[k, 1] / n
        my = sums[k, 2] / n
        cxx = sums[k, 3] / n - mx * mx + 1.0 / 12.0      # + pixel extent
        cxy = sums[k, 4] / n - mx * my
        cyy = sums[k, 5] / n - my * my + 1.0 / 12.0
        mean[0] = mx
        mean[1] = my
        c2[0, 0] = cxx
        c2[0, 1] = cxy
        c2[1, 0] = cxy
        c2[1, 1] = cyy
        cov[k] = c2
        xy[k, 0] = mx
        xy[k, 1] = my
        area[k] = n
        if visible[k]:
            # only blobs within reach compete for pixels (the test costs per sample)
            reach = 2.5 * (math.sqrt(max(cxx, cyy)) + 1.0)
            n_near = 0
            for j in range(K):
                if j != k and math.isfinite(sites[j, 0]):
                    rj = 2.5 * math.sqrt(max(1.0 / max(sites[j, 2], 1e-12), 1.0 / max(sites[j, 4], 1e-12)))
                    if math.hypot(sites[j, 0] - mx, sites[j, 1] - my) < 2.0 * (reach + rj):
                        n_near += 1
            own = sites if n_near > 0 else sites[k:k + 1]
            cx, cy, a = deform_ellipse(skin, sil, mean, c2, kp, contours[k], own, k if n_near > 0 else 0)
            r_blob = math.sqrt(n / math.pi)
            if a > 0 and math.hypot(cx - mx, cy - my) <= max_shift_frac * r_blob + 0.5:
                xy[k, 0] = cx
                xy[k, 1] = cy
                area[k] = a
                has_contour[k] = True
