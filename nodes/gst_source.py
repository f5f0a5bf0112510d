"""Camera sources through GStreamer (PyGObject): ``--source gst:"PIPELINE"``.

One pipeline description per camera (``{camera}`` and ``{index}`` in it are replaced by the
rig camera's name and its 0-based rig index, so one template serves the whole rig), e.g.

* ``dc1394src guid=GUID ! videoconvert`` — IEEE1394/IIDC cameras (GUID: the camera's 64-bit bus id in hex;
  without ``guid`` the first camera on the bus);
* ``aravissrc camera-name={camera} ! videoconvert`` — GenICam (GigE/USB3 Vision) cameras;
* ``rtspsrc location=rtsp://10.0.0.{index}/stream latency=0 ! decodebin`` — IP cameras;
* ``v4l2src device=/dev/video{index} ! image/jpeg ! jpegdec`` — V4L2 through GStreamer;
* ``filesrc location=REC/video/{camera}/seg_000000.avi ! avidemux ! jpegdec`` — a recorded
  segment of the recording format.

Unless the description has its own ``appsink``, ``! videoconvert ! video/x-raw,format=BGR !
appsink`` is appended. The pipeline is put in PAUSED first: a **live** pipeline (its sources
capture on their own clock; GStreamer answers NO_PREROLL) becomes a ``LiveSource`` behind the
same ``Grabber`` thread as V4L2, keeping only the newest frame, stamped with the buffer's
**PTS** mapped onto the monotonic clock (the element's capture time: for ``v4l2src`` the
driver's timestamp, for ``aravissrc`` / ``dc1394src`` the camera's when they give one) and a
wall-clock stamp from a ``timestamp/x-unix`` reference-timestamp meta when present (a
hardware or PTP time). A **non-live** pipeline (files) is played frame by frame like
``replay:``: trigger ``k`` gets pipeline frame ``k mod n`` (it is rewound at end of stream),
and the next frame is decoded between triggers.

Backgrounds: a live pipeline captures ``LIVE_BACKGROUND_FRAMES`` frames at start (empty
scene), a file pipeline takes its first ones; ``backgrounds_from=REC_DIR`` takes the stored
empty-scene images of a recording instead (and its ``source``, e.g. "studio", which selects
the perception preset), so a recording played through GStreamer is perceived exactly like
``replay:`` of it.

PyGObject (``gi``) is imported only here, on first use: the library and the other sources
work without it.
"""

from __future__ import annotations

import logging
import time
from pathlib import Path

import numpy as np

from nodes.live import GRAB_TIMEOUT_S, LIVE_BACKGROUND_FRAMES, Grab, LiveSource

log = logging.getLogger(__name__)

SINK_NAME = "mocap_rt_sink"
APPENDED = f" ! videoconvert ! video/x-raw,format=BGR ! appsink name={SINK_NAME}"
# FFmpeg's MJPEG decoder (what cv2.VideoCapture decodes recordings with): its planar 4:2:0 goes
# to the appsink and is converted like OpenCV's swscale does (mocap_rt.io.yuv), so a recording
# played through GStreamer gives the very pixels of replay:
APPENDED_YUV = f" ! videoconvert ! video/x-raw,format=I420 ! appsink name={SINK_NAME}"
YUV_DECODERS = ("avdec_mjpeg",)
STATE_TIMEOUT_S = 10.0
_gst = None


def gst_modules():
    """(Gst, GstVideo) after ``Gst.init``; ImportError naming what to install when missing."""
    global _gst
    if _gst is None:
        try:
            import gi

            gi.require_version("Gst", "1.0")
            gi.require_version("GstVideo", "1.0")
            gi.require_version("GstApp", "1.0")
            from gi.repository import Gst, GstApp, GstVideo  # noqa: F401 - GstApp: appsink methods
        except (ImportError, ValueError) as exc:
            raise ImportError(f"gst: sources need GStreamer's Python bindings ({exc}); run `make system-deps "
                              f"setup` (Debian gstreamer1.0-plugins-*, gir1.2-gst*, PyGObject<3.50 in the venv)") from None
        Gst.init(None)
        _gst = (Gst, GstVideo)
    return _gst


