"""The estimator's command-line options, shared by every command that estimates pairs
(estimate, track, smooth, monitor, demo): adding them to a parser and turning the parsed
values into an ``EstimatorConfig`` and parallel-run settings."""

from __future__ import annotations

import argparse
import math
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from ..camera import CameraModel
from ..errors import InputError
from ..estimator_config import MAX_REFINEMENTS, REFINEMENT_WEIGHTING
from ..rig import DEFAULT_PITCH_DEG, MAX_READOUT_S, PITCH_RANGE_DEG, Rig
from ..text_files import read_text
from .common import seconds_or_auto
from .option_types import whole_number

#: ``--refinement-weights`` → EstimatorConfig fields ("auto": the estimator's per-camera
#: default)
REFINEMENT_WEIGHTS: dict[str, dict[str, object]] = {
    "auto": {}, **REFINEMENT_WEIGHTING,
}


#: ``--refinement-resolution`` → ``EstimatorConfig.ipm_poc_level``
REFINEMENT_RESOLUTION: dict[str, int] = {"full": 0, "half": 1}


#: dest → option of every estimator and parallel option, with its default: with
#: ``--estimates`` none of them is used (:func:`check_no_estimating_options`)
ESTIMATING_OPTIONS: dict[str, tuple[str, Any]] = {}


class _Recorded:
    """An argument group whose options are recorded in :data:`ESTIMATING_OPTIONS`."""

    def __init__(self, group: argparse._ArgumentGroup) -> None:
        self._group = group

    def add_argument(self, *flags: str, **kwargs: Any) -> argparse.Action:
        action = self._group.add_argument(*flags, **kwargs)
        ESTIMATING_OPTIONS[action.dest] = (action.option_strings[0], action.default)
        return action


def check_no_estimating_options(args: argparse.Namespace) -> None:
    """InputError naming the estimator options given with ``--estimates``: the table's rows
    are taken as they are, and a ``--max-roll 1`` meant to drop rows did nothing, silently."""
    given = [flag for dest, (flag, default) in ESTIMATING_OPTIONS.items()
             if getattr(args, dest, default) != default]
    if given:
        raise InputError(f"{', '.join(given)}: estimator options, for --images/--video; "
                         "with --estimates the table's rows are taken as they are (drop "
                         f"{'them' if len(given) > 1 else 'it'}, or estimate again)")


