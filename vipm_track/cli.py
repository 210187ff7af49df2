"""``vipm-track`` command line: argument parsing only; each subcommand lives in
``vipm_track/commands/<name>.py`` as ``register(subparsers)`` + a handler calling the library."""

from __future__ import annotations

import argparse
import importlib
import signal
import sys
from collections.abc import Sequence

from .commands.common import infer_inputs
from .errors import InputError, NothingUsable, os_error_line, printable

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


#: Exit codes: 0 usable output, 1 ran but nothing usable, 2 bad input, 130 interrupted.
EXIT_OK, EXIT_NOTHING_USABLE, EXIT_BAD_INPUT, EXIT_INTERRUPTED = 0, 1, 2, 130


def _terminate(signum: int, frame: object) -> None:
    # SIGTERM ends a run as Ctrl-C does: what is decided is written, then exit 130
    raise KeyboardInterrupt


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    name = f"vipm-track {args.command}"
    previous = signal.getsignal(signal.SIGTERM)
    try:
        signal.signal(signal.SIGTERM, _terminate)
    except ValueError:  # not the main thread (an embedding program): leave SIGTERM alone
        previous = None
    try:
        infer_inputs(args)
        return int(args.handler(args) or 0)
    except InputError as exc:
        print(f"{name}: error: {printable(exc, 2000)}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except NothingUsable as exc:
        print(f"{name}: nothing usable: {printable(exc, 2000)}", file=sys.stderr)
        return EXIT_NOTHING_USABLE
    except OSError as exc:
        print(f"{name}: error: {os_error_line(exc)}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except KeyboardInterrupt:
        print(f"{name}: interrupted; the rows written before it are complete and kept",
              file=sys.stderr)
        return EXIT_INTERRUPTED
    finally:
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)


if __name__ == "__main__":
    raise SystemExit(main())
