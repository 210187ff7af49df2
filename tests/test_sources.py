"""Frame sources: image folders, times.txt, videos, and their error messages."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from tests.conftest import shared_data
from vipm_track.errors import InputError
from vipm_track.sources import ArraySource, SourceError, open_source, read_times


def _write_images(
    folder: Path, n: int, size: tuple[int, int] = (40, 30), colour: bool = False
) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    for i in range(n):
        value = 10 * i + 5
        image = np.full((size[1], size[0], 3) if colour else (size[1], size[0]), value, np.uint8)
        cv2.imwrite(str(folder / f"{i:06d}.png"), image)


def test_folder_with_times_in_parent_kitti_style(tmp_path: Path) -> None:
    _write_images(tmp_path / "image_0", 4, colour=True)
    (tmp_path / "times.txt").write_text("0.0\n0.1\n0.25\n0.3\n")
    frames = list(open_source(images=tmp_path / "image_0"))
    assert [f.index for f in frames] == [0, 1, 2, 3]
    assert [f.t for f in frames] == [0.0, 0.1, 0.25, 0.3]
    assert all(f.image.ndim == 2 and f.image.dtype == np.uint8 for f in frames)
    assert int(frames[2].image[0, 0]) == 25  # colour converted to grey, pixel value kept


def test_folder_sorted_by_name_and_fps_fallback(tmp_path: Path) -> None:
    _write_images(tmp_path, 3)
    (tmp_path / "notes.txt").write_text("not an image")
    source = open_source(images=tmp_path, fps=20.0)
    frames = list(source)
    assert len(source) == 3
    np.testing.assert_allclose([f.t for f in frames], [0.0, 0.05, 0.1])
    assert [int(f.image[0, 0]) for f in frames] == [5, 15, 25]


def test_unpadded_names_are_read_in_their_numbers_order(tmp_path: Path) -> None:
    """ffmpeg's ``frame_%d.png``: sorted as text they were read 0, 1, 10, 11, 2, … and each
    jump estimated as a pair; a macOS ``._`` file beside a frame was read as frame 0."""
    for i in range(12):
        cv2.imwrite(str(tmp_path / f"frame_{i}.png"), np.full((30, 40), 10 * i + 5, np.uint8))
    (tmp_path / "._frame_3.png").write_bytes(b"\x00\x05\x16\x07 AppleDouble")
    frames = list(open_source(images=tmp_path, fps=10.0))
    assert [int(f.image[0, 0]) for f in frames] == [10 * i + 5 for i in range(12)]
    # times written by str(float) are numbers too: .25 before .5 (as text sorted them)
    stamps = tmp_path / "stamps"
    stamps.mkdir()
    for i, stamp in enumerate(("1403636579.25", "1403636579.5", "1403636579.75",
                               "1403636580.0")):
        cv2.imwrite(str(stamps / f"{stamp}.png"), np.full((30, 40), 10 * i + 5, np.uint8))
    frames = list(open_source(images=stamps, fps=10.0))
    assert [int(f.image[0, 0]) for f in frames] == [5, 15, 25, 35]


def test_start_and_max_frames_keep_recording_indices(tmp_path: Path) -> None:
    _write_images(tmp_path, 6)
    source = open_source(images=tmp_path, fps=10.0, start=2, max_frames=3)
    frames = list(source)
    assert len(source) == 3
    assert [f.index for f in frames] == [2, 3, 4]
    np.testing.assert_allclose([f.t for f in frames], [0.2, 0.3, 0.4])


def test_unreadable_image_is_reported_and_the_run_goes_on(tmp_path: Path) -> None:
    _write_images(tmp_path, 3)
    (tmp_path / "000001.png").write_bytes(b"this is not a png")
    frames = list(open_source(images=tmp_path, fps=10.0))
    assert [f.ok for f in frames] == [True, False, True]
    assert "unreadable frame" in frames[1].error and "000001.png" in frames[1].error


def test_times_count_mismatch_names_the_file(tmp_path: Path) -> None:
    _write_images(tmp_path, 3)
    (tmp_path / "times.txt").write_text("0.0\n0.1\n")
    with pytest.raises(SourceError, match=r"times\.txt: 2 timestamps but 3 images"):
        open_source(images=tmp_path)


def test_bad_times_lines(tmp_path: Path) -> None:
    path = tmp_path / "times.txt"
    path.write_text("0.0\nabc\n")
    with pytest.raises(SourceError, match="line 2: not a timestamp"):
        read_times(path)
    path.write_text("0.0\n0.2\n0.1\n")
    with pytest.raises(SourceError, match=r"line 3: timestamp 0\.1 does not increase"):
        read_times(path)
    path.write_text("# comment\n1.5e-1\n\n2.0e-1 extra\n")
    np.testing.assert_allclose(read_times(path), [0.15, 0.2])
    # "index time": read by the first field, every frame was 1 s after the one before
    path.write_text("0 0.0\n1 0.1\n")
    with pytest.raises(SourceError, match="line 1: 2 numbers on the line, which is the time"):
        read_times(path)
    # milliseconds, nanoseconds and hours: frames 100 s (1e8 s, 1e-5 s) apart were taken as
    # seconds, and a track's speed read 0.001 m/s
    for scale in (1e3, 1e9, 1e-4):
        path.write_text("".join(f"{i * 0.1 * scale!r}\n" for i in range(5)))
        with pytest.raises(SourceError, match=r"times\.txt: consecutive frames are .* s apart "
                           r"\(median\), a frame rate outside 0\.1–1000 Hz: the times must "
                           "be in seconds"):
            read_times(path)


def test_a_video_without_frames_is_named_so(tmp_path: Path) -> None:
    """A container with no frame was four rows of unreadable frames."""
    path = tmp_path / "empty.avi"
    _write_video(path, 0, 10.0)
    with pytest.raises(SourceError, match=r"empty\.avi: the video has no frame OpenCV can"):
        open_source(video=path)


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({}, "exactly one input"),
        ({"images": "/no/such/folder"}, "image folder not found"),
        ({"video": "/no/such/video.mp4"}, "video file not found"),
        ({"images": ".", "fps": -1.0}, r"--fps must be a number of frames per second in \[0.1, "
         r"1000\], got -1"),
        # a frame every 30 years timed a drive as standing; a megahertz one as a rocket
        ({"images": ".", "fps": 1e-9}, "got 1e-09"),
        ({"images": ".", "fps": 1e6}, "got 1e"),
        ({"images": ".", "fps": float("nan")}, "got nan"),
        ({"images": ".", "start": -1}, "--start must be >= 0"),
        ({"images": ".", "max_frames": 0}, "--max-frames must be >= 1"),
    ],
)
def test_bad_options_fail_fast(kwargs: dict, message: str) -> None:
    with pytest.raises(InputError, match=message):
        open_source(**kwargs)


def test_a_folder_or_an_image_given_as_a_video_is_named_so(tmp_path: Path) -> None:
    """--video on a folder said "video file not found"; on a PNG OpenCV played it as a
    5-frame video that ended in "0/5 frames ok"."""
    with pytest.raises(SourceError, match=r"a folder, not a video; .*--images"):
        open_source(video=tmp_path)
    image = tmp_path / "000000.png"
    cv2.imwrite(str(image), np.zeros((8, 8), np.uint8))
    with pytest.raises(SourceError, match=r"an image, not a video; .*--images"):
        open_source(video=image)


def test_folder_problems(tmp_path: Path) -> None:
    with pytest.raises(SourceError, match="no images in the folder"):
        open_source(images=tmp_path, fps=10.0)
    _write_images(tmp_path, 2)
    with pytest.raises(SourceError, match=r"no times\.txt.*pass --fps"):
        open_source(images=tmp_path)
    with pytest.raises(SourceError, match="--start 5 but the folder has 2 images"):
        open_source(images=tmp_path, fps=10.0, start=5)


def _write_video(path: Path, n: int, fps: float) -> None:
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), fps, (64, 48))
    assert writer.isOpened()
    for i in range(n):
        writer.write(np.full((48, 64, 3), 20 * i, np.uint8))
    writer.release()


def test_video_timestamps_grey_frames_and_fps_override(tmp_path: Path) -> None:
    path = tmp_path / "clip.avi"
    _write_video(path, 6, 12.5)
    source = open_source(video=path)
    frames = list(source)
    assert len(source) == 6 and len(frames) == 6
    np.testing.assert_allclose([f.t for f in frames], np.arange(6) / 12.5, atol=1e-6)
    assert frames[0].image.shape == (48, 64) and frames[0].image.dtype == np.uint8
    assert abs(int(frames[3].image[10, 10]) - 60) <= 3  # MJPG is lossy
    frames = list(open_source(video=path, fps=5.0, start=2, max_frames=2))
    assert [f.index for f in frames] == [2, 3]
    np.testing.assert_allclose([f.t for f in frames], [0.4, 0.6])


@pytest.mark.parametrize("fourcc", ["MJPG", "mp4v"])
def test_chunks_of_sources_are_their_frames(tmp_path: Path, fourcc: str) -> None:
    """A chunk of a video (seeked to), of an image folder and of arrays yields the same
    frames — pixels, indices, times — as the whole source does at those positions."""
    path = tmp_path / f"clip.{'avi' if fourcc == 'MJPG' else 'mp4'}"
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*fourcc), 10.0, (64, 48))
    rng = np.random.default_rng(1)
    for _ in range(40):  # textured frames: a wrong frame would not look alike
        writer.write(rng.integers(0, 255, (48, 64, 3), dtype=np.uint8))
    writer.release()
    _write_images(tmp_path / "img", 6)
    (tmp_path / "img" / "times.txt").write_text("".join(f"{0.1 * i}\n" for i in range(6)))
    arrays = ArraySource([np.full((4, 4), i, np.uint8) for i in range(6)], np.arange(6) * 0.5)
    for source, position, count in ((open_source(video=path, start=3), 20, 7),
                                    (open_source(images=tmp_path / "img", start=1), 2, 3),
                                    (arrays, 2, 3)):
        whole = list(source)[position:position + count]
        chunk = list(source.frames(position, count))
        assert [f.index for f in chunk] == [f.index for f in whole]
        np.testing.assert_allclose([f.t for f in chunk], [f.t for f in whole])
        for a, b in zip(chunk, whole, strict=True):
            np.testing.assert_array_equal(a.image, b.image)


def test_a_video_cut_short_says_so(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    """A video whose file ends before the frames its header states (a copy cut short): the
    frames before the cut are read, and the run is told where the file ends."""
    path = tmp_path / "clip.avi"
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 10.0, (64, 48))
    rng = np.random.default_rng(2)
    for _ in range(30):
        writer.write(rng.integers(0, 255, (48, 64, 3), dtype=np.uint8))
    writer.release()
    cut = tmp_path / "cut.avi"
    cut.write_bytes(path.read_bytes()[: path.stat().st_size // 2])
    frames = list(open_source(video=cut))
    read = [f for f in frames if f.image is not None]
    assert 5 <= len(read) < 30 and read == frames[: len(read)]
    err = capsys.readouterr().err
    assert f"{cut}: no frame reads from frame {len(read)} on" in err
    assert "header says 30 frames: the file ends early" in err
    list(open_source(video=path))  # the whole video: nothing said
    assert "ends early" not in capsys.readouterr().err


def test_unreadable_video_fails_fast(tmp_path: Path) -> None:
    path = tmp_path / "junk.mp4"
    path.write_bytes(b"definitely not a video")
    with pytest.raises(SourceError, match=r"junk\.mp4: OpenCV cannot open this video"):
        open_source(video=path)


def test_kitti_folder_reads_times_from_parent() -> None:
    folder = shared_data("kitti07", "image_0")
    source = open_source(images=folder, max_frames=3)
    frames = list(source)
    assert source.times_file.name == "times.txt"
    assert frames[0].image.shape == (370, 1226)
    np.testing.assert_allclose(frames[1].t, 0.1038752)
