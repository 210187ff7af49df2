"""Camera intrinsics and lens distortion, and the file formats they come in.

Reads ROS ``camera_info`` YAML, OpenCV FileStorage YAML and KITTI ``calib.txt`` (P0), and
writes ROS ``camera_info`` YAML. Models: pinhole with OpenCV distortion (``plumb_bob`` with
5 coefficients, ``rational_polynomial`` with 8 or more) and equidistant fisheye (4).

The estimator works on undistorted images whose intrinsic matrix is :attr:`CameraModel.k`
(see :meth:`CameraModel.undistort_image`), so distortion lives here and nowhere else.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
import yaml
from numpy.typing import ArrayLike, NDArray

from .errors import InputError, InvalidYaml, parse_yaml, printable
from .text_files import read_text

PINHOLE_MODELS = ("plumb_bob", "rational_polynomial", "none")
FISHEYE_MODELS = ("equidistant", "fisheye")

#: Keys of a ROS camera_info YAML (what ``camera_calibration`` writes); others are errors.
ROS_KEYS = ("image_width", "image_height", "camera_name", "camera_matrix", "distortion_model",
            "distortion_coefficients", "rectification_matrix", "projection_matrix")
#: Fields of a ``sensor_msgs/CameraInfo`` message printed by ``ros2 topic echo``.
ROS2_MESSAGE_KEYS = ("header", "height", "width", "distortion_model", "d", "k", "r", "p",
                     "binning_x", "binning_y", "roi")
#: Keys of a matrix in a ROS camera_info YAML.
ROS_MATRIX_KEYS = ("rows", "cols", "data")
#: Nodes of an OpenCV FileStorage camera file: the ones read, then the ones OpenCV's
#: calibration sample writes beside them (not needed here, accepted).
OPENCV_KEYS = ("camera_matrix", "distortion_coefficients", "image_width", "image_height",
               "distortion_model")
OPENCV_CALIBRATION_KEYS = (
    "calibration_time", "calibration_Time", "nr_of_frames", "nrOfFrames", "board_width",
    "board_height", "board_Width", "board_Height", "square_size", "square_Size", "flags",
    "calibrate_FixAspectRatio", "calibrate_AssumeZeroTangentialDistortion",
    "calibrate_FixPrincipalPointAtTheCenter", "fix_aspect_ratio", "fisheye_model",
    "FixAspectRatio", "aspectRatio", "avg_reprojection_error", "avg_reprojection_Error",
    "per_view_reprojection_errors", "extrinsic_parameters", "image_points", "grid_points",
    "Avg_Reprojection_Error", "Per_View_Reprojection_Errors", "Extrinsic_Parameters",
    "Image_points",
)


def intrinsic_matrix_problem(k: NDArray) -> str | None:
    """What is wrong with a 3×3 intrinsic matrix's fixed entries (lower triangle 0, last row
    ``0 0 1``), else None: the estimator reads fx, fy, cx, cy alone, so any other value there
    would go unnoticed and every pose would come out wrong."""
    fixed = np.array([k[1, 0], k[2, 0], k[2, 1], k[2, 2] - 1.0])
    if np.all(np.abs(fixed) <= 1e-9):
        return None
    return ("is not an intrinsic matrix: its second row must start with 0 and its last row "
            f"be 0 0 1, got {k[1, 0]:g} and {k[2, 0]:g} {k[2, 1]:g} {k[2, 2]:g}")


class CameraFileError(InputError):
    """A camera file is missing, unreadable or has a wrong field; the message names both."""

    def __init__(self, path: str | Path, problem: str, field_name: str | None = None) -> None:
        where = f"{path}" + (f", field '{field_name}'" if field_name else "")
        super().__init__(f"{where}: {problem}")
        self.path = str(path)
        self.field_name = field_name


@dataclass(frozen=True)
class CameraModel:
    """Intrinsics ``k`` (3×3, pixels), image size (pixels) and lens distortion.

    ``distortion_model`` is one of ``plumb_bob``, ``rational_polynomial``, ``none``
    (OpenCV's pinhole model) or ``equidistant`` (OpenCV's fisheye model).
    """

    k: NDArray[np.float64]
    width: int
    height: int
    distortion_model: str = "none"
    distortion: NDArray[np.float64] = field(default_factory=lambda: np.zeros(0))

    def __post_init__(self) -> None:
        # contiguous: OpenCV 5's USAC estimators (findEssentialMat with MAGSAC++) return
        # nothing for a strided matrix, such as KITTI's K read as a view of its P
        k = np.ascontiguousarray(self.k, dtype=float)
        object.__setattr__(self, "k", k)
        distortion = np.asarray(self.distortion, dtype=float).ravel()
        if self.distortion_model in FISHEYE_MODELS and distortion.size == 0:
            distortion = np.zeros(4)  # the pure equidistant lens, r = f·θ
        object.__setattr__(self, "distortion", distortion)
        if k.shape != (3, 3):
            raise ValueError(f"camera matrix must be 3×3, got shape {k.shape}")
        if (problem := intrinsic_matrix_problem(k)) is not None:
            raise ValueError(problem)
        if not (k[0, 0] > 0 and k[1, 1] > 0):
            raise ValueError(f"focal lengths must be > 0, got fx={k[0, 0]}, fy={k[1, 1]}")
        if self.width <= 0 or self.height <= 0:
            raise ValueError(f"image size must be positive, got {self.width}×{self.height}")
        if self.distortion_model not in PINHOLE_MODELS + FISHEYE_MODELS:
            raise ValueError(f"unknown distortion model '{self.distortion_model}'")
        if self.is_fisheye and distortion.size != 4:
            raise ValueError(f"an equidistant (fisheye) lens has 4 distortion coefficients, "
                             f"got {distortion.size}")

    @property
    def fx(self) -> float:
        return float(self.k[0, 0])

    @property
    def fy(self) -> float:
        return float(self.k[1, 1])

    @property
    def cx(self) -> float:
        return float(self.k[0, 2])

    @property
    def cy(self) -> float:
        return float(self.k[1, 2])

    @property
    def is_fisheye(self) -> bool:
        return self.distortion_model in FISHEYE_MODELS

    @property
    def has_distortion(self) -> bool:
        """Whether the image differs from the ideal pinhole image of ``k``: any nonzero
        coefficient, and every fisheye lens (its projection, r = f·θ, is not a pinhole's
        even where its coefficients are all zero)."""
        return self.is_fisheye or bool(np.any(self.distortion != 0))

    def check_image(self, shape: tuple[int, ...], source: str) -> None:
        """Raise ValueError naming ``source`` if an image's shape disagrees with the model."""
        if shape[0] != self.height or shape[1] != self.width:
            raise ValueError(
                f"{source}: image is {shape[1]}×{shape[0]} px but the camera model is "
                f"{self.width}×{self.height} px"
            )

    def undistort_points(self, pixels: ArrayLike) -> NDArray[np.float64]:
        """Distorted pixels (..., 2) → ideal pinhole pixels (..., 2) with matrix ``k``."""
        p = np.asarray(pixels, dtype=np.float64)
        if not self.has_distortion:
            return p.copy()
        flat = np.ascontiguousarray(p.reshape(-1, 1, 2))
        # OpenCV's default is 5 fixed-point iterations (~mpx errors at the corners of a
        # strongly distorted lens); iterate to convergence instead.
        criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-12)
        if self.is_fisheye:
            out = cv2.fisheye.undistortPoints(
                flat, self.k, self.distortion[:4], P=self.k, criteria=criteria
            )
        elif hasattr(cv2, "undistortPointsIter"):  # OpenCV 4.x spells the criteria variant so
            out = cv2.undistortPointsIter(
                flat, self.k, self.distortion, np.eye(3), self.k, criteria
            )
        else:
            out = cv2.undistortPoints(flat, self.k, self.distortion, P=self.k, criteria=criteria)
        return out.reshape(p.shape)

    def distort_points(self, pixels: ArrayLike) -> NDArray[np.float64]:
        """Ideal pinhole pixels (..., 2) with matrix ``k`` → distorted pixels (..., 2)."""
        p = np.asarray(pixels, dtype=np.float64)
        if not self.has_distortion:
            return p.copy()
        kinv = np.linalg.inv(self.k)
        norm = np.concatenate([p.reshape(-1, 2), np.ones((p[..., 0].size, 1))], axis=1) @ kinv.T
        # Contiguous copy: OpenCV's bindings misread the strided view of norm[:, :2].
        pts = np.ascontiguousarray(norm[:, :2]).reshape(-1, 1, 2)
        if self.is_fisheye:
            out = cv2.fisheye.distortPoints(pts, self.k, self.distortion[:4])
        else:
            obj = np.concatenate([pts.reshape(-1, 2), np.ones((pts.shape[0], 1))], axis=1)
            out, _ = cv2.projectPoints(obj, np.zeros(3), np.zeros(3), self.k, self.distortion)
        return out.reshape(p.shape)

    def undistortion_maps(self) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
        """cv2.remap maps producing the ideal pinhole image (matrix ``k``, same size)."""
        size = (self.width, self.height)
        if self.is_fisheye:
            return cv2.fisheye.initUndistortRectifyMap(
                self.k, self.distortion[:4], np.eye(3), self.k, size, cv2.CV_32FC1
            )
        return cv2.initUndistortRectifyMap(
            self.k, self.distortion, np.eye(3), self.k, size, cv2.CV_32FC1
        )

    def undistort_image(self, image: NDArray) -> NDArray:
        """The ideal pinhole image (matrix ``k``) of a distorted image; a copy-free pass
        when there is no distortion."""
        if not self.has_distortion:
            return image
        map_x, map_y = self.undistortion_maps()
        return cv2.remap(image, map_x, map_y, cv2.INTER_LINEAR)


