"""The subject's proportions fitted to the silhouettes (analysis by synthesis, per subject).

``estimate.estimate_bone_lengths`` scales a default adult by three group factors from what
the six cues measure; the proportions inside a group stay the default's. People (and the
suite's skeletons) differ more than that: forearm / upper arm 0.68-0.92, shoulder half-width
0.10-0.19 m. And the torso cue is the trunk's visible centre, not its joint: 4 cm above it on
the CMU skeleton, 2 cm below on the Bandai one. A wrong split moves the elbows, shoulders,
hips and knees by centimetres however well the cues are placed.

``fit_bone_lengths`` chooses them from frames of the calibration window: a coordinate
search over ``PARAMS`` (the lengths by multiplicative steps, the torso cue's height by
added ones), each candidate scored by the sum over the frames of ``fit.BodyFitter``'s cost
(limit violation + silhouette chamfer, at the frame's best pan and swivels, then with the
torso point moved to where the silhouettes put it: ``BodyFitter.fit_torso``; the
torso cue is 2-5 cm off in single frames, which would otherwise decide the trunk's split)
+ ``PRIOR_COST`` per frame and per percent a length moved from the estimate. The head's
distance from the torso cue is what the cues measure, so the neck takes up what the trunk
or the cue's height changes. Frames the estimate fits badly (cost > ``FRAME_COST_MAX``: a
wrong heading or identity in the first seconds) are left out.
"""

from __future__ import annotations

import multiprocessing
import os
import pickle
import threading
import weakref
from collections.abc import Sequence
from dataclasses import replace

import numpy as np

from mocap_rt.body.analytic import AnalyticConfig
from mocap_rt.body.fit import BodyFitter, FitConfig
from mocap_rt.body.silhouette import SilhouetteTargets
from mocap_rt.body.skeleton import BoneLengths, body_model

# the lengths searched; the torso cue's height and the trunk with the neck (module doc)
PARAMS = ("torso_cue_up_m", "trunk_m", "shoulder_half_width_m", "upper_arm_m", "forearm_m", "hip_half_width_m",
          "thigh_m", "shank_m")
STEPS = (0.84, 0.92, 1.08, 1.19)            # the first sweeps' factors
FINE_STEPS = (0.96, 1.04)                   # the last sweep's
CUE_STEPS_M = (-0.04, -0.02, 0.02, 0.04)    # the torso cue's height, added
FINE_CUE_STEPS_M = (-0.01, 0.01)
MAX_CUE_UP_M = 0.08
MAX_FACTOR = 1.6                            # no length leaves [estimate / this, estimate * this]
MIN_NECK_M = 0.05
FRAME_COST_MAX = 12.0                       # a frame the estimate fits worse than this is left out
MIN_FRAMES = 5                              # fewer frames left: the estimate stays
# per frame and per % a length moved (per cm of the cue's height). Without it the silhouettes
# recover a rendered body's lengths but pull some of the suite's fused clips far off (docs/body.md)
PRIOR_COST = 0.01
# the published body's own fit (``fit_state_and_published``): the trunk, the torso cue's height
# and the arms searched again from the estimate without the prior; its legs stay the estimate's
PUBLISHED_PARAMS = ("torso_cue_up_m", "trunk_m", "shoulder_half_width_m", "upper_arm_m", "forearm_m")


def _with(lengths: BoneLengths, name: str, value: float) -> BoneLengths | None:
    """``lengths`` with ``name`` set to ``value``, the neck keeping the head where it was; None
    when the neck would be shorter than ``MIN_NECK_M``."""
    if name == "torso_cue_up_m":
        neck = lengths.neck_head_m + (value - lengths.torso_cue_up_m)
    elif name == "trunk_m":
        neck = lengths.neck_head_m + (lengths.trunk_m - value) / 2
    else:
        return replace(lengths, **{name: value})
    return None if neck < MIN_NECK_M else replace(lengths, **{name: value, "neck_head_m": neck})


def frame_costs(lengths: BoneLengths, frames: Sequence[tuple], analytic: AnalyticConfig = AnalyticConfig(),
                fit: FitConfig = FitConfig()) -> np.ndarray:
    """Each frame's cost (module doc) for the body of ``lengths``; ``frames`` as
    ``fit_bone_lengths`` takes them."""
    fitter = BodyFitter(body_model(lengths, "paper"), analytic, fit)
    out = np.empty(len(frames))
    for i, (cues, axes, targets) in enumerate(frames):
        r = fitter.fit(cues, axes, None, targets)
        out[i] = fitter.fit_torso(cues, r.axes, r.swivel, targets)[2]
    return out


