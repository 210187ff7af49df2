"""Traffic scene: box vehicles drawn into the rendered ground, against independent maths.

The camera here is built with ``cv2.Rodrigues`` from the text of CONVENTIONS.md
(R_GC = Rx(−pitch)·Rz(roll), camera centre at (0, −h, 0) in G, a world point reaching G
through Ry(heading)ᵀ(P − (x, 0, z))) and box corners are projected with
``cv2.projectPoints``, not with the module's own chain.
"""

from __future__ import annotations

import itertools
from dataclasses import astuple

import cv2
import numpy as np
import pytest

from vipm_track.cli import main
from vipm_track.geometry import GroundPose
from vipm_track.render import Effects, render_frame
from vipm_track.sim import PRESETS, make_trajectory, preset_texture, render_trajectory_frame
from vipm_track.texture import GroundTexture
from vipm_track.traffic import LEVELS, Vehicle, draw_traffic, make_traffic

CAMERA = PRESETS["car"].camera()
GROUND = 30.0
EMPTY = -1000.0  # a canvas value no vehicle takes: what stays EMPTY is not covered


def _camera_from_world(pitch, roll, height, world_xz, heading):
    """(rvec, tvec) of world → camera, written from CONVENTIONS.md with cv2.Rodrigues."""
    r_gc = cv2.Rodrigues(np.array([-pitch, 0.0, 0.0]))[0] @ cv2.Rodrigues(
        np.array([0.0, 0.0, roll]))[0]
    r_wg = cv2.Rodrigues(np.array([0.0, heading, 0.0]))[0]
    r_cw = r_gc.T @ r_wg.T
    t_cw = -r_cw @ np.array([world_xz[0], 0.0, world_xz[1]]) - r_gc.T @ np.array(
        [0.0, -height, 0.0])
    return cv2.Rodrigues(r_cw)[0], t_cw


def _corners(v: Vehicle, t: float) -> np.ndarray:
    """The box's 8 world corners (y up is negative: into the ground is +y)."""
    z = v.z0_m + v.speed_mps * t
    return np.array([[v.x_m + sx * v.width_m / 2, -sy * v.height_m, z + sz * v.length_m / 2]
                     for sx in (-1, 1) for sy in (0, 1) for sz in (-1, 1)])


def _project(points, pose, world_xz, heading) -> np.ndarray:
    rvec, tvec = _camera_from_world(*pose, world_xz, heading)
    return cv2.projectPoints(points, rvec, tvec, CAMERA.k, np.zeros(5))[0].reshape(-1, 2)


def _flat_vehicle(x, z, grey=230.0, **kw) -> Vehicle:
    """A uniformly grey box (its faces' texture has zero gain)."""
    size = {"length_m": 4.5, "width_m": 1.8, "height_m": 1.5} | kw
    return Vehicle(0, "car", "ahead", x, z, 0.0, gain=0.0, offset=grey, **size)


def _coverage(vehicles, pose, world_xz, heading, t=0.0) -> np.ndarray:
    img = np.full((CAMERA.height, CAMERA.width), EMPTY, np.float32)
    return draw_traffic(img, vehicles, CAMERA, GroundPose(*pose), world_xz, heading, t)


# pose (pitch, roll, h), world (x, z), heading, vehicle (x, z)
CASES = {
    "ahead-rolled": ((np.radians(3.0), np.radians(1.5), 1.5), (0.7, 3.0), np.radians(4.0),
                     (1.2, 17.0)),
    "left-lane-pitched": ((np.radians(6.0), np.radians(-2.0), 1.3), (-0.4, -2.0),
                          np.radians(-3.0), (-3.5, 8.0)),
}


