"""Camera sources through GStreamer: videotestsrc frames (colour, capture stamps), a recorded
segment played frame by frame, the elements of IEEE1394 cameras, clear errors, and the whole
cluster fed through a file pipeline giving the poses of ``replay:``."""

import time

import numpy as np
import pytest
from service_helpers import small_recording

from mocap_rt.geometry.camera import Camera
from mocap_rt.io.recording import Recording

pytest.importorskip("gi", reason="PyGObject (gi) is not installed: `make system-deps setup` installs it")
gst_source = pytest.importorskip("nodes.gst_source")
from nodes.sources import open_source  # noqa: E402


@pytest.fixture(autouse=True, scope="module")
def _gstreamer():
    """GStreamer initialised (``Gst.init``) when these tests run, not when they are collected:
    every pytest-xdist worker collects every module, and the library tests' worker has no use
    for GStreamer's state in its process."""
    try:
        gst_source.gst_modules()
    except ImportError as exc:                  # gi without GStreamer's typelibs
        pytest.skip(str(exc))


def _camera(w=320, h=240, name="cam_1"):
    return Camera(name=name, size=(w, h), K=np.array([[300.0, 0, w / 2], [0, 300, h / 2], [0, 0, 1]]),
                  dist=np.zeros(5), R=np.eye(3), t=np.zeros(3))


@pytest.fixture(scope="module")
def walk(tmp_path_factory, data_dir):
    return small_recording(tmp_path_factory.getbasetemp(), data_dir)


def test_live_videotestsrc_frames_arrive_in_bgr_with_capture_stamps():
    # solid red (ARGB 0xffff0000): BGR (0, 0, 255) after the appended videoconvert
    src = open_source("gst:videotestsrc is-live=true pattern=solid-color foreground-color=0xffff0000 "
                      "! video/x-raw,width=320,height=240,framerate=30/1", _camera())
    try:
        assert src.live
        grabs, seq = [], -1
        for _ in range(8):
            g = src.grabber.latest(after_seq=seq)
            grabs.append(g)
            seq = g.seq
        now = time.monotonic_ns()
    finally:
        src.close()
    for g in grabs:
        assert g.image.shape == (240, 320, 3) and g.image.dtype == np.uint8
        assert (g.image == [0, 0, 255]).all()
    t = np.array([g.t_mono_ns for g in grabs])
    seq = np.array([g.seq for g in grabs])
    # stamps on this host's monotonic clock (not the pipeline's running time from 0)
    assert np.all(np.diff(t) > 0) and np.all(np.diff(seq) > 0) and 0 <= now - t[-1] < 10e9
    # the buffers' PTS, not the moment the grabber woke up: 30 fps apart per buffer (a consumer
    # slower than the source on a loaded machine skips buffers: the grabber keeps the newest)
    assert np.median(np.diff(t) / np.diff(seq)) == pytest.approx(1e9 / 30, rel=0.2)


def test_live_mjpeg_through_avdec_mjpeg_keeps_the_colours():
    """A live MJPEG stream (solid colours -> full-range I420 -> jpegenc, as a UVC webcam's)
    decoded by avdec_mjpeg: its I420 goes to the appsink and is converted in Python (JFIF
    BT.601 full range); each colour comes back within JPEG's and the fixed point's rounding."""
    for argb, bgr in ((0xFFFF0000, (0, 0, 255)), (0xFF00C000, (0, 192, 0)), (0xFF808080, (128, 128, 128)),
                      (0xFF2040A0, (160, 64, 32))):
        src = open_source(f"gst:videotestsrc is-live=true pattern=solid-color foreground-color={argb:#x} "
                          "! video/x-raw,format=BGR,width=320,height=240,framerate=30/1 ! videoconvert "
                          "! video/x-raw,format=I420,colorimetry=1:4:0:0 ! jpegenc quality=95 ! jpegparse ! avdec_mjpeg",
                          _camera())
        try:
            g = src.grabber.latest(after_seq=-1, timeout_s=20.0)      # a live pipeline's first frame: ~1 s
        finally:
            src.close()
        assert g.image.shape == (240, 320, 3)
        assert np.abs(g.image.reshape(-1, 3).astype(int) - bgr).max() <= 3, (hex(argb), g.image[120, 160])


def test_file_pipeline_plays_a_recorded_segment_frame_by_frame(walk):
    rec = Recording(walk)
    src = open_source(f"gst:filesrc location={walk}/video/{{camera}}/seg_000000.avi ! avidemux ! jpegdec",
                      rec.rig["cam_2"], backgrounds_from=str(walk))
    try:
        assert not src.live and src.origin == rec.source
        np.testing.assert_array_equal(src.backgrounds(), rec.backgrounds("cam_2"))
        diffs = []
        for k in (0, 1, 2, 17, 29, 30, 33, 61):          # 30 frames per segment: it loops
            src.prefetch(k)
            g = src.grab(k)
            ref = rec.read_frame("cam_2", k % rec.segment_frames)
            diffs.append(np.abs(g.image.astype(int) - ref.astype(int)))
            assert g.seq == k % rec.segment_frames
        assert src.n_frames == rec.segment_frames
    finally:
        src.close()
    # GStreamer's jpegdec + videoconvert and OpenCV's decoder round differently
    assert max(d.max() for d in diffs) <= 8 and np.mean([d.mean() for d in diffs]) < 1.0


