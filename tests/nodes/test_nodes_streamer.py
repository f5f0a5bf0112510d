"""The VMC stream of a running cluster, received by a plain UDP socket and the tests' own OSC
reader: bundles delivered, and each one rebuilds the recorded pose in Unity axes."""

import numpy as np
import pytest
from osc_reader import JOINT, bones_of, receiver_fk, unity

from mocap_rt.names import JOINT_NAMES

pytestmark = pytest.mark.slow


def test_vmc_stream_of_a_replay(replay_run):
    """The session's shared run (conftest.replay_run) streams to a loopback UDP sink."""
    assert replay_run.returncode == 0, replay_run.stderr[-3000:]
    stats, sink = replay_run.stats, replay_run.sink
    poses = np.load(replay_run.rec / "poses.npz")
    # the poses fusion published: the launcher's monitor and the recorder count the same ones
    # (their frame windows keep a pose that a busy host delays); one per triggered frame at most
    assert len(poses["frames"]) == stats["poses_published"], stats
    n_poses = stats["poses_published"]
    bundles = [bones_of(data) for _, data in sink.packets]
    print(f"VMC: {len(bundles)} bundles for {stats['poses_published']} poses seen by the monitor, "
          f"{len(poses['frames'])} recorded; streamer status {stats.get('stream')}")
    assert n_poses > 0 and 0.98 * n_poses <= len(bundles) <= n_poses
    assert stats["nodes"]["streamer"]["drops"] == 0 and stats["nodes"]["streamer"]["decode_drops"] == 0

    # every bundle is one recorded pose, in order: root = its pelvis, and a receiver's forward
    # kinematics of the bone-local rotations puts every joint where the service had it
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
