"""The whole process cluster on a studio replay: CLI run, recording, Rerun file, live source."""

import json
import subprocess
import sys

import numpy as np
import pytest
from service_helpers import small_recording

from mocap_rt.body.bvh_export import bvh_skeleton_of
from mocap_rt.body.skeleton import BoneLengths, read_bone_lengths
from mocap_rt.io.bvh import read_bvh
from mocap_rt.io.recording import Recording

pytestmark = pytest.mark.slow

MAX_MEDIAN_CUE_ERROR_M = 0.10      # triangulated cues of the service vs the studio's truth
CALIBRATION_POSES = 60             # fusion estimates the subject's bones from 2 s of poses (30 fps)


@pytest.fixture(scope="module")
def walk(tmp_path_factory, data_dir):
    return small_recording(tmp_path_factory.getbasetemp(), data_dir)


def _rrd_entities(path) -> str:
    exe = str(__import__("pathlib").Path(sys.executable).with_name("rerun"))
    out = subprocess.run([exe, "rrd", "verify", str(path)], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    out = subprocess.run([exe, "rrd", "print", str(path)], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    return out.stdout


def test_cli_run_replay_records_poses_and_rerun_file(replay_run):
    """``mocap-rt run --source replay:WALK --record --rerun save: --stats`` (the session's shared
    run, conftest.replay_run: at half speed, from an empty kernel cache)."""
    walk, rec, rrd = replay_run.walk, replay_run.rec, replay_run.rrd
    assert replay_run.returncode == 0, replay_run.stderr[-3000:]
    stats = replay_run.stats
    n = Recording(walk).n_frames
    print("stats:", json.dumps({k: stats[k] for k in ("frames_triggered", "poses_published",
                                                    "frames_dropped", "latency_ms")}))
    for key in ("frames_triggered", "poses_published", "frames_dropped", "latency_ms", "cameras", "cpu_s"):
        assert key in stats
    assert set(stats["latency_ms"]) >= {"p50", "p95", "p99"}
    assert stats["cameras"] == [f"cam_{i}" for i in range(1, 7)]
    assert {"sync", "fusion", "recorder", "viewer"} | {f"worker-cam_{i}" for i in range(1, 7)} <= set(stats["cpu_s"])
    assert all(v > 0 for v in stats["cpu_s"].values())
    # one pass of the replay: every slot triggered or counted as skipped, every trigger posed
    sync_drops = stats["nodes"]["sync"]["drops"]
    assert stats["frames_triggered"] + sync_drops == n
    assert stats["poses_published"] == stats["frames_triggered"] - stats["frames_dropped"]
    assert stats["decode_drops"] == 0

    # recorder: BVH and NPZ agree with each other and with the truth of the studio
    clip = read_bvh(rec / "poses.bvh")
    poses = np.load(rec / "poses.npz")
    assert clip.motion.shape[0] == len(poses["frames"])
    # nearly every frame gives a pose (an idle machine: all 75); a frame is lost only when all six
    # workers skipped its trigger. Enough poses to estimate the bones below, whatever the load.
    # The launcher's monitor and the recorder count the same poses (their frame windows keep a
    # pose that a busy host delays: nodes/frame_window.RECORD_BEHIND / RECORD_AHEAD).
    assert len(poses["frames"]) == stats["poses_published"], stats
    assert stats["poses_published"] >= max(CALIBRATION_POSES, 0.8 * n), stats
    assert set(poses["frames"].tolist()) <= set(range(n))          # one pose per replayed frame
    np.testing.assert_allclose(clip.motion, poses["bvh_motion"], atol=1e-4)
    # fusion estimated the subject's bones after 2 s of this 2.5-s clip: the BVH hierarchy is
    # that subject's (not the default adult), and bones.toml holds the lengths for later runs
    bones = read_bone_lengths(rec / "bones.toml")
    assert bones != BoneLengths()
    np.testing.assert_allclose(clip.skeleton.offsets, bvh_skeleton_of(bones).offsets, atol=1e-5)
    truth = np.load(walk / "truth.npz")
    f = poses["frames"]
    assert np.isfinite(poses["joints"]).all(axis=(1, 2)).mean() > 0.8
    # the cues that went through the service (2D over Zenoh, triangulated by fusion) are the
    # studio's: head, hands and torso within a few centimetres of the truth (the feet and the
    # IK are the perception's and body's business, measured in their own benches)
    err = np.linalg.norm(poses["cues_3d"] - truth["cues"][f], axis=2)          # (F, 6) metres
    for c in ("head", "hand_l", "hand_r", "torso"):
        i = list(truth["cue_names"]).index(c)
        assert np.nanmedian(err[:, i]) < MAX_MEDIAN_CUE_ERROR_M, (c, np.nanmedian(err[:, i]))

    # viewer: the .rrd holds the skeleton, cues, camera frusta, images with ellipses, latency
    text = _rrd_entities(rrd)
    for entity in ("world/skeleton", "world/cues", "world/cameras/cam_1", "world/cameras/cam_6/image",
                   "world/cameras/cam_3/image/cues/ellipses", "plots/latency_ms"):
        assert entity in text, entity


def test_cli_rejects_bad_input(tmp_path):
    exe = str(__import__("pathlib").Path(sys.executable).with_name("mocap-rt"))
    for argv, needle in ((["--source", f"replay:{tmp_path}"], "rig"),
                         (["--source", "usb:0"], "expected replay"),
                         (["--source", "v4l2:/dev/video0"], "--rig is required")):
        p = subprocess.run([exe, "run", *argv], capture_output=True, text=True, timeout=60)
        assert p.returncode == 2 and needle in p.stderr, p.stderr


def test_live_fake_camera_source_is_recorded_as_a_replayable_stream(walk, tmp_path):
    """fake:REC plays the recording as live cameras in real time through the V4L2 grabber code;
    the recorder stores the raw multi-view stream, which opens as a recording."""
    from nodes.launcher import Launcher, RunConfig

    rec = tmp_path / "rec"
    cfg = RunConfig(rig_path=walk / "rig.toml", source=f"fake:{walk}", duration_s=2.0, record=rec,
                    status_line=False, log_dir=tmp_path / "logs")
    stats = Launcher(cfg).run()
    assert stats["poses_published"] > 0.5 * stats["frames_triggered"] > 0
    stream = Recording(rec / "stream")
    assert stream.camera_names == [f"cam_{i}" for i in range(1, 7)]
    assert stream.n_frames >= 0.5 * stats["frames_triggered"]
    assert stream.backgrounds("cam_2").shape[1:] == (240, 320, 3)
    src = Recording(walk)
    # every recorded image is one of the source's images (MJPG twice: small differences)
    img = stream.read_frame("cam_4", stream.n_frames // 2).astype(np.float32)
    diffs = [np.abs(img - src.read_frame("cam_4", k).astype(np.float32)).mean() for k in range(src.n_frames)]
    assert min(diffs) < 3.0
    assert np.isfinite(stream.timestamps).any()


def test_launcher_plan_links_each_pair_once_on_loopback(walk, tmp_path):
    """No processes: the plan's ports, endpoints and start-up arguments."""
    from nodes.launcher import Launcher, RunConfig, _ephemeral_range

    L = Launcher(RunConfig(rig_path=walk / "rig.toml", source=f"replay:{walk}", record=tmp_path / "r",
                           rerun=f"save:{tmp_path / 'x.rrd'}", log_dir=tmp_path / "logs"))
    names = list(L.nodes)
    assert names[:3] == ["recorder", "viewer", "fusion"] and names[-1] == "sync"
    assert [n for n in names if n.startswith("worker-")] == [f"worker-cam_{i}" for i in range(1, 7)]
    lo, hi = _ephemeral_range()
    ports = [n.port for n in L.nodes.values()] + [L.monitor_port]
    assert len(set(ports)) == len(ports) and not any(lo <= p <= hi for p in ports)

    def flag(argv, name):
        return [argv[i + 1] for i, a in enumerate(argv) if a == name]
    links = set()
    for i, (name, node) in enumerate(L.nodes.items()):
        listen, connect = flag(node.argv, "--listen"), flag(node.argv, "--connect")
        assert listen == [f"tcp/127.0.0.1:{node.port}"]
        assert all(e.startswith("tcp/127.0.0.1:") for e in connect)
        # every node reaches the launcher's monitor and each node started before it
        assert f"tcp/127.0.0.1:{L.monitor_port}" in connect
        earlier = {f"tcp/127.0.0.1:{L.nodes[n].port}" for n in names[:i]}
        assert set(connect) - {f"tcp/127.0.0.1:{L.monitor_port}"} == earlier
        links |= {frozenset((name, n)) for n in names[:i]}
    assert len(links) == len(names) * (len(names) - 1) // 2          # a full mesh, each link once
    sync = L.nodes["sync"].argv
    assert flag(sync, "--expect-peers") == [str(len(names))]          # the other nodes + monitor
    assert flag(sync, "--frames") == [str(Recording(walk).n_frames)]  # one pass of the replay