def add_estimator_options(parser: argparse.ArgumentParser) -> None:
    """Estimator options shared by ``estimate``, ``demo`` and the benchmarks."""
    group = _Recorded(parser.add_argument_group("estimator"))
    group.add_argument("--roi", metavar="x0,y0,x1,y1|FILE",
                       help="where the ground is: a pixel rectangle x0,y0,x1,y1, a polygon "
                       "file (x y per line) or a mask image (non-zero = ground); "
                       "default: the estimator's")
    group.add_argument("--refinements", type=int, default=None, metavar="N",
                       help="virtual-IPM refinement passes (default: the estimator's, 2 for level "
                       "cameras (horizon in view, pitch < 10°), 1 for all others)")
    group.add_argument("--grid", default=None, metavar="COLSxROWS",
                       help="patch grid, e.g. 11x9 (default: the estimator's)")
    group.add_argument("--patch-size", type=int, default=None, metavar="PX",
                       help="largest image-plane patch size in pixels, a multiple of 16 "
                       "(default: the estimator's, 128)")
    group.add_argument("--pitch", type=float, default=None, metavar="DEG",
                       help="nominal pitch for the cold start, degrees, > 0 looking down "
                       "(default: the estimator's, 60; give ~0-5 for forward cameras)")
    group.add_argument("--roll", type=float, default=None, metavar="DEG",
                       help="nominal roll for the cold start, degrees (default 0)")
    group.add_argument("--max-roll", type=float, default=None, metavar="DEG",
                       help="plausible roll of the camera about --roll (or level), degrees: "
                       "pairs and nominal-pose searches that fit a roll beyond it are "
                       "rejected (default 10)")
    group.add_argument("--max-acceleration", type=float, default=None, metavar="M/S²",
                       help="the vehicle's largest acceleration, m/s²: an ok pair whose velocity "
                       "on the ground differs from that of the last ok pair which agreed with "
                       "the one before it (within 1 s) by more than it allows, plus three "
                       "standard deviations, gets status 'implausible motion' (default 10, "
                       "about 1 g; 'inf' turns it off)")
    group.add_argument("--long-baseline", type=float, default=None, metavar="HEIGHTS",
                       help="a level camera's pair that travels less than this many camera "
                       "heights also reads frame k's pose against an earlier frame that far "
                       "back (up to 5 frames, 1 s), where the pitch no longer trades against "
                       "a short travel (default 0.3; 0 turns it off; docs/kitti.md, 'Slow "
                       "driving')")
    group.add_argument("--pose-prior-deg", type=float, default=None, metavar="DEG",
                       help="standard deviation of a prior on pitch and roll around "
                       "--pitch/--roll inside the fit, degrees; resolves the pitch/travel "
                       "ambiguity of near-level cameras; 0 turns it off (default: the "
                       "estimator's, 2 for level cameras (horizon in view, pitch < 10°), off for "
                       "others)")
    group.add_argument("--vertical-motion", action=argparse.BooleanOptionalAction,
                       default=None,
                       help="estimate the camera's vertical motion within a pair (an 8th "
                       "parameter; default: on for steep cameras, off for level ones, where "
                       "it trades against pitch; turn it on for a body that bounces much "
                       "per frame; docs/kitti.md)")
    group.add_argument("--readout-time", type=seconds_or_auto, default=None,
                       metavar="SECONDS|auto",
                       help="rolling shutter: time from the exposure of the image's first row "
                       "to its last, seconds (a CMOS dashcam's is 10-35 ms; see the sensor's "
                       "datasheet), or 'auto': found from pairs that move in the first 300 "
                       "frames (the readout whose fit leaves the smallest residual, printed "
                       "with its uncertainty, ~25 s; where the residual shows no clear dip, a "
                       "warning and a global shutter); the fit then gives each patch the motion "
                       "over its rows' exposure times. Default: a global shutter, with a warning "
                       "where a 20 ms readout would move this drive's pitch, roll or travel "
                       "(on a rendered car at 0.6 m per frame a 33 ms readout left unmodelled "
                       "biases pitch by -0.4 deg and distance by +6.5 %%); 0 says the "
                       "shutter is global")
    group.add_argument("--subset-seed", type=int, default=None, metavar="N",
                       help="seed of the random-subset sampler (default: the estimator's, 0); "
                       "a run is deterministic for a given seed, and another seed shows how "
                       "much a result owes to the subsets drawn")
    group.add_argument("--refinement-resolution", choices=tuple(REFINEMENT_RESOLUTION),
                       default="full",
                       help="resolution of the virtual-IPM patches' correlation: 'half' "
                       "correlates on the bird's-eye planes halved (the same frequencies of "
                       "the road, a quarter of the pixels): faster, a little less accurate (what "
                       "it costs: docs/speed.md); 'full' (default) for the most accurate "
                       "estimates")
    group.add_argument("--refinement-weights", choices=tuple(REFINEMENT_WEIGHTS),
                       default="auto",
                       help="virtual-IPM patches in the refinement fit: 'noise' weights each "
                       "by its modelled noise, re-centres the POC windows on the measured "
                       "shift and tightens the inlier threshold to the residuals; 'uniform' "
                       "is the paper's (all alike); 'auto' (default): uniform for level "
                       "cameras (horizon in view, pitch < 10°), noise for all others")


def add_parallel_options(parser: argparse.ArgumentParser) -> None:
    """``--workers``, ``--chunk-frames``: a long recording estimated in parallel chunks."""
    group = _Recorded(parser.add_argument_group("parallel (long recordings)"))
    group.add_argument("--workers", type=int, default=1, metavar="N",
                       help="processes that estimate chunks of the recording in parallel "
                       "(default 1: one sequential run); results depend on --chunk-frames, "
                       "not on N")
    group.add_argument("--chunk-frames", type=int, default=None, metavar="K",
                       help="frames per chunk (default with --workers > 1: 500; given with "
                       "--workers 1, the same chunks run one after another); each chunk's "
                       "first pair starts cold, as after a failed pair")
    group.add_argument("--threads", type=whole_number(1), default=None, metavar="T",
                       help="threads of one pair's work: its patches' correlation and its "
                       "random subsets' LM, and with T > 1 the next frame read ahead (default: "
                       "2, or the machine's cores if fewer); with --workers > 1 each process "
                       "uses one and T has no effect; the estimates do not depend on it")


