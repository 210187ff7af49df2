"""The camera height a pair measures with the wheels: h = h0 · d / |t| (CONVENTIONS.md,
Scale), where |t| is the pair's travel in units of the assumed height h0 and d the distance
the wheel speed says the vehicle went between the pair's frames. It is the height of the
pair's first frame, whose ground frame the travel is measured in. Its variance combines the
travel's covariance and the speed's noise (a relative and an absolute std per sample,
averaged over the samples within the pair). The monitor tests the mount's height with it
(``monitor_inputs``); the filters measure the body's heave with it (``heave``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from vipm_track.measurement import PairMeasurement

from .wheel_speed import DEFAULT_MAX_GAP, cumulative_distance

#: a smoothed height further than this factor from the height the pairs were estimated with
#: is called out: wheel speed scales the pairs' travel, and one from another drive, in other
#: units or on another clock moves the height with it (a CAN log of another drive: 5.56 m
#: for a 0.7 m cart, no other warning)
HEIGHT_SCALE_WARNING = 1.25

FloatArray = NDArray[np.float64]

#: a pair measures the height only while the vehicle moves at least this fast [m/s] and
#: this far [share of the height]: below them the wheel distance is mostly its quantisation
MIN_SPEED_MPS = 0.05
MIN_TRAVEL_FRAC = 0.005


def wheel_distance(t_speed: FloatArray, speed_mps: FloatArray, times: FloatArray) -> FloatArray:
    """Distance travelled (m) from the first speed sample to each of ``times`` (camera clock),
    by trapezoidal integration of the samples; NaN outside the samples."""
    t_speed = np.asarray(t_speed, dtype=float)
    cum = cumulative_distance(t_speed, speed_mps)
    times = np.asarray(times, dtype=float)
    out = np.interp(times, t_speed, cum)
    out[(times < t_speed[0]) | (times > t_speed[-1])] = np.nan
    return out


def height_from_travel(h0: ArrayLike, distance_m: ArrayLike, distance_var: ArrayLike,
                       z: ArrayLike, cov: ArrayLike) -> tuple[FloatArray, FloatArray]:
    """Height [m] and its variance [m²] of pairs ``z`` (n, 7) with ``cov`` (n, 7, 7) (travel
    ``z[:, 4:6]`` in units of ``h0`` [m]) whose frames the wheels put ``distance_m`` apart
    (variance ``distance_var``), (n,) each; NaN where undefined."""
    z, cov = np.asarray(z, dtype=np.float64), np.asarray(cov, dtype=np.float64)
    d = np.asarray(distance_m, dtype=np.float64)
    travel = np.hypot(z[:, 4], z[:, 5])
    with np.errstate(invalid="ignore", divide="ignore"):
        travel_var = (z[:, 4] ** 2 * cov[:, 4, 4] + z[:, 5] ** 2 * cov[:, 5, 5]
                      + 2 * z[:, 4] * z[:, 5] * cov[:, 4, 5]) / travel**2
        height = np.asarray(h0, dtype=np.float64) * d / travel
        height_var = height**2 * (travel_var / travel**2 + np.asarray(distance_var) / d**2)
    return height, height_var


def distance_variance(dt: ArrayLike, v_mean: ArrayLike, n_samples: ArrayLike,
                      speed_std_rel: float, speed_std_abs_mps: float) -> FloatArray:
    """Variance [m²] of a distance over ``dt`` [s] at mean speed ``v_mean`` [m/s] from
    ``n_samples`` speed samples, each with std ``speed_std_rel`` · v + ``speed_std_abs_mps``
    (in quadrature)."""
    dt, v = np.asarray(dt, dtype=np.float64), np.asarray(v_mean, dtype=np.float64)
    sample_var = (speed_std_rel * v) ** 2 + speed_std_abs_mps**2
    return dt**2 * sample_var / np.asarray(n_samples, dtype=np.float64)


def pair_heights(
    t: FloatArray, dt: FloatArray, z: FloatArray, cov: FloatArray, h0: FloatArray,
    speed_t: FloatArray, speed_mps: FloatArray, *,
    min_speed_mps: float, min_travel_frac: float, speed_std_rel: float,
    speed_std_abs_mps: float, max_speed_gap_s: float,
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Each pair's height and variance (module doc) and the speed magnitude at its frame,
    (n,) each, from speed samples (``speed_t`` on the camera clock [s], ``speed_mps``): pair
    k spans ``dt[k]`` seconds up to ``t[k]`` (NaN where it does not join the frame before).
    NaN heights where the vehicle moves slower than ``min_speed_mps`` or less than
    ``min_travel_frac`` of the height (the distance is then mostly the speed's
    quantisation) and where a speed gap over ``max_speed_gap_s`` brackets a frame."""
    ts = np.asarray(speed_t, dtype=float)
    vs = np.asarray(speed_mps, dtype=float)
    n = len(t)
    dist = wheel_distance(ts, vs, t)
    # a speed gap longer than the frame interval brackets one of the interval's ends
    j = np.clip(np.searchsorted(ts, t), 1, max(1, len(ts) - 1))
    spacing = ts[j] - ts[j - 1] if len(ts) > 1 else np.full(n, np.inf)
    dist[spacing > max_speed_gap_s] = np.nan
    # magnitudes: a source that signs its speed says < 0 when reversing
    v_now = np.abs(np.interp(t, ts, vs, left=np.nan, right=np.nan))
    d_wheel = np.full(n, np.nan)
    d_wheel[1:] = np.where(np.isfinite(dt[1:]), np.abs(dist[1:] - dist[:-1]), np.nan)
    rate = (len(ts) - 1) / (ts[-1] - ts[0]) if len(ts) > 1 and ts[-1] > ts[0] else 1.0
    n_samples = np.maximum(1.0, np.nan_to_num(dt) * rate)
    with np.errstate(invalid="ignore", divide="ignore"):
        v_mean = d_wheel / dt
        dist_var = distance_variance(dt, v_mean, n_samples, speed_std_rel, speed_std_abs_mps)
        height, height_var = height_from_travel(h0, d_wheel, dist_var, z, cov)
        moving = (v_mean > min_speed_mps) & (d_wheel > min_travel_frac * h0)
    return np.where(moving, height, np.nan), np.where(moving, height_var, np.nan), v_now


