"""Node settings: one dataclass per node, filled by its flags or by ``--config FILE`` (flags win)."""

import dataclasses
import importlib
import re
import threading
from pathlib import Path

import pytest
from service_helpers import wait_for

from mocap_rt.config import dataclass_to_dict, dumps_toml
from nodes.cli import NODE_MODULES
from nodes.node import NodeSettings, parse_settings

SETTINGS = {"sync": "SyncSettings", "camera": "WorkerSettings", "fusion": "FusionSettings",
            "recorder": "RecorderSettings", "viewer": "ViewerSettings", "stream": "StreamerSettings"}


def node(role):
    mod = importlib.import_module(NODE_MODULES[role])
    return mod, getattr(mod, SETTINGS[role])


def write_toml(path: Path, values: dict) -> Path:
    """Top-level keys (``dumps_toml`` writes tables): the table's lines without its header."""
    text = dumps_toml({"x": values})
    path.write_text("\n".join(line for line in text.splitlines() if line != "[x]") + "\n")
    return path


@pytest.mark.parametrize("role", sorted(SETTINGS))
def test_flag_defaults_are_the_dataclass_defaults(role):
    mod, cls = node(role)
    assert issubclass(cls, NodeSettings)
    s = parse_settings(mod.build_parser(), cls, ["--rig", "rig.toml"])
    assert s == cls(rig=Path("rig.toml"))


@pytest.mark.parametrize("role", sorted(SETTINGS))
def test_config_file_round_trips_and_flags_win(role, tmp_path):
    mod, cls = node(role)
    changed = {"rig": Path("/etc/rig.toml"), "rig_name": "studio", "log_level": "DEBUG", "rt_priority": 7,
               "connect": ("tcp/127.0.0.1:7001", "tcp/127.0.0.1:7002")}
    own = {"sync": {"fps": 60.0, "frames": 12, "expect_peers": 3},
           "camera": {"camera": "cam_2", "source": "replay:/data/rec", "preview_every": 6, "publish_frames": True},
           "fusion": {"deadline_frac": 0.5, "fps": 25.0, "bones": Path("/etc/bones.toml")},
           "recorder": {"out": Path("/var/rec"), "raw": True},
           "viewer": {"rerun": "save:/tmp/x.rrd", "preview_every": 3},
           "stream": {"stream": "vmc:127.0.0.1:40000"}}[role]
    want = dataclasses.replace(cls(), **changed, **own)
    cfg = write_toml(tmp_path / "node.toml", {k: str(v) if isinstance(v, Path) else v
                                             for k, v in dataclass_to_dict(want).items()})
    assert parse_settings(mod.build_parser(), cls, ["--config", str(cfg)]) == want
    flags = parse_settings(mod.build_parser(), cls, ["--config", str(cfg), "--rt-priority", "3",
                                                     "--connect", "tcp/127.0.0.1:7003"])
    assert flags == dataclasses.replace(want, rt_priority=3, connect=("tcp/127.0.0.1:7003",))


def test_a_bad_config_is_one_error_naming_file_and_key(tmp_path, capsys):
    mod, cls = node("fusion")
    for text, words in (("rig = 'r.toml'\ndeadline_fraction = 0.5\n", ["deadline_fraction"]),
                        ("rig = 'r.toml'\ndeadline_frac = 'soon'\n", ["deadline_frac"]),
                        ("rig = 'r.toml'\ndeadline_frac = 1.5\n", ["deadline_frac", "(0, 1]"]),
                        ("deadline_frac = 0.5\n", ["--rig"])):
        cfg = tmp_path / "fusion.toml"
        cfg.write_text(text)
        with pytest.raises(SystemExit) as exit_:
            parse_settings(mod.build_parser(), cls, ["--config", str(cfg)])
        assert exit_.value.code == 2
        err = capsys.readouterr().err.strip().splitlines()[-1]
        assert "error:" in err and all(w in err for w in words), err
    with pytest.raises(SystemExit):
        parse_settings(mod.build_parser(), cls, ["--config", str(tmp_path / "missing.toml")])
    assert "missing.toml" in capsys.readouterr().err


