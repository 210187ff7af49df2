"""Bags as frame sources: a ROS 1 bag and a rosbag2 MCAP written with rosbags hold the
rendered drive's images, intrinsics and speed exactly; ``estimate --bag`` gives the
estimates of ``estimate --images``."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest
from conftest import render_small_drive, write_bag
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from vipm_track.bag_source import BagError, BagSource, read_bag_camera, read_bag_speed
from vipm_track.camera import load_camera
from vipm_track.cli import main
from vipm_track.filters.wheel_speed import read_speed_csv
from vipm_track.sources import read_times
from vipm_track.table import read_table

T0 = 100.0


@pytest.fixture(scope="module")
def drive(tmp_path_factory) -> Path:
    return render_small_drive(tmp_path_factory.mktemp("bagdrive") / "drive", frames=10)


@pytest.fixture(scope="module")
def bags(drive) -> dict[str, Path]:
    folder = drive.parent
    ros1 = write_bag(drive, folder / "drive.bag", "ros1", T0)
    mcap = write_bag(drive, folder / "drive_mcap", "mcap", T0)
    return {"ros1": ros1, "rosbag2": mcap, "mcap": mcap / "drive_mcap.mcap"}


@pytest.mark.parametrize("kind", ["ros1", "rosbag2", "mcap"])
def test_bag_holds_the_drive(drive, bags, kind):
    path = bags[kind]
    source = BagSource(path)
    frames = list(source)
    images = sorted((drive / "images").glob("*.png"))
    assert len(source) == len(frames) == len(images)
    np.testing.assert_allclose([f.t for f in frames], read_times(drive / "times.txt") + T0,
                               atol=1e-9)
    for f, png in zip(frames, images, strict=True):
        assert f.error is None
        assert np.array_equal(f.image, cv2.imread(str(png), cv2.IMREAD_GRAYSCALE))
    camera = read_bag_camera(path)
    np.testing.assert_array_equal(camera.k, load_camera(drive / "camera.yaml").k)
    assert (camera.width, camera.height) == (400, 300)
    speed, truth = read_bag_speed(path), read_speed_csv(drive / "speed.csv")
    np.testing.assert_allclose(speed.t, truth.t + T0, atol=1e-9)
    np.testing.assert_allclose(speed.speed_mps, truth.speed_mps)
    chunk = source.frames(3, 4)
    assert [f.index for f in chunk] == [3, 4, 5, 6] and len(chunk) == 4


@pytest.mark.parametrize("share", [0.4, 0.75, 0.999])
def test_an_mcap_cut_short_gives_its_complete_frames(drive, bags, tmp_path, capsys, share):
    """A logger that died mid-file: rosbags refuses an MCAP without its footer ("File end
    magic is invalid") and the whole recording read as nothing; its complete records are
    read now, said once, and are the drive's first frames exactly."""
    whole = bags["mcap"].read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(whole[: int(share * len(whole))])
    source = BagSource(cut)
    frames = list(source)
    images = sorted((drive / "images").glob("*.png"))
    assert 1 <= len(frames) == len(source) <= len(images)
    for f, png in zip(frames, images, strict=False):
        assert f.error is None
        assert np.array_equal(f.image, cv2.imread(str(png), cv2.IMREAD_GRAYSCALE))
    assert read_bag_camera(cut).width == 400
    err = capsys.readouterr().err
    assert err.count(f"{cut}: cut short (no MCAP footer): reading its complete records") == 1


def test_an_mcap_cut_within_its_header_is_still_refused(bags, tmp_path):
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(bags["mcap"].read_bytes()[:40])
    with pytest.raises(BagError, match=r"cut.mcap: cannot read the bag: AnyReaderError"):
        BagSource(cut)


def test_estimate_bag_matches_images(drive, bags, tmp_path):
    common = ["--height", "0.7", "--pitch", "45", "--quiet", "--parquet"]
    assert main(["estimate", "--images", str(drive / "images"), "--out",
                 str(tmp_path / "img.csv"), *common]) == 0
    assert main(["estimate", "--bag", str(bags["mcap"]), "--out", str(tmp_path / "bag.csv"),
                 *common]) == 0
    a, b = read_table(tmp_path / "img.parquet"), read_table(tmp_path / "bag.parquet")
    np.testing.assert_allclose(b["t"], a["t"] + T0, atol=1e-9)
    assert list(a["status"]) == list(b["status"]) and (a["status"] == "ok").sum() >= 9
    # the same pairs; the frame intervals of times offset by 100 s differ in their last bits
    for column, atol in (("pitch_deg", 1e-3), ("roll_deg", 1e-3), ("tx_m", 1e-5),
                         ("tz_m", 1e-5), ("yaw_deg", 1e-3)):
        np.testing.assert_allclose(b[column], a[column], rtol=0, atol=atol)


def test_bad_topics_and_files_are_named(bags, tmp_path, capsys):
    with pytest.raises(BagError, match="no topic '/nope'"):
        BagSource(bags["ros1"], "/nope")
    with pytest.raises(BagError, match="is sensor_msgs/msg/CameraInfo, not"):
        BagSource(bags["ros1"], "/camera/camera_info")
    with pytest.raises(BagError, match="bag not found"):
        BagSource(tmp_path / "missing.bag")
    junk = tmp_path / "junk.mcap"
    junk.write_bytes(b"not an mcap file at all")
    assert main(["estimate", "--bag", str(junk), "--height", "0.7",
                 "--out", str(tmp_path / "e.csv")]) == 2
    assert "junk.mcap: cannot read the bag" in capsys.readouterr().err


@settings(max_examples=25, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(st.binary(max_size=300))
def test_garbage_bags_are_input_errors(tmp_path, data):
    for suffix in (".bag", ".mcap"):
        path = tmp_path / f"g{suffix}"
        path.write_bytes(data)
        with pytest.raises(BagError):
            list(BagSource(path))


@settings(max_examples=40, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(st.integers(min_value=0, max_value=10**9), st.binary(max_size=200))
def test_a_cut_mcap_with_garbage_is_read_or_refused(bags, tmp_path, cut_at, tail):
    """Cut anywhere and followed by garbage: the complete records before the damage are read,
    or the bag is refused; never another error."""
    whole = bags["mcap"].read_bytes()
    path = tmp_path / "g.mcap"
    path.write_bytes(whole[: cut_at % len(whole)] + tail)
    try:
        frames = list(BagSource(path))
    except BagError:
        return
    assert all(f.error is None or f.error.startswith("unreadable frame") for f in frames)
