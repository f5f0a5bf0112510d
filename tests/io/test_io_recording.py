"""The recorded stream format: round trip, random access, bad files, crash safety."""

import textwrap

import numpy as np
import pytest

from mocap_rt.geometry.rig import ring_rig
from mocap_rt.io.recording import Recording, RecordingError, RecordingWriter

W, H = 160, 120


def _image(frame: int, cam: int) -> np.ndarray:
    """A smooth, frame- and camera-specific test image (JPEG keeps it within a few levels)."""
    yy, xx = np.mgrid[0:H, 0:W]
    img = np.empty((H, W, 3), np.uint8)
    img[..., 0] = (xx + 37 * frame) % 256
    img[..., 1] = (yy * 2 + 40 * cam) % 256
    img[..., 2] = 128
    img[40:80, (frame * 4) % 120:(frame * 4) % 120 + 30] = (30, 60, 200)
    return img


def _write(path, n_frames=25, fps=10.0, n_cams=2):
    rig = ring_rig(n_cams, size=(W, H))
    with RecordingWriter(path, rig, fps=fps) as w:
        for c in range(n_cams):
            w.write_backgrounds(rig[c].name, np.stack([_image(0, c), _image(1, c)]))
        for f in range(n_frames):
            w.write_frame(100 + f, [_image(f, c) for c in range(n_cams)],
                          [f / fps + 0.001 * c for c in range(n_cams)])
        w.write_truth({"frames": np.arange(n_frames), "camera_names": np.array(rig.names)})
    return rig


def test_round_trip(tmp_path):
    rig = _write(tmp_path / "rec")
    rec = Recording(tmp_path / "rec")
    assert rec.camera_names == list(rig.names) and rec.fps == 10.0 and rec.n_frames == 25
    np.testing.assert_array_equal(rec.frames, 100 + np.arange(25))
    np.testing.assert_allclose(rec.timestamps[:, 1], np.arange(25) / 10 + 0.001, atol=1e-6)
    np.testing.assert_allclose(rec.rig[1].K, rig[1].K)
    np.testing.assert_array_equal(rec.backgrounds("cam_2")[1], _image(1, 1))  # PNG is lossless
    for f, img in rec.iter_frames(0):
        assert np.abs(img.astype(int) - _image(f, 0)).mean() < 3.0
    # random access across segments, both directions, by name and index
    for f in (24, 3, 17, 18, 0, 11):
        for c in (1, "cam_1"):
            ci = 0 if c == "cam_1" else c
            img = rec.read_frame(c, f)
            assert np.abs(img.astype(int) - _image(f, ci)).mean() < 3.0, (c, f)
            other = _image(f + 1, ci)
            assert np.abs(img.astype(int) - other).mean() > 5.0
    assert list(rec.truth["camera_names"]) == list(rig.names)
    rec.validate()
    with pytest.raises(KeyError, match="cam_9"):
        rec.read_frame("cam_9", 0)


def test_rejects_unknown_version(tmp_path):
    _write(tmp_path / "rec", n_frames=3)
    meta = tmp_path / "rec" / "recording.toml"
    meta.write_text(meta.read_text().replace("version = 1", "version = 7"))
    with pytest.raises(RecordingError, match=r"recording\.toml.*'version' = 7"):
        Recording(tmp_path / "rec")


def test_rejects_missing_camera(tmp_path):
    _write(tmp_path / "rec", n_frames=3)
    for f in (tmp_path / "rec" / "video" / "cam_2").iterdir():
        f.unlink()
    (tmp_path / "rec" / "video" / "cam_2").rmdir()
    with pytest.raises(RecordingError, match="cam_2.*missing"):
        Recording(tmp_path / "rec")


def test_rejects_truncated_video(tmp_path):
    _write(tmp_path / "rec", n_frames=25)
    seg = tmp_path / "rec" / "video" / "cam_1" / "seg_000001.avi"
    seg.write_bytes(seg.read_bytes()[: seg.stat().st_size // 3])
    rec = Recording(tmp_path / "rec")
    with pytest.raises(RecordingError, match="seg_000001.avi"):
        for _ in rec.iter_frames("cam_1"):
            pass
    with pytest.raises(RecordingError, match="seg_000001.avi"):
        rec.validate()


def test_rejects_table_rig_mismatch(tmp_path):
    _write(tmp_path / "rec", n_frames=3)
    t = tmp_path / "rec" / "frames.csv"
    t.write_text(t.read_text().replace("frame,cam_1,cam_2", "frame,cam_1,cam_X"))
    with pytest.raises(RecordingError, match="frames.csv.*header"):
        Recording(tmp_path / "rec")


def test_not_a_recording(tmp_path):
    with pytest.raises(RecordingError, match="recording.toml"):
        Recording(tmp_path)


def test_crash_safety_sigkill(tmp_path, kill_when_ready):
    out = tmp_path / "live"
    script = textwrap.dedent(f"""
        import time, numpy as np
        from mocap_rt.geometry.rig import ring_rig
        from mocap_rt.io.recording import RecordingWriter
        rig = ring_rig(2, size=({W}, {H}))
        w = RecordingWriter({str(out)!r}, rig, fps=10.0, source="live")
        for f in range(10**6):
            img = np.full(({H}, {W}, 3), f % 256, np.uint8)
            w.write_frame(f, [img, img], [f * 0.1, f * 0.1])
            if f == 34:
                print("ready", flush=True)
            if f > 34:
                time.sleep(0.002)
    """)
    kill_when_ready(script)
    rec = Recording(out)
    assert rec.n_frames >= 30 and rec.n_frames % 10 == 0   # whole 1 s segments kept
    rows = len((out / "frames.csv").read_text().splitlines()) - 1
    assert rows - rec.n_frames <= 2 * 10  # at most the open segment (+ rows written meanwhile)
    for f, img in rec.iter_frames("cam_2"):
        assert abs(float(img.mean()) - f % 256) < 3.0
