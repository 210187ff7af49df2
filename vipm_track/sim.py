"""Synthetic ground sequences with exact ground truth: presets, trajectories, writer.

A :class:`Trajectory` holds, per frame, the camera pose against the ground, the world pose
of the frame's ground frame G and (derived from consecutive world poses with geometry's
``compose_motion``) the planar motion k-1 → k in the sense of CONVENTIONS.md.
:func:`simulate_sequence` renders one (``render.render_frame``) and writes
``DIR/images/000000.png …``, ``DIR/camera.yaml`` (ROS camera_info), ``DIR/gt.csv`` and
``DIR/times.txt`` and ``DIR/speed.csv`` (a simulated wheel speed, :func:`wheel_speed_samples`:
50 Hz, 0.5 % noise, 0.01 km/h resolution); with ``traffic``, vehicles on the road
(``traffic.py``) and ``DIR/traffic.csv``.

Profiles follow the paper's experiments: ``static`` (constant pose), ``gradual`` (slow
pitch/roll changes of a few degrees over seconds), ``shaking`` (1–3 Hz pitch/roll
oscillations of ~1–2° plus a little height change), ``height`` (height variation),
``turn`` (constant yaw rate), ``drift`` (a slow linear mount pitch/roll drift, the
calibration changing, under 1–3 Hz body shaking of ~0.3°: the filters' mount + body model),
``knock`` (the same shaking on a fixed mount whose pitch steps by 1° at 40 % of the drive:
a camera knocked out of its calibration).

Where a profile separates the slow mount (the calibration) from the body motion, the
trajectory's ``mount_*`` arrays hold the mount part and ``gt.csv`` has ``mount_*`` columns
(empty for ``gradual`` and ``height``, whose pose changes are neither).
"""

from __future__ import annotations

import csv
import errno
import functools
import math
import re
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray
from scipy.interpolate import CubicSpline

from .camera import CameraModel, write_ros_yaml
from .errors import InputError
from .geometry import (
    GroundPose,
    PlanarMotion,
    below_horizon,
    compose_motion,
    invert_motion,
    predict_pixels,
)
from .progress import progress_bar
from .render import Effects, ExposureBand, ExposurePose, render_frame, world_pose_motion
from .table import TableWriter, write_columns_csv
from .texture import TEXTURES, GroundTexture, load_texture
from .traffic import TRAFFIC_COLUMNS, Vehicle, draw_traffic, make_traffic, traffic_rows

PROFILES: tuple[str, ...] = (
    "static", "gradual", "shaking", "height", "turn", "drift", "knock",
)
GT_EXTRA_COLUMNS: tuple[str, ...] = (
    "prev_pitch_deg", "prev_roll_deg", "prev_height_m", "speed_mps",
    "world_x_m", "world_z_m", "world_heading_deg",
    "mount_pitch_deg", "mount_roll_deg", "mount_height_m",
)
#: mount drift of the ``drift`` profile per unit amplitude, degrees per second (pitch, roll)
DRIFT_RATE_DPS: tuple[float, float] = (0.01, -0.006)
#: amplitude of each of the three body-shaking sinusoids of ``drift``, degrees (pitch, roll)
DRIFT_SHAKE_DEG: tuple[float, float] = (0.2, 0.15)
#: mount pitch step of ``knock`` per unit amplitude, degrees, and when it happens (fraction
#: of the drive's duration)
KNOCK_PITCH_DEG: float = 1.0
KNOCK_AT: float = 0.4


@dataclass(frozen=True)
class Preset:
    """A simulated rig: camera intrinsics, nominal pose against the ground, frame rate,
    nominal speed [m/s], turn rate of the ``turn`` profile [deg/s] and ground texture."""

    name: str
    width: int
    height: int
    fx: float
    pitch_deg: float
    height_m: float
    fps: float
    speed_mps: float
    turn_rate_dps: float
    texture: str
    metres_per_texel: float
    texture_tiles: int
    roll_deg: float = 0.0

    def camera(self) -> CameraModel:
        """Pinhole camera (square pixels, principal point at the image centre)."""
        cx, cy = (self.width - 1) / 2.0, (self.height - 1) / 2.0
        k = np.array([[self.fx, 0.0, cx], [0.0, self.fx, cy], [0.0, 0.0, 1.0]])
        return CameraModel(k=k, width=self.width, height=self.height)

    def pose(self) -> GroundPose:
        return GroundPose(np.radians(self.pitch_deg), np.radians(self.roll_deg), self.height_m)


