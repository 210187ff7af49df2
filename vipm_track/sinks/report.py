"""Plot report of a finished run: PNG plots and a Markdown summary of a per-frame table.

:func:`write_report` reads a track / estimate / monitor table (``table.read_table``: CSV or
Parquet, CONVENTIONS.md columns) and, optionally, a ground-truth table (``gt.csv`` of
``vipm-track simulate``, same first columns), and writes into ``out``:

- ``pitch_roll_height.png``: pose of every frame (degrees, metres) with its ±2σ band where
  the table has ``*_std`` columns, ground truth where given;
- ``errors.png`` (with ground truth): estimate − truth per frame for pitch, roll, height,
  travel distance and yaw;
- ``motion.png``: tx, tz, yaw per frame and the planar trajectory (motions chained);
- ``monitor.png`` (when the table has a ``monitor_state`` column): the monitor's state over
  time; where the table has them (``vipm-track monitor``'s columns) its CUSUM statistics
  ``stat_*`` against the alarm level, the deviations ``dev_*`` from the nominal, and the
  filter's mount ``mount_*`` with the new extrinsics ``new_*`` and their 95 % interval
  ``new_*_lo``/``new_*_hi``; other numeric ``monitor_*`` columns join the statistics;
- ``report.md``: summary numbers (mean, std, range, drift of each axis; error statistics
  against ground truth; statuses; monitor states, transitions and the last new extrinsics)
  and the plots.

A row is plotted and scored where its numbers are finite (CONVENTIONS.md: rows without an
estimate have empty numbers), whatever its status word (a filter's ``partial`` rows count).
"""

from __future__ import annotations

import itertools
from collections import Counter
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..errors import InputError
from ..evaluate import frame_errors
from ..kitti import is_kitti_poses, kitti_truth_table
from ..measurement import table_in_sequence
from ..table import TEXT_COLUMNS, first_data_row, read_table
from .drift_report import STATE_COLORS, drift_figure, fmt, summary_lines, write_html
from .drift_summary import (
    MIN_RATE_SPAN_S,
    MOUNT_AXES,
    DriftSummary,
    has_finite,
    state_runs,
    summarize_drift,
)
from .trajectory import planar_path

BAND_SIGMA = 2.0
#: columns of a KITTI truth that hold the assumed nominal pose, not a measured one
RELATIVE_ONLY = frozenset({"pitch_deg", "roll_deg", "prev_pitch_deg", "prev_roll_deg"})
#: (column, std column, label, unit) of the pose panels.
POSE_PANELS: tuple[tuple[str, str, str, str], ...] = (
    ("pitch_deg", "pitch_std_deg", "pitch", "deg"),
    ("roll_deg", "roll_std_deg", "roll", "deg"),
    ("height_m", "height_std_m", "height", "m"),
)
MOTION_PANELS: tuple[tuple[str, str, str, str], ...] = (
    ("tx_m", "tx_std_m", "tx (right)", "m"),
    ("tz_m", "tz_std_m", "tz (forward)", "m"),
    ("yaw_deg", "yaw_std_deg", "yaw (> 0 right)", "deg"),
)
#: Errors plotted against ground truth: name → (label, unit).
ERROR_PANELS: dict[str, tuple[str, str]] = {
    "pitch_deg": ("pitch", "deg"),
    "roll_deg": ("roll", "deg"),
    "height_m": ("height", "m"),
    "distance_m": ("travel per frame", "m"),
    "yaw_deg": ("yaw per frame", "deg"),
}
EST_COLOR, TRUTH_COLOR = "tab:blue", "0.25"
#: Deviation columns of a monitor table (``vipm-track monitor``): 1 s mean pose − nominal.
MONITOR_DEVIATIONS: tuple[str, ...] = ("dev_pitch_deg", "dev_roll_deg", "dev_height_m")
#: (label, mount column, new-extrinsics column, its 95 % low / high columns, unit).
MONITOR_AXES: tuple[tuple[str, str, str, str, str, str], ...] = (
    ("pitch", "mount_pitch_deg", "new_pitch_deg", "new_pitch_lo_deg", "new_pitch_hi_deg", "deg"),
    ("roll", "mount_roll_deg", "new_roll_deg", "new_roll_lo_deg", "new_roll_hi_deg", "deg"),
    ("height", "mount_height_m", "new_height_m", "new_height_lo_m", "new_height_hi_m", "m"),
)


