"""State and measurement model shared by the EKF (``filters/ekf.py``) and the smoother.

The camera pose of frame k against the ground is split into a **slow mount** part (what a
calibration means) and a **fast body** part (suspension, shaking):

    pitch_k = pitch_m + b_pitch_k        roll_k = roll_m + b_roll_k        h_k = h_m

- mount (pitch_m, roll_m, h_m, yaw_m): random walks with tiny rates (``NoiseParams``);
  ``yaw_m`` is the heading of the camera's ground frame G to the right of the direction of
  travel (a camera turned right sees the vehicle move left: tx < 0);
- body (b_pitch, b_roll): zero-mean first-order Gauss–Markov, time constant ``body_tau_s``,
  stationary std ``body_std_deg``;
- planar motion: speed v (m/s, along the direction of travel), yaw rate ω (rad/s, > 0 turning
  right), both random walks; vehicle pose (x, y, ψ) in a world frame = the planar frame of the
  first frame: x to its right (G's x), y forward (G's z), heading ψ > 0 turning right
  (CONVENTIONS.md signs). The camera's G origin moves with the vehicle (no lever arm: the
  filters' output adds the lever arms measured from the pairs, ``filters.lever_arm``).

A pair measurement relates frames k-1 and k, so the state carries a *clone* of the previous
frame's body and planar pose (stochastic cloning): ``transition`` copies the current part into
the clone before propagating. The state vector (indices below, radians / metres / seconds):

    0 pitch_m  1 roll_m  2 h_m  3 yaw_m | 4 b_pitch  5 b_roll | 6 b_pitch_prev  7 b_roll_prev
    8 v  9 ω | 10 x  11 y  12 ψ | 13 x_prev  14 y_prev  15 ψ_prev

The 7-vector of ``vipm_track.measurement`` is predicted as

    (pitch_m + b_pitch_prev, roll_m + b_roll_prev, pitch_m + b_pitch, roll_m + b_roll,
     tx, tz, yaw)

where (tx, tz) is the displacement (x − x_prev, y − y_prev) rotated into G_{k-1} (heading
ψ_prev + yaw_m) and *scaled by h0 / h_m* (h0 = ``PairMeasurement.height_assumed``: two frames
fix translation in units of the height, CONVENTIONS.md Scale), and yaw = ψ − ψ_prev. A wheel
speed measures v in m/s, which makes h_m observable; without it h_m stays at its prior.

Standstill (zero-velocity update): a standing vehicle does not turn, but no pair says so (the
estimator cannot solve a pair without motion), so the random-walk yaw rate would keep its last
value and integrate it into the heading for the whole stop. ``standstill_states`` decides from a
frame's wheel speed and pair status that the vehicle stands, and ``standstill_measurement``
pins the yaw rate (and, without wheel speed, the speed) to 0 as a pseudo-measurement.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]

# --- state layout ---------------------------------------------------------------------------
MOUNT_PITCH, MOUNT_ROLL, MOUNT_HEIGHT, MOUNT_YAW = 0, 1, 2, 3
BODY_PITCH, BODY_ROLL = 4, 5
PREV_BODY_PITCH, PREV_BODY_ROLL = 6, 7
SPEED, YAW_RATE = 8, 9
POS_X, POS_Y, HEADING = 10, 11, 12
PREV_POS_X, PREV_POS_Y, PREV_HEADING = 13, 14, 15
STATE_DIM = 16

MOUNT = slice(0, 3)  # (pitch_m, roll_m, h_m): "the calibration"
BODY = slice(4, 6)
PREV_BODY = slice(6, 8)
POSE = slice(10, 13)
PREV_POSE = slice(13, 16)

STATE_NAMES: tuple[str, ...] = (
    "pitch_m", "roll_m", "h_m", "yaw_m", "b_pitch", "b_roll", "b_pitch_prev", "b_roll_prev",
    "v", "omega", "x", "y", "psi", "x_prev", "y_prev", "psi_prev",
)


@dataclass(frozen=True)
class NoiseParams:
    """Process noise and priors of the model (units in the names; angles in degrees here,
    radians through the ``*_rad`` helpers).

    Defaults suit a car-mounted camera at 10–30 fps; ``for_preset('cart')`` gives a walking cart.
    """

    #: mount random-walk rates (per √s): calibration drifts slowly
    mount_angle_rw_deg_per_sqrt_s: float = 0.002
    mount_height_rw_m_per_sqrt_s: float = 0.0002
    mount_yaw_rw_deg_per_sqrt_s: float = 0.002
    #: body shaking: first-order Gauss–Markov
    body_tau_s: float = 0.3
    body_std_deg: float = 0.2
    #: body std assumed while too few pairs have been seen to measure it (``body_scale``): a
    #: vehicle shaking by a degree (a cart on cobbles, a robot on gravel) is as likely at the
    #: start as a calm one
    body_std_unknown_deg: float = 1.5
    #: planar motion random walks (speed in m/s per √s, yaw rate in deg/s per √s): large
    #: enough that speed changes and turn entries and exits rarely trip the motion gate (a
    #: car leaving a turn on KITTI 07 lost 16 °/s of yaw rate in 0.5 s; at 2 °/s per √s the
    #: EKF gated those pairs and held the old rate, its yaw 1.5° off per frame at σ 0.14°)
    speed_rw_mps_per_sqrt_s: float = 0.5
    yaw_rate_rw_dps_per_sqrt_s: float = 8.0
    #: priors (standard deviations) at initialisation
    prior_mount_angle_std_deg: float = 3.0
    prior_height_std_rel: float = 0.05
    prior_mount_yaw_std_deg: float = 2.0
    prior_speed_std_mps: float = 5.0
    prior_yaw_rate_std_dps: float = 10.0
    #: wheel speed noise: relative std and absolute floor (quantisation 0.01 km/h ≈ 0.0028 m/s
    #: uniform → 0.0008 m/s std)
    speed_meas_std_rel: float = 0.005
    speed_meas_std_abs_mps: float = 0.002
    #: standstill (zero-velocity update, ``standstill_states``): a wheel speed at or below
    #: ``standstill_speed_mps`` (CAN logs read exactly 0 at a stop; 0.05 m/s = 0.18 km/h is
    #: above their quantisation and below walking pace) means the vehicle stands, and so does
    #: a pair reported as "no motion" when there is no wheel speed. Then the yaw rate is
    #: measured as 0 ± ``standstill_yaw_rate_std_dps`` (and, without wheel speed, the speed as
    #: 0 ± ``standstill_speed_std_mps``). The yaw-rate std allows for a vehicle still creeping
    #: at the threshold on a tight curve; ``standstill_update=False`` turns it off.
    standstill_update: bool = True
    standstill_speed_mps: float = 0.05
    standstill_yaw_rate_std_dps: float = 0.05
    standstill_speed_std_mps: float = 0.02
    #: floor on each frame's pitch/roll measurement std (deg): the estimator's covariance holds
    #: its POC noise only, while a frame's pose is measured by two pairs with correlated
    #: errors and the body model is approximate; trusting ~0.005° per frame lets the body
    #: shaking leak into the mount (rendered cart, drift-matched random walk: mount pitch
    #: 0.060° → 0.038°; 0.032° at 0.02°, where the frame pose starts to lag the raw one);
    #: simulated streams (0.1° per frame) are unaffected
    min_angle_meas_std_deg: float = 0.01
    #: floor on the std of a pair's pitch/roll *change* (current − previous frame), deg. The
    #: two frames' angles of a pair are correlated ~0.999 (their difference is what the pair
    #: measures best), and the estimator's covariance puts that difference 3–5× too tight:
    #: 0.0021° reported vs 0.0097° RMS error on the rendered car drive (0.0006° vs 0.0008° on
    #: the cart; KITTI 07: 0.013° vs 0.07°, road slope included). Trusted as reported, a
    #: smoother's robust loss rejects most pose blocks. The floor (at most the angles' own
    #: variance, so independent angles keep theirs) adds noise to the change only (the pair's
    #: mean angle keeps its variance); 0.01° let the shaking leak into a fast-walking mount
    #: (docs/filters.md)
    min_angle_change_std_deg: float = 0.03
    #: the model moves the camera as the vehicle, without side slip; a camera ahead of (or
    #: behind) the axle the vehicle turns about also slides sideways by ~L·Δψ over a pair that
    #: turns by Δψ (KITTI 07: 0.05–0.1 m per frame in its turns at 30°/s). Its lateral motion
    #: (tx) gets that much more variance, with L up to ``lever_arm_std_m``, or the mount yaw
    #: absorbs the turns (6° on KITTI) and the motion gate locks out the pairs after them
    lever_arm_std_m: float = 2.0

    def pair_covariance(self, covariance: FloatArray, yaw_rad: float = 0.0) -> FloatArray:
        """A pair's 7×7 measurement covariance as the filters use it: the estimator's, each
        pitch/roll variance raised to at least ``min_angle_meas_std_deg``² (correlations
        scaled along), the variance of each angle's change within the pair to at least
        ``min_angle_change_std_deg``², and the lateral motion's raised by the unmodelled lever
        arm of a pair turning by ``yaw_rad`` (``lever_arm_std_m``)."""
        cov = np.array(covariance, dtype=float)
        if math.isfinite(yaw_rad):
            cov[4, 4] += (self.lever_arm_std_m * math.sin(yaw_rad)) ** 2
        floor = math.radians(self.min_angle_meas_std_deg)
        for i in range(4):  # scalars: this runs for every pair of every filter
            var = float(cov[i, i])
            if var == 0.0:
                cov[i, i] = floor**2
            elif 0.0 < var < floor**2:
                scale = floor / math.sqrt(var)
                cov[i, :] *= scale
                cov[:, i] *= scale
        change_floor = math.radians(self.min_angle_change_std_deg) ** 2
        for prev, curr in ((0, 2), (1, 3)):
            # the floor, but never above the angles' own variance: a pair whose angles are
            # (nearly) independent keeps its covariance; only a change claimed far better
            # known than either angle is doubted
            floor = min(change_floor, 0.5 * (cov[prev, prev] + cov[curr, curr]))
            # noise of variance δ on the change alone: ±δ/4 on (prev, curr), −δ/4 between
            short = floor - (cov[prev, prev] + cov[curr, curr] - 2.0 * cov[prev, curr])
            if short > 0.0:
                cov[prev, prev] += 0.25 * short
                cov[curr, curr] += 0.25 * short
                cov[prev, curr] -= 0.25 * short
                cov[curr, prev] -= 0.25 * short
        return cov

    @classmethod
    def for_preset(cls, preset: str) -> NoiseParams:
        """Defaults for ``car`` (road vehicle) or ``cart`` (walking-speed cart)."""
        if preset == "car":
            return cls()
        if preset == "cart":
            return cls(speed_rw_mps_per_sqrt_s=0.1, yaw_rate_rw_dps_per_sqrt_s=5.0)
        raise ValueError(f"unknown preset {preset!r}; expected 'car' or 'cart'")

    @property
    def initial_body_std_deg(self) -> float:
        """Body std (deg) before the shaking has been measured: the prior of the first frame's
        body and the adaptive std's start (``body_scale``)."""
        return max(self.body_std_unknown_deg, self.body_std_deg)

    def speed_meas_var(self, speed_mps: float) -> float:
        """Variance of one wheel-speed reading at ``speed_mps``, (m/s)²."""
        return (self.speed_meas_std_rel * abs(speed_mps)) ** 2 + self.speed_meas_std_abs_mps**2

    def standstill_var(self, states: tuple[int, ...]) -> FloatArray:
        """Variances of the standstill pseudo-measurement of ``states`` (``SPEED`` in (m/s)²,
        ``YAW_RATE`` in (rad/s)²), in that order."""
        var = {
            SPEED: self.standstill_speed_std_mps**2,
            YAW_RATE: np.radians(self.standstill_yaw_rate_std_dps) ** 2,
        }
        return np.array([var[i] for i in states], dtype=float)