PRESETS: dict[str, Preset] = {
    # The paper's cart: 800×600, f ≈ 729 px, h ≈ 0.7 m, looking 45° down, walking speed.
    "cart": Preset("cart", 800, 600, 729.0, 45.0, 0.7, 10.0, 1.2, 15.0, "gravel", 0.0015, 24),
    # Forward-looking dashcam: 1280×720, f ≈ 900 px, h ≈ 1.5 m, pitch 3°, 5–20 m/s.
    "car": Preset("car", 1280, 720, 900.0, 3.0, 1.5, 20.0, 12.0, 8.0, "gravel", 0.008, 24),
    # KITTI's grey camera: 1241×376, f ≈ 718 px, h 1.65 m, near level (1°), 10 fps, town speed;
    # wide and short, so a vehicle ahead fills much of its ground
    "kitti": Preset("kitti", 1241, 376, 718.0, 1.0, 1.65, 10.0, 8.0, 8.0, "gravel", 0.008, 24),
}


@dataclass(frozen=True)
class Trajectory:
    """Per-frame ground truth of a simulated drive.

    Attributes: ``t`` [s] (N,), ``pitch``/``roll`` [rad] (N,), ``height`` [m] (N,),
    ``world_xz`` [m] (N, 2) and ``world_heading`` [rad] (N,) of each frame's G in the world,
    ``speed`` [m/s] (N,); ``mount_pitch``/``mount_roll`` [rad], ``mount_height`` [m] (N,): the
    slow mount part of the pose where the profile defines one (else ``None``).
    """

    t: NDArray[np.float64]
    pitch: NDArray[np.float64]
    roll: NDArray[np.float64]
    height: NDArray[np.float64]
    world_xz: NDArray[np.float64]
    world_heading: NDArray[np.float64]
    speed: NDArray[np.float64]
    mount_pitch: NDArray[np.float64] | None = None
    mount_roll: NDArray[np.float64] | None = None
    mount_height: NDArray[np.float64] | None = None

    def __len__(self) -> int:
        return len(self.t)

    def pose(self, k: int) -> GroundPose:
        """Pose of frame k against the ground."""
        return GroundPose(float(self.pitch[k]), float(self.roll[k]), float(self.height[k]))

    def world_pose(self, k: int) -> PlanarMotion:
        """World pose of frame k's G as the planar motion W → G_k."""
        return world_pose_motion(self.world_xz[k], float(self.world_heading[k]))

    def motion(self, k: int) -> PlanarMotion:
        """Planar motion from frame k-1 to frame k (CONVENTIONS.md), k ≥ 1."""
        if k < 1:
            raise IndexError("frame 0 has no motion")
        m = compose_motion(invert_motion(self.world_pose(k - 1)), self.world_pose(k))
        return PlanarMotion(float(m.tx), float(m.tz), float(m.yaw))

    def pose_at(self, u: float) -> ExposurePose:
        """Pose against the ground, world (x, z) [m] and heading [rad] at the fractional frame
        index ``u`` (motion blur, rolling shutter): cubic splines through the frames, which
        keep a constant acceleration exact between and beyond them."""
        if len(self) == 1:
            return self.pose(0), self.world_xz[0].copy(), float(self.world_heading[0])
        pitch, roll, height, x, z, heading = (float(v) for v in self._splines(u))
        return GroundPose(pitch, roll, height), np.array([x, z]), heading

    @functools.cached_property
    def _splines(self) -> CubicSpline:
        values = np.column_stack([self.pitch, self.roll, self.height, self.world_xz,
                                  self.world_heading])
        return CubicSpline(np.arange(len(self)), values, axis=0)

    @property
    def poses(self) -> list[GroundPose]:
        return [self.pose(k) for k in range(len(self))]

    @property
    def motions(self) -> list[PlanarMotion | None]:
        """Motion k-1 → k per frame; ``None`` for frame 0."""
        return [None] + [self.motion(k) for k in range(1, len(self))]


