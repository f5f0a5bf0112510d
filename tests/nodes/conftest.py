"""The end-to-end (slow) service tests start nodes: they get a warm kernel cache first.

``replay_run``: ONE ``mocap-rt run`` of the studio walk, shared by the tests of what such a run
produces (the CLI's outputs in test_nodes_service, the cold kernel cache in test_nodes_lifecycle,
the VMC stream in test_nodes_streamer): a cluster start and a replay cost ~20 s, so they are not
repeated per assertion.
"""

import json
import os
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import pytest
from service_helpers import UdpSink, small_recording

REPLAY_SPEED = 0.5          # 15 fps: a 67-ms period leaves a loaded or 3x slower machine time for
                            # every camera of every frame (the rate is the benches' business)


@pytest.fixture(autouse=True)
def _warm_kernels_for_services(request):
    if request.node.get_closest_marker("slow") and not request.node.get_closest_marker("cold_cache"):
        request.getfixturevalue("warm_kernels")


@dataclass(frozen=True)
class ReplayRun:
    """What ``mocap-rt run --source replay:WALK`` left: its recording, Rerun file, stats, logs,
    the numba cache it started from empty, the UDP sink of its VMC stream, and the command's
    exit code and stderr."""

    walk: Path
    out: Path
    sink: UdpSink
    returncode: int
    stderr: str

    @property
    def stats(self) -> dict:
        return json.loads((self.out / "stats.json").read_text())

    rec = property(lambda self: self.out / "rec")
    rrd = property(lambda self: self.out / "view.rrd")
    logs = property(lambda self: self.out / "logs")
    numba_cache = property(lambda self: self.out / "numba-cache")


@pytest.fixture(scope="session")
def replay_run(tmp_path_factory, data_dir) -> ReplayRun:
    """One pass of the walk through the CLI with recorder, viewer and VMC stream on (the demo
    path and more), from an EMPTY numba cache directory (``NUMBA_CACHE_DIR``): the launcher must
    build it once before any node starts."""
    walk = small_recording(tmp_path_factory.getbasetemp(), data_dir)
    out = tmp_path_factory.mktemp("replay_run")
    (out / "numba-cache").mkdir()
    sink = UdpSink()
    run = ReplayRun(walk, out, sink, 0, "")
    exe = str(Path(sys.executable).with_name("mocap-rt"))
    try:
        proc = subprocess.run([exe, "run", "--source", f"replay:{walk}", "--record", str(run.rec),
                               "--rerun", f"save:{run.rrd}", "--stream", f"vmc:127.0.0.1:{sink.port}",
                               "--stats", str(out / "stats.json"), "--quiet", "--speed", str(REPLAY_SPEED),
                               "--log-dir", str(run.logs)],
                              env=dict(os.environ, NUMBA_CACHE_DIR=str(run.numba_cache)),
                              capture_output=True, text=True, timeout=1800)
        if proc.returncode == 0:
            # every bundle the streamer sent is on the socket: wait until the sink has read them
            sink.drain(run.stats.get("stream", {}).get("sent", 0))
    finally:
        sink.close()
    return ReplayRun(walk, out, sink, proc.returncode, proc.stderr)