# --- process model --------------------------------------------------------------------------


def body_transition(
    dt: float, noise: NoiseParams, std: FloatArray | None = None
) -> tuple[FloatArray, FloatArray]:
    """Decay a and process variance (rad²) of the Gauss–Markov body (pitch, roll) over ``dt``
    s with stationary std ``std`` (rad, per axis; None: ``body_std_deg``):
    b_k = a·b_{k-1} + w. A larger std comes with a shorter time constant,
    τ = ``body_tau_s`` · (σ₀/σ)², so the body's low-frequency power 2σ²τ, what competes with
    the slow mount, stays the model's (``filters.body_scale``: the std adapted to the data)."""
    std0 = math.radians(noise.body_std_deg)
    std = np.full(2, std0) if std is None else np.asarray(std, dtype=float)
    decay = np.exp(-dt * (std / std0) ** 2 / noise.body_tau_s)
    return decay, std**2 * (1.0 - decay**2)


def propagate_pose(
    x: float, y: float, psi: float, v: float, omega: float, dt: float
) -> tuple[float, float, float]:
    """Vehicle pose after ``dt`` s at speed v (m/s) and yaw rate ω (rad/s): midpoint heading."""
    a = psi + 0.5 * omega * dt
    return x + v * dt * np.sin(a), y + v * dt * np.cos(a), psi + omega * dt


