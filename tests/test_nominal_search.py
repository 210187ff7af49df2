"""Finding the cold start's nominal pose when no --pitch is given (vipm_track.nominal_search)."""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import pytest

from tests.conftest import shared_data
from vipm_track.camera import load_camera, write_ros_yaml
from vipm_track.cli import main
from vipm_track.estimator_config import EstimatorConfig
from vipm_track.nominal_search import (
    GROUND_AGREE_DEG,
    TRAVEL_PAIRS,
    _stretches,
    search_nominal_pose,
    travel_pitch_over,
)
from vipm_track.rig import DEFAULT_PITCH_DEG, Rig
from vipm_track.sim import (
    PRESETS,
    make_trajectory,
    preset_texture,
    render_trajectory_frame,
    simulate_sequence,
)
from vipm_track.sources import ArraySource, Frame, FrameSource, open_source
from vipm_track.traffic import make_traffic
from vipm_track.travel_direction import pitch_from_travel


def _rig(camera, preset) -> Rig:
    """``camera`` at the preset's height, nominally at the default (paper's) 60° pitch."""
    return Rig(camera, preset.height_m, DEFAULT_PITCH_DEG)

def _render(folder: Path, preset_name: str, frames: int, pitch_deg: float | None = None,
            profile: str = "shaking"):
    preset = PRESETS[preset_name]
    if pitch_deg is not None:
        preset = replace(preset, pitch_deg=pitch_deg)
    traj = simulate_sequence(preset, frames, folder, seed=3, profile=profile)
    return preset, preset.camera(), traj


@pytest.mark.parametrize("pitch_deg", [3.0, 0.5, 20.0])
def test_forward_and_mid_cameras_get_their_pitch(tmp_path, pitch_deg):
    # the default cold start (60°) fails on these; the search converges near the truth
    preset, camera, traj = _render(tmp_path, "car", 3, pitch_deg)
    found = search_nominal_pose(open_source(images=tmp_path / "images"),
                                _rig(camera, preset), EstimatorConfig())
    assert found is not None and found.default_pitch_deg == 60.0
    assert found.frames == (0, 1)
    assert abs(found.pitch_deg - math.degrees(traj.pitch[1])) < 0.5
    assert abs(found.measured_roll_deg - math.degrees(traj.roll[1])) < 2.0
    assert found.roll_deg == 0.0  # within the camber of level: the nominal stays level
    assert "--pitch" in found.line()


def test_untrackable_travel_does_not_contradict_a_level_camera(tmp_path):
    """A car at 25 m/s filmed at 10 fps (2.5 m per frame): the corners cannot be tracked, and
    the two pairs that fit an essential matrix point 75-86° off the axis, each its own way.
    That is no evidence against the level camera the ground fit finds (every pair was marked
    'no nominal pose' on it); travel that pairs agree on off the axis still is
    (test_cli_paths.py, a steep cart found level)."""
    preset = PRESETS["car"]
    traj = simulate_sequence(preset, 8, tmp_path, seed=5, profile="gradual", fps=10.0,
                             speed=25.0)
    found = search_nominal_pose(open_source(images=tmp_path / "images"),
                                _rig(preset.camera(), preset), EstimatorConfig())
    assert found is not None and found.determined, found and found.line()
    assert found.travel is not None and found.travel.off_axis_deg > 40.0
    assert abs(found.pitch_deg - math.degrees(traj.pitch[1])) < 2.0


def test_a_pose_one_pair_converges_to_is_not_the_cameras(tmp_path):
    """A cart at 45° and 5 m/s (0.52 m per frame): the default start fails, its travel cannot
    be measured (one pair of nine gave a direction), and from the 1° start one pair converged
    at pitch 4.6° that none of the other five converge from. That was taken as the nominal
    pose and printed `ok` rows 40° off; a pose that most pairs do not converge from is not
    determined."""
    preset = replace(PRESETS["cart"], pitch_deg=45.0)
    traj = simulate_sequence(preset, 12, tmp_path, seed=1, profile="gradual", speed=5.0)
    found = search_nominal_pose(open_source(images=tmp_path / "images"),
                                _rig(preset.camera(), preset), EstimatorConfig())
    if found is not None and found.determined:
        assert abs(found.pitch_deg - math.degrees(traj.pitch[1])) < 2.0, found.line()
    else:
        assert found is not None and "do not converge" in found.undetermined, found


