"""The bone lengths from the first seconds of a capture (``fusion.tracker``'s calibration window).

``LengthCalibration`` keeps each frame's measured cues and body axes, and every
``CALIB_EVERY``-th frame its IK cues and silhouettes. Once ``calibration_s`` of them are in
(or at ``finish``), ``estimate.estimate_bone_lengths`` scales the default adult to the cues;
then, with ``FusionConfig.fit_bone_lengths``, ``body.calibrate.fit_state_and_published`` fits the
proportions to the kept silhouettes, the state's and the published pose's. That fit takes 3-7 s
of CPU: in the background (``background``, the service) it runs in another process at the idle
priority (``calibrate.BackgroundFit``, started with the window, before the frames) and ``poll``
hands over its lengths once it is done; else (offline) it runs in the frame that calibrates.
"""

from __future__ import annotations

import logging

import numpy as np

from mocap_rt.body.calibrate import BackgroundFit, fit_state_and_published
from mocap_rt.body.estimate import estimate_bone_lengths
from mocap_rt.body.silhouette import SilhouetteTargets
from mocap_rt.body.skeleton import BoneLengths
from mocap_rt.fusion.config import FusionConfig

log = logging.getLogger(__name__)

Lengths = tuple[BoneLengths, BoneLengths]    # (the tracker's state's, the published pose's)
CALIB_EVERY = 2      # every this many calibration frames one keeps its silhouettes (body.calibrate)


class LengthCalibration:
    """One subject's calibration window (module doc)."""

    def __init__(self, config: FusionConfig, background: bool = False) -> None:
        self.config = config
        self.background = background
        self.fitting: BackgroundFit | None = None     # the background fit under way
        # its process, started now, before the frames (``BackgroundFit``: a start at the
        # calibration delayed the next pose)
        self._process = (BackgroundFit() if background and config.fit_bone_lengths and config.bone_lengths is None
                         else None)
        self._cues: list[np.ndarray] = []
        self._axes: list[np.ndarray] = []
        self._views: list[tuple] = []

    def add(self, X: np.ndarray, axes: np.ndarray | None, cues_ik: np.ndarray | None = None,
            targets: SilhouetteTargets | None = None) -> Lengths | None:
        """Keep a frame's measured cues X (6, 3) and axes, and every ``CALIB_EVERY``-th frame its
        IK cues and silhouettes; once ``calibration_s`` of them are in, the lengths to take
        (``finish``), else None."""
        if axes is not None:
            self._cues.append(X.copy())
            self._axes.append(axes)
            if targets is not None and targets.n_views > 0 and len(self._cues) % CALIB_EVERY == 0:
                self._views.append((cues_ik, axes, targets))
        if len(self._cues) >= self.config.calibration_s * self.config.fps:
            return self.finish()
        return None

    def finish(self) -> Lengths | None:
        """The lengths (state, published) of the frames kept so far (the window is emptied): the
        fitted ones, or in the background the estimate (both) while the fit runs; None without a
        frame or an estimate."""
        if not self._cues:
            return None
        est = estimate_bone_lengths(np.array(self._cues), BoneLengths(), np.array(self._axes))
        views = list(self._views)
        self._cues.clear()
        self._axes.clear()
        self._views.clear()
        if est is None:
            return None
        log.info("bone lengths estimated from the cues: %s", est)
        if not (self.config.fit_bone_lengths and views):
            return est, est
        args = (est, views, self.config.analytic, self.config.fit)
        if self.background:
            self.fitting, self._process = self._process or BackgroundFit(), None
            self.fitting.submit(*args)
            return est, est
        return _fitted(fit_state_and_published(*args))

    def poll(self) -> Lengths | None:
        """The background fit's lengths (state, published) once it is done, else None (a failed
        fit: None, and the estimate stays)."""
        job = self.fitting
        if job is None or not job.done():
            return None
        self.fitting = None
        try:
            return _fitted(job.result(0.0))
        except RuntimeError as e:
            log.error("%s; the estimate stays", e)
            return None


def _fitted(lengths: Lengths) -> Lengths:
    log.info("bone lengths fitted to the silhouettes: %s; the published pose's: %s", *lengths)
    return lengths
