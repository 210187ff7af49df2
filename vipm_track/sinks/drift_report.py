"""The drift report's own parts: the calibration figure (``drift.png``), the summary a
calibration engineer reads first (Markdown) and the whole report as one self-contained HTML
page. ``report.write_report`` puts them together; the numbers come from
``drift_summary.summarize_drift``.

Numbers are written in fixed decimals by unit (:func:`fmt`): degrees 3, metres 4, seconds 2,
rates 4, errors against ground truth one more (degrees 4, metres 5) — never in scientific
notation.
"""

from __future__ import annotations

import base64
import html
import math
import re
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .drift_summary import (
    DRIFT_SIGMAS,
    FRAMES_SINCE_STEP,
    MOUNT_AXES,
    Z95,
    DriftSummary,
    state_runs,
)

#: decimals a number is written with, by unit
DECIMALS: dict[str, int] = {"deg": 3, "m": 4, "s": 2, "%": 2, "rate": 4, "": 3,
                             "deg error": 4, "m error": 5}
STATE_COLORS: dict[str, str] = {
    "UNCALIBRATED": "#bdbdbd", "CALIBRATED": "#4caf50", "DRIFTING": "#ffb300",
    "RECALIBRATE": "#e53935", "INVALID": "#8e24aa", "HOLD": "#90a4ae",
}
MOUNT_COLOR, POSE_COLOR, TRUTH_COLOR, NOMINAL_COLOR = "tab:blue", "0.7", "k", "tab:green"
CHANGE_COLOR = "tab:red"
#: frame-pose column drawn faint behind each mount panel
POSE_COLUMNS: dict[str, str] = {"pitch": "pitch_deg", "roll": "roll_deg", "height": "height_m"}


def fmt(value: float | None, unit: str = "", signed: bool = False) -> str:
    """``value`` in fixed decimals for ``unit`` (:data:`DECIMALS`); "–" where not finite."""
    if value is None or not math.isfinite(value):
        return "–"
    digits = DECIMALS.get(unit, 3)
    text = f"{value:+.{digits}f}" if signed else f"{value:.{digits}f}"
    if float(text) == 0.0:  # no "-0.000"
        text = ("+" if signed else "") + f"{0.0:.{digits}f}"
    return text


# --- Markdown --------------------------------------------------------------------------------


