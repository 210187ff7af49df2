"""``vipm-track report``: the drift report (PNG, Markdown, optionally one HTML page) of a
per-frame table."""

from __future__ import annotations

import argparse
import sys


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "report",
        help="plots (PNG) and a Markdown summary of a track / estimate / monitor table",
        description="The calibration of a track / smooth / monitor table in a minute: the "
        "mount pitch, roll and height over time with 95 % bands, the nominal and its "
        "tolerances, the monitor's states and events, and the summary (current extrinsics with "
        "their interval, change since the nominal, when it changed, how sure, drift rates over "
        "spans of a minute or more); then the per-frame pose, motion and trajectory, with "
        "errors against ground truth when given. Writes report.md and PNG plots into --out "
        "(and report.html, one self-contained page, with --html).",
    )
    parser.add_argument("table", metavar="TRACK.csv",
                        help="per-frame table written by estimate, track, smooth or monitor")
    parser.add_argument("--gt", metavar="GT.csv|poses.txt", default=None,
                        help="ground truth: a table with the same first columns (gt.csv of "
                        "'vipm-track simulate', with mount_* columns for the true mount) or "
                        "KITTI's poses.txt (motion and pitch/roll changes; times.txt beside it)")
    parser.add_argument("--nominal", metavar="CALIB.yaml", default=None,
                        help="nominal calibration the mount is held against (the monitor's "
                        "file); without it, changes are since the table's first mount")
    parser.add_argument("--out", required=True, metavar="DIR", help="folder for the report")
    parser.add_argument("--title", default=None, help="title of the plots and the report")
    parser.add_argument("--html", action="store_true",
                        help="also write report.html: the report with its plots embedded")
    parser.add_argument("--start", type=int, default=0, metavar="K",
                        help="first frame index to report (default 0)")
    parser.add_argument("--max-frames", type=int, default=None, metavar="N",
                        help="report at most N frames from --start")
    parser.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    from vipm_track.filters.nominal import load_nominal

    from ..sinks.report import write_report
    from .common import check_output_dir

    check_output_dir(args.out)
    nominal = load_nominal(args.nominal) if args.nominal else None
    notes: list[str] = []
    report = write_report(args.table, args.out, gt=args.gt, title=args.title, nominal=nominal,
                          html=args.html, start=args.start, max_frames=args.max_frames,
                          notes=notes)
    for line in notes:
        print(f"vipm-track: warning: {line}", file=sys.stderr)
    names = ", ".join(p.name for p in report.plots.values())
    page = f" and {report.html.name}" if report.html is not None else ""
    print(f"wrote {report.markdown}{page} and {names} in {report.out}", file=sys.stderr)
    return 0