def travel_sign(z: FloatArray) -> FloatArray:
    """Direction of travel of pair motions ``z`` (..., 7; rows 4–5: tx, tz): +1 forward along
    the camera's ground z, −1 backward (reversing, or a camera that faces backward)."""
    return np.where(np.asarray(z, dtype=float)[..., 5] < 0, -1.0, 1.0)


def pair_rates(
    z: FloatArray, height_m: float, height_assumed: float, dt: float
) -> tuple[float, float]:
    """Speed (m/s, signed: < 0 reversing) and yaw rate (rad/s) that a pair's motion ``z``
    (rows 4–6: tx, tz at the assumed height h0, m; yaw, rad) implies over ``dt`` s at mount
    height ``height_m``."""
    speed = float(travel_sign(z)) * math.hypot(z[4], z[5]) * height_m / height_assumed / dt
    return speed, z[6] / dt


#: highest wheel speed (m/s) at which the direction of travel may change (a vehicle reverses
#: only through a stop; above it, a pair that seems to go the other way is an outlier)
REVERSAL_MAX_SPEED_MPS = 1.0


#: fastest a vehicle is taken to reverse (m/s, 18 km/h): a drive that starts with its wheels
#: faster goes forward, whatever its first pairs say
REVERSING_MAX_SPEED_MPS = 5.0


