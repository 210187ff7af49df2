"""KITTI odometry ground truth (``poses.txt``) as the conventions' per-frame planar motion.

``poses.txt`` holds, per frame, the 3×4 pose ``[R | t]`` of camera 0 in the first frame's
camera frame (OpenCV axes: x right, y down, z forward). The relative pose between frames
k-1 and k, ``T_rel = T_{k-1}⁻¹ T_k``, is camera k in camera k-1's frame. To turn it into the
motion of the ground frame G (``CONVENTIONS.md``) we need camera k-1's pose against the road,
which KITTI does not record; we take a nominal one (``pitch``, ``roll``; the KITTI camera is
close to level, ~1°) and assume a flat road and constant camera height over one frame:

- ``R_{G_{k-1} C_k} = R_GC(pitch, roll) · R_rel`` (camera k's axes in G_{k-1});
- yaw = heading of camera k's optical axis projected on the ground:
  ``atan2(z_x, z_z)`` of its third column (> 0 turning right);
- (tx, tz) = x, z of ``R_GC · t_rel``: the camera centre's displacement in G_{k-1}, whose
  ground foot is the origin of G_k;
- pitch and roll of frame k against the road: ``R_{G_k C_k} = Ry(yaw)ᵀ R_{G_{k-1} C_k}``,
  so the pitch/roll *changes* are exact while the absolute values inherit the nominal ones.

A 1° error in the nominal pitch changes (tx, tz) by < 0.02 % and yaw by < 0.02 %
of its value, far below what is being measured.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from .errors import InputError
from .geometry import pose_from_rotation, rot_y, rotation_ground_from_camera
from .text_files import read_text


@dataclass(frozen=True)
class KittiMotion:
    """Ground-truth motion into frames 1..N-1 (arrays of length N-1): ``tx``, ``tz`` [m],
    ``yaw`` [rad, > 0 right], ``pitch``/``roll`` of frame k and of frame k-1 [rad] (from the
    nominal pose of frame k-1, see module doc)."""

    tx: NDArray[np.float64]
    tz: NDArray[np.float64]
    yaw: NDArray[np.float64]
    pitch: NDArray[np.float64]
    roll: NDArray[np.float64]
    prev_pitch: float
    prev_roll: float

    @property
    def distance(self) -> NDArray[np.float64]:
        """Travel distance per frame [m]."""
        return np.hypot(self.tx, self.tz)


def read_poses(path: str | Path) -> NDArray[np.float64]:
    """(N, 4, 4) homogeneous camera-to-first-camera poses from a KITTI ``poses.txt``."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: KITTI poses file not found")
    rows = []
    for lineno, line in enumerate(read_text(path).splitlines(), start=1):
        if not line.strip():
            continue
        try:
            values = [float(v) for v in line.split()]
        except ValueError as exc:
            raise InputError(f"{path}: line {lineno}: not 12 numbers") from exc
        if len(values) != 12:
            raise InputError(f"{path}: line {lineno}: {len(values)} numbers, expected 12 (3×4)")
        rows.append(values)
    if len(rows) < 2:
        raise InputError(f"{path}: need at least 2 poses, got {len(rows)}")
    poses = np.tile(np.eye(4), (len(rows), 1, 1))
    poses[:, :3, :] = np.asarray(rows).reshape(-1, 3, 4)
    return poses


def planar_motion(poses: NDArray, pitch: float = 0.0, roll: float = 0.0) -> KittiMotion:
    """Per-frame planar motion (frames 1..N-1) of (N, 4, 4) camera poses, given the nominal
    ``pitch``/``roll`` [rad] of each frame k-1 against the road (see module doc)."""
    rel = np.linalg.inv(poses[:-1]) @ poses[1:]
    r_gc = rotation_ground_from_camera(pitch, roll)
    r_g_ck = r_gc @ rel[:, :3, :3]
    t_g = rel[:, :3, 3] @ r_gc.T
    yaw = np.arctan2(r_g_ck[:, 0, 2], r_g_ck[:, 2, 2])
    pr = np.array([pose_from_rotation(rot_y(a).T @ r) for a, r in zip(yaw, r_g_ck, strict=True)])
    return KittiMotion(t_g[:, 0], t_g[:, 2], yaw, pr[:, 0], pr[:, 1], pitch, roll)


#: pitch of the KITTI camera against the road assumed for the truth's motion [deg]: the
#: camera is near level, and the motion hardly depends on it (module doc)
KITTI_PITCH_DEG = 1.0


def is_kitti_poses(path: str | Path) -> bool:
    """Whether ``path`` looks like a KITTI ``poses.txt``: its first line is 12 numbers."""
    path = Path(path)
    if not path.is_file() or path.suffix.lower() in (".csv", ".parquet"):
        return False
    with path.open("rb") as f:
        first = f.readline(4096).decode("utf-8", errors="replace").split()
    try:
        return len(first) == 12 and all(np.isfinite(float(v)) for v in first)
    except ValueError:
        return False


def kitti_truth_table(path: str | Path, pitch_deg: float = KITTI_PITCH_DEG,
                      ) -> dict[str, NDArray]:
    """Ground truth of frames 1..N-1 of a KITTI ``poses.txt`` as per-frame table columns
    (``table.read_table`` layout): ``frame``, ``t`` (from ``times.txt`` beside it, where
    there), ``tx_m``, ``tz_m``, ``yaw_deg`` and the pitch/roll of frames k and k-1 around the
    nominal ``pitch_deg`` (only their *changes* are truth: module doc)."""
    path = Path(path)
    gt = planar_motion(read_poses(path), np.radians(pitch_deg))
    n = gt.tx.size
    table: dict[str, NDArray] = {
        "frame": np.arange(1, n + 1),
        "tx_m": gt.tx, "tz_m": gt.tz, "yaw_deg": np.degrees(gt.yaw),
        "pitch_deg": np.degrees(gt.pitch), "roll_deg": np.degrees(gt.roll),
        "prev_pitch_deg": np.full(n, pitch_deg), "prev_roll_deg": np.zeros(n),
    }
    times = path.with_name("times.txt")
    if times.is_file():
        from .sources import read_times

        t = read_times(times)
        if t.size < n + 1:
            raise InputError(f"{times}: {t.size} times for the {n + 1} poses of {path}; "
                             "it needs one line per pose")
        table["t"] = t[1 : n + 1]
    return table
