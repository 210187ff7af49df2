"""A smoothed drive condensed: the mean mount with 95 % intervals (the model's and the
data's, from batch means of measured pose − smoothed mount) and its drift
(``summarize_mount``), as JSON-ready numbers and a Markdown table."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

from vipm_track.measurement import PairMeasurement

from .forward_slow import slow_drive_note
from .long_run import batch_means
from .mount_change import short_drive_note
from .mount_steps import (
    StepTestConfig,
    mount_steps,
    pairs_steps,
    steps_text,
    trend_statistic,
    untested_drive_note,
    usable_angles,
)
from .pair_height import HEIGHT_SCALE_WARNING, measured_heights
from .smoother_config import SmoothedFrame
from .wheel_speed import SpeedSource

FloatArray = NDArray[np.float64]


def summarize_mount(
    frames: Sequence[SmoothedFrame], measurements: Sequence[PairMeasurement] | None = None,
    step_test: StepTestConfig | None = None, speed: SpeedSource | None = None,
) -> dict[str, object]:
    """The drive's extrinsics in brief (degrees, metres, minutes): for mount pitch, roll and
    height the mean with a 95 % interval, its 1-σ, the start and end values, the drift
    (least-squares slope per minute and max − min), plus the frame counts by status.

    Model interval: mean ± 1.96 × the mean per-frame σ (the smoothed mount of neighbouring
    frames is almost fully correlated, so the per-frame σ is what the mean is known to).
    With ``measurements`` (the pairs that were smoothed), pitch and roll are also checked
    against the data: the batch-means standard error (``filters.long_run``) of the measured
    frame pose minus the smoothed mount, i.e. of what the model calls body shaking and
    noise. Where slow errors the model lacks (road camber, load, the front end's tracking
    correlation) make that wider, the interval is the data's (``interval_from``: ``data``);
    ``std_model`` / ``std_data`` give both. ``step_test``: the batch's step and drift tests'
    design where they ran (a drive too short for them is then warned of).

    With ``speed`` (the wheel speed the drive was smoothed with, on the camera clock) the
    height is checked against the heights the pairs measure with it (``pair_height``) the
    same way; the model holds the camera height still at the mount's, so where the body's
    height swings (a heaving body, a load shifting) it can settle away from the heights'
    mean (a car's ±10 % swing: 1.619 ± 0.002 m, the frames' mean 1.513 m). Where the pairs'
    mean height is beyond both intervals from the mount's, the height's mean and interval
    are the pairs' (``height_from_pairs`` says so)."""
    good = [f for f in frames if f.initialised and np.all(np.isfinite(f.mount))]
    counts: dict[str, int] = {}
    for f in frames:
        counts[f.status] = counts.get(f.status, 0) + 1
    out: dict[str, object] = {"frames": len(frames), "status_counts": counts}
    if not good:
        out["note"] = "no frame has an estimate"
        return out
    t = np.array([f.t for f in good])
    note = short_drive_note(float(t[-1] - t[0])) or (
        "" if step_test is None else untested_drive_note(t, step_test))
    if note:
        out["short_drive"] = note
    mount = np.array([f.mount for f in good])
    std = np.array([f.mount_std for f in good])
    residual = _pose_residuals(good, measurements, speed)
    out["duration_s"] = float(t[-1] - t[0])
    steps = mount_steps_in(mount[:, :2], std[:, :2])
    if not np.isfinite(std[:, :2]).any() and step_test is not None and measurements:
        # no σ (``--no-std``): where the batch's own test on the pairs let the mount jump
        steps = _pairs_steps(t, measurements, step_test)
    if steps:  # a mean across a knock is neither mount: the mount since the last one
        out["mount_steps"] = [{"t": float(t[k]),
                               "pitch_deg": math.degrees(mount[k, 0] - mount[k - 1, 0]),
                               "roll_deg": math.degrees(mount[k, 1] - mount[k - 1, 1])}
                              for k in steps]
        last = steps[-1]
        out["since_step"] = (
            f"the mount stepped at {', '.join(f'{t[k]:.2f} s' for k in steps)} (pitch "
            f"{math.degrees(mount[last, 0] - mount[last - 1, 0]):+.2f}°, roll "
            f"{math.degrees(mount[last, 1] - mount[last - 1, 1]):+.2f}° at the last): the "
            f"mount given is that of the {t[-1] - t[last]:.1f} s since; before it pitch "
            f"{math.degrees(mount[last - 1, 0]):.3f}°, roll "
            f"{math.degrees(mount[last - 1, 1]):.3f}°")
        t, mount, std = t[last:], mount[last:], std[last:]
        residual = None if residual is None else residual[last:]
    elif step_test is None and measurements is not None:
        note = _unfollowed_step_note(measurements, out)
        if note:
            out["pairs_step"] = note
    for i, (name, unit, conv) in enumerate(
        (("pitch", "deg", np.degrees), ("roll", "deg", np.degrees), ("height", "m", np.asarray))
    ):
        v = np.asarray(conv(mount[:, i]), dtype=float)
        sd = np.asarray(conv(std[:, i]), dtype=float)
        mean = float(np.mean(v))
        sigma = float(np.nanmean(sd)) if np.any(np.isfinite(sd)) else float("nan")
        half, source, sigma_data = 1.96 * sigma, "model", float("nan")
        data = batch_means(conv(residual[:, i])) if residual is not None else None
        if data is not None:
            sigma_data = data.std
            if not data.half_width95 <= half:  # also where the model gave no σ
                half, source = data.half_width95, "data"
            # the pitch and roll the mount is fitted to scatter about it; the heights the
            # model holds still at the mount's may not (module doc)
            offset = float(np.nanmean(conv(residual[:, i])))
            if i == 2 and abs(offset) > 1.96 * math.hypot(sigma if math.isfinite(sigma) else 0,
                                                          sigma_data):
                out["height_from_pairs"] = _height_note(mean, mean + offset, sigma_data)
                mean, half, source = mean + offset, data.half_width95, "data"
        slope = float(np.polyfit(t / 60.0, v, 1)[0]) if len(t) > 1 and t[-1] > t[0] else 0.0
        out[name] = {
            "unit": unit,
            "mean": mean,
            "ci95": [mean - half, mean + half],
            "std": sigma if source == "model" else sigma_data,
            "std_model": sigma,
            "std_data": sigma_data,
            "interval_from": source,
            "start": float(v[0]),
            "end": float(v[-1]),
            "drift_per_min": slope,
            "max_minus_min": float(np.max(v) - np.min(v)),
        }
    if measurements is not None:
        note = _height_scale_note(float(out["height"]["mean"]), measurements)  # type: ignore[index]
        if note:
            out["height_scale"] = note
        note = slow_drive_note(measurements)
        if note:
            out["slow_forward"] = note
        if step_test is not None and step_test.enabled:
            note = _trend_note(measurements, step_test, out)
            if note:
                out["pairs_trend"] = note
    return out