@dataclass(frozen=True)
class Report:
    """What :func:`write_report` wrote: the plots (name → path), the Markdown file (and the
    HTML page, or None), the summary numbers (axis → statistic → value, in the table's units),
    the errors against ground truth and the calibration summary (None without mount columns)."""

    out: Path
    plots: dict[str, Path]
    markdown: Path
    summary: dict[str, dict[str, float]] = field(default_factory=dict)
    errors: dict[str, dict[str, float]] = field(default_factory=dict)
    drift: DriftSummary | None = None
    html: Path | None = None


def write_report(
    track: str | Path,
    out: str | Path,
    gt: str | Path | None = None,
    title: str | None = None,
    *,
    nominal: object | None = None,
    html: bool = False,
    start: int = 0,
    max_frames: int | None = None,
    notes: list[str] | None = None,
) -> Report:
    """Write the plots and ``report.md`` of the table ``track`` (optional ground truth ``gt``:
    a table of our format or a KITTI ``poses.txt``) into the folder ``out`` (see module doc).
    ``nominal``: a ``filters.nominal.NominalCalibration`` the mount is held against; ``html``:
    also ``report.html``, one self-contained page; ``start``/``max_frames``: the rows of frames
    ``start`` on, at most ``max_frames`` of them; ``notes``: gets a line per kind of row left
    out (``measurement.table_in_sequence``: repeated frames, frames or times going backwards,
    named by row). Raises :class:`InputError` naming the file
    for a missing/unreadable table or one without any pose column."""
    track, out = Path(track), Path(out)
    if out.exists() and not out.is_dir():
        raise InputError(f"--out {out}: exists and is not a folder")
    table = read_table(track)
    _check_finite(table, track)  # before rows are left out: the file's own row numbers
    if "frame" in table:  # repeats, frames or times going backwards: left out, said in notes
        rows = len(table["frame"])
        table, issues = table_in_sequence(table, first_data_row(track))
        issues.check_a_sequence(str(track), rows)
        if issues and notes is not None:
            notes.extend(issues.lines(str(track)))
    est = window_rows(table, start, max_frames)
    if not any(c in est for c, *_ in POSE_PANELS + MOTION_PANELS):
        raise InputError(f"{track}: no pose or motion column (pitch_deg, roll_deg, height_m, "
                         "tx_m, tz_m, yaw_deg); is this a per-frame table?")
    if len(est["frame"]) == 0:
        raise InputError(f"{track}: the table has no rows"
                         + (f" from frame {start}" if start else ""))
    pitch = np.asarray(est.get("pitch_deg", np.full(len(est["frame"]), np.nan)), float)
    if not np.isfinite(pitch).any() and notes is not None:
        notes.append(f"{track}: no row has a pitch (pitch_deg missing or empty): the report "
                     "shows no pose")
    if notes is not None:
        notes.extend(table_notes(est, track))
    truth = read_truth(gt) if gt is not None else None
    relative = gt is not None and is_kitti_poses(gt)  # only pitch/roll changes are truth
    if truth is not None:
        check_same_drive(est, truth, track, Path(gt))
        if "t" not in truth and notes is not None:
            notes.append(f"{gt}: no times (a times.txt beside it): its frames are taken as the "
                         f"table's by their numbers, unchecked against {track}'s clock")
        lacking = [c for c, *_ in POSE_PANELS + MOTION_PANELS
                   if c in est and not has_finite(truth, c)
                   and not (relative and c in RELATIVE_ONLY)]
        if lacking and notes is not None:
            notes.append(f"{gt}: no values in column(s) {', '.join(lacking)}: not scored")
    title = title or track.name
    out.mkdir(parents=True, exist_ok=True)
    x, x_label = _time_axis(est)
    x_truth = _time_axis(truth)[0] if truth is not None else None
    if truth is not None and x_label == "frame":
        x_truth = np.asarray(truth["frame"], float)

    plt = _pyplot()
    plots: dict[str, Path] = {}
    drift = summarize_drift(est, nominal, truth) if _has_time(est) else None
    if drift is None and nominal is not None and notes is not None:
        notes.append(f"{track}: no mount (calibration) to hold against the nominal (the "
                     "mount_* columns of track, smooth and monitor tables): the nominal is "
                     "not used")
    if drift is not None:
        plots["drift"] = drift_figure(plt, est, drift, nominal, truth, out / "drift.png",
                                      f"{title}: calibration")
    if any(c in est for c, *_ in POSE_PANELS):  # a motion-only table has no pose figure
        plots["pitch_roll_height"] = _series_figure(
            plt, est, truth, x, x_truth, x_label, POSE_PANELS, out / "pitch_roll_height.png",
            f"{title}: pose against the ground")
    errors: dict[str, NDArray] = {}
    if truth is not None:
        errors = frame_errors(est, truth, scored="finite")
        if relative:
            errors = {k: v for k, v in errors.items() if k not in RELATIVE_ONLY}
            truth = {k: v for k, v in truth.items() if k not in RELATIVE_ONLY}
        if len(errors.get("frame", ())):
            plots["errors"] = _errors_figure(plt, est, errors, x_label, out / "errors.png",
                                             f"{title}: error against ground truth")
    if any(c in est for c, *_ in MOTION_PANELS):
        plots["motion"] = _motion_figure(plt, est, truth, x, x_truth, x_label,
                                         out / "motion.png", f"{title}: planar motion")
    if "monitor_state" in est:
        plots["monitor"] = _monitor_figure(plt, est, x, x_label, out / "monitor.png",
                                           f"{title}: calibration monitor")
    summary = summarize(est)
    error_summary = {name: _abs_stats(values) for name, values in errors.items()
                     if name != "frame"}
    markdown = out / "report.md"
    text = _markdown(title, track, gt, est, summary, error_summary, plots, out, drift)
    markdown.write_text(text)
    page = write_html(text, out, out / "report.html") if html else None
    return Report(out, plots, markdown, summary, error_summary, drift, page)


