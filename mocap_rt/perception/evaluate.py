"""Accuracy of per-camera 2D cues against a studio truth: errors with left/right left to
fusion, losses and re-acquisition (the hard-case perception suite, issue 12).

Arrays: ``xy`` and ``truth_xy`` (C, F, 6, 2) pixels in ``CUE_NAMES`` order (NaN = not
found / not defined), ``visible`` (C, F, 6) bool (the truth cue is visible and inside the
image).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mocap_rt.names import CUE_NAMES, LR_PAIRS

# A visible cue farther than this from its truth (pixels at 640 px width, scaled) is lost.
LOST_PX_640 = 20.0


# The truth joint at which each blob cue's body part adjoins the next one (the collar, the
# sleeve, the trouser leg cover that end of the skin or shoe blob): ``along_limb_errors``.
ADJOINING_JOINT = {"head": "neck", "hand_l": "wrist_l", "hand_r": "wrist_r", "foot_l": "ankle_l", "foot_r": "ankle_r"}


def _pair_swaps(xy: np.ndarray, truth_xy: np.ndarray) -> np.ndarray:
    """(C, F, len(LR_PAIRS)) bool: the crossed labelling of the pair scores better (both cues
    and both truths defined)."""
    err = np.linalg.norm(xy - truth_xy, axis=-1)
    out = np.zeros(err.shape[:-1] + (len(LR_PAIRS),), bool)
    for i, (a, b) in enumerate(LR_PAIRS):
        crossed = (np.linalg.norm(xy[..., a, :] - truth_xy[..., b, :], axis=-1)
                   + np.linalg.norm(xy[..., b, :] - truth_xy[..., a, :], axis=-1))
        out[..., i] = crossed < (err[..., a] + err[..., b])        # False where any is NaN
    return out


def _matched(truth_xy: np.ndarray, swaps: np.ndarray) -> np.ndarray:
    """``truth_xy`` (C, F, 6, 2) with each pair's cues exchanged where ``swaps``."""
    out = truth_xy.copy()
    for i, (a, b) in enumerate(LR_PAIRS):
        s = swaps[..., i, None]
        out[..., a, :] = np.where(s, truth_xy[..., b, :], truth_xy[..., a, :])
        out[..., b, :] = np.where(s, truth_xy[..., a, :], truth_xy[..., b, :])
    return out


def pair_best_errors(xy: np.ndarray, truth_xy: np.ndarray) -> np.ndarray:
    """(C, F, 6) pixel errors; for each hand and foot pair, per camera and frame, the
    labelling (straight or crossed) with the smaller summed error is used when both cues
    and both truths are defined; otherwise the straight one (identity is fusion's job)."""
    xy, truth_xy = np.asarray(xy, np.float64), np.asarray(truth_xy, np.float64)
    return np.linalg.norm(xy - _matched(truth_xy, _pair_swaps(xy, truth_xy)), axis=-1)


def along_limb_errors(xy: np.ndarray, truth_xy: np.ndarray, joint_xy: np.ndarray) -> np.ndarray:
    """(C, F, 6, 2) each cue's error split into its component along the limb, away from the
    joint it adjoins (``joint_xy`` (C, F, 6, 2): that joint's truth, ``ADJOINING_JOINT``;
    NaN for the torso), and across it (the 2D cross product of the limb's direction and the
    error), under the labelling ``pair_best_errors`` scores. NaN where undefined or the joint
    lies within 1 px of the cue."""
    xy, truth_xy, joint_xy = (np.asarray(a, np.float64) for a in (xy, truth_xy, joint_xy))
    swaps = _pair_swaps(xy, truth_xy)
    truth, joint = _matched(truth_xy, swaps), _matched(joint_xy, swaps)
    u = truth - joint
    n = np.linalg.norm(u, axis=-1, keepdims=True)
    u = np.where(n >= 1.0, u / np.where(n >= 1.0, n, 1.0), np.nan)
    d = xy - truth
    return np.stack([(d * u).sum(-1), u[..., 0] * d[..., 1] - u[..., 1] * d[..., 0]], axis=-1)


def loss_episodes(lost: np.ndarray, ok: np.ndarray) -> list[tuple[int, bool, int]]:
    """Loss episodes of one track over frames: lost, ok (F,) bool (neither = the cue is not
    visible, which neither starts nor ends an episode). An episode starts at a lost frame
    and lasts until the next ok frame; returns [(length in frames, re-acquired, lost frames
    in it)]: the last counts only the frames the cue was visible (a hand lost for one frame
    as it goes behind the head and found in the first frame it shows again: 1)."""
    out, start = [], None
    for f in range(len(lost)):
        if lost[f] and start is None:
            start = f
        elif ok[f] and start is not None:
            out.append((f - start, True, int(lost[start:f].sum())))
            start = None
    if start is not None:
        out.append((len(lost) - start, False, int(lost[start:].sum())))
    return out


@dataclass(frozen=True)
class CueTrackStats:
    """One cue over all cameras. median_px, p95_px over visible and found frames (NaN if
    none); lost_frames: visible frames not found or farther than the loss threshold;
    visible_frames; longest_loss_s over all loss episodes; reacq_median_s, reacq_max_s over
    the episodes that ended with the cue re-acquired (NaN if none); episodes;
    longest_seen_loss_s: the longest episode counted in the frames the cue was visible only
    (``loss_episodes``), without the frames it was hidden in between."""

    median_px: float
    p95_px: float
    lost_frames: int
    visible_frames: int
    longest_loss_s: float
    reacq_median_s: float
    reacq_max_s: float
    episodes: int
    longest_seen_loss_s: float


def cue_track_stats(xy: np.ndarray, truth_xy: np.ndarray, visible: np.ndarray, fps: float,
                    lost_px: float) -> dict[str, CueTrackStats]:
    """Per cue (``CUE_NAMES``) statistics of a recording's 2D cues (module doc for shapes)."""
    err = pair_best_errors(xy, truth_xy)
    found = np.isfinite(err)
    visible = np.asarray(visible, bool)
    lost = visible & (~found | (np.nan_to_num(err, nan=np.inf) > lost_px))
    ok = visible & ~lost
    out = {}
    for k, name in enumerate(CUE_NAMES):
        e = err[..., k][visible[..., k] & found[..., k]]
        eps = [ep for c in range(err.shape[0]) for ep in loss_episodes(lost[c, :, k], ok[c, :, k])]
        reacq = np.array([n for n, back, _ in eps if back], np.float64) / fps
        out[name] = CueTrackStats(
            float(np.median(e)) if e.size else float("nan"), float(np.percentile(e, 95)) if e.size else float("nan"),
            int(lost[..., k].sum()), int(visible[..., k].sum()),
            max((n for n, _, _ in eps), default=0) / fps,
            float(np.median(reacq)) if reacq.size else float("nan"),
            float(reacq.max()) if reacq.size else float("nan"), len(eps),
            max((n for _, _, n in eps), default=0) / fps)
    return out


def truth_visible(truth: dict, width: int, height: int, min_visible: float = 0.5) -> np.ndarray:
    """(C, F, 6) bool: the truth cue is at least ``min_visible`` visible and inside the image."""
    t2d = np.asarray(truth["cues_2d"], np.float64)
    inside = np.isfinite(t2d).all(-1) & (t2d[..., 0] >= 0) & (t2d[..., 0] <= width - 1) & \
        (t2d[..., 1] >= 0) & (t2d[..., 1] <= height - 1)
    return inside & (np.asarray(truth["cue_visibility"]) >= min_visible)
