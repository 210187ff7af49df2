"""``vipm-track simulate``: render a synthetic ground sequence with exact ground truth."""

from __future__ import annotations

import argparse
import sys

import numpy as np

from ..errors import InputError
from ..frame_rates import FPS_RANGE_HZ
from ..measurement import MAX_SPEED_MPS
from ..render import Effects
from ..rig import MAX_ANGLE_DEG
from ..sim import PRESETS, PROFILES, clear_earlier_run, make_trajectory, simulate_sequence
from ..texture import TEXTURES
from ..traffic import LEVELS
from .common import check_output_dir
from .option_types import number, whole_number


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "simulate",
        help="render a synthetic ground sequence (images, camera.yaml, gt.csv, times.txt)",
        description="Render a camera looking at a flat ground textured with real photographs "
        "along a trajectory with exact ground truth. Writes OUT/images/000000.png…, "
        "OUT/camera.yaml (ROS camera_info), OUT/gt.csv, OUT/times.txt and OUT/speed.csv "
        "(simulated wheel speed: 50 Hz, 0.5 % noise, 0.01 km/h steps).",
    )
    p.add_argument("--preset", choices=sorted(PRESETS), default="cart",
                   help="rig: cart (800×600, h 0.7 m, pitch 45°, 10 fps), car (1280×720, "
                   "h 1.5 m, pitch 3°, 20 fps) or kitti (1241×376, h 1.65 m, pitch 1°, 10 fps)")
    p.add_argument("--frames", type=int, required=True, metavar="N", help="number of frames")
    p.add_argument("--out", required=True, metavar="DIR", help="output folder")
    p.add_argument("--seed", type=whole_number(0), default=0,
                   help="random seed (texture, pose, noise), >= 0")
    p.add_argument("--profile", choices=PROFILES, default="static", help="pose/motion profile")
    p.add_argument("--texture", choices=sorted(TEXTURES), default=None,
                   help="ground texture (default: the preset's); corridor = weak texture")
    p.add_argument("--fps", type=number(*FPS_RANGE_HZ, what="frame rate"), default=None,
                   help=f"frame rate [Hz], {FPS_RANGE_HZ[0]:g} to {FPS_RANGE_HZ[1]:g} "
                   "(default: preset)")
    p.add_argument("--speed", type=number(0, MAX_SPEED_MPS), default=None,
                   help=f"speed [m/s], 0 to {MAX_SPEED_MPS:g} (default: preset)")
    p.add_argument("--amplitude", type=number(0), default=1.0,
                   help="scale of the profile's pose changes / turn rate, >= 0 (default 1)")
    p.add_argument("--traffic", choices=LEVELS, nargs="?", const="mix", default=None,
                   metavar="LEVEL", help="drive among box-shaped vehicles on a straight road "
                   "along the start's heading: one ahead in our lane, others beside, oncoming "
                   "and parked; LEVEL light, mix (if given alone) or dense (slow city traffic; "
                   "pair with a low --speed); writes OUT/traffic.csv (vehicles' world "
                   "positions per frame); gt.csv is unchanged")
    fx = p.add_argument_group("photometric effects")
    fx.add_argument("--noise", type=number(0), default=0.0, metavar="SIGMA",
                    help="Gaussian sensor noise, grey levels")
    # a drift of 1 or more would drive the gain to zero or below: black frames
    fx.add_argument("--exposure-drift", type=number(0, 1, below=True), nargs="?", const=0.15,
                    default=0.0, metavar="AMP",
                    help="relative gain drift amplitude, below 1 (default 0.15 if given)")
    fx.add_argument("--vignetting", type=number(0, 1), nargs="?", const=0.8, default=0.0,
                    metavar="STRENGTH", help="cos⁴ vignetting strength 0..1 (0.8 if given)")
    fx.add_argument("--highlights", type=whole_number(0), nargs="?", const=3, default=0,
                    metavar="N", help="specular blobs fixed in the image (3 if given)")
    fx.add_argument("--motion-blur", type=number(0, 1), nargs="?", const=0.3, default=0.0,
                    metavar="EXPOSURE", help="exposure as a fraction of the frame interval, "
                    "0..1 (0.3 if given)")
    fx.add_argument("--readout-time", type=number(0, what="number of seconds"), default=0.0,
                    metavar="SECONDS",
                    help="rolling shutter: time from the first row's exposure to the last's, "
                    "seconds, at most the frame interval (row 0 at the frame's time; default "
                    "0: global shutter); estimate with the same --readout-time")
    fx.add_argument("--obstacle", action="store_true",
                    help="a non-ground region (wall) fixed in the image's lower right")
    p.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    if args.frames < 1:
        raise InputError(f"--frames must be ≥ 1, got {args.frames}")
    fps = args.fps or PRESETS[args.preset].fps
    if args.readout_time * fps > 1:
        raise InputError(f"--readout-time must be in [0, 1/fps] = [0, {1 / fps:g}] s, got "
                         f"{args.readout_time}")
    _check_pose_range(args)
    check_output_dir(args.out)
    effects = Effects(
        noise_sigma=args.noise, exposure_drift=args.exposure_drift, vignetting=args.vignetting,
        highlights=args.highlights, motion_blur=args.motion_blur,
        rolling_shutter=args.readout_time * fps, obstacle=args.obstacle, seed=args.seed,
    )
    removed = clear_earlier_run(args.out)
    if removed:
        print(f"vipm-track simulate: removed {removed} images of an earlier run in "
              f"{args.out}/images", file=sys.stderr)
    traj = simulate_sequence(
        args.preset, args.frames, args.out, seed=args.seed, profile=args.profile,
        effects=effects, texture=args.texture, fps=args.fps, speed=args.speed,
        amplitude=args.amplitude, progress=True, traffic=args.traffic,
    )
    print(f"wrote {len(traj)} frames to {args.out} "
          f"(images/, camera.yaml, gt.csv, times.txt, speed.csv"
          f"{', traffic.csv' if args.traffic else ''})", file=sys.stderr)
    return 0


def _check_pose_range(args: argparse.Namespace) -> None:
    """InputError where ``--amplitude`` swings the profile's pose off what a camera can be:
    at or below the ground, or pitched or rolled beyond ±``MAX_ANGLE_DEG`` (the truth is
    computed here, before any frame is rendered; it is cheap)."""
    traj = make_trajectory(args.profile, args.frames, args.fps, args.preset, args.seed,
                           args.speed, args.amplitude)
    what = f"--amplitude {args.amplitude:g} with --profile {args.profile}"
    low = int(np.argmin(traj.height))
    if not traj.height[low] > 0:
        raise InputError(f"{what} puts the camera at height {traj.height[low]:.3g} m at frame "
                         f"{low}, at or below the ground; give a smaller --amplitude")
    for name, angles in (("pitch", traj.pitch), ("roll", traj.roll)):
        worst = int(np.argmax(np.abs(angles)))
        if abs(np.degrees(angles[worst])) > MAX_ANGLE_DEG:
            raise InputError(f"{what} turns the camera to {name} "
                             f"{np.degrees(angles[worst]):.4g}° at frame {worst}, beyond "
                             f"±{MAX_ANGLE_DEG:g}°; give a smaller --amplitude")