@pytest.mark.parametrize(("seed", "profile", "speed", "within_deg"), [
    # 3.6 m/s: the start with the smallest residual on the first pair (1°) settles at pitch
    # -2.7° on 2 of 6 pairs, the right start's cold start having failed as a wrong minimum;
    # the other converging starts, then the stepped ones, are settled in turn (it had been
    # 'not determined', every pair lost)
    (1, "gradual", 3.6, 2.0),
    # 4.8 m/s: no plain start converges on the first pair, the 40° start stepped off its
    # pitch does; the steps are the camera type's (the config leaves them None), and reading
    # None as "no steps" lost the pose (no search result at all)
    (0, "static", 4.8, 1.0),
])
def test_a_fast_steep_cart_gets_its_pose_from_another_start(tmp_path, seed, profile, speed,
                                                             within_deg):
    """A cart at 45° whose first pair the default start and the best start do not solve:
    the search goes on to the starts that do."""
    preset = replace(PRESETS["cart"], pitch_deg=45.0)
    traj = simulate_sequence(preset, 8, tmp_path, seed=seed, profile=profile, fps=10.0,
                             speed=speed)
    found = search_nominal_pose(open_source(images=tmp_path / "images"),
                                _rig(preset.camera(), preset), EstimatorConfig())
    assert found is not None and found.determined, found and found.line()
    assert abs(found.pitch_deg - math.degrees(traj.pitch[1])) < within_deg, found.line()


def test_camera_near_the_default_pitch_keeps_it(tmp_path):
    preset, camera, _ = _render(tmp_path, "cart", 3, 58.0)
    assert search_nominal_pose(open_source(images=tmp_path / "images"),
                               _rig(camera, preset), EstimatorConfig()) is None


def test_camera_far_from_the_default_that_converges_gets_its_own_nominal(tmp_path, capsys):
    # a camera 36° down (shaking to 34°) converges from 60° on its first pair, but its pose
    # leaves the plausible window (max_deviation_deg 25° around the nominal) when it shakes
    # below 35°: with the nominal kept at 60° those pairs were rejected; moved to where the
    # first pair converged, none is
    from vipm_track.cli import main
    from vipm_track.table import read_table

    preset, camera, traj = _render(tmp_path, "cart", 12, 36.0)
    found = search_nominal_pose(open_source(images=tmp_path / "images"),
                                _rig(camera, preset), EstimatorConfig())
    assert found is not None and not found.default_failed
    assert found.start_pitch_deg == found.default_pitch_deg == 60.0
    assert abs(found.pitch_deg - 36.0) < 1.0
    assert "the cold start from 60° on frames 0-1 converged" in found.line()
    out = tmp_path / "est.csv"
    assert main(["estimate", "--images", str(tmp_path / "images"), "--camera",
                 str(tmp_path / "camera.yaml"), "--height", str(preset.height_m),
                 "--out", str(out)]) == 0
    assert "nominal pose now pitch 3" in capsys.readouterr().err
    est = read_table(out)
    assert list(est["status"][1:]) == ["ok"] * 11
    assert np.max(np.abs(est["pitch_deg"][1:] - np.degrees(traj.pitch[1:]))) < 0.1


def test_cli_without_pitch_estimates_a_forward_camera_as_with_it(tmp_path, capsys):
    # the command line has no --pitch: a car camera must work as if it had one
    from vipm_track.cli import main
    from vipm_track.table import read_table

    preset, _, traj = _render(tmp_path, "car", 5, profile="gradual")
    errors = {}
    for name, extra in (("searched", []), ("given", ["--pitch", "3"])):
        out = tmp_path / f"{name}.csv"
        assert main(["estimate", "--images", str(tmp_path / "images"), "--camera",
                     str(tmp_path / "camera.yaml"), "--height", str(preset.height_m),
                     "--out", str(out), *extra]) == 0
        est = read_table(out)
        assert list(est["status"][1:]) == ["ok"] * 4, name
        errors[name] = np.abs(est["pitch_deg"][1:] - np.degrees(traj.pitch[1:]))
    assert "converged to pitch" in capsys.readouterr().err
    assert np.median(errors["searched"]) < np.median(errors["given"]) + 0.05
    assert np.max(errors["searched"]) < 0.5



