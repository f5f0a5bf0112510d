"""End to end: synthesize -> recording; truth against OpenCV and against the pixels."""

import cv2
import numpy as np
import pytest

from mocap_rt.cli import main as cli_main
from mocap_rt.geometry.rig import read_rig
from mocap_rt.io.recording import Recording
from mocap_rt.names import CUE_NAMES, JOINT_NAMES
from mocap_rt.studio.body_shape import DEFAULT_ALBEDO_BGR
from mocap_rt.studio.synth import make_rig, synthesize, unpack_masks

W, H = 320, 240
N_FRAMES = 12


@pytest.fixture(scope="module")
def recording(data_dir, tmp_path_factory):
    out = tmp_path_factory.mktemp("synth") / "rec"
    rig = make_rig("ring", 6, (W, H))
    stats = synthesize(data_dir / "bvh" / "cmu" / "cmu_131_01_start_walk_stop.bvh", out, rig=rig,
                       fps=30.0, seconds=N_FRAMES / 30.0, start_s=3.0, seed=5, n_backgrounds=2)
    assert stats.n_frames == N_FRAMES and stats.n_images == 6 * N_FRAMES
    return Recording(out)


def test_truth_keys_and_shapes(recording):
    t = recording.truth
    F, C = N_FRAMES, 6
    assert list(t["joint_names"]) == list(JOINT_NAMES) and list(t["cue_names"]) == list(CUE_NAMES)
    assert t["joints"].shape == (F, 20, 3) and t["cues"].shape == (F, 6, 3)
    assert list(t["camera_names"]) == recording.camera_names == [c.name for c in read_rig(recording.path / "rig.toml")]
    assert t["cues_2d"].shape == (C, F, 6, 2) and t["cue_visibility"].shape == (C, F, 6)
    assert ((t["cue_visibility"] >= 0) & (t["cue_visibility"] <= 1)).all()
    np.testing.assert_array_equal(t["frames"], recording.frames)
    assert t["bone_lengths"].shape == t["bone_names"].shape and (t["bone_lengths"] > 0.03).all()
    assert t["masks"].shape == (C, F, H, W // 8)
    np.testing.assert_allclose(t["cues"][:, 1], t["joints"][:, JOINT_NAMES.index("hand_l")])
    assert recording.n_frames == F and recording.backgrounds(0).shape == (2, H, W, 3)


def test_truth_2d_is_opencv_projection_with_the_written_rig(recording):
    t = recording.truth
    rig = read_rig(recording.path / "rig.toml")
    for ci, cam in enumerate(rig.cameras):
        pts = t["cues"].reshape(-1, 3)
        uv, _ = cv2.projectPoints(pts, cam.rvec, cam.t, cam.K, cam.dist)
        np.testing.assert_allclose(t["cues_2d"][ci].reshape(-1, 2), uv.reshape(-1, 2), atol=1e-6)


def _chroma(bgr):
    bgr = np.asarray(bgr, float)
    return bgr[..., :3] / bgr.sum(axis=-1, keepdims=True)


def test_pixels_at_visible_cues_have_the_cue_colour(recording):
    t = recording.truth
    skin = _chroma(DEFAULT_ALBEDO_BGR["skin"])
    shoe = _chroma(DEFAULT_ALBEDO_BGR["shoe"])
    n_skin = n_shoe = 0
    for ci, name in enumerate(recording.camera_names):
        for f, img in recording.iter_frames(name):
            for k, cue in enumerate(CUE_NAMES):
                if t["cue_visibility"][ci, f, k] < 0.9:
                    continue
                u, v = np.round(t["cues_2d"][ci, f, k]).astype(int)
                patch = img[v - 1:v + 2, u - 1:u + 2].reshape(-1, 3).mean(axis=0)  # 3x3 vs sensor noise
                c = _chroma(patch)
                if cue in ("head", "hand_l", "hand_r"):
                    assert np.abs(c - skin).max() < 0.03, (name, f, cue, patch)
                    n_skin += 1
                elif cue in ("foot_l", "foot_r"):
                    # shaded saturated green: JPEG shifts its chromaticity, the hue stays
                    assert patch[1] > 2 * patch[0] and patch[1] > 2 * patch[2], (name, f, cue, patch)
                    assert shoe[1] > 2 * shoe[0] and shoe[1] > 2 * shoe[2]
                    n_shoe += 1
                else:
                    assert np.abs(c - skin).max() > 0.05  # the shirt is not skin
    assert n_skin > 100 and n_shoe > 40


def test_masks_match_pixels_against_background(recording):
    t = recording.truth
    masks = unpack_masks(t, W)
    assert masks.shape == (6, N_FRAMES, H, W)
    bg = recording.backgrounds("cam_3")[0].astype(int)
    img = recording.read_frame("cam_3", 6).astype(int)
    changed = np.abs(img - bg).sum(axis=2) > 40
    m = masks[2, 6]
    assert m.sum() > 500
    # silhouette pixels differ from the empty studio; elsewhere only the shadow (darker) and
    # JPEG ringing next to the silhouette do
    assert changed[m].mean() > 0.9
    near = cv2.dilate(m.astype(np.uint8), np.ones((5, 5), np.uint8)).astype(bool)
    outside = changed & ~near
    darker = (img - bg).sum(axis=2) < 0
    assert darker[outside].mean() > 0.98  # (a few JPEG-blurred pixels on the horizon line)


def test_deterministic_for_a_seed(data_dir, tmp_path):
    clip = data_dir / "bvh" / "cmu" / "cmu_02_01_walk.bvh"
    rig = make_rig("ring", 2, (160, 120))
    for name, seed in (("a", 1), ("b", 1), ("c", 2)):
        synthesize(clip, tmp_path / name, rig=rig, seconds=0.2, seed=seed, n_backgrounds=1, truth_masks=False)
    ra, rb, rc = (Recording(tmp_path / n) for n in "abc")
    np.testing.assert_array_equal(ra.read_frame(1, 3), rb.read_frame(1, 3))
    assert not np.array_equal(ra.read_frame(1, 3), rc.read_frame(1, 3))
    for k in ("joints", "cues_2d", "cue_visibility"):
        np.testing.assert_array_equal(ra.truth[k], rb.truth[k])
    assert "masks" not in ra.truth


def test_cli_desktop_rig(data_dir, tmp_path, capsys):
    out = tmp_path / "desk"
    code = cli_main(["synth", "--motion", str(data_dir / "bvh" / "bandai_namco" / "dataset-1_bye_normal_001.bvh"),
                     "--rig", "desktop", "--size", "160x120", "--fps", "60", "--seconds", "0.25",
                     "--seed", "0", "--out", str(out), "--no-progress", "--no-truth-masks",
                     "--light", "30,60,0.5", "--light", "200,40,0.2,noshadow", "--flicker", "0.05"])
    assert code == 0
    rec = Recording(out)
    assert rec.camera_names == ["cam_1", "cam_2"] and rec.fps == 60.0 and rec.n_frames == 15
    assert rec.read_frame(1, 14).shape == (120, 160, 3)
    # the desktop rig frames the upper body: head and hands in view
    vis = rec.truth["cue_visibility"]
    assert (vis[:, :, 0] > 0.5).all()
    assert "wrote" in capsys.readouterr().out
    assert cli_main(["synth", "--motion", str(tmp_path / "missing.bvh"), "--out", str(tmp_path / "x")]) == 2
    with pytest.raises(SystemExit):
        cli_main(["synth", "--motion", "x.bvh", "--out", "y", "--light", "30,-5,1"])
    assert cli_main(["synth", "--motion", str(data_dir / "bvh" / "cmu" / "cmu_02_01_walk.bvh"),
                     "--out", str(out)]) == 2  # refuses to overwrite


def test_every_shared_clip_gives_a_replayable_recording(data_dir, tmp_path):
    rig = make_rig("ring", 2, (96, 72))
    clips = sorted((data_dir / "bvh").glob("*/*.bvh"))
    assert len(clips) == 13
    for i, clip in enumerate(clips):
        out = tmp_path / f"r{i}"
        synthesize(clip, out, rig=rig, seconds=0.1, start_s=0.4, n_backgrounds=1, truth_masks=False)
        rec = Recording(out)
        rec.validate()
        assert rec.n_frames == 3 and rec.read_frame(1, 2).shape == (72, 96, 3)
        t = rec.truth
        assert np.isfinite(t["joints"]).all() and np.isfinite(t["cues_2d"]).all(), clip.name
        # the subject is in view of the ring's cameras
        assert (t["cue_visibility"][:, :, CUE_NAMES.index("torso")] > 0.2).all(), clip.name


def test_synth_config_file_sets_the_render_config_and_flags_override(data_dir, tmp_path, monkeypatch, capsys):
    """--config's [render] table is the RenderConfig synthesize gets; a flag given overrides its key."""
    from types import SimpleNamespace

    import mocap_rt.studio.synth as synth
    from mocap_rt.studio.render import RenderConfig
    from mocap_rt.studio.scene import Light, StudioScene

    got = {}

    def fake(motion, out, **kw):
        got.update(kw)
        return SimpleNamespace(out=out, n_frames=0, n_images=0, total_s=0.0, render_s=0.0, encode_s=0.0)

    monkeypatch.setattr(synth, "synthesize", fake)
    cfg = tmp_path / "r.toml"
    cfg.write_text("[render]\nnoise_sigma_levels = 0.5\nflicker_hz = 2.0\nshadows = false\n"
                   "[render.albedo_bgr]\nshirt = [0.1, 0.2, 0.3]\n"
                   "[scene]\nambient = 0.3\nlights = [{ direction = [0.0, -1.0, 1.0], intensity = 0.7 }]\n")
    argv = ["synth", "--motion", str(data_dir / "bvh" / "cmu" / "cmu_02_01_walk.bvh"), "--out", str(tmp_path / "o"),
            "--config", str(cfg), "--no-progress"]
    assert cli_main([*argv, "--flicker", "0.1"]) == 0
    assert got["config"] == RenderConfig(noise_sigma_levels=0.5, flicker_amplitude=0.1, flicker_hz=2.0,
                                         shadows=False, albedo_bgr={"shirt": [0.1, 0.2, 0.3]})
    assert got["scene"] == StudioScene(ambient=0.3, lights=(Light((0.0, -1.0, 1.0), 0.7),))
    assert cli_main([*argv, "--ambient", "0.5"]) == 0
    assert got["scene"].ambient == 0.5 and got["scene"].lights == (Light((0.0, -1.0, 1.0), 0.7),)
    cfg.write_text("[render]\nnoise = 0.5\n")
    assert cli_main(argv) == 2
    assert capsys.readouterr().err.strip().endswith("r.toml [render]: unknown key(s) ['noise'] (known: ['albedo_bgr', "
                                                    "'flicker_amplitude', 'flicker_hz', 'gain_jitter', 'noise_sigma_levels', "
                                                    "'shadows', 'white_balance_jitter'])")