def table_notes(est: Mapping[str, NDArray], track: Path) -> list[str]:
    """What in the table the report cannot vouch for, one line each: no status column, rows
    saying ``ok`` without their numbers (a monitor table's pose is the filter's, empty
    while it starts: not checked), monitor states vipm-track does not write, a mount
    axis without its column (a table edited or cut by hand)."""
    notes = []
    first = first_data_row(track)
    frames = np.asarray(est["frame"])

    def rows_text(index: NDArray) -> str:
        shown = ", ".join(f"row {i + first} frame {int(frames[i])}" for i in index[:3])
        return shown + (f", … ({index.size} rows)" if index.size > 3 else "")

    if "status" not in est:
        notes.append(f"{track}: no status column: the report counts no statuses")
    elif "monitor_state" not in est:  # a monitor's status is the pair's, its pose the filter's
        ok = np.asarray(est["status"], dtype=object) == "ok"

        def finite(panels: tuple) -> NDArray:  # (columns present, rows)
            return np.array([np.isfinite(np.asarray(est[c], float)) for c, *_ in panels
                             if c in est]).reshape(-1, ok.size)

        # a filter's first frame has a pose and no motion yet: the motion all or none
        pose, motion = finite(POSE_PANELS), finite(MOTION_PANELS)
        lacking = ok & (~pose.all(axis=0) | (motion.any(axis=0) & ~motion.all(axis=0)))
        if lacking.any():
            notes.append(f"{track}: rows say ok but lack numbers: "
                         f"{rows_text(np.flatnonzero(lacking))}")
    if "monitor_state" in est:
        state = np.asarray(est["monitor_state"], dtype=object)
        odd = np.flatnonzero([str(v) not in STATE_COLORS and v not in ("", None) for v in state])
        if odd.size:
            notes.append(f"{track}: monitor states vipm-track does not write "
                         f"({', '.join(sorted({repr(str(state[i])) for i in odd}))}): "
                         f"{rows_text(odd)}")
    mount = [axis[2] for axis in MOUNT_AXES if axis[2] in est]
    if mount and len(mount) < len(MOUNT_AXES):
        absent = [axis[2] for axis in MOUNT_AXES if axis[2] not in est]
        notes.append(f"{track}: no column {', '.join(absent)}: the calibration has no "
                     f"{', '.join(a.split('_')[1] for a in absent)} row")
    return notes