# --- readers -------------------------------------------------------------------------------


def load_camera(path: str | Path, image_size: tuple[int, int] | None = None) -> CameraModel:
    """Read a camera file, choosing the reader by content: ROS camera_info YAML, OpenCV
    FileStorage YAML/XML, or KITTI calib.txt (P0). ``image_size`` (width, height; the frames
    the camera is used on) is the size of a KITTI camera, whose file holds none; the other
    files state theirs."""
    path = Path(path)
    if not path.is_file():
        raise CameraFileError(path, "is a folder; give the camera file" if path.is_dir()
                              else "file not found")
    text = read_text(path)
    kind = _file_kind(path, text)
    if kind == "opencv":
        return _read_opencv_storage(path)
    if kind == "kitti":
        return read_kitti_calib(path, image_size)
    return _read_ros_yaml(path, text)


def _file_kind(path: Path, text: str) -> str:
    """Which reader a camera file is for: ``opencv`` (FileStorage), ``kitti`` (calib.txt)
    or ``ros`` (camera_info YAML, or a CameraInfo message)."""
    if text.lstrip().startswith("%YAML") or "opencv-matrix" in text or path.suffix == ".xml":
        return "opencv"
    if path.suffix == ".txt" or text.lstrip().startswith("P0:"):
        return "kitti"
    return "ros"