def pipeline_for(template: str, camera: str, index: int) -> str:
    """The description of one camera: ``{camera}`` / ``{index}`` substituted, appsink appended."""
    desc = str(template).replace("{camera}", camera).replace("{index}", str(index)).strip()
    if not desc:
        raise ValueError("--source gst: empty pipeline")
    if "appsink" in desc:
        return desc
    last = desc.rsplit("!", 1)[-1].split()
    return desc + (APPENDED_YUV if last and last[0] in YUV_DECODERS else APPENDED)


class GstPipeline:
    """A parsed pipeline with its appsink; ``live`` tells how its sources behave."""

    def __init__(self, description: str, size: tuple[int, int]) -> None:
        Gst, _ = gst_modules()
        self.description = description
        self.size = (int(size[0]), int(size[1]))
        try:
            self.pipeline = Gst.parse_launch(description)
        except Exception as exc:       # GLib.Error: unknown element, bad syntax
            raise ValueError(f"--source gst:{description!r}: {exc}") from None
        self.sink = self.pipeline.get_by_name(SINK_NAME) or self._find_appsink()
        ret = self.pipeline.set_state(Gst.State.PAUSED)
        if ret == Gst.StateChangeReturn.FAILURE:
            self._raise_bus_error("cannot start")
        self.live = ret == Gst.StateChangeReturn.NO_PREROLL
        # live: keep only the newest frame (like a V4L2 buffer of 1); files: every frame, in order
        self.sink.set_property("sync", False)
        self.sink.set_property("max-buffers", 1 if self.live else 2)
        self.sink.set_property("drop", self.live)
        if self.pipeline.set_state(Gst.State.PLAYING) == Gst.StateChangeReturn.FAILURE:
            self._raise_bus_error("cannot play")
        self.frames = 0

    def _find_appsink(self):
        Gst, _ = gst_modules()
        it = self.pipeline.iterate_sinks()
        while True:
            ok, elem = it.next()
            if ok != Gst.IteratorResult.OK:
                raise ValueError(f"--source gst:{self.description!r}: no appsink in the pipeline")
            if elem.get_factory() is not None and elem.get_factory().get_name() == "appsink":
                return elem

    def _raise_bus_error(self, what: str) -> None:
        Gst, _ = gst_modules()
        msg = self.pipeline.get_bus().timed_pop_filtered(0, Gst.MessageType.ERROR)
        detail = msg.parse_error()[0].message if msg is not None else "state change failed"
        self.pipeline.set_state(Gst.State.NULL)
        raise RuntimeError(f"--source gst:{self.description!r}: {what}: {detail}")

    def pull(self, timeout_s: float) -> tuple[np.ndarray, int, int] | None:
        """(image (H, W, 3) uint8 BGR, capture t_mono_ns, t_wall_ns), or None at end of stream
        / timeout. The appsink gets BGR, or I420 converted as OpenCV's FFmpeg backend does
        (``mocap_rt.io.yuv``). A pipeline error raises RuntimeError with GStreamer's message."""
        Gst, GstVideo = gst_modules()
        sample = self.sink.try_pull_sample(int(timeout_s * Gst.SECOND))
        if sample is None:
            if self.pipeline.get_bus().have_pending():
                msg = self.pipeline.get_bus().pop_filtered(Gst.MessageType.ERROR)
                if msg is not None:
                    self.pipeline.set_state(Gst.State.NULL)
                    err, debug = msg.parse_error()
                    raise RuntimeError(f"--source gst:{self.description!r}: {err.message} ({debug})")
            return None
        info = GstVideo.VideoInfo.new_from_caps(sample.get_caps())
        if info.finfo.format not in (GstVideo.VideoFormat.BGR, GstVideo.VideoFormat.I420):
            raise RuntimeError(f"--source gst:{self.description!r}: appsink caps must be format=BGR or I420")
        if (info.width, info.height) != self.size:
            raise RuntimeError(f"--source gst:{self.description!r}: frames are {info.width}x{info.height}, "
                               f"the rig camera is {self.size[0]}x{self.size[1]}")
        buf = sample.get_buffer()
        ok, mapped = buf.map(Gst.MapFlags.READ)
        if not ok:
            raise RuntimeError(f"--source gst:{self.description!r}: cannot map a buffer")
        try:
            if info.finfo.format == GstVideo.VideoFormat.I420:
                image = self._i420(info, mapped.data)
            else:
                rows = np.frombuffer(mapped.data, np.uint8, count=info.stride[0] * info.height)
                image = rows.reshape(info.height, info.stride[0])[:, :info.width * 3].reshape(
                    info.height, info.width, 3).copy()
        finally:
            buf.unmap(mapped)
        t_mono, t_wall = self._stamps(buf)
        self.frames += 1
        return image, t_mono, t_wall

    def _i420(self, info, data) -> np.ndarray:
        """BGR of a mapped I420 buffer (planes at the caps' offsets and strides)."""
        from mocap_rt.io.yuv import i420_to_bgr

        _, GstVideo = gst_modules()
        c = info.colorimetry
        full, video = (GstVideo.VideoColorRange(n) for n in (1, 2))       # 0_255, 16_235
        matrix = {GstVideo.VideoColorMatrix.BT601: "bt601", GstVideo.VideoColorMatrix.BT709: "bt709"}.get(c.matrix)
        if matrix is None or c.range not in (full, video):
            raise RuntimeError(f"--source gst:{self.description!r}: I420 colorimetry {c.to_string()} "
                               f"is not BT.601/BT.709 at full or video range")
        buf = np.frombuffer(data, np.uint8)
        chroma = ((info.height + 1) // 2, (info.width + 1) // 2)
        planes = []
        for p, (h, w) in enumerate(((info.height, info.width), chroma, chroma)):
            stride, off = info.stride[p], info.offset[p]
            planes.append(buf[off:off + stride * h].reshape(h, stride)[:, :w])
        return i420_to_bgr(*planes, matrix=matrix, full_range=c.range == full)

    def _stamps(self, buf) -> tuple[int, int]:
        """Capture time of ``buf``: its PTS (running time) + base time on the pipeline clock,
        moved onto this host's monotonic clock; wall time from a ``timestamp/x-unix``
        reference meta (hardware/PTP) when the element attached one."""
        Gst, _ = gst_modules()
        now_mono, now_wall = time.monotonic_ns(), time.time_ns()
        clock = self.pipeline.get_clock()
        if buf.pts == Gst.CLOCK_TIME_NONE or clock is None:
            return now_mono, now_wall
        age = clock.get_time() - (self.pipeline.get_base_time() + buf.pts)
        age = max(0, age)
        t_wall = now_wall - age
        try:
            meta = buf.get_reference_timestamp_meta(Gst.Caps.from_string("timestamp/x-unix"))
            if meta is not None:
                t_wall = int(meta.timestamp)
        except (AttributeError, TypeError):
            pass
        return now_mono - age, t_wall

    def rewind(self) -> None:
        """Back to the first frame (files)."""
        Gst, _ = gst_modules()
        if not self.pipeline.seek_simple(Gst.Format.TIME, Gst.SeekFlags.FLUSH | Gst.SeekFlags.ACCURATE, 0):
            raise RuntimeError(f"--source gst:{self.description!r}: cannot seek back to the start")
        self.pipeline.get_state(int(STATE_TIMEOUT_S * Gst.SECOND))

    def close(self) -> None:
        Gst, _ = gst_modules()
        self.pipeline.set_state(Gst.State.NULL)


class GstDevice:
    """A live pipeline as a ``Device`` for ``Grabber``: ``read()`` blocks for the next frame;
    ``capture_stamps()`` gives the last frame's (t_mono_ns, t_wall_ns)."""

    def __init__(self, pipe: GstPipeline) -> None:
        self.pipe = pipe
        self._stamps = (0, 0)

    def read(self) -> tuple[bool, np.ndarray | None]:
        got = self.pipe.pull(GRAB_TIMEOUT_S)
        if got is None:
            return False, None
        image, *stamps = got
        self._stamps = tuple(stamps)
        return True, image

    def capture_stamps(self) -> tuple[int, int]:
        return self._stamps

    def release(self) -> None:
        self.pipe.close()


class GstFileSource:
    """A non-live pipeline played frame by frame: trigger ``k`` -> pipeline frame ``k mod n``
    (``n`` learnt at the first end of stream), like ``ReplaySource``."""

    live = False

    def __init__(self, pipe: GstPipeline, camera: str, backgrounds_fn=None, origin: str = "live") -> None:
        self.pipe, self.camera, self.origin = pipe, camera, origin
        self._backgrounds_fn = backgrounds_fn
        self.n_frames: int | None = None
        self._pos = 0                          # index of the next frame the pipeline gives
        self._next: tuple[int, np.ndarray] | None = None

    def _frame(self, frame_id: int) -> np.ndarray:
        idx = frame_id if self.n_frames is None else frame_id % self.n_frames
        if self._next is not None and self._next[0] == idx:
            return self._next[1]
        if idx < self._pos:
            self.pipe.rewind()
            self._pos = 0
        while True:
            got = self.pipe.pull(GRAB_TIMEOUT_S)
            if got is None:                    # end of stream: now the length is known
                if self._pos == 0:
                    raise RuntimeError(f"--source gst:{self.pipe.description!r}: no frames")
                self.n_frames = self._pos
                self.pipe.rewind()
                self._pos = 0
                idx %= self.n_frames
                continue
            self._pos += 1
            if self._pos - 1 == idx:
                return got[0]

    def grab(self, frame_id: int) -> Grab:
        t_mono, t_wall = time.monotonic_ns(), time.time_ns()
        image = self._frame(frame_id)
        self._next = None
        return Grab(image, t_mono, t_wall, frame_id if self.n_frames is None else frame_id % self.n_frames)

    def prefetch(self, frame_id: int) -> None:
        """Decode the image of ``frame_id`` now (between triggers), as ``ReplaySource`` does."""
        self._next = None
        image = self._frame(frame_id)                  # may learn n_frames
        self._next = (frame_id if self.n_frames is None else frame_id % self.n_frames, image)

    def backgrounds(self) -> np.ndarray:
        if self._backgrounds_fn is not None:
            return np.asarray(self._backgrounds_fn())
        return np.stack([self._frame(i) for i in range(LIVE_BACKGROUND_FRAMES)])

    def close(self) -> None:
        self.pipe.close()


def open_gst_source(template: str, camera, index: int, backgrounds_from: str | Path | None = None):
    """The source of rig camera ``camera`` (its ``index`` in the rig) for ``gst:template``."""
    backgrounds_fn, origin = None, "live"
    if backgrounds_from:
        from mocap_rt.io.recording import Recording

        rec = Recording(backgrounds_from)
        if camera.name not in list(rec.camera_names):
            raise ValueError(f"--backgrounds-from {backgrounds_from}: no camera {camera.name!r}")
        backgrounds_fn, origin = (lambda: rec.backgrounds(camera.name)), rec.source
    pipe = GstPipeline(pipeline_for(template, camera.name, index), tuple(camera.size))
    log.info("gst source %s: %s pipeline %s", camera.name, "live" if pipe.live else "file", pipe.description)
    if pipe.live:
        return LiveSource(GstDevice(pipe), camera.name, backgrounds_fn=backgrounds_fn, origin=origin)
    return GstFileSource(pipe, camera.name, backgrounds_fn, origin)