def summary_lines(s: DriftSummary) -> list[str]:
    """The calibration section of ``report.md``: a table of the current extrinsics, the change
    since the reference, when, how sure and the drift rate, then the monitor's timeline."""
    lines = [f"Mount (calibration) at frame {s.last_frame}, t = {fmt(s.t1, 's')} s, of a table "
             f"spanning {fmt(s.t1 - s.t0, 's')} s; 95 % intervals. Change = current − "
             + ("nominal" if any(a.reference_from == "nominal" for a in s.axes.values())
                else "the table's first mount (no nominal given)")
             + "; P(beyond tolerance) is the probability that the true change exceeds the "
             "tolerance; a drift rate is given only over ≥ 60 s since the last change.", "",
             "| axis | current [95 %] | reference | change ± 1σ | tolerance | P(beyond "
             "tolerance) | changed at | drift / min ± 1σ |",
             "| --- | --- | --- | --- | --- | --- | --- | --- |"]
    for a in s.axes.values():
        u = a.unit
        interval = f" [{fmt(a.lo, u)}, {fmt(a.hi, u)}]" if math.isfinite(a.lo) else ""
        when = (f"{fmt(a.changed_at_s, 's')} s" if math.isfinite(a.changed_at_s)
                else "not found" if a.off_unfound else "no change")
        rate = (f"{fmt(a.rate_per_min, 'rate', True)} ± {fmt(a.rate_std_per_min, 'rate')} {u}"
                if math.isfinite(a.rate_per_min) else a.rate_note)
        p = "–" if not math.isfinite(a.p_beyond) else _percent(a.p_beyond)
        lines.append(f"| {a.axis} [{u}] | {fmt(a.current, u)}{interval} | {fmt(a.reference, u)} "
                     f"({a.reference_from}) | {fmt(a.change, u, True)} ± "
                     f"{fmt(a.change_std, u)} | {fmt(a.tolerance, u)} | {p} | {when} | {rate} |")
    creeping = [a.axis for a in s.axes.values() if a.interval_from == "drift fit"]
    if creeping:
        lines += ["", f"{' and '.join(creeping).capitalize()} drift{'s' * (len(creeping) == 1)}"
                  f" (rate beyond {DRIFT_SIGMAS:g}σ, a line fitting better than a step): "
                  "current is where the drift line through the frames ends, not the filter's "
                  "mount, which lags a creep."]
    unfollowed = [a.axis for a in s.axes.values() if a.interval_from == FRAMES_SINCE_STEP]
    if unfollowed:
        lines += ["", f"{' and '.join(unfollowed).capitalize()}: the frames' own pose stepped "
                  "and the filter's mount did not follow (beyond both intervals): current is "
                  "the frames' mean since their step, with its standard error; smooth the "
                  "drive (`smooth` splits it at the step) for the mount itself."]
    truth = [a for a in s.axes.values() if math.isfinite(a.true_current)]
    if truth:
        lines += ["", "Against the true mount (ground truth):", "",
                  "| axis | true | error | in the 95 % interval | true change at |",
                  "| --- | --- | --- | --- | --- |"]
        for a in truth:
            covered = {True: "yes", False: "no", None: "–"}[a.covers_truth]
            when = (f"{fmt(a.true_changed_at_s, 's')} s" if math.isfinite(a.true_changed_at_s)
                    else "no change")
            lines.append(f"| {a.axis} [{a.unit}] | {fmt(a.true_current, a.unit)} | "
                         f"{fmt(a.error, a.unit, True)} | {covered} | {when} |")
    if s.monitor is not None:
        m = s.monitor
        alarm = (f"first alarm ({m.first_alarm_state}) at frame "
                 f"{m.first_alarm[0]}, t = {fmt(m.first_alarm[1], 's')} s"
                 if m.first_alarm else "no alarm")
        lines += ["", f"Monitor: now **{m.final_state}**; {alarm}; "
                  + ", ".join(f"{k or '(empty)'} {fmt(v, 's')} s" for k, v in m.seconds.items())
                  + ".", ""]
        for frame, t, before, after in m.transitions[:30]:
            lines.append(f"- t = {fmt(t, 's')} s (frame {frame}): {before or '(empty)'} → "
                         f"{after or '(empty)'}")
        if len(m.transitions) > 30:
            lines.append(f"- … {len(m.transitions) - 30} more")
    return lines


def _percent(p: float) -> str:
    if p > 0.999:
        return "> 99.9 %"
    if p < 0.001:
        return "< 0.1 %"
    return f"{100 * p:.1f} %"


# --- figure ----------------------------------------------------------------------------------


def drift_figure(plt: Any, table: Mapping[str, NDArray], summary: DriftSummary,
                 nominal: object | None, truth: Mapping[str, NDArray] | None, path: Path,
                 title: str) -> Path:
    """PNG over time [s]: per mount axis the per-frame pose faint, the mount with its 95 %
    band, the nominal with its tolerance band, the true mount (dashed) and the change found
    (red line); below, the monitor's state as coloured spans with its transitions marked."""
    t = np.asarray(table["t"], float)
    axes_spec = [a for a in MOUNT_AXES if a[0] in summary.axes]
    with_monitor = summary.monitor is not None
    ratios = [2.2] * len(axes_spec) + [0.8] * with_monitor
    fig, axes = plt.subplots(len(ratios), 1, figsize=(11, 1.0 + 1.6 * sum(ratios)),
                             sharex=True, squeeze=False, gridspec_kw={"height_ratios": ratios})
    for ax, spec in zip(axes[: len(axes_spec), 0], axes_spec, strict=True):
        _mount_panel(ax, table, t, spec, summary.axes[spec[0]], nominal, truth)
    if with_monitor:
        _state_panel(axes[-1, 0], table, t)
    for ax in axes[:, 0]:
        for a in summary.axes.values():
            if math.isfinite(a.changed_at_s):
                ax.axvline(a.changed_at_s, color=CHANGE_COLOR, lw=1.0, ls=":")
    axes[-1, 0].set_xlabel("time [s]")
    axes[0, 0].legend(loc="upper left", fontsize=8, ncol=3)
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


