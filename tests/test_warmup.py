"""The kernel-cache stamp of ``mocap_rt.warmup``: what it depends on, where it lives."""

import json
import subprocess
import sys

from mocap_rt import warmup


def _package(tmp_path):
    pkg = tmp_path / "pkg"
    (pkg / "sub").mkdir(parents=True)
    (pkg / "kern.py").write_text("from numba import njit\n\n@njit(cache=True)\ndef f(x):\n    return x\n")
    (pkg / "sub" / "plain.py").write_text("def g(x):\n    return x\n")
    (pkg / "sub" / "kern2.py").write_text("import numba\n")
    return pkg


def test_stamp_follows_the_kernel_sources_numba_and_the_cache_dir(tmp_path, monkeypatch):
    pkg = _package(tmp_path)
    monkeypatch.setattr(warmup, "PACKAGE_DIR", pkg)
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path / "cache"))
    assert [p.relative_to(pkg).as_posix() for p in warmup.kernel_sources()] == ["kern.py", "sub/kern2.py"]
    assert warmup.stamp_path() == tmp_path / "cache" / warmup.STAMP_NAME
    assert not warmup.is_warm()                                  # no stamp yet
    warmup.stamp_path().write_text(json.dumps({"digest": warmup.sources_digest()}))
    assert warmup.is_warm()
    (pkg / "sub" / "plain.py").write_text("def g(x):\n    return 2 * x\n")
    assert warmup.is_warm()                                      # not a kernel source
    (pkg / "kern.py").write_text((pkg / "kern.py").read_text() + "\n# changed\n")
    assert not warmup.is_warm()                                  # a kernel source changed
    warmup.stamp_path().write_text(json.dumps({"digest": warmup.sources_digest()}))
    assert warmup.is_warm()
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path / "other"))
    (tmp_path / "other").mkdir()
    (tmp_path / "other" / warmup.STAMP_NAME).write_text((tmp_path / "cache" / warmup.STAMP_NAME).read_text())
    assert not warmup.is_warm()                                  # the digest names the cache dir


def test_a_warm_up_on_synthetic_frames_is_not_warm_once_the_data_is_there(tmp_path, monkeypatch):
    """Synthetic frames leave kernels out: with the data's clip at hand their stamp is cold
    (the next warm-up renders the clip), without it warm; a rendered scene's stamp is warm."""
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path / "cache"))
    data = tmp_path / "data"
    clip = data / warmup.DEFAULT_CLIP
    clip.parent.mkdir(parents=True)
    clip.write_text("HIERARCHY\n")
    monkeypatch.setenv("MOCAP_RT_DATA", str(tmp_path / "nothing here"))
    warmup.stamp_path().write_text(json.dumps({"digest": warmup.sources_digest(), "scene": warmup.SYNTHETIC_SCENE}))
    assert warmup.is_warm()
    monkeypatch.setenv("MOCAP_RT_DATA", str(data))
    assert not warmup.is_warm()
    warmup.stamp_path().write_text(json.dumps({"digest": warmup.sources_digest(), "scene": f"rendering {clip}"}))
    assert warmup.is_warm()


def test_without_the_variable_the_data_beside_the_checkout_counts(tmp_path, monkeypatch):
    """No ``MOCAP_RT_DATA``: the clip is looked for in the project's data (``../shared/data``,
    where the benches read it), so a synthetic warm-up there is cold too."""
    monkeypatch.delenv("MOCAP_RT_DATA", raising=False)
    from mocap_rt import shared_data

    monkeypatch.setattr(shared_data, "DEFAULT_DATA", tmp_path)
    assert warmup.default_motion() is None
    clip = tmp_path / warmup.DEFAULT_CLIP
    clip.parent.mkdir(parents=True)
    clip.write_text("HIERARCHY\n")
    assert warmup.default_motion() == clip
    monkeypatch.setenv("MOCAP_RT_DATA", str(tmp_path / "elsewhere"))
    assert warmup.default_motion() is None                       # the variable wins


def test_the_package_kernel_sources_are_the_numba_modules():
    names = {p.name for p in warmup.kernel_sources()}
    assert {"blob_kernels.py", "ik_kernels.py", "render_kernels.py", "warmup.py"} <= names
    assert "recording.py" not in names                            # io: no kernels


def test_a_warm_up_in_a_process_that_already_compiled_kernels_refuses(tmp_path):
    """numba never writes a kernel it already holds, so a warm-up after the kernels ran in the
    same process would stamp a nearly empty cache warm (every node then compiles at start): it
    refuses, names the way to run it, and leaves the cache and stamp alone."""
    import os
    import subprocess
    import sys

    code = ("import numpy as np\n"
            "from mocap_rt.geometry.lens import undistort_point\n"
            "undistort_point(1.0, 2.0, np.eye(3), np.zeros(8))\n"
            "from mocap_rt import warmup\n"
            "warmup.ensure_warm(force=True)\n")
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "cache"))
    r = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=300)
    assert r.returncode != 0
    assert "warm-up must run in a fresh process (`python -m mocap_rt.warmup`)" in r.stderr
    assert "undistort_point" in r.stderr
    assert not (tmp_path / "cache" / warmup.STAMP_NAME).exists()


def test_the_cache_check_imports_no_numba():
    """``is_warm`` and the data's clip it asks for (``default_motion``) stay cheap: every node and
    the launcher call them at start-up (a check through ``studio.procedural`` took 1.1 s)."""
    code = ("import sys; from mocap_rt import warmup; warmup.is_warm(); warmup.default_motion(); "
            "print('numba' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, timeout=60)
    assert out.stdout.strip() == "False", out
