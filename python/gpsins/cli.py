"""The ``gpsins`` command: one subcommand per job, each a thin layer over a module."""

from __future__ import annotations

import argparse
import sys

from . import __version__


def _cmd_log(args: argparse.Namespace) -> int:
    from gpsins_logger import daemon

    return daemon.main(args.logger_args)


def _cmd_run(args: argparse.Namespace) -> int:
    from . import mainjob

    return mainjob.run(args)


def _cmd_dump(args: argparse.Namespace) -> int:
    from . import dump

    return dump.main(args)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="gpsins", description=__doc__)
    parser.add_argument("--version", action="version", version=f"gpsins {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    p = sub.add_parser("run", help="the main job on its built-in default")
    p.add_argument("--out", default="out", help="output directory (default: out)")
    p.set_defaults(func=_cmd_run)

    p = sub.add_parser("dump", help="summarise a session directory or a raw device capture")
    p.add_argument("path", help="session directory, or with --raw a capture file")
    p.add_argument("--raw", choices=("superstar2", "bp3010"), help="PATH is a raw byte stream of this device")
    p.add_argument("--csv", action="store_true", help="list every record as CSV on stdout")
    p.add_argument("--format", choices=("text", "json"), default="text")
    p.set_defaults(func=_cmd_dump)

    p = sub.add_parser("log", help="run the logger daemon (same as gpsins-logger)", add_help=False)
    p.add_argument("logger_args", nargs=argparse.REMAINDER)
    p.set_defaults(func=_cmd_log)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    return int(args.func(args) or 0)


if __name__ == "__main__":
    sys.exit(main())
