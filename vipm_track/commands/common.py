"""Option groups shared by subcommands, so every subcommand spells them the same way."""

from __future__ import annotations

import argparse
import math
import sys
import tempfile
from pathlib import Path

import numpy as np

from ..errors import InputError, os_error_line


def add_input_options(parser: argparse.ArgumentParser, required: bool = True,
                      bag: bool = False) -> None:
    """``--images DIR | --video FILE`` (``| --bag PATH`` with its topics where ``bag``) and
    ``--fps``."""
    group = parser.add_mutually_exclusive_group(required=required)
    group.add_argument("--images", metavar="DIR", help="folder of images sorted by name "
                       "(timestamps from times.txt in it or its parent, else --fps)")
    group.add_argument("--video", metavar="FILE", help="any video OpenCV reads")
    if bag:
        group.add_argument("--bag", metavar="PATH", help="a ROS 1 .bag, a rosbag2 folder or "
                           "an .mcap file with an image topic (times from the headers)")
        parser.add_argument("--image-topic", metavar="TOPIC", help="the bag's image topic "
                            "(default: its first Image / CompressedImage topic)")
        parser.add_argument("--camera-info-topic", metavar="TOPIC", help="the bag's "
                            "CameraInfo topic, read where --camera is not given (default: "
                            "its first)")
    parser.add_argument("--fps", type=float, default=None,
                        help="frame rate for timestamps when the input has none [Hz]")


def add_camera_options(
    parser: argparse.ArgumentParser, height_required: bool = True, camera_required: bool = True
) -> None:
    """``--camera`` (intrinsics file) and ``--height`` (nominal camera height, metres)."""
    parser.add_argument("--camera", metavar="CAMERA.yaml", required=camera_required,
                        help="intrinsics: ROS camera_info YAML, OpenCV FileStorage YAML or "
                        "KITTI calib.txt (default: camera.yaml or calib.txt in or beside the "
                        "--images folder)")
    parser.add_argument("--height", type=float, required=height_required, metavar="H",
                        help="nominal camera height above the ground [m]")


def add_filter_inputs(parser: argparse.ArgumentParser, verb: str,
                      height_required: bool = True) -> None:
    """Where a filtering subcommand's pairs come from: a recording (``--images``/``--video``
    with ``--camera``, estimated on the fly) or ``--estimates EST.csv``; ``--height``; the
    wheel-speed group. ``verb`` says what the command does with them (help text)."""
    add_input_options(parser, required=False)
    parser.add_argument("--estimates", metavar="EST.csv",
                        help=f"skip estimation: {verb} this estimates table (written by "
                        "'vipm-track estimate') instead of --images/--video")
    add_camera_options(parser, height_required=height_required, camera_required=False)
    parser.add_argument("--start", type=int, default=0, metavar="K",
                        help="first frame index to use (default 0)")
    parser.add_argument("--max-frames", type=int, default=None, metavar="N",
                        help="use at most N frames from --start")
    add_speed_options(parser)


#: intrinsics files looked for beside an image folder (in it, then in its parent), in order
CAMERA_FILES: tuple[str, ...] = ("camera.yaml", "camera.yml", "camera_info.yaml", "calib.txt")


def camera_beside(images: str | Path) -> Path | None:
    """The intrinsics file that sits with an image folder (``CAMERA_FILES`` in it, then in
    its parent: the simulator's ``camera.yaml`` beside ``images/``, KITTI's ``calib.txt``
    beside ``image_0/``); None where there is none."""
    folder = Path(images)
    for place in (folder, folder.parent):
        for name in CAMERA_FILES:
            if (place / name).is_file():
                return place / name
    return None


def height_of_table(path: str | Path) -> float | None:
    """The camera height an estimates table was made with: the median of its ``height_m``
    column [m]; None where it has none. InputError where the table has no rows (the reading
    that follows would say so too, after this one had blamed the missing height)."""
    from ..table import read_table

    table = read_table(path, quiet=True)  # the table is read again for its rows: named there
    if not len(table.get("frame", [])):
        raise InputError(f"{path}: no rows")
    heights = np.asarray(table.get("height_m", []), dtype=float)
    heights = heights[np.isfinite(heights) & (heights > 0)]
    return float(np.median(heights)) if heights.size else None


def check_images_folder(args: argparse.Namespace) -> None:
    """``--images`` (where given) as an existing folder: named as such before the camera is
    looked for beside it (a missing folder was reported as a missing ``--camera``)."""
    images = getattr(args, "images", None)
    if isinstance(images, (str, Path)) and images and not Path(images).is_dir():
        what = "is a file; give the folder of the images" if Path(images).exists() else \
            "no such folder"
        raise InputError(f"--images {images}: {what}")


