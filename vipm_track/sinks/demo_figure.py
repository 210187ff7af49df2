"""The demo's figure: one PNG of a monitored drive against its truth (``vipm-track demo``):
pose, mount with its 95 % band, monitor state, the knock marked (:func:`write_demo_figure`)."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .drift_report import STATE_COLORS
from .drift_summary import has_finite, state_runs
from .report import _pyplot, _save

#: (label, frame-pose column, mount column, its std column, unit) of the demo figure's panels
DEMO_PANELS: tuple[tuple[str, str, str, str, str], ...] = (
    ("pitch", "pitch_deg", "mount_pitch_deg", "mount_pitch_std_deg", "deg"),
    ("roll", "roll_deg", "mount_roll_deg", "mount_roll_std_deg", "deg"),
    ("height", "height_m", "mount_height_m", "mount_height_std_m", "m"),
)
KNOCK_COLOR, MOUNT_COLOR = "tab:red", "tab:blue"


def write_demo_figure(
    path: str | Path,
    *,
    estimates: Mapping[str, NDArray],
    smoothed: Mapping[str, NDArray],
    truth: Mapping[str, NDArray],
    monitor: Mapping[str, NDArray],
    wheel_height: Mapping[str, NDArray] | None = None,
    knock_s: float | None = None,
    steps_s: tuple[float, ...] = (),
    title: str = "",
) -> Path:
    """PNG of a monitored drive against its truth (``vipm-track demo``), over time [s]: per
    axis (pitch, roll in degrees, height in metres) the true frame pose, the two-frame
    estimates (``estimates``: an estimates table; for height the per-frame heights through
    the wheel speed, ``wheel_height`` columns ``t``, ``height_m``), the smoothed mount
    (``smoothed``: a track table with ``mount_*`` and ``mount_*_std`` columns) with its 95 %
    band and the true mount (``truth``'s ``mount_*`` columns where it has them); then the
    monitor's state over time (``monitor``: ``t``, ``monitor_state``). The knock
    (``knock_s``) is a red line in every panel, the mount steps the smoother found
    (``steps_s``) dotted lines. Tables are column dicts (``table.read_table``)."""
    path = Path(path)
    plt = _pyplot()
    fig, axes = plt.subplots(4, 1, figsize=(11, 11), sharex=True,
                             gridspec_kw={"height_ratios": [2.2, 2.2, 2.2, 1.0]})
    t_truth = np.asarray(truth["t"], float)
    t_est = np.asarray(estimates["t"], float)
    t_sm = np.asarray(smoothed["t"], float)
    for ax, (label, col, mount, std, unit) in zip(axes[:3], DEMO_PANELS, strict=True):
        ax.plot(t_truth, np.asarray(truth[col], float), "-", color="0.65", lw=0.8,
                label="true frame pose")
        if col == "height_m":
            if wheel_height is not None:
                ax.plot(np.asarray(wheel_height["t"], float),
                        np.asarray(wheel_height["height_m"], float), ".", color="tab:orange",
                        ms=2.5, label="per pair, through the wheel speed")
        elif col in estimates:
            ax.plot(t_est, np.asarray(estimates[col], float), ".", color="tab:orange", ms=2.5,
                    label="two-frame estimate")
        if mount in smoothed:
            m = np.asarray(smoothed[mount], float)
            if std in smoothed:
                s = 1.96 * np.asarray(smoothed[std], float)
                ax.fill_between(t_sm, m - s, m + s, color=MOUNT_COLOR, alpha=0.25, lw=0,
                                label="95 % interval")
            ax.plot(t_sm, m, "-", color=MOUNT_COLOR, lw=1.4, label="smoothed mount")
        if mount in truth and has_finite(truth, mount):
            ax.plot(t_truth, np.asarray(truth[mount], float), "--", color="k", lw=1.2,
                    label="true mount")
        _zoom_to_mount(ax, smoothed, truth, mount, std)
        ax.set_ylabel(f"{label} [{unit}]")
        ax.grid(alpha=0.3)
    ax = axes[3]
    states = np.asarray(monitor["monitor_state"], dtype=object)
    t_mon = np.asarray(monitor["t"], float)
    for start, stop, state in state_runs(states):
        x1 = t_mon[stop] if stop < len(t_mon) else t_mon[-1]
        ax.axvspan(t_mon[start], x1, color=STATE_COLORS.get(state, "#607d8b"), lw=0)
        if x1 - t_mon[start] > 0.06 * max(np.ptp(t_mon), 1e-9):
            ax.text(0.5 * (t_mon[start] + x1), 0.5, state, ha="center", va="center",
                    fontsize=8)
    ax.set_yticks([])
    ax.set_ylabel("monitor")
    ax.set_xlabel("time [s]")
    for a in axes:
        for s in steps_s:
            a.axvline(s, color=MOUNT_COLOR, ls=":", lw=1.0)
        if knock_s is not None:
            a.axvline(knock_s, color=KNOCK_COLOR, lw=1.4)
    if knock_s is not None:
        axes[0].annotate("knock", (knock_s, 0.0), xycoords=("data", "axes fraction"),
                         xytext=(4, 4), textcoords="offset points", color=KNOCK_COLOR)
    axes[0].legend(loc="upper left", fontsize=8, ncol=3)
    axes[2].legend(loc="upper left", fontsize=8, ncol=3)
    fig.suptitle(title, fontsize=10)
    path.parent.mkdir(parents=True, exist_ok=True)
    return _save(plt, fig, path)


def _zoom_to_mount(ax: Any, smoothed: Mapping, truth: Mapping, mount: str, std: str) -> None:
    """Limit the y axis to the mount's range with room for the shaking around it: the
    per-frame estimates' outliers would otherwise flatten what the panel is about."""
    values = [np.asarray(t[mount], float) for t in (smoothed, truth) if mount in t]
    values = [v[np.isfinite(v)] for v in values]
    values = [v for v in values if v.size]
    if not values:
        return
    v = np.concatenate(values)
    lo, hi = float(v.min()), float(v.max())
    room = max(hi - lo, 1e-3 * max(abs(hi), 1.0))
    room = max(room, 1.0) if mount.endswith("_deg") else max(room, 0.02 * abs(hi))
    ax.set_ylim(lo - room, hi + room)