def moved_percent(lengths: BoneLengths, estimate: BoneLengths, params: Sequence[str] = PARAMS) -> float:
    """Percent the lengths ``params`` moved from ``estimate`` (cm for the torso cue's height)."""
    p = 0.0
    for name in params:
        a, b = getattr(lengths, name), getattr(estimate, name)
        p += 100.0 * (abs(a - b) if name == "torso_cue_up_m" else abs(np.log(a / b)))
    return p


def fit_bone_lengths(estimate: BoneLengths, frames: Sequence[tuple], analytic: AnalyticConfig = AnalyticConfig(),
                     fit: FitConfig = FitConfig(), sweeps: int = 2, prior_cost: float = PRIOR_COST,
                     params: Sequence[str] = PARAMS) -> BoneLengths:
    """``estimate`` with ``params`` (of ``PARAMS``) fitted to ``frames`` (module doc): ``sweeps``
    coordinate sweeps over ``STEPS`` (``CUE_STEPS_M``), then one over ``FINE_STEPS``
    (``FINE_CUE_STEPS_M``); ``prior_cost`` per frame and per % moved (``PRIOR_COST``).
    ``frames``: (cues (6, 3) metres, world; body axes (3, 3); ``SilhouetteTargets``). Frames
    with a missing cue or no view are skipped; with fewer than ``MIN_FRAMES`` usable,
    ``estimate`` is returned."""
    frames = [f for f in frames if np.isfinite(f[0]).all() and isinstance(f[2], SilhouetteTargets)
              and f[2].n_views > 0]
    if len(frames) < MIN_FRAMES:
        return estimate
    costs = frame_costs(estimate, frames, analytic, fit)
    frames = [f for f, c in zip(frames, costs) if c <= FRAME_COST_MAX]
    if len(frames) < MIN_FRAMES:
        return estimate
    w_prior = prior_cost * len(frames)
    lengths, best = estimate, float(costs[costs <= FRAME_COST_MAX].sum())
    for fine in [False] * sweeps + [True]:
        for name in params:
            v0, e = getattr(lengths, name), getattr(estimate, name)
            if name == "torso_cue_up_m":
                values = [v0 + d for d in (FINE_CUE_STEPS_M if fine else CUE_STEPS_M) if abs(v0 + d) <= MAX_CUE_UP_M]
            else:
                values = [v0 * s for s in (FINE_STEPS if fine else STEPS) if e / MAX_FACTOR <= v0 * s <= e * MAX_FACTOR]
            for v in values:
                cand = _with(lengths, name, v)
                if cand is None:
                    continue
                cost = float(frame_costs(cand, frames, analytic, fit).sum()) + w_prior * moved_percent(cand, estimate,
                                                                                                      params)
                if cost < best:
                    best, lengths = cost, cand
    return lengths


def fit_state_and_published(estimate: BoneLengths, frames: Sequence[tuple], analytic: AnalyticConfig = AnalyticConfig(),
                            fit: FitConfig = FitConfig()) -> tuple[BoneLengths, BoneLengths]:
    """The lengths of the tracker's state, ``fit_bone_lengths`` with the prior, and those of the
    published pose, ``PUBLISHED_PARAMS`` fitted from ``estimate`` without it: the prior holds the
    state near the estimate, where the identity was measured to hold (docs/body.md, "The published
    body's trunk and arms fitted without the prior")."""
    return (fit_bone_lengths(estimate, frames, analytic, fit),
            fit_bone_lengths(estimate, frames, analytic, fit, prior_cost=0.0, params=PUBLISHED_PARAMS))


def _send_args(conn, args: tuple) -> None:
    """``args`` on the pipe ``conn`` as a pickle whose arrays travel out of band (protocol 5),
    written from where they lie rather than copied into one pickle first (~9 MB of frames)."""
    buffers: list[pickle.PickleBuffer] = []
    head = pickle.dumps(args, protocol=5, buffer_callback=buffers.append)
    conn.send(len(buffers))
    conn.send_bytes(head)
    for b in buffers:
        conn.send_bytes(b.raw())


def _recv_args(conn) -> tuple:
    """The ``args`` of ``_send_args`` (writable arrays)."""
    n = conn.recv()
    head = conn.recv_bytes()
    return pickle.loads(head, buffers=[bytearray(conn.recv_bytes()) for _ in range(n)])