def _check_finite(table: Mapping[str, NDArray], path: Path) -> None:
    """InputError naming row, frame and column for the first infinite time, angle or length
    (``t``, ``*_deg``, ``*_m``): no estimate has one; plotted or summarised as a missing
    value it would pass unseen (an empty cell is the way to say "none")."""
    for name, values in table.items():
        if not (name == "t" or name.endswith(("_deg", "_m"))) or name in TEXT_COLUMNS:
            continue
        bad = np.isinf(np.asarray(values, float))
        if bad.any():
            row = int(np.flatnonzero(bad)[0])
            frame = f" (frame {int(table['frame'][row])})" if "frame" in table else ""
            raise InputError(f"{path}: row {row + first_data_row(path)}{frame}: {name} = "
                             f"{values[row]} is not a finite number")


def window_rows(table: dict[str, NDArray], start: int = 0,
                max_frames: int | None = None) -> dict[str, NDArray]:
    """The rows of ``table`` whose frame is at least ``start``, at most ``max_frames`` of them
    (``--start`` / ``--max-frames``; InputError for negative values)."""
    if start < 0 or (max_frames is not None and max_frames < 1):
        raise InputError(f"--start must be >= 0 and --max-frames >= 1, got {start} and "
                         f"{max_frames}")
    rows = np.flatnonzero(np.asarray(table["frame"]) >= start)
    if max_frames is not None:
        rows = rows[:max_frames]
    return {name: np.asarray(values)[rows] for name, values in table.items()}


def check_same_drive(est: Mapping[str, NDArray], truth: Mapping[str, NDArray], track: Path,
                     gt: Path) -> None:
    """InputError where the frames the table and the truth share disagree on their time by
    more than a quarter of a frame interval (at least 1 ms): another drive's truth, or the
    same frames on another clock, would be scored frame by frame as if it were this one's."""
    if "t" not in est or "t" not in truth or "frame" not in truth:
        return
    frames_est = np.asarray(est["frame"])
    t_truth = dict(zip(np.asarray(truth["frame"]).tolist(), np.asarray(truth["t"], float),
                       strict=True))
    t_est = np.asarray(est["t"], float)
    shared = [(i, t_truth[f]) for i, f in enumerate(frames_est.tolist())
              if f in t_truth and np.isfinite(t_truth[f]) and np.isfinite(t_est[i])]
    if len(shared) < 2:
        return
    rows, t_gt = np.array([i for i, _ in shared]), np.array([t for _, t in shared])
    steps = np.diff(t_est[rows])
    tolerance = max(1e-3, 0.25 * float(np.median(steps[steps > 0])) if (steps > 0).any()
                    else 1e-3)
    off = np.abs(t_est[rows] - t_gt) > tolerance
    if off.any():
        i = int(np.flatnonzero(off)[0])
        raise InputError(
            f"{gt}: frame {int(frames_est[rows[i]])} is at t = {t_gt[i]:.3f} s there but at "
            f"{t_est[rows[i]]:.3f} s in {track} ({int(off.sum())} of {off.size} shared frames "
            "disagree): not the truth of this drive, or another clock")


def read_truth(path: str | Path) -> dict[str, NDArray]:
    """Ground truth: a per-frame table (``gt.csv`` of ``vipm-track simulate``: CSV or
    Parquet), or KITTI's ``poses.txt`` (``kitti.kitti_truth_table``: motion and pitch/roll
    changes; its absolute pitch/roll are not known, so not scored)."""
    if is_kitti_poses(path):
        return kitti_truth_table(path)
    table = read_table(path)
    _check_finite(table, Path(path))
    return table


# --- numbers ---------------------------------------------------------------------------------


