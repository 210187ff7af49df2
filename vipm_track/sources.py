"""Frame sources: image folders and videos, with their timestamps.

A source yields :class:`Frame` objects in order: the frame's index in the recording (kept
when ``start`` skips frames, so rows line up with ground truth), its timestamp in seconds,
and the grey ``uint8`` image, or ``None`` and an ``error`` when that one frame cannot be
read (the run goes on). Problems with the input as a whole (missing folder, no images, a
``times.txt`` that disagrees with the images, a video OpenCV cannot open, no way to time the
frames) raise :class:`~vipm_track.errors.InputError` when the source is opened.

Timestamps, first that applies:

- image folder: ``times.txt`` in the folder or its parent (KITTI style, one time in seconds
  per line), else ``index / fps``;
- video: ``index / fps`` when ``fps`` is given, else the container's time stamps
  (``CAP_PROP_POS_MSEC``), else its frame rate.
"""

from __future__ import annotations

import copy
import math
import re
import sys
from collections import Counter
from collections.abc import Iterator
from dataclasses import dataclass
from decimal import Decimal
from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray

from .errors import InputError, printable
from .frame_rates import fps_problem, interval_problem
from .text_files import read_text

IMAGE_SUFFIXES: frozenset[str] = frozenset(
    {".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".pgm", ".ppm", ".pnm", ".webp"}
)

#: Consecutive failed reads after which a video is taken to have ended.
_MAX_VIDEO_READ_FAILURES = 5


class SourceError(InputError):
    """An input folder, video or timestamp file that cannot be used; the message names it."""


@dataclass(frozen=True)
class Frame:
    """One frame: index in the recording, time [s], grey image (H, W) ``uint8`` or ``None``.

    ``error`` says why ``image`` is ``None`` (e.g. ``"unreadable frame: img/000012.png"``).
    ``name`` is the file name or ``video#index`` for messages."""

    index: int
    t: float
    image: NDArray[np.uint8] | None
    error: str | None = None
    name: str = ""

    @property
    def ok(self) -> bool:
        return self.image is not None


class FrameSource:
    """Iterable of :class:`Frame`; ``len()`` is the number of frames it will yield (for a
    video, as the container reports it). ``description`` names the input for messages."""

    description: str = ""

    def __iter__(self) -> Iterator[Frame]:  # pragma: no cover - interface
        raise NotImplementedError

    def __len__(self) -> int:  # pragma: no cover - interface
        raise NotImplementedError

    def frames(self, position: int, count: int) -> FrameSource:
        """The source of this one's frames at positions ``position … position + count − 1``
        (0: its first frame), with their own indices and times: a chunk of a long run."""
        raise NotImplementedError(f"{type(self).__name__} cannot be split into chunks")


def open_source(
    images: str | Path | None = None,
    video: str | Path | None = None,
    fps: float | None = None,
    start: int = 0,
    max_frames: int | None = None,
) -> FrameSource:
    """Open an image folder or a video (exactly one) as a :class:`FrameSource`.

    Parameters
    ----------
    images, video : folder of images sorted by name, or a video file OpenCV reads.
    fps : frame rate [Hz] for timestamps when the input has none (see module doc).
    start : index of the first frame to yield (earlier frames are skipped).
    max_frames : yield at most this many frames (``None``: all).

    Raises :class:`SourceError` (an ``InputError``) naming the file for unusable input.
    """
    if (images is None) == (video is None):
        raise SourceError("give exactly one input: an image folder (--images) or a video (--video)")
    if fps is not None and (problem := fps_problem(fps)):
        raise SourceError(f"--fps must be {problem}")
    if start < 0:
        raise SourceError(f"--start must be >= 0, got {start}")
    if max_frames is not None and max_frames < 1:
        raise SourceError(f"--max-frames must be >= 1, got {max_frames}")
    if images is not None:
        return ImageFolderSource(images, fps=fps, start=start, max_frames=max_frames)
    assert video is not None
    return VideoSource(video, fps=fps, start=start, max_frames=max_frames)


class ArraySource(FrameSource):
    """Frames from images already in memory (grey or BGR arrays) at times ``t`` [s]; a
    ``None`` image stands for an unreadable frame."""

    def __init__(self, images: list[NDArray | None], t: NDArray | list[float],
                 description: str = "arrays") -> None:
        t = np.asarray(t, dtype=float)
        if t.shape != (len(images),):
            raise SourceError(f"{description}: {len(images)} images but {t.size} timestamps")
        self.images, self.t, self.description = images, t, description
        self.first_index = 0

    def __len__(self) -> int:
        return len(self.images)

    def frames(self, position: int, count: int) -> ArraySource:
        stop = position + count
        chunk = ArraySource(self.images[position:stop], self.t[position:stop], self.description)
        chunk.first_index = self.first_index + position
        return chunk

    def __iter__(self) -> Iterator[Frame]:
        for i, (image, t) in enumerate(zip(self.images, self.t, strict=True),
                                       start=self.first_index):
            name = f"{self.description}#{i}"
            if image is None:
                yield Frame(i, float(t), None, f"unreadable frame: {name}", name)
            else:
                yield Frame(i, float(t), _to_grey(image), None, name)


# --- image folders ---------------------------------------------------------------------------


def natural_key(name: str) -> tuple[tuple[int, Decimal | str], ...]:
    """Sort key of a file name with its numbers as numbers: ``frame_2`` before ``frame_10``
    (ffmpeg's ``%d`` names, which sorted as text were read 0, 1, 10, 11, …, 2), a decimal
    ``1403636579.25`` before ``1403636579.5`` (a time written by ``str(float)``);
    zero-padded names keep their order."""
    return tuple((0, Decimal(part)) if part[0].isdecimal() else (1, part)
                 for part in re.split(r"(\d+(?:\.\d+)?)", name, flags=re.ASCII) if part)


def list_images(folder: str | Path) -> list[Path]:
    """Image files (by suffix) directly in ``folder``, in natural order of their names
    (:func:`natural_key`); hidden files (``.name``: macOS's ``._000010.png`` beside each
    frame copied from its disks) are not frames."""
    folder = Path(folder)
    if not folder.is_dir():
        raise SourceError(f"{folder}: image folder not found")
    files = sorted(
        (p for p in folder.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES
         and not p.name.startswith(".") and p.is_file()),
        key=lambda p: (natural_key(p.name), p.name))
    if not files:
        suffixes = ", ".join(sorted(IMAGE_SUFFIXES))
        raise SourceError(f"{folder}: no images in the folder (looked for {suffixes})")
    return files


#: images read for a folder's frame size (:func:`first_frame_size`)
FIRST_SIZE_FRAMES = 5


def first_frame_size(images: str | Path | None = None, video: str | Path | None = None,
                     ) -> tuple[int, int] | None:
    """(width, height) of a folder's images, the size most of its first five image files
    that can be read have (one odd first frame must not make every other frame the wrong
    size), or of a
    video's frames; None where there is none (the source then says why)."""
    try:
        files = list_images(images) if images else []
    except SourceError:
        return None
    sizes = [(image.shape[1], image.shape[0]) for path in files[:FIRST_SIZE_FRAMES]
             if (image := read_grey(path)) is not None]
    if sizes:
        return Counter(sizes).most_common(1)[0][0]  # a tie: the first frame's
    if video and Path(video).is_file():
        capture = cv2.VideoCapture(str(video))
        try:
            size = (int(capture.get(cv2.CAP_PROP_FRAME_WIDTH)),
                    int(capture.get(cv2.CAP_PROP_FRAME_HEIGHT)))
        finally:
            capture.release()
        return size if min(size) > 0 else None
    return None


def find_times_file(folder: str | Path) -> Path | None:
    """``times.txt`` in ``folder`` or its parent (KITTI keeps it beside ``image_0/``)."""
    folder = Path(folder)
    for candidate in (folder / "times.txt", folder.parent / "times.txt"):
        if candidate.is_file():
            return candidate
    return None


def read_times(path: str | Path, expected: int | None = None) -> NDArray[np.float64]:
    """Timestamps [s] from a one-number-per-line file (blank lines and ``#`` comments skipped).

    Raises :class:`SourceError` naming the file and line for a non-number, a time that does
    not increase, or (with ``expected``) a count different from the number of images."""
    path = Path(path)
    values: list[float] = []
    for lineno, line in enumerate(read_text(path).splitlines(), start=1):
        text = line.split("#", 1)[0].strip()
        if not text:
            continue
        fields = text.split()
        if any(_is_number(f) for f in fields[1:]):
            # "index time" lines read by their first field timed every frame 1 s apart; a
            # note after the time (a file name) is no second candidate
            raise SourceError(f"{path}: line {lineno}: {len(fields)} numbers on the line, "
                              f"which is the time? One timestamp in seconds per line: "
                              f"'{printable(text, 60)}'")
        try:
            value = float(fields[0])
        except ValueError as exc:
            raise SourceError(
                f"{path}: line {lineno}: not a timestamp in seconds: '{printable(text, 60)}'"
            ) from exc
        if not math.isfinite(value):
            raise SourceError(f"{path}: line {lineno}: timestamp is not finite: "
                              f"'{printable(text, 60)}'")
        if values and value <= values[-1]:
            raise SourceError(
                f"{path}: line {lineno}: timestamp {value} does not increase "
                f"(previous {values[-1]})"
            )
        values.append(value)
    if expected is not None and len(values) != expected:
        raise SourceError(
            f"{path}: {len(values)} timestamps but {expected} images in the folder; "
            "times.txt needs one line per image"
        )
    if (problem := interval_problem(np.diff(values))) is not None:
        raise SourceError(f"{path}: {problem}")
    return np.asarray(values, dtype=np.float64)


def _is_number(text: str) -> bool:
    """Whether ``text`` reads as a float."""
    try:
        float(text)
    except ValueError:
        return False
    return True


_SAID: set[str] = set()


def _say_once(line: str) -> None:
    """Print ``line`` on stderr the first time it comes (a run opens its source several
    times: set-up searches, then the run)."""
    if line not in _SAID:
        _SAID.add(line)
        print(line, file=sys.stderr)


def read_grey(path: str | Path) -> NDArray[np.uint8] | None:
    """Grey ``uint8`` image of a file (colour averaged by OpenCV), or ``None`` if unreadable."""
    try:
        image = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    except cv2.error:
        return None
    if image is None or image.size == 0:
        return None
    return image


class ImageFolderSource(FrameSource):
    """Images of a folder sorted by name, timed by ``times.txt`` or ``fps``."""

    def __init__(
        self,
        folder: str | Path,
        fps: float | None = None,
        start: int = 0,
        max_frames: int | None = None,
    ) -> None:
        self.folder = Path(folder)
        files = list_images(self.folder)
        self.times_file = find_times_file(self.folder)
        if self.times_file is not None:
            times = read_times(self.times_file, expected=len(files))
            if fps is not None:
                _say_once(f"vipm-track: --fps {fps:g} not used: the frames of {self.folder} "
                          f"are timed by {self.times_file} (remove it to time them by --fps)")
        elif fps is not None:
            times = np.arange(len(files)) / fps
        else:
            raise SourceError(
                f"{self.folder}: no times.txt in the folder or its parent; "
                "pass --fps to time the frames (a fleet manifest: its fps column)"
            )
        if start >= len(files):
            raise SourceError(
                f"{self.folder}: --start {start} but the folder has {len(files)} images"
            )
        stop = len(files) if max_frames is None else min(len(files), start + max_frames)
        self.indices = range(start, stop)
        self.files = files
        self.times = times
        self.description = str(self.folder)

    def __len__(self) -> int:
        return len(self.indices)

    def frames(self, position: int, count: int) -> ImageFolderSource:
        chunk = copy.copy(self)
        chunk.indices = self.indices[position:position + count]
        return chunk

    def __iter__(self) -> Iterator[Frame]:
        for i in self.indices:
            path = self.files[i]
            image = read_grey(path)
            error = None if image is not None else f"unreadable frame: {path}"
            yield Frame(i, float(self.times[i]), image, error, path.name)


# --- videos ----------------------------------------------------------------------------------


class VideoSource(FrameSource):
    """Frames of a video read with ``cv2.VideoCapture``, converted to grey."""

    def __init__(
        self,
        path: str | Path,
        fps: float | None = None,
        start: int = 0,
        max_frames: int | None = None,
    ) -> None:
        self.path = Path(path)
        if self.path.is_dir():
            raise SourceError(f"{self.path}: a folder, not a video; for a folder of images "
                              "give --images")
        if not self.path.is_file():
            raise SourceError(f"{self.path}: video file not found")
        if self.path.suffix.lower() in IMAGE_SUFFIXES:
            # (OpenCV opens a PNG as a one-image "video": 0 of 5 frames ok, exit 1)
            raise SourceError(f"{self.path}: an image, not a video; give the folder of the "
                              "images with --images")
        capture = self._open()
        try:
            self.container_fps = float(capture.get(cv2.CAP_PROP_FPS) or 0.0)
            count = int(capture.get(cv2.CAP_PROP_FRAME_COUNT) or 0)
            # a container without frames read as rows of unreadable frames
            if not capture.grab():
                raise SourceError(f"{self.path}: the video has no frame OpenCV can read")
        finally:
            capture.release()
        self.fps = fps
        if fps is None and not (math.isfinite(self.container_fps) and self.container_fps > 0):
            raise SourceError(f"{self.path}: the video has no frame rate; pass --fps")
        if fps is not None:
            _say_once(f"vipm-track: frames of {self.path} timed by --fps {fps:g} (index / fps), "
                      "not by the video's own time stamps")
        self.frame_count = max(count, 0)
        if self.frame_count and start >= self.frame_count:
            raise SourceError(
                f"{self.path}: --start {start} but the video has {self.frame_count} frames"
            )
        self.start = start
        self.max_frames = max_frames
        self.description = str(self.path)

    def _open(self) -> cv2.VideoCapture:
        capture = cv2.VideoCapture(str(self.path))
        if not capture.isOpened():
            raise SourceError(
                f"{self.path}: OpenCV cannot open this video (unknown format or corrupt)"
            )
        return capture

    def __len__(self) -> int:
        n = max(self.frame_count - self.start, 0)
        return n if self.max_frames is None else min(n, self.max_frames)

    def frames(self, position: int, count: int) -> VideoSource:
        chunk = copy.copy(self)
        chunk.start = self.start + position
        chunk.max_frames = max(min(count, len(self) - position), 0)
        return chunk

    def __iter__(self) -> Iterator[Frame]:
        capture = self._open()
        try:
            if self.start and not self._seek(capture, self.start):
                capture.release()
                capture = self._open()
                for _ in range(self.start):  # decode up to the first frame instead
                    if not capture.grab():
                        return
            yield from self._frames(capture)
        finally:
            capture.release()

    @staticmethod
    def _seek(capture: cv2.VideoCapture, index: int) -> bool:
        """Whether the container moved ``capture`` to frame ``index`` (and says so)."""
        moved = bool(capture.set(cv2.CAP_PROP_POS_FRAMES, index))
        return moved and round(capture.get(cv2.CAP_PROP_POS_FRAMES)) == index

    def _frames(self, capture: cv2.VideoCapture) -> Iterator[Frame]:
        rate = self.fps or self.container_fps
        index, yielded, failures, last_t = self.start, 0, 0, -math.inf
        while self.max_frames is None or yielded < self.max_frames:
            ok, image = capture.read()
            name = f"{self.path.name}#{index}"
            if not ok or image is None:
                failures += 1
                # Past the reported end, or several failures in a row: the video is over.
                past_end = bool(self.frame_count) and index >= self.frame_count
                if past_end or failures >= _MAX_VIDEO_READ_FAILURES:
                    if not past_end and self.frame_count:
                        first = index - failures + 1
                        _say_once(f"vipm-track: warning: {self.path}: no frame reads from frame "
                                  f"{first} on, though its header says {self.frame_count} "
                                  "frames: the file ends early (cut short?)")
                    return
                yield Frame(index, index / rate, None, f"unreadable frame: {name}", name)
            else:
                failures = 0
                t = index / rate
                if self.fps is None:
                    msec = capture.get(cv2.CAP_PROP_POS_MSEC)
                    # Container time when it is sane (some backends report 0 throughout).
                    if math.isfinite(msec) and msec / 1000.0 > last_t and (index == 0 or msec > 0):
                        t = msec / 1000.0
                last_t = t
                yield Frame(index, t, _to_grey(image), None, name)
            index += 1
            yielded += 1


def _to_grey(image: NDArray) -> NDArray[np.uint8]:
    """Grey ``uint8`` of a BGR/BGRA/grey frame (16-bit scaled down)."""
    if np.issubdtype(image.dtype, np.floating):
        image = cv2.convertScaleAbs(image, alpha=255.0)  # float frames are in [0, 1]
    elif image.dtype != np.uint8:
        image = cv2.convertScaleAbs(image, alpha=255.0 / float(np.iinfo(image.dtype).max))
    if image.ndim == 3 and image.shape[2] == 4:
        return cv2.cvtColor(image, cv2.COLOR_BGRA2GRAY)
    if image.ndim == 3 and image.shape[2] == 3:
        return cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
    if image.ndim == 3:
        return np.ascontiguousarray(image[..., 0])
    return image
