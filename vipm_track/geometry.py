"""Pose against the ground, projections, planar motion and IPM homographies.

The single home of the frames and signs of ``CONVENTIONS.md``; every other module calls
these functions rather than re-deriving them.

- Camera frame C: OpenCV's (x right, y down, z forward).
- Ground frame G: origin under the camera centre, y along the ground normal pointing *into*
  the ground, z the optical axis projected onto the ground, x = y × z (right). The ground is
  y = 0 and the camera centre is at (0, -h, 0).
- Pose Θ = (pitch, roll, h): ``R_GC = Rx(-pitch) · Rz(roll)`` (columns: camera axes in G).
  pitch > 0 looks down, roll > 0 dips the image's right edge toward the ground.
- Planar motion Ψ = (tx, tz, yaw) from frame k-1 to k: ``P_k = Ry(yaw)ᵀ (P_{k-1} - (tx, 0, tz))``.

Ground points are handled as 2-vectors ``(X, Z)`` on the plane y = 0, in metres.
Angles are radians.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class GroundPose:
    """Camera pose against the ground: pitch and roll in radians, height in metres."""

    pitch: float
    roll: float
    height: float

    def as_degrees(self) -> tuple[float, float, float]:
        """Return (pitch_deg, roll_deg, height_m)."""
        return float(np.degrees(self.pitch)), float(np.degrees(self.roll)), self.height


@dataclass(frozen=True)
class PlanarMotion:
    """Motion from frame k-1 to k: origin of G_k in G_{k-1} (tx right, tz forward, metres)
    and heading change yaw (radians, > 0 turning right)."""

    tx: float
    tz: float
    yaw: float

    @property
    def distance(self) -> float:
        """Travel distance sqrt(tx² + tz²), metres."""
        return float(np.hypot(self.tx, self.tz))


@dataclass(frozen=True)
class IpmGrid:
    """A bird's-eye (IPM) image grid on the ground plane of some frame G.

    Pixel (u, v) sits at ground point X = x_min + u·mpp, Z = z_max - v·mpp, so the image's
    up is forward and its right is right. ``width``/``height`` are in pixels.
    """

    x_min: float
    z_max: float
    metres_per_pixel: float
    width: int
    height: int

    @classmethod
    def from_extent(
        cls, x_min: float, x_max: float, z_min: float, z_max: float, metres_per_pixel: float
    ) -> IpmGrid:
        """Grid covering [x_min, x_max] × [z_min, z_max] metres at the given resolution."""
        if metres_per_pixel <= 0:
            raise ValueError(f"IPM metres_per_pixel must be > 0, got {metres_per_pixel}")
        if x_max <= x_min or z_max <= z_min:
            raise ValueError(
                f"IPM extent is empty: x [{x_min}, {x_max}], z [{z_min}, {z_max}] metres"
            )
        width = int(np.floor((x_max - x_min) / metres_per_pixel)) + 1
        height = int(np.floor((z_max - z_min) / metres_per_pixel)) + 1
        return cls(x_min, z_max, metres_per_pixel, width, height)

    def ground_from_pixel_matrix(self) -> FloatArray:
        """3×3 affine map from IPM pixels (u, v, 1) to ground (X, Z, 1)."""
        s = self.metres_per_pixel
        return np.array([[s, 0.0, self.x_min], [0.0, -s, self.z_max], [0.0, 0.0, 1.0]])

    def pixel_from_ground(self, ground_xz: ArrayLike) -> FloatArray:
        """IPM pixel coordinates (..., 2) of ground points (..., 2) [m]."""
        g = np.asarray(ground_xz, dtype=float)
        s = self.metres_per_pixel
        return np.stack([(g[..., 0] - self.x_min) / s, (self.z_max - g[..., 1]) / s], axis=-1)

    def ground_from_pixel(self, pixels: ArrayLike) -> FloatArray:
        """Ground points (..., 2) [m] of IPM pixel coordinates (..., 2)."""
        p = np.asarray(pixels, dtype=float)
        s = self.metres_per_pixel
        return np.stack([self.x_min + p[..., 0] * s, self.z_max - p[..., 1] * s], axis=-1)


# --- rotations ------------------------------------------------------------------------------


def rot_x(angle: float) -> FloatArray:
    """Rotation about +x by ``angle`` radians (right-handed)."""
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def rot_y(angle: float) -> FloatArray:
    """``Ry(a) = [[cos,0,sin],[0,1,0],[-sin,0,cos]]`` (CONVENTIONS.md)."""
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def rot_z(angle: float) -> FloatArray:
    """``Rz(a) = [[cos,-sin,0],[sin,cos,0],[0,0,1]]`` (CONVENTIONS.md)."""
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def rotation_ground_from_camera(pitch: ArrayLike, roll: ArrayLike) -> FloatArray:
    """R_GC = Rx(-pitch) · Rz(roll): columns are the camera axes expressed in G; (3, 3) for
    scalar angles, (..., 3, 3) for arrays (broadcast), the product written out."""
    c, s = np.cos(np.asarray(pitch, dtype=float)), np.sin(np.asarray(pitch, dtype=float))
    cr, sr = np.cos(np.asarray(roll, dtype=float)), np.sin(np.asarray(roll, dtype=float))
    # filled element by element: np.stack's Python overhead dominated the small batches of
    # the bundle adjustment
    out = np.empty((*np.broadcast_shapes(c.shape, cr.shape), 3, 3))
    out[..., 0, 0], out[..., 0, 1], out[..., 0, 2] = cr, -sr, 0.0
    out[..., 1, 0], out[..., 1, 1], out[..., 1, 2] = c * sr, c * cr, s
    out[..., 2, 0], out[..., 2, 1], out[..., 2, 2] = -s * sr, -s * cr, c
    return out


def pose_from_rotation(r_gc: ArrayLike) -> tuple[float, float]:
    """Invert :func:`rotation_ground_from_camera`: (pitch, roll) radians of a rotation whose
    ground-frame heading has been removed (its optical axis has no x component in G)."""
    r = np.asarray(r_gc, dtype=float)
    # Third column (optical axis) = (0, sin p, cos p); first row = (cos r, -sin r, 0).
    pitch = np.arctan2(r[1, 2], r[2, 2])
    roll = np.arctan2(-r[0, 1], r[0, 0])
    return float(pitch), float(roll)


# --- projection ----------------------------------------------------------------------------


def image_from_ground_homography(k: ArrayLike, pose: GroundPose) -> FloatArray:
    """3×3 homography from ground (X, Z, 1) [m] to pixels: ``m ~ K R_GCᵀ (X, h, Z)``."""
    r = rotation_ground_from_camera(pose.pitch, pose.roll)
    lift = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, pose.height], [0.0, 1.0, 0.0]])
    return np.asarray(k, dtype=float) @ r.T @ lift


def ground_from_image_homography(k: ArrayLike, pose: GroundPose) -> FloatArray:
    """3×3 homography from pixels to ground (X, Z, 1) [m] (inverse of the above)."""
    return np.linalg.inv(image_from_ground_homography(k, pose))


def apply_homography(h: ArrayLike, points: ArrayLike) -> FloatArray:
    """Map points (..., 2) through a 3×3 homography; points mapped to infinity become NaN."""
    p = np.asarray(points, dtype=float)
    hm = np.asarray(h, dtype=float)
    w = hm[2, 0] * p[..., 0] + hm[2, 1] * p[..., 1] + hm[2, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        x = (hm[0, 0] * p[..., 0] + hm[0, 1] * p[..., 1] + hm[0, 2]) / w
        y = (hm[1, 0] * p[..., 0] + hm[1, 1] * p[..., 1] + hm[1, 2]) / w
    out = np.stack([x, y], axis=-1)
    out[w == 0] = np.nan
    return out


def rotation_parallax(
    k: ArrayLike, pixels_prev: ArrayLike, pixels_curr: ArrayLike
) -> tuple[FloatArray, float]:
    """What a pure camera rotation leaves of a matched displacement field.

    Fits the rotation R whose infinite homography ``K R K⁻¹`` best maps ``pixels_prev``
    (N, 2) onto ``pixels_curr`` (N, 2) (least squares on the unit rays, refitted on the better
    half against outliers) and returns each match's distance to it in pixels (N,) and the
    rotation angle [rad]. Translation shows only in this parallax: without it the pose
    against the ground is unobservable."""
    kk = np.asarray(k, dtype=float)
    k_inv = np.linalg.inv(kk)
    prev = np.asarray(pixels_prev, dtype=float)
    curr = np.asarray(pixels_curr, dtype=float)

    def rays(p: FloatArray) -> FloatArray:
        r = np.concatenate([p, np.ones((len(p), 1))], axis=1) @ k_inv.T
        return r / np.linalg.norm(r, axis=1, keepdims=True)

    a, b = rays(prev), rays(curr)
    use = np.ones(len(a), bool)
    for _ in range(2):
        u, _s, vt = np.linalg.svd(a[use].T @ b[use])
        d = np.sign(np.linalg.det(u @ vt))
        rot = (u @ np.diag([1.0, 1.0, d]) @ vt).T  # b ≈ rot · a (Kabsch)
        residual = np.linalg.norm(apply_homography(kk @ rot @ k_inv, prev) - curr, axis=1)
        use = residual <= np.median(residual)
    angle = float(np.arccos(np.clip(0.5 * (np.trace(rot) - 1.0), -1.0, 1.0)))
    return residual, angle


def homography_jacobian(h: ArrayLike, points: ArrayLike) -> FloatArray:
    """Jacobians (..., 2, 2) of the map of a 3×3 homography at points (..., 2):
    d(output)/d(input), rows the output coordinates; NaN where a point maps to infinity."""
    p = np.asarray(points, dtype=float)
    hm = np.asarray(h, dtype=float)
    m = p @ hm[:2, :2].T + hm[:2, 2]  # numerators (..., 2)
    w = p @ hm[2, :2] + hm[2, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        jac = (hm[:2, :2] * w[..., None, None] - m[..., :, None] * hm[2, :2]) / (
            w[..., None, None] ** 2)
    jac[w == 0] = np.nan
    return jac


def project(k: ArrayLike, pose: GroundPose, ground_xz: ArrayLike) -> FloatArray:
    """π: pixels (..., 2) of ground points (..., 2) [m] in G. Points behind the camera
    (non-positive depth) give NaN."""
    g = np.asarray(ground_xz, dtype=float)
    r = rotation_ground_from_camera(pose.pitch, pose.roll)
    p_c = np.stack([g[..., 0], np.full(g.shape[:-1], pose.height), g[..., 1]], axis=-1) @ r
    uvw = p_c @ np.asarray(k, dtype=float).T
    with np.errstate(divide="ignore", invalid="ignore"):
        pix = uvw[..., :2] / uvw[..., 2:3]
    pix[p_c[..., 2] <= 0] = np.nan
    return pix


def back_project(k: ArrayLike, pose: GroundPose, pixels: ArrayLike) -> FloatArray:
    """π⁻¹: ground points (..., 2) [m] in G seen at pixels (..., 2).

    Pixels on or above the horizon (their ray never meets the ground in front of the
    camera) give NaN; use :func:`below_horizon` for the mask.
    """
    rays = _rays_in_ground(k, pose, pixels)
    with np.errstate(divide="ignore", invalid="ignore"):
        scale = pose.height / rays[..., 1]
    out = np.stack([rays[..., 0] * scale, rays[..., 2] * scale], axis=-1)
    out[~(rays[..., 1] > 0)] = np.nan
    return out


def below_horizon(
    k: ArrayLike, pose: GroundPose, pixels: ArrayLike, margin: float = 0.0
) -> NDArray[np.bool_]:
    """True where a pixel's ray meets the ground; ``margin`` demands a ray elevation of at
    least that many radians below the horizon."""
    rays = _rays_in_ground(k, pose, pixels)
    norm = np.linalg.norm(rays, axis=-1)
    return rays[..., 1] > np.sin(margin) * norm


def horizon_row(k: ArrayLike, pose: GroundPose, u: float) -> float:
    """Image row v of the horizon at column u (pixels); ground lies below (larger v)."""
    kinv = np.linalg.inv(np.asarray(k, dtype=float))
    r = rotation_ground_from_camera(pose.pitch, pose.roll)
    # Ray y-component in G is linear in (u, v): n · (u, v, 1) = 0 with n = (R K⁻¹)ᵀ[1].
    n = (r @ kinv)[1]
    if abs(n[1]) < 1e-15:
        return float("-inf") if n[0] * u + n[2] > 0 else float("inf")
    return float(-(n[0] * u + n[2]) / n[1])


def _rays_in_ground(k: ArrayLike, pose: GroundPose, pixels: ArrayLike) -> FloatArray:
    p = np.asarray(pixels, dtype=float)
    kinv = np.linalg.inv(np.asarray(k, dtype=float))
    r = rotation_ground_from_camera(pose.pitch, pose.roll)
    m = np.stack([p[..., 0], p[..., 1], np.ones(p.shape[:-1])], axis=-1)
    return m @ (r @ kinv).T


# --- planar motion -------------------------------------------------------------------------


def motion_matrix(motion: PlanarMotion) -> FloatArray:
    """T(Ψ): 3×3 map of ground points (X, Z, 1) from G_{k-1} to G_k."""
    c, s = np.cos(motion.yaw), np.sin(motion.yaw)
    # Ry(yaw)ᵀ restricted to (X, Z): [[c, -s], [s, c]].
    rot = np.array([[c, -s], [s, c]])
    t = -rot @ np.array([motion.tx, motion.tz])
    return np.array([[c, -s, t[0]], [s, c, t[1]], [0.0, 0.0, 1.0]])


def transform_ground(motion: PlanarMotion, ground_xz: ArrayLike) -> FloatArray:
    """Ground points (..., 2) of G_{k-1} expressed in G_k (``motion_matrix`` applied
    point-wise; written out, as the tracking runs are sensitive to its last bits)."""
    g = np.asarray(ground_xz, dtype=float)
    c, s = np.cos(motion.yaw), np.sin(motion.yaw)
    dx, dz = g[..., 0] - motion.tx, g[..., 1] - motion.tz
    return np.stack([c * dx - s * dz, s * dx + c * dz], axis=-1)


def compose_motion(first: PlanarMotion, second: PlanarMotion) -> PlanarMotion:
    """Motion G_a → G_c of ``first`` (G_a → G_b) followed by ``second`` (G_b → G_c)."""
    c, s = np.cos(first.yaw), np.sin(first.yaw)
    # Origin of G_c in G_b is (second.tx, second.tz); in G_a: Ry(first.yaw)·that + t_first.
    tx = first.tx + c * second.tx + s * second.tz
    tz = first.tz - s * second.tx + c * second.tz
    return PlanarMotion(tx, tz, first.yaw + second.yaw)


def invert_motion(motion: PlanarMotion) -> PlanarMotion:
    """Motion G_k → G_{k-1}, the inverse of ``motion``."""
    c, s = np.cos(motion.yaw), np.sin(motion.yaw)
    tx = -(c * motion.tx - s * motion.tz)
    tz = -(s * motion.tx + c * motion.tz)
    return PlanarMotion(tx, tz, -motion.yaw)


# --- two-frame maps ------------------------------------------------------------------------


def pair_homography(
    k: ArrayLike, pose_prev: GroundPose, pose_curr: GroundPose, motion: PlanarMotion
) -> FloatArray:
    """3×3 homography taking pixels of frame k-1 to pixels of frame k, for ground content.

    Uses ``pose_prev.height`` for both frames' back-projection and projection heights as
    given (the estimator assumes a constant height within the pair)."""
    return (
        image_from_ground_homography(k, pose_curr)
        @ motion_matrix(motion)
        @ ground_from_image_homography(k, pose_prev)
    )


def predict_pixels(
    k: ArrayLike,
    pose_prev: GroundPose,
    pose_curr: GroundPose,
    motion: PlanarMotion,
    pixels_prev: ArrayLike,
) -> FloatArray:
    """Pixels (..., 2) in frame k where ground seen at ``pixels_prev`` in frame k-1 appears."""
    ground_prev = back_project(k, pose_prev, pixels_prev)
    return project(k, pose_curr, transform_ground(motion, ground_prev))


def image_from_ipm_homography(k: ArrayLike, pose: GroundPose, grid: IpmGrid) -> FloatArray:
    """3×3 homography from IPM-grid pixels to camera pixels for ``pose``.

    Feed it to ``cv2.warpPerspective(img, H, (grid.width, grid.height),
    flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP)`` to render the bird's-eye image."""
    return image_from_ground_homography(k, pose) @ grid.ground_from_pixel_matrix()


def ipm_from_image_homography(k: ArrayLike, pose: GroundPose, grid: IpmGrid) -> FloatArray:
    """3×3 homography from camera pixels to IPM-grid pixels for ``pose``."""
    return np.linalg.inv(image_from_ipm_homography(k, pose, grid))
