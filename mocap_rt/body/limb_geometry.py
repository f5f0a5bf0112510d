"""Numba geometry of the analytic IK's limbs (``body.analytic``) and their joint limits.

``_two_link`` places the middle joint of a two-link limb (A.5: direction + clamped
distance, bent towards a pole), ``_frame`` builds a bone frame, ``joint_violation`` measures
how far a joint's angles leave the range-of-motion table (the fit's measure; the shoulder's
as swing and twist), and
``_arm_pole`` re-bends an arm that the fixed elbow pole puts out of range
(``AnalyticConfig.elbow_pole_candidates``). Vectors are (3,) float64, world frame; angles
radians; lengths metres.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from mocap_rt.body.kinematics import other_xyz_name
from mocap_rt.body.silhouette import points_cost

# Relative reach below which a limb is treated as folded (avoids the |L1 - L2| singularity).
MIN_REACH_FRAC = 0.05


@njit(cache=True, nogil=True)
def _cross(a, b):
    out = np.empty(3)
    out[0] = a[1] * b[2] - a[2] * b[1]
    out[1] = a[2] * b[0] - a[0] * b[2]
    out[2] = a[0] * b[1] - a[1] * b[0]
    return out


@njit(cache=True, nogil=True)
def _unit_or_none(v):
    """``v`` / |v|, or None where |v| is ~0 or not finite: callers that would build a fallback
    array build it only when it is needed (arrays cost more than the maths here)."""
    n = np.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2])
    if n > 1e-9 and np.isfinite(n):
        return v / n
    return None


@njit(cache=True, nogil=True)
def _nunit(v, fallback):
    """``v`` / |v|, or a copy of ``fallback`` where ``_unit_or_none`` finds no direction."""
    u = _unit_or_none(v)
    return fallback.copy() if u is None else u


@njit(cache=True, nogil=True)
def _reach(dist, L1, L2):
    """(L, cos_a): the distance ``dist`` (m) from a two-link limb's root to its goal clamped into
    the reachable [|L1 - L2|, L1 + L2] (folded no tighter than ``MIN_REACH_FRAC``), and the
    cosine of the first link's angle to the root -> end line (law of cosines at the root)."""
    lo = max(abs(L1 - L2), MIN_REACH_FRAC * (L1 + L2))
    hi = (L1 + L2) * (1 - 1e-9)
    L = min(max(dist, lo), hi)
    return L, min(1.0, max(-1.0, (L1 * L1 + L * L - L2 * L2) / (2 * L1 * L)))


@njit(cache=True, nogil=True)
def _two_link(root, goal, L1, L2, pole):
    """Middle joint and reached end of a 2-link chain (A.5 direction + clamped distance).

    The end always lies on the ray root -> goal, at the goal's distance clamped into
    [|L1 - L2|, L1 + L2]; the middle joint bends towards ``pole`` (3,) (unit).
    Returns (middle (3,), end (3,)) metres and the unit vectors u (root -> end) and w
    (the bending direction, perpendicular to u), all (3,).
    """
    d = goal - root
    dist = np.sqrt(d @ d)
    u = _unit_or_none(d)
    if u is None:
        u = -pole if abs(pole[2]) < 0.9 else np.array([0.0, 0.0, -1.0])
    L, cos_a = _reach(dist, L1, L2)
    w = _unit_or_none(pole - u * (pole @ u))
    if w is None:
        w = _nunit(_cross(u, np.array([1.0, 0.0, 0.0])), np.array([0.0, 1.0, 0.0]))
    mid = root + L1 * (cos_a * u + np.sqrt(1 - cos_a * cos_a) * w)
    return mid, root + L * u, u, w


@njit(cache=True, nogil=True)
def _rot_about(axis, angle, v):
    axis = axis / np.sqrt(axis @ axis)
    c, s = np.cos(angle), np.sin(angle)
    return v * c + _cross(axis, v) * s + axis * (axis @ v) * (1 - c)


@njit(cache=True, nogil=True)
def _frame(z, x_hint, out):
    """Write into ``out`` (3, 3) the frame with Z along ``z`` and X nearest ``x_hint``."""
    z = _unit_or_none(z)
    if z is None:
        z = np.array([0.0, 0.0, -1.0])
    x = _unit_or_none(x_hint - z * (x_hint @ z))
    if x is None:
        x = _nunit(_cross(np.array([0.0, 1.0, 0.0]), z), np.array([1.0, 0.0, 0.0]))
    y = _cross(z, x)
    for i in range(3):
        out[i, 0], out[i, 1], out[i, 2] = x[i], y[i], z[i]


