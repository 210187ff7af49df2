"""Calibration drift monitor: a per-frame verdict on whether the camera still sits where its
nominal calibration says (``DriftMonitor``; ``run_monitor`` for a whole sequence).

The states are listed in ``filters.monitor_types``, the test behind them is explained in
``filters.monitor_core``, the nominal calibration files are read by ``filters.nominal``.

The new extrinsics reported with DRIFTING/RECALIBRATE are the nominal plus the median
deviation of the frames after the last step of the mount (``filters.monitor_segments``,
looked for from a second before the CUSUM's change time on; that change time where none
stands out); the 95 % interval uses the long-run variance of a mean of n correlated frames
(× π/2 for the median), or the frames' own batch-means scatter (``filters.long_run``) where
wider. Where those frames rise along a line by more than their scatter makes, the interval
also spans the line's end (a creeping mount, which their median lags); where the line fits
them better than any one step and surely rises, the value is the line's end
(:meth:`DriftMonitor._line_end`). ``scripts/bench_monitor_estimates.py`` scores both against
the truth.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import NDArray

from vipm_track import json_text

from .body_scale import BodyScale
from .long_run import batch_means
from .monitor_core import MonitorCore
from .monitor_segments import last_step
from .monitor_stats import HeaveScale, ar1_coefficient, mean_variance
from .monitor_types import (
    AXES,
    CALIBRATED,
    DRIFTING,
    HOLD,
    INVALID,
    RECALIBRATE,
    STATES,
    UNCALIBRATED,
    MonitorConfig,
    MonitorInput,
    MonitorOutput,
)
from .mount_steps import one_step_squares
from .nominal import NominalCalibration

FloatArray = NDArray[np.float64]

#: how far back [s] the new extrinsics look for a second move of the camera within the frames
#: they are read from (the step test finds older ones; each second more costs every frame)
MOVED_AGAIN_S = 6.0
#: ... and how far apart the two sides' medians must read, in their 95 % half-widths taken
#: together: the splits are a dozen tests a frame (over 30 simulated drives held after a
#: step the largest was 1.3–1.9; a second 1° knock of a rendered car or cart reads 2 within
#: 0.3–1.5 s)
MOVED_APART = 2.0
#: a line through the frames since a change that rises by more than this many of its standard
#: deviations, and fits them better than one step, gives the new extrinsics (a line rising
#: by more than one only widens the median's interval to its end)
CREEP_SIGMAS = 3.0


class _Frame(NamedTuple):
    """A used frame as the new extrinsics are estimated from it: its used-frame count, time
    (s), its deviation from nominal and variance (rad, rad, m), and the whitening filter's
    innovation, its variance, AR(1) coefficient, gain and the road's long-run variance factor
    on it (``MonitorCore.last_whitening``)."""

    used: int
    t: float
    dev: FloatArray
    var: FloatArray
    nu: FloatArray
    nu_var: FloatArray
    a: FloatArray
    gain: FloatArray
    road: FloatArray


class DriftMonitor:
    """Streaming monitor of one camera: ``update(MonitorInput) -> MonitorOutput``.

    Example::

        mon = DriftMonitor(load_nominal("data/nominal_car.yaml"), MonitorConfig(fps=10))
        for inp in inputs:
            out = mon.update(inp)
            if out.event:
                print(json_text.dumps(out.event))
    """

    def __init__(self, nominal: NominalCalibration, config: MonitorConfig | None = None) -> None:
        self.core = MonitorCore(nominal, config, batch=1)
        self.nominal = nominal
        self.config = self.core.config
        n_hist = max(1, round(self.config.history_s * self.config.fps))
        self._history: deque[_Frame] = deque(maxlen=n_hist)
        self._state: str | None = None
        self._reported: str | None = None  # the state the last event announced
        # frames behind the last _estimate, and whether all of them follow the change's start
        self._estimate_frames, self._since_change = 0, True
        self._estimate_from = math.nan  # time of the first frame behind the last _estimate (s)
        self._line_axes: set[int] = set()  # axes the last _estimate read from a drift line
        self._alarm_t = math.nan  # when RECALIBRATE was entered (s)
        self._hold_event: dict[str, Any] | None = None  # a HOLD not yet long enough to report
        self._announced_off: set[int] = set()  # axes RECALIBRATE's events have read off
        self._change_at: int | None = None
        # used-frame count just before the last step found of the change under way (None:
        # none): the frames behind the new extrinsics start there at the earliest
        self._step_at: int | None = None
        self._held = 0
        cfg = self.config
        self._body = BodyScale(cfg.body_noise(), cfg.body_window_s, cfg.body_min_pairs)
        self._heave = HeaveScale(cfg.body_window_s, cfg.body_min_pairs,
                                  cfg.heave_std_unknown_frac * nominal.height_m)

    @property
    def thresholds(self) -> FloatArray:
        """(3, D) CUSUM thresholds (log-likelihood units) per axis and design shift, at the
        current body std."""
        return self.core.s.threshold[0].copy()

    def accept(self, nominal: NominalCalibration) -> None:
        """Adopt a new nominal calibration (after a recalibration) and start over."""
        self.__init__(nominal, self.config)  # type: ignore[misc]

    def update(self, inp: MonitorInput) -> MonitorOutput:
        """Judge one frame (see ``MonitorOutput``)."""
        core = self.core
        pose = np.asarray(inp.pose, dtype=float).reshape(3)
        var = np.asarray(inp.pose_var, dtype=float).reshape(3)
        mount = None if inp.mount is None else np.asarray(inp.mount, dtype=float).reshape(1, 3)
        before = core.s.base[0]
        body_std = None
        if inp.usable and inp.change is not None and self.config.body_window_s > 0:
            change_var = np.full(2, np.nan) if inp.change_var is None else inp.change_var
            self._body.add(float(inp.t), pose[:2], var[:2], np.asarray(inp.change, dtype=float),
                           np.asarray(change_var, dtype=float), float(inp.dt))
            self._heave.add(float(inp.t), float(pose[2]), float(var[2]))
            body_std = np.append(self._body.std(), self._heave.std())[None]
        code = int(core.step(
            np.array([float(inp.t)]), pose[None], var[None], np.array([bool(inp.usable)]),
            np.array([bool(inp.gated)]), mount, body_std,
        )[0])
        base = int(core.s.base[0])
        used = int(core.s.count[0])
        if inp.usable:
            nu, sv, a, gain, road = (v[0] for v in core.last_whitening)
            self._history.append(_Frame(used, float(inp.t), pose - core.nominal_values, var, nu,
                                        sv, a, gain, road))
        if base == RECALIBRATE and before != RECALIBRATE:
            self._change_at = int(core.s.onset[0])  # the statistics restarted at the alarm
            self._alarm_t = float(inp.t)
        elif base not in (RECALIBRATE, DRIFTING):
            self._change_at = self._step_at = None
        state = STATES[code]
        stat = core.last_statistic[0].copy()
        estimate = interval = None
        if code in (DRIFTING, RECALIBRATE) or (code == HOLD and base in (DRIFTING, RECALIBRATE)):
            start = self._change_at if base == RECALIBRATE else self._change_start()
            estimate, interval = self._estimate(start)
        reason = self._reason(code, base, inp, stat, estimate, interval)
        event = self._debounced_event(inp, state, reason, estimate, interval)
        off = self._axes_off(interval) if state == "RECALIBRATE" else set()
        if self._reported != "RECALIBRATE":
            self._announced_off = set()
        elif event is not None:  # the alarm's own event: its axis, and what reads off now
            self._announced_off = off | {int(core.s.alarm_axis[0])}
        elif off - self._announced_off:
            # held RECALIBRATE, and another axis now reads off too: said, not only tabled
            event = self._event(inp, state, reason, estimate, interval)
            self._announced_off |= off
        self._state = state
        return MonitorOutput(
            frame=inp.frame, t=float(inp.t), state=state, reason=reason, statistic=stat,
            deviation=core.s.ema[0].copy(), estimate=estimate, interval95=interval, event=event,
            mount=None if inp.mount is None else np.asarray(inp.mount, dtype=float),
        )

    # -- internals --------------------------------------------------------------------------

    def _debounced_event(self, inp: MonitorInput, state: str, reason: str,
                         estimate: FloatArray | None, interval: FloatArray | None,
                         ) -> dict[str, Any] | None:
        """The event of this frame, if any: a change of the announced state, where a HOLD
        counts only once it has lasted ``min_hold_event_s`` (see MonitorConfig)."""
        if state == "HOLD":
            if self._state != "HOLD":
                self._hold_event = self._event(inp, state, reason, estimate, interval)
            pending = self._hold_event
            if (pending is not None and self._reported != "HOLD"
                    and float(inp.t) - pending["t"] >= self.config.min_hold_event_s - 1e-9):
                self._reported = "HOLD"
                return pending
            return None
        self._hold_event = None
        if state == self._reported:
            return None
        self._reported = state
        return self._event(inp, state, reason, estimate, interval)

    def _change_start(self) -> int:
        """Used-frame count at which the change under way began (``MonitorCore.change_onset``
        on the leading axis)."""
        core = self.core
        return int(core.change_onset(core.s.alarm_axis[:1])[0])

    def _estimate(self, start: int | None) -> tuple[FloatArray, FloatArray]:
        core, cfg = self.core, self.config
        body_std = core.s.body_std[0]
        a = ar1_coefficient(np.full(3, 1.0 / cfg.fps), core.body_tau(body_std))
        a_road = math.exp(-1.0 / (cfg.fps * cfg.road_tau_s))
        history = list(self._history)
        if self._step_at is not None:  # a step found before stays found: no flip-flop back
            start = self._step_at if start is None else max(start, self._step_at)
        since = next((i for i, h in enumerate(history) if start is None or h.used > start),
                     len(history))
        # the change time may be many frames off, and the camera may have moved again since:
        # the frames after the last step, looked for from a second before the change time
        first = max(0, since - round(cfg.fps))
        window = history[first:]
        # an axis without a frame since the step found below (height after the wheel speed
        # stopped) keeps its estimate from the frames since the change time
        fallback = history[since:]
        step = 0
        if window:
            # the errors' measured correlation and the road's modelled wander both run on in
            # the innovations: a step must stand out of both (a told road's wander made steps)
            factor = core.s.corr_factor[0] * np.nanmedian([h.road for h in window], axis=0)
            step = last_step(np.array([h.nu for h in window]),
                             np.array([h.nu_var for h in window]),
                             np.median([h.a for h in window], axis=0),
                             np.median([h.gain for h in window], axis=0),
                             np.nan_to_num(factor, nan=1.0), core.nominal.tolerances)
            if step > 0:
                # the first step of a change may lie in the lead-in (the change time late);
                # a later one only moves the window forward
                since = first + step if self._step_at is None else max(since, first + step)
                self._step_at = history[since].used - 1
        hist = history[since:]
        # the frames since the change began, however few (a median of frames from before it
        # is no estimate of where the camera went: the demo's DRIFTING, one frame after a +1°
        # knock, reported -0.11°); the last frames where none has come since
        self._since_change = bool(hist)
        if not hist:
            hist = history[-self._half_second:]
        self._estimate_frames = len(hist)
        self._estimate_from = hist[0].t if hist else math.nan
        self._line_axes = set()
        dev = np.array([h.dev for h in hist])
        var = np.array([h.var for h in hist])
        est = np.full(3, np.nan)
        lo, hi = np.full(3, np.nan), np.full(3, np.nan)

        def median_interval(d: FloatArray, v: FloatArray, j: int) -> tuple[float, float]:
            """Median of the deviations ``d`` [rad, m] of axis ``j`` and its 95 % half-width
            (the body's and road's correlation; the data's own scatter where wider)."""
            n = len(d)
            mv = (mean_variance(body_std[j], a[j], float(np.mean(v)), n)
                  + mean_variance(core.road_std[j], a_road, 0.0, n))
            width = 1.96 * math.sqrt(math.pi / 2.0 * mv)
            data = batch_means(d)
            if data is not None:
                width = max(width, math.sqrt(math.pi / 2.0) * data.half_width95)
            return float(np.median(d)), width

        for j in range(3):
            ok = np.isfinite(dev[:, j])
            if not ok.any() and fallback:
                dev_j = np.array([h.dev for h in fallback])
                var_j = np.array([h.var for h in fallback])
                ok = np.isfinite(dev_j[:, j])
            else:
                dev_j, var_j = dev, var
            if not ok.any():
                continue
            d, v = dev_j[ok, j], var_j[ok, j]
            est[j], half = median_interval(d, v, j)
            lo[j], hi[j] = est[j] - half, est[j] + half
            if dev_j is not dev:
                continue
            line = self._line_end(np.array([h.t for h in hist])[ok], d,
                                  lambda r, v=v, j=j: median_interval(r, v, j)[1])
            if line is not None:
                # a creeping mount: the median of the frames since the change lags it; the
                # line ends on it, and the interval spans both readings where the rise is not
                # yet sure
                end, end_half, sure = line
                if sure:
                    est[j], lo[j], hi[j] = end, end - end_half, end + end_half
                    self._line_axes.add(j)
                    continue
                lo[j], hi[j] = min(lo[j], end - end_half), max(hi[j], end + end_half)
            # where the latest seconds read apart from the frames before them, the camera
            # moved again (a second knock while RECALIBRATE is held) before the step test
            # could say so
            cut = self._moved_again(
                d, lambda a, b, d=d, v=v, j=j: median_interval(d[a:b], v[a:b], j))
            if cut is not None:
                # it reads where the camera is now, within what both readings allow; the
                # next frames are read from there on (found stays found, as a step)
                now, now_half = median_interval(d[cut:], v[cut:], j)
                est[j] = now
                lo[j], hi[j] = min(lo[j], now - now_half), max(hi[j], now + now_half)
                first = hist[int(np.flatnonzero(ok)[cut])]
                moved = first.used - 1
                self._step_at = moved if self._step_at is None else max(self._step_at, moved)
                # the reason's "median of N frames over the last …" is of these frames
                self._estimate_frames = len(d) - cut
                self._estimate_from = first.t
        value = core.nominal_values + est
        return value, np.stack([core.nominal_values + lo, core.nominal_values + hi], axis=1)

    def _line_end(self, t: FloatArray, d: FloatArray,
                  half_width_of: Callable[[FloatArray], float],
                  ) -> tuple[float, float, bool] | None:
        """The end of the straight line through the deviations ``d`` at times ``t`` [s], its
        95 % half-width and whether it surely creeps (rises by more than
        :data:`CREEP_SIGMAS` of its standard deviation, and fits them better than any one
        step on half-second splits does: a creep, not a knock), where it rises by more than
        its standard deviation; None otherwise.
        ``half_width_of(r)``: the 95 % half-width of the middle of residuals ``r`` (the
        body's and road's correlation, or their own scatter); a line's end is twice as
        uncertain as its middle (uniform frames)."""
        step, n = self._half_second, len(d)
        span = float(t[-1] - t[0]) if n else 0.0
        if n < 4 * step or not span > 0:
            return None
        slope, intercept = np.polyfit(t - t[-1], d, 1)
        residual = d - (slope * (t - t[-1]) + intercept)
        half = half_width_of(residual)
        # the rise's σ is √12 times the middle's over a uniform span
        rise = abs(slope * span) / (math.sqrt(12.0) * half / 1.96)
        if not rise > 1.0:
            return None  # no more rise than the frames' scatter makes
        # a step that reads better (a knock, its change time early) is not surely a creep;
        # on a shaking body one step often reads better than a line through a creep too, so
        # the line's end still widens the interval
        cuts = np.arange(step, n - step + 1, step)
        stepped = float(residual @ residual) >= float(np.min(one_step_squares(d, cuts)))
        return float(intercept), 2.0 * half, bool(rise > CREEP_SIGMAS and not stepped)

    def _moved_again(self, d: FloatArray,
                     interval_of: Callable[[int, int], tuple[float, float]]) -> int | None:
        """Where the deviations ``d`` (one axis, in time order) read apart from those before:
        of the splits on half-second steps within the last :data:`MOVED_AGAIN_S`, the one
        whose two medians differ most, by more than :data:`MOVED_APART` times their 95 %
        half-widths taken together (``interval_of(first, stop)``: median and half-width of
        ``d[first:stop]``); None where none does."""
        step = self._half_second
        first = max(step, len(d) - round(MOVED_AGAIN_S * self.config.fps))
        best, most = None, MOVED_APART
        for cut in range(len(d) - step, first - 1, -step):
            (before, before_half), (after, after_half) = interval_of(0, cut), interval_of(cut,
                                                                                        len(d))
            apart = abs(after - before) / math.hypot(before_half, after_half)
            if apart > most:
                best, most = cut, apart
        return best

    def _reason(self, code: int, base: int, inp: MonitorInput, stat: FloatArray,
                estimate: FloatArray | None, interval: FloatArray | None) -> str:
        core = self.core
        if code == HOLD:
            return inp.hold_reason or ("gated by the filter" if inp.gated else "unusable frame")
        if code == INVALID:
            j = int(core.s.invalid_axis[0])
            limit = _fmt_dev(j, core.limits[j], sign=False)
            source = "filter's mount" if core.s.invalid_mount[0] else "1 s mean of the frames"
            return (f"{AXES[j]} {_fmt_dev(j, float(core.s.invalid_dev[0]))} from nominal "
                    f"({source}) exceeds the limit {limit}")
        if code == UNCALIBRATED:
            evidence = int(core.s.evidence[0])
            if evidence < core.calib_frames:
                return f"collecting evidence ({evidence}/{core.calib_frames} usable frames)"
            mean, half = _mean_so_far(core)
            bound = core.calibrated_bound()
            j = int(np.nanargmax(np.abs(mean) + half - bound))
            within = (f"{_fmt_dev(j, bound[j], sign=False)} (the tolerance "
                      f"{_fmt_dev(j, core.nominal.tolerances[j], sign=False)} and the "
                      "smallest change tested)")
            if abs(mean[j]) - half[j] > bound[j]:
                # the interval lies beyond the bound: said so, not "not shown within" it
                return (f"collecting evidence ({evidence} usable frames): the mean deviation "
                        f"so far, {_fmt_mean(j, mean, half)}, lies beyond {within}; the "
                        "change test, set for its false-alarm rate, has not confirmed a "
                        "change yet")
            return (f"collecting evidence ({evidence} usable frames): the mean deviation so "
                    f"far, {_fmt_mean(j, mean, half)}, is not shown within {within} yet")
        if code == CALIBRATED:
            # what the test can say: it has not found a change; one less than its smallest
            # design shift beyond the tolerance takes long to find (a 0.3° knock against a
            # 0.2° tolerance stayed CALIBRATED for 9 s on a cart)
            mean, half = _mean_so_far(core)
            tested = [j for j in range(3) if math.isfinite(mean[j])]
            so_far = ", ".join(_fmt_mean(j, mean, half) for j in tested)
            if 2 not in tested:  # no metric travel yet: the height has not been tested
                return (f"no change beyond the tolerance found in pitch and roll (mean "
                        f"deviation {so_far}); height not tested (it needs wheel speed)")
            return f"no change beyond the tolerance found (mean deviation {so_far})"
        j = int(core.s.alarm_axis[0])
        tol = _fmt_dev(j, core.nominal.tolerances[j], sign=False)
        dev = (estimate - core.nominal_values)[j] if estimate is not None else core.s.ema[0, j]
        # a creeping axis is read from the line through its frames, not their median
        read = "end of the drift line" if j in self._line_axes else "median"
        if code == RECALIBRATE:
            span = ""
            if interval is not None:
                lo, hi = interval[j] - core.nominal_values[j]
                span = f", 95 % {_fmt_dev(j, lo)} … {_fmt_dev(j, hi)}"
            over = (self._since_text(inp) if estimate is None or self._since_change else
                    f"of the last {self._estimate_frames} frames, from before the change")
            if estimate is not None and abs(dev) <= core.nominal.tolerances[j]:
                # latched, and the frames behind the new extrinsics read within the tolerance:
                # "set back?" where half a second of them follows a step after the alarm
                settled = self._estimate_frames >= self._half_second
                back = settled and self._since_change and self._estimate_from > self._alarm_t
                return (f"{AXES[j]} changed beyond the tolerance {tol} (the test crossed its "
                        f"threshold), and reads {_fmt_dev(j, dev)} from nominal "
                        f"{'again ' if back else ''}({read} {over}{span})"
                        + (f": set back? RECALIBRATE clears after "
                           f"{self.config.clear_after_s:g} s of frames without a warning"
                           if back else ""))
            text = (f"{AXES[j]} changed: {_fmt_dev(j, dev)} from nominal ({read} {over}"
                    f"{span}), beyond the tolerance {tol}: the test crossed its threshold")
            for k in sorted(self._axes_off(interval) - {j}):
                # a second change while the first is held (a knock after a height change)
                lo, hi = interval[k] - core.nominal_values[k]  # type: ignore[index]
                text += (f"; {AXES[k]} reads off too: 95 % {_fmt_dev(k, lo)} … "
                         f"{_fmt_dev(k, hi)}, beyond its tolerance "
                         f"{_fmt_dev(k, core.nominal.tolerances[k], sign=False)}")
            recent = float(core.s.ema[0, j])
            if abs(recent) <= core.nominal.tolerances[j]:
                # latched: the camera may have been set back (or knocked back) since
                text += (f"; its last second reads {_fmt_dev(j, recent)}, within the "
                         f"tolerance (RECALIBRATE clears after {self.config.clear_after_s:g} "
                         "s of frames without a warning)")
            return text
        over = (self._since_text(inp) if estimate is None or self._since_change else
                f"over the last {self._estimate_frames} frames, from before it began")
        return (f"{AXES[j]} drifting: the test stands at {stat[j]:.0%} of its threshold "
                f"(DRIFTING from {self.config.warn_enter:.0%}); {read} deviation {over} "
                f"{_fmt_dev(j, dev)}, tolerance {tol}")

    def _axes_off(self, interval: FloatArray | None) -> set[int]:
        """Axes whose new extrinsics' 95 % ``interval`` lies wholly beyond the nominal's
        tolerance (none without an interval)."""
        if interval is None:
            return set()
        dev = interval - self.core.nominal_values[:, None]
        tol = np.asarray(self.core.nominal.tolerances, dtype=float)
        with np.errstate(invalid="ignore"):
            beyond = (dev[:, 0] > tol) | (dev[:, 1] < -tol)
        return {int(k) for k in np.flatnonzero(beyond)}

    @property
    def _half_second(self) -> int:
        """Frames in half a second (at least 3): the fewest a median is read from."""
        return max(3, round(0.5 * self.config.fps))

    def _since_text(self, inp: MonitorInput) -> str:
        """How far back the new extrinsics reach, in seconds before this frame (a live
        camera's times are Unix times: "since 1764445123.40 s" said nothing)."""
        n = self._estimate_frames
        return (f"of the {n} frame{'s' if n != 1 else ''} over the last "
                f"{float(inp.t) - self._estimate_from:.1f} s")

    def _event(self, inp: MonitorInput, state: str, reason: str, estimate: FloatArray | None,
               interval: FloatArray | None) -> dict[str, Any]:
        return event_dict(float(inp.t), int(inp.frame), state, reason, estimate, interval,
                          inp.mount)


def event_dict(t: float | None, frame: int | None, state: str, reason: str,
               estimate: FloatArray | None = None, interval: FloatArray | None = None,
               mount: Any = None) -> dict[str, Any]:
    """A monitor event as written to ``--events`` (docs/formats.md): time [s], frame, state,
    the new extrinsics and their 95 % interval (rad, rad, m in; degrees and metres out; None
    outside DRIFTING / RECALIBRATE), the filter's mount, the reason."""
    ev: dict[str, Any] = {"t": t, "frame": frame, "state": state}
    ev["estimate"] = None if estimate is None else _pose_dict(estimate)
    ev["interval95"] = None if interval is None else {
        k: [v0, v1] for (k, v0), (_, v1) in zip(
            _pose_dict(interval[:, 0]).items(), _pose_dict(interval[:, 1]).items(), strict=True)
    }
    ev["filter_mount"] = None if mount is None else _pose_dict(np.asarray(mount, dtype=float))
    ev["reason"] = reason
    return ev


def _pose_dict(v: FloatArray) -> dict[str, float | None]:
    out = {"pitch_deg": math.degrees(v[0]), "roll_deg": math.degrees(v[1]), "height_m": v[2]}
    return {k: (round(float(x), 6) if math.isfinite(x) else None) for k, x in out.items()}


def _mean_so_far(core: MonitorCore) -> tuple[FloatArray, FloatArray]:
    """The (one) stream's mean deviation since the evidence began (3,) and the half-width
    CALIBRATED holds it to (``calibrate_within_z`` standard errors)."""
    mean, se = (x[0] for x in core.mean_deviation())
    return mean, core.config.calibrate_within_z * se


def _fmt_mean(axis: int, mean: FloatArray, half: FloatArray) -> str:
    """'pitch -0.53° ± 0.51°': one axis of :func:`_mean_so_far`."""
    return f"{AXES[axis]} {_fmt_dev(axis, mean[axis])} ± {_fmt_dev(axis, half[axis], sign=False)}"


def _fmt_dev(axis: int, value: float, sign: bool = True) -> str:
    if not math.isfinite(value):
        return "?"
    if axis < 2:
        return f"{math.degrees(value):+.2f}°" if sign else f"{math.degrees(value):.2f}°"
    return f"{value * 100:+.1f} cm" if sign else f"{value * 100:.1f} cm"


def run_monitor(
    inputs: Iterable[MonitorInput], nominal: NominalCalibration, config: MonitorConfig | None = None
) -> list[MonitorOutput]:
    """Monitor a whole sequence; one output per input."""
    mon = DriftMonitor(nominal, config)
    return [mon.update(i) for i in inputs]


def write_events(outputs: Sequence[MonitorOutput], path: str | Path) -> int:
    """Write the events of ``outputs`` as JSON lines; return how many."""
    n = 0
    with Path(path).open("w") as f:
        for o in outputs:
            if o.event is not None:
                f.write(json_text.dumps(o.event) + "\n")
                n += 1
    return n


__all__ = ["DriftMonitor", "run_monitor", "write_events"]
