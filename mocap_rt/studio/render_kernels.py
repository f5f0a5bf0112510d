"""The studio renderer's numba kernels: per-pixel z-buffer ray casting of capsules.

Per camera and frame (``render.StudioRenderer`` calls them in this order):
1. ``raster_capsules``: for each capsule, over its projected bounding box only, cast the
   pixel's ray, keep the nearest hit in a z-buffer seeded with the empty studio's depth
   (so the floor hides what is below it), and count the capsule's pixels ignoring
   occlusion (also outside the image, with the undistorted pinhole ray) for visibility.
2. ``cast_shadows``: for floor pixels inside the bounding box of the body's shadow,
   test the ray towards each shadow-casting light against every capsule.
3. ``compose``: Lambert shading (ambient + directional lights), the floor shadow,
   global flicker, per-camera gain and white balance, sensor noise from a per-pixel
   hash (``splitmix``; deterministic for a seed, whatever the threading), to uint8 BGR.
Shading is in display units (albedo x light, no gamma).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from mocap_rt.studio.scene import FLOOR

# Nearest accepted hit along a ray (m), to ignore self-hits of shadow rays.
MIN_HIT_T_M = 1e-6
# Off-image pixels are counted on a grid of this stride (each hit stands for stride^2).
OFF_IMAGE_STRIDE = 4


@njit(cache=True, nogil=True)
def _sphere_t(ox, oy, oz, dx, dy, dz, cx, cy, cz, r):
    """Nearest positive t of the ray o + t d (|d| = 1) on a sphere, or -1."""
    px, py, pz = ox - cx, oy - cy, oz - cz
    b = px * dx + py * dy + pz * dz
    c = px * px + py * py + pz * pz - r * r
    h = b * b - c
    if h < 0.0:
        return -1.0
    s = math.sqrt(h)
    t = -b - s
    if t > MIN_HIT_T_M:
        return t
    t = -b + s
    return t if t > MIN_HIT_T_M else -1.0


@njit(cache=True, nogil=True)
def _capsule_t(ox, oy, oz, dx, dy, dz, ax, ay, az, bx, by, bz, r):
    """Nearest positive t of the ray on the capsule (segment a-b, radius r), or -1."""
    best = 1e30
    t = _sphere_t(ox, oy, oz, dx, dy, dz, ax, ay, az, r)
    if 0.0 < t < best:
        best = t
    t = _sphere_t(ox, oy, oz, dx, dy, dz, bx, by, bz, r)
    if 0.0 < t < best:
        best = t
    bax, bay, baz = bx - ax, by - ay, bz - az
    baba = bax * bax + bay * bay + baz * baz
    if baba > 1e-12:
        oax, oay, oaz = ox - ax, oy - ay, oz - az
        bard = bax * dx + bay * dy + baz * dz
        baoa = bax * oax + bay * oay + baz * oaz
        rdoa = dx * oax + dy * oay + dz * oaz
        oaoa = oax * oax + oay * oay + oaz * oaz
        qa = baba - bard * bard
        if qa > 1e-12 * baba:
            qb = baba * rdoa - baoa * bard
            qc = baba * oaoa - baoa * baoa - r * r * baba
            h = qb * qb - qa * qc
            if h >= 0.0:
                s = math.sqrt(h)
                for t in ((-qb - s) / qa, (-qb + s) / qa):
                    y = baoa + t * bard
                    if t > MIN_HIT_T_M and 0.0 < y < baba and t < best:
                        best = t
                        break
    return best if best < 1e30 else -1.0


@njit(cache=True, nogil=True)
def raster_capsules(rays, origin, rt_kinv, A, B, rad, bbox, cue_of, zbuf, idbuf, cuehit, total):
    """Z-buffer the capsules into zbuf/idbuf; count each capsule's pixels in ``total``.

    cue_of (P,) i8: cue index of each capsule or -1; cuehit (H, W) u1 gets bit k where
    cue k's capsule covers the pixel (occluded or not).

    rays (H, W, 3) f8; origin (3,); rt_kinv (3, 3) = R^T K^-1 for off-image pixels;
    A, B (P, 3); rad (P,); bbox (P, 4) int64 u0, u1, v0, v1 inclusive (may leave the
    image; off-image pixels are sampled every OFF_IMAGE_STRIDE); zbuf (H, W) f4 seeded
    with the background depth; idbuf (H, W) i2 seeded -1.
    """
    H, W = zbuf.shape
    ox, oy, oz = origin[0], origin[1], origin[2]
    for p in range(A.shape[0]):
        u0, u1, v0, v1 = bbox[p, 0], bbox[p, 1], bbox[p, 2], bbox[p, 3]
        ax, ay, az = A[p, 0], A[p, 1], A[p, 2]
        bx, by, bz = B[p, 0], B[p, 1], B[p, 2]
        r = rad[p]
        n = 0
        for v in range(v0, v1 + 1):
            row_inside = 0 <= v < H
            if not row_inside and v % OFF_IMAGE_STRIDE != 0:
                continue
            for u in range(u0, u1 + 1):
                inside = row_inside and 0 <= u < W
                if not inside and (u % OFF_IMAGE_STRIDE != 0 or v % OFF_IMAGE_STRIDE != 0):
                    continue
                if inside:
                    dx, dy, dz = rays[v, u, 0], rays[v, u, 1], rays[v, u, 2]
                else:
                    dx = rt_kinv[0, 0] * u + rt_kinv[0, 1] * v + rt_kinv[0, 2]
                    dy = rt_kinv[1, 0] * u + rt_kinv[1, 1] * v + rt_kinv[1, 2]
                    dz = rt_kinv[2, 0] * u + rt_kinv[2, 1] * v + rt_kinv[2, 2]
                    nn = math.sqrt(dx * dx + dy * dy + dz * dz)
                    dx, dy, dz = dx / nn, dy / nn, dz / nn
                t = _capsule_t(ox, oy, oz, dx, dy, dz, ax, ay, az, bx, by, bz, r)
                if t > 0.0:
                    n += 1 if inside else OFF_IMAGE_STRIDE * OFF_IMAGE_STRIDE
                    if inside:
                        if cue_of[p] >= 0:
                            cuehit[v, u] |= np.uint8(1 << cue_of[p])
                        if t < zbuf[v, u]:
                            zbuf[v, u] = t
                            idbuf[v, u] = p
        total[p] = n


@njit(cache=True, nogil=True)
def cast_shadows(point, kind, idbuf, box, basis, light_index, seg2d, rad, shadow):
    """Set bit ``light_index[k]`` of ``shadow`` on floor pixels whose way to light k is blocked.

    A floor point is in the shadow of a capsule when the line through it along the light
    passes within the radius of the capsule's segment, i.e. when, projected on the plane
    normal to the light (orthonormal ``basis`` (K, 2, 3)), the point lies within the
    radius of the projected segment ``seg2d`` (K, P, 4: ax, ay, bx, by).
    point (H, W, 3) f4 world points; kind (H, W) u1; box (4,) u0, u1, v0, v1 in the image.
    """
    K, P = seg2d.shape[0], seg2d.shape[1]
    lo = np.empty((K, P, 2))
    hi = np.empty((K, P, 2))
    for k in range(K):
        for p in range(P):
            lo[k, p, 0] = min(seg2d[k, p, 0], seg2d[k, p, 2]) - rad[p]
            hi[k, p, 0] = max(seg2d[k, p, 0], seg2d[k, p, 2]) + rad[p]
            lo[k, p, 1] = min(seg2d[k, p, 1], seg2d[k, p, 3]) - rad[p]
            hi[k, p, 1] = max(seg2d[k, p, 1], seg2d[k, p, 3]) + rad[p]
    for v in range(box[2], box[3] + 1):
        for u in range(box[0], box[1] + 1):
            if kind[v, u] != FLOOR or idbuf[v, u] >= 0:
                continue
            px, py, pz = point[v, u, 0], point[v, u, 1], point[v, u, 2]
            bits = 0
            for k in range(K):
                qx = px * basis[k, 0, 0] + py * basis[k, 0, 1] + pz * basis[k, 0, 2]
                qy = px * basis[k, 1, 0] + py * basis[k, 1, 1] + pz * basis[k, 1, 2]
                for p in range(P):
                    if qx < lo[k, p, 0] or qx > hi[k, p, 0] or qy < lo[k, p, 1] or qy > hi[k, p, 1]:
                        continue
                    ax, ay = seg2d[k, p, 0], seg2d[k, p, 1]
                    ex, ey = seg2d[k, p, 2] - ax, seg2d[k, p, 3] - ay
                    ee = ex * ex + ey * ey
                    s = 0.0
                    if ee > 1e-12:
                        s = min(max(((qx - ax) * ex + (qy - ay) * ey) / ee, 0.0), 1.0)
                    dx, dy = qx - ax - s * ex, qy - ay - s * ey
                    if dx * dx + dy * dy <= rad[p] * rad[p]:
                        bits |= 1 << light_index[k]
                        break
            shadow[v, u] = bits


@njit(cache=True, nogil=True)
def splitmix(x):
    x = x + np.uint64(0x9E3779B97F4A7C15)
    x = (x ^ (x >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
    x = (x ^ (x >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    return x ^ (x >> np.uint64(31))


@njit(cache=True, nogil=True)
def _gauss3(key):
    """Three approximately standard normal numbers from one 64-bit key.

    Each is a sum of three 7-bit uniforms (Irwin-Hall, n = 3), rescaled to unit variance.
    """
    x = splitmix(key)
    m = np.uint64(0x7F)
    g0 = float(x & m) + float((x >> np.uint64(7)) & m) + float((x >> np.uint64(14)) & m)
    g1 = float((x >> np.uint64(21)) & m) + float((x >> np.uint64(28)) & m) + float((x >> np.uint64(35)) & m)
    g2 = float((x >> np.uint64(42)) & m) + float((x >> np.uint64(49)) & m) + float((x >> np.uint64(56)) & m)
    # (sum + 1.5) / 128 is a sum of three U(0, 1), mean 1.5, variance 3/12
    return ((g0 + 1.5) / 128.0 - 1.5) * 2.0, ((g1 + 1.5) / 128.0 - 1.5) * 2.0, ((g2 + 1.5) / 128.0 - 1.5) * 2.0


@njit(cache=True, nogil=True)
def compose(bg_albedo, bg_cos, rays, origin, zbuf, idbuf, shadow, A, B, mat, mat_albedo,
             light_dirs, light_int, ambient, scale_bgr, noise_sigma, key, out, mask, visible,
             cuehit, cue_index, group, cue_visible):
    """Shade every pixel to uint8 BGR ``out``; fill ``mask``, per-capsule ``visible``
    counts, and ``cue_visible`` (6,): pixels where the cue's capsule is hit and the
    nearest surface belongs to its group."""
    H, W = zbuf.shape
    L = light_dirs.shape[0]
    for p in range(visible.shape[0]):
        visible[p] = 0
    for k in range(cue_visible.shape[0]):
        cue_visible[k] = 0
    for v in range(H):
        for u in range(W):
            p = idbuf[v, u]
            if p >= 0:
                visible[p] += 1
                mask[v, u] = True
                hits = cuehit[v, u]
                if hits != 0:
                    for k in range(cue_index.shape[0]):
                        if (hits >> k) & 1 and group[cue_index[k]] == group[p]:
                            cue_visible[k] += 1
                t = zbuf[v, u]
                hx = origin[0] + t * rays[v, u, 0]
                hy = origin[1] + t * rays[v, u, 1]
                hz = origin[2] + t * rays[v, u, 2]
                ex, ey, ez = B[p, 0] - A[p, 0], B[p, 1] - A[p, 1], B[p, 2] - A[p, 2]
                ee = ex * ex + ey * ey + ez * ez
                s = 0.0
                if ee > 1e-12:
                    s = ((hx - A[p, 0]) * ex + (hy - A[p, 1]) * ey + (hz - A[p, 2]) * ez) / ee
                    s = min(max(s, 0.0), 1.0)
                nx, ny, nz = hx - A[p, 0] - s * ex, hy - A[p, 1] - s * ey, hz - A[p, 2] - s * ez
                nn = math.sqrt(nx * nx + ny * ny + nz * nz) + 1e-12
                nx, ny, nz = nx / nn, ny / nn, nz / nn
                light = ambient
                for k in range(L):
                    c = nx * light_dirs[k, 0] + ny * light_dirs[k, 1] + nz * light_dirs[k, 2]
                    if c > 0.0:
                        light += light_int[k] * c
                m = mat[p]
                a0, a1, a2 = mat_albedo[m, 0], mat_albedo[m, 1], mat_albedo[m, 2]
            else:
                mask[v, u] = False
                light = ambient
                bits = shadow[v, u]
                for k in range(L):
                    if (bits >> k) & 1 == 0:
                        light += light_int[k] * bg_cos[v, u, k]
                a0, a1, a2 = bg_albedo[v, u, 0], bg_albedo[v, u, 1], bg_albedo[v, u, 2]
            if noise_sigma > 0.0:
                g = _gauss3(key ^ np.uint64(v * W + u))
                n0, n1, n2 = noise_sigma * g[0], noise_sigma * g[1], noise_sigma * g[2]
            else:
                n0 = n1 = n2 = 0.0
            for ch in range(3):
                a = a0 if ch == 0 else (a1 if ch == 1 else a2)
                val = 255.0 * a * light * scale_bgr[ch] + (n0 if ch == 0 else (n1 if ch == 1 else n2))
                val = math.floor(val + 0.5)
                if val < 0.0:
                    val = 0.0
                elif val > 255.0:
                    val = 255.0
                out[v, u, ch] = np.uint8(val)
