"""The procedural motions (``MOTIONS``): smooth keyframe scripts, varied per seed, and
``generate(name, seed)``, a motion as a BVH clip (the skeleton and the solver: ``procedural``).

Every motion is written in the *body frame* of its start (x forward, y the subject's
left, z up, metres; origin on the floor under the pelvis) and carried into the world by a
per-frame origin and heading. Keyframes are joined by minimum-jerk segments
(``10 s^3 - 15 s^4 + 6 s^5``: zero velocity and acceleration at every key), steps by
min-jerk swings with a lift. The seed draws an amplitude and a tempo factor
(0.85-1.15 each), the initial heading, the leading side and motion-specific choices.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from mocap_rt.io.bvh import BvhClip
from mocap_rt.studio.procedural import (DEFAULT_FPS, DEFAULT_SECONDS, Script, SkeletonGeometry, Timeline,
                                         min_jerk, skeleton_geometry, solve_script)

G_MPS2 = 9.81
HANG_DEG = 8.0            # arm elevation of hanging arms (clears the hips)
REACH = 0.985             # fraction of the arm length used for a "straight" arm


def _rz(h: np.ndarray) -> np.ndarray:
    c, s = np.cos(h), np.sin(h)
    z, o = np.zeros_like(h), np.ones_like(h)
    return np.stack([np.stack([c, -s, z], -1), np.stack([s, c, z], -1), np.stack([z, z, o], -1)], -2)


@dataclass
class Body:
    """A motion under construction, body frame of the start (see the module doc)."""

    g: SkeletonGeometry
    tl: Timeline
    origin: np.ndarray       # (F, 3) floor point under the pelvis, start body frame
    heading: np.ndarray      # (F,) rad relative to the start heading
    pelvis: np.ndarray       # (F, 3) relative to origin, current heading frame
    trunk: np.ndarray
    neck: np.ndarray
    ankles: np.ndarray       # (F, 2, 3) current heading frame, or world when ``feet_world``
    foot_heading: np.ndarray  # (F, 2) relative to the start heading
    hands: np.ndarray
    elbow_pole: np.ndarray
    knee_pole: np.ndarray
    feet_world: bool = False

    @classmethod
    def standing(cls, g: SkeletonGeometry, tl: Timeline) -> "Body":
        F, lm = tl.n, g.landmarks
        hips = lm["hip_offsets"]
        b = cls(g, tl, np.zeros((F, 3)), np.zeros(F), np.tile([0.0, 0.0, lm["pelvis_z"]], (F, 1)),
                np.zeros((F, 3)), np.zeros(F),
                np.tile([[hips[0, 0], hips[0, 1], g.ankle_height_m], [hips[1, 0], hips[1, 1], g.ankle_height_m]],
                        (F, 1, 1)), np.zeros((F, 2)), np.zeros((F, 2, 3)),
                np.tile([[-1.0, 0.4, -0.2], [-1.0, -0.4, -0.2]], (F, 1, 1)),
                np.tile([[1.0, 0.15, 0.0], [1.0, -0.15, 0.0]], (F, 1, 1)))
        for k in range(2):
            b.hands[:, k] = b.arm(k, np.radians(HANG_DEG), 0.0)
        return b

    # landmarks that follow the pelvis and the trunk's forward bend (approximate)
    def _follow(self, name: str) -> np.ndarray:
        lm = self.g.landmarks
        rel = lm[name] - np.array([0.0, 0.0, lm["pelvis_z"]])
        a = self.trunk[:, 0]
        rot = np.stack([np.cos(a) * rel[0] + np.sin(a) * rel[2], np.full_like(a, rel[1]),
                        -np.sin(a) * rel[0] + np.cos(a) * rel[2]], -1)
        return self.pelvis + rot

    def shoulder(self, k: int) -> np.ndarray:
        return self._follow(("shoulder_l", "shoulder_r")[k])

    def head(self) -> np.ndarray:
        return self._follow("head")

    def arm(self, k: int, elevation, plane, reach: float = REACH) -> np.ndarray:
        """(F, 3) hand centre of a straight-ish arm: ``elevation`` from hanging (rad; 0 down,
        pi up, negative = behind), ``plane`` 0 = sideways, pi/2 = forward."""
        e = np.broadcast_to(np.asarray(elevation, float), (self.tl.n,))
        p = np.broadcast_to(np.asarray(plane, float), (self.tl.n,))
        out = 1.0 if k == 0 else -1.0
        d = np.stack([np.sin(e) * np.sin(p), out * np.sin(e) * np.cos(p), -np.cos(e)], -1)
        return self.shoulder(k) + reach * self.g.arm_m * d

    def steps(self, windows: list[tuple[int, float, float, float, Callable | float]]) -> None:
        """Feet locked to the floor except in swing ``windows`` (side, t0, t1, t_target, lift):
        from its place at t0 the foot swings (min-jerk) to where the nominal ``ankles``
        (body frame) are at t_target; lift: metres (h sin(pi s)) or a function of s."""
        world = self.to_world(self.ankles)
        fh = self.heading[:, None] + self.foot_heading
        ank, head = world.copy(), fh.copy()
        for k in range(2):
            wins = sorted((w for w in windows if w[0] == k), key=lambda w: w[1])
            pos, hd, w_i = world[0, k].copy(), fh[0, k], 0
            start = None
            for f, t in enumerate(self.tl.t):
                while w_i < len(wins) and t > wins[w_i][2]:
                    _, _, _, tt, _ = wins[w_i]
                    pos, hd = world[self.tl.frame(tt), k].copy(), fh[self.tl.frame(tt), k]
                    pos[2] = world[self.tl.frame(tt), k, 2]
                    w_i, start = w_i + 1, None
                if w_i < len(wins) and t >= wins[w_i][1]:
                    _, t0, t1, tt, lift = wins[w_i]
                    start = start or (pos.copy(), hd)
                    s = (t - t0) / (t1 - t0)
                    m = min_jerk(np.array(s))
                    tgt, thd = world[self.tl.frame(tt), k], fh[self.tl.frame(tt), k]
                    ank[f, k] = start[0] + m * (tgt - start[0])
                    ank[f, k, 2] += lift(s) if callable(lift) else lift * np.sin(np.pi * s)
                    head[f, k] = start[1] + m * (np.angle(np.exp(1j * (thd - start[1]))))
                else:
                    ank[f, k], head[f, k] = pos, hd
        self.ankles, self.foot_heading, self.feet_world = ank, head - self.heading[:, None], True

    def to_world(self, local: np.ndarray, direction: bool = False) -> np.ndarray:
        """Body-frame points (F, ..., 3) -> start body frame."""
        R = _rz(self.heading)
        extra = local.ndim - 2
        R = R.reshape((self.tl.n,) + (1,) * extra + (3, 3))
        out = np.einsum("...ij,...j->...i", R, local)
        if not direction:
            out = out + self.origin.reshape((self.tl.n,) + (1,) * extra + (3,))
        return out

    def script(self) -> Script:
        """The world script (the start body frame turned to ``heading0``)."""
        h0 = self.tl.heading0
        w = lambda x: x @ _rz(np.array(h0)).T  # noqa: E731
        ankles = self.ankles if self.feet_world else self.to_world(self.ankles)
        return Script(w(self.to_world(self.pelvis)), self.heading + h0, self.trunk, self.neck, w(ankles),
                      self.foot_heading + self.heading[:, None] + h0, w(self.to_world(self.hands)),
                      w(self.to_world(self.elbow_pole, True)), w(self.to_world(self.knee_pole, True)))


# ----------------------------------------------------------------------------- motions

def _rad(deg) -> np.ndarray:
    return np.radians(np.asarray(deg, dtype=np.float64))


def sidestep(g: SkeletonGeometry, tl: Timeline) -> Script:
    """Side steps: the leading foot steps out, the other closes; half the cycles one way."""
    b = Body.standing(g, tl)
    P, step = 1.1 / tl.tempo, 0.30 * tl.amp
    n = int(tl.seconds // P)
    lat, y, wins = [0.0], 0.0, []
    for c in range(n):
        d = 1.0 if (c < (n + 1) // 2) == (tl.side == 0) else -1.0
        lead = 0 if d > 0 else 1
        wins += [(lead, c * P + 0.05 * P, c * P + 0.45 * P, (c + 1) * P, 0.06),
                 (1 - lead, c * P + 0.5 * P, c * P + 0.9 * P, (c + 1) * P, 0.05)]
        y += d * step
        lat.append(y)
    times = np.concatenate([[0.0], np.arange(1, n + 1) * P])
    b.origin[:, 1] = tl.keys(times, lat)
    b.steps(wins)
    b.pelvis[:, 2] -= 0.015 * np.sin(np.pi * tl.t / P) ** 2
    for k in range(2):
        b.hands[:, k] = b.arm(k, _rad(HANG_DEG + 10 * np.sin(np.pi * tl.t / P) ** 2), 0.2)
    return b.script()


def _crouch_fraction(tl: Timeline, period: float) -> np.ndarray:
    return tl.cycle_keys(period, [0, 0.4 * period, 0.6 * period, 0.85 * period, period], [0, 1, 1, 0, 0])


def crouch(g: SkeletonGeometry, tl: Timeline) -> Script:
    """Deep knee bends (crouch) with the trunk leaning and the arms forward for balance."""
    b = Body.standing(g, tl)
    f = _crouch_fraction(tl, 3.0 / tl.tempo)
    depth = min(0.36 * tl.amp, 0.40)
    b.pelvis += np.stack([-0.10 * f, 0 * f, -depth * f], -1)
    b.trunk[:, 0] = _rad(25) * f
    b.knee_pole[:] = [[1.0, 0.3, 0.0], [1.0, -0.3, 0.0]]
    for k in range(2):
        b.hands[:, k] = b.arm(k, _rad(HANG_DEG + 70 * f), _rad(75), reach=0.9)
    return b.script()


def arms_overhead(g: SkeletonGeometry, tl: Timeline) -> Script:
    """Both arms raised above the head (plane of elevation between sideways and forward)."""
    b = Body.standing(g, tl)
    P = 3.0 / tl.tempo
    f = tl.cycle_keys(P, np.array([0, 0.15, 0.45, 0.65, 0.95, 1.0]) * P, [0, 0, 1, 1, 0, 0])
    e_max = _rad(min(170.0, 155.0 * tl.amp))
    plane = tl.rng.uniform(0.1, 1.2)
    for k in range(2):
        b.hands[:, k] = b.arm(k, _rad(HANG_DEG) + (e_max - _rad(HANG_DEG)) * f, plane)
    return b.script()


def _hang(b: Body, k: int) -> np.ndarray:
    return b.arm(k, _rad(HANG_DEG), 0.0)


def _out(k: int) -> float:
    return 1.0 if k == 0 else -1.0


def _path(b: Body, k: int, times, points: list[np.ndarray]) -> np.ndarray:
    """Hand k through keyframe points (each (F, 3) or (3,)), min-jerk per frame-varying key."""
    pts = [np.broadcast_to(p, (b.tl.n, 3)) for p in points]
    w = b.tl.keys(times, np.eye(len(pts)))                 # (F, K) blend weights, one key active
    return np.einsum("fk,kfi->fi", w, np.stack(pts))


def hands_cross_face(g: SkeletonGeometry, tl: Timeline) -> Script:
    """Both hands up in front of the face, crossing and uncrossing there (left hand nearer)."""
    b = Body.standing(g, tl)
    T, amp = tl.seconds, tl.amp
    n_sweeps = max(2, int(round(3 * tl.tempo)))
    times = np.concatenate([[0.0, 0.1 * T, 0.25 * T], np.linspace(0.3 * T, 0.75 * T, n_sweeps), [0.85 * T, T]])
    head = b.head()
    for k in range(2):
        chest = b.shoulder(k) + [0.30 + 0.09 * k, -_out(k) * 0.10, -0.10]
        near = [0.20 + 0.09 * k, 0.0, -0.02 * k]
        cross = head + np.add(near, [0, -_out(k) * 0.11 * amp, 0])
        open_ = head + np.add(near, [0, _out(k) * 0.10 * amp, 0])
        sweep = [cross if i % 2 == 0 else open_ for i in range(n_sweeps)]
        b.hands[:, k] = _path(b, k, times, [_hang(b, k), _hang(b, k), chest] + sweep + [chest, _hang(b, k)])
        b.elbow_pole[:, k] = [-0.2, _out(k), -0.6]
    return b.script()


def _flight(h: float) -> tuple[float, Callable]:
    """Flight time (s) of a jump of height h (m) and its height profile over s in [0, 1]."""
    return 2.0 * np.sqrt(2.0 * h / G_MPS2), lambda s: 4.0 * h * s * (1.0 - s)


def _airborne(tl: Timeline, flights) -> np.ndarray:
    """(F,) height of the body above its stance over the flight windows (side, to, land, _, lift)."""
    air = np.zeros(tl.n)
    for _, to, land, _, lift in flights:
        s = (tl.t - to) / (land - to)
        air += np.where((s > 0) & (s < 1), lift(np.clip(s, 0, 1)), 0.0)
    return air


def jump(g: SkeletonGeometry, tl: Timeline) -> Script:
    """Vertical jumps (a small random hop each): dip, arm swing, flight, landing."""
    b = Body.standing(g, tl)
    h = 0.18 * tl.amp
    tf, lift = _flight(h)
    P = max(1.9 / tl.tempo, 1.1 + tf)
    dip, arm, wins, tz, z, ta, ea, hop = [0.0], [0.0], [], [0.0], [0.0], [0.0], [HANG_DEG], [np.zeros(2)]
    for c in range(int(tl.seconds // P)):
        t0 = c * P + 0.1
        to, land = t0 + 0.5, t0 + 0.5 + tf
        tz += [t0, t0 + 0.35, to, land, land + 0.15, land + 0.5]
        z += [0, 1, 0, 0, 0.7, 0]
        ta += [t0, t0 + 0.3, land, land + 0.5]
        ea += [HANG_DEG, -30, 110, HANG_DEG]
        wins += [(k, to, land, land, lift) for k in range(2)]
        hop.append(hop[-1] + tl.rng.uniform(-0.12, 0.12, 2))
        dip.append(land)
    bend = tl.keys(tz + [tl.seconds + 1], z + [0])
    b.origin[:, :2] = tl.keys(dip + [tl.seconds + 1], np.array(hop + [hop[-1]]))
    b.steps(wins)
    air = _airborne(tl, wins[::2])
    b.pelvis[:, 2] += air - 0.14 * bend
    b.trunk[:, 0] = _rad(20) * bend
    e = _rad(tl.keys(ta + [tl.seconds + 1], ea + [HANG_DEG]))
    for k in range(2):
        b.hands[:, k] = b.arm(k, e, _rad(80))
    return b.script()


def jumping_jacks(g: SkeletonGeometry, tl: Timeline) -> Script:
    """Jumping jacks (feet apart + arms overhead, then together + arms down) while
    drifting sideways and turning."""
    b = Body.standing(g, tl)
    h = 0.07 * tl.amp
    tf, lift = _flight(h)
    P = 1.0 / tl.tempo
    rate = tl.rng.choice([-1.0, 1.0]) * _rad(tl.rng.uniform(25, 45))
    b.heading[:] = rate * tl.t
    spread = 0.22 * tl.amp
    times, state, wins, drift, lat = [0.0], [0.0], [], 0.06 * tl.amp * _out(tl.side), [0.0]
    for c in range(int((tl.seconds - 0.2) // P)):
        to = c * P + 0.2
        land = to + tf
        wins += [(k, to, land, land, lift) for k in range(2)]
        times += [to - 0.3 * P, land + 0.05]
        state += [state[-1], 1.0 - state[-1]]
        lat += [lat[-1], lat[-1] + drift]
    open_ = tl.keys(times + [tl.seconds + 1], state + [state[-1]])
    b.origin[:, 1] = tl.keys(times + [tl.seconds + 1], lat + [lat[-1]])
    for k in range(2):
        b.ankles[:, k, 1] += _out(k) * spread * open_
    b.steps(wins)
    air = _airborne(tl, wins[::2])
    b.pelvis[:, 2] += air - 0.05 * open_
    for k in range(2):
        b.hands[:, k] = b.arm(k, _rad(HANG_DEG) + (_rad(155) - _rad(HANG_DEG)) * open_, 0.15)
    return b.script()


def clap(g: SkeletonGeometry, tl: Timeline) -> Script:
    """Hands raised in front of the chest, clapping (the hand centres meet) at ~2 Hz."""
    b = Body.standing(g, tl)
    T, freq = tl.seconds, 1.8 * tl.tempo
    ready = tl.keys([0, 0.6, 1.2, T - 1.0, T - 0.3, T + 1], [0, 0, 1, 1, 0, 0])
    gap_max, gap_min = 0.34 * tl.amp, 0.05
    gap = gap_min + (gap_max - gap_min) * (0.5 + 0.5 * np.cos(2 * np.pi * freq * (tl.t - 1.2)))
    gap = np.where(tl.t < 1.2, gap_max, gap)
    centre = 0.5 * (b.shoulder(0) + b.shoulder(1)) + [0.33, 0.0, -0.12]
    for k in range(2):
        target = centre + np.stack([0 * gap, _out(k) * gap / 2, 0 * gap], -1)
        b.hands[:, k] = _hang(b, k) + ready[:, None] * (target - _hang(b, k))
        b.elbow_pole[:, k] = [-0.3, _out(k), -0.8]
    return b.script()


def _raise_to(b: Body, k: int, target: np.ndarray, hold: tuple[float, float]) -> np.ndarray:
    """Hand k from hanging, through a point beside and above the shoulder, to ``target``,
    held over ``hold`` (s, s), and back."""
    via = b.shoulder(k) + [0.05, _out(k) * 0.30, 0.28]
    t0, t1 = hold
    return _path(b, k, [0, 0.2, t0 - 0.6, t0, t1, t1 + 0.6, b.tl.seconds - 0.2, b.tl.seconds],
                 [_hang(b, k), _hang(b, k), via, target, target, via, _hang(b, k), _hang(b, k)])


def hands_on_head(g: SkeletonGeometry, tl: Timeline) -> Script:
    """Both hands put on top of the head, held, and lowered."""
    b = Body.standing(g, tl)
    hold = (1.8 / tl.tempo, tl.seconds - 1.8 / tl.tempo)
    sway = 0.02 * np.sin(2 * np.pi * 0.7 * tl.t)[:, None] * [1.0, 0, 0]
    for k in range(2):
        b.hands[:, k] = _raise_to(b, k, b.head() + [0.0, _out(k) * 0.07, 0.13] + sway, hold)
        b.elbow_pole[:, k] = [0.3, _out(k) * 0.6, -0.7]
    return b.script()


def hand_behind_head(g: SkeletonGeometry, tl: Timeline) -> Script:
    """One hand (the seed's side) behind the head, held; the other hangs."""
    b = Body.standing(g, tl)
    k = tl.side
    hold = (1.8 / tl.tempo, tl.seconds - 1.8 / tl.tempo)
    b.hands[:, k] = _raise_to(b, k, b.head() + [-0.12, _out(k) * 0.02, 0.03], hold)
    b.elbow_pole[:, k] = [0.3, _out(k) * 0.6, -0.7]
    return b.script()


def crouch_hands_to_feet(g: SkeletonGeometry, tl: Timeline) -> Script:
    """Crouching with the trunk bent forward and both hands down by the feet."""
    b = Body.standing(g, tl)
    f = _crouch_fraction(tl, 3.0 / tl.tempo)
    b.pelvis += np.stack([-0.10 * f, 0 * f, -min(0.38 * tl.amp, 0.40) * f], -1)
    b.trunk[:, 0] = _rad(70) * f
    b.knee_pole[:] = [[1.0, 0.35, 0.0], [1.0, -0.35, 0.0]]
    for k in range(2):
        feet = b.ankles[:, k] + [0.15, _out(k) * 0.05, 0.05]
        b.hands[:, k] = _hang(b, k) + min_jerk(f)[:, None] * (feet - _hang(b, k))
        b.elbow_pole[:, k] = [-0.2, _out(k), 0.0]
    return b.script()


def feet_cross(g: SkeletonGeometry, tl: Timeline) -> Script:
    """Each foot in turn steps across in front of the other and back."""
    b = Body.standing(g, tl)
    P = 1.6 / tl.tempo
    b.pelvis[:, 2] -= 0.05                   # knees a little bent: the crossing foot reaches
    nominal = b.ankles.copy()
    wins = []
    for c in range(int(tl.seconds // P)):
        k = (c + tl.side) % 2
        t0 = c * P
        crossed = (nominal[:, 1 - k, 1] - _out(k) * 0.10 * tl.amp)
        sel = (tl.t >= t0) & (tl.t < t0 + 0.55 * P)
        b.ankles[sel, k, 0] = nominal[sel, k, 0] + 0.14
        b.ankles[sel, k, 1] = crossed[sel]
        wins += [(k, t0 + 0.05 * P, t0 + 0.35 * P, t0 + 0.35 * P, 0.10),
                 (k, t0 + 0.6 * P, t0 + 0.9 * P, t0 + 0.9 * P, 0.08)]
    b.steps(wins)
    return b.script()


def turn_in_place(g: SkeletonGeometry, tl: Timeline) -> Script:
    """Turning on the spot (70-110 deg/s) with small alternating steps."""
    b = Body.standing(g, tl)
    rate = tl.rng.choice([-1.0, 1.0]) * _rad(tl.rng.uniform(70, 110)) * tl.tempo
    T = tl.seconds
    b.heading[:] = tl.keys([0, 0.3, 0.8, T - 0.8, T - 0.3, T + 1],
                           np.array([0, 0, 0.25, T - 1.35, T - 1.1, T - 1.1]) * rate)
    P = 0.45 / tl.tempo
    wins = [((c + tl.side) % 2, 0.3 + c * P, 0.3 + c * P + 0.8 * P, 0.3 + c * P + 1.2 * P, 0.06)
            for c in range(int((T - 0.3) // P))]
    b.steps(wins)
    return b.script()


MOTIONS: dict[str, Callable[[SkeletonGeometry, Timeline], Script]] = {
    f.__name__: f for f in (sidestep, crouch, arms_overhead, hands_cross_face, jump, jumping_jacks, clap,
                            hands_on_head, hand_behind_head, crouch_hands_to_feet, feet_cross, turn_in_place)}


def generate(name: str, seed: int = 0, seconds: float | None = None, fps: float = DEFAULT_FPS,
             skeleton_path: str | None = None) -> BvhClip:
    """The procedural motion ``name`` (see ``MOTIONS``) for ``seed``, as a BVH clip."""
    if name not in MOTIONS:
        raise ValueError(f"unknown procedural motion {name!r}; known: {', '.join(sorted(MOTIONS))}")
    if fps <= 0 or (seconds is not None and seconds <= 0):
        raise ValueError(f"fps and seconds must be > 0, got {fps}, {seconds}")
    g = skeleton_geometry(skeleton_path)
    tl = Timeline.make(name, int(seed), float(seconds or DEFAULT_SECONDS), float(fps))
    script = MOTIONS[name](g, tl)
    return BvhClip(g.skeleton, solve_script(g, script), 1.0 / fps)
