"""The recorder's C3D/TRC exports: what was recorded is in them, written atomically."""

import numpy as np
from service_helpers import wait_for

from mocap_rt.body.bvh_export import bvh_skeleton_of
from mocap_rt.body.skeleton import BoneLengths
from mocap_rt.markers.io import read_c3d, read_trc
from nodes.messages import Pose
from nodes.recorder import PoseFiles, output_paths


def _pose(frame: int, rng) -> Pose:
    n_ch = bvh_skeleton_of(BoneLengths()).n_channels
    return Pose("r", frame, 0, 1, np.zeros((6, 3)), np.ones(6, bool), rng.uniform(-1, 2, (20, 3)),
                np.zeros(n_ch), ("a",), (), BoneLengths().as_array())


def test_pose_files_write_c3d_and_trc_matching_the_npz(tmp_path):
    rng = np.random.default_rng(1)
    npz, bvh, bones, _ = output_paths(tmp_path)
    files = PoseFiles(npz, bvh, bones, ["a"], 30.0)
    frames = [f for f in range(25) if f not in (10, 11)]          # two frames without a pose
    for f in frames[:15]:
        files.add(_pose(f, rng))
    files.snapshot(now=100.0)                                      # first rewrite: due at once
    assert read_c3d(tmp_path / "poses.c3d").n_frames == 17        # frames 0..16, 10 and 11 empty
    for f in frames[15:]:
        files.add(_pose(f, rng))
    files.snapshot(now=100.1)                                      # not due yet: NPZ only
    assert read_trc(tmp_path / "poses.trc").n_frames == 17
    files.close()                                                  # close writes everything
    with np.load(npz) as z:
        joints, rec_frames = z["joints"], z["frames"]
    np.testing.assert_array_equal(rec_frames, frames)
    c3d, trc = read_c3d(tmp_path / "poses.c3d"), read_trc(tmp_path / "poses.trc")
    assert c3d.n_frames == trc.n_frames == 25
    rows = np.asarray(frames)
    np.testing.assert_allclose(c3d.positions[rows], joints, atol=1e-6)
    np.testing.assert_allclose(trc.positions[rows][..., [0, 2, 1]] * [1, -1, 1], joints, atol=1e-8)
    assert np.isnan(c3d.positions[[10, 11]]).all() and np.isnan(trc.positions[[10, 11]]).all()
    # a second recording in the same directory never touches these files
    assert output_paths(tmp_path)[0].name == "poses_001.npz"
    assert not list(tmp_path.glob("*.tmp*"))


N_SENT = 60                  # poses sent to the recorder (2 s at 30 fps: two export periods)


def _exports_hold(out, last_frame: int) -> bool:
    """The C3D and TRC on disk now have a row for every frame up to ``last_frame`` (row = frame
    - first recorded frame); False while a file is missing (they are replaced atomically)."""
    try:
        with np.load(out / "poses.npz") as z:
            f0 = int(z["frames"][0])
        return min(read_c3d(out / "poses.c3d").n_frames, read_trc(out / "poses.trc").n_frames) >= last_frame + 1 - f0
    except (OSError, ValueError, IndexError):
        return False


def test_recorder_killed_leaves_readable_c3d_and_trc(tmp_path):
    """A recorder node process fed triggers and poses over Zenoh (loopback): poses.c3d and
    poses.trc are rewritten while it runs (not only at its end) until they hold every pose sent;
    then ``kill -9``: they open, hold those poses, equal to the NPZ; nothing half-written is left
    under the final names. (How recent they are, ~1 s, is timing: printed, not asserted.)"""
    import os
    import signal
    import subprocess
    import sys
    import time

    import zenoh

    from mocap_rt.geometry.rig import write_rig
    from mocap_rt.studio.synth import make_rig
    from nodes.launcher import free_port
    from nodes.messages import Keys, Status, Trigger
    from nodes.transport import make_config

    write_rig(make_rig(n_cameras=2, size=(320, 240)), tmp_path / "rig.toml")
    port, keys = free_port(), Keys("rig")
    proc = subprocess.Popen([sys.executable, "-m", "nodes.recorder", "--rig", str(tmp_path / "rig.toml"),
                             "--rig-name", "rig", "--out", str(tmp_path / "out"), "--fps", "30",
                             "--listen", f"tcp/127.0.0.1:{port}"],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    session = zenoh.open(make_config(["tcp/127.0.0.1:0"], [f"tcp/127.0.0.1:{port}"]))
    states = []
    sub = session.declare_subscriber(keys.status("*"),
                                     lambda s: states.append(Status.from_msgpack(bytes(s.payload)).state))
    rng = np.random.default_rng(5)
    sent = {}
    try:
        assert wait_for(lambda: "running" in states, 120), "recorder did not start"
        period = round(1e9 / 30)
        t0 = time.monotonic_ns()
        for f in range(N_SENT):
            t = t0 + f * period
            time.sleep(max(0.0, (t - time.monotonic_ns()) / 1e9))
            session.put(keys.trigger, Trigger("rig", f, t, time.time_ns(), period).to_msgpack())
            pose = _pose(f, rng)
            pose = Pose("rig", f, t, time.monotonic_ns(), pose.cues_3d, pose.cue_valid, pose.joints,
                        pose.bvh_frame, pose.cameras_used, (), pose.bones)
            session.put(keys.pose, pose.to_msgpack())
            sent[f] = (time.monotonic(), pose.joints)
        t_sent = time.monotonic()
        out = tmp_path / "out"
        assert wait_for(lambda: _exports_hold(out, N_SENT - 1), 60), "the exports never held every pose sent"
        t_kill = time.monotonic()
        print(f"exports complete {t_kill - t_sent:.2f} s after the last pose was sent")
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait()
    finally:
        sub.undeclare()
        session.close()
        if proc.poll() is None:
            proc.kill()
    c3d, trc = read_c3d(out / "poses.c3d"), read_trc(out / "poses.trc")
    with np.load(out / "poses.npz") as z:
        frames, joints = z["frames"], z["joints"]
    assert not list(out.glob("*.tmp*"))
    assert min(c3d.n_frames, trc.n_frames) == N_SENT - frames[0] and frames[-1] == N_SENT - 1
    rows = frames - frames[0]                                          # row = frame - first frame
    held = rows < min(c3d.n_frames, trc.n_frames)
    np.testing.assert_allclose(c3d.positions[rows[held]], joints[held], atol=1e-6)
    np.testing.assert_allclose(trc.positions[rows[held]][..., 1], joints[held][..., 2], atol=1e-8)
    np.testing.assert_allclose(joints[held], [sent[f][1] for f in frames[held]])