def initial_direction(z: FloatArray, readings: FloatArray | None = None) -> float:
    """Direction of travel (+1 / −1, ``travel_sign``) of a drive's first pair motions ``z``
    (n, 7): the sign of their median tz; +1 without any, or where the wheel ``readings`` at
    those pairs (m/s, NaN: none) read faster than ``REVERSING_MAX_SPEED_MPS`` (median of
    their magnitudes): travel beyond the estimator's range aliases to a short backward one,
    and a car at 35 m/s taken as reversing from three such pairs went backwards all drive."""
    z = np.asarray(z, dtype=float).reshape(-1, 7)
    if not len(z):
        return 1.0
    if readings is not None:
        known = np.abs(np.asarray(readings, dtype=float))
        known = known[np.isfinite(known)]
        if known.size and float(np.median(known)) > REVERSING_MAX_SPEED_MPS:
            return 1.0
    return float(travel_sign(np.median(z, axis=0)))


def travel_direction(previous: float, reading: float, z: FloatArray | None) -> float:
    """Direction of travel (+1 / −1) at a frame with wheel-speed ``reading`` (m/s; NaN: none)
    and pair motion ``z`` (None: no usable pair): ``previous`` unless the reading's magnitude
    is at most ``REVERSAL_MAX_SPEED_MPS`` and the pair says otherwise (``travel_sign``).

    The reading's sign is not trusted: most wheel speeds are magnitudes, and a signed one
    whose sign convention is the opposite of ours (or a logger that negates it) would lock
    every pair out as going the wrong way; ``speed_sign_conflicts`` reports such spans."""
    if z is None or not abs(reading) <= REVERSAL_MAX_SPEED_MPS:
        return previous
    return float(travel_sign(z))


