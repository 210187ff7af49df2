"""Camera files (ROS, OpenCV FileStorage, KITTI), their errors, and lens distortion."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
import yaml

from tests.conftest import shared_data
from vipm_track.camera import CameraFileError, CameraModel, load_camera, write_ros_yaml

K = np.array([[729.0, 0.0, 401.5], [0.0, 731.0, 298.0], [0.0, 0.0, 1.0]])
DISTORTIONS = {
    "plumb_bob": np.array([-0.28, 0.09, 0.0012, -0.0007, -0.012]),
    "rational_polynomial": np.array([-0.3, 0.11, 0.001, -0.0005, 0.02, 0.05, -0.01, 0.004]),
    "equidistant": np.array([-0.05, 0.012, -0.004, 0.0007]),
}


def _ros_doc(**changes) -> dict:
    doc = {
        "image_width": 800, "image_height": 600, "camera_name": "test",
        "camera_matrix": {"rows": 3, "cols": 3, "data": K.ravel().tolist()},
        "distortion_model": "plumb_bob",
        "distortion_coefficients": {"rows": 1, "cols": 5,
                                    "data": DISTORTIONS["plumb_bob"].tolist()},
    }
    doc.update(changes)
    return {k: v for k, v in doc.items() if v is not None}


def _write(tmp_path, doc: dict, name: str = "cam.yaml"):
    path = tmp_path / name
    path.write_text(yaml.safe_dump(doc))
    return path


@pytest.mark.parametrize("model", sorted(DISTORTIONS))
def test_ros_yaml_round_trip(tmp_path, model):
    cam = CameraModel(K, 800, 600, model, DISTORTIONS[model])
    write_ros_yaml(cam, tmp_path / "c.yaml")
    back = load_camera(tmp_path / "c.yaml")
    assert np.allclose(back.k, K) and (back.width, back.height) == (800, 600)
    assert back.distortion_model == model and np.allclose(back.distortion, DISTORTIONS[model])


def test_ros_yaml_as_written_by_camera_calibration(tmp_path):
    cam = load_camera(_write(tmp_path, _ros_doc()))
    assert np.isclose(cam.fx, 729.0) and np.isclose(cam.fy, 731.0)
    assert (cam.cx, cam.cy) == (401.5, 298.0) and cam.distortion_model == "plumb_bob"


@pytest.mark.parametrize("model", sorted(DISTORTIONS))
def test_opencv_filestorage_yaml(tmp_path, model):
    path = tmp_path / "cv.yaml"
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    fs.write("image_width", 800)
    fs.write("image_height", 600)
    fs.write("camera_matrix", K)
    fs.write("distortion_coefficients", DISTORTIONS[model].reshape(1, -1))
    if model == "equidistant":
        fs.write("distortion_model", "equidistant")
    fs.release()
    cam = load_camera(path)
    assert np.allclose(cam.k, K) and (cam.width, cam.height) == (800, 600)
    assert cam.distortion_model == model and np.allclose(cam.distortion, DISTORTIONS[model])


def test_opencv_calibration_samples_fisheye_flag_is_the_fisheye_model(tmp_path):
    """OpenCV's calibration sample writes a fisheye calibration as ``fisheye_model: 1`` and
    4 coefficients, no ``distortion_model``: read as plumb_bob's k1, k2, p1, p2 it gave rows
    8° off (a new user's fisheye cart); a ``distortion_model`` that contradicts it is named."""
    def write(path, **extra):
        fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
        fs.write("image_width", 800)
        fs.write("image_height", 600)
        fs.write("camera_matrix", K)
        fs.write("distortion_coefficients", DISTORTIONS["equidistant"].reshape(-1, 1))
        for key, value in extra.items():
            fs.write(key, value)
        fs.release()
        return path

    cam = load_camera(write(tmp_path / "fish.yaml", fisheye_model=1))
    assert cam.is_fisheye and np.allclose(cam.distortion, DISTORTIONS["equidistant"])
    for flag in (1.0, "true"):  # written as a real number or a word: the same flag
        assert load_camera(write(tmp_path / "fish2.yaml", fisheye_model=flag)).is_fisheye
    with pytest.raises(CameraFileError, match="field 'fisheye_model': must be 0 or 1"):
        load_camera(write(tmp_path / "odd.yaml", fisheye_model="maybe"))
    assert load_camera(write(tmp_path / "pin.yaml", fisheye_model=0)).distortion_model == \
        "plumb_bob"
    with pytest.raises(CameraFileError, match="'plumb_bob' contradicts fisheye_model: 1"):
        load_camera(write(tmp_path / "both.yaml", fisheye_model=1, distortion_model="plumb_bob"))


def test_a_camera_info_printed_by_ros2_topic_echo_is_read(tmp_path):
    """``ros2 topic echo --once /camera_info > cam.yaml``: lower-case fields, flat lists, a
    header and a closing ``---`` (refused as an unknown key 'header' before)."""
    k = ", ".join(repr(float(v)) for v in K.ravel())
    d = "\n".join(f"- {float(v)!r}" for v in DISTORTIONS["plumb_bob"])
    path = tmp_path / "echo.yaml"
    path.write_text(
        "header:\n  stamp:\n    sec: 1700000000\n    nanosec: 5\n  frame_id: camera\n"
        f"height: 600\nwidth: 800\ndistortion_model: plumb_bob\nd:\n{d}\nk: [{k}]\n"
        "r: [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]\n"
        f"p: [{k[:k.rindex(',')]}, 0.0, 0.0, 0.0, 0.0]\n"
        "binning_x: 0\nbinning_y: 0\nroi:\n  x_offset: 0\n  y_offset: 0\n  height: 0\n"
        "  width: 0\n  do_rectify: false\n---\n")
    cam = load_camera(path)
    assert np.allclose(cam.k, K) and (cam.width, cam.height) == (800, 600)
    assert np.allclose(cam.distortion, DISTORTIONS["plumb_bob"])
    path.write_text(path.read_text().replace("k: [", "kk: ["))
    with pytest.raises(CameraFileError, match="'kk'"):
        load_camera(path)


def test_kitti_calib():
    path = shared_data("kitti07", "calib.txt")
    cam = load_camera(path)
    assert np.isclose(cam.fx, 707.0912) and np.isclose(cam.fy, 707.0912)
    assert np.isclose(cam.cx, 601.8873) and np.isclose(cam.cy, 183.1104)
    assert (cam.width, cam.height) == (1226, 370)
    assert not cam.has_distortion


def test_kitti_calib_takes_the_size_of_the_frames_it_is_used_on(tmp_path, capsys):
    """A calib.txt beside a folder of frames not named image_0 (or of JPEGs): the size comes
    from the frames given, not a default (frames of KITTI 07, 1226×370, were refused as not
    1241×376)."""
    from vipm_track.cli import EXIT_NOTHING_USABLE, main
    from vipm_track.sources import first_frame_size

    calib = tmp_path / "calib.txt"
    calib.write_text("P0: 7.07e+02 0 6.0e+02 0 0 7.07e+02 1.8e+02 0 0 0 1 0\n")
    assert (load_camera(calib).width, load_camera(calib).height) == (1241, 376)
    frames = tmp_path / "frames"
    frames.mkdir()
    rng = np.random.default_rng(0)
    for k in range(3):
        cv2.imwrite(str(frames / f"f{k}.jpg"), rng.integers(0, 255, (370, 1226), np.uint8))
    assert first_frame_size(frames) == (1226, 370)
    cam = load_camera(calib, first_frame_size(frames))
    assert (cam.width, cam.height) == (1226, 370) and np.isclose(cam.fx, 707.0)
    rc = main(["estimate", "--images", str(frames), "--height", "1.65", "--pitch", "1",
               "--fps", "10", "--out", str(tmp_path / "e.csv"), "--quiet"])
    err = capsys.readouterr().err
    assert rc in (0, EXIT_NOTHING_USABLE), err  # noise frames: nothing usable is fine
    assert "camera model is" not in err and "too few inliers" in (tmp_path / "e.csv").read_text()


@pytest.mark.parametrize(("changes", "field"), [
    ({"image_width": None}, "image_width"),
    ({"image_height": "tall"}, "image_height"),
    ({"camera_matrix": None}, "camera_matrix"),
    ({"camera_matrix": {"rows": 3, "cols": 3, "data": [729.0, 0, 400, 0, 729, 300, 0, 0]}},
     "camera_matrix"),
    ({"camera_matrix": {"data": [729.0, 0, 400, 0, "x", 300, 0, 0, 1]}}, "camera_matrix"),
    ({"camera_matrix": {"data": [0.0, 0, 400, 0, 729, 300, 0, 0, 1]}}, "camera_matrix"),
    ({"camera_matrix": {"data": [729.0, 0, 400, 0, -729, 300, 0, 0, 1]}}, "camera_matrix"),
    ({"camera_matrix": {"data": [729.0, 0, 5000.5, 0, 729, 300, 0, 0, 1]}}, "camera_matrix"),
    ({"camera_matrix": {"data": [729.0, 0, 400, 0, 729, -3, 0, 0, 1]}}, "camera_matrix"),
    # not an intrinsic matrix: K[2,2] of 2 gave `ok` rows 8–17° off at a 0.01° std
    ({"camera_matrix": {"data": [729.0, 0, 400, 0, 729, 300, 0, 0, 2]}}, "camera_matrix"),
    ({"camera_matrix": {"data": [729.0, 0, 400, 0.5, 729, 300, 0, 0, 1]}}, "camera_matrix"),
    ({"image_width": 0}, "image_width"),
    ({"distortion_model": "fancy"}, "distortion_model"),
    ({"distortion_coefficients": {"data": [0.1, 0.2, 0.3]}}, "distortion_coefficients"),
    ({"distortion_coefficients": {"rows": 1, "cols": 4, "data": [0.1, 0.01, 0, 0, 0.001]}},
     "distortion_coefficients"),
    ({"distortion_model": "equidistant"}, "distortion_coefficients"),
])
def test_ros_yaml_errors_name_file_and_field(tmp_path, changes, field):
    path = _write(tmp_path, _ros_doc(**changes))
    with pytest.raises(CameraFileError) as info:
        load_camera(path)
    assert str(path) in str(info.value) and f"'{field}'" in str(info.value)
    assert info.value.field_name == field


def test_other_file_errors(tmp_path):
    with pytest.raises(CameraFileError, match="file not found"):
        load_camera(tmp_path / "nope.yaml")
    with pytest.raises(CameraFileError, match="is a folder; give the camera file"):
        load_camera(tmp_path)  # it said "file not found" of a folder that exists
    bad = tmp_path / "bad.yaml"
    bad.write_text("image_width: [1, 2\n")
    with pytest.raises(CameraFileError, match=r"bad\.yaml"):
        load_camera(bad)
    listing = tmp_path / "list.yaml"
    listing.write_text("- 1\n- 2\n")
    with pytest.raises(CameraFileError, match="mapping"):
        load_camera(listing)
    kitti = tmp_path / "calib.txt"
    kitti.write_text("P1: 1 0 0 0 0 1 0 0 0 0 1 0\n")
    with pytest.raises(CameraFileError, match="'P0'"):
        load_camera(kitti)
    kitti.write_text("P0: 1 0 0 0 0 1\n")
    with pytest.raises(CameraFileError, match="'P0'"):
        load_camera(kitti)
    cvfile = tmp_path / "cv.yaml"
    fs = cv2.FileStorage(str(cvfile), cv2.FILE_STORAGE_WRITE)
    fs.write("image_width", 800)
    fs.write("distortion_coefficients", np.zeros((1, 5)))
    fs.release()
    with pytest.raises(CameraFileError, match="'camera_matrix'"):
        load_camera(cvfile)
    # OpenCV's reader: a NaN or inf coefficient, and a K with a skewed last row
    for dist, k, field in (([np.nan, 0, 0, 0, 0], K, "distortion_coefficients"),
                           ([np.inf, 0, 0, 0, 0], K, "distortion_coefficients"),
                           ([0.0] * 5, K + np.array([[0, 0, 0], [0, 0, 0], [0.1, 0, 0]]),
                            "camera_matrix")):
        fs = cv2.FileStorage(str(cvfile), cv2.FILE_STORAGE_WRITE)
        fs.write("image_width", 800)
        fs.write("image_height", 600)
        fs.write("camera_matrix", np.asarray(k, float))
        fs.write("distortion_coefficients", np.array([dist], float))
        fs.release()
        with pytest.raises(CameraFileError, match=f"'{field}'"):
            load_camera(cvfile)


def test_check_image_size_mismatch():
    cam = CameraModel(K, 800, 600)
    cam.check_image((600, 800), "frame 3")
    cam.check_image((600, 800, 3), "frame 3")
    with pytest.raises(ValueError, match=r"frame 7.*640×480.*800×600"):
        cam.check_image((480, 640), "frame 7")


def test_model_validation():
    with pytest.raises(ValueError, match="focal"):
        CameraModel(np.diag([-1.0, 1.0, 1.0]), 10, 10)
    with pytest.raises(ValueError, match="3×3"):
        CameraModel(np.eye(2), 10, 10)
    with pytest.raises(ValueError, match="last row be 0 0 1"):
        CameraModel(K * 2, 800, 600)
    with pytest.raises(ValueError, match="unknown distortion model"):
        CameraModel(K, 800, 600, "kannala")


@pytest.mark.parametrize("model", sorted(DISTORTIONS))
def test_distort_undistort_points_round_trip(model):
    cam = CameraModel(K, 800, 600, model, DISTORTIONS[model])
    rng = np.random.default_rng(0)
    ideal = rng.uniform([40, 30], [760, 570], size=(200, 2))
    distorted = cam.distort_points(ideal)
    # Real distortion: barrel moves the corners by many pixels.
    assert np.max(np.hypot(*(distorted - ideal).T)) > 5
    assert np.allclose(cam.undistort_points(distorted), ideal, atol=1e-3)
    assert cam.distort_points(ideal.reshape(10, 20, 2)).shape == (10, 20, 2)
    # Against OpenCV's own projection of the normalised rays.
    rays = np.column_stack([(ideal - K[:2, 2]) / [K[0, 0], K[1, 1]], np.ones(len(ideal))])
    if model == "equidistant":
        ref = cv2.fisheye.distortPoints(rays[:, None, :2], K, DISTORTIONS[model]).reshape(-1, 2)
    else:
        ref, _ = cv2.projectPoints(rays, np.zeros(3), np.zeros(3), K, DISTORTIONS[model])
        ref = ref.reshape(-1, 2)
    assert np.allclose(distorted, ref, atol=1e-6)


@pytest.mark.parametrize("model", sorted(DISTORTIONS))
def test_undistort_image_agrees_with_undistort_points(model):
    cam = CameraModel(K, 800, 600, model, DISTORTIONS[model])
    # Small bright spots drawn directly at distorted positions.
    distorted_pts = np.array([[120.0, 90.0], [690.0, 110.0], [400.0, 300.0], [150.0, 520.0],
                              [660.0, 500.0], [300.5, 200.25]])
    v, u = np.mgrid[0:600, 0:800].astype(float)
    img = np.zeros((600, 800))
    for x, y in distorted_pts:
        img += 250 * np.exp(-((u - x) ** 2 + (v - y) ** 2) / (2 * 1.5**2))
    out = cam.undistort_image(np.clip(img, 0, 255).astype(np.float32)).astype(float)
    expected = cam.undistort_points(distorted_pts)
    for ex, ey in expected:
        x0, y0 = round(float(ex)), round(float(ey))
        patch = out[y0 - 12:y0 + 13, x0 - 12:x0 + 13]
        yy, xx = np.mgrid[y0 - 12:y0 + 13, x0 - 12:x0 + 13]
        centroid = np.array([(xx * patch).sum(), (yy * patch).sum()]) / patch.sum()
        assert np.hypot(*(centroid - (ex, ey))) < 0.15
    assert cam.undistort_image(img) is not img
    plain = CameraModel(K, 800, 600)
    assert plain.undistort_image(img) is img


@pytest.mark.parametrize("coefficients", [[0.0, 0.0, 0.0, 0.0], []])
def test_a_fisheye_lens_without_coefficients_is_still_a_fisheye(coefficients, tmp_path):
    # The pure equidistant lens (r = f·θ) has all four coefficients zero; it was taken for a
    # pinhole camera and its frames left as they were: on a rendered 122° lens the smoothed
    # pitch read 4.15° for 3° and the monitor called the height 27 cm off.
    cam = CameraModel(K, 800, 600, "equidistant", np.array(coefficients))
    assert cam.has_distortion and cam.distortion.shape == (4,)
    theta = 0.8  # a ray 0.8 rad off the axis lands f·θ from the centre, not f·tan θ
    distorted = K[:2, 2] + [K[0, 0] * theta, 0.0]
    ideal = cam.undistort_points(distorted)
    assert np.allclose(ideal, K[:2, 2] + [K[0, 0] * np.tan(theta), 0.0], atol=1e-6)
    assert np.allclose(cam.distort_points(ideal), distorted, atol=1e-6)
    write_ros_yaml(cam, tmp_path / "camera.yaml")
    assert load_camera(tmp_path / "camera.yaml").has_distortion
    with pytest.raises(ValueError, match="4 distortion coefficients"):
        CameraModel(K, 800, 600, "equidistant", np.zeros(5))