@njit(cache=True, nogil=True)
def _range_excess(a, lo, hi):
    """How far (radians) the angle ``a`` lies outside [lo, hi] (0 inside)."""
    return max(0.0, lo - a) + max(0.0, a - hi)


@njit(cache=True, nogil=True)
def joint_violation(ang, lo, hi, dof, j):
    """Limit violation (radians) of joint j: how far its moving angles ``ang`` (J, 3) lie
    outside ``lo``, ``hi`` (J, 3) radians (``dof`` (J, 3) bool), summed; a joint whose Y range
    passes the horizontal (the shoulder) judged as swing and twist (``_swing_twist_violation``)."""
    if dof[j, 0] and dof[j, 1] and dof[j, 2] and max(abs(lo[j, 1]), abs(hi[j, 1])) > 0.5 * np.pi:
        return _swing_twist_violation(ang[j, 0], ang[j, 1], ang[j, 2], lo[j], hi[j])
    v = 0.0
    for q in range(3):
        if dof[j, q]:
            v += _range_excess(ang[j, q], lo[j, q], hi[j, q])
    return v


TWIST_FULL_WEIGHT_RAD = 0.75 * np.pi   # elevation up to which the twist limit holds in full


@njit(cache=True, nogil=True)
def _swing_twist_violation(x, y, z, lo, hi):
    """Limit violation (radians) of a joint that swings past the horizontal (the shoulder;
    X-Y-Z angles x, y, z, limits lo, hi (3,)), judged as swing and twist:

    * swing: where the bone points, from the X and Y limits: of the |Y| <= pi/2 name below
      the horizontal (the X range is the extension limit there), of the better of the two
      names above it (an arm raised sideways past the shoulder has only (x + pi, pi - y));
    * twist: the rotation about the bone left after the minimal swing of the rest frame (Z
      down) onto the bone, against the Z limits. It equals Z near the rest pose and stays
      near 0 on a plain raise in any plane, where an Euler name's Z reaches pi (Codman's
      paradox). The minimal swing is undefined with the bone straight up, so the twist's
      limit fades from full weight at ``TWIST_FULL_WEIGHT_RAD`` of elevation to none at pi.

    A rotation that both names' boxes admit (``_viol3``), a hanging arm turned about itself
    by pi ((x + pi, pi - y, z) with x, y small), has a twist of pi: its elbow bends backwards."""
    cx, sx, cy, sy, cz, sz = np.cos(x), np.sin(x), np.cos(y), np.sin(y), np.cos(z), np.sin(z)
    d0, d1, d2 = sy, -sx * cy, cx * cy                                      # the bone: M[:, 2]
    m00, m10, m20 = cy * cz, cx * sz + sx * sy * cz, sx * sz - cx * sy * cz  # M[:, 0]
    sw = _range_excess(x, lo[0], hi[0]) + _range_excess(y, lo[1], hi[1])
    if d2 < 0.0:                                                          # above the horizontal
        x2, y2, _ = other_xyz_name(x, y, z)
        sw = min(sw, _range_excess(x2, lo[0], hi[0]) + _range_excess(y2, lo[1], hi[1]))
    w = min(1.0, (np.pi - np.arccos(min(1.0, max(-1.0, d2)))) / (np.pi - TWIST_FULL_WEIGHT_RAD))
    if w <= 0.0:
        return sw
    k = 1.0 / (1.0 + d2)                                # minimal swing of e_z onto d: its e_x image
    r0, r1, r2 = 1.0 - d0 * d0 * k, -d0 * d1 * k, -d0
    c = r0 * m00 + r1 * m10 + r2 * m20
    s = d0 * (r1 * m20 - r2 * m10) + d1 * (r2 * m00 - r0 * m20) + d2 * (r0 * m10 - r1 * m00)
    return sw + w * _range_excess(np.arctan2(s, c), lo[2], hi[2])


