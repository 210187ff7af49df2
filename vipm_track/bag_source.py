"""Recordings in ROS bags: ROS 1 ``.bag`` files, rosbag2 folders (sqlite3 or MCAP storage)
and bare ``.mcap`` / ``.db3`` files, all read with ``rosbags``' ``AnyReader``.

A bag holds a drive when it has an image topic (``sensor_msgs/Image`` or
``sensor_msgs/CompressedImage``); its intrinsics may come from a ``sensor_msgs/CameraInfo``
topic and a speed from a twist or odometry topic (``geometry_msgs/TwistStamped``,
``geometry_msgs/TwistWithCovarianceStamped``, ``nav_msgs/Odometry``: the forward
``linear.x``, m/s). Topics are found by message type unless named. Frame times are the
messages' ``header.stamp`` [s] (the bag's receive time where a stamp is zero), so images and
speed share the recording's clock.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray
from rosbags.highlevel import AnyReader, AnyReaderError
from rosbags.typesys import Stores, get_typestore

from .camera import CameraModel
from .mcap_recovery import repaired_copy
from .sources import Frame, FrameSource, SourceError, _say_once, _to_grey

IMAGE_TYPES: tuple[str, ...] = ("sensor_msgs/msg/Image", "sensor_msgs/msg/CompressedImage")
CAMERA_INFO_TYPES: tuple[str, ...] = ("sensor_msgs/msg/CameraInfo",)
#: speed messages → the attribute path of the forward speed [m/s]
SPEED_TYPES: dict[str, tuple[str, ...]] = {
    "geometry_msgs/msg/TwistStamped": ("twist", "linear", "x"),
    "geometry_msgs/msg/TwistWithCovarianceStamped": ("twist", "twist", "linear", "x"),
    "nav_msgs/msg/Odometry": ("twist", "twist", "linear", "x"),
}
#: file names and suffixes ``is_bag`` takes for a bag
BAG_SUFFIXES: tuple[str, ...] = (".bag", ".mcap", ".db3")

_ENCODINGS_8BIT = {"mono8": None, "8uc1": None, "bgr8": cv2.COLOR_BGR2GRAY,
                   "rgb8": cv2.COLOR_RGB2GRAY, "bgra8": cv2.COLOR_BGRA2GRAY,
                   "rgba8": cv2.COLOR_RGBA2GRAY, "8uc3": cv2.COLOR_BGR2GRAY}
_ENCODINGS_16BIT = ("mono16", "16uc1")


class BagError(SourceError):
    """A bag that cannot be read or lacks a topic; the message names the bag and topic."""


def is_bag(path: str | Path) -> bool:
    """Whether ``path`` is a bag: a file with a suffix of :data:`BAG_SUFFIXES` or a rosbag2
    folder (one holding ``metadata.yaml``)."""
    path = Path(path)
    if path.is_dir():
        return (path / "metadata.yaml").is_file()
    return path.is_file() and path.suffix.lower() in BAG_SUFFIXES


def _reader(path: Path) -> AnyReader:
    if not path.exists():
        raise BagError(f"{path}: bag not found")
    if not is_bag(path):
        raise BagError(f"{path}: not a bag (a .bag, .mcap or .db3 file, or a rosbag2 folder "
                       "with metadata.yaml)")
    try:
        return _any_reader(path)
    except (AnyReaderError, OSError, ValueError) as exc:
        raise BagError(f"{path}: cannot open the bag: {exc}") from None


def _any_reader(path: Path) -> AnyReader:
    return AnyReader([path], default_typestore=get_typestore(Stores.LATEST))


@contextmanager
def _opened(path: Path) -> Iterator[AnyReader]:
    """The bag at ``path`` open for reading (BagError naming it where it cannot be); a bare
    MCAP file cut short is read up to its last complete record (``mcap_recovery``), said
    once on stderr."""
    reader = _reader(path)
    try:
        reader.open()
    except Exception as exc:  # rosbags raises its own error types per storage
        reader = _cut_mcap_reader(path, exc)
        if reader is None:
            raise BagError(f"{path}: cannot read the bag: {type(exc).__name__}: {exc}") from None
    try:
        yield reader
    finally:
        reader.close()


def _cut_mcap_reader(path: Path, error: Exception) -> AnyReader | None:
    """A reader open on the complete records of ``path`` where it is an MCAP file whose end
    is missing (``error`` the reader's own), else None."""
    if path.is_dir() or path.suffix.lower() != ".mcap" or "magic" not in str(error).lower():
        return None
    try:
        repaired = repaired_copy(path)
    except OSError:
        return None
    if repaired is None:
        return None
    copy, kept, size = repaired
    _say_once(f"vipm-track: warning: {path}: cut short (no MCAP footer): reading its complete "
              f"records, the first {kept:,} of {size:,} bytes (a chunk cut part-way is left "
              "out)")
    reader = _any_reader(copy)
    try:
        reader.open()
    except Exception:
        return None
    return reader


def _topic(reader: AnyReader, path: Path, topic: str | None, types: tuple[str, ...],
           what: str, option: str, required: bool = True) -> str | None:
    """The topic named ``topic`` (checked to be of one of ``types``), else the first topic of
    those types by name; None (or BagError where ``required``) where there is none."""
    found = {c.topic: c.msgtype for c in reader.connections}
    if topic is not None:
        if topic not in found:
            raise BagError(f"{path}: no topic {topic!r} ({option}); topics: "
                           f"{', '.join(sorted(found)) or 'none'}")
        if found[topic] not in types:
            raise BagError(f"{path}: topic {topic!r} ({option}) is {found[topic]}, not "
                           f"{' or '.join(types)}")
        return topic
    candidates = sorted(t for t, msgtype in found.items() if msgtype in types)
    if not candidates and required:
        raise BagError(f"{path}: no {what} topic ({' or '.join(types)}); topics: "
                       + (", ".join(f"{t} [{m}]" for t, m in sorted(found.items())) or "none"))
    return candidates[0] if candidates else None


def _stamp(msg: Any, bag_ns: int) -> float:
    """``header.stamp`` of a message [s], or the bag's receive time where it is zero."""
    stamp = getattr(getattr(msg, "header", None), "stamp", None)
    if stamp is not None and (stamp.sec or stamp.nanosec):
        return stamp.sec + stamp.nanosec * 1e-9
    return bag_ns * 1e-9


def image_of(msg: Any, msgtype: str) -> NDArray[np.uint8]:
    """Grey ``uint8`` image of a ``sensor_msgs`` Image or CompressedImage message
    (ValueError saying why where it cannot be decoded)."""
    if msgtype.endswith("CompressedImage"):
        image = cv2.imdecode(np.frombuffer(bytes(msg.data), np.uint8), cv2.IMREAD_UNCHANGED)
        if image is None:
            raise ValueError(f"compressed image ({msg.format!r}) cannot be decoded")
        return _to_grey(image)
    encoding = str(msg.encoding).lower()
    h, w, step = int(msg.height), int(msg.width), int(msg.step)
    data = np.frombuffer(bytes(msg.data), np.uint8)
    if h <= 0 or w <= 0 or data.size < h * step:
        raise ValueError(f"image of {w}×{h} (step {step}) holds {data.size} bytes")
    rows = data[: h * step].reshape(h, step)
    if encoding in _ENCODINGS_8BIT:
        channels = 1 if _ENCODINGS_8BIT[encoding] is None else (4 if "a" in encoding[3:] else 3)
        image = np.ascontiguousarray(rows[:, : w * channels]).reshape(h, w, channels)
        code = _ENCODINGS_8BIT[encoding]
        return image[..., 0].copy() if code is None else cv2.cvtColor(image, code)
    if encoding in _ENCODINGS_16BIT:
        dtype = ">u2" if msg.is_bigendian else "<u2"
        image = np.ascontiguousarray(rows[:, : 2 * w]).view(dtype).reshape(h, w)
        return _to_grey(image.astype(np.uint16))
    raise ValueError(f"image encoding {msg.encoding!r} is not supported (mono8, mono16, "
                     "bgr8, rgb8, bgra8, rgba8)")


class BagSource(FrameSource):
    """The frames of a bag's image topic, timed by their header stamps [s].

    ``image_topic`` None: the bag's first Image / CompressedImage topic by name. A message
    that cannot be decoded, or whose time does not increase, is a frame without an image
    (its ``error`` says why) and the run goes on."""

    def __init__(self, path: str | Path, image_topic: str | None = None, start: int = 0,
                 max_frames: int | None = None) -> None:
        self.path = Path(path)
        if start < 0 or (max_frames is not None and max_frames < 1):
            raise BagError(f"--start must be >= 0 and --max-frames >= 1, got {start} and "
                           f"{max_frames}")
        with _opened(self.path) as reader:
            self.topic = _topic(reader, self.path, image_topic, IMAGE_TYPES, "image",
                                "--image-topic")
            total = sum(c.msgcount for c in reader.connections if c.topic == self.topic)
        if total == 0:
            raise BagError(f"{self.path}: topic {self.topic} has no messages")
        self.position = min(start, total)
        self.count = total - self.position if max_frames is None else min(
            max_frames, total - self.position)
        if self.count <= 0:
            raise BagError(f"{self.path}: --start {start} is past the {total} images of "
                           f"{self.topic}")
        self.description = f"{self.path}:{self.topic}"

    def __len__(self) -> int:
        return self.count

    def frames(self, position: int, count: int) -> BagSource:
        chunk = object.__new__(BagSource)
        chunk.path, chunk.topic, chunk.description = self.path, self.topic, self.description
        chunk.position = self.position + position
        chunk.count = max(0, min(count, self.count - position))
        return chunk

    def __iter__(self) -> Iterator[Frame]:
        stop = self.position + self.count
        last_t = -np.inf
        with _opened(self.path) as reader:
            connections = [c for c in reader.connections if c.topic == self.topic]
            for index, (conn, bag_ns, raw) in enumerate(reader.messages(connections)):
                if index >= stop:
                    return
                if index < self.position:
                    continue
                name = f"{self.description}#{index}"
                try:
                    msg = reader.deserialize(raw, conn.msgtype)
                    t = _stamp(msg, bag_ns)
                    if not t > last_t:
                        raise ValueError(f"time {t:.6f} s does not increase (previous "
                                         f"{last_t:.6f} s)")
                    image = image_of(msg, conn.msgtype)
                except Exception as exc:  # one bad message: reported in its row, run goes on
                    yield Frame(index, bag_ns * 1e-9, None, f"unreadable frame: {name}: {exc}",
                                name)
                    continue
                last_t = t
                yield Frame(index, t, image, None, name)


def read_bag_camera(path: str | Path, topic: str | None = None) -> CameraModel:
    """Intrinsics of the first message of a bag's CameraInfo topic (``topic`` None: the
    first by name). BagError naming the bag and topic where there is none or it is bad."""
    path = Path(path)
    with _opened(path) as reader:
        topic = _topic(reader, path, topic, CAMERA_INFO_TYPES, "camera_info",
                       "--camera-info-topic")
        connections = [c for c in reader.connections if c.topic == topic]
        for conn, _, raw in reader.messages(connections):
            msg = reader.deserialize(raw, conn.msgtype)
            k = np.asarray(_field(msg, "k"), dtype=float).reshape(3, 3)
            dist = np.asarray(_field(msg, "d"), dtype=float)
            model = str(msg.distortion_model) or ("plumb_bob" if dist.size else "none")
            model = {"equidistant": "equidistant", "fisheye": "equidistant"}.get(model, model)
            try:
                return CameraModel(k=k, width=int(msg.width), height=int(msg.height),
                                   distortion_model=model, distortion=dist)
            except ValueError as exc:
                raise BagError(f"{path}: {topic}: {exc}") from None
    raise BagError(f"{path}: topic {topic} has no messages")


def _field(msg: Any, name: str) -> Any:
    # ROS 2 spells the CameraInfo arrays k, d; ROS 1 spells them K, D
    return getattr(msg, name, None) if hasattr(msg, name) else getattr(msg, name.upper())


@dataclass(frozen=True)
class BagSpeed:
    """Forward speed of a bag's twist / odometry topic: times [s] and speeds [m/s]."""

    t: NDArray[np.float64]
    speed_mps: NDArray[np.float64]
    source: str


def read_bag_speed(path: str | Path, topic: str | None = None) -> BagSpeed | None:
    """The forward speed (``linear.x``) of a bag's twist or odometry topic (``topic`` None:
    the first by name; None where the bag has none). Samples whose time does not increase
    are left out."""
    path = Path(path)
    with _opened(path) as reader:
        topic = _topic(reader, path, topic, tuple(SPEED_TYPES), "speed", "--speed-topic",
                       required=False)
        if topic is None:
            return None
        connections = [c for c in reader.connections if c.topic == topic]
        t: list[float] = []
        v: list[float] = []
        for conn, bag_ns, raw in reader.messages(connections):
            msg = reader.deserialize(raw, conn.msgtype)
            value: Any = msg
            for attr in SPEED_TYPES[conn.msgtype]:
                value = getattr(value, attr)
            stamp = _stamp(msg, bag_ns)
            if np.isfinite(value) and (not t or stamp > t[-1]):
                t.append(stamp)
                v.append(float(value))
    if not t:
        raise BagError(f"{path}: speed topic {topic} has no usable messages")
    return BagSpeed(np.asarray(t), np.asarray(v), f"{path}:{topic}")
