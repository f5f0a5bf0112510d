"""Multi-host deploy rehearsal: sync, two camera workers and fusion in separate network namespaces.

Each node runs in its own namespace, joined by veth pairs to a bridge in a 'switch'
namespace; private addresses exist only inside these namespaces, which the test creates and
deletes. Zenoh shared memory stays off (the default of every node), so the traffic really
crosses the veth links, which the interface counters confirm.

The second test runs the deploy/zenoh configs themselves (mutual TLS, access control by
certificate common name) with a throwaway CA made here by the openssl CLI: a peer whose
certificate is not from the rig's CA, or that has none, cannot connect; the camera host of
cam_1 can put only cam_1's keys and receives only cam_1's predictions.
"""

import contextlib
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
FPS = 10                         # trigger rate: these nodes run without real-time priority, and a
                                 # 100-ms period leaves a loaded or 3x slower machine time for every
                                 # frame (what is tested is the links, not the rate)
READY_TIMEOUT_S = 120.0          # node start-up (imports, warm-up) on a loaded machine


def sh(*argv, check=True) -> str:
    p = subprocess.run(list(argv), capture_output=True, text=True, timeout=60)
    if check and p.returncode != 0:
        raise RuntimeError(f"{' '.join(argv)}: {p.stderr}")
    return p.stdout


def link_bytes(ns: str, dev: str) -> int:
    stats = json.loads(sh("ip", "-n", ns, "-s", "-j", "link", "show", "dev", dev))[0]["stats64"]
    return stats["rx"]["bytes"] + stats["tx"]["bytes"]


@contextlib.contextmanager
def namespaces(roles: list[str]):
    """One namespace per role, each with ``eth0`` on a bridge in a 'switch' namespace; yields
    (namespace names, addresses, processes to stop); everything is deleted on the way out."""
    tag = uuid.uuid4().hex[:6]
    sw = f"mrt{tag}sw"
    ns = {r: f"mrt{tag}{r}" for r in roles}
    addr = {r: SUBNET.format(int(tag[:2], 16), i + 10) for i, r in enumerate(roles)}
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
        yield ns, addr, procs
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


def _env() -> dict:
    return dict(os.environ, PYTHONPATH=str(Path(__file__).parents[2]), PYTHONUNBUFFERED="1")


@pytest.mark.skipif(os.geteuid() != 0, reason="network namespaces need root")
def test_nodes_in_separate_network_namespaces(tmp_path, tmp_path_factory, data_dir):
    walk = small_recording(tmp_path_factory.getbasetemp(), data_dir)
    rig2 = tmp_path / "rig2.toml"
    write_rig(read_rig(walk / "rig.toml").subset(["cam_1", "cam_4"]), rig2)
    roles = ["fusion", "cam1", "cam4", "sync", "probe"]
    with namespaces(roles) as (ns, addr, procs):
        ep = {r: f"tcp/{addr[r]}:{PORT}" for r in roles}
        py = [sys.executable]
        common = ["--rig", str(rig2), "--rig-name", "netns"]
        env = _env()

        def start(role, argv, connect):
            cmd = ["ip", "netns", "exec", ns[role], *py, *argv, "--listen", ep[role]]
            for c in connect:
                cmd += ["--connect", ep[c]]
            log = open(tmp_path / f"{role}.log", "w")
            procs.append(subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, env=env,
                                          cwd=str(tmp_path)))
            return procs[-1]

        start("fusion", ["-m", "nodes.fusion_node", *common, "--fps", str(FPS)], [])
        for cam, role in (("cam_1", "cam1"), ("cam_4", "cam4")):
            start(role, ["-m", "nodes.camera_worker", *common, "--camera", cam, "--source", f"replay:{walk}",
                         "--node", f"worker-{cam}"], ["fusion"])
        probe = start("probe", [str(Path(__file__).with_name("netns_probe.py")), "netns", str(WINDOW_S),
                                "--wait-nodes", "fusion,worker-cam_1,worker-cam_4",
                                "--timeout", str(READY_TIMEOUT_S)],
                      ["fusion", "cam1", "cam4"])
        start("sync", ["-m", "nodes.sync", *common, "--fps", str(FPS)], ["fusion", "cam1", "cam4", "probe"])
        before = link_bytes(ns["fusion"], "eth0")
        probe.wait(timeout=READY_TIMEOUT_S + WINDOW_S + 30)
        logs = {p.name: p.read_text()[-1500:] for p in tmp_path.glob("*.log")}
        summary = json.loads((tmp_path / "probe.log").read_text().strip().splitlines()[-1])
        crossed = link_bytes(ns["fusion"], "eth0") - before
        print(f"netns: ready after {summary['ready_after_s']} s, {summary['poses']} poses, cameras {summary['cameras_used']}, "
              f"{summary['all_cameras_frames']} with both cameras, {crossed} bytes through fusion's veth")
        assert summary["ready_after_s"] is not None, (summary, logs)
        assert summary["poses"] > 0.5 * FPS * WINDOW_S, (summary, logs)
        assert summary["cameras_used"] == ["cam_1", "cam_4"], logs
        assert summary["all_cameras_frames"] > 0.5 * summary["poses"]
        frames = summary["frames"]
        assert frames == sorted(frames) and len(set(frames)) == len(frames)
        assert summary["decode_drops"] == 0
        # cues in + poses/predictions out: many kB crossed the link (no shared memory shortcut)
        assert crossed > 100 * summary["poses"]


