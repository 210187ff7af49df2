"""Box-shaped vehicles on a straight road, drawn into the ground renderer's image.

The road runs along the world z axis (the start of a simulated drive: world pose (0, 0),
heading 0; the world frame W has the axes of G, see render.py: x right, y into the ground,
z forward). Our lane is centred on x = 0, right-hand traffic, lanes ``LANE_M`` wide:

- ``ahead``: one vehicle in our lane at our nominal speed, a few metres ahead, its gap
  surging slowly by about a metre (nearly fixed in the image);
- ``beside``: the next lanes of our direction, x = −3.5 m (faster: overtaking us) and
  x = +3.5 m (slower, vans and trucks: we overtake them);
- ``oncoming``: the opposite lanes, x = −7 m and −10.5 m;
- ``parked``: standing vehicles at the right kerb, x = +6.3 m (and the left, x = −14 m).

A :class:`Vehicle` is a box standing on the ground whose centre moves along world z as
z(t) = z0 + v·t + a·sin(2πt/T + φ). :func:`draw_traffic` renders its upper five faces as
textured planar quads: for a face plane the map pixel → face texel is one homography (K,
the pose against the ground, the world pose of G, the vehicle's pose at time t), evaluated
with ``cv2.warpPerspective`` over the face's bounding box at ``supersample``× resolution
and masked by the face's polygon (clipped to z_C ≥ ``NEAR_M``). Occlusion is a z-buffer on
the supersampled grid (exact between faces of any vehicles, no seams where faces meet);
the grid is box-averaged down and blended over the ground, its coverage the anti-aliased
alpha. Vehicles are drawn at the frame's time (no motion blur, no rolling shutter).
"""

from __future__ import annotations

import functools
from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from .camera import CameraModel
from .geometry import GroundPose, rot_y, rotation_ground_from_camera
from .texture import TEXTURES, GroundTexture

LANE_M = 3.5
#: size of a face texel [m]
FACE_MPT = 0.01
#: near clipping plane [m] (camera z)
NEAR_M = 0.1
#: vehicles whose centre is farther from the camera are not drawn [m]
MAX_RANGE_M = 250.0
LEVELS: tuple[str, ...] = ("light", "mix", "dense")
#: columns of :func:`traffic_rows`
TRAFFIC_COLUMNS: tuple[str, ...] = (
    "frame", "t", "vehicle", "kind", "role", "world_x_m", "world_z_m", "speed_mps",
    "length_m", "width_m", "height_m",
)
#: length, width, height ranges [m] of each kind of box
KINDS: dict[str, tuple[tuple[float, float], ...]] = {
    "car": ((4.2, 4.8), (1.75, 1.85), (1.4, 1.6)),
    "van": ((5.0, 6.0), (1.95, 2.1), (2.0, 2.6)),
    "truck": ((8.0, 10.0), (2.45, 2.55), (3.1, 3.5)),
}


@dataclass(frozen=True)
class Vehicle:
    """A box on the ground moving along world z.

    ``x_m``: centre's world x [m]; ``z0_m``: centre's world z at t = 0 [m]; ``speed_mps``:
    mean velocity along world z [m/s] (< 0 oncoming); ``surge_m``, ``surge_period_s``,
    ``surge_phase``: the smooth oscillation a·sin(2πt/T + φ) added to z [m, s, rad];
    ``length_m``/``width_m``/``height_m``: box size along z/x/up [m]; ``facing``: +1 front
    towards +z, −1 towards −z; ``texture`` (a :data:`TEXTURES` name), ``gain``/``offset``
    (face grey = gain · texel + offset) and ``look_seed`` (where its faces are cut from the
    texture) fix its appearance.
    """

    ident: int
    kind: str
    role: str
    x_m: float
    z0_m: float
    speed_mps: float
    length_m: float
    width_m: float
    height_m: float
    facing: int = 1
    surge_m: float = 0.0
    surge_period_s: float = 10.0
    surge_phase: float = 0.0
    texture: str = "gravel"
    gain: float = 1.0
    offset: float = 0.0
    look_seed: int = 0

    def z_at(self, t: float) -> float:
        """World z [m] of the box centre at time t [s]."""
        w = 2 * np.pi / self.surge_period_s
        surge = self.surge_m * np.sin(w * t + self.surge_phase)
        return float(self.z0_m + self.speed_mps * t + surge)

    def speed_at(self, t: float) -> float:
        """Velocity along world z [m/s] at time t [s]."""
        w = 2 * np.pi / self.surge_period_s
        return float(self.speed_mps + self.surge_m * w * np.cos(w * t + self.surge_phase))