@njit(cache=True, nogil=True)
def _viol3(x, y, z, lo, hi):
    """Limit violation (radians) of a 3-DOF rotation with X-Y-Z angles (x, y, z), limits lo,
    hi (3,): the smaller over its two decompositions, (x, y, z) with |y| <= pi/2
    (``euler_xyz_from_matrix``) and (x + pi, pi - y, z + pi) (wrapped); an arm raised
    sideways above the shoulder (abduction > 90 deg) has only the second name."""
    v1 = _range_excess(x, lo[0], hi[0]) + _range_excess(y, lo[1], hi[1]) + _range_excess(z, lo[2], hi[2])
    x2, y2, z2 = other_xyz_name(x, y, z)
    return min(v1, _range_excess(x2, lo[0], hi[0]) + _range_excess(y2, lo[1], hi[1]) + _range_excess(z2, lo[2], hi[2]))


@njit(cache=True, nogil=True)
def _pole_circle(shoulder, hand, L1, L2, pole):
    """The circle of the elbow about shoulder -> hand: (d = hand - shoulder, u = unit(d), w0 =
    the pole's unit part normal to u, v0 = u x w0, ca, sa = cosine and sine of the upper arm's
    angle to u); the elbow bent towards the pole turned by t about d is
    shoulder + L1 (ca u + sa (cos t w0 + sin t v0)) (``_two_link``). u is NaN when the circle
    is undefined (hand on the shoulder, or the pole along the arm)."""
    d = hand - shoulder
    dist = np.sqrt(d @ d)
    w0 = pole - d * ((pole @ d) / max(dist * dist, 1e-300))
    nw = np.sqrt(w0 @ w0)
    if dist < 1e-9 or nw < 1e-9:
        nan = np.full(3, np.nan)
        return d, nan, nan, nan, 1.0, 0.0
    u = d / dist
    w0 = w0 / nw
    _, ca = _reach(dist, L1, L2)
    return d, u, w0, _cross(u, w0), ca, np.sqrt(1 - ca * ca)


@njit(cache=True, nogil=True)
def _elbow_cost(shoulder, hand, L1, u, w0, v0, ca, sa, k, n, views, w_elbow, turn_cost, base, pts):
    """``_arm_pole``'s cost of candidate k (of n, on the circle of ``_pole_circle``) with its
    elbow measured: ``base`` (its violation + twist) + ``w_elbow`` * the mean squared distance
    (m^2) outside the silhouettes ``views`` (P, f, grid, dt, dt_off) of the upper arm's
    middle, the elbow and the forearm's middle (``silhouette.points_cost``) + ``turn_cost``
    per degree the pole turned; ``pts`` (3, 3) scratch."""
    t = 2.0 * np.pi * k / n
    c, s = np.cos(t), np.sin(t)
    for i in range(3):
        e = shoulder[i] + L1 * (ca * u[i] + sa * (c * w0[i] + s * v0[i]))
        pts[0, i] = 0.5 * (shoulder[i] + e)
        pts[1, i] = e
        pts[2, i] = 0.5 * (e + hand[i])
    return base + (w_elbow * points_cost(pts, views[0], views[1], views[2], views[3], views[4])
                   + turn_cost * 360.0 * min(k, n - k) / n)


