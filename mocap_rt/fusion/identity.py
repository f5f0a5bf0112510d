"""Left/right identity and heading as competing hypotheses (issue 10, item 3).

A symmetric body seen from a ring of cameras looks almost the same with its hands
exchanged, its feet exchanged, or wholly mirrored (left and right exchanged and the
facing turned by 180 deg): the cue points alone cannot tell these apart, and neither can
the walking direction (people walk backwards and sideways). What can: the silhouettes (a
mirrored body bends its knees and elbows the wrong way and puts the shank at the toe end
of the shoe) and the joint limits (crossed arms or legs twist out of range).

So every frame the current labelling and three alternatives are solved and scored alike
(``score_hypotheses``: the pan searched within +-``pan_search_deg`` of the previous
heading, turned by 180 deg for the mirror, default limb swivels; ``BodyFitter.fit`` cost = limit violation +
silhouette chamfer + pan change). Each alternative's evidence is a leaky sum of how much
cheaper it is than the current one (``decide``); the labels switch when the evidence
passes ``switch_evidence`` and the alternative also wins this frame by ``frame_margin``
plus ``frame_margin_frac`` of the current cost (hysteresis: one odd frame never
switches, and a frame that no hypothesis fits well decides nothing). The mirror exchanges
both pairs, and the pair it adds to the best single-pair swap must be earned: by the
mirror's evidence beating that swap's by the threshold too, or by that pair's own swap
having positive evidence; else the single swap is taken (a cold start with only the hands
wrong fits the mirror 1-2 units better than the hands swap, the feet labels barely mattering,
and must not exchange its right feet). During the first ``acquire_frames`` of a
track the threshold is ``acquire_factor`` times lower, so a cold start on any motion
takes the right identity within a few frames, without a calibration pose.

The legs stand on the heels. Perception measures where each leg's silhouette meets its shoe
blob (``perception.leg_attach``); a body turned round puts its ankles at the toe ends
(``foot_axis``, the legs' term). While a track acquires its identity (the first
``acquire_frames``, when the facing is still open) the hypotheses are scored with that term,
``legs_on_shoes_weight``; it speaks to the facing, not to which foot is which, so only the
current labelling and the mirror are scored with it, and the hands and feet swaps keep their
difference to the current labelling scored without it. Past acquisition it is left out
(docs/body.md, "Foot direction: the heel end": scored on every frame it turned the kicks
round, whose raised leg is not above its shoe).

Past acquisition the hypotheses' elbows are measured on the silhouettes as the pose's are
(``FitConfig.elbow_silhouette``): a hand on the head bends the elbow out, and the fixed pole
("backwards and down") had charged every labelling alike for it. While acquiring they keep
the fixed pole: at a cold start with the arms hanging, measured elbows let the hands swap fit
the arms crossed in front of the body as well as the truth (jumping jacks, frame 0: 20 against
49; with the fixed pole 99), and nothing earlier holds the labels (docs/body.md).

Legs cannot pass through each other (``crossed_legs_cm2``): drawn from the last pose's hips
to the feet cues, the two legs' lines must stay a shin's radius apart. Where the current feet
labels bring them closer and the exchanged labels do not, the depth by which they would pass
through each other (cm^2) is credited to the feet alternative that frame: feet that came out
of a touch exchanged, standing apart side by side, are put right within a few frames, where
the silhouettes and limits gain 2-5 units a frame against the debt of the right past. Only a
credit, never a debit: the exchanged labels' impossibility while the labels are right is no
evidence of anything and must not pile up a debt that a later exchange has to repay.

Feet that stand closer together than the hips (``feet_together``) cannot be told apart by
the fit: the two labellings put the legs within the model's own error of each other, and what
separates their costs is that error (a standing Bandai subject's exchanged feet fit the
silhouettes 1-2.5 cm^2 a frame better, docs/body.md). There the feet alternative is scored as
the current labelling, so that no evidence is summed from it; the crossed legs' credit still
counts. Until a frame has told the feet apart (hips known, feet not together) or a switch has
exchanged them, nothing has decided the feet's labels (``IdentityState.feet_decided``): they
are the cold start's, and a feet switch then reaches back over the whole track, as one
while acquiring does.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from mocap_rt.body.fit import BodyFitter
from mocap_rt.body.foot_axis import legs_only
from mocap_rt.body.silhouette import SilhouetteTargets
from mocap_rt.names import C_HEAD, C_TORSO, LIMB_CUES, LR_PAIRS
from mocap_rt.studio.body_shape import SHIN_RADIUS_M

# the alternatives to the current labelling, and the cue pairs each one exchanges
ALTERNATIVES = ("hands", "feet", "mirror")
HANDS, FEET = LR_PAIRS
ALTERNATIVE_PAIRS = ((HANDS,), (FEET,), (HANDS, FEET))
_MIRROR = ALTERNATIVES.index("mirror")
_FEET = ALTERNATIVES.index("feet")
_HANDS = ALTERNATIVES.index("hands")
_SINGLE = tuple(k for k in range(len(ALTERNATIVES)) if k != _MIRROR)
# Two legs' lines (hip -> foot cue) closer than this (m) pass through each other: a shin's radius
# (the studio's body). The truth's hip -> ankle lines keep >= 5 cm on every suite clip; its hip ->
# foot-cue lines come closer only with the feet touching, where the exchanged labels' do too
LEG_CLEARANCE_M = SHIN_RADIUS_M
# the swivel slots (arm_l, arm_r, leg_l, leg_r) each alternative exchanges
_SWIVEL_ORDER = (np.array([1, 0, 2, 3]), np.array([0, 1, 3, 2]), np.array([1, 0, 3, 2]))


@dataclass(frozen=True)
class IdentityConfig:
    """Hypothesis switching (cost units: degrees of limit violation = cm^2 of silhouette)."""

    enabled: bool = True
    pan_search_deg: float = 15.0    # pan search of every hypothesis around the previous heading
    pan_refine: int = 1             # ... then one halving of the step around the best
    cold_step_deg: float = 15.0     # without a previous heading: the whole circle in these steps
    decay: float = 0.95             # evidence kept per frame
    switch_evidence: float = 25.0   # leaky sum of (current - alternative) costs that switches
    frame_margin: float = 0.0       # ... when the alternative also wins this frame by this
    frame_margin_frac: float = 0.0  # ... plus this fraction of the current cost (a poor fit decides nothing)
    acquire_frames: int = 15        # the first frames of a track ...
    acquire_factor: float = 0.5     # ... switch on this fraction of the evidence
    feet_together_hips: float = 1.0   # feet closer than this many hip widths: their exchange is not scored; 0 = off
    crossed_legs_weight: float = 1.0  # per cm^2 of legs passing through each other (crossed_legs_cm2); 0 = off
    legs_on_shoes_weight: float = 1.0  # per cm^2 of legs meeting the shoes off the ankles (body.foot_axis), while
                                       # acquiring, for the facing only (module doc); 0 = off


@dataclass
class IdentityState:
    """Evidence (3,) per alternative (ALTERNATIVES order), frames seen, switches made.

    won (3,): for how many frames in a row (this one included) each alternative has been
    cheaper than the current labelling, within this track; ``last_switch``: the alternative
    the last switch took and how many frames back it reaches (that count; while acquiring, all
    the track's frames: its labels were the cold start's guess; so too for a feet switch until
    ``feet_decided``). ``feet_decided``: a frame has told the feet apart (set by the caller,
    ``BodyTracker``) or a switch has exchanged them (``decide``).
    """

    evidence: np.ndarray = field(default_factory=lambda: np.zeros(len(ALTERNATIVES)))
    frames: int = 0
    switches: int = 0
    last_costs: np.ndarray = field(default_factory=lambda: np.full(1 + len(ALTERNATIVES), np.nan))
    won: np.ndarray = field(default_factory=lambda: np.zeros(len(ALTERNATIVES), np.int64))
    last_switch: tuple[int, int] = (-1, 0)
    feet_decided: bool = False

    def reset(self) -> None:
        self.evidence[:] = 0.0
        self.frames = 0
        self.won[:] = 0
        self.feet_decided = False


def swap_pairs(X: np.ndarray, k: int) -> np.ndarray:
    """A copy of the cue array X (6, ...) with alternative k's pairs exchanged."""
    X = X.copy()
    for a, b in ALTERNATIVE_PAIRS[k]:
        X[[a, b]] = X[[b, a]]
    return X


