"""What ``vipm-track demo`` prints: the run's accuracy, the mount before and after the knock
with intervals against the truth, the monitor's timeline and the height, in a few lines
(``demo_lines``), and where its files are and how to open them (``files_lines``)."""

from __future__ import annotations

import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from .demo import ACCURACY, DemoResult, Interval, MountSpan, extrinsics, title


def demo_lines(result: DemoResult) -> list[str]:
    """What the demo prints: the drive, per-frame accuracy, the mount before and after each
    step, the height, the monitor's timeline and the detection delay, the files."""
    r, n = result, result.nominal
    lines = [title(r) + ".", ""]
    lines.append("Per-frame accuracy against the truth, median / p95 of |error|:")
    for stage, errs in r.accuracy.items():
        head = f"  {stage:<9}"
        if stage == "estimator":
            head += f" ({r.pairs_ok}/{r.pairs} pairs ok)"
        # the estimator's height is the one it assumed (the nominal), not an estimate
        cells = [f"{label} {errs[name].median * k:.{d}f} / {errs[name].p95 * k:.{d}f}{unit}"
                 for name, label, unit, k, d in ACCURACY if name in errs and errs[name].n
                 and not (stage == "estimator" and name == "height_m")]
        lines.append(head + ": " + (", ".join(cells) or "no frame with an estimate"))
    lines += ["", "Mount from the batch smoother (95 % interval; truth; in = the truth lies "
              "inside):"]
    if r.steps_s:
        lines.append("  its mount-change test found a step at t = "
                     + ", ".join(f"{s:.2f} s" for s in r.steps_s)
                     + (f" (the knock: {r.knock_s:.2f} s)" if r.knock_s is not None else ""))
    else:
        lines.append("  its mount-change test found no step"
                     + (f" (the knock: {r.knock_s:.2f} s)" if r.knock_s is not None else ""))
    for span in r.spans:
        where = _span_name(span, r.knock_s)
        lines.append(f"  {where:<14} {span.start_s:5.1f}–{span.end_s:4.1f} s: "
                     f"pitch {_deg(span.pitch)}; roll {_deg(span.roll)}")
    h = r.height
    lines += ["", f"Camera height through the wheel speed (smoother, whole drive): "
              f"{h.value:.4f} m [{h.lo:.4f}, {h.hi:.4f}], truth {h.truth:.4f} m "
              f"({_inside(h)}; nominal {n.height_m:.3f} m)"]
    lines += ["", f"Monitor against the nominal calibration {r.nominal_file.name} (pitch "
              f"{n.pitch_deg:.2f}°, roll {n.roll_deg:.2f}°, height {n.height_m:.3f} m; "
              f"tolerance {n.pitch_tol_deg:g}°, {n.roll_tol_deg:g}°, "
              f"{n.height_tol_m * 1000:g} mm):"]
    shown = list(r.events[:10])
    for ev in shown:
        text = f"  t = {ev['t']:6.2f} s  {ev['state']:<12} {ev['reason']}"
        if ev["state"] == "RECALIBRATE" and ev.get("estimate"):
            text += f"; new extrinsics {_newextrinsics(ev)}"
        lines.append(text)
    if len(r.events) > len(shown):
        lines.append(f"  … {len(r.events) - len(shown)} more events in "
                     f"{r.files['events'].name}")
    lines.append("  " + _verdict(r))
    if r.final is not None and r.final.estimate is not None:
        lines.append(f"  at the end (t = {r.final.t:.2f} s, {r.final.state}): new extrinsics "
                     f"{_newextrinsics(extrinsics(r.final))}")
    return lines


def files_lines(result: DemoResult, recording: str | Path | None = None) -> list[str]:
    """Where the files are and how to open them, and the time each stage took."""
    f = result.files
    out = f["plot"].parent
    named = ", ".join(p.name for p in (f["plot"], f["estimates"], f["track"], f["smoothed"],
                                       f["monitor"], f["events"], f["summary"]))
    lines = [f"Wrote {out}/: {named}; the rendered drive in {result.drive.folder} "
             "(images, gt.csv, speed.csv, camera.yaml)."]
    lines.append(f"  plot: open {f['plot']} (per-frame pose, mount with its 95 % band, "
                 "monitor state; the knock marked)")
    if recording is not None:
        lines.append(f"  rerun: rerun {recording}   (the viewer comes with rerun-sdk)")
    lines.append(f"  more plots: vipm-track report {f['monitor']} --gt "
                 f"{result.drive.truth_file} --out {out / 'report'}")
    parts = ", ".join(f"{k} {v:.1f}" for k, v in result.seconds.items() if math.isfinite(v))
    lines.append(f"Stage times, s: {parts}.")
    return lines


def _span_name(span: MountSpan, knock: float | None) -> str:
    if knock is None:
        return "mount"
    if span.end_s < knock:
        return "before knock"
    return "after knock" if span.start_s >= knock else "across knock"


def _deg(iv: Interval) -> str:
    return (f"{iv.value:.3f}° [{iv.lo:.3f}, {iv.hi:.3f}], truth {iv.truth:.3f}° "
            f"({_inside(iv)})")


def _inside(iv: Interval) -> str:
    if not math.isfinite(iv.truth):
        return "no truth"
    return "in" if iv.covers else "OUTSIDE"


def _verdict(r: DemoResult) -> str:
    if r.knock_s is None:
        flagged = r.flagged_before_knock
        return (f"no knock in this drive; {flagged} frames flagged" if flagged
                else "no knock in this drive, and no flag")
    before = ("no flag before it" if not r.flagged_before_knock
              else f"{r.flagged_before_knock} frames flagged before it")
    if r.calibrated_s is not None:
        before += f" (CALIBRATED from t = {r.calibrated_s:.2f} s)"
    if r.first_flag is None:
        return f"knock at t = {r.knock_s:.2f} s: NOT flagged by the end of the drive; {before}"
    text = (f"knock at t = {r.knock_s:.2f} s: {r.first_flag.state} {r.flag_delay_s:.2f} s "
            "after it")
    rec = r.first_recalibrate
    if rec is not None and rec is not r.first_flag:
        text += f", RECALIBRATE {rec.t - r.knock_s:.2f} s after it"
    return text + f"; {before}"


def _newextrinsics(ev: Mapping[str, Any]) -> str:
    est, iv = ev["estimate"], ev.get("interval95") or {}
    parts = []
    for key, label, unit, digits in (("pitch_deg", "pitch", "°", 2), ("roll_deg", "roll", "°", 2),
                                     ("height_m", "height", " m", 3)):
        value = est.get(key)
        if value is None:
            continue
        text = f"{label} {value:.{digits}f}{unit}"
        lo, hi = iv.get(key, (None, None))
        if lo is not None and hi is not None:
            text += f" [{lo:.{digits}f}, {hi:.{digits}f}]"
        parts.append(text)
    return ", ".join(parts)


