"""Accuracy of fused cues and joints against a studio ``truth.npz``, and truth-driven cues.

``truth`` is the dict of a recording's ``truth.npz`` (keys documented with the
recording format): ``frames`` (F,), ``joints`` (F, J, 3) m, ``cues`` (F, 6, 3) m,
``camera_names`` (C,), ``cues_2d`` (C, F, 6, 2) px, ``cue_visibility`` (C, F, 6).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mocap_rt.cues import CameraCues, CompactSilhouette
from mocap_rt.names import CUE_NAMES, JOINT_NAMES

# A truth cue counts as seen by a camera when at least this fraction of it is visible.
MIN_VISIBLE_FRAC = 0.5


@dataclass(frozen=True)
class Accuracy:
    """Errors in metres. cue_err (F, 6) and joint_err (F, J): NaN where not estimated."""

    cue_err: np.ndarray
    joint_err: np.ndarray

    @property
    def cue_median_mm(self) -> float:
        return float(np.nanmedian(self.cue_err) * 1e3)

    @property
    def cue_p95_mm(self) -> float:
        return float(np.nanpercentile(self.cue_err, 95) * 1e3)

    @property
    def mpjpe_mm(self) -> float:
        return float(np.nanmean(self.joint_err) * 1e3)

    @property
    def cue_coverage(self) -> float:
        """Fraction of (frame, cue) estimated."""
        return float(np.isfinite(self.cue_err).mean())

    @property
    def joint_coverage(self) -> float:
        return float(np.isfinite(self.joint_err).mean())

    def per_joint_mm(self) -> dict[str, float]:
        return {n: float(np.nanmean(self.joint_err[:, j]) * 1e3) if np.isfinite(self.joint_err[:, j]).any()
                else float("nan") for j, n in enumerate(JOINT_NAMES)}

    def per_cue_mm(self) -> dict[str, tuple[float, float]]:
        out = {}
        for c, n in enumerate(CUE_NAMES):
            e = self.cue_err[:, c]
            e = e[np.isfinite(e)]
            out[n] = (float(np.median(e) * 1e3), float(np.percentile(e, 95) * 1e3)) if e.size else (np.nan, np.nan)
        return out

    def summary(self) -> str:
        lines = [f"cue 3D error: median {self.cue_median_mm:.1f} mm, p95 {self.cue_p95_mm:.1f} mm "
                 f"({100 * self.cue_coverage:.0f}% of cue-frames); MPJPE {self.mpjpe_mm:.1f} mm "
                 f"({100 * self.joint_coverage:.0f}% of frames)"]
        lines.append("per cue (median/p95 mm): " + ", ".join(
            f"{n} {m:.0f}/{p:.0f}" for n, (m, p) in self.per_cue_mm().items()))
        lines.append("per joint (mean mm): " + ", ".join(f"{n} {v:.0f}" for n, v in self.per_joint_mm().items()))
        return "\n".join(lines)


def align_truth(truth: dict, frames: np.ndarray) -> np.ndarray:
    """(F,) indices into the truth arrays for our ``frames`` (ValueError if one is missing)."""
    tf = np.asarray(truth["frames"]).astype(np.int64)
    pos = {int(f): i for i, f in enumerate(tf)}
    try:
        return np.array([pos[int(f)] for f in frames], dtype=np.int64)
    except KeyError as exc:
        raise ValueError(f"truth.npz has no frame {exc.args[0]}") from None


def accuracy(truth: dict, frames: np.ndarray, cues: np.ndarray, joints: np.ndarray) -> Accuracy:
    """Errors of cues (F, 6, 3) and joints (F, J, 3), metres, world, for ``frames`` (F,)."""
    idx = align_truth(truth, frames)
    names = [str(n) for n in truth.get("joint_names", JOINT_NAMES)]
    order = [names.index(n) for n in JOINT_NAMES]
    tj = np.asarray(truth["joints"])[idx][:, order]
    tc = np.asarray(truth["cues"])[idx]
    return Accuracy(np.linalg.norm(cues - tc, axis=-1), np.linalg.norm(joints - tj, axis=-1))


def truth_silhouette(packed_rows: np.ndarray, width: int) -> CompactSilhouette:
    """The compact silhouette (as perception sends it) of one truth mask, ``np.packbits``
    rows (H, ceil(W / 8)) of a (H, ``width``) image."""
    m = np.unpackbits(np.asarray(packed_rows), axis=-1, count=width).astype(bool)
    rows, cols = np.flatnonzero(m.any(axis=1)), np.flatnonzero(m.any(axis=0))
    if rows.size == 0:
        return CompactSilhouette(0, 0, 1, np.zeros((0, 0), bool))
    y0, y1, x0, x1 = rows[0], rows[-1] + 1, cols[0], cols[-1] + 1
    return CompactSilhouette.from_box_mask(m[y0:y1, x0:x1], (x0, y0, x1 - x0, y1 - y0))


def truth_camera_cues(truth: dict, camera_names: list[str], t_index: int, frame: int,
                      noise_px: float, rng: np.random.Generator, widths: dict[str, int] | None = None
                      ) -> dict[str, CameraCues]:
    """The truth's 2D cues of one frame as ``CameraCues`` (+ Gaussian pixel noise).

    A cue is present where its visible fraction is >= MIN_VISIBLE_FRAC; confidence 1.
    With ``widths`` (camera -> image width px) and masks in the truth, each camera's cues
    carry the truth silhouette (``truth_silhouette``).
    """
    tnames = [str(n) for n in truth["camera_names"]]
    out = {}
    for name in camera_names:
        c = tnames.index(name)
        xy = np.asarray(truth["cues_2d"][c, t_index], dtype=np.float64).copy()
        vis = np.asarray(truth["cue_visibility"][c, t_index]) >= MIN_VISIBLE_FRAC
        xy += rng.normal(0.0, noise_px, xy.shape) if noise_px > 0 else 0.0
        xy[~vis] = np.nan
        cov = np.where(vis[:, None, None], np.eye(2) * max(noise_px, 0.5) ** 2, np.nan)
        sil = None
        if widths is not None and "masks" in truth:
            sil = truth_silhouette(truth["masks"][c, t_index], widths[name])
        out[name] = CameraCues(name, frame, xy, cov, np.where(vis, 100.0, 0.0), vis.astype(np.float64),
                               silhouette=sil)
    return out


# Joint angles read geometrically from joint positions, degrees (``anatomical_angles``).
ANGLE_NAMES: tuple[str, ...] = tuple(f"{a}_{s}" for a in ("hip_flex", "hip_abd", "knee_flex", "shoulder_flex",
                                                           "shoulder_abd", "elbow_flex") for s in ("l", "r"))


def _unit_rows(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def trunk_axes(joints: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(forward, left, up) unit vectors (each (F, 3)) of the trunk from joints (F, 20, 3) in
    JOINT_NAMES order: up = pelvis -> neck, left = hip_r -> hip_l made perpendicular to up,
    forward = left x up (the right-handed body frame)."""
    j = {n: i for i, n in enumerate(JOINT_NAMES)}
    up = _unit_rows(joints[:, j["neck"]] - joints[:, j["pelvis"]])
    lat = joints[:, j["hip_l"]] - joints[:, j["hip_r"]]
    left = _unit_rows(lat - up * np.sum(lat * up, axis=-1, keepdims=True))
    return np.cross(left, up), left, up