def swap_swivel(swivel: np.ndarray, k: int) -> np.ndarray:
    """The limb swivels (4,) relabelled by alternative k."""
    return np.asarray(swivel)[_SWIVEL_ORDER[k]]


def fill_missing(cues: np.ndarray, axes: np.ndarray, rest_cues: np.ndarray) -> np.ndarray:
    """Cues (6, 3) with missing rows put at the rest pose (``rest_cues`` (6, 3), body frame)
    placed with the body ``axes`` (3, 3) at the torso cue (which must be present)."""
    out = cues.copy()
    missing = ~np.isfinite(out).all(axis=1)
    if missing.any():
        out[missing] = out[C_TORSO] + (rest_cues[missing] - rest_cues[C_TORSO]) @ axes.T
    return out


def hold_limbs(held: np.ndarray, cues_ik: np.ndarray, axes: np.ndarray) -> np.ndarray:
    """``held`` (6, 3) with each hand and foot estimated in ``cues_ik`` (6, 3, NaN = not)
    held at its offset from the torso cue in the body frame ``axes`` (3, 3): where the pose
    puts that limb while no view measures it (``PoseSolver.fill_missing``). A hand behind the
    head stays raised, where the rest pose dropped the arm (its hand 0.9 m off)."""
    out = held.copy()
    limbs = np.array(LIMB_CUES)
    known = limbs[np.isfinite(cues_ik[limbs]).all(axis=1)]
    out[known] = (cues_ik[known] - cues_ik[C_TORSO]) @ axes
    return out