def signed_speed(reading: float, direction: float) -> float:
    """A wheel-speed ``reading`` (m/s) as the state's signed speed v: its magnitude in the
    ``direction`` of travel (``travel_direction``); NaN stays NaN."""
    return direction * abs(reading)


def speed_sign_conflicts(
    t: FloatArray, readings: FloatArray, z: FloatArray, min_span_s: float = 2.0
) -> list[tuple[float, float]]:
    """Spans (first, last frame time, s) of at least ``min_span_s`` over which the wheel
    ``readings`` (m/s at frame times ``t``) are negative — a source saying it reverses —
    while the pairs' motions ``z`` (n, 7; NaN rows: no usable pair) go forward at more than
    ``REVERSAL_MAX_SPEED_MPS``. Frames without a reading or a pair neither break nor extend
    a span's evidence; a frame that agrees ends it."""
    t = np.asarray(t, dtype=float)
    v = np.asarray(readings, dtype=float)
    z = np.asarray(z, dtype=float).reshape(-1, 7)
    known = np.isfinite(v) & np.all(np.isfinite(z[:, 4:6]), axis=1)
    forward = travel_sign(np.nan_to_num(z)) > 0
    conflict = known & (v < -REVERSAL_MAX_SPEED_MPS) & forward
    agree = known & ~conflict
    spans: list[tuple[float, float]] = []
    start = last = None
    for k in range(len(t)):
        if conflict[k]:
            start = t[k] if start is None else start
            last = t[k]
        elif agree[k] and start is not None:
            if last - start >= min_span_s:
                spans.append((float(start), float(last)))
            start = last = None
    if start is not None and last - start >= min_span_s:
        spans.append((float(start), float(last)))
    return spans


