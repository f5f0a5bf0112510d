"""Multi-host deploy rehearsal: sync, two camera workers and fusion in separate network namespaces.

Each node runs in its own namespace, joined by veth pairs to a bridge in a 'switch'
namespace; private addresses exist only inside these namespaces, which the test creates and
deletes. Zenoh shared memory stays off (the default of every node), so the traffic really
crosses the veth links, which the interface counters confirm.
"""

import json
import os
import subprocess
import sys
import uuid
from pathlib import Path

import pytest
from service_helpers import small_recording

from mocap_rt.geometry.rig import read_rig, write_rig

pytestmark = [pytest.mark.slow, pytest.mark.netns]

SUBNET = "10.231.{}.{}"          # RFC 1918, used only inside the test's namespaces
PORT = 7447
WINDOW_S = 4.0                   # the probe counts poses this long once every node is ready
READY_TIMEOUT_S = 120.0          # node start-up (imports, warm-up) on a loaded machine


def sh(*argv, check=True) -> str:
    p = subprocess.run(list(argv), capture_output=True, text=True, timeout=60)
    if check and p.returncode != 0:
        raise RuntimeError(f"{' '.join(argv)}: {p.stderr}")
    return p.stdout


def link_bytes(ns: str, dev: str) -> int:
    stats = json.loads(sh("ip", "-n", ns, "-s", "-j", "link", "show", "dev", dev))[0]["stats64"]
    return stats["rx"]["bytes"] + stats["tx"]["bytes"]


@pytest.mark.skipif(os.geteuid() != 0, reason="network namespaces need root")
def test_nodes_in_separate_network_namespaces(tmp_path, tmp_path_factory, data_dir):
    walk = small_recording(tmp_path_factory.getbasetemp(), data_dir)
    rig2 = tmp_path / "rig2.toml"
    write_rig(read_rig(walk / "rig.toml").subset(["cam_1", "cam_4"]), rig2)
    tag = uuid.uuid4().hex[:6]
    sw = f"mrt{tag}sw"
    roles = ["fusion", "cam1", "cam4", "sync", "probe"]
    ns = {r: f"mrt{tag}{r}" for r in roles}
    addr = {r: SUBNET.format(int(tag[:2], 16), i + 10) for i, r in enumerate(roles)}
    ep = {r: f"tcp/{addr[r]}:{PORT}" for r in roles}
    procs: list[subprocess.Popen] = []
    created: list[str] = []
    try:
        sh("ip", "netns", "add", sw)
        created.append(sw)
        sh("ip", "-n", sw, "link", "add", "br0", "type", "bridge")
        sh("ip", "-n", sw, "link", "set", "br0", "up")
        for i, r in enumerate(roles):
            sh("ip", "netns", "add", ns[r])
            created.append(ns[r])
            # create the pair inside the switch namespace, then move one end: nothing in ours
            sh("ip", "-n", sw, "link", "add", f"p{i}", "type", "veth", "peer", "name", "eth0", "netns", ns[r])
            sh("ip", "-n", sw, "link", "set", f"p{i}", "master", "br0", "up")
            sh("ip", "-n", ns[r], "addr", "add", f"{addr[r]}/24", "dev", "eth0")
            sh("ip", "-n", ns[r], "link", "set", "eth0", "up")
            sh("ip", "-n", ns[r], "link", "set", "lo", "up")
        assert "10.231." not in sh("ip", "-4", "addr")      # no address leaked into our namespace

        py = [sys.executable]
        common = ["--rig", str(rig2), "--rig-name", "netns"]
        env = dict(os.environ, PYTHONPATH=str(Path(__file__).parents[2]), PYTHONUNBUFFERED="1")

        def start(role, argv, connect):
            cmd = ["ip", "netns", "exec", ns[role], *py, *argv, "--listen", ep[role]]
            for c in connect:
                cmd += ["--connect", ep[c]]
            log = open(tmp_path / f"{role}.log", "w")
            procs.append(subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, env=env,
                                          cwd=str(tmp_path)))
            return procs[-1]

        start("fusion", ["-m", "nodes.fusion_node", *common, "--fps", "30"], [])
        for cam, role in (("cam_1", "cam1"), ("cam_4", "cam4")):
            start(role, ["-m", "nodes.camera_worker", *common, "--camera", cam, "--source", f"replay:{walk}",
                         "--node", f"worker-{cam}"], ["fusion"])
        probe = start("probe", [str(Path(__file__).with_name("netns_probe.py")), "netns", str(WINDOW_S),
                                "--wait-nodes", "fusion,worker-cam_1,worker-cam_4",
                                "--timeout", str(READY_TIMEOUT_S)],
                      ["fusion", "cam1", "cam4"])
        start("sync", ["-m", "nodes.sync", *common, "--fps", "30"], ["fusion", "cam1", "cam4", "probe"])
        before = link_bytes(ns["fusion"], "eth0")
        probe.wait(timeout=READY_TIMEOUT_S + WINDOW_S + 30)
        logs = {p.name: p.read_text()[-1500:] for p in tmp_path.glob("*.log")}
        summary = json.loads((tmp_path / "probe.log").read_text().strip().splitlines()[-1])
        crossed = link_bytes(ns["fusion"], "eth0") - before
        print(f"netns: ready after {summary['ready_after_s']} s, {summary['poses']} poses, cameras {summary['cameras_used']}, "
              f"{summary['all_cameras_frames']} with both cameras, {crossed} bytes through fusion's veth")
        assert summary["ready_after_s"] is not None, (summary, logs)
        assert summary["poses"] > 0.5 * 30 * WINDOW_S, (summary, logs)
        assert summary["cameras_used"] == ["cam_1", "cam_4"], logs
        assert summary["all_cameras_frames"] > 0.5 * summary["poses"]
        frames = summary["frames"]
        assert frames == sorted(frames) and len(set(frames)) == len(frames)
        assert summary["decode_drops"] == 0
        # cues in + poses/predictions out: many kB crossed the link (no shared memory shortcut)
        assert crossed > 100 * summary["poses"]
    finally:
        for p in procs:
            if p.poll() is None:
                p.terminate()
        for p in procs:
            try:
                p.wait(timeout=10)
            except subprocess.TimeoutExpired:
                p.kill()
        for n in reversed(created):
            sh("ip", "netns", "del", n, check=False)
        left = sh("ip", "netns", "list")
        assert not any(n in left for n in created), left