def score_hypotheses(fitter: BodyFitter, cues: np.ndarray, rest_cues: np.ndarray, prev_axes: np.ndarray | None,
                     targets: SilhouetteTargets | None, config: IdentityConfig,
                     feet: np.ndarray | None = None, measured_elbows: bool = True,
                     skip: frozenset[int] = frozenset()) -> np.ndarray:
    """Costs (4,): the current labelling, then each of ALTERNATIVES, scored alike; NaN for the
    alternatives in ``skip`` (indices into ALTERNATIVES), which are not fitted.

    cues (6, 3) metres (head and torso finite; missing hands/feet are filled at rest).
    Each hypothesis searches its pan within +-``pan_search_deg`` of the previous body axes
    ``prev_axes`` (3, 3) (turned by 180 deg for the mirror; the body's up from the cues),
    or, without previous axes, over the whole circle in steps of ``cold_step_deg``.
    feet (6, C, 5): the shoe measurements labelled like ``cues`` (``foot_axis.foot_axes``),
    relabelled with each hypothesis (None: not scored). Only where the legs meet the shoes is
    scored, with ``legs_on_shoes_weight`` (the axes are the same for every labelling), and only
    for the facing: the current labelling and the mirror are fitted with it, and the single
    swaps keep their difference to the current labelling fitted without it (module doc).
    ``measured_elbows``: the elbows on the silhouettes (``BodyFitter.fit``), else the fixed pole.
    """
    feet = legs_only(feet, config.legs_on_shoes_weight)
    up = cues[C_HEAD] - cues[C_TORSO]
    up = up / max(float(np.linalg.norm(up)), 1e-9)
    right = np.array([1.0, 0.0, 0.0]) if prev_axes is None else prev_axes[:, 0]
    right = right - up * (right @ up)
    right = right / max(float(np.linalg.norm(right)), 1e-9)

    def cost(h: int, legs: bool) -> float:
        if h - 1 in skip:
            return np.nan
        X = cues if h == 0 else swap_pairs(cues, h - 1)
        F = None if not legs else feet if h == 0 else swap_pairs(feet, h - 1)
        r = -right if (h == 1 + _MIRROR and prev_axes is not None) else right
        axes = np.column_stack([r, np.cross(up, r), up])
        X = fill_missing(X, axes, rest_cues)
        if prev_axes is None:
            return fitter.fit(X, axes, None, targets, search_swivel=False, pan_search_deg=180.0,
                              pan_step_deg=config.cold_step_deg, feet=F, measured_elbows=measured_elbows).cost
        return fitter.fit(X, axes, None, targets, search_swivel=False, pan_search_deg=config.pan_search_deg,
                          pan_refine=config.pan_refine, feet=F, measured_elbows=measured_elbows).cost

    if feet is None:
        return np.array([cost(h, False) for h in range(1 + len(ALTERNATIVES))])
    # the legs score the facing: the current labelling and the mirror with them; the single
    # swaps keep their difference to the current one without them (each pan fitted to its
    # own objective)
    costs = np.empty(1 + len(ALTERNATIVES))
    single = [1 + k for k in _SINGLE]
    costs[single] = [cost(h, False) for h in single]
    with_legs = cost(0, True)
    costs[single] += with_legs - cost(0, False)
    costs[0], costs[1 + _MIRROR] = with_legs, cost(1 + _MIRROR, True)
    return costs