def _mount_panel(ax: Any, table: Mapping, t: NDArray, spec: tuple, a: Any,
                 nominal: object | None, truth: Mapping | None) -> None:
    name, unit, col, std_col, _, new_lo, new_hi, nom_attr, tol_attr = spec
    pose = POSE_COLUMNS[name]
    if pose in table:
        ax.plot(t, np.asarray(table[pose], float), ".", color=POSE_COLOR, ms=2,
                label="frame pose")
    mount = np.asarray(table[col], float)
    if std_col in table:
        s = Z95 * np.asarray(table[std_col], float)
        ax.fill_between(t, mount - s, mount + s, color=MOUNT_COLOR, alpha=0.25, lw=0,
                        label="mount 95 %")
    if new_lo in table and new_hi in table:
        ax.fill_between(t, np.asarray(table[new_lo], float), np.asarray(table[new_hi], float),
                        color="tab:purple", alpha=0.2, lw=0, label="monitor's new 95 %")
    ax.plot(t, mount, "-", color=MOUNT_COLOR, lw=1.4, label="mount")
    values = [mount[np.isfinite(mount)]]
    if nominal is not None:
        ref, tol = float(getattr(nominal, nom_attr)), float(getattr(nominal, tol_attr))
        ax.axhspan(ref - tol, ref + tol, color=NOMINAL_COLOR, alpha=0.12, lw=0,
                   label="nominal ± tolerance")
        ax.axhline(ref, color=NOMINAL_COLOR, lw=1.0, label="nominal")
        values.append(np.array([ref - tol, ref + tol]))
    if truth is not None and col in truth:
        true = np.asarray(truth[col], float)
        if np.isfinite(true).any():
            ax.plot(np.asarray(truth["t"], float), true, "--", color=TRUTH_COLOR, lw=1.1,
                    label="true mount")
            values.append(true[np.isfinite(true)])
    v = np.concatenate(values)
    lo, hi = float(v.min()), float(v.max())
    room = max(hi - lo, 1.0 if unit == "deg" else 0.02 * abs(hi), 1e-9)
    ax.set_ylim(lo - 0.5 * room, hi + 0.5 * room)  # the shaking would flatten the mount
    ax.set_ylabel(f"{name} [{unit}]")
    ax.set_title(f"{name}: now {fmt(a.current, unit)} {unit}, change "
                 f"{fmt(a.change, unit, True)} ± {fmt(a.change_std, unit)} {unit}",
                 fontsize=9, loc="left")
    ax.grid(alpha=0.3)


def _state_panel(ax: Any, table: Mapping, t: NDArray) -> None:
    states = np.asarray(table["monitor_state"], dtype=object)
    end = t[-1] + (t[-1] - t[-2] if len(t) > 1 else 1.0)
    for start, stop, state in state_runs(states):
        x1 = t[stop] if stop < len(t) else end
        ax.axvspan(t[start], x1, color=STATE_COLORS.get(str(state), "#607d8b"), lw=0)
        if x1 - t[start] > 0.06 * max(end - t[0], 1e-9):
            ax.text(0.5 * (t[start] + x1), 0.5, str(state), ha="center", va="center",
                    fontsize=8)
        if start > 0:
            ax.axvline(t[start], color="k", lw=0.8)
    ax.set_yticks([])
    ax.set_ylabel("monitor")


# --- HTML ------------------------------------------------------------------------------------


def write_html(markdown: str, out: Path, path: Path) -> Path:
    """``markdown`` (the report, its images relative to ``out``) as one HTML page at ``path``
    with the images embedded as data URIs: a single file to mail or attach."""
    from markdown_it import MarkdownIt

    # raw HTML off: a title, a file or a drive name with markup in it is shown as text
    body = MarkdownIt("commonmark", {"html": False}).enable("table").render(markdown)

    def embed(match: re.Match) -> str:
        image = out / html.unescape(match.group(1))
        if not image.is_file():
            return match.group(0)
        data = base64.b64encode(image.read_bytes()).decode("ascii")
        return f'src="data:image/png;base64,{data}"'

    body = re.sub(r'src="([^":]+\.png)"', embed, body)
    title = markdown.splitlines()[0].lstrip("# ").strip() if markdown else "report"
    page = ("<!DOCTYPE html>\n<html><head><meta charset=\"utf-8\">"
            f"<title>{html.escape(title)}</title><style>{_CSS}</style></head>\n<body>\n"
            f"{body}</body></html>\n")
    path.write_text(page, encoding="utf-8")
    return path


_CSS = ("body{font-family:sans-serif;max-width:1150px;margin:2em auto;padding:0 1em}"
        "table{border-collapse:collapse;margin:1em 0}td,th{border:1px solid #ccc;"
        "padding:3px 8px;text-align:right}th{background:#f4f4f4}img{max-width:100%}")


__all__: Sequence[str] = ["drift_figure", "fmt", "summary_lines", "write_html"]
