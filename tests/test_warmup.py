"""The kernel-cache stamp of ``mocap_rt.warmup``: what it depends on, where it lives."""

import json

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


def test_the_package_kernel_sources_are_the_numba_modules():
    names = {p.name for p in warmup.kernel_sources()}
    assert {"blob_kernels.py", "ik_kernels.py", "render_kernels.py", "warmup.py"} <= names
    assert "recording.py" not in names                            # io: no kernels