def transition(
    state: FloatArray, dt: float, noise: NoiseParams
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """State after ``dt`` seconds (clone, then propagate), its Jacobian F and process noise Q.

    The clone slots receive the current body and pose *before* propagation, so after this call
    they hold frame k-1 and the current slots frame k.
    """
    n = STATE_DIM
    s = np.array(state, dtype=float)
    # cloning: a linear copy
    c = np.eye(n)
    c[PREV_BODY, :] = 0.0
    c[PREV_POSE, :] = 0.0
    c[PREV_BODY, BODY] = np.eye(2)
    c[PREV_POSE, POSE] = np.eye(3)
    s = c @ s

    v, om, psi = s[SPEED], s[YAW_RATE], s[HEADING]
    a = psi + 0.5 * om * dt
    sa, ca = np.sin(a), np.cos(a)
    decay, bvar = body_transition(dt, noise)
    out = s.copy()
    out[BODY] *= decay
    out[POS_X], out[POS_Y], out[HEADING] = propagate_pose(s[POS_X], s[POS_Y], psi, v, om, dt)

    f = np.eye(n)
    f[BODY, BODY] = np.diag(decay)
    f[POS_X, SPEED] = dt * sa
    f[POS_Y, SPEED] = dt * ca
    f[POS_X, HEADING] = v * dt * ca
    f[POS_Y, HEADING] = -v * dt * sa
    f[POS_X, YAW_RATE] = v * dt * ca * 0.5 * dt
    f[POS_Y, YAW_RATE] = -v * dt * sa * 0.5 * dt
    f[HEADING, YAW_RATE] = dt
    jac = f @ c

    q = np.zeros((n, n))
    ang = np.radians(noise.mount_angle_rw_deg_per_sqrt_s) ** 2 * dt
    q[MOUNT_PITCH, MOUNT_PITCH] = q[MOUNT_ROLL, MOUNT_ROLL] = ang
    q[MOUNT_HEIGHT, MOUNT_HEIGHT] = noise.mount_height_rw_m_per_sqrt_s**2 * dt
    q[MOUNT_YAW, MOUNT_YAW] = np.radians(noise.mount_yaw_rw_deg_per_sqrt_s) ** 2 * dt
    q[BODY_PITCH, BODY_PITCH], q[BODY_ROLL, BODY_ROLL] = bvar
    # white acceleration (speed random walk) integrated into the along-track position
    qa = noise.speed_rw_mps_per_sqrt_s**2
    u = np.array([sa, ca])
    pos = [POS_X, POS_Y]
    q[np.ix_(pos, pos)] += qa * dt**3 / 3.0 * np.outer(u, u)
    q[pos, SPEED] += qa * dt**2 / 2.0 * u
    q[SPEED, pos] += qa * dt**2 / 2.0 * u
    q[SPEED, SPEED] += qa * dt
    # white yaw acceleration integrated into the heading
    qw = np.radians(noise.yaw_rate_rw_dps_per_sqrt_s) ** 2
    q[HEADING, HEADING] += qw * dt**3 / 3.0
    q[HEADING, YAW_RATE] += qw * dt**2 / 2.0
    q[YAW_RATE, HEADING] += qw * dt**2 / 2.0
    q[YAW_RATE, YAW_RATE] += qw * dt
    return out, jac, q


# --- measurement model ----------------------------------------------------------------------


def expected_pair(
    mount: tuple[float, float, float, float],
    body_prev: tuple[float, float],
    body_curr: tuple[float, float],
    pose_prev: tuple[float, float, float],
    pose_curr: tuple[float, float, float],
    height_assumed: float,
) -> FloatArray:
    """Expected pair 7-vector (pitch_prev, roll_prev, pitch, roll, tx, tz, yaw), rad / m.

    ``mount`` = (pitch_m, roll_m, h_m, yaw_m); bodies are (b_pitch, b_roll); poses are the
    vehicle's world (x, y, ψ). tx, tz are in metres *at* ``height_assumed`` (h0): the true
    displacement in G_{k-1} times h0 / h_m. The smoother's pair factor uses this function.
    Entries may be arrays of one shape (many pairs): the result is then (..., 7).
    """
    pitch_m, roll_m, h_m, yaw_m = mount
    dx, dy = pose_curr[0] - pose_prev[0], pose_curr[1] - pose_prev[1]
    g = pose_prev[2] + yaw_m
    c, s = np.cos(g), np.sin(g)
    k = height_assumed / h_m
    # np.array(...).T: (7,) from scalars, (..., 7) from arrays (cheap for the EKF's scalars)
    return np.array([
        pitch_m + body_prev[0], roll_m + body_prev[1],
        pitch_m + body_curr[0], roll_m + body_curr[1],
        k * (c * dx - s * dy), k * (s * dx + c * dy),
        pose_curr[2] - pose_prev[2],
    ]).T


# the pair Jacobian's constant entries (angles = mount + body, yaw = ψ_k − ψ_{k-1}) and the
# (row, column) of its state-dependent ones (pair_measurement)
_PAIR_JAC_CONST = np.zeros((7, STATE_DIM))
_PAIR_JAC_CONST[[0, 2, 1, 3, 0, 1, 2, 3], [MOUNT_PITCH, MOUNT_PITCH, MOUNT_ROLL, MOUNT_ROLL,
                                            PREV_BODY_PITCH, PREV_BODY_ROLL, BODY_PITCH,
                                            BODY_ROLL]] = 1.0
_PAIR_JAC_CONST[6, HEADING], _PAIR_JAC_CONST[6, PREV_HEADING] = 1.0, -1.0
_PAIR_JAC_ROWS = np.array([4, 4, 4, 4, 5, 5, 5, 5, 4, 4, 5, 5, 4, 5])
_PAIR_JAC_COLS = np.array([
    POS_X, POS_Y, PREV_POS_X, PREV_POS_Y, POS_X, POS_Y, PREV_POS_X, PREV_POS_Y,
    PREV_HEADING, MOUNT_YAW, PREV_HEADING, MOUNT_YAW, MOUNT_HEIGHT, MOUNT_HEIGHT,
])


def pair_measurement(
    state: FloatArray, height_assumed: float | FloatArray
) -> tuple[FloatArray, FloatArray]:
    """Expected pair 7-vector of ``state`` (see ``expected_pair``) and its 7×16 Jacobian;
    ``state`` (..., 16) gives (..., 7) and (..., 7, 16)."""
    s = np.asarray(state, dtype=float)
    v = s.T  # v[i]: a scalar for one state, the (...) array of state entry i for many
    h0 = height_assumed if np.ndim(height_assumed) == 0 else np.asarray(height_assumed).T
    z = expected_pair(
        (v[MOUNT_PITCH], v[MOUNT_ROLL], v[MOUNT_HEIGHT], v[MOUNT_YAW]),
        (v[PREV_BODY_PITCH], v[PREV_BODY_ROLL]), (v[BODY_PITCH], v[BODY_ROLL]),
        (v[PREV_POS_X], v[PREV_POS_Y], v[PREV_HEADING]), (v[POS_X], v[POS_Y], v[HEADING]),
        h0,
    )
    zt = z.T
    dx, dy = v[POS_X] - v[PREV_POS_X], v[POS_Y] - v[PREV_POS_Y]
    g = v[PREV_HEADING] + v[MOUNT_YAW]
    c, sn = np.cos(g), np.sin(g)
    k = h0 / v[MOUNT_HEIGHT]
    # tx = k (c dx - s dy), tz = k (s dx + c dy); entries in _PAIR_JAC_ROWS/COLS order
    dtx_dg, dtz_dg = k * (-sn * dx - c * dy), k * (c * dx - sn * dy)
    kc, ks = k * c, k * sn
    h = np.empty((*s.shape[:-1], 7, STATE_DIM))
    h[...] = _PAIR_JAC_CONST
    h[..., _PAIR_JAC_ROWS, _PAIR_JAC_COLS] = np.array(
        [kc, -ks, -kc, ks, ks, kc, -ks, -kc, dtx_dg, dtx_dg, dtz_dg, dtz_dg,
         -zt[4] / v[MOUNT_HEIGHT], -zt[5] / v[MOUNT_HEIGHT]]
    ).T
    return z, h


def motion_given_pose(covariance: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Split a pair's 7×7 covariance (``pair_covariance``) into its four angles and the
    motion given them: (A, C) with motion error − A · angle error independent of the angle
    error and of covariance C (3×3).

    The estimator's tz is correlated ~−0.95 with its pitch (a steeper camera sees the same
    image motion as a shorter step), so a smoother that knows a frame's pose better than one
    pair does also corrects that pair's motion by A · (its pose − the pair's)."""
    cov = np.asarray(covariance, dtype=float)
    gain = np.linalg.solve(cov[:4, :4], cov[:4, 4:]).T
    conditional = cov[4:, 4:] - gain @ cov[:4, 4:]
    return gain, 0.5 * (conditional + conditional.T)


def speed_measurement(state: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Expected wheel speed (1-vector, m/s) and its 1×16 Jacobian."""
    h = np.zeros((1, STATE_DIM))
    h[0, SPEED] = 1.0
    return np.array([state[SPEED]]), h