@njit(cache=True, nogil=True)
def _pole_costs(u, w0, v0, ca, sa, axes, lim, n, twist_cost, out, stop_within):
    """Each candidate's shoulder violation (deg, ``_viol3``: either name of the rotation) +
    ``twist_cost`` * |twist| (deg; the Euler Z of the |Y| <= 90 deg name) into ``out`` (n,),
    for the pole turned by k * 360/n deg about the circle of ``_pole_circle``; with
    ``stop_within``, False as soon as the given pole (k = 0) is within the limits.

    No arrays per candidate: ``_two_link`` bent towards the pole turned by t has the upper
    arm z = ca u + sa w, w = cos t w0 + sin t v0, and ``_frame`` gives x = w x u = sin t w0 -
    cos t v0, y = z x x = ca w - sa u; the shoulder's matrix relative to the trunk at rest
    (columns right, -forward, -up) is read from their dot products with the body ``axes``
    (3, 3), as ``euler_xyz_from_matrix`` does."""
    # e . (u, w0, v0) for e = right, -forward, -up (the rest frame's columns)
    eu, ew, ev = np.empty(3), np.empty(3), np.empty(3)
    for a in range(3):
        sg = 1.0 if a == 0 else -1.0
        eu[a] = sg * (axes[0, a] * u[0] + axes[1, a] * u[1] + axes[2, a] * u[2])
        ew[a] = sg * (axes[0, a] * w0[0] + axes[1, a] * w0[1] + axes[2, a] * w0[2])
        ev[a] = sg * (axes[0, a] * v0[0] + axes[1, a] * v0[1] + axes[2, a] * v0[2])
    cd, sd = np.cos(2.0 * np.pi / n), np.sin(2.0 * np.pi / n)
    c, s = 1.0, 0.0
    for k in range(n):
        if k > 0:
            c, s = c * cd - s * sd, s * cd + c * sd
        m02 = ca * eu[0] + sa * (c * ew[0] + s * ev[0])          # M[a, 2] = e_a . z
        m12 = ca * eu[1] + sa * (c * ew[1] + s * ev[1])
        m22 = ca * eu[2] + sa * (c * ew[2] + s * ev[2])
        sb = min(1.0, max(-1.0, m02))
        ay = np.arcsin(sb)
        if abs(sb) < 1.0 - 1e-12:
            ax = np.arctan2(-m12, m22)
            az = np.arctan2(-(ca * (c * ew[0] + s * ev[0]) - sa * eu[0]), s * ew[0] - c * ev[0])  # -M01, M00
        else:
            ax = np.arctan2(ca * (c * ew[2] + s * ev[2]) - sa * eu[2], ca * (c * ew[1] + s * ev[1]) - sa * eu[1])
            az = 0.0
        viol = _viol3(ax, ay, az, lim[:, 0], lim[:, 1])
        if k == 0 and viol == 0.0 and stop_within:
            return False
        out[k] = np.degrees(viol) + twist_cost * np.degrees(abs(az))
    return True


@njit(cache=True, nogil=True)
def _arm_pole(shoulder, hand, L1, L2, pole, axes, lim, n, twist_cost, views, w_elbow, turn_cost):
    """The elbow's pole (3,) for the two-link arm shoulder -> hand (metres, world; L1, L2
    the upper arm and forearm + hand): ``pole`` turned about shoulder -> hand by the
    k * 360/n deg (k < n) of least ``_pole_costs`` (shoulder violation + twist: among arms
    within the limits, the one nearest the neutral rotation), ``pole`` itself while it keeps
    the shoulder within ``lim`` (3, 2) radians. The elbow's flexion is fixed by the reach,
    not the pole, so the shoulder decides alone. ``axes`` (3, 3) the trunk's (right, forward,
    up) columns. Why: the fixed pole ("backwards and down") is the hanging arm's; a hand at
    the face or on the head bends the elbow out or forwards.

    With ``w_elbow`` > 0 the elbow decides too: every candidate, the given pole included,
    costs ``_elbow_cost`` (its elbow against the silhouettes ``views``, plus ``turn_cost``
    per degree turned), evaluated only where it can win: the silhouette term is >= 0, so a
    candidate whose cost without it exceeds a cost found (first the least such cost's) is
    passed over, which chooses exactly what scoring every candidate does.
    """
    d, u, w0, v0, ca, sa = _pole_circle(shoulder, hand, L1, L2, pole)
    if not np.isfinite(u[0]):
        return pole
    base = np.empty(n)
    scored = w_elbow > 0.0
    if not _pole_costs(u, w0, v0, ca, sa, axes, lim, n, twist_cost, base, not scored):
        return pole
    if not scored:
        return _rot_about(d, 2.0 * np.pi * np.argmin(base) / n, pole)
    bound = np.empty(n)
    for k in range(n):
        bound[k] = base[k] + turn_cost * 360.0 * min(k, n - k) / n
    pts = np.empty((3, 3))
    k0 = np.argmin(bound)
    cost0 = _elbow_cost(shoulder, hand, L1, u, w0, v0, ca, sa, k0, n, views, w_elbow, turn_cost, base[k0], pts)
    best, best_k = np.inf, 0
    for k in range(n):
        if bound[k] > cost0 or bound[k] > best:
            continue
        cost = cost0 if k == k0 else _elbow_cost(shoulder, hand, L1, u, w0, v0, ca, sa, k, n, views, w_elbow,
                                                 turn_cost, base[k], pts)
        if cost < best:
            best, best_k = cost, k
    return _rot_about(d, 2.0 * np.pi * best_k / n, pole)