def test_kitti_without_pitch_finds_a_level_camera():
    # Real data: KITTI 07's camera is ~1° down. The candidate starts are scored alike; with
    # each start's own defaults the 12° one won by its eighth parameter (vertical motion) and
    # a self-tightening inlier threshold, and the run settled at 13.3° with the travel 47 %
    # short (the second minimum of a level camera: steeper pitch, shorter travel).
    data = shared_data("kitti07")
    source = open_source(images=data / "image_0", max_frames=12)
    rig = Rig(load_camera(data / "calib.txt"), 1.65, DEFAULT_PITCH_DEG)
    found = search_nominal_pose(source, rig, EstimatorConfig())
    assert found is not None and found.default_failed
    assert 0.0 < found.pitch_deg < 3.0
    assert found.roll_deg == 0.0


def _level_wide_rig():
    # a wide level camera high up (1280×960, 89° across, 2.29 m, pitch 1.3°): the 60° start's
    # patches cover the whole view, half of it sky that stands still while the ground moves
    return replace(PRESETS["car"], name="wide", height=960, fx=651.0, pitch_deg=1.3,
                   height_m=2.29, fps=15.0, speed_mps=14.4, metres_per_texel=0.01)


@pytest.mark.parametrize("forced_no_motion", [False, True])
def test_default_start_calling_a_moving_view_still_is_a_failed_start(
        tmp_path, monkeypatch, forced_no_motion: bool) -> None:
    """The 60° default start fails on this level view ("no motion": its patches sat on the
    sky; or "did not converge": which of the two is chaotic in the last bits, the sums'
    order on the machine's SIMD width), and the search finds the pitch from the other
    starts either way. ``forced_no_motion``: the default start's verdict on the first pair
    is made "no motion", so that the rule (a moving view the default calls still is a
    failed start, not a standing vehicle) is tested on every machine."""
    import vipm_track.nominal_search as search_module
    from vipm_track.estimator import TwoFrameEstimator
    from vipm_track.pair_chain import estimate_pair
    from vipm_track.pair_result import STATUS_NO_MOTION, STATUS_OK, PairResult
    from vipm_track.pipeline import prepare_image

    preset = _level_wide_rig()
    traj = simulate_sequence(preset, 3, tmp_path, seed=13, profile="gradual")
    camera = preset.camera()
    frames = list(open_source(images=tmp_path / "images"))
    before, image = (prepare_image(f, camera) for f in frames[:2])
    default = estimate_pair(TwoFrameEstimator(Rig(camera, preset.height_m, DEFAULT_PITCH_DEG)),
                            before, image, None)
    assert default.status != STATUS_OK
    calls = []

    def default_sees_no_motion(*args, **kwargs):
        calls.append(1)
        if len(calls) == 1:  # the default start on the first moving pair
            return PairResult(STATUS_NO_MOTION, "forced by the test")
        return estimate_pair(*args, **kwargs)

    if forced_no_motion:
        monkeypatch.setattr(search_module, "estimate_pair", default_sees_no_motion)
    found = search_nominal_pose(open_source(images=tmp_path / "images"),
                                _rig(camera, preset), EstimatorConfig())
    assert found is not None and found.default_failed and found.frames == (0, 1)
    assert abs(found.pitch_deg - math.degrees(traj.pitch[1])) < 0.5
    assert len(calls) > 1 or not forced_no_motion


def test_search_starts_where_a_drive_that_starts_standing_moves(tmp_path):
    # 20 frames standing (the first frame under fresh sensor noise each time), then moving:
    # the search looked at the first 12 frames only, found "no motion" in each and left the
    # run at the 60° default (every pair failed)
    import cv2

    preset, camera, traj = _render(tmp_path / "render", "car", 4, profile="gradual")
    rendered = sorted((tmp_path / "render" / "images").glob("*.png"))
    first = cv2.imread(str(rendered[0]), cv2.IMREAD_GRAYSCALE).astype(np.float32)
    folder = tmp_path / "images"
    folder.mkdir()
    rng = np.random.default_rng(0)
    for k in range(20):
        noisy = np.clip(first + rng.normal(0.0, 2.0, first.shape), 0, 255).astype(np.uint8)
        cv2.imwrite(str(folder / f"{k:06d}.png"), noisy)
    for k, path in enumerate(rendered[1:], start=20):
        (folder / f"{k:06d}.png").write_bytes(path.read_bytes())
    found = search_nominal_pose(open_source(images=folder, fps=preset.fps),
                                _rig(camera, preset), EstimatorConfig())
    assert found is not None and found.frames == (19, 20)
    assert abs(found.pitch_deg - math.degrees(traj.pitch[1])) < 0.5