def _pairs_steps(t: FloatArray, measurements: Sequence[PairMeasurement],
                 step_test: StepTestConfig) -> list[int]:
    """Indices into the frames at times ``t`` [s] where the step test on the usable pairs'
    angles (``mount_steps``, the batch's, pitch or roll) puts a step of the mount."""
    if not step_test.enabled:
        return []
    found = {int(np.searchsorted(t, onset))
             for onset, _, _ in pairs_steps(*usable_angles(measurements), step_test)}
    return sorted(k for k in found if 0 < k < len(t))


#: a step of the smoothed mount between two frames beyond this many of its σ, and beyond
#: ``STEP_OVER_TYPICAL`` × its typical change from frame to frame, is a knock (the batch
#: lets its mount jump where its step tests found one; a drift moves it by hundredths of σ)
STEP_SIGMAS = 3.0
STEP_OVER_TYPICAL = 10.0


def mount_steps_in(mount: FloatArray, std: FloatArray) -> list[int]:
    """Indices k where the smoothed mount (n, axes) [rad] steps from frame k-1 to k on any
    axis (``STEP_SIGMAS``, ``STEP_OVER_TYPICAL``), with its per-frame σ ``std`` (n, axes)."""
    if len(mount) < 3:
        return []
    change = np.abs(np.diff(mount, axis=0))
    typical = np.median(change, axis=0)
    sigma = np.maximum(std[1:], std[:-1])
    with np.errstate(invalid="ignore"):
        step = (change > STEP_SIGMAS * sigma) & (change > STEP_OVER_TYPICAL * typical)
    return [int(k) + 1 for k in np.flatnonzero(step.any(axis=1))]


def _height_scale_note(height_m: float, measurements: Sequence[PairMeasurement]) -> str:
    """A warning where the smoothed ``height_m`` is beyond ``HEIGHT_SCALE_WARNING`` times (or
    below its inverse) the median height the usable ``measurements`` assumed ("" if not)."""
    assumed = [m.height_assumed for m in measurements if m.ok and m.height_assumed > 0]
    if not assumed or not np.isfinite(height_m):
        return ""
    ratio = height_m / float(np.median(assumed))
    if 1.0 / HEIGHT_SCALE_WARNING <= ratio <= HEIGHT_SCALE_WARNING:
        return ""
    return (f"the smoothed height {height_m:.3f} m is {ratio:.2f}× the "
            f"{float(np.median(assumed)):g} m the pairs were estimated with: the wheel speed "
            "sets the scale, so it likely belongs to another drive, has another unit or scale "
            "(--speed-scale), or is offset in time (--clock-offset).")


