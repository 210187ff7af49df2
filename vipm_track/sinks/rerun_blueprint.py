"""The recording's timelines and its default viewer layout.

Every entity of a recording (``rerun_sink.RerunSink``) sits on the ``frame`` timeline
(sequence: the frame index) and, where the frame has a timestamp, on ``time`` (duration,
seconds). :func:`default_blueprint` arranges the entities into views: the estimator's layout
(``estimate``) or the calibration's (``drift``: ``track``, ``smooth``, ``monitor``).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

FRAME_TIMELINE = "frame"
TIME_TIMELINE = "time"

#: The pose series, one view each: ``series/{axis}`` (degrees; height in metres).
AXES: tuple[str, ...] = ("pitch", "roll", "height")


def default_blueprint(layout: str = "estimate") -> Any:
    """The default layout. ``estimate``: camera and IPM views left, pose series middle,
    trajectory, motion, monitor and log right. ``drift`` (:func:`drift_blueprint`): the
    calibration first."""
    # rerun is imported when a recording is made: the CLI starts without it
    import rerun.blueprint as rrb

    if layout == "drift":
        return drift_blueprint()
    if layout != "estimate":
        raise ValueError(f"unknown rerun layout {layout!r}; expected 'estimate' or 'drift'")

    whole_run = rrb.VisibleTimeRange(
        FRAME_TIMELINE, start=rrb.TimeRangeBoundary.infinite(),
        end=rrb.TimeRangeBoundary.cursor_relative(),
    )
    series = [rrb.TimeSeriesView(origin=f"series/{axis}", name=f"{axis}"
                                 + (" [deg]" if axis != "height" else " [m]")) for axis in AXES]
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Vertical(
                rrb.Spatial2DView(origin="camera", name="camera: patches, displacements"),
                rrb.Horizontal(
                    rrb.Spatial2DView(origin="ipm/prev", name="virtual IPM k-1"),
                    rrb.Spatial2DView(origin="ipm/curr", name="virtual IPM k"),
                ),
                row_shares=[3, 2],
            ),
            rrb.Vertical(*series),
            rrb.Vertical(
                rrb.Spatial2DView(origin="trajectory", name="planar trajectory [m]",
                                  time_ranges=[whole_run]),
                rrb.Tabs(
                    rrb.TimeSeriesView(origin="motion", name="motion"),
                    rrb.TimeSeriesView(origin="monitor/statistic", name="monitor statistic"),
                    rrb.TimeSeriesView(origin="monitor/deviation", name="monitor deviation"),
                    rrb.TimeSeriesView(origin="quality", name="quality"),
                    rrb.TimeSeriesView(origin="timing", name="timing [ms]"),
                ),
                rrb.StateTimelineView(origin="monitor/state", name="monitor state"),
                rrb.TextLogView(origin="log", name="log"),
                row_shares=[3, 3, 1, 2],
            ),
            column_shares=[4, 3, 3],
        ),
        collapse_panels=True,
    )


def drift_blueprint() -> Any:
    """The calibration's layout: per axis the mount with its 95 % band, the nominal with its
    tolerance band, the monitor's new extrinsics and its events as markers, the frame pose
    behind (``series/{axis}``, whole run); under them the monitor's state; right, the camera
    with its patches, the monitor's statistic and the log."""
    import rerun.blueprint as rrb

    whole_run = rrb.VisibleTimeRange(
        FRAME_TIMELINE, start=rrb.TimeRangeBoundary.infinite(),
        end=rrb.TimeRangeBoundary.cursor_relative(),
    )
    mounts = [rrb.TimeSeriesView(origin=f"series/{axis}", time_ranges=[whole_run],
                                 name=f"mount {axis}" + (" [m]" if axis == "height" else " [deg]"))
              for axis in AXES]
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Vertical(*mounts,
                         rrb.StateTimelineView(origin="monitor/state", name="monitor state"),
                         row_shares=[3, 3, 3, 1]),
            rrb.Vertical(
                rrb.Spatial2DView(origin="camera", name="camera: patches, displacements"),
                rrb.Tabs(
                    rrb.TimeSeriesView(origin="monitor/statistic", name="monitor statistic"),
                    rrb.TimeSeriesView(origin="monitor/deviation", name="monitor deviation"),
                    rrb.TimeSeriesView(origin="motion", name="motion"),
                ),
                rrb.TextLogView(origin="log", name="events and log"),
                row_shares=[3, 2, 2],
            ),
            column_shares=[3, 2],
        ),
        collapse_panels=True,
    )


__all__: Sequence[str] = ["AXES", "FRAME_TIMELINE", "TIME_TIMELINE", "default_blueprint",
                          "drift_blueprint"]