def test_a_travel_pitch_that_sees_no_ground_leaves_the_pose_undetermined():
    # a narrow camera (±1.7° vertically) pitched 5° up by its direction of travel sees only
    # sky: the search says so rather than stopping the run on an empty region of interest
    from types import SimpleNamespace

    from vipm_track.camera import CameraModel
    from vipm_track.nominal_search import _from_travel
    from vipm_track.travel_direction import TravelPitch

    camera = CameraModel(np.array([[5000.0, 0, 200], [0, 5000.0, 150], [0, 0, 1]]), 400, 300)
    rig = Rig(camera, 1.5, DEFAULT_PITCH_DEG)
    travel = TravelPitch(-5.0, 6, 6, 0.1)
    found = _from_travel(rig, EstimatorConfig(), [SimpleNamespace(frames=(0, 1))], travel)
    assert not found.determined
    assert found.undetermined.startswith("at the direction of travel's pitch -5.0° the region")


class _RenderedOnDemand(FrameSource):
    """Frames ``start … start + count − 1`` of a trajectory, rendered as they are first read
    (``read``: the frames read, shared by its chunks)."""

    def __init__(self, traj, preset, start: int = 0, count: int | None = None, seed: int = 0,
                 vehicles=None) -> None:
        self.traj, self.preset, self.start = traj, preset, start
        self.count = len(traj) - start if count is None else count
        self.seed, self.vehicles = seed, vehicles
        self.read: dict[int, np.ndarray] = {}

    def __len__(self) -> int:
        return self.count

    def frames(self, position: int, count: int) -> _RenderedOnDemand:
        chunk = _RenderedOnDemand(self.traj, self.preset, self.start + position,
                                  max(0, min(count, self.count - position)), self.seed,
                                  self.vehicles)
        chunk.read = self.read
        return chunk

    def __iter__(self):
        texture, camera = preset_texture(self.preset, None, self.seed), self.preset.camera()
        for k in range(self.start, self.start + self.count):
            if k not in self.read:
                self.read[k] = render_trajectory_frame(texture, camera, self.traj, k, None,
                                                       self.vehicles)
            yield Frame(k, float(self.traj.t[k]), self.read[k], None, f"#{k}")


def test_the_travel_pitch_is_the_mounts_not_the_first_seconds():
    # A car whose body pitches ±2° about its 3° mount over 8 s: the first pairs of the drive
    # see the body's pitch (here 1.4-2.0° above the mount), pairs spread over the drive its
    # mount. The spread reads few frames: one pair per stretch. The ground fit that gives
    # the roll is spread likewise: on the first pairs its pitch (4.8°) disagreed with the
    # spread travel's (2.5°) by more than the 2° allowed, and the pose was not determined.
    preset = PRESETS["car"]
    traj = make_trajectory("gradual", 160, fps=20.0, preset=preset, seed=2)
    mount = preset.pitch_deg
    first_second = np.degrees(traj.pitch[:20]) - mount
    assert first_second.min() > 1.0, first_second
    source = _RenderedOnDemand(traj, preset)
    spread = travel_pitch_over(source, preset.camera(), 300)
    assert spread.determined, spread.reason
    assert abs(spread.pitch_deg - mount) < 0.6, spread
    assert len(source.read) < 80, len(source.read)
    first = travel_pitch_over(source.frames(0, 30), preset.camera(), 300)
    assert first.pitch_deg - mount > 1.2, first
    found = search_nominal_pose(source, _rig(preset.camera(), preset), EstimatorConfig())
    assert found is not None and found.determined, found
    assert abs(found.pitch_deg - mount) < 0.6, found.line()