# ------------------------------------------------------------------ mutual TLS + access control
DEPLOY = Path(__file__).resolve().parents[2] / "deploy" / "zenoh"
DEPLOY_ADDR = {"sync": "10.10.0.10", "fusion": "10.10.0.20", "cam1": "10.10.0.31"}   # in the files


def make_pki(d: Path, leaves: dict[str, tuple[str, str]]) -> None:
    """A throwaway CA ``ca``, a second one ``rogueca``, and per leaf name (CA, IP) an EC key and a
    certificate with that CN and IP/DNS subject alternative names (openssl CLI)."""
    def run(*argv):
        sh("openssl", *argv)
    for ca in ("ca", "rogueca"):
        run("req", "-x509", "-newkey", "ec", "-pkeyopt", "ec_paramgen_curve:prime256v1", "-nodes",
            "-keyout", str(d / f"{ca}.key"), "-out", str(d / f"{ca}.pem"), "-days", "2", "-subj", f"/CN={ca}",
            "-addext", "basicConstraints=critical,CA:TRUE", "-addext", "keyUsage=critical,keyCertSign,cRLSign")
    for name, (ca, ip) in leaves.items():
        run("req", "-newkey", "ec", "-pkeyopt", "ec_paramgen_curve:prime256v1", "-nodes",
            "-keyout", str(d / f"{name}.key"), "-out", str(d / f"{name}.csr"), "-subj", f"/CN={name.split('@')[0]}")
        (d / f"{name}.ext").write_text("basicConstraints=CA:FALSE\nkeyUsage=critical,digitalSignature\n"
                                       f"extendedKeyUsage=serverAuth,clientAuth\nsubjectAltName=IP:{ip}\n")
        run("x509", "-req", "-in", str(d / f"{name}.csr"), "-CA", str(d / f"{ca}.pem"), "-CAkey", str(d / f"{ca}.key"),
            "-CAcreateserial", "-out", str(d / f"{name}.pem"), "-days", "2", "-extfile", str(d / f"{name}.ext"))


def render(deploy_file: str, tls: Path, addr: dict[str, str], out: Path, replace: dict[str, str] = ()) -> Path:
    """A deploy config with the test's certificate folder and namespace addresses."""
    text = (DEPLOY / deploy_file).read_text().replace("/etc/mocap-rt/tls/", f"{tls}/")
    for role, a in DEPLOY_ADDR.items():
        text = text.replace(a, addr[role])
    for old, new in dict(replace).items():
        assert old in text, old
        text = text.replace(old, new)
    out.write_text(text)
    return out


