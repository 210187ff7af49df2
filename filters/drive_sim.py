"""Long simulated measurement streams, without rendering, from the estimator's noise model.

``simulate_drive(config, seed)`` draws a drive and returns its truth, the per-frame
``PairMeasurement`` list the two-frame estimator would produce, and wheel-speed samples
(``profile=DriveProfile(...)`` replaces the random speed and curvature by given knots):

- mount (the calibration): nominal pitch/roll/height/yaw offset, optional steps and ramps
  (``MountChange``), plus a slow random walk (rates of ``filters.model.NoiseParams``);
- body shaking: first-order Gauss–Markov on pitch and roll (exactly the model's), plus an
  optional slow road-relative tilt (``road_std_deg``, ``road_tau_s``: a second, slower
  Gauss–Markov standing for road camber and slope changes; not in the filters' model, off by
  default), kept in the truth's ``body_*``;
- planar drive: speed held and ramped (cosine ramps) between random targets, with standstill
  periods; turns as curvature segments (yaw rate = curvature · speed); integrated on a fine
  grid; the camera's ground frame G moves with the vehicle, turned by the mount yaw offset;
- measurements: the 7-vector (pitch_prev, roll_prev, pitch, roll, tx, tz, yaw) of each pair
  with tx, tz at the *assumed* height (× h0 / h_true), plus Gaussian noise (angles correlated
  between the two frames of a pair, translation noise proportional to the travel), optional
  outliers (pairs replaced by wrong values, reported with the normal covariance) and failed
  frames (status ≠ ok, NaNs; also every standstill pair, which the estimator cannot solve:
  status "no motion", as the estimator reports it);
- wheel speed at its own rate with relative noise, quantisation (km/h steps) and a clock
  offset: the samples' clock is the camera clock minus ``speed_clock_offset_s`` (so
  ``t_camera = t_speed + offset``, the CLI's ``--clock-offset``).

Everything is vectorised; an hour at 20 fps takes well under a second. Deterministic from
the seed.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import NDArray
from scipy.signal import lfilter

from vipm_track.measurement import PairMeasurement

from .model import NO_MOTION_STATUS, NoiseParams

FloatArray = NDArray[np.float64]

_SUBSTEPS = 10  # fine integration steps per frame


@dataclass(frozen=True)
class MountChange:
    """A change of the mount starting at ``t_s``: a step (``duration_s`` = 0) or a linear
    ramp over ``duration_s`` seconds, by the given deltas (degrees, metres)."""

    t_s: float
    pitch_deg: float = 0.0
    roll_deg: float = 0.0
    height_m: float = 0.0
    duration_s: float = 0.0


@dataclass(frozen=True)
class DriveConfig:
    """A simulated drive: vehicle, mount, drive profile and noise (units in the names).

    ``DriveConfig.preset('car' | 'cart', **overrides)`` gives the two standard set-ups.
    """

    duration_s: float = 60.0
    fps: float = 20.0
    # mount truth and the estimator's assumed (nominal) height
    height_m: float = 1.5
    height_assumed_m: float | None = None  # None: equal to height_m
    pitch_deg: float = 3.0
    roll_deg: float = 0.0
    yaw_offset_deg: float = 0.0
    #: the camera's lever arms (``filters.lever_arm``): metres ahead of the point the
    #: vehicle turns about, and above the axis its body rolls about (0: the camera moves as
    #: the vehicle, the filters' model)
    lever_arm_m: float = 0.0
    roll_arm_m: float = 0.0
    mount_changes: tuple[MountChange, ...] = ()
    mount_random_walk: bool = True
    noise: NoiseParams = field(default_factory=NoiseParams)  # body shaking + mount walk truth
    road_std_deg: float = 0.0  # slow road-relative tilt on pitch and roll (0: flat ground)
    road_tau_s: float = 2.0
    # drive profile
    speed_min_mps: float = 5.0
    speed_max_mps: float = 20.0
    accel_mps2: float = 1.5
    segment_mean_s: float = 8.0
    stop_probability: float = 0.1
    stop_s: tuple[float, float] = (2.0, 5.0)
    max_curvature_per_m: float = 1.0 / 60.0
    turn_probability: float = 0.4
    # measurement noise (what the estimator reports; cov_scale ≠ 1 mis-reports it)
    angle_std_deg: float = 0.1
    prev_curr_corr: float = 0.5
    trans_std_rel: float = 0.003
    trans_std_abs_m: float = 0.001
    yaw_std_deg: float = 0.03
    cov_scale: float = 1.0
    # bad data
    outlier_fraction: float = 0.0
    outlier_angle_deg: float = 2.0
    outlier_trans_rel: float = 0.3
    failure_fraction: float = 0.01
    min_travel_m: float = 0.01
    # wheel speed
    speed_rate_hz: float = 50.0
    speed_noise_rel: float = 0.005
    speed_quantum_kmh: float = 0.01
    speed_clock_offset_s: float = 0.0

    @classmethod
    def preset(cls, name: str, **overrides: object) -> DriveConfig:
        """``car``: 20 fps, h 1.5 m, pitch 3°, 5–20 m/s; ``cart``: 10 fps, h 0.7 m,
        pitch 45°, 0.8–1.6 m/s (the renderer's presets), with ``overrides`` applied."""
        if name == "car":
            base = cls()
        elif name == "cart":
            base = cls(
                fps=10.0, height_m=0.7, pitch_deg=45.0, speed_min_mps=0.8, speed_max_mps=1.6,
                accel_mps2=0.5, max_curvature_per_m=1.0 / 4.0, noise=NoiseParams.for_preset("cart"),
            )
        else:
            raise ValueError(f"unknown drive preset {name!r}; expected 'car' or 'cart'")
        return replace(base, **overrides)  # type: ignore[arg-type]

    @property
    def h0(self) -> float:
        """Height the estimator assumes, metres."""
        return self.height_m if self.height_assumed_m is None else self.height_assumed_m


@dataclass(frozen=True)
class DriveProfile:
    """A given planar drive instead of the random one: speed (m/s) and curvature (1/m, > 0
    turning right) at knot times (s), cosine-interpolated between knots (flat where two
    consecutive values agree), held after the last knot."""

    knot_t: tuple[float, ...]
    speed_mps: tuple[float, ...]
    curvature_per_m: tuple[float, ...]

    def __post_init__(self) -> None:
        n = len(self.knot_t)
        if n < 2 or len(self.speed_mps) != n or len(self.curvature_per_m) != n:
            raise ValueError("a drive profile needs ≥ 2 knots and one speed, curvature each")
        if np.any(np.diff(self.knot_t) <= 0):
            raise ValueError("drive profile knot times must increase")


@dataclass(frozen=True)
class SpeedSamples:
    """Wheel speed samples: times (s, speed-sensor clock) and speed (m/s)."""

    t: FloatArray
    speed_mps: FloatArray

    def at(self, times: FloatArray, clock_offset_s: float = 0.0) -> FloatArray:
        """Speed at camera ``times`` (linear interpolation; NaN outside the samples), m/s."""
        tt = np.asarray(times, dtype=float) - clock_offset_s
        out = np.interp(tt, self.t, self.speed_mps)
        out[(tt < self.t[0]) | (tt > self.t[-1])] = np.nan
        return out


@dataclass(frozen=True)
class DriveTruth:
    """True values at each frame time (arrays of length n_frames; radians, metres, seconds).

    ``pitch``/``roll`` = mount + body; ``tx, tz, yaw`` = true metric motion from frame k-1
    to k in G_{k-1} (NaN at frame 0); ``x, y, heading`` = vehicle pose in the world frame of
    ``filters.model``."""

    t: FloatArray
    mount_pitch: FloatArray
    mount_roll: FloatArray
    mount_height: FloatArray
    mount_yaw: FloatArray
    body_pitch: FloatArray
    body_roll: FloatArray
    speed: FloatArray
    yaw_rate: FloatArray
    x: FloatArray
    y: FloatArray
    heading: FloatArray
    tx: FloatArray
    tz: FloatArray
    yaw: FloatArray

    @property
    def pitch(self) -> FloatArray:
        return self.mount_pitch + self.body_pitch

    @property
    def roll(self) -> FloatArray:
        return self.mount_roll + self.body_roll


@dataclass(frozen=True)
class DriveRun:
    """A simulated drive: truth, the measurement arrays and list, and wheel speed.

    ``z`` (n, 7) and ``covariance`` (n, 7, 7) are the arrays behind ``measurements``
    (frame 0 and failed frames hold NaN in ``z``); ``outlier`` marks replaced pairs."""

    config: DriveConfig
    truth: DriveTruth
    z: FloatArray
    covariance: FloatArray
    status: NDArray[np.str_]
    outlier: NDArray[np.bool_]
    measurements: list[PairMeasurement]
    speed: SpeedSamples


def simulate_drive(
    config: DriveConfig | None = None, seed: int = 0, profile: DriveProfile | None = None
) -> DriveRun:
    """Draw a drive of ``config`` (default: the car preset) from ``seed``, on the planar
    ``profile`` if given (else a random one); see module doc."""
    cfg = config or DriveConfig()
    if cfg.duration_s <= 0 or cfg.fps <= 0 or cfg.height_m <= 0 or cfg.h0 <= 0:
        raise ValueError("duration_s, fps, height_m and height_assumed_m must be > 0")
    rng = np.random.default_rng(seed)
    n = round(cfg.duration_s * cfg.fps) + 1
    t = np.arange(n) / cfg.fps
    truth = _truth(cfg, t, rng, profile)
    z, cov, status, outlier = _measurements(cfg, truth, rng)
    speed = _speed_samples(cfg, truth, rng)
    meas = [
        PairMeasurement(
            frame=k, t=float(t[k]), z=z[k], covariance=cov[k], height_assumed=cfg.h0,
            status=str(status[k]), inliers=0 if status[k] != "ok" else 99,
        )
        for k in range(n)
    ]
    return DriveRun(cfg, truth, z, cov, status, outlier, meas, speed)


# --- truth ----------------------------------------------------------------------------------


def _truth(
    cfg: DriveConfig, t: FloatArray, rng: np.random.Generator, profile: DriveProfile | None
) -> DriveTruth:
    n = len(t)
    dt = 1.0 / cfg.fps
    noise = cfg.noise
    # mount: nominal + changes + random walk
    pitch = np.full(n, np.radians(cfg.pitch_deg))
    roll = np.full(n, np.radians(cfg.roll_deg))
    height = np.full(n, cfg.height_m)
    yaw_m = np.full(n, np.radians(cfg.yaw_offset_deg))
    for ch in cfg.mount_changes:
        frac = (
            (t >= ch.t_s).astype(float) if ch.duration_s <= 0
            else np.clip((t - ch.t_s) / ch.duration_s, 0.0, 1.0)
        )
        pitch += np.radians(ch.pitch_deg) * frac
        roll += np.radians(ch.roll_deg) * frac
        height += ch.height_m * frac
    if cfg.mount_random_walk:
        walk = rng.standard_normal((n, 4)) * np.sqrt(dt)
        walk[0] = 0.0
        walk = np.cumsum(walk, axis=0)
        pitch += np.radians(noise.mount_angle_rw_deg_per_sqrt_s) * walk[:, 0]
        roll += np.radians(noise.mount_angle_rw_deg_per_sqrt_s) * walk[:, 1]
        height += noise.mount_height_rw_m_per_sqrt_s * walk[:, 2]
        yaw_m += np.radians(noise.mount_yaw_rw_deg_per_sqrt_s) * walk[:, 3]
    # body: AR(1) at the frame rate, started in its stationary distribution
    body = _gauss_markov(rng, n, 2, np.exp(-dt / noise.body_tau_s), np.radians(noise.body_std_deg))
    # the body's roll about its axis sways the camera sideways; the road's tilt does not
    sway = cfg.roll_arm_m * np.sin(body[:, 1])
    if cfg.road_std_deg > 0:
        body += _gauss_markov(rng, n, 2, np.exp(-dt / cfg.road_tau_s),
                              np.radians(cfg.road_std_deg))
    # planar drive on a fine grid
    tf = np.arange((n - 1) * _SUBSTEPS + 1) * (dt / _SUBSTEPS)
    if profile is None:
        v = _speed_profile(cfg, tf, rng)
        kappa = _curvature_profile(cfg, tf, rng)
    else:
        knots = np.array(profile.knot_t, dtype=float)
        v = _cosine_profile(knots, np.array(profile.speed_mps, dtype=float), tf)
        kappa = _cosine_profile(knots, np.array(profile.curvature_per_m, dtype=float), tf)
    omega = kappa * v
    dtf = dt / _SUBSTEPS
    psi = np.concatenate([[0.0], np.cumsum(0.5 * (omega[1:] + omega[:-1]) * dtf)])
    vx, vy = v * np.sin(psi), v * np.cos(psi)
    x = np.concatenate([[0.0], np.cumsum(0.5 * (vx[1:] + vx[:-1]) * dtf)])
    y = np.concatenate([[0.0], np.cumsum(0.5 * (vy[1:] + vy[:-1]) * dtf)])
    idx = np.arange(n) * _SUBSTEPS
    x, y, psi, v, omega = x[idx], y[idx], psi[idx], v[idx], omega[idx]
    # the camera: ``lever_arm_m`` ahead (sin ψ, cos ψ) and ``sway`` right (cos ψ, −sin ψ)
    # of the point the vehicle turns about (x, y)
    cam_x = x + cfg.lever_arm_m * np.sin(psi) + sway * np.cos(psi)
    cam_y = y + cfg.lever_arm_m * np.cos(psi) - sway * np.sin(psi)
    # true motion in G_{k-1} (heading ψ + yaw_m), metric
    tx = np.full(n, np.nan)
    tz = np.full(n, np.nan)
    yaw = np.full(n, np.nan)
    g = psi[:-1] + yaw_m[:-1]
    dx, dy = np.diff(cam_x), np.diff(cam_y)
    tx[1:] = np.cos(g) * dx - np.sin(g) * dy
    tz[1:] = np.sin(g) * dx + np.cos(g) * dy
    yaw[1:] = np.diff(psi)
    return DriveTruth(
        t=t, mount_pitch=pitch, mount_roll=roll, mount_height=height, mount_yaw=yaw_m,
        body_pitch=body[:, 0], body_roll=body[:, 1], speed=v, yaw_rate=omega, x=x, y=y,
        heading=psi, tx=tx, tz=tz, yaw=yaw,
    )


def _gauss_markov(
    rng: np.random.Generator, n: int, dims: int, a: float, std: float
) -> FloatArray:
    """(n, dims) stationary AR(1) series with coefficient ``a`` and std ``std``."""
    w = rng.standard_normal((n, dims)) * std * np.sqrt(1.0 - a * a)
    w[0] = rng.standard_normal(dims) * std
    return lfilter([1.0], [1.0, -a], w, axis=0)


def _cosine_profile(knot_t: FloatArray, knot_v: FloatArray, t: FloatArray) -> FloatArray:
    """Piecewise cosine interpolation through knots (flat where consecutive values agree)."""
    j = np.clip(np.searchsorted(knot_t, t, side="right") - 1, 0, len(knot_t) - 2)
    span = knot_t[j + 1] - knot_t[j]
    u = np.clip((t - knot_t[j]) / np.where(span > 0, span, 1.0), 0.0, 1.0)
    return knot_v[j] + (knot_v[j + 1] - knot_v[j]) * 0.5 * (1.0 - np.cos(np.pi * u))


def _speed_profile(cfg: DriveConfig, t: FloatArray, rng: np.random.Generator) -> FloatArray:
    """Speed (m/s): holds at random targets, cosine ramps at about ``accel_mps2``, stops."""
    knots_t, knots_v = [0.0], [rng.uniform(cfg.speed_min_mps, cfg.speed_max_mps)]
    end = t[-1] + 1.0
    while knots_t[-1] < end:
        hold = rng.exponential(cfg.segment_mean_s) + 1.0
        knots_t.append(knots_t[-1] + hold)
        knots_v.append(knots_v[-1])
        if knots_v[-1] > 0 and rng.random() < cfg.stop_probability:
            target = 0.0
        else:
            target = rng.uniform(cfg.speed_min_mps, cfg.speed_max_mps)
        # a cosine ramp's peak acceleration is π/2 × the mean: scale so the peak ≈ accel_mps2
        ramp = max(1.0, np.pi / 2 * abs(target - knots_v[-1]) / cfg.accel_mps2)
        knots_t.append(knots_t[-1] + ramp)
        knots_v.append(target)
        if target == 0.0:
            knots_t.append(knots_t[-1] + rng.uniform(*cfg.stop_s))
            knots_v.append(0.0)
    return _cosine_profile(np.array(knots_t), np.array(knots_v), t)


def _curvature_profile(cfg: DriveConfig, t: FloatArray, rng: np.random.Generator) -> FloatArray:
    """Curvature (1/m, > 0 turning right): straight stretches and turns with cosine entries."""
    knots_t, knots_k = [0.0], [0.0]
    end = t[-1] + 1.0
    while knots_t[-1] < end:
        knots_t.append(knots_t[-1] + rng.exponential(cfg.segment_mean_s) + 1.0)
        knots_k.append(knots_k[-1])
        turn = rng.random() < cfg.turn_probability and knots_k[-1] == 0.0
        size = rng.choice([-1.0, 1.0]) * rng.uniform(0.3, 1.0) * cfg.max_curvature_per_m
        target = size if turn else 0.0
        knots_t.append(knots_t[-1] + rng.uniform(1.0, 3.0))
        knots_k.append(target)
    return _cosine_profile(np.array(knots_t), np.array(knots_k), t)


# --- measurements ---------------------------------------------------------------------------


def _measurements(
    cfg: DriveConfig, tr: DriveTruth, rng: np.random.Generator
) -> tuple[FloatArray, FloatArray, NDArray[np.str_], NDArray[np.bool_]]:
    n = len(tr.t)
    scale = cfg.h0 / tr.mount_height
    truth = np.stack(
        [
            np.concatenate([[np.nan], tr.pitch[:-1]]), np.concatenate([[np.nan], tr.roll[:-1]]),
            tr.pitch, tr.roll, tr.tx * scale, tr.tz * scale, tr.yaw,
        ],
        axis=1,
    )
    # noise covariance: angles (pp, rp, pc, rc) with prev/curr correlation ρ
    sa = np.radians(cfg.angle_std_deg)
    rho = cfg.prev_curr_corr
    corr = np.array([[1, 0, rho, 0], [0, 1, 0, rho], [rho, 0, 1, 0], [0, rho, 0, 1]], dtype=float)
    c4 = sa**2 * corr
    travel = np.hypot(truth[:, 4], truth[:, 5])
    st = cfg.trans_std_rel * np.nan_to_num(travel) + cfg.trans_std_abs_m
    sy = np.radians(cfg.yaw_std_deg)
    cov = np.zeros((n, 7, 7))
    cov[:, :4, :4] = c4
    cov[:, 4, 4] = cov[:, 5, 5] = st**2
    cov[:, 6, 6] = sy**2
    eps = rng.standard_normal((n, 7))
    noise = np.empty((n, 7))
    noise[:, :4] = sa * eps[:, :4] @ np.linalg.cholesky(corr).T
    noise[:, 4:6] = eps[:, 4:6] * st[:, None]
    noise[:, 6] = eps[:, 6] * sy
    z = truth + noise

    status = np.full(n, "ok", dtype=object)
    status[0] = "first frame"
    still = np.nan_to_num(np.hypot(tr.tx, tr.tz)) < cfg.min_travel_m
    status[1:][still[1:]] = NO_MOTION_STATUS
    fail = rng.random(n) < cfg.failure_fraction
    status[fail & (status == "ok")] = "too few inliers"
    ok = status == "ok"
    # outliers: ok pairs replaced by a wrong solution of a few degrees / tens of percent
    outlier = ok & (rng.random(n) < cfg.outlier_fraction)
    m = int(outlier.sum())
    if m:
        sign = rng.choice([-1.0, 1.0], size=(m, 5))
        mag = rng.uniform(0.5, 1.0, size=(m, 5))
        z[outlier, :4] += np.radians(cfg.outlier_angle_deg) * sign[:, :4] * mag[:, :4]
        z[outlier, 4:6] *= (1.0 + cfg.outlier_trans_rel * sign[:, 4:5] * mag[:, 4:5])
        z[outlier, 6] += np.radians(cfg.outlier_angle_deg) * rng.uniform(-1.0, 1.0, m)
    z[~ok] = np.nan
    return z, cov * cfg.cov_scale, status.astype(str), outlier


def _speed_samples(cfg: DriveConfig, tr: DriveTruth, rng: np.random.Generator) -> SpeedSamples:
    """Wheel speed at ``speed_rate_hz`` on the sensor clock (= camera clock − offset)."""
    t_cam = np.arange(0.0, tr.t[-1], 1.0 / cfg.speed_rate_hz)
    v = np.interp(t_cam, tr.t, tr.speed)
    v = v * (1.0 + cfg.speed_noise_rel * rng.standard_normal(len(v)))
    if cfg.speed_quantum_kmh > 0:
        q = cfg.speed_quantum_kmh / 3.6
        v = np.round(v / q) * q
    return SpeedSamples(t=t_cam - cfg.speed_clock_offset_s, speed_mps=np.abs(v))