@pytest.mark.parametrize(("pitch_deg", "roll_deg", "seed", "stands"), [
    (0.5, 0.5, 7, False),  # the ground fit settles on the vehicles
    (1.0, 0.0, 0, True),   # the ground fit's pose is the camera's
])
def test_a_ground_fit_far_from_the_scattered_travel_is_not_the_cameras(pitch_deg, roll_deg,
                                                                       seed, stands):
    # KITTI's camera (1241×376, f 718 px, 1.65 m) at 1 m/s in dense traffic, its body
    # pitching ±2° over the drive: the pairs' directions of travel scatter, so they give no
    # pitch, and the ground fit runs from the cold starts. On seed 7 it settles on the
    # vehicles (pitch -5.3°, roll 3.9°: every row `ok`, 5° off); on seed 0 near the truth.
    # The scattered travel still puts the pitch within a few degrees of the truth. Where the
    # ground fit lands is chaotic (seed 7, subset seeds 0-2 on one machine: -2.1°, -5.0°,
    # -7.6°; the last bits of a compiled sum move it): the rule is held on three draws.
    preset = replace(PRESETS["kitti"], pitch_deg=pitch_deg, roll_deg=roll_deg)
    traj = make_trajectory("gradual", 60, None, preset, seed, 1.0)
    cars = make_traffic("dense", seed=seed, duration_s=float(traj.t[-1]), speed_mps=1.0)
    source = _RenderedOnDemand(traj, preset, seed=seed, vehicles=cars)
    travel = travel_pitch_over(source, preset.camera(), 300)
    assert not travel.determined and "disagree" in travel.reason, travel
    truth = np.degrees(np.median(traj.pitch))
    if stands:
        found = search_nominal_pose(source, _rig(preset.camera(), preset), EstimatorConfig())
        assert found is not None and found.determined, found
        # single pairs at 0.06 camera heights per frame read a level camera's pitch low
        # (docs/kitti.md, "Slow driving"): -0.5° and 0.1° over subset seeds 0-2
        assert abs(found.pitch_deg - truth) < 2.0, found.line()
        return
    caught = 0
    for subset_seed in range(3):
        found = search_nominal_pose(source, _rig(preset.camera(), preset),
                                    EstimatorConfig(seed=subset_seed))
        assert found is not None
        at_roll = pitch_from_travel(list(travel.travels), math.radians(found.measured_roll_deg))
        apart = abs(found.pitch_deg - at_roll.pitch_deg)
        tolerance = GROUND_AGREE_DEG + 3.0 * at_roll.standard_error_deg
        if found.determined:  # the rule's bound holds for a pose it let stand ...
            assert apart <= tolerance, found.line()
        else:  # ... and one beyond it is the ground fit's, as reported
            assert apart > tolerance and "but the direction of travel over" in found.undetermined
            assert abs(found.pitch_deg - truth) > 3.0
            caught += 1
    assert caught >= 2  # the vehicles taken for the ground, caught in most draws


@pytest.mark.parametrize("frames, starts, length", [
    (100, list(range(0, 90, 6)), 12),   # 15 stretches of 6 frames, each read into the next
    (400, list(range(0, 300, 20)), 40),  # only the first 300 frames (the search's window)
    (44, None, None),                    # stretches under 3 frames: none
])
def test_travel_stretches_start_evenly_and_run_into_the_next(frames, starts, length):
    source = ArraySource(np.zeros((frames, 4, 4), np.uint8), np.arange(frames) / 10.0)
    parts = _stretches(source, TRAVEL_PAIRS, 300)
    if starts is None:
        assert parts is None
        return
    assert [p.first_index for p in parts] == starts
    window = min(frames, 300)
    assert [len(p) for p in parts] == [min(length, window - s) for s in starts]


def test_a_search_that_finds_nothing_says_why(tmp_path, capsys):
    """Frames of noise move (every pixel changes) but no start converges on them: the search
    returned None, as for a camera at the default pitch, and the run failed every pair
    without a word about the search."""
    preset = replace(PRESETS["cart"], width=240, height=180, fx=218.0)
    camera = preset.camera()
    rng = np.random.default_rng(0)
    (tmp_path / "images").mkdir()
    for k in range(4):
        cv2.imwrite(str(tmp_path / "images" / f"{k:06d}.png"),
                    rng.integers(0, 255, (180, 240), dtype=np.uint8))
    write_ros_yaml(camera, tmp_path / "camera.yaml")
    rc = main(["estimate", "--images", str(tmp_path / "images"), "--height", "0.7",
               "--readout-time", "0", "--fps", "10", "--out", str(tmp_path / "e.csv"),
               "--quiet"])
    err = capsys.readouterr().err
    assert rc == 1 and "the nominal pose was not found: no cold start (from 60°" in err, err
    assert "converged on the pairs of frames 0-1 (" in err
    assert "the run starts from the default pitch 60° (give --pitch/--roll" in err
