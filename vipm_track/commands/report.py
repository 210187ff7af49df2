"""``vipm-track report``: PNG plots and a Markdown summary of a per-frame table."""

from __future__ import annotations

import argparse
import sys


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "report",
        help="plots (PNG) and a Markdown summary of a track / estimate / monitor table",
        description="Plot the pose, motion, trajectory and monitor state of a per-frame table "
        "(CSV or Parquet, CONVENTIONS.md columns), with errors against ground truth when "
        "given, and write a short Markdown summary (report.md) beside the plots.",
    )
    parser.add_argument("table", metavar="TRACK.csv",
                        help="per-frame table written by estimate, track, smooth or monitor")
    parser.add_argument("--gt", metavar="GT.csv", default=None,
                        help="ground truth with the same first columns (e.g. gt.csv of "
                        "'vipm-track simulate')")
    parser.add_argument("--out", required=True, metavar="DIR", help="folder for the report")
    parser.add_argument("--title", default=None, help="title of the plots and the report")
    parser.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    from ..sinks.report import write_report
    from .common import check_output_dir

    check_output_dir(args.out)

    report = write_report(args.table, args.out, gt=args.gt, title=args.title)
    names = ", ".join(p.name for p in report.plots.values())
    print(f"wrote {report.markdown} and {names} in {report.out}", file=sys.stderr)
    return 0