@pytest.mark.parametrize("case", list(CASES))
def test_silhouette_and_band_where_an_independent_projection_puts_them(case):
    pose, world_xz, heading, (vx, vz) = CASES[case]
    vehicle = _flat_vehicle(vx, vz)
    flat = GroundTexture(np.full((64, 64), GROUND), 0.01)
    fx = Effects(sky_level=GROUND)
    ground = render_frame(flat, CAMERA, GroundPose(*pose), world_xz, heading, fx)
    img = render_frame(flat, CAMERA, GroundPose(*pose), world_xz, heading, fx,
                       overlay=lambda im: draw_traffic(im, [vehicle], CAMERA, GroundPose(*pose),
                                                       world_xz, heading, 0.0))
    # The box's silhouette is the convex hull of its projected corners.
    hull = cv2.convexHull(_project(_corners(vehicle, 0.0), pose, world_xz, heading)
                          .astype(np.float32)).reshape(-1, 2).astype(float)
    v, u = np.mgrid[0:CAMERA.height, 0:CAMERA.width].astype(float)
    inside = np.full(u.shape, np.inf)
    area = 0.0
    for p, q in zip(hull, np.roll(hull, -1, axis=0), strict=True):
        area += p[0] * q[1] - p[1] * q[0]
    sign = np.sign(area)
    for p, q in zip(hull, np.roll(hull, -1, axis=0), strict=True):
        d = q - p
        # signed distance to the edge's line, > 0 on the hull's side
        inside = np.minimum(inside, sign * (d[0] * (v - p[1]) - d[1] * (u - p[0]))
                            / np.hypot(*d))
    assert (inside > 1.0).sum() > 2000
    assert np.all(img[inside > 1.0] >= 50)  # the darkest face texel: 0.3 · 0.82 · 230
    assert np.array_equal(img[inside < -1.0], ground[inside < -1.0])
    # Texture mapping: the dark band's top, 0.4 m above the ground on the back face.
    top = _project(np.array([[vx, -0.4, vz - 2.25]]), pose, world_xz, heading)[0]
    col = img[:, int(np.rint(top[0]))].astype(float)
    body, band = 0.95 * 230.0, 0.3 * 0.95 * 230.0
    rows = np.arange(int(top[1]) - 6, int(top[1]) + 7)
    assert col[rows[0]] == pytest.approx(body, abs=2) and col[rows[-1]] == pytest.approx(band,
                                                                                       abs=2)
    mid = 0.5 * (body + band)
    i = rows[np.argmax(col[rows] < mid)]
    crossing = i - 1 + (col[i - 1] - mid) / (col[i - 1] - col[i])
    assert abs(crossing - top[1]) < 0.5


def test_ahead_keeps_its_place_while_ground_and_oncoming_move():
    traj = make_trajectory("static", 11, preset="car", seed=1)
    cars = make_traffic("mix", seed=4, speed_mps=PRESETS["car"].speed_mps,
                        duration_s=float(traj.t[-1]))
    ahead = [v for v in cars if v.role == "ahead"]
    assert len(ahead) == 1
    gap = [ahead[0].z_at(t) - ahead[0].length_m / 2 - z
           for t, z in zip(traj.t, traj.world_xz[:, 1], strict=True)]
    assert 5.0 < min(gap) and max(gap) < 16.0
    oncoming = sorted((v for v in cars if v.role == "oncoming" and 20 < v.z0_m < 80),
                      key=lambda v: v.z0_m)[:1]
    assert oncoming

    def blob(vehicles, k):
        covered = _coverage(vehicles, astuple(traj.pose(k)), traj.world_xz[k],
                            float(traj.world_heading[k]), float(traj.t[k])) > EMPTY / 2
        ys, xs = np.nonzero(covered)
        return np.array([xs.mean(), ys.mean()]), covered.sum()

    (c0, n0), (c1, n1) = blob(ahead, 0), blob(ahead, 10)
    assert np.linalg.norm(c1 - c0) < 4.0 and abs(n1 / n0 - 1) < 0.1
    (o0, m0), (o1, m1) = blob(oncoming, 0), blob(oncoming, 10)
    assert np.linalg.norm(o1 - o0) > 20.0 and m1 > 1.3 * m0
    tex = preset_texture("car")
    g0, g1 = (render_trajectory_frame(tex, CAMERA, traj, k).astype(float) for k in (0, 10))
    assert np.mean(np.abs(g1[500:] - g0[500:])) > 10.0  # the ground below moves