def pair_spans(frame: ArrayLike, t: ArrayLike) -> FloatArray:
    """Each pair's span [s]: ``t[k] − t[k−1]`` where frame k follows frame k−1 (the pair
    joins them), NaN otherwise (the first, and after a left-out frame)."""
    frame, t = np.asarray(frame), np.asarray(t, dtype=float)
    dt = np.full(len(t), np.nan)
    if len(t) > 1:
        dt[1:] = np.where(frame[1:] == frame[:-1] + 1, t[1:] - t[:-1], np.nan)
    return dt


def measured_heights(measurements: Sequence[PairMeasurement], speed_t: ArrayLike,
                     speed_mps: ArrayLike, *, speed_std_rel: float = 0.005,
                     speed_std_abs_mps: float = 0.002,
                     max_speed_gap_s: float = DEFAULT_MAX_GAP) -> tuple[FloatArray, FloatArray]:
    """The height [m] each usable pair of ``measurements`` measures (:func:`pair_heights`,
    that of its first frame) with the wheel speed (``speed_t`` on the camera clock [s],
    ``speed_mps``) and the monitor's thresholds, and its variance [m²]; NaN where it
    measures none, (n,) each."""
    if not measurements:
        return np.zeros(0), np.zeros(0)
    frame = np.array([m.frame for m in measurements])
    t = np.array([m.t for m in measurements], dtype=float)
    z = np.array([m.z if m.ok else np.full(7, np.nan) for m in measurements], dtype=float)
    cov = np.array([m.covariance for m in measurements], dtype=float)
    h0 = np.array([m.height_assumed for m in measurements], dtype=float)
    height, variance, _ = pair_heights(
        t, pair_spans(frame, t), z, cov, h0, np.asarray(speed_t, dtype=float),
        np.asarray(speed_mps, dtype=float), min_speed_mps=MIN_SPEED_MPS,
        min_travel_frac=MIN_TRAVEL_FRAC, speed_std_rel=speed_std_rel,
        speed_std_abs_mps=speed_std_abs_mps, max_speed_gap_s=max_speed_gap_s)
    return height, variance


def point_speed_height(m_z: FloatArray, m_cov: FloatArray, h0: float, dt: float,
                       speeds: tuple[float, float], *, min_speed_mps: float,
                       min_travel_frac: float, speed_std_rel: float,
                       speed_std_abs_mps: float) -> tuple[float, float]:
    """One pair's height and variance (as :func:`pair_heights`) from the speeds at its two
    frames only (a live stream's: the distance by one trapezoid, two samples' noise)."""
    v_mean = 0.5 * (abs(speeds[0]) + abs(speeds[1]))
    distance = v_mean * dt
    if not (v_mean > min_speed_mps and distance > min_travel_frac * h0):
        return math.nan, math.nan
    var = distance_variance(dt, v_mean, 2.0, speed_std_rel, speed_std_abs_mps)
    h, h_var = height_from_travel(h0, [distance], [var], m_z[None], m_cov[None])
    return float(h[0]), float(h_var[0])
