"""The launcher's own duties: distinct listen ports, a node that cannot start explains why,
the hot spare camera worker."""

import subprocess
import sys

import pytest
from service_helpers import small_recording

from nodes.launcher import Launcher, RunConfig, free_port


def test_free_port_never_hands_out_the_same_port_twice():
    # all ports of a service are drawn before any node binds one, so "free now" is not enough;
    # 300 draws from the ~12 000-port range repeat one with probability ~98 % if unguarded
    ports = [free_port() for _ in range(300)]
    assert len(set(ports)) == len(ports)


@pytest.mark.slow
def test_a_node_failing_at_start_is_reported_with_its_log(tmp_path, tmp_path_factory, data_dir):
    walk = small_recording(tmp_path_factory.getbasetemp(), data_dir)
    cfg = RunConfig(rig_path=walk / "rig.toml", source=f"replay:{walk}", duration_s=5.0,
                    status_line=False, log_dir=tmp_path / "logs",
                    extra_node_args={"fusion": ["--no-such-flag"]})
    L = Launcher(cfg)
    try:
        with pytest.raises(RuntimeError) as err:
            L.start()
    finally:
        L.stop()
    msg = str(err.value)
    assert "fusion failed at start" in msg and "unrecognized arguments: --no-such-flag" in msg


@pytest.mark.slow
@pytest.mark.parametrize("kind", ["replay", "fake"])
def test_hot_spare_warms_up_and_exits_at_end_of_input(kind, tmp_path_factory, data_dir):
    # a live source's device belongs to the running worker: the spare warms up on synthetic
    # frames there; a replay it reads. With no assignment (the launcher stopped) it exits 0.
    walk = small_recording(tmp_path_factory.getbasetemp(), data_dir)
    proc = subprocess.run([sys.executable, "-m", "nodes.camera_worker", "--rig", str(walk / "rig.toml"),
                           "--camera", "cam_1", "--source", f"{kind}:{walk}", "--standby"],
                          input="", capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert "standby: warm, waiting" in proc.stderr and "taking over" not in proc.stderr
