"""The fleet report: per vehicle, each drive's smoothed mount (pitch, roll, height) with its
95 % interval, drives in time order, so a camera that moved between drives stands out
(PNG + Markdown)."""

from __future__ import annotations

from collections.abc import Sequence
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from ..table import float_or_nan
from .report import _pyplot

AXES: tuple[tuple[str, str, str], ...] = (("pitch", "deg", "°"), ("roll", "deg", "°"),
                                          ("height", "m", " m"))


def started_instant(text: str) -> datetime | None:
    """A drive's ``started`` (ISO 8601: a date, or a date and time with or without a UTC
    offset) as a time zone-aware instant, one without an offset taken as UTC; None where
    it is no such time."""
    when = _parsed(text)
    return when if when is None or when.tzinfo is not None else when.replace(tzinfo=UTC)


def _has_zone(text: str) -> bool:
    when = _parsed(text)
    return when is not None and when.tzinfo is not None


def _parsed(text: str) -> datetime | None:
    """``text`` as ISO 8601, as it says it (with or without a UTC offset); None if not."""
    try:
        return datetime.fromisoformat(str(text).strip())
    except ValueError:
        return None


def by_vehicle(rows: Sequence[dict[str, Any]]) -> dict[str, list[dict[str, Any]]]:
    """The ok drives of ``rows`` grouped by ``vehicle`` (where none is given, by the nominal
    calibration: a cart's drives are not compared with a car's), each group in time order
    (``started`` as an instant — 10:00+02:00 before 09:00+00:00 —, then the first frame's
    time, then the drive's name)."""
    groups: dict[str, list[dict[str, Any]]] = {}
    for row in rows:
        if row.get("status") == "ok":
            groups.setdefault(_vehicle(row), []).append(row)

    def order(r: dict[str, Any]) -> tuple:
        when = started_instant(str(r.get("started") or ""))
        return (when is None, when.timestamp() if when else 0.0,
                float_or_nan(r.get("t_start_s")), str(r["drive"]))

    for drives in groups.values():
        drives.sort(key=order)
    return dict(sorted(groups.items()))


def _vehicle(row: dict[str, Any]) -> str:
    if row.get("vehicle"):
        return str(row["vehicle"])
    nominal = ", ".join(f"{float_or_nan(row.get(f'nominal_{axis}_{unit}')):g}{sign}"
                        for axis, unit, sign in AXES)
    return f"(none; nominal {nominal})"


def moved(previous: dict[str, Any], drive: dict[str, Any]) -> list[str]:
    """The mount axes whose 95 % intervals of two consecutive drives do not overlap."""
    out = []
    for axis, unit, _ in AXES:
        a = (float_or_nan(previous.get(f"mount_{axis}_ci95_low_{unit}")),
             float_or_nan(previous.get(f"mount_{axis}_ci95_high_{unit}")))
        b = (float_or_nan(drive.get(f"mount_{axis}_ci95_low_{unit}")),
             float_or_nan(drive.get(f"mount_{axis}_ci95_high_{unit}")))
        if a[1] < b[0] or b[1] < a[0]:
            out.append(axis)
    return out


def fleet_markdown(rows: Sequence[dict[str, Any]]) -> str:
    """The report's Markdown: counts, then per vehicle a table of its drives in time order
    with the mount, its interval and the monitor's verdict; a drive whose interval misses
    the previous drive's is marked (the camera moved between them); failed drives last."""
    ok = [r for r in rows if r.get("status") == "ok"]
    lines = [f"Drives: {len(rows)}, ok {len(ok)}, failed {len(rows) - len(ok)}.", ""]
    for vehicle, drives in by_vehicle(rows).items():
        lines += [f"## Vehicle {vehicle}", "",
                  "| drive | frames | pitch (°) [95 %] | roll (°) [95 %] | height (m) [95 %] "
                  "| monitor | moved since previous |",
                  "| --- | --- | --- | --- | --- | --- | --- |"]
        for i, r in enumerate(drives):
            cells = []
            for axis, unit, _ in AXES:
                fmt = "{:.4f}" if unit == "m" else "{:.3f}"
                mid, lo, hi = (float_or_nan(r.get(f"mount_{axis}_{part}{unit}"))
                               for part in ("", "ci95_low_", "ci95_high_"))
                cells.append(f"{fmt.format(mid)} [{fmt.format(lo)}, {fmt.format(hi)}]")
            shift = ", ".join(moved(drives[i - 1], r)) if i else ""
            flag = f"**{shift}**" if shift else ""
            lines.append(f"| {r['drive']} | {r.get('frames')} | {' | '.join(cells)} | "
                         f"{r.get('monitor_verdict', '')} | {flag} |")
        zones = {_has_zone(str(r.get("started"))) for r in drives if r.get("started")}
        if len(zones) > 1:
            lines.append("Some drives' `started` has a UTC offset and some not: those without "
                         "are taken as UTC in this order.")
        lines.append("")
    warned = [r for r in ok if r.get("warnings")]
    if warned:  # what the drives' numbers do not say on their own
        lines += ["## Warnings", ""]
        lines += [f"- **{r['drive']}**: {r['warnings']}" for r in warned]
        lines.append("")
    failed = [r for r in rows if r.get("status") != "ok"]
    if failed:
        lines += ["## Failed drives", "", "| drive | error |", "| --- | --- |"]
        lines += [f"| {r['drive']} | {str(r.get('status')).replace('|', '/')} |" for r in failed]
        lines.append("")
    return "\n".join(lines)


def write_fleet_report(rows: Sequence[dict[str, Any]], out: str | Path) -> tuple[Path, Path]:
    """``OUT/fleet_report.md`` and ``fleet_report.png`` (one row of pitch / roll / height
    panels per vehicle, each drive's mount with its 95 % interval and the nominal)."""
    out = Path(out)
    md = out / "fleet_report.md"
    md.write_text("# Fleet report\n\n" + fleet_markdown(rows) + "\n")
    groups = by_vehicle(rows)
    png = out / "fleet_report.png"
    plt = _pyplot()
    fig, axes = plt.subplots(max(len(groups), 1), 3, figsize=(12, 2.6 * max(len(groups), 1)),
                             squeeze=False)
    for (vehicle, drives), panel in zip(groups.items(), axes, strict=False):
        x = range(len(drives))
        for ax, (axis, unit, sign) in zip(panel, AXES, strict=True):
            mean = [float_or_nan(r.get(f"mount_{axis}_{unit}")) for r in drives]
            low = [m - float_or_nan(r.get(f"mount_{axis}_ci95_low_{unit}"))
                   for m, r in zip(mean, drives, strict=True)]
            high = [float_or_nan(r.get(f"mount_{axis}_ci95_high_{unit}")) - m
                    for m, r in zip(mean, drives, strict=True)]
            ax.errorbar(list(x), mean, yerr=[low, high], fmt="o", capsize=3)
            ax.plot(list(x), [float_or_nan(r.get(f"nominal_{axis}_{unit}")) for r in drives], "k--",
                    lw=0.8, label="nominal")
            ax.set_title(f"{vehicle}: mount {axis}")
            ax.set_ylabel(f"{axis} ({sign.strip()})")
            ax.set_xticks(list(x), [str(r["drive"]) for r in drives], rotation=30, fontsize=7)
    if not groups:
        axes[0][0].set_title("no drive ok")
    fig.tight_layout()
    fig.savefig(png, dpi=100)
    plt.close(fig)
    return md, png