def states_image_size(path: str | Path) -> bool:
    """Whether the camera file at ``path`` (one :func:`load_camera` reads) states the image
    size it was calibrated for (a KITTI calib.txt does not)."""
    path = Path(path)
    return _file_kind(path, read_text(path)) != "kitti"


def read_kitti_calib(path: str | Path, image_size: tuple[int, int] | None = None) -> CameraModel:
    """Camera 0 of a KITTI ``calib.txt`` (rectified, no distortion).

    ``image_size`` is (width, height) of the frames (``sources.first_frame_size``); KITTI
    files do not store it, so by default it is taken from the first image in ``image_0/``
    beside the file, else 1241×376."""
    path = Path(path)
    rows = {}
    for lineno, line in enumerate(read_text(path).splitlines(), start=1):
        if ":" in line:
            key, values = line.split(":", 1)
            rows[key.strip()] = values.split()
        elif line.strip():
            raise CameraFileError(path, f"line {lineno}: expected 'KEY: numbers' "
                                  "(KITTI calib.txt)")
    if "P0" not in rows:
        raise CameraFileError(path, "no P0 line (KITTI calib.txt expected)", "P0")
    try:
        p0 = np.array([float(v) for v in rows["P0"]]).reshape(3, 4)
    except ValueError:
        raise CameraFileError(path, f"must hold 12 numbers, got {printable(rows['P0'], 120)}",
                              "P0") from None
    if not np.all(np.isfinite(p0)):
        raise CameraFileError(path, "contains non-finite values", "P0")
    if image_size is None:
        image_size = _kitti_image_size(path.parent) or (1241, 376)
    return _build(path, p0[:, :3], image_size[0], image_size[1], "none", np.zeros(0), "P0")


