"""Fusion's settings (``FusionConfig``): each default lives here, units in the names.

What ``fusion.tracker.BodyTracker`` runs on; read from TOML by ``mocap_rt.pipeline_config``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from mocap_rt.body.analytic import AnalyticConfig
from mocap_rt.body.ccd import CcdConfig
from mocap_rt.body.fit import FitConfig
from mocap_rt.body.skeleton import BoneLengths
from mocap_rt.fusion.filter import FilterConfig
from mocap_rt.fusion.identity import IdentityConfig

VIEW_MODES = ("all", "pair")
IK_MODES = ("analytic", "ccd")


@dataclass(frozen=True)
class FusionConfig:
    """Fusion settings; each default lives here (units in the names)."""

    fps: float = 30.0                      # frame rate, converts frame numbers to seconds
    views: str = "all"                     # "all" or "pair" (A.6 frontal pair)
    max_reproj_px: float = 6.0             # outlier rejection threshold (head, hands, feet)
    torso_max_reproj_px: float = 15.0      # the same for the torso (its 2D points are silhouette
                                           # centres, not projections of one 3D point)
    consensus_views: bool = False          # restart outlier rejection from the largest consensus set of views
                                           # (views.triangulate_cues); off: docs/body.md says why
    min_confidence: float = 0.05           # 2D cues below this are ignored
    min_ray_angle_deg: float = 20.0        # a cue whose views' rays meet closer to parallel (two cameras facing
                                           # each other) is placed along them by the filter (ill_conditioned and
                                           # triangulate_with_prior, mocap_rt.geometry); 0 = off
    fix_left_right: bool = True            # make the views' left/right labels agree (labels.fix_left_right)
    duplicate_m: float = 0.12              # a hand/foot this near the head is a duplicate unless predicted there
    hand_on_head_m: float = 0.20           # a hand predicted this near the head (beyond duplicate_m) and moving
    hand_rest_mps: float = 0.5             # ... slower than this rests on it: kept where a view finds it on the
                                           # head's blob (views.hands_on_head)
    use_filtered: bool = False             # IK on filtered (True) or measured (False) cues
    ik: str = "analytic"                   # "analytic" or "ccd" (analytic + CCD refinement)
    bone_lengths: BoneLengths | None = None
    # the feet, degrees below the horizontal (``BoneLengths.foot_pitch_deg``): the subject's, which
    # the cues do not measure, for estimated lengths (the suite's skeletons: 49 CMU, 58 Bandai), and
    # the one of the body the tracker's state moves (its fit, the identity, the predictions, the
    # lengths' fit), the legs reaching as far (``BoneLengths.with_foot_pitch``). The published pose
    # has the subject's; the subject's in the state lost the identity of six suite clips at their
    # start (docs/body.md, "The published foot pitched as the skeletons'")
    subject_foot_pitch_deg: float = 50.0
    tracking_foot_pitch_deg: float = 30.0
    calibration_s: float = 2.0             # seconds of cues for the automatic bone lengths
    fit_bone_lengths: bool = True          # ... their proportions fitted to the silhouettes (body.calibrate)
    # offline only (``mocap-rt process``, ``fusion.smooth``): the clip's poses low-passed both ways
    # at this cutoff once every frame is solved; 0 = off (what the live service, which cannot look
    # ahead, publishes)
    offline_smooth_hz: float = 4.0
    velocity_smoothing: float = 0.85       # EMA factor per frame of the torso velocity (pan from walking)
    silhouettes: bool = True               # fit the body to the cameras' silhouettes when the cues carry them
    visible_offsets: bool = True           # predictions carry where the head's and hands' visible centres lie
    shoe_shapes_max_speed_mps: float = 0.5  # ... and the shoes' shapes while both feet move slower (0: never)
    shoe_offsets: bool = True              # ... with the shoes' visible centres, cast on the published feet
    identity: IdentityConfig = field(default_factory=IdentityConfig)
    fit: FitConfig = field(default_factory=FitConfig)
    filter: FilterConfig = field(default_factory=FilterConfig)
    analytic: AnalyticConfig = field(default_factory=AnalyticConfig)
    ccd: CcdConfig = field(default_factory=lambda: CcdConfig(angle_tolerance_deg=20.0, max_iterations=30))

    def __post_init__(self) -> None:
        if self.views not in VIEW_MODES:
            raise ValueError(f"FusionConfig.views must be one of {VIEW_MODES}, got {self.views!r}")
        if self.ik not in IK_MODES:
            raise ValueError(f"FusionConfig.ik must be one of {IK_MODES}, got {self.ik!r}")
        if self.fps <= 0:
            raise ValueError(f"FusionConfig.fps must be > 0, got {self.fps}")
        if not 0.0 <= self.min_ray_angle_deg < 90.0:
            raise ValueError(f"FusionConfig.min_ray_angle_deg must be in [0, 90) degrees (0 = off), "
                             f"got {self.min_ray_angle_deg}")
        if self.offline_smooth_hz < 0:
            raise ValueError(f"FusionConfig.offline_smooth_hz must be >= 0 (0 = off), got {self.offline_smooth_hz}")
        for name in ("subject_foot_pitch_deg", "tracking_foot_pitch_deg"):
            if not 0.0 <= getattr(self, name) < 90.0:
                raise ValueError(f"FusionConfig.{name} must be in [0, 90) degrees, got {getattr(self, name)}")