#: what the filter commands read their pairs from, one of them
ONE_INPUT = "give exactly one of --estimates EST.csv, --images DIR, --video FILE"


def infer_inputs(args: argparse.Namespace) -> None:
    """Fill in what the data already says where the user left it out (said on stderr unless
    ``--quiet``): ``--camera`` from the file beside ``--images``; ``--height`` of ``track`` and
    ``smooth`` from the ``--estimates`` table's ``height_m``. A filter command without any
    input says so first (not that its height is missing)."""
    quiet = getattr(args, "quiet", False)
    command = f"vipm-track {getattr(args, 'command', '')}".strip()
    if getattr(args, "command", None) in ("track", "smooth", "monitor") and not any(
            getattr(args, name, None) for name in ("estimates", "images", "video")):
        raise InputError(ONE_INPUT)
    images = getattr(args, "images", None)
    if hasattr(args, "camera") and not args.camera and images and Path(images).is_dir():
        found = camera_beside(images)
        if found is not None:
            args.camera = str(found)
            if not quiet:
                print(f"{command}: --camera {found} (found beside the images)", file=sys.stderr)
    if (getattr(args, "command", None) in ("track", "smooth") and args.height is None
            and getattr(args, "estimates", None)):
        args.height = height_of_table(args.estimates)
        if args.height is None:
            raise InputError(f"--height not given and {args.estimates} has no height_m to take "
                             "it from; give --height")
        if not quiet:
            print(f"{command}: --height {args.height:g} (the height {args.estimates} was "
                  "estimated with)", file=sys.stderr)


#: options naming what a command reads, and what it writes (``--parquet``: beside ``--out``)
_INPUT_OPTIONS = ("estimates", "images", "video", "bag", "camera", "can", "dbc", "gt",
                  "nominal", "speed_csv", "frame_times", "roi", "log", "table", "drives")
_OUTPUT_OPTIONS = ("out", "events", "rerun", "summary")
#: inputs that are folders (a bag may be a rosbag2 folder); any other input given as a
#: folder is the wrong input, which its reader names, not a folder of inputs
_FOLDER_INPUTS = ("images", "bag", "drives")


def _option(name: str) -> str:
    return f"--{name.replace('_', '-')}" if name not in ("log", "table", "drives") else name.upper()


def _implicit_inputs(args: argparse.Namespace) -> list[tuple[str, Path]]:
    """Inputs read without an option naming them: the ``times.txt`` of ``--images``."""
    images = getattr(args, "images", None)
    if not isinstance(images, (str, Path)) or not images:
        return []
    folder = Path(images)
    return [("images", times) for times in (folder / "times.txt", folder.parent / "times.txt")
            if times.is_file()]


def _outputs(args: argparse.Namespace) -> list[tuple[str, Path]]:
    """Every file a command writes that an option names or implies: ``--parquet`` beside
    ``--out``, ``smooth``'s summary (JSON and Markdown, default beside ``--out``)."""
    outputs = [(name, Path(value)) for name in _OUTPUT_OPTIONS
               if isinstance(value := getattr(args, name, None), (str, Path)) and value]
    out = getattr(args, "out", None)
    if getattr(args, "parquet", None) is True and out:
        outputs.append(("parquet", Path(out).with_suffix(".parquet")))
    if getattr(args, "command", None) == "smooth" and out:
        summary = Path(args.summary) if args.summary else Path(out).with_suffix(".summary.json")
        if summary.suffix.lower() == ".md":
            raise InputError(f"--summary {summary}: names the JSON summary (its Markdown goes "
                             "beside it, as .md); give FILE.json")
        outputs = [o for o in outputs if o[0] != "summary"]
        outputs += [("summary", summary), ("summary", summary.with_suffix(".md"))]
    return outputs


def check_outputs_apart(args: argparse.Namespace) -> None:
    """InputError where an output would overwrite an input: the same file (``smooth
    --estimates x.csv --out x.csv`` replaced the table it read), a file of an input folder
    (a frame of ``--images``) or one read beside it (its ``times.txt``); or where two outputs
    are one file (``--out x.csv --rerun x.csv`` interleaved a table and a recording)."""
    inputs = [(name, Path(value)) for name in _INPUT_OPTIONS
              if isinstance(value := getattr(args, name, None), (str, Path)) and value
              and Path(value).exists()] + _implicit_inputs(args)
    outputs = _outputs(args)
    for i, (name_a, a) in enumerate(outputs):
        for name_b, b in outputs[i + 1:]:
            if a.resolve() == b.resolve():
                raise InputError(f"{_option(name_a)} {a} and {_option(name_b)} {b} are the same "
                                 "file; give each output its own path")
    for out_name, out in outputs:
        if not out.exists():
            continue
        for in_name, given in inputs:
            same = out.samefile(given)
            if same or (given.is_dir() and in_name in _FOLDER_INPUTS and not out.is_dir()
                        and given.resolve() in out.resolve().parents):
                what = "is" if same else "is a file of"
                raise InputError(f"{_option(out_name)} {out}: {what} the input {_option(in_name)} "
                                 f"{given}; writing it would destroy the input, give another path")