def _fit_in_child(jobs, send) -> None:
    """``BackgroundFit``'s process: ``fit_state_and_published(*args)`` of the args received on
    ``jobs``, its result (True, (state, published)) or failure (False, message) sent on ``send``; nothing when the
    parent closed ``jobs`` without a job."""
    try:
        args = _recv_args(jobs)
    except EOFError:
        send.close()
        return
    try:
        send.send((True, fit_state_and_published(*args)))
    except Exception as e:      # noqa: BLE001 - reported to the parent, which keeps its estimate
        send.send((False, f"{type(e).__name__}: {e}"))
    finally:
        send.close()


def _stop(proc) -> None:
    if proc.is_alive():
        proc.terminate()


class BackgroundFit:
    """``fit_state_and_published(*args)`` in a spawned process at the idle CPU priority (the
    service's fusion: 3-7 s of CPU that must neither stall its frames nor share their
    interpreter lock; a thread doubled the service's latency p99).

    The process may start before its job: ``BackgroundFit()`` starts it, ``submit(*args)``
    gives the job (``BackgroundFit(*args)`` does both); the frames go from a thread, pickled
    with their arrays out of band (``_send_args``; a pipe blocks until the process reads them).
    The service's pose after the calibration (the demo's frame 60, p99 11 ms) was late
    (16-42 ms) in 2 of 3 runs with the process started at the job and the ~9 MB pickled in band,
    in 3 of 10 with the early start alone, in 2 of 4 with the out-of-band pickle alone, in 0 of
    10 with both, and in 0 of 4 with the fit turned off. ``done()`` polls, ``result()`` gives
    the lengths or raises ``RuntimeError``. The process is a daemon (a node that stops does not
    wait for it), and is stopped when this object is collected."""

    def __init__(self, *args) -> None:
        ctx = multiprocessing.get_context("spawn")
        self._recv, send = ctx.Pipe(duplex=False)
        jobs, self._jobs = ctx.Pipe(duplex=False)
        self._proc = ctx.Process(target=_fit_in_child, args=(jobs, send), name="mocap-calibrate", daemon=True)
        self._proc.start()
        try:        # Linux: the CPU only when nothing else wants it; else the lowest priority
            os.sched_setscheduler(self._proc.pid, os.SCHED_IDLE, os.sched_param(0))
        except (AttributeError, OSError):
            try:
                os.setpriority(os.PRIO_PROCESS, self._proc.pid, 19)
            except (AttributeError, OSError):
                pass
        send.close()
        jobs.close()
        weakref.finalize(self, _stop, self._proc)
        self._answer: tuple | None = None       # (ok, lengths or message), once received
        self._submitted = False
        if args:
            self.submit(*args)

    def submit(self, *args) -> None:
        """Give the process its job, ``fit_state_and_published(*args)`` (once)."""
        if self._submitted:
            raise RuntimeError("a BackgroundFit runs one job")
        self._submitted = True
        threading.Thread(target=self._send, args=(args,), name="mocap-calibrate-send", daemon=True).start()

    def _send(self, args: tuple) -> None:
        try:
            _send_args(self._jobs, args)
        except OSError:         # the process ended first: result() says so
            pass
        finally:
            self._jobs.close()

    def done(self) -> bool:
        return self._answer is not None or self._recv.poll() or not self._proc.is_alive()

    def result(self, timeout: float | None = None) -> tuple[BoneLengths, BoneLengths]:
        """The fitted lengths (state, published), waiting up to ``timeout`` s (None: until done); RuntimeError when
        the fit failed, the process ended without a result or the time ran out."""
        if self._answer is None:
            try:
                if not self._recv.poll(timeout):
                    raise RuntimeError(f"the bone lengths' fit gave no result within {timeout} s")
                self._answer = self._recv.recv()
            except (EOFError, OSError) as e:
                self._proc.join(0.5)        # a crash: its exit code for the message
                raise RuntimeError("the bone lengths' fit ended without a result (exit code "
                                   f"{self._proc.exitcode})") from e
            # reaped if it has exited; not waited for: the service's frame takes the answer, and
            # the process, at the idle priority, may need the CPU for a while to exit (a join of
            # up to 0.5 s here stalled the demo's poses by 180-500 ms)
            self._proc.join(0)
        ok, value = self._answer
        if not ok:
            raise RuntimeError(f"the bone lengths' fit failed: {value}")
        return value