#: pair status of the two-frame estimator when the image did not move
#: (``vipm_track.pair_result.STATUS_NO_MOTION``; a test holds them equal)
NO_MOTION_STATUS = "no motion"


def standstill_states(
    speed_mps: float | None, pair_status: str | None, noise: NoiseParams
) -> tuple[int, ...]:
    """State indices a standstill pins to 0 at a frame: ``(YAW_RATE,)`` when the wheel speed
    (m/s) is at most ``noise.standstill_speed_mps`` (the wheel speed itself measures v),
    ``(SPEED, YAW_RATE)`` when there is no wheel speed (None / NaN) and the pair's status is
    ``NO_MOTION_STATUS``, else ``()`` (moving, or nothing says otherwise)."""
    if not noise.standstill_update:
        return ()
    if speed_mps is not None and np.isfinite(speed_mps):
        return (YAW_RATE,) if abs(speed_mps) <= noise.standstill_speed_mps else ()
    return (SPEED, YAW_RATE) if pair_status == NO_MOTION_STATUS else ()


def standstill_measurement(
    state: FloatArray, states: tuple[int, ...]
) -> tuple[FloatArray, FloatArray]:
    """Expected standstill pseudo-measurement (the ``states`` of ``state``, measured as 0) and
    its len(states)×16 Jacobian; noise ``NoiseParams.standstill_var(states)``."""
    idx = list(states)
    h = np.zeros((len(idx), STATE_DIM))
    h[np.arange(len(idx)), idx] = 1.0
    return np.asarray(state, dtype=float)[idx].copy(), h


