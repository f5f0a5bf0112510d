"""The ``mocap-rt`` command: one subcommand per module, each with ``--help``.

Each subcommand module defines ``register(subparsers)`` which adds its parser and sets
``func`` (called with the parsed args; returns an exit code). Heavy imports stay inside
the functions so that ``mocap-rt --help`` is quick.
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
    "nodes.cli",
)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="mocap-rt", description="Real-time marker-free multi-camera human motion capture; "
        "every subcommand has --help.")
    parser.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name in SUBCOMMANDS:
        if importlib.util.find_spec(name) is None:
            continue
        importlib.import_module(name).register(sub)
    return parser


# what a bad input raises: the project's errors (mocap_rt.config.FileFormatError and its
# subclasses RecordingError, RigFileError, BvhError ..., OutputError: all ValueErrors) and the
# OS's (missing files, permissions)
USER_ERRORS = (ValueError, OSError)


def main(argv: list[str] | None = None) -> int:
    """Run one subcommand. A bad input ends it with one line ``mocap-rt COMMAND: error: ...`` on
    stderr and exit code 2 (as argparse does for a bad flag); ``-v`` adds the traceback."""
    parser = build_parser()
    argv = sys.argv[1:] if argv is None else list(argv)
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
