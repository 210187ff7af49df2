"""``vipm-track fleet``: every drive of a folder or manifest estimated, smoothed, summarised
and monitored as Dask tasks; hive-partitioned Parquet, a fleet summary and a report."""

from __future__ import annotations

import argparse
from pathlib import Path

from ..errors import InputError, NothingUsable
from .common import add_columns_option, check_output_dir


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "fleet",
        help="many logged drives on Dask: estimate, smooth, summarise and monitor each; "
        "partitioned Parquet and a fleet report",
        description="Process every drive of DRIVES (a folder with one subfolder per drive, "
        "or a manifest CSV; docs/fleet.md) as one Dask task each, on a local cluster or an "
        "existing scheduler: estimate every pair (seeded at the drive's nominal.yaml), smooth "
        "the drive, summarise its mount with 95 % intervals and monitor it against its "
        "nominal. Writes OUT/drive=NAME/{estimates,smoothed,monitor}.parquet, "
        "OUT/fleet_summary.csv/.parquet and OUT/fleet_report.md/.png. Drives already done "
        "with the same inputs and settings are skipped.",
    )
    parser.add_argument("drives", metavar="DRIVES", help="folder of drive folders, or a "
                        "manifest CSV")
    parser.add_argument("--out", required=True, metavar="OUT", help="output folder")
    group = parser.add_argument_group("cluster")
    where = group.add_mutually_exclusive_group()
    where.add_argument("--workers", type=int, default=2, metavar="N",
                       help="worker processes of the local cluster (default 2)")
    where.add_argument("--scheduler", metavar="ADDRESS",
                       help="use a running Dask scheduler (tcp://host:8786) instead")
    group.add_argument("--retries", type=int, default=2, metavar="N",
                       help="times a drive is run again after its worker died (default 2)")
    group = parser.add_argument_group("drives")
    group.add_argument("--vehicle", choices=("car", "cart"), default="car",
                       help="noise preset of the smoother (default: car)")
    group.add_argument("--lag", type=float, default=0.0, metavar="SECONDS",
                       help="smoother window; 0 = each drive at once (default)")
    group.add_argument("--chunk-frames", type=int, default=None, metavar="N",
                       help="estimate a drive in chunks of N frames, as estimate does")
    group.add_argument("--no-std", action="store_true",
                       help="skip the smoother's marginal covariances (faster)")
    group.add_argument("--image-topic", metavar="TOPIC", help="a bag's image topic "
                       "(default: its first Image / CompressedImage topic)")
    group.add_argument("--camera-info-topic", metavar="TOPIC", help="a bag's CameraInfo "
                       "topic (default: its first), where the drive has no camera.yaml")
    group.add_argument("--speed-topic", metavar="TOPIC", help="a bag's twist / odometry "
                       "topic (default: its first, if any), where the drive has no speed.csv")
    add_columns_option(group)
    parser.add_argument("--quiet", action="store_true", help="no progress")
    parser.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    from ..fleet.cluster import run_fleet, scheduler_address
    from ..fleet.drive_run import FleetSettings
    from ..fleet.drives import find_drives
    from ..sinks.fleet_report import write_fleet_report

    if args.workers < 1 or args.retries < 0:
        raise InputError(f"--workers must be >= 1 and --retries >= 0, got {args.workers} and "
                         f"{args.retries}")
    if args.scheduler is not None:
        scheduler_address(args.scheduler)
    drives = Path(args.drives).resolve()
    if drives.is_dir() and drives in Path(args.out).resolve().parents:
        raise InputError(f"--out {args.out}: inside the DRIVES folder {args.drives}, where the "
                         "next run would take it for a drive; give a folder outside it")
    # absolute: the workers of a --scheduler may run in another folder
    out = check_output_dir(args.out).absolute()
    specs = [spec.absolute() for spec in find_drives(args.drives)]
    settings = FleetSettings(vehicle=args.vehicle, lag_s=args.lag,
                             chunk_frames=args.chunk_frames, marginals=not args.no_std,
                             image_topic=args.image_topic,
                             camera_info_topic=args.camera_info_topic,
                             speed_topic=args.speed_topic, columns=args.columns)
    rows: list[dict] = []
    try:
        rows = run_fleet(specs, out, settings, workers=args.workers, scheduler=args.scheduler,
                         retries=args.retries, progress=not args.quiet, on_row=rows.append)
    finally:
        if rows:
            write_fleet_report(rows, out)
    if not any(r.get("status") == "ok" for r in rows):
        raise NothingUsable(f"{args.drives}: no drive ok; {out / 'fleet_summary.csv'} holds "
                            "each drive's error")
    return 0