@pytest.mark.skipif(os.geteuid() != 0, reason="network namespaces need root")
def test_deploy_tls_and_access_control_in_network_namespaces(tmp_path):
    roles = ["fusion", "cam1", "rogue", "nocert", "sync"]       # nothing runs at the sync address
    with namespaces(roles) as (ns, addr, procs):
        tls = tmp_path / "tls"
        tls.mkdir()
        make_pki(tls, {"fusion-host": ("ca", addr["fusion"]), "camera-cam_1": ("ca", addr["cam1"]),
                       # the attacker's certificate has the right name but is not from the rig's CA
                       "camera-cam_1@rogue": ("rogueca", addr["rogue"])})
        conf = {
            "fusion": render("fusion-host.json5", tls, addr, tmp_path / "fusion.json5"),
            # a camera host that ignores its own access control (a compromised host): the fusion
            # host's rules alone must keep it to cam_1's keys
            "cam1": render("camera-host.json5", tls, addr, tmp_path / "cam1.json5",
                           {"access_control: {\n    enabled: true": "access_control: {\n    enabled: false"}),
            "rogue": render("camera-host.json5", tls, addr, tmp_path / "rogue.json5",
                            {"camera-cam_1.pem": "camera-cam_1@rogue.pem", "camera-cam_1.key": "camera-cam_1@rogue.key",
                             addr["cam1"]: addr["rogue"]}),
            # TLS to the right server, but no client certificate of its own
            "nocert": render("camera-host.json5", tls, addr, tmp_path / "nocert.json5",
                             {f'listen: {{ endpoints: ["tls/{addr["cam1"]}:7447"] }}': "listen: { endpoints: [] }",
                              "enable_mtls: true": "enable_mtls: false"}),
        }
        text = conf["nocert"].read_text()
        conf["nocert"].write_text("\n".join(ln for ln in text.splitlines()
                                            if not ln.strip().startswith(("connect_certificate", "connect_private_key",
                                                                          "listen_certificate", "listen_private_key"))))
        puts = {"fusion": ["mocap/r/prediction/cam_1", "mocap/r/prediction/cam_2", "mocap/r/pose"],
                "cam1": ["mocap/r/cues/cam_1", "mocap/r/status/worker-cam_1", "mocap/r/cues/cam_2", "mocap/r/pose",
                         "mocap/r/trigger"],
                "rogue": ["mocap/r/cues/cam_1", "mocap/r/pose"], "nocert": ["mocap/r/cues/cam_1"]}
        # fusion and cam1 put for the same 6 s once linked (each may start later than the other
        # on a loaded machine: equal windows overlap most); no wall time added, fusion's 6 s bound it
        timing = {"fusion": ("30", "6"), "cam1": ("30", "6"), "rogue": ("8", "2"), "nocert": ("8", "2")}
        for role, keys in puts.items():
            wait, secs = timing[role]
            cmd = ["ip", "netns", "exec", ns[role], sys.executable, str(Path(__file__).with_name("netns_tls_peer.py")),
                   role, "--zenoh-config", str(conf[role]), "--connect-wait", wait, "--seconds", secs]
            for k in keys:
                cmd += ["--put", k]
            log = open(tmp_path / f"{role}.log", "w")
            procs.append(subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, env=_env(), cwd=str(tmp_path)))
        for p in procs:
            p.wait(timeout=120)
        logs = {r: (tmp_path / f"{r}.log").read_text() for r in puts}
        res = {}
        for r, text in logs.items():
            lines = [ln for ln in text.splitlines() if ln.startswith("{")]
            assert lines, (r, text[-2000:])
            res[r] = {"peers": json.loads(lines[-1])["peers"],
                      "received": {tuple(x) for x in json.loads(lines[-1])["received"]}}
        from_ = lambda r, who: {k for k, src in res[r]["received"] if src == who}   # noqa: E731
        print("tls: peers", {r: v["peers"] for r, v in res.items()}, "| fusion got from cam1", sorted(from_("fusion", "cam1")),
              "| cam1 got from fusion", sorted(from_("cam1", "fusion")))
        # mutual TLS: a certificate from another CA, or none, gets no link at all
        assert res["rogue"]["peers"] == 0 and res["nocert"]["peers"] == 0, logs
        assert res["cam1"]["peers"] >= 1 and res["fusion"]["peers"] >= 1, logs
        for r in ("rogue", "nocert"):
            assert from_("fusion", r) == set() and from_(r, "fusion") == set() and from_(r, "cam1") == set()
        # access control: the host of cam_1 puts only cam_1's keys and receives only cam_1's predictions
        assert from_("fusion", "cam1") == {"mocap/r/cues/cam_1", "mocap/r/status/worker-cam_1"}
        assert from_("cam1", "fusion") == {"mocap/r/prediction/cam_1"}