def anatomical_angles(joints: np.ndarray) -> dict[str, np.ndarray]:
    """Joint angles (F,) degrees per ``ANGLE_NAMES``, from joint positions (F, 20, 3), in the
    trunk frame of ``trunk_axes``:

    * ``hip_flex`` / ``shoulder_flex``: angle of the thigh / upper arm from straight down,
      in the sagittal plane, positive forward: ``atan2(d . fwd, -d . up)``;
    * ``hip_abd`` / ``shoulder_abd``: its angle out of the sagittal plane, positive away from
      the midline: ``asin(d . out / |d|)``, out = left for the left side, right for the right;
    * ``knee_flex`` / ``elbow_flex``: angle between the two segments (0 = straight).
    NaN where a joint is NaN.
    """
    joints = np.asarray(joints, dtype=np.float64)
    fwd, left, up = trunk_axes(joints)
    j = {n: i for i, n in enumerate(JOINT_NAMES)}
    out = {}
    for s, sgn in (("l", 1.0), ("r", -1.0)):
        for a, b, c, first, second in (("hip", "knee", "ankle", "hip", "knee"),
                                       ("shoulder", "elbow", "wrist", "shoulder", "elbow")):
            d = joints[:, j[f"{b}_{s}"]] - joints[:, j[f"{a}_{s}"]]
            e = joints[:, j[f"{c}_{s}"]] - joints[:, j[f"{b}_{s}"]]
            dn = np.linalg.norm(d, axis=-1)
            out[f"{first}_flex_{s}"] = np.degrees(np.arctan2(np.sum(d * fwd, -1), -np.sum(d * up, -1)))
            out[f"{first}_abd_{s}"] = np.degrees(np.arcsin(np.clip(sgn * np.sum(d * left, -1) / dn, -1, 1)))
            cosb = np.sum(d * e, -1) / (dn * np.linalg.norm(e, axis=-1))
            out[f"{second}_flex_{s}"] = np.degrees(np.arccos(np.clip(cosb, -1, 1)))
    return {n: out[n] for n in ANGLE_NAMES}