def parallel_settings(args: argparse.Namespace) -> dict[str, Any]:
    """``workers`` and ``chunk_frames`` of ``args`` for ``estimate_sequence`` /
    ``sequence_steps``, and this process's patch-correlation threads set from ``--threads``;
    InputError for unusable values (and for ``--rerun`` with workers)."""
    from ..parallel import MIN_CHUNK_FRAMES
    from ..workers import set_threads
    from .rerun_options import wants_rerun

    workers = getattr(args, "workers", 1)
    chunk = getattr(args, "chunk_frames", None)
    threads = getattr(args, "threads", None)
    if workers < 1:
        raise InputError(f"--workers must be >= 1, got {workers}")
    if threads is not None:
        set_threads(threads)
    if chunk is not None and chunk < MIN_CHUNK_FRAMES:
        raise InputError(f"--chunk-frames must be >= {MIN_CHUNK_FRAMES}, got {chunk}")
    if workers > 1 and wants_rerun(args):
        raise InputError("--rerun logs the frames as they are estimated: use it with --workers 1")
    return {"workers": workers, "chunk_frames": chunk}


def build_config(args: argparse.Namespace, camera: CameraModel):
    """The estimator configuration from the estimator options of ``args``."""
    from ..estimator_config import EstimatorConfig
    from ..pipeline import config_with

    grid = parse_grid(args.grid) if args.grid else None
    if args.refinements is not None and not 0 <= args.refinements <= MAX_REFINEMENTS:
        raise InputError(f"--refinements must be between 0 and {MAX_REFINEMENTS}, got "
                         f"{args.refinements}")
    if args.patch_size is not None and (args.patch_size < 32 or args.patch_size % 16):
        raise InputError(f"--patch-size must be a multiple of 16, >= 32, got {args.patch_size}")
    max_roll = _angle(getattr(args, "max_roll", None), "--max-roll", 0.1, 90.0)
    prior = getattr(args, "pose_prior_deg", None)
    if prior is not None and not (math.isfinite(prior) and 0 <= prior <= 45):
        raise InputError(f"--pose-prior-deg must be in [0, 45] degrees, got {prior}")
    max_accel = getattr(args, "max_acceleration", None)
    if max_accel is not None and not max_accel > 0:  # (NaN too)
        raise InputError(f"--max-acceleration must be > 0 m/s², got {max_accel}")
    long_baseline = getattr(args, "long_baseline", None)
    if long_baseline is not None and not 0 <= long_baseline < 10:  # (NaN too)
        raise InputError(f"--long-baseline must be in [0, 10) camera heights, got "
                         f"{long_baseline}")
    roi = parse_roi(args.roi, camera) if args.roi else None
    seed = getattr(args, "subset_seed", None)
    if seed is not None and seed < 0:
        raise InputError(f"--subset-seed must be >= 0, got {seed}")
    return config_with(
        EstimatorConfig(),
        grid=grid,
        refinements=args.refinements,
        patch_image=args.patch_size,
        max_roll_deg=max_roll,
        max_acceleration_mps2=max_accel,
        long_baseline_heights=long_baseline,
        roi=roi,
        vertical_motion=args.vertical_motion,
        pose_prior_deg=prior,
        seed=seed,
        ipm_poc_level=REFINEMENT_RESOLUTION[getattr(args, "refinement_resolution", "full")],
        **REFINEMENT_WEIGHTS[getattr(args, "refinement_weights", "auto")],
    )


def build_rig(
    args: argparse.Namespace, camera: CameraModel, height: float,
    pitch_deg: float | None = None, roll_deg: float | None = None,
) -> Rig:
    """``camera`` at ``height`` [m] with the nominal pose and readout of the options in
    ``args``: ``--pitch``/``--roll`` where given, else ``pitch_deg``/``roll_deg`` (a nominal
    calibration's), else ``rig.DEFAULT_PITCH_DEG`` and level; ``--readout-time`` (``auto``: a
    global shutter until searched, ``commands.inputs.with_searched_setup``)."""
    pitch = _angle(getattr(args, "pitch", None), "--pitch", *PITCH_RANGE_DEG)
    roll = _angle(getattr(args, "roll", None), "--roll", -45.0, 45.0)
    readout = getattr(args, "readout_time", None)
    if readout is None or readout == "auto":
        readout = 0.0
    if not (math.isfinite(readout) and 0 <= readout <= MAX_READOUT_S):
        raise InputError(f"--readout-time must be in [0, {MAX_READOUT_S:g}] seconds, got "
                         f"{readout}")
    return Rig(camera, height,
               next(p for p in (pitch, pitch_deg, DEFAULT_PITCH_DEG) if p is not None),
               next(r for r in (roll, roll_deg, 0.0) if r is not None), float(readout))


