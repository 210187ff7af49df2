"""Feature-homography baseline (Miksch et al. 2010, Knorr et al. 2013 style).

Keypoints (SIFT or ORB) on the ground region of both frames, ratio-test matches, a
RANSAC ground-plane homography (``cv2.findHomography``), decomposed
(``cv2.decomposeHomographyMat``) into the rotation, the translation over the plane distance
and the plane normal, from which the pose of both frames against the ground and the planar
motion follow. The estimator's accuracy benchmark compares against it on the same frames.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from .camera import CameraModel
from .geometry import GroundPose, PlanarMotion, rotation_ground_from_camera

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class BaselineResult:
    """Outcome of :func:`homography_baseline`: ``status`` is "ok" or a short reason; poses
    (radians, metres) and motion (frame k-1 → k, CONVENTIONS.md) are None unless ok."""

    status: str
    pose_prev: GroundPose | None = None
    pose_curr: GroundPose | None = None
    motion: PlanarMotion | None = None
    n_matches: int = 0
    n_inliers: int = 0

    @property
    def ok(self) -> bool:
        return self.status == "ok"


def homography_baseline(
    prev: NDArray,
    curr: NDArray,
    camera: CameraModel,
    height: float,
    nominal: GroundPose,
    mask: NDArray[np.bool_] | None = None,
    detector: str = "sift",
    ransac_px: float = 1.5,
    max_features: int = 4000,
) -> BaselineResult:
    """Pose of both frames and the planar motion from a feature homography.

    Parameters
    ----------
    prev, curr : grey uint8 images of frames k-1 and k (undistorted, matrix ``camera.k``).
    camera : intrinsics.
    height : assumed camera height [m] (the plane distance of the decomposition).
    nominal : pose used to pick among the decomposition's solutions (the one whose ground
        normal is closest to the nominal one).
    mask : ground region where keypoints are detected (None: whole image).
    detector : "sift" or "orb".
    ransac_px : RANSAC reprojection threshold, pixels.
    """
    det, norm = _detector(detector, max_features)
    m8 = None if mask is None else mask.astype(np.uint8)
    kp1, des1 = det.detectAndCompute(prev, m8)
    kp2, des2 = det.detectAndCompute(curr, m8)
    if des1 is None or des2 is None or len(kp1) < 8 or len(kp2) < 8:
        return BaselineResult("no texture")
    matcher = cv2.BFMatcher(norm)
    pairs = matcher.knnMatch(des1, des2, k=2)
    good = [p[0] for p in pairs if len(p) == 2 and p[0].distance < 0.75 * p[1].distance]
    if len(good) < 8:
        return BaselineResult("too few inliers", n_matches=len(good))
    p1 = np.float64([kp1[m.queryIdx].pt for m in good])
    p2 = np.float64([kp2[m.trainIdx].pt for m in good])
    h, inl = cv2.findHomography(p1, p2, cv2.RANSAC, ransac_px, maxIters=5000, confidence=0.999)
    if h is None:
        return BaselineResult("did not converge", n_matches=len(good))
    inl = inl.ravel().astype(bool)
    if inl.sum() < 8:
        return BaselineResult("too few inliers", n_matches=len(good), n_inliers=int(inl.sum()))
    sol = decompose(h, camera.k, height, nominal, p1[inl])
    if sol is None:
        return BaselineResult("degenerate", n_matches=len(good), n_inliers=int(inl.sum()))
    return BaselineResult("ok", *sol, n_matches=len(good), n_inliers=int(inl.sum()))


def decompose(
    h: FloatArray, k: FloatArray, height: float, nominal: GroundPose, pixels_prev: FloatArray
) -> tuple[GroundPose, GroundPose, PlanarMotion] | None:
    """(pose_prev, pose_curr, motion) of a ground-plane homography (pixels k-1 → k).

    OpenCV's decomposition gives ``X_k = R X_{k-1} + t`` with ``t`` over the plane distance
    and the plane normal ``n`` in camera k-1; the solution kept puts the matched ground
    points in front of the plane side (``n · ray > 0``) and has the normal nearest the
    nominal pose's. The ground normal (into the ground) in the camera frame is
    ``(cos p sin r, cos p cos r, sin p)``, i.e. the second row of R_GC.
    """
    n_solutions, rotations, translations, normals = cv2.decomposeHomographyMat(h, k)
    n_nom = rotation_ground_from_camera(nominal.pitch, nominal.roll)[1]
    homog = np.concatenate([pixels_prev, np.ones((len(pixels_prev), 1))], axis=1)
    rays = homog @ np.linalg.inv(k).T
    best, best_dot = None, -np.inf
    for i in range(n_solutions):
        n = normals[i].ravel()
        if np.mean(rays @ n > 0) < 0.9:
            continue
        dot = float(n @ n_nom)
        if dot > best_dot:
            best, best_dot = i, dot
    if best is None:
        return None
    r = rotations[best]
    t = translations[best].ravel() * height
    n_p = normals[best].ravel()
    n_c = r @ n_p
    pitch_p, roll_p = _pose_from_normal(n_p)
    pitch_c, roll_c = _pose_from_normal(n_c)
    r_gc_p = rotation_ground_from_camera(pitch_p, roll_p)
    # Camera k's centre and optical axis in camera k-1, then in G_{k-1}.
    centre = r_gc_p @ (-r.T @ t)
    axis = r_gc_p @ (r.T @ np.array([0.0, 0.0, 1.0]))
    motion = PlanarMotion(float(centre[0]), float(centre[2]), float(np.arctan2(axis[0], axis[2])))
    return (GroundPose(pitch_p, roll_p, height), GroundPose(pitch_c, roll_c, height), motion)


def _pose_from_normal(n: FloatArray) -> tuple[float, float]:
    """(pitch, roll) radians of the unit ground normal (into the ground) in camera axes."""
    n = n / np.linalg.norm(n)
    return float(np.arcsin(np.clip(n[2], -1.0, 1.0))), float(np.arctan2(n[0], n[1]))


def _detector(name: str, max_features: int) -> tuple[cv2.Feature2D, int]:
    if name == "sift":
        return cv2.SIFT_create(nfeatures=max_features), cv2.NORM_L2
    if name == "orb":
        return cv2.ORB_create(nfeatures=max_features), cv2.NORM_HAMMING
    raise ValueError(f"unknown detector '{name}'; choose 'sift' or 'orb'")