def frame_window(items: list, frame_of, start: int, max_frames: int | None,
                 source: str = "the input") -> list:
    """The ``items`` whose frame (``frame_of(item)``) is at least ``start``, at most
    ``max_frames`` of them (``--start`` / ``--max-frames``; InputError for negative values
    and for a ``start`` beyond every item of ``source``)."""
    if start < 0 or (max_frames is not None and max_frames < 1):
        raise InputError(f"--start must be >= 0 and --max-frames >= 1, got {start} and "
                         f"{max_frames}")
    kept = [item for item in items if frame_of(item) >= start]
    if items and not kept:
        raise InputError(f"{source}: no rows from frame {start} (--start); its frames are "
                         f"{frame_of(items[0])}..{frame_of(items[-1])}")
    return kept if max_frames is None else kept[:max_frames]


def check_height(height: float | None) -> float:
    """``--height`` as a positive number of metres (InputError otherwise)."""
    if height is None:
        raise InputError("--height is needed: the camera's height above the ground, metres")
    if not (math.isfinite(height) and height > 0):
        raise InputError(f"--height must be a positive number of metres, got {height}")
    return float(height)


def check_output(out: str, parquet: bool = False, option: str = "--out") -> Path:
    """``--out`` as a CSV path that can be written: not a folder, not a .parquet name
    (``--parquet`` writes the Parquet beside the CSV, checked too where ``parquet``)."""
    path = Path(out)
    if path.is_dir():
        raise InputError(f"{option} {out}: is a folder; give a CSV file name")
    if path.suffix.lower() == ".parquet":
        raise InputError(f"{option} {out}: give a .csv name; --parquet writes the Parquet "
                         "beside it")
    check_writable(path, option)
    beside = path.with_suffix(".parquet")
    if parquet:
        check_writable(beside, "--parquet")
    elif beside.is_file():
        # a reader of the Parquet would take an earlier run for this one
        print(f"vipm-track: warning: {beside} is from an earlier run; this run writes {path} "
              "only (give --parquet to write both)", file=sys.stderr)
    return path


def check_writable(path: str | Path, option: str) -> Path:
    """``path`` as a file this run can create or overwrite, checked before any work: its
    folder is created, the file opened for appending (and removed again where it did not
    exist). InputError naming the option, the path and the OS reason otherwise."""
    path = Path(path)
    if path.is_dir():
        raise InputError(f"{option} {path}: is a folder; give a file name")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputError(f"{option} {path}: cannot create its folder: "
                         f"{os_error_line(exc)}") from None
    existed = path.exists()
    try:
        with path.open("a"):
            pass
        if not existed:
            path.unlink()
    except OSError as exc:
        raise InputError(f"{option} {path}: cannot be written: {os_error_line(exc)}") from None
    return path


def check_output_dir(out: str | Path, option: str = "--out") -> Path:
    """``out`` as a folder this run can write into (created where missing); InputError naming
    the option, the folder and the OS reason otherwise."""
    path = Path(out)
    if path.exists() and not path.is_dir():
        raise InputError(f"{option} {path}: is a file; give a folder")
    try:
        path.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryFile(dir=path):
            pass
    except OSError as exc:
        raise InputError(f"{option} {path}: cannot write into this folder: "
                         f"{os_error_line(exc)}") from None
    return path


def check_rerun_output(args: argparse.Namespace) -> None:
    """``--rerun OUT.rrd`` (where given) as a file this run can write (:func:`check_writable`)
    and its image options, before any work."""
    if getattr(args, "rerun", None):
        from ..sinks.rerun_sink import check_image_options

        check_image_options(getattr(args, "rerun_image_every", None),
                            getattr(args, "rerun_jpeg_quality", 75))
        check_writable(args.rerun, "--rerun")


