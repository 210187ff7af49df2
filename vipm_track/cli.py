"""``vipm-track`` command line: argument parsing only; each subcommand lives in
``vipm_track/commands/<name>.py`` as ``register(subparsers)`` + a handler calling the library."""

from __future__ import annotations

import argparse
import importlib
import sys
from collections.abc import Sequence

from .errors import InputError

#: Subcommand modules under ``vipm_track.commands``, in the order ``--help`` lists them.
COMMANDS: tuple[str, ...] = (
    "simulate", "estimate", "track", "smooth", "monitor", "can_speed", "report", "demo",
)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="vipm-track",
        description="Camera pitch, roll, height against the ground and planar motion from a "
        "monocular vehicle camera; filtering, smoothing and a recalibration monitor.",
    )
    parser.add_argument("--version", action="version", version="vipm-track 0.1.0")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name in COMMANDS:
        importlib.import_module(f"vipm_track.commands.{name}").register(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.handler(args) or 0)
    except (InputError, FileNotFoundError) as exc:
        print(f"vipm-track {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(
            f"vipm-track {args.command}: interrupted; rows written so far are kept", file=sys.stderr
        )
        return 130


if __name__ == "__main__":
    raise SystemExit(main())