# ----------------------------------------------------------------------------- motion-suite metrics
# Two labellings of a left/right pair must differ by more than this (metres, summed over the
# pair) before a frame counts as mirrored: hands together (a clap) are not a mirror.
MIRROR_MARGIN_M = 0.05
ANGLE_GROUPS: dict[str, tuple[str, ...]] = {
    "hips": ("hip_flex_l", "hip_flex_r", "hip_abd_l", "hip_abd_r"), "knees": ("knee_flex_l", "knee_flex_r"),
    "shoulders": ("shoulder_flex_l", "shoulder_flex_r", "shoulder_abd_l", "shoulder_abd_r"),
    "elbows": ("elbow_flex_l", "elbow_flex_r")}


def procrustes_errors(est: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """(F,) mean joint error (metres) per frame after the best similarity transform (rotation,
    uniform scale, translation; no reflection) of ``est`` (F, J, 3) onto ``truth``; joints
    NaN in either are left out, NaN for frames with fewer than 3 joints (PA-MPJPE)."""
    est, truth = np.asarray(est, np.float64), np.asarray(truth, np.float64)
    out = np.full(est.shape[0], np.nan)
    for f in range(est.shape[0]):
        ok = np.isfinite(est[f]).all(-1) & np.isfinite(truth[f]).all(-1)
        if ok.sum() < 3:
            continue
        X, Y = est[f, ok], truth[f, ok]
        mx, my = X.mean(0), Y.mean(0)
        X0, Y0 = X - mx, Y - my
        U, S, Vt = np.linalg.svd(X0.T @ Y0)
        d = np.sign(np.linalg.det(U @ Vt)) or 1.0
        D = np.diag([1.0, 1.0, d])
        R = U @ D @ Vt                        # X0 @ R ~ Y0
        nx = (X0 ** 2).sum()
        s = float((S * np.diag(D)).sum() / nx) if nx > 0 else 1.0
        out[f] = np.linalg.norm(s * X0 @ R - Y0, axis=-1).mean()
    return out


def mirrored_frames(est: np.ndarray, truth: np.ndarray, margin_m: float = MIRROR_MARGIN_M) -> np.ndarray:
    """(F,) float: 1 where the hands or the feet of ``est`` are labelled with the wrong side,
    0 where not, NaN where neither pair is complete in both (joints (F, 20, 3), metres; a
    frame with only one complete pair is judged on that pair).

    A pair (hand_l, hand_r) or (foot_l, foot_r) is mirrored when the crossed labelling is
    closer to the truth than the straight one by more than ``margin_m``:
    ``|e_l - t_r| + |e_r - t_l| + margin < |e_l - t_l| + |e_r - t_r|``."""
    j = {n: i for i, n in enumerate(JOINT_NAMES)}
    flags = []
    for a, b in (("hand_l", "hand_r"), ("foot_l", "foot_r")):
        el, er, tl, tr = est[:, j[a]], est[:, j[b]], truth[:, j[a]], truth[:, j[b]]
        straight = np.linalg.norm(el - tl, axis=-1) + np.linalg.norm(er - tr, axis=-1)
        crossed = np.linalg.norm(el - tr, axis=-1) + np.linalg.norm(er - tl, axis=-1)
        flags.append(np.where(np.isfinite(straight + crossed), (crossed + margin_m < straight) * 1.0, np.nan))
    return np.fmax(flags[0], flags[1])            # NaN only where both are NaN


def heading_deg(joints: np.ndarray) -> np.ndarray:
    """(F,) heading of the trunk (``trunk_axes`` forward projected on the floor), degrees from
    +X towards +Y."""
    fwd = trunk_axes(np.asarray(joints, np.float64))[0]
    return np.degrees(np.arctan2(fwd[:, 1], fwd[:, 0]))


def wrap_deg(a: np.ndarray) -> np.ndarray:
    """Angles (degrees) wrapped into [-180, 180)."""
    return (np.asarray(a) + 180.0) % 360.0 - 180.0


def angle_rmse_deg(est: np.ndarray, truth: np.ndarray) -> dict[str, float]:
    """RMSE (degrees, wrapped differences, NaN frames left out) of the ``anatomical_angles``
    of each group of ``ANGLE_GROUPS`` (hips, knees, shoulders, elbows)."""
    ae, at = anatomical_angles(est), anatomical_angles(truth)
    out = {}
    for g, names in ANGLE_GROUPS.items():
        d = np.concatenate([wrap_deg(ae[n] - at[n]) for n in names])
        d = d[np.isfinite(d)]
        out[g] = float(np.sqrt(np.mean(d ** 2))) if d.size else float("nan")
    return out


def _mean_finite(values) -> float:
    v = np.asarray(values, np.float64)
    v = v[np.isfinite(v)]
    return float(v.mean()) if v.size else float("nan")


def suite_metrics(truth: dict, frames: np.ndarray, cues: np.ndarray, joints: np.ndarray,
                  fusion_ms: np.ndarray | None = None, shown: np.ndarray | None = None) -> dict[str, float]:
    """The motion-suite figures of one clip (docs/body.md "Motion suite"): MPJPE, PA-MPJPE,
    elbow/knee mean error (mm), % frames mirrored, heading error median/p95 (deg), joint-angle
    RMSE per group (deg), cue 3D error median/p95 overall and per cue (mm), fusion ms
    median/p99. Inputs as for ``accuracy``; joints NaN where not estimated. ``shown`` (F, J, 3):
    the figure as published, with the joints not estimated where it put them: its MPJPE is
    ``mpjpe_shown_mm`` (what a user of the BVH sees)."""
    acc = accuracy(truth, frames, cues, joints)
    idx = align_truth(truth, frames)
    names = [str(n) for n in truth.get("joint_names", JOINT_NAMES)]
    tj = np.asarray(truth["joints"])[idx][:, [names.index(n) for n in JOINT_NAMES]]
    per_joint = acc.per_joint_mm()
    mir = mirrored_frames(joints, tj)
    herr = np.abs(wrap_deg(heading_deg(joints) - heading_deg(tj)))
    herr = herr[np.isfinite(herr)]
    m = {"frames": int(len(frames)), "mpjpe_mm": acc.mpjpe_mm,
         "pa_mpjpe_mm": float(np.nanmean(procrustes_errors(joints, tj)) * 1e3),
         "elbow_mm": _mean_finite([per_joint["elbow_l"], per_joint["elbow_r"]]),
         "knee_mm": _mean_finite([per_joint["knee_l"], per_joint["knee_r"]]),
         "mirrored_pct": float(100 * np.nanmean(mir)) if np.isfinite(mir).any() else float("nan"),
         "heading_med_deg": float(np.median(herr)) if herr.size else float("nan"),
         "heading_p95_deg": float(np.percentile(herr, 95)) if herr.size else float("nan"),
         "cue_med_mm": acc.cue_median_mm, "cue_p95_mm": acc.cue_p95_mm,
         "joint_coverage": acc.joint_coverage}
    m.update({f"rmse_{g}_deg": v for g, v in angle_rmse_deg(joints, tj).items()})
    for n, (med, p95) in acc.per_cue_mm().items():
        m[f"cue_{n}_med_mm"], m[f"cue_{n}_p95_mm"] = med, p95
    if shown is not None:
        m["mpjpe_shown_mm"] = float(np.nanmean(np.linalg.norm(shown - tj, axis=-1)) * 1e3)
    if fusion_ms is not None and len(fusion_ms):
        m["fusion_ms_med"], m["fusion_ms_p99"] = float(np.median(fusion_ms)), float(np.percentile(fusion_ms, 99))
    return m
