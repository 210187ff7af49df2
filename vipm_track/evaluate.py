"""Errors of a per-frame estimates table against ground truth, and their summary table.

Both tables are column dicts as :func:`vipm_track.table.read_table` returns them (the
``CONVENTIONS.md`` columns); rows are matched by ``frame``. Only estimate rows with status
``ok`` and finite ground truth are scored. Errors are signed (estimate − truth) per frame;
the summary reports statistics of their absolute values.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

#: Error name → (unit, description) in the order the table lists them.
ERROR_UNITS: dict[str, str] = {
    "pitch_deg": "deg",
    "roll_deg": "deg",
    "height_m": "m",
    "prev_pitch_deg": "deg",
    "prev_roll_deg": "deg",
    "pitch_change_deg": "deg",
    "roll_change_deg": "deg",
    "distance_m": "m",
    "distance_pct": "%",
    "yaw_deg": "deg",
}


@dataclass(frozen=True)
class ErrorStats:
    """Statistics of |error| over ``n`` frames: mean, median, 95th percentile, max."""

    n: int
    mean: float
    median: float
    p95: float
    max: float


def error_stats(errors: NDArray) -> ErrorStats:
    """:class:`ErrorStats` of the finite entries of ``errors`` (NaN stats when none)."""
    e = np.abs(np.asarray(errors, dtype=float))
    e = e[np.isfinite(e)]
    if e.size == 0:
        return ErrorStats(0, *([float("nan")] * 4))
    return ErrorStats(int(e.size), float(e.mean()), float(np.median(e)),
                      float(np.percentile(e, 95)), float(e.max()))


def frame_errors(est: Mapping[str, NDArray], truth: Mapping[str, NDArray],
                 scored: str = "ok") -> dict[str, NDArray]:
    """Per-frame signed errors (estimate − truth) for the frames of ``est`` that are scored
    and in ``truth``: ``scored="ok"`` the rows whose status is ``ok`` (an estimator's verdict);
    ``"finite"`` every row with a finite pitch, whatever its status word (a filter's
    ``partial`` or ``predicted`` rows have numbers too).

    Returns ``frame`` (the scored frames) and, where both tables have the columns, the
    entries of :data:`ERROR_UNITS`: poses (pitch, roll in degrees; height in metres: the
    height assumed by the estimator or estimated by a filter), pose changes within the pair
    (``pitch − prev_pitch``, what a camera-relative ground truth such as KITTI's can check),
    travel distance (metres and % of the true distance) and yaw change."""
    n = len(est["frame"])
    if scored == "finite":
        counts = np.isfinite(np.asarray(est.get("pitch_deg", np.full(n, np.nan)), float))
    elif scored == "ok":
        counts = np.asarray(est.get("status", np.array(["ok"] * n, dtype=object))) == "ok"
    else:
        raise ValueError(f"scored must be 'ok' or 'finite', got {scored!r}")
    index = {int(f): i for i, f in enumerate(truth["frame"])}
    rows = [(i, index[int(f)]) for i, f in enumerate(est["frame"])
            if counts[i] and int(f) in index]
    ei = np.array([r[0] for r in rows], dtype=int)
    ti = np.array([r[1] for r in rows], dtype=int)
    out: dict[str, NDArray] = {"frame": np.asarray(est["frame"])[ei]}

    def diff(e_col: str, t_col: str | None = None) -> NDArray | None:
        t_col = t_col or e_col
        if e_col not in est or t_col not in truth:
            return None
        return np.asarray(est[e_col], float)[ei] - np.asarray(truth[t_col], float)[ti]

    for name in ("pitch_deg", "roll_deg", "height_m", "prev_pitch_deg", "prev_roll_deg"):
        d = diff(name)
        if d is not None:
            out[name] = d
    for angle in ("pitch", "roll"):
        cur, prev = f"{angle}_deg", f"prev_{angle}_deg"
        if all(c in est and c in truth for c in (cur, prev)):
            e = np.asarray(est[cur], float)[ei] - np.asarray(est[prev], float)[ei]
            t = np.asarray(truth[cur], float)[ti] - np.asarray(truth[prev], float)[ti]
            out[f"{angle}_change_deg"] = e - t
    if all(c in est and c in truth for c in ("tx_m", "tz_m")):
        d_est = np.hypot(np.asarray(est["tx_m"], float)[ei], np.asarray(est["tz_m"], float)[ei])
        d_true = np.hypot(np.asarray(truth["tx_m"], float)[ti],
                          np.asarray(truth["tz_m"], float)[ti])
        out["distance_m"] = d_est - d_true
        with np.errstate(divide="ignore", invalid="ignore"):
            out["distance_pct"] = np.where(d_true > 0, 100.0 * (d_est - d_true) / d_true, np.nan)
    d = diff("yaw_deg")
    if d is not None:
        out["yaw_deg"] = d
    return out


def error_table(errors: dict[str, NDArray], names: tuple[str, ...] | None = None,
                title: str = "error") -> str:
    """Markdown table of |error| statistics (n, mean, median, p95, max) per error name."""
    names = names or tuple(n for n in ERROR_UNITS if n in errors)
    lines = [f"| {title} | unit | n | mean | median | p95 | max |",
             "| --- | --- | --- | --- | --- | --- | --- |"]
    for name in names:
        s = error_stats(errors[name])
        unit = ERROR_UNITS.get(name, "")
        digits = 4 if unit == "m" else 3
        cells = [f"{v:.{digits}f}" for v in (s.mean, s.median, s.p95, s.max)]
        label = name.removesuffix(f"_{unit}").removesuffix("_pct")
        lines.append(f"| {label} | {unit} | {s.n} | " + " | ".join(cells) + " |")
    return "\n".join(lines)