def add_output_options(parser: argparse.ArgumentParser, what: str = "per-frame CSV") -> None:
    """``--out``, ``--parquet`` and ``--columns``."""
    parser.add_argument("--out", required=True, metavar="OUT.csv", help=f"{what} to write")
    parser.add_argument("--parquet", action="store_true",
                        help="also write the table as Parquet beside the CSV")
    add_columns_option(parser)


def add_columns_option(parser: argparse._ActionsContainer) -> None:
    """``--columns all|concise|A,B,...``: which columns the per-frame tables carry
    (``vipm_track.table.choose_columns`` checks the names)."""
    parser.add_argument("--columns", default="concise", metavar="all|concise|A,B,...",
                        help="the table's columns: 'concise' (default: pose, motion, "
                        "calibration with their std, status, and every column another "
                        "vipm-track command reads back), 'all', or a comma-separated list "
                        "(the conventions' first columns are always written)")


def add_speed_options(parser: argparse.ArgumentParser) -> None:
    """Wheel speed: ``--speed-csv`` or ``--can LOG --dbc DBC --signals ...``."""
    group = parser.add_argument_group("wheel speed (makes the camera height observable)")
    group.add_argument("--speed-csv", metavar="FILE", help="CSV with columns t,speed_mps")
    group.add_argument("--can", metavar="LOG", help="CAN log (.log/.asc/.blf/.trc/.csv/.mf4)")
    add_can_decoding_options(group)


def add_can_decoding_options(group: argparse._ActionsContainer, dbc_required: bool = False,
                             ) -> None:
    """How CAN frames become a speed: ``--dbc``, ``--signals``, ``--combine``,
    ``--can-channel``, ``--speed-scale``, ``--clock-offset`` (shared by every subcommand that
    reads CAN, so they are spelled and default alike)."""
    group.add_argument("--dbc", metavar="DBC", required=dbc_required,
                       help="DBC file decoding the CAN frames")
    group.add_argument("--signals", metavar="MSG.SIG[:UNIT][,MSG.SIG...]",
                       help="speed signal(s) (default: the DBC's rear wheel speeds); several "
                       "are combined by --combine; :UNIT overrides the DBC's unit (km/h, m/s, "
                       "mph)")
    group.add_argument("--combine", default="mean", choices=("mean", "median", "min", "max"),
                       help="rule combining several speed signals (default: mean)")
    group.add_argument("--can-channel", metavar="CH", default=None,
                       help="only use frames from this CAN channel, as the summary's "
                            "'channels:' line names them (python-can's numbering: a Vector "
                            ".asc/.blf's channel 1 is 0, a PCAN .trc's 1 is 1; can0 also "
                            "matches 0)")
    group.add_argument("--speed-scale", type=float, default=1.0,
                       help="scale factor on the speed (tyre-radius correction)")
    group.add_argument("--clock-offset", type=seconds_or_auto, default=0.0,
                       metavar="SECONDS|auto",
                       help="seconds added to the speed timestamps to reach the camera clock, "
                       "or 'auto': found from the data (the wheel's distance over each frame "
                       "interval against the pair's travel; needs the speed to change while "
                       "the camera runs, and is printed with its uncertainty). Default 0")


def seconds_or_auto(text: str) -> float | str:
    """``--clock-offset``, ``--readout-time``: a number of seconds or ``auto``."""
    if text.strip().lower() == "auto":
        return "auto"
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected seconds or 'auto', got {text!r}") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"expected a finite number of seconds, got {text!r}")
    return value


def add_rerun_options(parser: argparse.ArgumentParser) -> None:
    """``--rerun OUT.rrd``, ``--rerun-spawn``, ``--rerun-connect ADDR`` (any combination) and
    the image decimation/quality of the recording (``vipm_track.sinks.rerun_sink``)."""
    group = parser.add_argument_group("rerun dashboard")
    group.add_argument("--rerun", metavar="OUT.rrd", help="write a rerun recording")
    group.add_argument("--rerun-spawn", action="store_true", help="spawn a rerun viewer")
    group.add_argument("--rerun-connect", metavar="ADDR", help="stream to a running viewer")
    images = group.add_mutually_exclusive_group()
    images.add_argument("--rerun-image-every", type=int, default=None, metavar="N",
                        help="log the camera/IPM images of every N-th pair (0: none). Default: "
                        "one pair's images every 2 s of the recording (every 20th pair without "
                        "timestamps), so an hour of a 30 fps camera costs under 1 GB")
    images.add_argument("--rerun-all-images", action="store_true",
                        help="log every pair's images (several GB per hour of video)")
    group.add_argument("--rerun-jpeg-quality", type=int, default=75, metavar="Q",
                       help="JPEG quality of logged images, 1-100 (default 75)")
