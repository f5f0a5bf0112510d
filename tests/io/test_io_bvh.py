"""BVH reader/FK/writer against the `bvh` PyPI parser, hand-built rotations and round trips."""

import textwrap
from pathlib import Path

import bvh as bvh_pkg
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mocap_rt.io.bvh import BvhError, forward_kinematics, read_bvh
from mocap_rt.io.bvh_writer import BvhStreamWriter, write_bvh


def _clips(data_dir: Path) -> list[Path]:
    clips = sorted((data_dir / "bvh").glob("*/*.bvh"))
    assert len(clips) >= 13
    return clips


def _elementary(axis: str, deg: np.ndarray) -> np.ndarray:
    a = np.radians(deg)
    c, s = np.cos(a), np.sin(a)
    if axis == "X":
        return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])
    if axis == "Y":
        return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


def _reference_fk(mocap: "bvh_pkg.Bvh", frame: int) -> dict[str, np.ndarray]:
    """FK written independently on top of the `bvh` package's parse (one frame)."""
    out_R, out_p = {}, {}
    for name in mocap.get_joints_names():
        chans = mocap.joint_channels(name)
        vals = mocap.frame_joint_channels(frame, name, chans)
        t = np.array(mocap.joint_offset(name), dtype=float)
        R = np.eye(3)
        for ch, v in zip(chans, vals):
            if ch.endswith("position"):
                t["XYZ".index(ch[0])] = float(v)
            else:
                R = R @ _elementary(ch[0], float(v))
        idx = mocap.joint_parent_index(name)
        if idx < 0:
            out_R[name], out_p[name] = R, t
        else:
            pname = mocap.get_joints_names()[idx]
            out_R[name] = out_R[pname] @ R
            out_p[name] = out_p[pname] + out_R[pname] @ t
    return out_p


def test_every_shared_clip_parses_with_constant_bone_lengths(data_dir):
    for path in _clips(data_dir):
        clip = read_bvh(path)
        assert clip.n_frames > 10 and 0 < clip.frame_time_s < 0.05, path
        pos = forward_kinematics(clip.skeleton, clip.motion, include_end_sites=True)
        assert np.isfinite(pos).all()
        sk = clip.skeleton
        starts = sk.channel_starts
        for j, joint in enumerate(sk.joints):
            if joint.parent < 0:
                continue
            pcols = [starts[j] + k for k, c in enumerate(joint.channels) if c.endswith("position")]
            if pcols and np.ptp(clip.motion[:, pcols], axis=0).max() > 1e-6:
                continue  # a translating joint (Bandai's Hips under joint_Root) is not a bone
            length = np.linalg.norm(pos[:, j] - pos[:, joint.parent], axis=1)
            assert np.ptp(length) < 1e-9 * max(1.0, length.max()), (path.name, joint.name)
        # the bodies are real: root path not constant, head above the feet (Y up files)
        assert np.ptp(pos[:, 0], axis=0).max() > 0 or np.ptp(pos[:, 1], axis=0).max() > 0