def _kitti_image_size(folder: Path) -> tuple[int, int] | None:
    for sub in ("image_0", "image_2", "."):
        images = sorted((folder / sub).glob("*.png"))
        if images:
            img = cv2.imread(str(images[0]), cv2.IMREAD_UNCHANGED)
            if img is not None:
                return img.shape[1], img.shape[0]
    return None


def _read_ros_yaml(path: Path, text: str) -> CameraModel:
    # ``ros2 topic echo --once`` ends its message with a document separator
    body = re.sub(r"\n---\s*\Z", "\n", text)
    try:
        doc = parse_yaml(body)
    except InvalidYaml as exc:
        raise CameraFileError(path, str(exc)) from None
    if not isinstance(doc, dict):
        raise CameraFileError(path, "expected a YAML mapping (ROS camera_info)")
    if not set(doc) & {"camera_matrix", "image_width", "image_height"} and set(doc) & {
            "header", "width", "height", "k"}:
        return _read_ros2_message(path, doc)
    _check_keys(path, doc, ROS_KEYS, "")
    for name in ("camera_matrix", "distortion_coefficients", "rectification_matrix",
                 "projection_matrix"):
        if isinstance(doc.get(name), dict):
            _check_keys(path, doc[name], ROS_MATRIX_KEYS, f"{name}.")
    width = _required(doc, "image_width", path)
    height = _required(doc, "image_height", path)
    k = _matrix(doc, "camera_matrix", path, (3, 3))
    model = str(doc.get("distortion_model", "plumb_bob") or "plumb_bob")
    dist = np.zeros(0)
    if "distortion_coefficients" in doc:
        dist = _matrix(doc, "distortion_coefficients", path, None).ravel()
    return _build(path, k, width, height, model, dist, "camera_matrix")


def _read_ros2_message(path: Path, doc: dict) -> CameraModel:
    """A ``sensor_msgs/CameraInfo`` message as ``ros2 topic echo`` prints it (``width``,
    ``height``, ``k`` and ``d`` as flat lists, ``distortion_model``; refused as an unknown
    ``header`` key before)."""
    _check_keys(path, doc, ROS2_MESSAGE_KEYS, "")
    width = _required(doc, "width", path)
    height = _required(doc, "height", path)
    k = _matrix(doc, "k", path, (3, 3))
    model = str(doc.get("distortion_model") or "plumb_bob")
    dist = _matrix(doc, "d", path, None).ravel() if doc.get("d") else np.zeros(0)
    return _build(path, k, width, height, model, dist, "k")


def _check_keys(path: Path, doc: dict, valid: tuple[str, ...], prefix: str) -> None:
    """CameraFileError naming the first key of ``doc`` not in ``valid``, and the valid ones."""
    unknown = [k for k in doc if k not in valid]
    if unknown:
        raise CameraFileError(path, f"unknown key; valid keys are {', '.join(valid)}",
                              printable(f"{prefix}{unknown[0]}", 80))


