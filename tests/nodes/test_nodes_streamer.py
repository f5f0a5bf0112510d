"""The VMC stream of a running cluster, received by a plain UDP socket and the tests' own OSC
reader: bundles delivered, and each one rebuilds the recorded pose in Unity axes."""

import socket
import threading
import time

import numpy as np
import pytest
from osc_reader import JOINT, bones_of, receiver_fk, unity
from service_helpers import small_recording

from mocap_rt.names import JOINT_NAMES
from nodes.launcher import Launcher, RunConfig

pytestmark = pytest.mark.slow


class UdpSink:
    """Every datagram arriving on a loopback port, with its arrival time."""

    def __init__(self) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        # room for the whole run's datagrams if this thread is not scheduled for a while
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 8 << 20)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.settimeout(0.1)
        self.port = self.sock.getsockname()[1]
        self.packets: list[tuple[float, bytes]] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                data = self.sock.recv(65536)
            except TimeoutError:
                continue
            self.packets.append((time.monotonic(), data))

    def drain(self, at_least: int, quiet_s: float = 0.5, timeout_s: float = 30.0) -> None:
        """Wait until ``at_least`` datagrams arrived and none for ``quiet_s``."""
        t_end = time.monotonic() + timeout_s
        n, t_n = -1, time.monotonic()
        while time.monotonic() < t_end:
            if len(self.packets) != n:
                n, t_n = len(self.packets), time.monotonic()
            elif n >= at_least and time.monotonic() - t_n >= quiet_s:
                return
            time.sleep(0.05)

    def close(self) -> None:
        self._stop.set()
        self._thread.join()
        self.sock.close()


def test_vmc_stream_of_a_replay(tmp_path, tmp_path_factory, data_dir):
    walk = small_recording(tmp_path_factory.getbasetemp(), data_dir)
    sink = UdpSink()
    try:
        L = Launcher(RunConfig(rig_path=walk / "rig.toml", source=f"replay:{walk}", record=tmp_path / "rec",
                               stream=f"vmc:127.0.0.1:{sink.port}", log_dir=tmp_path / "logs",
                               status_line=False))
        stats = L.run()
        # every bundle the streamer sent is on the socket already: wait until this thread has
        # read them all (its count reaches the streamer's and stays there)
        sink.drain(stats["stream"].get("sent", 0))
    finally:
        sink.close()
    n_poses = stats["poses_published"]
    bundles = [bones_of(data) for _, data in sink.packets]
    print(f"VMC: {len(bundles)} bundles for {n_poses} poses; streamer status {stats.get('stream')}")
    assert n_poses > 0 and 0.98 * n_poses <= len(bundles) <= n_poses
    assert stats["nodes"]["streamer"]["drops"] == 0 and stats["nodes"]["streamer"]["decode_drops"] == 0

    # every bundle is one recorded pose, in order: root = its pelvis, and a receiver's forward
    # kinematics of the bone-local rotations puts every joint where the service had it
    poses = np.load(tmp_path / "rec" / "poses.npz")
    pelvis_u = unity(poses["joints"][:, JOINT_NAMES.index("pelvis")])
    # on the one frame where fusion calibrates the subject's lengths, ``Pose.joints`` are still
    # solved with the old lengths while ``bvh_frame`` and ``bones`` (what the stream converts)
    # are the new skeleton's (``BodyTracker.step``): that frame's joints are not compared
    trunk = np.linalg.norm(poses["joints"][:, JOINT_NAMES.index("neck")]
                           - poses["joints"][:, JOINT_NAMES.index("pelvis")], axis=1)
    switch = set(np.flatnonzero(np.abs(np.diff(trunk)) > 1e-6).tolist())
    assert len(switch) <= 1
    k = -1
    for bones, root, other in bundles:
        assert root[0] == "root" and other["/VMC/Ext/OK"][0] == 1
        # the next recorded pose (in order) with this pelvis: UDP on loopback keeps the order
        near = np.flatnonzero(np.linalg.norm(pelvis_u[k + 1:] - np.array(root[1:4]), axis=1) < 1e-5)
        assert near.size, f"bundle root {root[1:4]} is none of the recorded poses after {k}"
        k = k + 1 + int(near[0])
        for name, (_, q) in bones.items():
            assert abs(np.linalg.norm(q) - 1) < 1e-5, name
        world = receiver_fk(bones, root)
        for name, joint in JOINT.items() if k not in switch else ():
            np.testing.assert_allclose(world[name][0], unity(poses["joints"][k, JOINT_NAMES.index(joint)]),
                                       atol=1e-4, err_msg=f"{name}, pose {k}")
    assert [b[2]["/VMC/Ext/T"][0] for b in bundles] == sorted(b[2]["/VMC/Ext/T"][0] for b in bundles)
