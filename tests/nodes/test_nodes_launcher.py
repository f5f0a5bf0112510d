"""The launcher's own duties: distinct listen ports, and a node that cannot start explains why."""

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