def _trend_note(measurements: Sequence[PairMeasurement], cfg: StepTestConfig,
                summary: dict[str, object]) -> str:
    """A warning where the usable pairs' pitch or roll trends within the drive beyond the
    step test's threshold but below the drift test's (``mount_steps.trend_statistic``,
    within the segments the steps leave; each axis's ``pairs_trend_per_min`` and
    ``pairs_trend_t`` go into ``summary``): the batch then holds the mount still, and the
    trend is the body, the road or a mount creeping faster than the data can tell."""
    t, angles = usable_angles(measurements)
    trending = []
    for i, name in enumerate(("pitch", "roll")):
        x = angles[:, i]
        trend = trend_statistic(t, x, mount_steps(t, x, cfg), cfg)
        if trend is None or not isinstance(summary.get(name), dict):
            continue
        per_min = float(np.degrees(trend[0]) * 60.0)
        summary[name].update(pairs_trend_per_min=per_min, pairs_trend_t=trend[1])  # type: ignore[union-attr]
        if cfg.threshold < trend[1] <= cfg.trend_threshold:
            trending.append(f"{name} by {per_min:+.2f}°/min (t = {trend[1]:.1f})")
    if not trending:
        return ""
    return (f"the pairs' {' and '.join(trending)} trend within the drive, beyond what the step "
            f"test calls significant ({cfg.threshold:g}) but below what the drift test calls "
            f"a drift ({cfg.trend_threshold:g}, above a real road's wander): the mount is held "
            "still and its intervals assume it did not creep; if it may have, judge it from "
            "a longer drive (docs/filters.md)")


def _unfollowed_step_note(measurements: Sequence[PairMeasurement],
                          summary: dict[str, object]) -> str:
    """A warning where the usable pairs' pitch or roll steps (``mount_steps``, its default
    test; each step into ``summary["pairs_steps"]``) and the smoothed mount did not step with
    it: a fixed-lag smoother's mount follows a small knock over tens of seconds, so its mean
    and interval held neither mount (45.4 [45.26, 45.57] for 45° then 46°, no warning)."""
    found = pairs_steps(*usable_angles(measurements))
    if not found:
        return ""
    summary["pairs_steps"] = [{"t": at, "axis": name, "step_deg": math.degrees(step)}
                              for at, name, step in found]
    return (f"the pairs' {steps_text(found)}: this smoother's mount did not follow at once (a "
            "fixed-lag window follows a small knock over tens of seconds): its mean and "
            "interval may hold neither mount; the batch smoother (no --lag) splits the drive "
            "at the step")


def _pose_residuals(
    frames: Sequence[SmoothedFrame], measurements: Sequence[PairMeasurement] | None,
    speed: SpeedSource | None = None,
) -> FloatArray | None:
    """(n, 3) measured pitch/roll of each frame's pair minus the frame's smoothed mount
    (rad; NaN where the pair is not usable or the smoother rejected its pose: one corrupt
    row 75° off widened the data's interval fifteenfold), and the height the wheel ``speed``
    puts each frame at (measured by the pair after it) minus its smoothed mount's (m; NaN
    without speed or such a pair, and beyond ``HEIGHT_OUTLIER_MADS`` robust σ of the
    others), or None without measurements."""
    if measurements is None:
        return None
    by_frame = {m.frame: m for m in measurements}
    out = np.full((len(frames), 3), np.nan)
    for i, f in enumerate(frames):
        m = by_frame.get(f.frame)
        if m is not None and m.ok and "pose" not in f.gated:
            out[i, :2] = m.z[2:4] - f.mount[:2]
    if speed is not None:
        heights, variances = measured_heights(list(measurements), speed.t, speed.speed_mps)
        of_frame = {m.frame - 1: h for m, h in zip(measurements, heights, strict=True)}
        out[:, 2] = [of_frame.get(f.frame, np.nan) - f.mount[2] for f in frames]
        out[~_robust_inliers(out[:, 2]), 2] = np.nan
        # heights that scatter within their own noise show no swing: a steady body's pairs
        # sit a little above the mount (their 1/travel bias), which a long drive's small
        # standard error took for one (+2.8 mm on a 30-s car)
        if np.isfinite(out[:, 2]).sum() >= 3:
            stated = math.sqrt(float(np.nanmedian(variances)))
            if not _robust_spread(out[:, 2])[1] > SWING_OVER_NOISE * stated:
                out[:, 2] = np.nan
    return out