def make_trajectory(
    profile: str,
    n_frames: int,
    fps: float | None = None,
    preset: Preset | str = "cart",
    seed: int = 0,
    speed: float | None = None,
    amplitude: float = 1.0,
) -> Trajectory:
    """Ground truth of ``n_frames`` frames at ``fps`` for a pose ``profile`` (see
    :data:`PROFILES`) around the preset's nominal pose.

    ``speed`` [m/s] overrides the preset's; the speed varies smoothly by ±5 % (seeded).
    ``amplitude`` scales the profile's pose changes. Deterministic from ``seed``.
    """
    p = PRESETS[preset] if isinstance(preset, str) else preset
    if profile not in PROFILES:
        raise ValueError(f"unknown profile '{profile}'; choose one of {list(PROFILES)}")
    if n_frames < 1:
        raise ValueError(f"n_frames must be ≥ 1, got {n_frames}")
    fps = float(fps or p.fps)
    if fps <= 0:
        raise ValueError(f"fps must be > 0, got {fps}")
    v0 = float(p.speed_mps if speed is None else speed)
    if v0 < 0:
        raise ValueError(f"speed must be ≥ 0, got {v0}")
    rng = np.random.default_rng(seed)
    t = np.arange(n_frames) / fps
    pitch, roll, height = _PROFILE_FUNCS[profile](t, p, rng, amplitude)
    mount = _MOUNT_FUNCS[profile](t, p, amplitude) if profile in _MOUNT_FUNCS else (None,) * 3
    # Speed with a slow seeded variation; heading from the yaw rate; position integrated on
    # a fine clock (the motion is then read off the world poses exactly).
    sub = 16
    tf = np.arange((n_frames - 1) * sub + 1) / (fps * sub)
    phase = rng.uniform(0, 2 * np.pi)
    vf = v0 * (1.0 + 0.05 * np.sin(2 * np.pi * tf / 7.0 + phase))
    rate = np.radians(p.turn_rate_dps) * amplitude if profile == "turn" else 0.0
    heading_f = rate * tf
    dt = 1.0 / (fps * sub)
    mid_heading = heading_f[:-1] + 0.5 * rate * dt
    mid_v = 0.5 * (vf[:-1] + vf[1:])
    step_xz = np.stack([np.sin(mid_heading), np.cos(mid_heading)], axis=1) * (mid_v * dt)[:, None]
    xz_f = np.vstack([np.zeros((1, 2)), np.cumsum(step_xz, axis=0)])
    return Trajectory(t, pitch, roll, height, xz_f[::sub].copy(), heading_f[::sub].copy(),
                      vf[::sub].copy(), *mount)


def _static(t, p, rng, a):
    n = len(t)
    base = p.pose()
    return np.full(n, base.pitch), np.full(n, base.roll), np.full(n, base.height)


def _gradual(t, p, rng, a):
    pitch, roll, height = _static(t, p, rng, a)
    ph = rng.uniform(0, 2 * np.pi, 2)
    pitch = pitch + a * np.radians(2.0) * np.sin(2 * np.pi * t / 8.0 + ph[0])
    roll = roll + a * np.radians(1.5) * np.sin(2 * np.pi * t / 11.0 + ph[1])
    return pitch, roll, height


def _shaking(t, p, rng, a):
    pitch, roll, height = _static(t, p, rng, a)
    for _ in range(3):
        f, ph = rng.uniform(1.0, 3.0, 2), rng.uniform(0, 2 * np.pi, 3)
        pitch = pitch + a * np.radians(0.8) * np.sin(2 * np.pi * f[0] * t + ph[0])
        roll = roll + a * np.radians(0.6) * np.sin(2 * np.pi * f[1] * t + ph[1])
        height = height + a * 0.005 * p.height_m * np.sin(2 * np.pi * f[0] * t + ph[2])
    return pitch, roll, height