def test_matches_bvh_package_parse_and_independent_fk(data_dir):
    # every skeleton family; the two 2 MB clips are left out only because `bvh` is slow
    clips = [p for p in _clips(data_dir) if p.stat().st_size < 1_000_000]
    assert len(clips) >= 11
    for path in clips:
        text = path.read_text()
        ref = bvh_pkg.Bvh(text)
        clip = read_bvh(path)
        assert clip.skeleton.names == ref.get_joints_names()
        assert clip.n_frames == ref.nframes
        assert clip.frame_time_s == pytest.approx(ref.frame_time)
        for name in clip.skeleton.names[:: max(1, len(clip.skeleton) // 12)]:
            j = clip.skeleton.index(name)
            assert list(clip.skeleton.joints[j].channels) == ref.joint_channels(name)
            np.testing.assert_allclose(clip.skeleton.joints[j].offset, ref.joint_offset(name))
        pos = forward_kinematics(clip.skeleton, clip.motion)
        for f in (0, clip.n_frames // 2, clip.n_frames - 1):
            expect = _reference_fk(ref, f)
            got = np.array([pos[f, clip.skeleton.index(n)] for n in expect])
            np.testing.assert_allclose(got, np.array(list(expect.values())), atol=1e-6)


def test_write_read_round_trip(tmp_path, data_dir):
    clip = read_bvh(data_dir / "bvh" / "cmu" / "cmu_131_01_start_walk_stop.bvh")
    out = tmp_path / "rt.bvh"
    write_bvh(out, clip.skeleton, clip.motion[:50], clip.frame_time_s)
    back = read_bvh(out)
    assert back.skeleton.names == clip.skeleton.names
    assert [j.channels for j in back.skeleton.joints] == [j.channels for j in clip.skeleton.joints]
    np.testing.assert_allclose(back.motion, clip.motion[:50], rtol=1e-8, atol=1e-9)
    np.testing.assert_allclose(forward_kinematics(back.skeleton, back.motion, True),
                               forward_kinematics(clip.skeleton, clip.motion[:50], True), atol=1e-7)
    assert bvh_pkg.Bvh(out.read_text()).nframes == 50


@pytest.mark.parametrize("mutate, words", [
    (lambda t: t.replace("CHANNELS 3", "CHANNELS x", 1), ["line", "integer"]),
    (lambda t: t.replace("Zrotation", "Qrotation", 1), ["line", "Qrotation"]),
    (lambda t: t[: len(t) // 2], ["truncated"]),
    (lambda t: t.replace("MOTION", "MOTON"), ["MOTON"]),
])
def test_bad_files_raise_clear_errors(tmp_path, data_dir, mutate, words):
    text = (data_dir / "bvh" / "cmu" / "cmu_02_01_walk.bvh").read_text()
    bad = tmp_path / "bad.bvh"
    bad.write_text(mutate(text))
    with pytest.raises(BvhError) as err:
        read_bvh(bad)
    assert "bad.bvh" in str(err.value)
    for w in words:
        assert w in str(err.value)


def test_stream_writer_survives_sigkill(tmp_path, data_dir, kill_when_ready):
    src = data_dir / "bvh" / "cmu" / "cmu_02_01_walk.bvh"
    out = tmp_path / "live.bvh"
    script = textwrap.dedent(f"""
        import sys, time
        from mocap_rt.io.bvh import read_bvh
        from mocap_rt.io.bvh_writer import BvhStreamWriter
        clip = read_bvh({str(src)!r})
        w = BvhStreamWriter({str(out)!r}, clip.skeleton, 0.01)  # flushes every 100 frames
        for i in range(10**9):
            w.write(clip.motion[i % clip.n_frames])
            if i == 250:
                print("ready", flush=True)
            if i > 250:
                time.sleep(0.0005)
    """)
    kill_when_ready(script)
    back = read_bvh(out)
    assert back.n_frames >= 200 and back.n_frames % 100 == 0
    clip = read_bvh(src)
    idx = np.arange(back.n_frames) % clip.n_frames
    np.testing.assert_allclose(back.motion, clip.motion[idx], rtol=1e-8, atol=1e-9)


def test_stream_writer_close_writes_everything(tmp_path, data_dir):
    clip = read_bvh(data_dir / "bvh" / "cmu" / "cmu_02_01_walk.bvh")
    with BvhStreamWriter(tmp_path / "s.bvh", clip.skeleton, clip.frame_time_s) as w:
        for row in clip.motion[:37]:
            w.write(row)
    back = read_bvh(tmp_path / "s.bvh")
    np.testing.assert_allclose(back.motion, clip.motion[:37], rtol=1e-8, atol=1e-9)


def test_stream_writer_new_skeleton_keeps_every_frame(tmp_path, data_dir):
    from dataclasses import replace

    from mocap_rt.io.bvh import BvhSkeleton

    clip = read_bvh(data_dir / "bvh" / "cmu" / "cmu_02_01_walk.bvh")
    bigger = BvhSkeleton(tuple(replace(j, offset=1.2 * np.asarray(j.offset)) for j in clip.skeleton.joints))
    path = tmp_path / "s.bvh"
    w = BvhStreamWriter(path, clip.skeleton, clip.frame_time_s, flush_interval_s=10 * clip.frame_time_s)
    for row in clip.motion[:37]:
        w.write(row)
    w.set_skeleton(bigger)                     # 37 frames so far, 7 of them not yet flushed
    mid = read_bvh(path)                       # the file parses while the writer is open
    np.testing.assert_allclose(mid.skeleton.offsets, bigger.offsets, rtol=1e-6)
    np.testing.assert_allclose(mid.motion, clip.motion[:37], rtol=1e-8, atol=1e-9)
    for row in clip.motion[37:60]:
        w.write(row)
    with pytest.raises(ValueError, match="channels"):
        w.set_skeleton(BvhSkeleton(clip.skeleton.joints[:1]))
    w.close()
    back = read_bvh(path)
    np.testing.assert_allclose(back.skeleton.offsets, bigger.offsets, rtol=1e-6)
    np.testing.assert_allclose(back.motion, clip.motion[:60], rtol=1e-8, atol=1e-9)
    assert not path.with_name("s.bvh.tmp").exists()


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 10_000), n_joints=st.integers(1, 8))
def test_random_skeletons_any_rotation_order(tmp_path_factory, seed, n_joints):
    """Random hierarchies, channel orders and angles: write -> read -> FK == hand-built FK."""
    from mocap_rt.io.bvh import BvhJoint, BvhSkeleton

    rng = np.random.default_rng(seed)
    joints = []
    for j in range(n_joints):
        rot = list(rng.permutation(["Xrotation", "Yrotation", "Zrotation"]))
        pos = list(rng.permutation(["Xposition", "Yposition", "Zposition"])) if (j == 0 or rng.random() < 0.2) else []
        chans = tuple(pos + rot) if rng.random() < 0.5 else tuple(rot + pos)
        end = rng.normal(size=3) if rng.random() < 0.4 else None
        joints.append(BvhJoint(f"j{j}", -1 if j == 0 else int(rng.integers(0, j)), rng.normal(size=3), chans, end))
    sk = BvhSkeleton(tuple(joints))
    motion = rng.uniform(-180, 180, (4, sk.n_channels))
    path = tmp_path_factory.mktemp("rnd") / "r.bvh"
    write_bvh(path, sk, motion, 1 / 60)
    back = read_bvh(path)
    pos = forward_kinematics(back.skeleton, back.motion)
    starts = back.skeleton.channel_starts
    for f in range(4):
        R, p = {}, {}
        for j, jt in enumerate(back.skeleton.joints):
            t, Rl = jt.offset.copy(), np.eye(3)
            for k, ch in enumerate(jt.channels):
                val = back.motion[f, starts[j] + k]
                if ch.endswith("position"):
                    t["XYZ".index(ch[0])] = val
                else:
                    Rl = Rl @ _elementary(ch[0], val)
            R[j], p[j] = (Rl, t) if jt.parent < 0 else (R[jt.parent] @ Rl, p[jt.parent] + R[jt.parent] @ t)
            np.testing.assert_allclose(pos[f, j], p[j], atol=1e-9)
