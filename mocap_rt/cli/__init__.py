"""The ``mocap-rt`` command: one subcommand per module, each with ``--help``.

Each subcommand module defines ``register(subparsers)`` which adds its parser and sets
``func`` (called with the parsed args; returns an exit code). Heavy imports stay inside
the functions so that ``mocap-rt --help`` is quick. The capture service's subcommands
(``run``, ``node``) come from ``nodes.cli`` when the ``service`` extra is installed; without
it they say what to install.
"""

from __future__ import annotations

import argparse
import importlib
import importlib.util
import logging
import sys

# subcommand module, in the order --help lists them
SUBCOMMANDS = (
    "mocap_rt.cli.calibrate",
    "mocap_rt.cli.synth",
    "mocap_rt.cli.colour_model",
    "mocap_rt.cli.perceive",
    "mocap_rt.cli.process",
    "mocap_rt.cli.pose_from_annotations",
    "mocap_rt.cli.joint_centres",
)
SERVICE_CLI = "nodes.cli"
SERVICE_SUBCOMMANDS = ("run", "node")
# what the service imports beyond the library (pyproject.toml, extra "service")
SERVICE_MODULES = {"zenoh": "eclipse-zenoh", "msgpack": "msgpack", "rerun": "rerun-sdk", "psutil": "psutil",
                   "setproctitle": "setproctitle"}
SERVICE_INSTALL = "pip install 'mocap-rt[service]'"


def service_unavailable() -> str | None:
    """Why the capture service cannot run here (None: it can): a distribution of the
    ``service`` extra, or the ``nodes`` package, cannot be imported."""
    missing = [dist for mod, dist in SERVICE_MODULES.items() if importlib.util.find_spec(mod) is None]
    if not missing and importlib.util.find_spec(SERVICE_CLI) is None:
        missing = ["the nodes package"]
    if not missing:
        return None
    return f"the capture service is not installed (missing: {', '.join(missing)}); install it with: {SERVICE_INSTALL}"


def _register_service(sub) -> None:
    """``run`` and ``node`` from ``nodes.cli``; without the service, listed stand-ins (``main``
    answers them with what to install)."""
    if service_unavailable() is None:
        importlib.import_module(SERVICE_CLI).register(sub)
        return
    for name in SERVICE_SUBCOMMANDS:
        sub.add_parser(name, help=f"the capture service (needs {SERVICE_INSTALL})", add_help=False)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="mocap-rt", description="Real-time marker-free multi-camera human motion capture; "
        "every subcommand has --help.")
    parser.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name in SUBCOMMANDS:
        importlib.import_module(name).register(sub)
    _register_service(sub)
    return parser


# what a bad input raises: the project's errors (mocap_rt.config.FileFormatError and its
# subclasses RecordingError, RigFileError, BvhError ..., OutputError: all ValueErrors) and the
# OS's (missing files, permissions)
USER_ERRORS = (ValueError, OSError)


def main(argv: list[str] | None = None) -> int:
    """Run one subcommand. A bad input ends it with one line ``mocap-rt COMMAND: error: ...`` on
    stderr and exit code 2 (as argparse does for a bad flag); ``-v`` adds the traceback."""
    argv = sys.argv[1:] if argv is None else list(argv)
    command = next((a for a in argv if not a.startswith("-")), None)
    if command in SERVICE_SUBCOMMANDS and (why := service_unavailable()) is not None:
        print(f"mocap-rt {command}: error: {why}", file=sys.stderr)
        return 2
    parser = build_parser()
    for a in argv:
        # Python 3.11's argparse turns "--opt=--" into an empty list instead of an error
        if a.startswith("--") and a.endswith("=--"):
            parser.error(f"argument {a[:-3]}: expected a value, got '--'")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.DEBUG if args.verbose else logging.INFO,
                        format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    try:
        return int(args.func(args) or 0)
    except KeyboardInterrupt:
        return 130
    except USER_ERRORS as exc:
        if args.verbose:
            import traceback

            traceback.print_exc()
        print(f"mocap-rt {args.command}: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