def _angle(value: float | None, option: str, low: float, high: float) -> float | None:
    if value is None:
        return None
    if not (math.isfinite(value) and low <= value <= high):
        raise InputError(f"{option} must be in [{low}, {high}] degrees, got {value}")
    return float(value)


def parse_grid(text: str) -> tuple[int, int]:
    """``"11x9"`` → (11, 9) (columns, rows)."""
    parts = text.lower().replace("×", "x").split("x")
    try:
        cols, rows = (int(p) for p in parts)
    except ValueError as exc:
        raise InputError(f"--grid must look like 11x9 (columns x rows), got {text!r}") from exc
    if cols < 2 or rows < 2:
        raise InputError(f"--grid needs at least 2x2 patches, got {text!r}")
    return cols, rows


def parse_roi(text: str, camera: CameraModel) -> NDArray[np.bool_]:
    """Ground mask (H, W) of the camera's image from ``--roi``: a rectangle ``x0,y0,x1,y1``
    in pixels, a polygon file (one ``x y`` or ``x,y`` vertex per line, pixels) or a mask
    image of the camera's size (non-zero = ground)."""
    shape = (camera.height, camera.width)
    path = Path(text)
    if not path.exists():
        parts = text.split(",")
        if len(parts) != 4:
            raise InputError(
                f"--roi {text!r}: neither a file nor a rectangle x0,y0,x1,y1 in pixels"
            )
        try:
            x0, y0, x1, y1 = (float(p) for p in parts)
        except ValueError as exc:
            raise InputError(f"--roi {text!r}: rectangle values must be numbers") from exc
        if not (0 <= x0 < x1 <= camera.width and 0 <= y0 < y1 <= camera.height):
            raise InputError(
                f"--roi {text!r}: need 0 <= x0 < x1 <= {camera.width} and "
                f"0 <= y0 < y1 <= {camera.height} (the camera image)"
            )
        mask = np.zeros(shape, bool)
        mask[round(y0):round(y1), round(x0):round(x1)] = True
        return mask
    image = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE) if path.suffix.lower() in {
        ".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".pgm"} else None
    if image is not None:
        if image.shape != shape:
            raise InputError(
                f"--roi {path}: mask is {image.shape[1]}×{image.shape[0]} px but the camera "
                f"image is {camera.width}×{camera.height} px"
            )
        mask = image > 0
    else:
        mask = _polygon_mask(path, shape)
    if mask.sum() < 0.01 * mask.size:
        raise InputError(f"--roi {path}: the region covers less than 1 % of the image")
    return mask


def _polygon_mask(path: Path, shape: tuple[int, int]) -> NDArray[np.bool_]:
    vertices = []
    for lineno, line in enumerate(read_text(path).splitlines(), start=1):
        text = line.split("#", 1)[0].replace(",", " ").split()
        if not text:
            continue
        try:
            x, y = float(text[0]), float(text[1])
        except (ValueError, IndexError) as exc:
            raise InputError(f"--roi {path}: line {lineno}: expected 'x y' in pixels") from exc
        # as for the rectangle: a vertex off the image is a polygon drawn on another size
        if not (0 <= x <= shape[1] and 0 <= y <= shape[0]):
            raise InputError(f"--roi {path}: line {lineno}: vertex ({x:g}, {y:g}) lies off the "
                             f"camera image: need 0 <= x <= {shape[1]} and 0 <= y <= {shape[0]}")
        vertices.append([x, y])
    if len(vertices) < 3:
        raise InputError(f"--roi {path}: a polygon needs at least 3 vertices, got {len(vertices)}")
    mask = np.zeros(shape, np.uint8)
    cv2.fillPoly(mask, [np.round(np.asarray(vertices)).astype(np.int32)], 1)
    return mask.astype(bool)
