"""Shared fixtures: paths to the real data beside the checkout (skipped where absent)."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path
from types import ModuleType

import pytest

ROOT = Path(__file__).resolve().parents[1]
SHARED_DATA = ROOT.parent / "shared" / "data"


def shared_data(*parts: str) -> Path:
    """Path under ../shared/data, or skip the test with a clear message if it is absent."""
    path = SHARED_DATA.joinpath(*parts)
    if not path.exists():
        pytest.skip(f"shared data not found at {path} (the real-data tests need ../shared/data)")
    return path


def load_script(name: str) -> ModuleType:
    """The module of ``scripts/NAME.py`` (registered under ``NAME``: its dataclasses look
    their module up)."""
    spec = importlib.util.spec_from_file_location(name, ROOT / "scripts" / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    spec.loader.exec_module(module)
    return module


#: A 1280×720 pinhole camera (fx = fy = 900 px, no distortion) as a ROS camera_info YAML.
CAR_CAMERA_YAML = (
    "image_width: 1280\nimage_height: 720\ncamera_matrix: {rows: 3, cols: 3, data: "
    "[900, 0, 640, 0, 900, 360, 0, 0, 1]}\ndistortion_model: plumb_bob\n"
    "distortion_coefficients: {rows: 1, cols: 5, data: [0, 0, 0, 0, 0]}\n"
)


def write_drive_inputs(run, folder: Path) -> tuple[Path, Path, Path]:
    """Write a drive_sim run as the files a user gives the CLI: ``est.csv`` (estimates table),
    ``speed.csv`` (t,speed_mps) and ``cam.yaml`` (:data:`CAR_CAMERA_YAML`) in ``folder``."""
    from vipm_track.filters.wheel_speed import SpeedSeries, write_speed_csv
    from vipm_track.measurement import measurement_row
    from vipm_track.table import ESTIMATE_COLUMNS, write_table

    write_table(folder / "est.csv", [measurement_row(m) for m in run.measurements],
                ESTIMATE_COLUMNS)
    write_speed_csv(SpeedSeries(run.speed.t, run.speed.speed_mps), folder / "speed.csv")
    (folder / "cam.yaml").write_text(CAR_CAMERA_YAML)
    return folder / "est.csv", folder / "speed.csv", folder / "cam.yaml"


def stop_in_a_turn(seed: int = 0):
    """A ``drive_sim`` cart run turning at 14°/s (curvature 0.25/m at 1 m/s), braking to a 10 s
    stop (8–18 s) in the turn, then driving off straight (the last pairs before the stop
    still see ~1.4°/s); returns (run, first and last index of the stop)."""
    import numpy as np

    from vipm_track.filters.drive_sim import DriveConfig, DriveProfile, simulate_drive

    profile = DriveProfile(
        (0.0, 6.0, 8.0, 18.0, 20.0), (1.0, 1.0, 0.0, 0.0, 1.0), (0.25, 0.25, 0.25, 0.0, 0.0)
    )
    cfg = DriveConfig.preset("cart", duration_s=30.0, height_m=0.7, failure_fraction=0.0)
    run = simulate_drive(cfg, seed, profile)
    still = np.flatnonzero(run.truth.speed == 0.0)
    assert run.truth.t[still[-1]] - run.truth.t[still[0]] >= 9.9
    return run, still[0], still[-1]


def render_small_drive(folder: Path, frames: int = 12, seed: int = 1, pitch_deg: float = 45.0,
                       nominal_pitch_deg: float = 45.0) -> Path:
    """A rendered 400×300 cart drive in ``folder`` as ``vipm-track fleet`` reads it:
    ``images/``, ``times.txt``, ``camera.yaml``, ``speed.csv``, ``gt.csv`` and a
    ``nominal.yaml`` at ``nominal_pitch_deg`` (the camera itself looks ``pitch_deg`` down)."""
    from dataclasses import replace

    from vipm_track.filters.nominal import NominalCalibration, write_nominal
    from vipm_track.sim import PRESETS, simulate_sequence

    preset = replace(PRESETS["cart"], width=400, height=300, fx=364.5, pitch_deg=pitch_deg)
    simulate_sequence(preset, frames, folder, seed=seed)
    write_nominal(NominalCalibration(nominal_pitch_deg, 0.0, 0.7, 0.2, 0.2),
                  folder / "nominal.yaml")
    return folder


def write_bag(drive: Path, path: Path, kind: str, t0: float = 100.0) -> Path:
    """The rendered drive in ``drive`` (:func:`render_small_drive`) written as a bag with
    rosbags' own writers: ``kind`` ``ros1`` (a ``.bag``: raw rgb8 ``/camera/image_raw``,
    ``/camera/camera_info``, TwistStamped ``/vehicle/twist``) or ``mcap`` (a rosbag2 folder
    with MCAP storage: PNG ``/camera/image/compressed``, ``/camera/camera_info``, Odometry
    ``/odom``). Header stamps are the drive's times plus ``t0`` seconds."""
    import cv2
    import numpy as np
    from rosbags.rosbag1 import Writer as Writer1
    from rosbags.rosbag2 import StoragePlugin
    from rosbags.rosbag2 import Writer as Writer2
    from rosbags.typesys import Stores, get_typestore

    from vipm_track.camera import load_camera
    from vipm_track.filters.wheel_speed import read_speed_csv
    from vipm_track.sources import read_times

    ros1 = kind == "ros1"
    store = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
    T = store.types
    camera = load_camera(drive / "camera.yaml")
    times = read_times(drive / "times.txt") + t0
    speed = read_speed_csv(drive / "speed.csv")
    images = sorted((drive / "images").glob("*.png"))

    def header(t: float):
        sec = int(t)
        stamp = T["builtin_interfaces/msg/Time"](sec=sec, nanosec=round((t - sec) * 1e9))
        extra = {"seq": 0} if ros1 else {}
        return T["std_msgs/msg/Header"](stamp=stamp, frame_id="camera", **extra)

    def info(t: float):
        k = camera.k.ravel().astype(float)
        arrays = ({"D": np.zeros(5), "K": k, "R": np.eye(3).ravel(),
                   "P": np.hstack([camera.k, np.zeros((3, 1))]).ravel()} if ros1 else
                  {"d": np.zeros(5), "k": k, "r": np.eye(3).ravel(),
                   "p": np.hstack([camera.k, np.zeros((3, 1))]).ravel()})
        roi = T["sensor_msgs/msg/RegionOfInterest"](x_offset=0, y_offset=0, height=0, width=0,
                                                    do_rectify=False)
        return T["sensor_msgs/msg/CameraInfo"](
            header=header(t), height=camera.height, width=camera.width,
            distortion_model="plumb_bob", binning_x=0, binning_y=0, roi=roi, **arrays)

    def image(t: float, png: Path):
        bgr = cv2.imread(str(png), cv2.IMREAD_COLOR)
        if ros1:
            rgb = cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)
            return T["sensor_msgs/msg/Image"](
                header=header(t), height=rgb.shape[0], width=rgb.shape[1], encoding="rgb8",
                is_bigendian=0, step=rgb.shape[1] * 3, data=rgb.ravel())
        ok, data = cv2.imencode(".png", bgr)
        assert ok
        return T["sensor_msgs/msg/CompressedImage"](header=header(t), format="png",
                                                    data=data.ravel())

    def twist(t: float, v: float):
        vec = T["geometry_msgs/msg/Vector3"]
        tw = T["geometry_msgs/msg/Twist"](linear=vec(x=v, y=0.0, z=0.0),
                                          angular=vec(x=0.0, y=0.0, z=0.0))
        if ros1:
            return T["geometry_msgs/msg/TwistStamped"](header=header(t), twist=tw)
        pose = T["geometry_msgs/msg/Pose"](
            position=T["geometry_msgs/msg/Point"](x=0.0, y=0.0, z=0.0),
            orientation=T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0))
        return T["nav_msgs/msg/Odometry"](
            header=header(t), child_frame_id="base_link",
            pose=T["geometry_msgs/msg/PoseWithCovariance"](pose=pose, covariance=np.zeros(36)),
            twist=T["geometry_msgs/msg/TwistWithCovariance"](twist=tw, covariance=np.zeros(36)))

    image_type = "sensor_msgs/msg/Image" if ros1 else "sensor_msgs/msg/CompressedImage"
    speed_type = "geometry_msgs/msg/TwistStamped" if ros1 else "nav_msgs/msg/Odometry"
    serialize = store.serialize_ros1 if ros1 else store.serialize_cdr
    writer = Writer1(path) if ros1 else Writer2(path, version=9,
                                                   storage_plugin=StoragePlugin.MCAP)
    with writer:
        topics = {"image": ("/camera/image_raw" if ros1 else "/camera/image/compressed",
                            image_type),
                  "info": ("/camera/camera_info", "sensor_msgs/msg/CameraInfo"),
                  "speed": ("/vehicle/twist" if ros1 else "/odom", speed_type)}
        conns = {k: writer.add_connection(topic, msgtype, typestore=store)
                 for k, (topic, msgtype) in topics.items()}
        messages = [(t, "image", image(t, png)) for t, png in zip(times, images, strict=True)]
        messages += [(times[0], "info", info(times[0]))]
        messages += [(t + t0, "speed", twist(t + t0, v))
                     for t, v in zip(speed.t, speed.speed_mps, strict=True)]
        for t, key, msg in sorted(messages, key=lambda m: m[0]):
            writer.write(conns[key], round(t * 1e9), serialize(msg, topics[key][1]))
    return path