def metric_motion(state: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Filtered motion (tx, tz, yaw) from frame k-1 to k in metres (true scale) / rad, in
    G_{k-1}, and its 3×16 Jacobian (the pair model with h0 = h_m); ``state`` (..., 16)
    gives (..., 3) and (..., 3, 16)."""
    s = np.asarray(state, dtype=float)
    z, h = pair_measurement(s, s[..., MOUNT_HEIGHT])
    jac = h[..., 4:7, :].copy()
    jac[..., MOUNT_HEIGHT] = 0.0  # h0 = h_m cancels
    motion = z[..., 4:7].copy()
    # a heading kept in (-π, π] (the smoothers' Pose2) turns by 2π where it crosses ±π
    motion[..., 2] = wrap_angle(motion[..., 2])
    return motion, jac


def wrap_angle(a: FloatArray | float) -> FloatArray:
    """Angles (rad) wrapped to [-π, π)."""
    return (np.asarray(a, dtype=float) + np.pi) % (2 * np.pi) - np.pi


#: Jacobian of the frame pose (pitch, roll, h) = mount + body w.r.t. the state
_FRAME_POSE_JAC = np.zeros((3, STATE_DIM))
_FRAME_POSE_JAC[0, MOUNT_PITCH] = _FRAME_POSE_JAC[0, BODY_PITCH] = 1.0
_FRAME_POSE_JAC[1, MOUNT_ROLL] = _FRAME_POSE_JAC[1, BODY_ROLL] = 1.0
_FRAME_POSE_JAC[2, MOUNT_HEIGHT] = 1.0
_FRAME_POSE_JAC.setflags(write=False)


def frame_pose(state: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Current frame pose (pitch, roll, h) = mount + body, rad / m, and its 3×16 Jacobian;
    ``state`` (..., 16) gives (..., 3) (the Jacobian is the same for every state)."""
    return np.asarray(state, dtype=float) @ _FRAME_POSE_JAC.T, _FRAME_POSE_JAC