def _read_opencv_storage(path: Path) -> CameraModel:
    try:
        return _read_opencv_nodes(path)
    except (cv2.error, SystemError) as exc:  # its parser raises either on a damaged file
        lines = str(exc).strip().splitlines() or [type(exc).__name__]
        raise CameraFileError(path, "OpenCV FileStorage cannot parse it ("
                              f"{printable(lines[-1], 200)})") from None


def _read_opencv_nodes(path: Path) -> CameraModel:
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    if not fs.isOpened():
        raise CameraFileError(path, "OpenCV FileStorage could not open it")
    try:
        root = fs.root()
        if not root.isMap():
            raise CameraFileError(path, "expected a mapping of named nodes (OpenCV FileStorage)")
        keys = root.keys()
        unknown = [k for k in keys if k not in OPENCV_KEYS + OPENCV_CALIBRATION_KEYS]
        if unknown:
            raise CameraFileError(
                path, f"unknown key; valid keys are {', '.join(OPENCV_KEYS)} (and the other "
                "nodes OpenCV's calibration sample writes)", printable(unknown[0], 80))
        k_node = fs.getNode("camera_matrix")
        if k_node.empty():
            raise CameraFileError(path, "missing", "camera_matrix")
        k = k_node.mat()
        if k is None or k.shape != (3, 3):
            raise CameraFileError(path, "must be a 3×3 matrix", "camera_matrix")
        dist_node = fs.getNode("distortion_coefficients")
        dist = np.zeros(0) if dist_node.empty() else np.asarray(dist_node.mat()).ravel()
        size = []
        for name in ("image_width", "image_height"):
            node = fs.getNode(name)
            if node.empty():
                raise CameraFileError(path, "missing", name)
            if not node.isInt():
                raise CameraFileError(path, "must be an integer", name)
            size.append(int(node.real()))
        model_node = fs.getNode("distortion_model")
        model = model_node.string() if not model_node.empty() else ""
        # OpenCV's calibration sample marks a fisheye calibration with ``fisheye_model: 1``
        # and no ``distortion_model``: its 4 coefficients are not plumb_bob's
        fisheye = _flag(fs.getNode("fisheye_model"), path, "fisheye_model")
        if fisheye and model and model not in FISHEYE_MODELS:
            raise CameraFileError(path, f"'{model}' contradicts fisheye_model: 1",
                                  "distortion_model")
        if not model:
            model = ("equidistant" if fisheye else
                     "rational_polynomial" if dist.size > 5 else "plumb_bob")
    finally:
        fs.release()
    return _build(path, k, size[0], size[1], model, dist, "camera_matrix")


def _flag(node: cv2.FileNode, path: Path, name: str) -> bool:
    """A FileStorage node read as a yes/no flag (``1``, ``1.0``, ``"true"``; absent: no);
    CameraFileError for any other value."""
    if node.empty():
        return False
    if node.isInt() or node.isReal():
        return node.real() != 0
    text = node.string().strip().lower() if node.isString() else ""
    if text in ("1", "true", "yes", "0", "false", "no"):
        return text in ("1", "true", "yes")
    raise CameraFileError(path, "must be 0 or 1", name)


def _required(doc: dict, name: str, path: Path) -> int:
    if name not in doc:
        raise CameraFileError(path, "missing", name)
    try:
        return int(doc[name])
    except (TypeError, ValueError) as exc:
        raise CameraFileError(path, f"must be an integer, got {doc[name]!r}", name) from exc


