"""deploy/: every Zenoh role config loads and is locked down; every systemd unit runs a valid node command."""

import configparser
import importlib
import json
import subprocess
from pathlib import Path

import pytest

from nodes.cli import NODE_MODULES
from nodes.transport import make_config

DEPLOY = Path(__file__).resolve().parents[2] / "deploy"
CONFIGS = sorted((DEPLOY / "zenoh").glob("*.json5"))
UNITS = sorted((DEPLOY / "systemd").glob("*.service"))


def test_deploy_files_exist():
    assert {p.stem for p in CONFIGS} == {"sync-host", "camera-host", "fusion-host"}
    assert {p.name for p in UNITS} == {"mocap-rt-sync.service", "mocap-rt-camera@.service",
                                       "mocap-rt-fusion.service", "mocap-rt-recorder.service",
                                       "mocap-rt-viewer.service", "mocap-rt-stream.service"}


@pytest.mark.parametrize("path", CONFIGS, ids=lambda p: p.stem)
def test_zenoh_role_config_is_locked_down(path):
    conf = make_config(config_file=path)          # what a node opens with --zenoh-config only
    get = lambda key: json.loads(conf.get_json(key))   # noqa: E731
    assert get("mode") == "peer"
    assert get("scouting/multicast/enabled") is False and get("scouting/gossip/enabled") is False
    assert get("transport/shared_memory/enabled") is False
    listen = get("listen/endpoints")
    assert listen and all(e.startswith("tls/") for e in listen), listen       # the file's endpoints kept
    assert not any(h in e for e in listen for h in ("0.0.0.0", "[::]")), listen
    assert all(e.startswith("tls/") for e in get("connect/endpoints"))
    tls = get("transport/link/tls")
    assert tls["enable_mtls"] is True and tls["root_ca_certificate"]
    acl = get("access_control")
    assert acl["enabled"] is True and acl["default_permission"] == "deny"
    # flags still win over the file
    conf2 = make_config(["tcp/127.0.0.1:7999"], ["tcp/127.0.0.1:7998"], config_file=path)
    assert json.loads(conf2.get_json("listen/endpoints")) == ["tcp/127.0.0.1:7999"]


def _env() -> dict:
    env = {}
    for line in (DEPLOY / "systemd" / "mocap-rt.env").read_text().splitlines():
        if line.strip() and not line.startswith("#"):
            k, v = line.split("=", 1)
            env[k] = v
    return env


@pytest.mark.parametrize("path", UNITS, ids=lambda p: p.stem)
def test_systemd_unit_runs_a_valid_node_command(path):
    unit = configparser.ConfigParser(interpolation=None, strict=False)
    unit.read(path)
    svc = unit["Service"]
    assert svc["EnvironmentFile"] == "/etc/mocap-rt/mocap-rt.env"
    assert svc["Restart"] == "always"
    cmd = svc["ExecStart"]
    prefix = "/bin/sh -c '"
    assert cmd.startswith(prefix) and cmd.endswith("'")
    script = cmd[len(prefix):-1].replace("%i", "cam_1").replace("%%", "%")
    assert script.startswith('exec "$MOCAP_RT" ')
    # let the shell expand the line exactly as systemd's /bin/sh would, but print the argv
    script = "printf '%s\\0' " + script[len('exec "$MOCAP_RT" '):]
    out = subprocess.run(["/bin/sh", "-c", script], env={**_env(), "PATH": "/usr/bin:/bin"},
                         capture_output=True, text=True, check=True).stdout
    argv = out.split("\0")[:-1]
    assert argv[0] == "node" and argv[1] in NODE_MODULES, argv
    args = importlib.import_module(NODE_MODULES[argv[1]]).build_parser().parse_args(argv[2:])
    assert args.rig == Path("/etc/mocap-rt/rig.toml") and args.rig_name == "studio"
    assert args.zenoh_config is not None and args.zenoh_config.name.startswith("zenoh-")
    if argv[1] == "camera":
        assert args.camera == "cam_1" and args.source == "v4l2:/dev/mocap-cam_1"
    if argv[1] == "stream":
        from mocap_rt.io.vmc import parse_vmc_target
        assert parse_vmc_target(args.stream, args.allow_remote_stream) == ("10.10.0.50", 39539)