def _height(t, p, rng, a):
    pitch, roll, height = _static(t, p, rng, a)
    ph = rng.uniform(0, 2 * np.pi)
    return pitch, roll, height * (1.0 + a * 0.1 * np.sin(2 * np.pi * t / 6.0 + ph))


def _turn(t, p, rng, a):
    return _static(t, p, rng, a)


def _drift_mount(t, p, a):
    """Mount of ``drift``: the nominal pose plus a linear pitch/roll drift."""
    pitch, roll, height = _static(t, p, None, a)
    return (pitch + a * np.radians(DRIFT_RATE_DPS[0]) * t,
            roll + a * np.radians(DRIFT_RATE_DPS[1]) * t, height)


def _drift(t, p, rng, a):
    return _shaken(_drift_mount(t, p, a), t, rng, a)


def _shaken(mount, t, rng, a):
    """The ``drift`` body shaking (three 1–3 Hz sinusoids, ``DRIFT_SHAKE_DEG``) on ``mount``."""
    pitch, roll, height = mount
    for _ in range(3):
        f, ph = rng.uniform(1.0, 3.0, 2), rng.uniform(0, 2 * np.pi, 2)
        pitch = pitch + a * np.radians(DRIFT_SHAKE_DEG[0]) * np.sin(2 * np.pi * f[0] * t + ph[0])
        roll = roll + a * np.radians(DRIFT_SHAKE_DEG[1]) * np.sin(2 * np.pi * f[1] * t + ph[1])
    return pitch, roll, height


def knock_time(t: NDArray[np.float64]) -> float:
    """Time (s) of the ``knock`` profile's mount step in a drive of frame times ``t``."""
    return float(t[0] + KNOCK_AT * (t[-1] - t[0]))


def _knock_mount(t, p, a):
    """Mount of ``knock``: the nominal pose, its pitch stepping by ``KNOCK_PITCH_DEG`` ×
    ``a`` at ``knock_time``."""
    pitch, roll, height = _static(t, p, None, a)
    return pitch + a * np.radians(KNOCK_PITCH_DEG) * (t >= knock_time(t)), roll, height


def _knock(t, p, rng, a):
    return _shaken(_knock_mount(t, p, a), t, rng, 1.0)


_PROFILE_FUNCS: dict[str, Callable] = {
    "static": _static, "gradual": _gradual, "shaking": _shaking, "height": _height, "turn": _turn,
    "drift": _drift, "knock": _knock,
}
#: mount part (slow calibration) of the profiles that separate it from the body motion
_MOUNT_FUNCS: dict[str, Callable] = {
    "static": lambda t, p, a: _static(t, p, None, a),
    "turn": lambda t, p, a: _static(t, p, None, a),
    "shaking": lambda t, p, a: _static(t, p, None, a),
    "drift": _drift_mount,
    "knock": _knock_mount,
}


def preset_texture(
    preset: Preset | str, texture: str | None = None, seed: int = 0
) -> GroundTexture:
    """The ground texture of a preset (``texture`` overrides its name), cached."""
    p = PRESETS[preset] if isinstance(preset, str) else preset
    name = texture or p.texture
    if name not in TEXTURES:
        raise ValueError(f"unknown texture '{name}'; choose one of {sorted(TEXTURES)}")
    return load_texture(name, p.metres_per_texel, seed, p.texture_tiles)


def render_trajectory_frame(
    texture: GroundTexture, camera: CameraModel, traj: Trajectory, k: int,
    effects: Effects | None = None,
    traffic: Sequence[Vehicle] | None = None,
) -> NDArray[np.uint8]:
    """Image of frame k of a trajectory (motion blur over the exposure centred on its time;
    with a rolling shutter, each band of rows at its own time), with the ``traffic``
    vehicles (``traffic.make_traffic``) drawn at frame k's time and pose."""
    exposure = None
    if effects is not None and (effects.motion_blur > 0 or effects.rolling_shutter > 0):
        exposure = exposure_bands(traj, k, effects, camera)
    pose, xz, heading, t = traj.pose(k), traj.world_xz[k], float(traj.world_heading[k]), \
        float(traj.t[k])
    overlay = None
    if traffic:
        overlay = functools.partial(draw_traffic, vehicles=traffic, camera=camera, pose=pose,
                                    world_xz=xz, world_heading=heading, t=t)
    return render_frame(texture, camera, pose, xz, heading, effects, t=t, frame_index=k,
                        exposure=exposure, overlay=overlay)