def test_a_sync_node_runs_from_its_config_file_alone(tmp_path):
    """``python -m nodes.sync --config FILE``: rate, frame count and endpoints from the file."""
    import subprocess
    import sys

    import zenoh

    from mocap_rt.geometry.rig import write_rig
    from mocap_rt.studio.synth import make_rig
    from nodes.messages import Decoder, Keys, Trigger
    from nodes.procs import free_port
    from nodes.transport import make_config

    write_rig(make_rig(n_cameras=2, size=(64, 48)), tmp_path / "rig.toml")
    port = free_port()
    frames = 8
    cfg = write_toml(tmp_path / "sync.toml", {"rig": str(tmp_path / "rig.toml"), "rig_name": "cfgtest", "fps": 40.0,
                                              "frames": frames, "start_frame": 100, "expect_peers": 1,
                                              "connect": [f"tcp/127.0.0.1:{port}"]})
    got, lock, dec = [], threading.Lock(), Decoder("test")

    def on_trigger(sample):
        msg = dec.decode(sample.payload, Trigger)
        with lock:
            got.append(msg)

    with zenoh.open(make_config([f"tcp/127.0.0.1:{port}"], [])) as session:
        sub = session.declare_subscriber(Keys("cfgtest").trigger, on_trigger)
        proc = subprocess.run([sys.executable, "-m", "nodes.sync", "--config", str(cfg)], capture_output=True,
                              text=True, timeout=120)
        wait_for(lambda: any(m.frame == 100 + frames - 1 for m in got), 5.0)
        sub.undeclare()
    assert proc.returncode == 0, proc.stderr
    # on a loaded host the first triggers can go out before the subscription reached the sync,
    # and a sync that was late skips slots (the last ones too: ``frames`` bounds the slots):
    # what arrived is in order, from the file's start frame and rate, and the file's count of
    # slots was sent or skipped
    sent, skipped = map(int, re.search(r"sync: (\d+) triggers sent, (\d+) slots skipped", proc.stderr).groups())
    assert sent + skipped == frames, proc.stderr
    seen = [m.frame for m in got]
    assert seen and seen == sorted(set(seen)) and set(seen) <= set(range(100, 100 + frames)), seen
    assert len(seen) <= sent
    if skipped == 0:
        assert seen[-1] == 100 + frames - 1, (seen, proc.stderr)
    assert all(m.period_ns == 25_000_000 for m in got)


def test_a_node_given_a_missing_rig_says_so_in_one_line(tmp_path):
    import subprocess
    import sys

    out = subprocess.run([sys.executable, "-m", "nodes.fusion_node", "--rig", str(tmp_path / "nope.toml")],
                         capture_output=True, text=True, timeout=120)
    assert out.returncode == 2
    assert out.stderr.strip().splitlines() == [f"fusion: error: {tmp_path / 'nope.toml'}: no such rig file"]


def test_run_takes_its_settings_from_a_file_and_flags_win(tmp_path, capsys):
    from mocap_rt.cli import build_parser, main
    from nodes.cli import run_config
    from nodes.run_config import RunConfig

    rec = tmp_path / "rec"
    cfg = tmp_path / "run.toml"
    cfg.write_text(f"source = 'replay:{rec}'\nspeed = 2.0\nduration_s = 5.0\nrecord = '{tmp_path / 'out'}'\n"
                   "deadline_frac = 0.6\nrestart = false\n[extra_node_args]\nfusion = ['--log-level', 'DEBUG']\n")
    args = build_parser().parse_args(["run", "--config", str(cfg), "--speed", "max", "--quiet"])
    assert run_config(args) == RunConfig(rig_path=rec / "rig.toml", source=f"replay:{rec}", speed=None, duration_s=5.0,
                                         record=tmp_path / "out", deadline_frac=0.6, restart=False,
                                         status_line=False, extra_node_args={"fusion": ["--log-level", "DEBUG"]})
    # without a file: the flags given, RunConfig's defaults for the rest
    args = build_parser().parse_args(["run", "--source", f"replay:{rec}", "--rig", str(tmp_path / "r.toml")])
    assert run_config(args) == RunConfig(rig_path=tmp_path / "r.toml", source=f"replay:{rec}")
    # a bad file is one line naming the file and the key
    (tmp_path / "bad.toml").write_text(f"source = 'replay:{rec}'\nspeeed = 2.0\n")
    assert main(["run", "--config", str(tmp_path / "bad.toml")]) == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert err.startswith("mocap-rt run: error: ") and "bad.toml" in err and "speeed" in err, err
    assert main(["run", "--speed", "2"]) == 2
    assert "--source is required" in capsys.readouterr().err


def test_run_never_overwrites_its_outputs_or_inputs(tmp_path, capsys):
    """``--stats`` and ``--rerun save:`` name new files: an existing one (an earlier run's result)
    stops the run before any node starts, unless ``--overwrite``; an input never, even then."""
    from mocap_rt.cli import main
    from nodes.preflight import check_options
    from nodes.run_config import RunConfig

    rig = tmp_path / "rig.toml"
    rig.write_text("not read by check_options\n")
    old = tmp_path / "stats.json"
    old.write_text('{"earlier": "run"}')
    for argv, needle in ((["--stats", str(old)], f"--stats: {old} exists"),
                         (["--rerun", f"save:{old}"], f"--rerun save:: {old} exists"),
                         (["--stats", str(rig), "--overwrite"], f"--stats {rig} is the input"),
                         (["--rerun", f"save:{tmp_path}"], "is a directory"),
                         (["--stats", str(tmp_path / "a"), "--rerun", f"save:{tmp_path / 'a'}"], "name one file")):
        assert main(["run", "--source", f"replay:{tmp_path}", "--rig", str(rig), *argv]) == 2, argv
        err = capsys.readouterr().err.strip().splitlines()[-1]
        assert err.startswith("mocap-rt run: error: ") and needle in err, (argv, err)
    assert old.read_text() == '{"earlier": "run"}'
    check_options(RunConfig(rig_path=rig, source=f"replay:{tmp_path}", stats=old, overwrite=True))
    check_options(RunConfig(rig_path=rig, source=f"replay:{tmp_path}", stats=tmp_path / "new.json",
                            rerun=f"save:{tmp_path / 'new.rrd'}"))
