"""The library installs and runs without the capture service; the service says what to install.

The service's packages are made unimportable in a fresh interpreter (``sys.modules[name] =
None``, what Python does for a module that failed to import), as on a machine where only
``pip install mocap-rt`` was run.
"""

import subprocess
import sys
import textwrap
import tomllib
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
SERVICE_ONLY = ("zenoh", "msgpack", "rerun", "psutil", "setproctitle")


def run_without_service(code: str, hide=SERVICE_ONLY) -> subprocess.CompletedProcess:
    prelude = "import sys\n" + "".join(f"sys.modules[{m!r}] = None\n" for m in hide)
    return subprocess.run([sys.executable, "-c", prelude + textwrap.dedent(code)], capture_output=True,
                          text=True, cwd=REPO, timeout=300)


def test_every_library_module_imports_without_the_service_packages():
    out = run_without_service("""
        import importlib, pkgutil, mocap_rt
        names = [m.name for m in pkgutil.walk_packages(mocap_rt.__path__, "mocap_rt.")]
        for name in names:
            importlib.import_module(name)
        assert not any(m in sys.modules and sys.modules[m] is not None for m in %r)
        print(len(names))
    """ % (SERVICE_ONLY,))
    assert out.returncode == 0, out.stderr
    assert int(out.stdout) > 40                   # the walk found the library


def test_run_and_node_without_the_service_say_what_to_install():
    for hide in (("zenoh",), SERVICE_ONLY):
        for argv in (["run", "--source", "replay:x"], ["node", "sync", "--rig", "r.toml"], ["-v", "run", "--help"]):
            out = run_without_service(f"from mocap_rt.cli import main; sys.exit(main({argv!r}))", hide)
            assert out.returncode == 2, (argv, out.stderr)
            line = out.stderr.strip().splitlines()[-1]
            command = next(a for a in argv if not a.startswith("-"))
            assert line.startswith(f"mocap-rt {command}: error: "), line
            assert "pip install 'mocap-rt[service]'" in line and "eclipse-zenoh" in line, line
    # the library's own commands are all there
    out = run_without_service("""
        from mocap_rt.cli import main
        try:
            main(["--help"])
        except SystemExit as e:
            sys.exit(e.code)
    """)
    assert out.returncode == 0, out.stderr
    for cmd in ("calibrate", "synth", "process", "joint-centres", "run", "node"):
        assert cmd in out.stdout


def test_with_the_service_run_is_the_service():
    out = run_without_service("""
        from mocap_rt.cli import main
        try:
            main(["run", "--help"])
        except SystemExit as e:
            sys.exit(e.code)
    """, hide=())
    assert out.returncode == 0 and "--source" in out.stdout and "--config" in out.stdout, out.stderr


def test_pyproject_keeps_the_service_packages_in_the_service_extra():
    from mocap_rt.cli import SERVICE_MODULES

    project = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]
    core = {d.split(">")[0].split("<")[0].split("=")[0].strip() for d in project["dependencies"]}
    service = {d.split(">")[0].split("<")[0].split("=")[0].strip() for d in project["optional-dependencies"]["service"]}
    assert service == set(SERVICE_MODULES.values())
    assert not core & service
