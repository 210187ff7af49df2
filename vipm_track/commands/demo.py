"""``vipm-track demo``: the embedded default end to end, scored against its ground truth.

Renders a short deterministic ``cart`` sequence (the paper's set-up: 800×600, h = 0.7 m,
looking 45° down, walking speed, with camera shaking) from the textures in ``data/``, runs
the estimator on it in tracking mode, prints the error table against ``gt.csv`` and writes
``DIR/estimates.csv`` and a plot ``DIR/demo.png``. Everything is callable as :func:`run_demo`.
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from ..errors import InputError
from ..estimator import EstimatorConfig
from .common import add_rerun_options, check_output_dir, check_rerun_output
from .estimate import add_estimator_options, build_config

DEMO_PRESET = "cart"
DEMO_PROFILE = "shaking"
DEMO_FRAMES = 20
DEMO_SEED = 7
DEMO_ERRORS = ("pitch_deg", "roll_deg", "distance_m", "distance_pct", "yaw_deg")


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "demo",
        help="render the embedded cart sequence, estimate it, print errors, plot",
        description=__doc__.split("\n\n")[1].replace("\n", " ").replace("``", ""),
    )
    parser.add_argument("--out", default="out/demo", metavar="DIR",
                        help="folder for the sequence, estimates.csv and demo.png "
                        "(default out/demo)")
    parser.add_argument("--frames", type=int, default=DEMO_FRAMES, metavar="N",
                        help=f"frames to render (default {DEMO_FRAMES})")
    parser.add_argument("--seed", type=int, default=DEMO_SEED, help="random seed of the scene")
    parser.add_argument("--profile", default=DEMO_PROFILE,
                        choices=("static", "gradual", "shaking", "height", "turn"),
                        help=f"camera motion profile (default {DEMO_PROFILE})")
    parser.add_argument("--no-tracking", action="store_true",
                        help="cold-start every pair")
    parser.add_argument("--quiet", action="store_true", help="no progress bars")
    add_estimator_options(parser)
    add_rerun_options(parser)
    parser.set_defaults(handler=run)


@dataclass(frozen=True)
class DemoResult:
    """What the demo produced: files, the error table (markdown), per-frame errors."""

    estimates: Path
    truth: Path
    plot: Path
    table: str
    summary: str
    errors: dict[str, NDArray]


def run(args: argparse.Namespace) -> int:
    if not 2 <= args.frames <= 2000:
        raise InputError(f"--frames must be between 2 and 2000, got {args.frames}")
    from ..sim import PRESETS

    check_output_dir(args.out)
    check_rerun_output(args)
    config = build_config(args, PRESETS[DEMO_PRESET].camera())
    result = run_demo(Path(args.out), args.frames, args.seed, args.profile, config,
                      tracking=not args.no_tracking, progress=False if args.quiet else None,
                      rerun_args=args)
    print(result.table)
    print(f"\n{result.summary}")
    print(f"wrote {result.estimates}, {result.plot}")
    return 0


def run_demo(
    out: Path,
    frames: int = DEMO_FRAMES,
    seed: int = DEMO_SEED,
    profile: str = DEMO_PROFILE,
    config=None,
    tracking: bool = True,
    progress: bool | None = None,
    rerun_args: argparse.Namespace | None = None,
) -> DemoResult:
    """Render, estimate, score and plot the demo sequence into ``out`` (see module doc);
    ``rerun_args`` (the parsed options: ``--rerun*`` log the run and its ground truth,
    ``--readout-time auto`` searches the readout on the rendered frames)."""
    from ..camera import load_camera
    from ..evaluate import error_table, frame_errors
    from ..pipeline import estimate_sequence
    from ..sim import PRESETS, simulate_sequence
    from ..sinks.rerun_sink import run_logging
    from ..sources import open_source
    from ..table import read_table
    from .inputs import with_searched_readout

    if progress is None:
        progress = sys.stderr.isatty()
    preset = PRESETS[DEMO_PRESET]
    sequence = out / "sequence"
    simulate_sequence(DEMO_PRESET, frames, sequence, seed=seed, profile=profile,
                      progress=progress)
    camera = load_camera(sequence / "camera.yaml")
    if getattr(rerun_args, "readout_time", None) == "auto":
        config = with_searched_readout(rerun_args, open_source(images=sequence / "images"),
                                       camera, preset.height_m, config or EstimatorConfig())
    estimates = out / "estimates.csv"
    logging = run_logging(rerun_args or argparse.Namespace(), "vipm-track demo",
                          open_source(images=sequence / "images"), camera, config)
    try:
        if logging.sink is not None:
            logging.sink.log_gt(read_table(sequence / "gt.csv"))
        summary = estimate_sequence(logging.source, camera, preset.height_m, estimates,
                                    logging.config, tracking=tracking, progress=progress,
                                    on_step=logging.on_step)
    finally:
        logging.finish()
    est, truth = read_table(estimates), read_table(sequence / "gt.csv")
    errors = frame_errors(est, truth)
    table = error_table(errors, tuple(n for n in DEMO_ERRORS if n in errors),
                        title=f"abs. error ({DEMO_PRESET}, {profile})")
    plot = out / "demo.png"
    plot_estimates(est, truth, plot, title=f"vipm-track demo: {DEMO_PRESET} preset, "
                   f"{profile} profile, {frames} frames")
    return DemoResult(estimates, sequence / "gt.csv", plot, table, summary.line(), errors)


def plot_estimates(est: dict, truth: dict, path: Path, title: str = "") -> None:
    """PNG with pitch, roll, travel distance and yaw per frame: estimate vs truth."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ok = est["status"] == "ok"
    fig, axes = plt.subplots(2, 2, figsize=(11, 7), sharex=True)
    panels = [
        ("pitch_deg", "pitch [deg]"), ("roll_deg", "roll [deg]"),
        ("distance_m", "travel distance per frame [m]"), ("yaw_deg", "yaw change [deg]"),
    ]
    for ax, (name, label) in zip(axes.ravel(), panels, strict=True):
        t_val = _column(truth, name)
        e_val = np.where(ok, _column(est, name), np.nan)
        ax.plot(truth["frame"], t_val, "-", color="0.3", lw=1.5, label="ground truth")
        ax.plot(est["frame"], e_val, "o", ms=3.5, color="tab:red", label="estimate")
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
    for ax in axes[1]:
        ax.set_xlabel("frame")
    axes[0, 0].legend(loc="best", fontsize=8)
    fig.suptitle(title)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=100)
    plt.close(fig)


def _column(table: dict, name: str) -> NDArray:
    if name == "distance_m":
        return np.hypot(np.asarray(table["tx_m"], float), np.asarray(table["tz_m"], float))
    return np.asarray(table[name], float)