def _matrix(doc: dict, name: str, path: Path, shape: tuple[int, int] | None) -> NDArray:
    node = doc.get(name)
    if node is None:
        raise CameraFileError(path, "missing", name)
    data = node.get("data") if isinstance(node, dict) else node
    try:
        arr = np.asarray(data, dtype=float)
    except (TypeError, ValueError) as exc:
        raise CameraFileError(path, f"data must be numbers ({exc})", name) from exc
    declared = [node.get(k) for k in ("rows", "cols")] if isinstance(node, dict) else []
    if all(isinstance(n, int) and not isinstance(n, bool) for n in declared) and declared:
        if declared[0] * declared[1] != arr.size:
            # a header that disagrees with its data is a file written wrongly: which is meant?
            raise CameraFileError(path, f"rows × cols is {declared[0]} × {declared[1]} but "
                                  f"data holds {arr.size} numbers", name)
    if shape is not None:
        if arr.size != shape[0] * shape[1]:
            raise CameraFileError(
                path, f"needs {shape[0] * shape[1]} numbers, got {arr.size}", name
            )
        arr = arr.reshape(shape)
    if not np.all(np.isfinite(arr)):
        raise CameraFileError(path, "contains non-finite values", name)
    return arr


def _build(
    path: Path, k: NDArray, width: int, height: int, model: str, dist: NDArray, k_field: str
) -> CameraModel:
    if not np.all(np.isfinite(k)):
        raise CameraFileError(path, "contains non-finite values", k_field)
    if not np.all(np.isfinite(dist)):
        raise CameraFileError(path, "contains non-finite values", "distortion_coefficients")
    if (problem := intrinsic_matrix_problem(k)) is not None:
        raise CameraFileError(path, problem, k_field)
    if not (k[0, 0] > 0 and k[1, 1] > 0):
        raise CameraFileError(
            path, f"focal lengths must be > 0, got fx={k[0, 0]}, fy={k[1, 1]}", k_field
        )
    if width <= 0 or height <= 0:
        raise CameraFileError(
            path, f"image size must be positive, got {width}×{height}", "image_width"
        )
    if not (0 <= k[0, 2] <= width and 0 <= k[1, 2] <= height):
        # a typing error (a crop's camera may have it outside, a calibration file not): the
        # region of interest then held no interest point, said without the file or field
        raise CameraFileError(
            path, f"principal point cx={k[0, 2]:g}, cy={k[1, 2]:g} lies outside the "
            f"{width}×{height} image", k_field
        )
    model = {"equidistant": "equidistant", "fisheye": "equidistant", "": "plumb_bob"}.get(
        model, model
    )
    if model not in PINHOLE_MODELS + FISHEYE_MODELS:
        raise CameraFileError(path, f"unknown model '{model}'", "distortion_model")
    if model == "equidistant" and dist.size not in (0, 4):
        raise CameraFileError(
            path, f"equidistant needs 4 coefficients, got {dist.size}", "distortion_coefficients"
        )
    if model in ("plumb_bob", "rational_polynomial") and dist.size not in (0, 4, 5, 8, 12, 14):
        raise CameraFileError(
            path,
            f"OpenCV distortion needs 4, 5, 8, 12 or 14 coefficients, got {dist.size}",
            "distortion_coefficients",
        )
    return CameraModel(
        k=k, width=int(width), height=int(height), distortion_model=model, distortion=dist
    )


# --- writer --------------------------------------------------------------------------------


def write_ros_yaml(camera: CameraModel, path: str | Path, name: str = "camera") -> None:
    """Write ``camera`` as a ROS camera_info YAML (as ``camera_calibration`` does)."""
    k = camera.k
    p = np.hstack([k, np.zeros((3, 1))])
    dist = camera.distortion if camera.distortion.size else np.zeros(5)
    doc = {
        "image_width": camera.width,
        "image_height": camera.height,
        "camera_name": name,
        "camera_matrix": {"rows": 3, "cols": 3, "data": [float(v) for v in k.ravel()]},
        "distortion_model": "plumb_bob"
        if camera.distortion_model == "none"
        else camera.distortion_model,
        "distortion_coefficients": {
            "rows": 1,
            "cols": int(dist.size),
            "data": [float(v) for v in dist],
        },
        "rectification_matrix": {
            "rows": 3,
            "cols": 3,
            "data": [float(v) for v in np.eye(3).ravel()],
        },
        "projection_matrix": {"rows": 3, "cols": 4, "data": [float(v) for v in p.ravel()]},
    }
    Path(path).write_text(yaml.safe_dump(doc, sort_keys=False))
