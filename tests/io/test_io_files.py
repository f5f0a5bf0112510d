"""mocap_rt.io.files: atomic writes, an output that is an input, earlier results."""

import os

import numpy as np
import pytest

from mocap_rt.io.files import OutputError, atomic_write, atomic_write_text, claim_outputs, refuse_input_as_output


def test_atomic_write_replaces_only_on_success(tmp_path):
    p = tmp_path / "poses.npz"
    with atomic_write(p, "wb") as fh:
        np.savez(fh, a=np.arange(3))
    assert np.load(p)["a"].tolist() == [0, 1, 2]
    with pytest.raises(RuntimeError):
        with atomic_write(p, "wb") as fh:
            np.savez(fh, a=np.arange(5))
            raise RuntimeError("the run failed half way")
    assert np.load(p)["a"].tolist() == [0, 1, 2]            # the earlier result is intact
    assert sorted(os.listdir(tmp_path)) == ["poses.npz"]      # and no temporary file is left
    atomic_write_text(tmp_path / "b.toml", "x = 1\n")
    assert (tmp_path / "b.toml").read_text() == "x = 1\n"
    assert oct((tmp_path / "b.toml").stat().st_mode & 0o777) == oct(0o666 & ~_umask())


def _umask():
    m = os.umask(0)
    os.umask(m)
    return m


def test_a_process_killed_mid_write_leaves_the_old_file(tmp_path, kill_when_ready):
    p = tmp_path / "bones.toml"
    p.write_text("thigh_m = 0.47\n")
    kill_when_ready(f"""
from mocap_rt.io.files import atomic_write
with atomic_write({str(p)!r}) as fh:
    fh.write("half")
    fh.flush()
    print("ready", flush=True)
    import time; time.sleep(60)
""")
    assert p.read_text() == "thigh_m = 0.47\n"


def test_an_output_that_is_an_input_is_refused(tmp_path, monkeypatch):
    src = tmp_path / "T.trc"
    src.write_text("markers")
    os.link(src, tmp_path / "hard.trc")
    (tmp_path / "soft.trc").symlink_to(src)
    monkeypatch.chdir(tmp_path)
    for out in (src, "T.trc", "./sub/../T.trc", tmp_path / "hard.trc", tmp_path / "soft.trc"):
        with pytest.raises(OutputError, match="would destroy the input"):
            refuse_input_as_output(out, [None, src])
    refuse_input_as_output(tmp_path / "new.trc", [src])       # a new file is fine
    assert src.read_text() == "markers"


def test_earlier_results_need_overwrite(tmp_path):
    old = tmp_path / "poses.bvh"
    claim_outputs([old], overwrite=False)                      # nothing there yet
    old.write_text("earlier")
    with pytest.raises(OutputError, match="pass --overwrite"):
        claim_outputs([tmp_path / "poses.npz", old], overwrite=False)
    claim_outputs([old], overwrite=True)