#: per level: ahead gap [m]; per lane: (role, x [m], speed offset to ours or −absolute
#: oncoming speed range [m/s], bumper gap range [m], weights of car/van/truck)
_LEVEL_SPECS: dict[str, tuple] = {
    "light": ((11.0, 15.0), (
        ("beside", -LANE_M, (3.0, 5.0), (50.0, 90.0), (0.8, 0.2, 0.0)),
        ("beside", LANE_M, (-4.0, -2.0), (60.0, 120.0), (0.3, 0.4, 0.3)),
        ("oncoming", -2 * LANE_M, (10.0, 16.0), (60.0, 120.0), (0.8, 0.15, 0.05)),
        ("parked", 6.3, None, (20.0, 60.0), (0.8, 0.2, 0.0)))),
    "mix": ((8.0, 13.0), (
        ("beside", -LANE_M, (2.0, 5.0), (20.0, 45.0), (0.7, 0.2, 0.1)),
        ("beside", LANE_M, (-4.0, -1.5), (15.0, 35.0), (0.3, 0.3, 0.4)),
        ("oncoming", -2 * LANE_M, (10.0, 16.0), (30.0, 60.0), (0.7, 0.2, 0.1)),
        ("oncoming", -3 * LANE_M, (10.0, 16.0), (40.0, 80.0), (0.7, 0.2, 0.1)),
        ("parked", 6.3, None, (3.0, 15.0), (0.8, 0.2, 0.0)))),
    "dense": ((5.5, 8.0), (
        ("beside", -LANE_M, (0.5, 2.0), (6.0, 12.0), (0.5, 0.3, 0.2)),
        ("beside", LANE_M, (-2.0, -0.5), (5.0, 10.0), (0.1, 0.3, 0.6)),
        ("oncoming", -2 * LANE_M, (4.0, 8.0), (8.0, 16.0), (0.6, 0.25, 0.15)),
        ("oncoming", -3 * LANE_M, (4.0, 8.0), (8.0, 16.0), (0.6, 0.25, 0.15)),
        ("parked", 6.3, None, (1.0, 4.0), (0.75, 0.25, 0.0)),
        ("parked", -14.0, None, (1.0, 5.0), (0.75, 0.25, 0.0)))),
}


def make_traffic(
    level: str = "mix", *, seed: int = 0, speed_mps: float = 12.0, duration_s: float = 10.0,
    window_m: tuple[float, float] = (-40.0, 160.0),
) -> tuple[Vehicle, ...]:
    """Vehicles of a traffic ``level`` (:data:`LEVELS`) for a drive at ``speed_mps`` [m/s]
    along world z from z = 0 lasting ``duration_s`` [s]: each lane holds vehicles wherever
    they come within ``window_m`` (metres behind/ahead of us at our nominal speed) during
    the drive. Deterministic from ``seed``."""
    if level not in _LEVEL_SPECS:
        raise ValueError(f"unknown traffic level '{level}'; choose one of {list(LEVELS)}")
    rng = np.random.default_rng([seed, 52711])
    v0, span = max(float(speed_mps), 0.0), max(float(duration_s), 0.0)
    gap_ahead, lanes = _LEVEL_SPECS[level]
    out = [_vehicle(rng, 0, "van" if level == "dense" else "car", "ahead", 0.0, v0, 1,
                    (0.5, 1.5), rng.uniform(*gap_ahead))]
    for role, x, dv, gap, weights in lanes:
        speed = 0.0 if role == "parked" else (-rng.uniform(*dv) if role == "oncoming"
                                              else max(v0 + rng.uniform(*dv), 0.0))
        rel = speed - v0
        lo = window_m[0] - max(rel, 0.0) * span
        hi = window_m[1] - min(rel, 0.0) * span
        rear = lo + rng.uniform(0.0, gap[1])
        # the slow lane's first vehicle ahead of us is a truck: one tall box beside us early
        truck_due = role == "beside" and x > 0
        while rear < hi:
            kind = str(rng.choice(list(KINDS), p=weights))
            if truck_due and rear > 0:
                kind, truck_due = "truck", False
            facing = -1 if role == "oncoming" else (int(rng.choice([-1, 1])) if role == "parked"
                                                    else 1)
            v = _vehicle(rng, len(out), kind, role, x, speed, facing,
                         (0.0, 0.0) if role == "parked" else (0.0, 0.4), rear)
            out.append(v)
            rear += v.length_m + rng.uniform(*gap)
    return tuple(out)


