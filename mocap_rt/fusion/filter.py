"""Temporal filter of the six 3D cues: a constant-velocity Kalman filter per cue.

Why Kalman rather than One-Euro: the fusion needs a *prediction* for the next frame
(seed digest A.4, the perception stage searches around it) and a principled way to
coast through missed detections and to gate outliers by their innovation; a
constant-velocity Kalman filter gives all three, while One-Euro only smooths.

Each cue has the state (position, velocity) per axis with one 2x2 covariance shared by
the three axes (isotropic measurement noise, white-acceleration process noise):

    F = [[1, dt], [0, 1]],  Q = q [[dt^3/3, dt^2/2], [dt^2/2, dt]],  R = r^2

with ``q = accel_noise_mps2^2 * dt`` style spectral density ``accel_psd`` (m^2/s^3).
A measurement farther than ``gate_m`` from the prediction is rejected, unless it lies
within ``gate_m`` of the last accepted measurement (the prediction ran off after a bad
update), or the track has coasted for more than ``max_coast_s``, or ``confirm_frames``
rejected measurements agree with each other (each within ``gate_m`` of the one before and
within ``confirm_window_s`` of it, accepted ones in between or not: a steady point the track
is not on, e.g. a head track started on the hands clasped above it while perception's head
check puts the head back every few frames): then the track restarts on the measurement.
While coasting the velocity decays (``coast_velocity_decay_s``), so a lost cue stays
near where it was last seen instead of drifting away.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mocap_rt.names import N_CUES


@dataclass(frozen=True)
class FilterConfig:
    """Kalman settings (units in the names)."""

    accel_psd_m2ps3: float = 10.0      # white-acceleration spectral density q (bench_fusion sweep)
    measurement_noise_m: float = 0.006  # r, std of a triangulated cue
    gate_m: float = 0.35               # innovation gate (distance to the prediction)
    max_coast_s: float = 0.5           # after this long without an update a track is dropped
    coast_velocity_decay_s: float = 0.1  # a coasting track's velocity decays with this time constant
    initial_velocity_std_mps: float = 1.0
    confirm_frames: int = 3            # rejected but mutually consistent this many times: restart there
    confirm_window_s: float = 0.3      # ... each within this long of the one before


class CueFilter:
    """Constant-velocity Kalman filter for N 3D points (default the 6 cues).

    State: ``pos (N, 3)`` metres, ``vel (N, 3)`` m/s, ``cov (N, 2, 2)``, ``time_s`` of the
    state, ``last_update_s (N,)``; ``alive (N,)`` bool; ``started_s (N,)`` when each track was
    last (re)started.
    """

    def __init__(self, n: int = N_CUES, config: FilterConfig = FilterConfig()) -> None:
        self.config = config
        self.pos = np.full((n, 3), np.nan)
        self.vel = np.zeros((n, 3))
        self.cov = np.zeros((n, 2, 2))
        self.alive = np.zeros(n, dtype=bool)
        self.last_update_s = np.full(n, -np.inf)
        self.last_meas = np.full((n, 3), np.nan)
        self.last_rejected = np.full((n, 3), np.nan)
        self.rejected_run = np.zeros(n, dtype=np.int64)   # consistent rejections so far
        self.last_rejected_s = np.full(n, -np.inf)
        self.started_s = np.full(n, -np.inf)
        self.time_s: float | None = None

    def _propagate(self, dt: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        c = self.cov
        q = self.config.accel_psd_m2ps3
        # F P F^T + Q with F = [[1, dt], [0, 1]], written out (2x2 per point)
        new = np.empty_like(c)
        new[:, 0, 0] = c[:, 0, 0] + dt * (c[:, 0, 1] + c[:, 1, 0]) + dt * dt * c[:, 1, 1] + q * dt ** 3 / 3
        new[:, 0, 1] = c[:, 0, 1] + dt * c[:, 1, 1] + q * dt ** 2 / 2
        new[:, 1, 0] = c[:, 1, 0] + dt * c[:, 1, 1] + q * dt ** 2 / 2
        new[:, 1, 1] = c[:, 1, 1] + q * dt
        return self.pos + self.vel * dt, self.vel.copy(), new

    def estimates(self) -> np.ndarray:
        """(N, 3) the tracks' last estimates (NaN for dead tracks)."""
        return np.where(self.alive[:, None], self.pos, np.nan)

    def predict_at(self, time_s: float) -> np.ndarray:
        """(N, 3) predicted positions at ``time_s`` (NaN for dead tracks); state unchanged."""
        if self.time_s is None:
            return np.full_like(self.pos, np.nan)
        pos, _, _ = self._propagate(time_s - self.time_s)
        return np.where(self.alive[:, None], pos, np.nan)

    def update(self, time_s: float, z: np.ndarray) -> np.ndarray:
        """Advance to ``time_s`` and fuse measurements ``z (N, 3)`` (NaN rows = missing).

        Returns (N,) bool: the measurement was accepted.
        """
        cfg = self.config
        z = np.asarray(z, dtype=np.float64)
        dt_step = 0.0
        if self.time_s is not None:
            dt_step = max(0.0, time_s - self.time_s)
            self.pos, self.vel, self.cov = self._propagate(dt_step)
        self.time_s = time_s
        self.alive &= (time_s - self.last_update_s) <= cfg.max_coast_s
        has = np.isfinite(z).all(axis=1)
        innov = z - self.pos
        dist = np.linalg.norm(innov, axis=1)
        ok = has & self.alive & (dist <= cfg.gate_m)
        # a measurement near the last accepted one while the prediction has run off (after
        # one bad measurement gave a wild velocity) restarts the track there
        near_last = np.linalg.norm(z - self.last_meas, axis=1) <= cfg.gate_m
        start = has & (~self.alive | (~ok & near_last))
        # rejected measurements that agree with each other, time after time: the track is on
        # something else (it started on an outlier); after confirm_frames it restarts there
        rejected = has & ~ok & ~start
        recent = (time_s - self.last_rejected_s) <= cfg.confirm_window_s
        steady = recent & (np.linalg.norm(z - self.last_rejected, axis=1) <= cfg.gate_m)
        self.rejected_run = np.where(rejected, np.where(steady, self.rejected_run + 1, 1),
                                     np.where(recent, self.rejected_run, 0))
        self.last_rejected = np.where(rejected[:, None], z, self.last_rejected)
        self.last_rejected_s = np.where(rejected, time_s, self.last_rejected_s)
        start |= self.rejected_run >= cfg.confirm_frames
        # Kalman update for accepted measurements (shared 2x2 covariance per point)
        S = self.cov[:, 0, 0] + cfg.measurement_noise_m ** 2
        K = self.cov[:, :, 0] / S[:, None]                          # (N, 2)
        sel = ok
        self.pos[sel] += K[sel, 0:1] * innov[sel]
        self.vel[sel] += K[sel, 1:2] * innov[sel]
        KH = np.zeros((len(S), 2, 2))
        KH[:, :, 0] = K
        new_cov = (np.eye(2) - KH) @ self.cov
        self.cov[sel] = new_cov[sel]
        # (re)start tracks on their first measurement
        self.pos[start] = z[start]
        self.vel[start] = 0.0
        self.cov[start] = np.diag([cfg.measurement_noise_m ** 2, cfg.initial_velocity_std_mps ** 2])
        self.alive |= start
        self.started_s[start] = time_s
        self.rejected_run[start] = 0
        self.last_rejected_s[start] = -np.inf
        accepted = ok | start
        self.last_update_s[accepted] = time_s
        self.last_meas[accepted] = z[accepted]
        if self.time_s is not None and cfg.coast_velocity_decay_s > 0:
            # coasting tracks slow down instead of flying off on a stale velocity
            coasting = self.alive & ~accepted
            self.vel[coasting] *= np.exp(-dt_step / cfg.coast_velocity_decay_s)
        return accepted

    def swap(self, a: int, b: int) -> None:
        """Exchange the whole state of tracks ``a`` and ``b`` (an identity fix, e.g. left/right)."""
        for arr in (self.pos, self.vel, self.cov, self.alive, self.last_update_s, self.last_meas,
                    self.last_rejected, self.rejected_run, self.last_rejected_s, self.started_s):
            arr[[a, b]] = arr[[b, a]]

    def end(self, tracks: np.ndarray) -> None:
        """End the tracks ``tracks`` ((N,) bool): a measurement found to be another's (the next
        one restarts them)."""
        self.alive &= ~tracks
