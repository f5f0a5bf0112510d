"""The whole process cluster on a studio replay: CLI run, recording, Rerun file, live source."""

import subprocess
import sys

import numpy as np
import pytest
from service_helpers import small_recording

from mocap_rt.io.recording import Recording

pytestmark = pytest.mark.slow

MAX_MEDIAN_CUE_ERROR_M = 0.10      # triangulated cues of the service vs the studio's truth
CALIBRATION_POSES = 60             # fusion estimates the subject's bones from 2 s of poses (30 fps)


@pytest.fixture(scope="module")
def walk(tmp_path_factory, data_dir):
    return small_recording(tmp_path_factory.getbasetemp(), data_dir)


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