def _vehicle(rng: np.random.Generator, ident: int, kind: str, role: str, x: float,
             speed: float, facing: int, surge: tuple[float, float], rear: float) -> Vehicle:
    """A vehicle of ``kind`` with seeded size and looks whose rear (along its travel, for
    ``facing`` +1) is at world z = ``rear`` [m] at t = 0, plus a seeded surge in ``surge`` [m]."""
    (l0, l1), (w0, w1), (h0, h1) = KINDS[kind]
    length, bright = rng.uniform(l0, l1), rng.uniform(0.45, 1.3)
    return Vehicle(ident, kind, role, float(x), float(rear + length / 2), float(speed),
                   length, rng.uniform(w0, w1), rng.uniform(h0, h1), facing,
                   rng.uniform(*surge), rng.uniform(8.0, 16.0), rng.uniform(0, 2 * np.pi),
                   str(rng.choice(["gravel", "grass", "brick"])), bright,
                   rng.uniform(-20.0, 40.0) * bright, int(rng.integers(2**31)))


def traffic_rows(vehicles: Sequence[Vehicle], frame: int, t: float,
                 world_xz: tuple[float, float] | NDArray) -> list[dict]:
    """Rows of ``traffic.csv`` for frame ``frame`` at time ``t`` [s]: the vehicles within
    ``MAX_RANGE_M`` of the camera's world (x, z) [m], with their world position [m],
    velocity along world z [m/s] and size [m]."""
    rows = []
    for v in vehicles:
        z = v.z_at(t)
        if np.hypot(v.x_m - world_xz[0], z - world_xz[1]) <= MAX_RANGE_M:
            rows.append({"frame": frame, "t": t, "vehicle": v.ident, "kind": v.kind,
                         "role": v.role, "world_x_m": v.x_m, "world_z_m": z,
                         "speed_mps": v.speed_at(t), "length_m": v.length_m,
                         "width_m": v.width_m, "height_m": v.height_m})
    return rows