def test_traffic_off_renders_the_ground_unchanged():
    traj = make_trajectory("shaking", 3, preset="car", seed=2)
    tex = preset_texture("car")
    fx = Effects(noise_sigma=2.0, vignetting=0.5, seed=3)
    plain = render_frame(tex, CAMERA, traj.pose(2), traj.world_xz[2],
                         float(traj.world_heading[2]), fx, t=float(traj.t[2]), frame_index=2)
    assert np.array_equal(render_trajectory_frame(tex, CAMERA, traj, 2, fx), plain)
    assert np.array_equal(render_trajectory_frame(tex, CAMERA, traj, 2, fx, ()), plain)
    cars = make_traffic("dense", seed=2, speed_mps=12.0, duration_s=float(traj.t[-1]))
    busy = render_trajectory_frame(tex, CAMERA, traj, 2, fx, cars)
    covered = _coverage(cars, astuple(traj.pose(2)), traj.world_xz[2],
                        float(traj.world_heading[2]), float(traj.t[2])) > EMPTY
    assert 0.05 < covered.mean() < 0.9
    assert np.array_equal(busy[~covered], plain[~covered])
    assert not np.array_equal(busy[covered], plain[covered])


def test_near_vehicle_hides_far_one_in_any_order():
    pose, world_xz, heading = (np.radians(3.0), 0.0, 1.5), (0.0, 0.0), 0.0
    near = _flat_vehicle(0.3, 9.0, grey=100.0)
    far = _flat_vehicle(-0.2, 20.0, grey=200.0, length_m=9.0, width_m=2.5, height_m=3.4)
    alone = _coverage([near], pose, world_xz, heading)
    both = _coverage([far, near], pose, world_xz, heading)
    assert np.array_equal(both, _coverage([near, far], pose, world_xz, heading))
    solid = cv2.erode((alone > EMPTY / 2).astype(np.uint8), np.ones((3, 3), np.uint8)) > 0
    assert solid.sum() > 5000 and np.array_equal(both[solid], alone[solid])
    # The truck's upper part shows above the car, its lower part is hidden.
    far_alone = _coverage([far], pose, world_xz, heading)
    far_only = (far_alone > EMPTY / 2) & (alone == EMPTY)
    assert far_only.sum() > 1000
    assert np.array_equal(both[far_only], far_alone[far_only])


@pytest.mark.parametrize("level", LEVELS)
def test_layout_is_seeded_and_lanes_never_collide(level):
    cars = make_traffic(level, seed=9, speed_mps=10.0, duration_s=20.0)
    assert cars == make_traffic(level, seed=9, speed_mps=10.0, duration_s=20.0)
    assert cars != make_traffic(level, seed=10, speed_mps=10.0, duration_s=20.0)
    assert {"ahead", "beside", "oncoming", "parked"} <= {v.role for v in cars}
    assert any(v.kind == "truck" for v in cars if v.role == "beside")
    for t in np.linspace(0.0, 20.0, 41):
        for x in {v.x_m for v in cars}:
            lane = sorted((v.z_at(t), v.length_m) for v in cars if v.x_m == x)
            for (z0, l0), (z1, l1) in itertools.pairwise(lane):
                assert z1 - l1 / 2 - (z0 + l0 / 2) > 0.5


def test_cli_writes_traffic_and_leaves_ground_truth_alone(tmp_path):
    args = ["simulate", "--preset", "car", "--frames", "2", "--profile", "shaking"]
    assert main([*args, "--out", str(tmp_path / "plain")]) == 0
    assert main([*args, "--out", str(tmp_path / "busy"), "--traffic", "dense"]) == 0
    gt = [(tmp_path / d / "gt.csv").read_bytes() for d in ("plain", "busy")]
    assert gt[0] == gt[1]
    assert not (tmp_path / "plain" / "traffic.csv").exists()
    lines = (tmp_path / "busy" / "traffic.csv").read_text().splitlines()
    assert lines[0].startswith("frame,t,vehicle,kind,role,world_x_m,world_z_m,speed_mps")
    assert {line.split(",")[0] for line in lines[1:]} == {"0", "1"}
    imgs = [cv2.imread(str(tmp_path / d / "images" / "000001.png"), cv2.IMREAD_GRAYSCALE)
            for d in ("plain", "busy")]
    assert not np.array_equal(*imgs)