def test_avdec_mjpeg_frames_are_the_pixels_of_opencv(walk):
    """FFmpeg's MJPEG decoder in GStreamer + the swscale-exact I420 -> BGR of mocap_rt.io.yuv:
    every frame equals cv2.VideoCapture's (the decoder of replay:), bit for bit."""
    rec = Recording(walk)
    src = open_source(f"gst:filesrc location={walk}/video/{{camera}}/seg_000000.avi ! avidemux ! avdec_mjpeg",
                      rec.rig["cam_3"], backgrounds_from=str(walk))
    try:
        for k in range(rec.segment_frames):
            src.prefetch(k)
            np.testing.assert_array_equal(src.grab(k).image, rec.read_frame("cam_3", k), err_msg=f"frame {k}")
    finally:
        src.close()


def test_ieee1394_and_bad_pipelines_fail_with_clear_errors():
    with pytest.raises(ValueError, match="nosuchsrc"):
        open_source("gst:nosuchsrc", _camera())
    with pytest.raises(RuntimeError, match="100x50, the rig camera is 320x240"):
        open_source("gst:videotestsrc ! video/x-raw,width=100,height=50", _camera()).grab(0)
    with pytest.raises(RuntimeError, match="I420 colorimetry bt2020"):          # only BT.601/709 are converted
        open_source("gst:videotestsrc num-buffers=2 ! video/x-raw,format=I420,width=320,height=240,colorimetry=bt2020 "
                    "! appsink", _camera()).grab(0)
    # dc1394src (IEEE1394/IIDC) is there; with no camera on the bus it says so
    with pytest.raises(RuntimeError, match="dc1394src"):
        open_source("gst:dc1394src", _camera())
    with pytest.raises(ValueError, match="index"):
        open_source("gst:v4l2src device=/dev/video{index}", _camera())


SPEED = 0.2         # 6 fps: a 167 ms deadline (fusion presumes a camera dead after 0.25 s)


def _run(rec_dir, source, out, **kw):
    from nodes.launcher import Launcher, RunConfig

    cfg = RunConfig(rig_path=rec_dir / "rig.toml", source=source, record=out / "rec", log_dir=out / "logs",
                    status_line=False, speed=SPEED, deadline_frac=1.0, **kw)
    stats = Launcher(cfg).run()
    return stats, np.load(out / "rec" / "poses.npz")


@pytest.mark.slow
def test_cluster_through_a_file_pipeline_gives_the_poses_of_replay(walk, tmp_path):
    """Six workers each play their camera's recorded MJPG segment through filesrc -> avidemux
    -> avdec_mjpeg -> appsink (I420, converted as OpenCV's swscale does); fusion must find the
    poses ``replay:`` finds on the same frames. Both runs trigger at a fifth of the
    recording's rate with a whole period as the deadline, so that every camera answers every
    frame even on a loaded machine."""
    seg = Recording(walk).segment_frames
    duration_s = (seg + 8) / (30 * SPEED)        # the first segment, which both runs compare
    _, ref = _run(walk, f"replay:{walk}", tmp_path / "replay", duration_s=duration_s)
    stats, got = _run(walk, f"gst:filesrc location={walk}/video/{{camera}}/seg_000000.avi ! avidemux ! avdec_mjpeg",
                      tmp_path / "gst", backgrounds_from=walk, duration_s=duration_s)
    assert all(n["restarts"] == 0 for n in stats["nodes"].values())
    common = np.intersect1d(ref["frames"][ref["frames"] < seg], got["frames"][got["frames"] < seg])
    assert len(common) >= seg - 2, (ref["frames"], got["frames"])
    a = ref["joints"][np.searchsorted(ref["frames"], common)]
    b = got["joints"][np.searchsorted(got["frames"], common)]
    ok = np.isfinite(a).all(axis=2) & np.isfinite(b).all(axis=2)
    assert ok.mean() > 0.8 and (np.isfinite(a).all(axis=2) == np.isfinite(b).all(axis=2)).all()
    diff_mm = np.linalg.norm(a - b, axis=2)[ok] * 1e3
    print(f"gst vs replay on {len(common)} frames: MPJPE difference {diff_mm.mean():.4f} mm, "
          f"max {diff_mm.max():.4f} mm")
    assert diff_mm.mean() <= 1.0