def draw_traffic(
    img: NDArray[np.float32], vehicles: Sequence[Vehicle], camera: CameraModel,
    pose: GroundPose, world_xz: tuple[float, float] | NDArray, world_heading: float,
    t: float, *, supersample: int = 3,
) -> NDArray[np.float32]:
    """``img`` (the ideal pinhole image of ``camera``, grey float32, modified in place and
    returned) with the vehicles at time ``t`` [s] drawn over it, seen from the camera at
    ``pose`` against the ground whose G has world pose ``world_xz`` [m], ``world_heading``
    [rad] (render.py's module doc)."""
    ss = max(1, int(supersample))
    k = camera.k
    r_gc = rotation_ground_from_camera(pose.pitch, pose.roll)
    # P_C = R_GCᵀ (Ry(heading)ᵀ (P_W − (x, 0, z)) − (0, −h, 0))  (CONVENTIONS.md)
    r_cw = r_gc.T @ rot_y(world_heading).T
    t_cw = -r_cw @ np.array([world_xz[0], 0.0, world_xz[1]]) + r_gc.T @ [0.0, pose.height, 0.0]
    faces = []
    for v in vehicles:
        centre = np.array([v.x_m, 0.0, v.z_at(t)])
        if np.hypot(*(centre - [world_xz[0], 0.0, world_xz[1]])[[0, 2]]) > MAX_RANGE_M:
            continue
        r_cv = r_cw @ rot_y(0.0 if v.facing > 0 else np.pi)
        o_v = r_cw @ centre + t_cw
        for i, (o, e1, e2, w, h, n) in enumerate(_box_faces(v)):
            o_c, e1_c, e2_c, n_c = r_cv @ o + o_v, r_cv @ e1, r_cv @ e2, r_cv @ n
            if n_c @ o_c > -1e-6:  # back-facing or edge-on (the plane holds the camera)
                continue
            quad = np.array([o_c, o_c + w * e1_c, o_c + w * e1_c + h * e2_c, o_c + h * e2_c])
            poly = _clip_near(quad)
            if len(poly) < 3:
                continue
            uv = (poly @ k.T)[:, :2] / poly[:, 2:]
            x0, y0 = np.maximum(np.floor(uv.min(axis=0)).astype(int) - 1, 0)
            x1 = min(int(np.ceil(uv[:, 0].max())) + 2, camera.width)
            y1 = min(int(np.ceil(uv[:, 1].max())) + 2, camera.height)
            if x1 > x0 and y1 > y0:
                faces.append((v, i, o_c, e1_c, e2_c, n_c, uv, (x0, y0, x1, y1)))
    if not faces:
        return img
    boxes = np.array([f[-1] for f in faces])
    rx0, ry0 = boxes[:, :2].min(axis=0)
    rx1, ry1 = boxes[:, 2:].max(axis=0)
    inv_depth = np.zeros(((ry1 - ry0) * ss, (rx1 - rx0) * ss), np.float32)
    grey = np.zeros_like(inv_depth)
    k_inv = np.linalg.inv(k)
    for v, i, o_c, e1_c, e2_c, n_c, uv, (x0, y0, x1, y1) in faces:
        bw, bh = (x1 - x0) * ss, (y1 - y0) * ss
        # supersample (i, j) of the face's box ↔ image pixel (x0 + (i + ½)/ss − ½, …)
        sub = np.array([[1 / ss, 0, x0 + 0.5 / ss - 0.5], [0, 1 / ss, y0 + 0.5 / ss - 0.5],
                        [0, 0, 1.0]])
        # texel (i, j) is centred on face point ((i + ½)·FACE_MPT, (j + ½)·FACE_MPT)
        img_from_texel = k @ np.column_stack([FACE_MPT * e1_c, FACE_MPT * e2_c,
                                              o_c + 0.5 * FACE_MPT * (e1_c + e2_c)])
        texel_from_sub = np.linalg.inv(img_from_texel) @ sub
        pyramid = _face_images(v)[i]
        centre = (uv.mean(axis=0) - [x0, y0] + 0.5) * ss - 0.5
        level = _mip_level(texel_from_sub, centre, len(pyramid))
        scale = 2.0**-level
        lev = np.array([[scale, 0, 0.5 * scale - 0.5], [0, scale, 0.5 * scale - 0.5], [0, 0, 1]])
        warped = cv2.warpPerspective(pyramid[level], lev @ texel_from_sub, (bw, bh),
                                     flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                                     borderMode=cv2.BORDER_REPLICATE)
        mask = np.zeros((bh, bw), np.uint8)
        pts = np.round(((uv - [x0, y0] + 0.5) * ss - 0.5) * 256).astype(np.int32)
        cv2.fillPoly(mask, [pts], 1, lineType=cv2.LINE_8, shift=8)
        # 1/z on the face plane n·P = n·O is linear in the pixel: (n·K⁻¹ m) / (n·O)
        q = (k_inv.T @ n_c) / (n_c @ o_c) @ sub
        jj, ii = np.arange(bh, dtype=np.float32), np.arange(bw, dtype=np.float32)
        iz = (q[0] * ii)[None, :] + (q[1] * jj + q[2])[:, None]
        sl = np.s_[(y0 - ry0) * ss:(y1 - ry0) * ss, (x0 - rx0) * ss:(x1 - rx0) * ss]
        nearer = mask.view(bool) & (iz > inv_depth[sl])
        np.copyto(inv_depth[sl], iz, where=nearer)
        np.copyto(grey[sl], warped, where=nearer)
    size = (int(rx1 - rx0), int(ry1 - ry0))
    alpha = cv2.resize((inv_depth > 0).astype(np.float32), size, interpolation=cv2.INTER_AREA)
    colour = cv2.resize(grey, size, interpolation=cv2.INTER_AREA)
    region = img[ry0:ry1, rx0:rx1]
    region *= 1.0 - alpha
    region += colour
    return img


def _box_faces(v: Vehicle) -> list[tuple[NDArray, NDArray, NDArray, float, float, NDArray]]:
    """The box's faces in its own frame (x right, y down, z forward, origin at the centre
    of its footprint): (top-left corner as seen from outside, unit right, unit down, width
    [m], height [m], outward normal) for back, front, left, right, roof."""
    a, b, hh = v.length_m / 2, v.width_m / 2, v.height_m
    x, y, z = np.eye(3)
    return [
        (np.array([-b, -hh, -a]), x, y, v.width_m, hh, -z),    # back
        (np.array([b, -hh, a]), -x, y, v.width_m, hh, z),      # front
        (np.array([-b, -hh, a]), -z, y, v.length_m, hh, -x),   # left side
        (np.array([b, -hh, -a]), z, y, v.length_m, hh, x),     # right side
        (np.array([-b, -hh, a]), x, -z, v.width_m, v.length_m, -y),  # roof
    ]