#: the pairs' heights swing (the summary's height check runs) where their robust spread
#: about the mount is beyond this many times their stated σ
SWING_OVER_NOISE = 2.0

#: a pair's height residual this many robust σ (1.4826 × MAD) from the median is an outlier
#: (a pair whose travel is near zero puts the camera metres up)
HEIGHT_OUTLIER_MADS = 5.0


def _robust_spread(x: FloatArray) -> tuple[float, float]:
    """(median, 1.4826 × median absolute deviation) of the finite values of ``x``."""
    finite = x[np.isfinite(x)]
    median = float(np.median(finite))
    return median, 1.4826 * float(np.median(np.abs(finite - median)))


def _robust_inliers(x: FloatArray) -> NDArray[np.bool_]:
    """Finite values of ``x`` within ``HEIGHT_OUTLIER_MADS`` robust σ of their median."""
    finite = np.isfinite(x)
    if finite.sum() < 3:
        return finite
    median, mad = _robust_spread(x)
    with np.errstate(invalid="ignore"):
        return finite & (np.abs(x - median) <= HEIGHT_OUTLIER_MADS * mad if mad > 0 else finite)


def _height_note(model_m: float, pairs_m: float, pairs_std_m: float) -> str:
    """Why the summary's height is the pairs' mean ``pairs_m`` and not the mount's."""
    return (f"the heights the wheel speed and the pairs' travel measure average {pairs_m:.3f} "
            f"m (±{1.96 * pairs_std_m:.3f} m), the smoothed mount's {model_m:.3f} m: the "
            "camera's height swings more than the model, which holds it at the mount's, "
            "allows (a heaving body, a shifting load); the height given is the pairs' mean")


def summary_markdown(summary: dict[str, object]) -> str:
    """A Markdown table of ``summarize_mount``'s result."""
    lines = [
        f"Frames: {summary['frames']} ({', '.join(f'{k} {v}' for k, v in sorted(summary['status_counts'].items()))})",  # type: ignore[union-attr]  # noqa: E501
        "",
        "| mount | mean | 95 % interval | 1-σ | interval from | start | end | drift / min "
        "| max − min |",
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    for name in ("pitch", "roll", "height"):
        d = summary.get(name)
        if not isinstance(d, dict):
            continue
        fmt = "{:.4f}" if d["unit"] == "m" else "{:.3f}"
        f = fmt.format
        lines.append(
            f"| {name} ({d['unit']}) | {f(d['mean'])} | [{f(d['ci95'][0])}, {f(d['ci95'][1])}] | "
            f"{f(d['std'])} | {d.get('interval_from', 'model')} | {f(d['start'])} | "
            f"{f(d['end'])} | {f(d['drift_per_min'])} | {f(d['max_minus_min'])} |"
        )
    return "\n".join(lines) + "\n" + "".join(f"\n**Warning:** {w}\n"
                                             for w in summary_warnings(summary))


def summary_warnings(summary: dict[str, object]) -> list[str]:
    """What the summary's numbers do not say on their own: a step of the mount (they are of
    the frames since), most pairs rejected, a drive too short for the step test, a height
    off the pairs', slow forward driving, a trend of the pairs."""
    return [w for w in (str(summary.get("since_step", "")), str(summary.get("pairs_step", "")),
                        _rejection_warning(summary),
                        str(summary.get("short_drive", "")), str(summary.get("height_scale", "")),
                        str(summary.get("height_from_pairs", "")),
                        str(summary.get("slow_forward", "")),
                        str(summary.get("pairs_trend", ""))) if w]


#: share of the frames beyond which the pairs' rejection is called out in the summary
REJECTED_SHARE_WARNING = 0.5


def _rejection_warning(summary: dict[str, object]) -> str:
    """A warning where most frames' pairs were rejected in part or whole (``partial`` /
    ``gated``): the intervals then rest on what the model kept, which may be the wrong part (a
    wheel speed from another drive or offset in time wins over the images)."""
    counts: dict[str, int] = summary.get("status_counts", {})  # type: ignore[assignment]
    frames = int(summary.get("frames", 0) or 0)  # type: ignore[call-overload]
    rejected = counts.get("partial", 0) + counts.get("gated", 0)
    if not frames or rejected <= REJECTED_SHARE_WARNING * frames:
        return ""
    return (f"the pairs' pose or motion was rejected on {rejected} of {frames} "
            "frames: the images and the rest of the model disagree there (a wheel speed from "
            "another drive or offset in time, a mount that changed, a body the model does not "
            "describe). The intervals above rest on what was kept; check the inputs before "
            "trusting them.")