def segment_distance(p1: np.ndarray, q1: np.ndarray, p2: np.ndarray, q2: np.ndarray) -> float:
    """Least distance between the segments p1-q1 and p2-q2 (3,) (closest points with clamped
    parameters, Ericson, Real-Time Collision Detection, 5.1.9), in their units."""
    d1, d2, r = q1 - p1, q2 - p2, p1 - p2
    a, e, f = float(d1 @ d1), float(d2 @ d2), float(d2 @ r)
    eps = 1e-12
    if a <= eps and e <= eps:
        return float(np.linalg.norm(r))
    if a <= eps:
        s, t = 0.0, float(np.clip(f / e, 0.0, 1.0))
    else:
        c = float(d1 @ r)
        if e <= eps:
            s, t = float(np.clip(-c / a, 0.0, 1.0)), 0.0
        else:
            b = float(d1 @ d2)
            den = a * e - b * b
            s = float(np.clip((b * f - c * e) / den, 0.0, 1.0)) if den > eps else 0.0
            t = (b * s + f) / e
            if t < 0.0:
                s, t = float(np.clip(-c / a, 0.0, 1.0)), 0.0
            elif t > 1.0:
                s, t = float(np.clip((b - c) / a, 0.0, 1.0)), 1.0
    return float(np.linalg.norm(p1 + s * d1 - (p2 + t * d2)))


def _hips_and_feet_known(hips: np.ndarray | None, cues: np.ndarray) -> bool:
    """The ``hips`` (2, 3) given and finite, and both feet cues of ``cues`` (6, 3) finite."""
    return hips is not None and bool(np.isfinite(hips).all()) and bool(np.isfinite(cues[list(FEET)]).all())


def feet_together(hips: np.ndarray | None, cues: np.ndarray, factor: float) -> bool:
    """The feet cues (of ``cues`` (6, 3)) lie closer together than ``factor`` times the
    distance between the ``hips`` (2, 3) (a recent pose's; None or NaN: False)."""
    if factor <= 0 or not _hips_and_feet_known(hips, cues):
        return False
    fl, fr = FEET
    return bool(np.linalg.norm(cues[fl] - cues[fr]) < factor * np.linalg.norm(hips[0] - hips[1]))


def feet_told_apart(hips: np.ndarray | None, cues: np.ndarray, factor: float) -> bool:
    """The fit can tell the feet apart: the ``hips`` and both feet cues known, and the feet not
    ``feet_together`` (what decides their labels, ``IdentityState.feet_decided``)."""
    return _hips_and_feet_known(hips, cues) and not feet_together(hips, cues, factor)


def crossed_legs_cm2(hips: np.ndarray | None, cues: np.ndarray, clearance_m: float = LEG_CLEARANCE_M) -> float:
    """How deep (cm^2) the legs, drawn as lines from the ``hips`` (2, 3) (left, right, metres,
    world; a recent pose's) to the feet ``cues`` (6, 3), pass through each other: ``(clearance
    - d)^2`` where their distance d is under ``clearance_m`` and the exchanged feet's legs keep
    at least ``clearance_m``; else 0 (legs apart, or both labellings crossed: feet together)."""
    if not _hips_and_feet_known(hips, cues):
        return 0.0
    fl, fr = FEET
    d = segment_distance(hips[0], cues[fl], hips[1], cues[fr])
    if d >= clearance_m or segment_distance(hips[0], cues[fr], hips[1], cues[fl]) < clearance_m:
        return 0.0
    return 1e4 * (clearance_m - d) ** 2