def exposure_bands(
    traj: Trajectory, k: int, effects: Effects, camera: CameraModel,
    max_step_px: float = 0.5, max_bands: int = 360,
) -> list[ExposureBand]:
    """Bands of rows of frame k and the sub-frame poses each is exposed over
    (:func:`exposure_poses`): one band for a global shutter; with a rolling shutter
    (``effects.rolling_shutter``, the readout as a fraction of the frame interval) row v is
    exposed ``v / rows · rolling_shutter`` intervals after frame k's time, in bands thin enough
    that the ground moves ≤ ``max_step_px`` pixels between neighbours (at most ``max_bands``)."""
    readout = effects.rolling_shutter
    if readout <= 0 or len(traj) < 2:
        return [(0, camera.height, exposure_poses(traj, k, effects.motion_blur, camera))]
    per_frame = _max_image_motion(camera, traj.pose_at(k - 0.5), traj.pose_at(k + 0.5))
    rows = max(int(max_step_px * camera.height / max(readout * per_frame, 1e-9)),
               -(-camera.height // max_bands), 1)
    bands = []
    for r0 in range(0, camera.height, rows):
        r1 = min(r0 + rows, camera.height)
        centre = k + readout * (0.5 * (r0 + r1 - 1)) / camera.height
        bands.append((r0, r1, exposure_poses(traj, centre, effects.motion_blur, camera)))
    return bands


def exposure_poses(
    traj: Trajectory, centre: float, exposure: float, camera: CameraModel,
    max_step_px: float = 1.0, max_poses: int = 48,
) -> list[ExposurePose]:
    """Sub-frame poses across an exposure of ``exposure`` frame intervals centred on the
    fractional frame index ``centre``: the pose and world pose interpolated linearly between
    frames (extrapolated from the nearest interval at the ends, so the first frame is blurred
    too), as many as keep the ground's image motion between neighbours ≤ ``max_step_px``
    pixels (at most ``max_poses``). One pose (no blur) for a one-frame trajectory or no
    exposure."""
    if len(traj) < 2 or exposure <= 0:
        return [traj.pose_at(float(centre))]
    ends = [traj.pose_at(centre - exposure / 2), traj.pose_at(centre + exposure / 2)]
    n = int(np.clip(np.ceil(_max_image_motion(camera, *ends) / max_step_px) + 1, 2, max_poses))
    return [traj.pose_at(u) for u in np.linspace(centre - exposure / 2, centre + exposure / 2, n)]


def _max_image_motion(camera: CameraModel, a: ExposurePose, b: ExposurePose) -> float:
    """Largest image motion [px] of ground seen between poses a and b, over a 16×16 grid of
    pixels that see the ground ≥ 1° below the horizon in a (and land in the image in b)."""
    u, v = np.meshgrid(np.linspace(0, camera.width - 1, 16), np.linspace(0, camera.height - 1, 16))
    pixels = np.stack([u.ravel(), v.ravel()], axis=1)
    pixels = pixels[below_horizon(camera.k, a[0], pixels, margin=np.radians(1.0))]
    if not len(pixels):
        return 0.0
    motion = compose_motion(invert_motion(world_pose_motion(a[1], a[2])),
                            world_pose_motion(b[1], b[2]))
    moved = predict_pixels(camera.k, a[0], b[0], motion, pixels)
    inside = np.all(np.isfinite(moved), axis=1) & (moved[:, 0] >= 0) & (moved[:, 1] >= 0) \
        & (moved[:, 0] < camera.width) & (moved[:, 1] < camera.height)
    return float(np.max(np.linalg.norm(moved - pixels, axis=1)[inside], initial=0.0))


def gt_rows(traj: Trajectory) -> list[dict]:
    """Rows of ``gt.csv``: conventions columns + :data:`GT_EXTRA_COLUMNS`; frame 0 has its
    pose, empty motion and status ``first``."""
    rows = []
    for k in range(len(traj)):
        pitch, roll, h = traj.pose(k).as_degrees()
        row = {"frame": k, "t": float(traj.t[k]), "pitch_deg": pitch, "roll_deg": roll,
               "height_m": h, "speed_mps": float(traj.speed[k]),
               "world_x_m": float(traj.world_xz[k, 0]), "world_z_m": float(traj.world_xz[k, 1]),
               "world_heading_deg": float(np.degrees(traj.world_heading[k]))}
        if traj.mount_pitch is not None:
            row.update(mount_pitch_deg=float(np.degrees(traj.mount_pitch[k])),
                       mount_roll_deg=float(np.degrees(traj.mount_roll[k])),
                       mount_height_m=float(traj.mount_height[k]))
        if k == 0:
            row["status"] = "first"
        else:
            m = traj.motion(k)
            pp, pr, ph = traj.pose(k - 1).as_degrees()
            row.update(tx_m=m.tx, tz_m=m.tz, yaw_deg=float(np.degrees(m.yaw)), status="ok",
                       prev_pitch_deg=pp, prev_roll_deg=pr, prev_height_m=ph)
        rows.append(row)
    return rows


def wheel_speed_samples(
    traj: Trajectory,
    rate_hz: float = 50.0,
    noise_rel: float = 0.005,
    quantum_kmh: float = 0.01,
    seed: int = 0,
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """A wheel-speed sensor on the trajectory: times [s, camera clock] at ``rate_hz`` over the
    drive and speeds [m/s] with relative Gaussian noise ``noise_rel`` and quantised to
    ``quantum_kmh`` km/h (a CAN speed signal's resolution). Deterministic from ``seed``."""
    if rate_hz <= 0 or noise_rel < 0 or quantum_kmh < 0:
        raise ValueError("rate_hz must be > 0, noise_rel and quantum_kmh >= 0")
    t = np.arange(0.0, float(traj.t[-1]) + 0.5 / rate_hz, 1.0 / rate_hz)
    v = np.interp(t, traj.t, traj.speed)
    v = v * (1.0 + noise_rel * np.random.default_rng([seed, 7]).standard_normal(len(t)))
    if quantum_kmh > 0:
        q = quantum_kmh / 3.6
        v = np.round(v / q) * q
    return t, np.abs(v)


def write_wheel_speed_csv(
    traj: Trajectory, path: str | Path, seed: int = 0, **sensor: float
) -> Path:
    """Write :func:`wheel_speed_samples` of ``traj`` as a ``t,speed_mps`` CSV (the format of
    ``--speed-csv``); ``sensor``: its rate/noise/quantum keywords. Returns the path."""
    t, v = wheel_speed_samples(traj, seed=seed, **sensor)
    return write_columns_csv(path, {"t": t, "speed_mps": v})


#: Names of the images :func:`simulate_sequence` writes into ``OUT/images``.
_OWN_IMAGE = re.compile(r"^\d{6}\.png$")


def clear_earlier_run(out_dir: str | Path) -> int:
    """Remove the images an earlier :func:`simulate_sequence` run left in ``out_dir/images``
    (so a shorter run does not leave frames its ``times.txt`` lacks); returns how many.
    Other files in that folder are not ours to delete: an :class:`InputError` names them."""
    folder = Path(out_dir) / "images"
    if not folder.is_dir():
        return 0
    entries = sorted(folder.iterdir())
    foreign = [e.name for e in entries if not (_OWN_IMAGE.match(e.name) and e.is_file())]
    if foreign:
        raise InputError(f"{folder}: holds files a simulation did not write "
                         f"({', '.join(foreign[:5])}{', ...' if len(foreign) > 5 else ''}); "
                         "give an empty or new --out folder")
    for e in entries:
        e.unlink()
    return len(entries)


def simulate_sequence(
    preset: Preset | str,
    frames: int,
    out_dir: str | Path,
    seed: int = 0,
    profile: str = "static",
    effects: Effects | None = None,
    texture: str | None = None,
    fps: float | None = None,
    speed: float | None = None,
    amplitude: float = 1.0,
    progress: bool = False,
    traffic: str | None = None,
) -> Trajectory:
    """Render a sequence and write it to ``out_dir`` (see module doc); returns its truth.

    ``effects`` are used as given (their own ``seed`` fixes noise and highlight layout).
    ``traffic``: a level of ``traffic.LEVELS`` to drive among vehicles (laid out from
    ``seed`` along the world z axis at the nominal speed); their world positions per frame
    go to ``traffic.csv``. The ground truth is unchanged.
    """
    p = PRESETS[preset] if isinstance(preset, str) else preset
    out = Path(out_dir)
    clear_earlier_run(out)
    (out / "images").mkdir(parents=True, exist_ok=True)
    traj = make_trajectory(profile, frames, fps, p, seed, speed, amplitude)
    tex = preset_texture(p, texture, seed)
    camera = p.camera()
    write_ros_yaml(camera, out / "camera.yaml", name=f"vipm_sim_{p.name}")
    (out / "times.txt").write_text("".join(f"{t:.6e}\n" for t in traj.t))
    write_wheel_speed_csv(traj, out / "speed.csv", seed=seed)
    vehicles = None
    (out / "traffic.csv").unlink(missing_ok=True)
    if traffic:
        vehicles = make_traffic(traffic, seed=seed, duration_s=float(traj.t[-1]),
                                speed_mps=p.speed_mps if speed is None else speed)
        _write_traffic_csv(out / "traffic.csv", vehicles, traj)
    iterator = range(frames)
    if progress:
        iterator = progress_bar(iterator, desc=f"simulate {p.name}", unit="frame")
    written = 0
    try:
        with TableWriter(out / "gt.csv", GT_EXTRA_COLUMNS) as writer:
            for k, row in zip(iterator, gt_rows(traj), strict=True):
                img = render_trajectory_frame(tex, camera, traj, k, effects, vehicles)
                image_path = out / "images" / f"{k:06d}.png"
                if not cv2.imwrite(str(image_path), img):
                    raise OSError(errno.EIO, "OpenCV could not write the image",
                                  str(image_path))
                writer.write(row)
                written = k + 1
    except BaseException:  # Ctrl-C, a full disk: what is kept must be a sequence of its own
        _cut_to_frames(out, written, traj)
        raise
    return traj


def _cut_to_frames(out: Path, frames: int, traj: Trajectory) -> None:
    """Cut an interrupted run's files to its first ``frames`` frames: images, ``times.txt``,
    the wheel speed and the traffic up to the last frame's time (they were written for all
    of them before rendering began)."""
    (out / "images" / f"{frames:06d}.png").unlink(missing_ok=True)  # its gt row is missing
    (out / "times.txt").write_text("".join(f"{t:.6e}\n" for t in traj.t[:frames]))
    end = float(traj.t[frames - 1]) if frames else -math.inf
    for name, column in (("speed.csv", "t"), ("traffic.csv", "t")):
        path = out / name
        if not path.is_file():
            continue
        with path.open(newline="") as fh:
            rows = list(csv.DictReader(fh))
            header = list(rows[0]) if rows else None
        if header is None:
            continue
        with path.open("w", newline="") as fh:
            writer = csv.DictWriter(fh, header, lineterminator="\n")
            writer.writeheader()
            writer.writerows(r for r in rows if float(r[column]) <= end)


def _write_traffic_csv(path: Path, vehicles: Sequence[Vehicle], traj: Trajectory) -> None:
    """Per frame, the vehicles near the camera (``traffic.traffic_rows``)."""
    with path.open("w", newline="") as fh:
        writer = csv.DictWriter(fh, TRAFFIC_COLUMNS, lineterminator="\n")
        writer.writeheader()
        for k in range(len(traj)):
            for row in traffic_rows(vehicles, k, float(traj.t[k]), traj.world_xz[k]):
                writer.writerow({c: f"{x:.6g}" if isinstance(x, float) else x
                                 for c, x in row.items()})
