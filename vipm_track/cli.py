"""``vipm-track`` command line: argument parsing only; each subcommand lives in
``vipm_track/commands/<name>.py`` as ``register(subparsers)`` + a handler calling the library."""

from __future__ import annotations

import argparse
import importlib
import signal
import sys
import time
from collections.abc import Sequence
from pathlib import Path

from .allocator import keep_freed_memory
from .commands.common import check_outputs_apart, infer_inputs
from .errors import InputError, NothingUsable, interrupted_in, os_error_line, printable

#: Subcommands: name → (module under ``vipm_track.commands``, the line ``--help`` lists), in
#: the order ``--help`` lists them. The line is the module's own ``help`` (a test holds them
#: equal): ``vipm-track --help`` and a command's parser then import that command alone.
COMMANDS: dict[str, tuple[str, str]] = {
    "simulate": ("simulate", "render a synthetic ground sequence (images, camera.yaml, gt.csv, "
                 "times.txt)"),
    "estimate": ("estimate", "pitch, roll and planar motion for every consecutive frame pair"),
    "track": ("track", "EKF over the two-frame estimates: mount calibration, shaking, motion"),
    "smooth": ("smooth", "smooth the two-frame estimates with a factor graph (gtsam): best "
               "calibration"),
    "monitor": ("monitor", "is the camera still calibrated? per-frame state and recalibration "
                "events"),
    "live": ("live", "monitor a camera and a CAN bus in real time: rows, state changes, "
             "summary"),
    "fleet": ("fleet", "many logged drives on Dask: estimate, smooth, summarise and monitor "
              "each; partitioned Parquet and a fleet report"),
    "can-speed": ("can_speed", "decode wheel speed from a CAN log or bus to t,speed_mps CSV"),
    "report": ("report", "plots (PNG) and a Markdown summary of a track / estimate / monitor "
               "table"),
    "demo": ("demo", "a drive whose camera is knocked out of calibration: estimate, filter, "
             "smooth, monitor, scored against the truth"),
}


def build_parser(only: str | None = None) -> argparse.ArgumentParser:
    """The command line; with ``only``, that subcommand's parser in full and the others as
    their names and help lines (their modules not imported: start-up stays fast)."""
    parser = argparse.ArgumentParser(
        prog="vipm-track",
        description="Camera pitch, roll, height against the ground and planar motion from a "
        "monocular vehicle camera; filtering, smoothing and a recalibration monitor.",
    )
    parser.add_argument("--version", action="version", version="vipm-track 0.1.0")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name, (module, line) in COMMANDS.items():
        if only is None or only == name:
            importlib.import_module(f"vipm_track.commands.{module}").register(sub)
        else:
            sub.add_parser(name, help=line)
    return parser


def _command_in(argv: Sequence[str]) -> str:
    """The subcommand named in ``argv`` ("" where none is: ``--help``, ``--version``)."""
    return next((a for a in argv if a in COMMANDS), "")


#: Exit codes: 0 usable output, 1 ran but nothing usable, 2 bad input, 130 interrupted.
EXIT_OK, EXIT_NOTHING_USABLE, EXIT_BAD_INPUT, EXIT_INTERRUPTED = 0, 1, 2, 130


def _terminate(signum: int, frame: object) -> None:
    # SIGTERM ends a run as Ctrl-C does: what is decided is written, then exit 130
    raise KeyboardInterrupt


def _kept(out: object, started: float) -> str:
    """What an interrupted command leaves of its output ``out`` (a table or a folder), by
    whether this run wrote it (modified since ``started``, epoch seconds): before the first
    row (a nominal-pose search, say) it wrote nothing."""
    path = Path(out) if isinstance(out, (str, Path)) else None
    if path is None:
        return "what was written before it is complete and kept"
    if not path.exists() or path.stat().st_mtime < started - 1.0:
        return f"it came before anything was written to {path}"
    if path.is_dir():
        return f"what was written to {path} before it is complete and kept"
    return f"the rows written to {path} before it are complete and kept"


def main(argv: Sequence[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    keep_freed_memory()
    previous = signal.getsignal(signal.SIGTERM)
    try:
        signal.signal(signal.SIGTERM, _terminate)
    except ValueError:  # not the main thread (an embedding program): leave SIGTERM alone
        previous = None
    try:
        return _run(argv)
    finally:
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)


def _run(argv: list[str]) -> int:
    started = time.time()
    command = _command_in(argv)
    try:  # a command's parser imports its modules (gtsam, cantools: a second or two)
        args = build_parser(only=command).parse_args(argv)
    except KeyboardInterrupt:
        print(f"vipm-track{' ' + command if command else ''}: interrupted while starting; "
              "nothing was done", file=sys.stderr)
        return EXIT_INTERRUPTED
    name = f"vipm-track {args.command}"
    try:
        infer_inputs(args)  # first: an input found beside the images is an input too
        check_outputs_apart(args)
        return int(args.handler(args) or 0)
    except (SystemError, ImportError) as exc:
        # Ctrl-C inside a compiled kernel, or inside a lazy import of a compiled module
        # (gtsam: "ImportError: initialization failed"), comes back as one of these
        if not interrupted_in(exc):
            raise
        return _interrupted(name, args, started)
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
        return _interrupted(name, args, started)


def _interrupted(name: str, args: argparse.Namespace, started: float) -> int:
    print(f"{name}: interrupted; {_kept(getattr(args, 'out', None), started)}", file=sys.stderr)
    return EXIT_INTERRUPTED


if __name__ == "__main__":
    raise SystemExit(main())