def summarize(est: Mapping[str, NDArray]) -> dict[str, dict[str, float]]:
    """Per column of pose and motion: n, mean, std, min, max over the finite rows, and the
    drift: ``end_minus_start`` (median of the last tenth of the rows minus that of the first)
    and, where the rows span at least ``MIN_RATE_SPAN_S`` seconds, ``slope_per_min`` (the
    least-squares slope against ``t``, per minute) with its standard error
    ``slope_std_per_min`` (from 30 block means: the shaking is correlated frame to frame)."""
    x, _ = _time_axis(est)
    timed = _has_time(est)
    out: dict[str, dict[str, float]] = {}
    for col, *_ in POSE_PANELS + MOTION_PANELS:
        if col not in est:
            continue
        v = np.asarray(est[col], float)
        ok = np.isfinite(v) & np.isfinite(x)
        if not ok.any():
            continue
        vals, xs = v[ok], x[ok]
        stats = {"n": float(vals.size), "mean": float(vals.mean()), "std": float(vals.std()),
                 "min": float(vals.min()), "max": float(vals.max())}
        if vals.size >= 3 and np.ptp(xs) > 0:
            tenth = max(1, vals.size // 10)
            stats["end_minus_start"] = float(np.median(vals[-tenth:]) - np.median(vals[:tenth]))
        if timed and vals.size >= 10 and np.ptp(xs) >= MIN_RATE_SPAN_S:
            blocks = min(30, vals.size // 2)
            xb = np.array([b.mean() for b in np.array_split(xs / 60.0, blocks)])
            vb = np.array([b.mean() for b in np.array_split(vals, blocks)])
            (slope, icept), cov = np.polyfit(xb, vb, 1, cov="unscaled")
            resid = vb - (slope * xb + icept)
            stats["slope_per_min"] = float(slope)
            stats["slope_std_per_min"] = float(np.sqrt(cov[0, 0] * (resid @ resid)
                                                       / max(blocks - 2, 1)))
        out[col] = stats
    return out


def _abs_stats(values: NDArray) -> dict[str, float]:
    """n, mean (signed: bias), std, RMS, median, p95 and max of |error| over finite entries."""
    v = np.asarray(values, float)
    v = v[np.isfinite(v)]
    if v.size == 0:
        return {"n": 0.0}
    a = np.abs(v)
    return {"n": float(v.size), "bias": float(v.mean()), "std": float(v.std()),
            "rms": float(np.sqrt(np.mean(v**2))), "median_abs": float(np.median(a)),
            "p95_abs": float(np.percentile(a, 95)), "max_abs": float(a.max())}


def _has_time(table: Mapping[str, NDArray]) -> bool:
    t = np.asarray(table.get("t", ()), float)
    return t.size > 0 and bool(np.all(np.isfinite(t)))


def _time_axis(table: Mapping[str, NDArray] | None) -> tuple[NDArray, str]:
    """x values of a table's rows: ``t`` [s] when every row has one, else the frame index."""
    if table is None:
        return np.zeros(0), ""
    if _has_time(table):
        return np.asarray(table["t"], float), "time [s]"
    return np.asarray(table["frame"], float), "frame"


# --- figures ---------------------------------------------------------------------------------


def _pyplot() -> Any:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _save(plt: Any, fig: Any, path: Path) -> Path:
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


def _series_figure(plt: Any, est: Mapping, truth: Mapping | None, x: NDArray,
                   x_truth: NDArray | None, x_label: str, panels: tuple, path: Path,
                   title: str) -> Path:
    present = [p for p in panels if p[0] in est]
    fig, axes = plt.subplots(len(present), 1, figsize=(11, 2.6 * len(present) + 0.6),
                             sharex=True, squeeze=False)
    for ax, panel in zip(axes[:, 0], present, strict=True):
        _series_panel(ax, est, truth, x, x_truth, panel)
    axes[-1, 0].set_xlabel(x_label)
    axes[0, 0].legend(loc="best", fontsize=8)
    fig.suptitle(title)
    return _save(plt, fig, path)


def _series_panel(ax: Any, est: Mapping, truth: Mapping | None, x: NDArray,
                  x_truth: NDArray | None, panel: tuple[str, str, str, str]) -> None:
    col, std_col, label, unit = panel
    v = np.asarray(est[col], float)
    if std_col in est:
        s = np.asarray(est[std_col], float)
        ax.fill_between(x, v - BAND_SIGMA * s, v + BAND_SIGMA * s, color=EST_COLOR, alpha=0.2,
                        lw=0, label=f"±{BAND_SIGMA:g}σ")
    if truth is not None and col in truth and x_truth is not None:
        ax.plot(x_truth, np.asarray(truth[col], float), "-", color=TRUTH_COLOR, lw=1.4,
                label="ground truth")
    ax.plot(x, v, ".-", color=EST_COLOR, ms=3, lw=0.8, label="estimate")
    ax.set_ylabel(f"{label} [{unit}]")
    ax.grid(alpha=0.3)


def _errors_figure(plt: Any, est: Mapping, errors: Mapping[str, NDArray], x_label: str,
                   path: Path, title: str) -> Path:
    names = [n for n in ERROR_PANELS if n in errors]
    frame_x = dict(zip(np.asarray(est["frame"]).tolist(), _time_axis(est)[0], strict=True))
    x = np.array([frame_x[int(f)] for f in errors["frame"]], float)
    fig, axes = plt.subplots(len(names), 1, figsize=(11, 2.2 * len(names) + 0.6), sharex=True,
                             squeeze=False)
    for ax, name in zip(axes[:, 0], names, strict=True):
        label, unit = ERROR_PANELS[name]
        e = np.asarray(errors[name], float)
        ax.axhline(0.0, color="0.5", lw=0.8)
        ax.plot(x, e, ".-", color="tab:red", ms=3, lw=0.8)
        stats = _abs_stats(e)
        if stats["n"]:
            ax.set_title(f"{label}: bias {fmt(stats['bias'], unit, True)}, RMS "
                         f"{fmt(stats['rms'], unit)} {unit}",
                         fontsize=9, loc="left")
        ax.set_ylabel(f"Δ {label} [{unit}]")
        ax.grid(alpha=0.3)
    axes[-1, 0].set_xlabel(x_label)
    fig.suptitle(title)
    return _save(plt, fig, path)


def _motion_figure(plt: Any, est: Mapping, truth: Mapping | None, x: NDArray,
                   x_truth: NDArray | None, x_label: str, path: Path, title: str) -> Path:
    fig = plt.figure(figsize=(13, 7))
    grid = fig.add_gridspec(3, 2, width_ratios=[3, 2])
    first = None
    for row, panel in enumerate(MOTION_PANELS):
        ax = fig.add_subplot(grid[row, 0], sharex=first)
        first = first or ax
        if panel[0] in est:
            _series_panel(ax, est, truth, x, x_truth, panel)
        if row == 0:
            ax.legend(loc="best", fontsize=8)
    ax.set_xlabel(x_label)
    ax = fig.add_subplot(grid[:, 1])
    path_est = planar_path(est)
    if truth is not None:
        path_truth = planar_path(truth)
        if path_truth is not None:
            ax.plot(path_truth[:, 0], path_truth[:, 1], "-", color=TRUTH_COLOR, lw=1.5,
                    label="ground truth")
    if path_est is not None:
        ax.plot(path_est[:, 0], path_est[:, 1], ".-", color=EST_COLOR, ms=2, lw=1,
                label="estimate (chained)")
    ax.set_xlabel("x, right of the first frame [m]")
    ax.set_ylabel("z, ahead of the first frame [m]")
    ax.set_aspect("equal", adjustable="datalim")
    ax.grid(alpha=0.3)
    ax.legend(loc="best", fontsize=8)
    ax.set_title("planar trajectory", fontsize=10)
    fig.suptitle(title)
    return _save(plt, fig, path)


def _monitor_figure(plt: Any, est: Mapping, x: NDArray, x_label: str, path: Path,
                    title: str) -> Path:
    """State over time, then (where the table has them) the CUSUM statistics ``stat_*``
    against the alarm level 1, the 1 s deviations ``dev_*`` from the nominal, and per axis
    the filter's mount ``mount_*`` with the monitor's new extrinsics ``new_*`` and their 95 %
    interval (``filters/monitor.py`` via ``vipm-track monitor``)."""
    states = np.asarray(est["monitor_state"], dtype=object)
    stats = [c for c in est if (c.startswith("stat_") or (
        c.startswith("monitor_") and c != "monitor_state")) and has_finite(est, c)]
    devs = [c for c in MONITOR_DEVIATIONS if has_finite(est, c)]
    axes_new = [p for p in MONITOR_AXES if has_finite(est, p[1]) or has_finite(est, p[2])]
    ratios = [1.0] + [1.6] * bool(stats) + [1.6] * bool(devs) + [1.6] * len(axes_new)
    fig, axes = plt.subplots(len(ratios), 1, figsize=(11, 1.0 + 1.7 * sum(ratios)),
                             sharex=True, squeeze=False, gridspec_kw={"height_ratios": ratios})
    panels = iter(axes[:, 0])
    ax = next(panels)
    names = [s for s in STATE_COLORS if s in set(states)]
    names += sorted({s for s in states if s and s not in STATE_COLORS})
    level = {s: i for i, s in enumerate(names)}
    for start, stop, state in state_runs(states):
        if not state:
            continue
        x0 = x[start]
        x1 = x[stop] if stop < len(x) else x[-1] + (x[-1] - x[-2] if len(x) > 1 else 1.0)
        ax.axvspan(x0, x1, color=STATE_COLORS.get(state, "#607d8b"), alpha=0.35, lw=0)
    y = np.array([level.get(s, np.nan) for s in states], float)
    ax.step(x, y, where="post", color="k", lw=1)
    ax.set_yticks(range(len(names)), names, fontsize=8)
    ax.set_ylim(-0.5, len(names) - 0.5)
    ax.set_ylabel("state")
    if stats:
        ax = next(panels)
        for c in stats:
            ax.plot(x, np.asarray(est[c], float), lw=1,
                    label=c.removeprefix("stat_").removeprefix("monitor_"))
        if any(c.startswith("stat_") for c in stats):
            ax.axhline(1.0, color="tab:red", lw=1, ls="--", label="alarm")
        ax.set_ylabel("CUSUM / threshold")
        ax.grid(alpha=0.3)
        ax.legend(loc="upper left", fontsize=8)
    if devs:
        ax = next(panels)
        twin = None
        for c in devs:
            target = ax
            if c.endswith("_m"):
                twin = twin or ax.twinx()
                target = twin
            target.plot(x, np.asarray(est[c], float), lw=1,
                        color="0.3" if target is twin else None,
                        label=c.removeprefix("dev_"))
        ax.axhline(0.0, color="0.5", lw=0.8)
        ax.set_ylabel("deviation [deg]")
        ax.grid(alpha=0.3)
        ax.legend(loc="upper left", fontsize=8)
        if twin is not None:
            twin.set_ylabel("height deviation [m]")
            twin.legend(loc="upper right", fontsize=8)
    for label, mount, new, lo, hi, unit in axes_new:
        ax = next(panels)
        if has_finite(est, mount):
            ax.plot(x, np.asarray(est[mount], float), color=EST_COLOR, lw=1,
                    label="filter mount")
        if has_finite(est, new):
            if has_finite(est, lo) and has_finite(est, hi):
                ax.fill_between(x, np.asarray(est[lo], float), np.asarray(est[hi], float),
                                color="tab:purple", alpha=0.25, lw=0, label="95 % interval")
            ax.plot(x, np.asarray(est[new], float), ".", color="tab:purple", ms=3,
                    label="new extrinsics")
        ax.set_ylabel(f"{label} [{unit}]")
        ax.grid(alpha=0.3)
        ax.legend(loc="upper left", fontsize=8)
    axes[-1, 0].set_xlabel(x_label)
    fig.suptitle(title)
    return _save(plt, fig, path)


# --- markdown --------------------------------------------------------------------------------


def _unit(column: str) -> str:
    """The unit a column's numbers are written in (its name's suffix; ``fmt``)."""
    for suffix, unit in (("_deg", "deg"), ("_m", "m"), ("_pct", "%")):
        if column.endswith(suffix):
            return unit
    return ""


def _markdown(title: str, track: Path, gt: str | Path | None, est: Mapping,
              summary: dict, errors: dict, plots: dict[str, Path], out: Path,
              drift: DriftSummary | None = None) -> str:
    n = len(est["frame"])
    counts = Counter(str(s) for s in est["status"]) if "status" in est else None
    has_pose = np.isfinite(np.asarray(est.get("pitch_deg", np.full(n, np.nan)), float))
    lines = [f"# Report: {title}", "",
             f"- table: `{track}` ({n} rows, frames {int(est['frame'][0])}–"
             f"{int(est['frame'][-1])})"]
    if _has_time(est):
        t = np.asarray(est["t"], float)
        lines.append(f"- time span: {fmt(t[0], 's')}–{fmt(t[-1], 's')} s "
                     f"({fmt(t[-1] - t[0], 's')} s)")
    if gt is not None:
        lines.append(f"- ground truth: `{gt}`")
    lines.append(f"- rows with a pose: {int(has_pose.sum())} / {n} "
                 f"({100.0 * has_pose.sum() / max(n, 1):.1f} %)")
    lines.append("- statuses: " + (", ".join(f"{s or '(empty)'} × {c}"
                                             for s, c in counts.most_common())
                                   if counts is not None else "no status column"))
    if drift is not None:
        lines += ["", "## Calibration", "", *summary_lines(drift)]
        if "drift" in plots:
            lines += ["", "![drift](drift.png)"]
    lines += ["", "## Per-frame values", "",
              "End − start: median of the last tenth of the rows minus that of the first "
              f"tenth. Drift: least-squares slope per minute ± its standard error, only over "
              f"≥ {MIN_RATE_SPAN_S:.0f} s.", "",
              "| column | n | mean | std | min | max | end − start | drift / min ± 1σ |",
              "| --- | --- | --- | --- | --- | --- | --- | --- |"]
    for col, s in summary.items():
        u = _unit(col)
        slope = (f"{fmt(s['slope_per_min'], 'rate', True)} ± "
                 f"{fmt(s['slope_std_per_min'], 'rate')}" if "slope_per_min" in s else "–")
        lines.append(f"| {col} | {int(s['n'])} | {fmt(s['mean'], u)} | {fmt(s['std'], u)} | "
                     f"{fmt(s['min'], u)} | {fmt(s['max'], u)} | "
                     f"{fmt(s.get('end_minus_start'), u, True)} | {slope} |")
    if errors:
        lines += ["", "## Error against ground truth", "",
                  "Estimate − truth over the frames both tables have (bias = mean signed "
                  "error).", "",
                  "| error | n | bias | std | RMS | median abs | p95 abs | max abs |",
                  "| --- | --- | --- | --- | --- | --- | --- | --- |"]
        for name, s in errors.items():
            if not s.get("n"):
                continue
            u = _unit(name) + " error" if _unit(name) in ("deg", "m") else _unit(name)
            lines.append(f"| {name} | {int(s['n'])} | {fmt(s['bias'], u, True)} | "
                         f"{fmt(s['std'], u)} | {fmt(s['rms'], u)} | {fmt(s['median_abs'], u)} "
                         f"| {fmt(s['p95_abs'], u)} | {fmt(s['max_abs'], u)} |")
    if "monitor_state" in est and (drift is None or drift.monitor is None):
        lines += ["", "## Monitor", "", *_monitor_lines(est)]
    lines += ["", "## Plots", ""]
    for name, path in plots.items():
        if name == "drift":
            continue
        rel = path.relative_to(out) if path.is_relative_to(out) else path
        lines.append(f"![{name}]({rel})")
    return "\n".join(lines) + "\n"


def _monitor_lines(est: Mapping) -> list[str]:
    states = np.asarray(est["monitor_state"], dtype=object)
    x, x_label = _time_axis(est)
    step = np.diff(x, append=x[-1] + (np.median(np.diff(x)) if len(x) > 1 else 1.0))
    unit = "s" if x_label.startswith("time") else "frames"
    lines = [f"| state | rows | {unit} |", "| --- | --- | --- |"]
    for state in dict.fromkeys(states):
        rows = states == state
        lines.append(f"| {state or '(empty)'} | {int(rows.sum())} | {step[rows].sum():.1f} |")
    runs = state_runs(states)
    lines += ["", f"Transitions ({max(len(runs) - 1, 0)}):", ""]
    for (_, _, before), (start, _, after) in list(itertools.pairwise(runs))[:30]:
        lines.append(f"- frame {int(est['frame'][start])} ({x_label.split()[0]} "
                     f"{x[start]:.2f}): {before or '(empty)'} → {after or '(empty)'}")
    if len(runs) > 31:
        lines.append(f"- … {len(runs) - 31} more")
    new = [p for p in MONITOR_AXES if has_finite(est, p[2])]
    if new:
        last = int(np.flatnonzero(np.isfinite(np.asarray(est[new[0][2]], float)))[-1])
        lines += ["", f"New extrinsics at frame {int(est['frame'][last])} "
                  f"({states[last] or '(empty)'}; 95 % interval):", ""]
        for label, _, col, lo, hi, unit in new:
            value = float(np.asarray(est[col], float)[last])
            bounds = (f" [{fmt(float(est[lo][last]), unit)}, {fmt(float(est[hi][last]), unit)}]"
                      if lo in est and hi in est else "")
            lines.append(f"- {label}: {fmt(value, unit)}{bounds} {unit}")
    return lines