def frame_costs(fitter: BodyFitter, cues: np.ndarray, rest_cues: np.ndarray, prev_axes: np.ndarray | None,
                targets: SilhouetteTargets | None, config: IdentityConfig, feet: np.ndarray | None,
                hips: np.ndarray | None, acquiring: bool, hands_on_head: bool = False) -> np.ndarray:
    """One frame's costs (4,) for ``decide``: ``score_hypotheses`` (the shoes ``feet`` and the
    fixed elbow pole only while ``acquiring``), with what the frame cannot tell apart taken out.
    Without views the mirror is not scored (inf: the limits alone cannot see it); with the feet
    together (``feet_together`` of the previous pose's ``hips``) the feet alternative scores as
    the current labelling; with ``hands_on_head`` (a hand measured from a view that found it on
    the head's blob, ``views.hands_on_head``) so do the alternatives that exchange the hands:
    such a view cannot tell which arm reached up. Legs that pass through each other credit the
    feet alternative (``crossed_legs_cm2``; module doc)."""
    no_views = targets is None or targets.n_views == 0
    together = feet_together(hips, cues, config.feet_together_hips)
    skip = frozenset(k for k, off in ((_MIRROR, no_views), (_FEET, together)) if off)
    costs = score_hypotheses(fitter, cues, rest_cues, prev_axes, targets, config, feet if acquiring else None,
                             measured_elbows=not acquiring, skip=skip)
    if no_views:
        costs[1 + _MIRROR] = np.inf
    if together:
        costs[1 + _FEET] = costs[0]
    if hands_on_head:
        costs[[1 + _HANDS, 1 + _MIRROR]] = costs[0]
    costs[1 + _FEET] -= config.crossed_legs_weight * crossed_legs_cm2(hips, cues)
    return costs


def decide(state: IdentityState, costs: np.ndarray, config: IdentityConfig) -> int:
    """Update the evidence with one frame's ``costs`` (4,) (``score_hypotheses``); return the
    alternative to switch to (index into ALTERNATIVES) or -1 to keep the labels."""
    state.last_costs = costs.copy()
    gain = costs[0] - costs[1:]
    gain = np.where(np.isfinite(gain), gain, 0.0)
    state.evidence = config.decay * state.evidence + gain
    state.won = np.where(gain > 0, state.won + 1, 0)
    state.frames += 1
    acquiring = state.frames <= config.acquire_frames
    need = config.switch_evidence * (config.acquire_factor if acquiring else 1.0)
    ok = (state.evidence > need) & (gain > config.frame_margin + config.frame_margin_frac * costs[0])
    if not ok.any():
        return -1
    k = int(np.argmax(np.where(ok, state.evidence, -np.inf)))
    if k == _MIRROR:
        # the mirror exchanges both pairs, and each must earn its exchange: the pair it adds to
        # the best single-pair swap is earned when the mirror beats that swap by the threshold
        # too, or when that pair's own swap is supported (evidence > 0); else it is undecided
        # (feet together, hands together) and keeps its measured labels
        single, other = sorted(_SINGLE, key=lambda j: -state.evidence[j])
        if state.evidence[k] - state.evidence[single] <= need and state.evidence[other] <= 0:
            if not ok[single]:
                return -1
            k = single
    # how far back the switch reaches: a track's labels before it has acquired its identity were
    # the cold start's guess, and so were its feet's until something decided them; else the
    # frames the alternative won in a row
    undecided = ALTERNATIVES[k] == "feet" and not state.feet_decided
    state.last_switch = (k, state.frames if acquiring or undecided else int(state.won[k]))
    state.feet_decided |= ALTERNATIVES[k] != "hands"
    state.evidence[:] = 0.0
    state.won[:] = 0
    state.switches += 1
    return k