def _clip_near(poly: NDArray) -> NDArray:
    """The polygon (N, 3), camera frame, clipped to z ≥ NEAR_M (Sutherland–Hodgman)."""
    out = []
    for p, q in zip(poly, np.roll(poly, -1, axis=0), strict=True):
        if p[2] >= NEAR_M:
            out.append(p)
        if (p[2] >= NEAR_M) != (q[2] >= NEAR_M):
            out.append(p + (NEAR_M - p[2]) / (q[2] - p[2]) * (q - p))
    return np.array(out).reshape(-1, 3)


def _mip_level(h: NDArray, at: NDArray, n_levels: int) -> int:
    """Pyramid level whose texels are about one supersample wide where ``h`` (supersample
    → texel) maps the point ``at``."""
    p = np.array([[at[0], at[1], 1.0], [at[0] + 1, at[1], 1.0], [at[0], at[1] + 1, 1.0]]) @ h.T
    p = p[:, :2] / p[:, 2:]
    foot = max(np.linalg.norm(p[1] - p[0]), np.linalg.norm(p[2] - p[0]), 1e-9)
    return int(np.clip(np.round(np.log2(foot)), 0, n_levels - 1))


@functools.lru_cache(maxsize=3)
def _panel(name: str) -> NDArray[np.uint8]:
    """A 1024² texel canvas of a named photo texture at ``FACE_MPT``."""
    recipe = TEXTURES[name]
    canvas = GroundTexture.from_photo(recipe.photo, FACE_MPT, tiles=4, seed=7, recipe=recipe)
    return canvas.levels[0]


@functools.lru_cache(maxsize=1024)
def _face_images(v: Vehicle) -> tuple[list[NDArray[np.uint8]], ...]:
    """Mip pyramids (uint8, texel (i, j) centred on face point (i + ½, j + ½)·FACE_MPT from its
    top-left) of
    the faces of :func:`_box_faces`: the vehicle's texture, brightness, per-face shading (a
    box reads as a solid), glass (darker, less contrast) and a dark band at the bottom
    (wheels, shadow: POC sees structure there)."""
    panel = _panel(v.texture)
    rng = np.random.default_rng(v.look_seed)
    shades = (0.95, 1.0, 0.82, 0.82, 1.12)
    out = []
    for i, (_, _, _, w, h, _) in enumerate(_box_faces(v)):
        # sides padded to multiples of 64 texels: each pyramid level halves exactly (the
        # face's polygon, not the image's edge, bounds what is drawn)
        cols, rows = (-(-int(np.ceil(x / FACE_MPT)) // 64) * 64 for x in (w, h))
        oy, ox = rng.integers(0, panel.shape[0], 2)
        tex = panel[np.ix_((oy + np.arange(rows)) % panel.shape[0],
                           (ox + np.arange(cols)) % panel.shape[1])].astype(np.float32)
        face = (v.gain * tex + v.offset) * shades[i]
        s, d = (np.arange(cols) + 0.5) * FACE_MPT, (np.arange(rows)[:, None] + 0.5) * FACE_MPT
        if i < 4:
            # glass: all round a car or van's upper part; a truck's cab windscreen only
            top, depth = (0.08, 0.42 * h) if v.kind != "truck" else (0.5, min(1.3, 0.4 * h))
            inset = 0.3 if v.kind != "truck" or i == 1 else np.inf
            glass = (d >= top) & (d <= top + depth) & (s >= inset) & (s <= w - inset)
            face = np.where(glass, 0.35 * face + 15.0, face)
            face = np.where(d >= h - 0.4, 0.3 * face, face)
        level = np.clip(np.rint(face), 0, 255).astype(np.uint8)
        pyramid = [level]
        while all(n % 2 == 0 and n >= 8 for n in pyramid[-1].shape):
            p = pyramid[-1]
            pyramid.append(cv2.resize(p, (p.shape[1] // 2, p.shape[0] // 2),
                                      interpolation=cv2.INTER_AREA))
        out.append(pyramid)
    return tuple(out)
