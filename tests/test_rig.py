"""The rig (camera + nominal pose + height + readout) and the configuration that runs for it."""

from __future__ import annotations

import math
import re

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from vipm_track.errors import InputError
from vipm_track.estimator_config import (
    COLD_PITCH_STEPS_DEG,
    LEVEL_ROI_RANGE_H,
    EstimatorConfig,
    camera_kind,
    resolve,
)
from vipm_track.geometry import GroundPose
from vipm_track.rig import DEFAULT_PITCH_DEG, Rig
from vipm_track.sim import PRESETS

CAR = PRESETS["car"]  # a dashcam 3° down, 1.5 m up (horizon in view)
CART = PRESETS["cart"]  # the paper's rig, 45° down, 0.7 m up


@pytest.mark.parametrize(("field", "value", "message"), [
    ("height_m", 0.0, "rig: height_m must be a positive number of metres, got 0.0"),
    ("height_m", -1.5, "rig: height_m must be a positive"),
    ("height_m", math.nan, "rig: height_m must be a positive"),
    ("height_m", math.inf, "rig: height_m must be a positive"),
    ("height_m", "1.5", "rig: height_m must be a positive"),
    ("pitch_deg", math.nan, "rig: pitch_deg must be a number of degrees within ±90, got nan"),
    ("pitch_deg", -math.inf, "rig: pitch_deg must be a number of degrees within"),
    ("pitch_deg", 450.0, "rig: pitch_deg must be a number of degrees within ±90, got 450"),
    ("roll_deg", math.inf, "rig: roll_deg must be a number of degrees within ±90, got inf"),
    ("roll_deg", -90.5, "rig: roll_deg must be a number of degrees within ±90, got -90.5"),
    ("readout_s", -0.01, "rig: readout_s must be a number of seconds in [0, 1], got -0.01"),
    ("readout_s", math.nan, "rig: readout_s must be a number of seconds in [0, 1]"),
    ("readout_s", True, "rig: readout_s must be a number of seconds in [0, 1]"),
    ("readout_s", 5.0, "rig: readout_s must be a number of seconds in [0, 1], got 5.0"),
    # a path or nothing failed later inside the run with an AttributeError
    ("camera", None, "rig: camera must be a CameraModel (camera.load_camera(PATH)), got None"),
    ("camera", "calib.txt", "rig: camera must be a CameraModel"),
])
def test_bad_rig_names_the_field(field: str, value: object, message: str) -> None:
    fields = {"camera": CAR.camera(), "height_m": 1.5, "pitch_deg": 3.0, "roll_deg": 0.0,
              "readout_s": 0.0}
    with pytest.raises(InputError, match="^" + re.escape(message)):
        Rig(**{**fields, field: value})


@settings(max_examples=200, deadline=None)
@given(pitch=st.floats(-89.0, 89.0), roll=st.floats(-45.0, 45.0),
       height=st.floats(0.01, 100.0), readout=st.floats(0.0, 1.0))
def test_nominal_pose_is_the_rig_in_radians_and_back(pitch: float, roll: float, height: float,
                                                     readout: float) -> None:
    rig = Rig(CART.camera(), height, pitch, roll, readout)
    pose = rig.nominal_pose
    assert (pose.pitch, pose.roll) == pytest.approx(
        (math.radians(pitch), math.radians(roll)), rel=1e-15, abs=1e-300)
    assert pose.height == height
    back = pose.as_degrees()
    assert back == pytest.approx((pitch, roll, height), rel=1e-12, abs=1e-12)
    # each with_* changes its own fact and nothing else
    moved = rig.with_pose(back[0] + 1.0)
    assert (moved.pitch_deg, moved.roll_deg) == pytest.approx((pitch + 1.0, roll))
    assert moved.with_pose(pitch, roll).nominal_pose == pose
    assert moved.camera is rig.camera and moved.readout_s == readout
    higher = rig.with_height(2 * height)
    assert higher.nominal_pose == GroundPose(pose.pitch, pose.roll, 2 * height)
    global_shutter = rig.with_readout(0.0)
    assert global_shutter.readout_s == 0.0 and global_shutter.nominal_pose == pose


def test_resolve_gives_level_defaults_for_a_level_rig_and_steep_ones_for_a_steep_rig() -> None:
    config = EstimatorConfig()
    level = Rig(CAR.camera(), CAR.height_m, CAR.pitch_deg)
    steep = Rig(CART.camera(), CART.height_m, CART.pitch_deg)
    assert camera_kind(level) == (False, True)
    assert camera_kind(steep) == (True, False)
    on_level, on_steep = resolve(config, level), resolve(config, steep)
    assert (on_level.refinements, on_steep.refinements) == (2, 1)
    assert (on_level.vertical_motion, on_steep.vertical_motion) == (False, True)
    assert (on_level.pose_prior_deg, on_steep.pose_prior_deg) == (2.0, 0.0)
    assert (on_level.roi_max_range_h, on_steep.roi_max_range_h) == (LEVEL_ROI_RANGE_H, 15.0)
    assert on_level.cold_pitch_steps_deg == COLD_PITCH_STEPS_DEG["level"]
    assert on_steep.cold_pitch_steps_deg == COLD_PITCH_STEPS_DEG["steep"]
    assert (on_level.weight_patches, on_steep.weight_patches) == (False, True)
    # the same camera is steep where its nominal pose puts the horizon out of view, and
    # neither level nor steep 15° down (horizon in view, pitch above 10°)
    assert camera_kind(level.with_pose(DEFAULT_PITCH_DEG)) == (True, False)
    assert camera_kind(level.with_pose(15.0)) == (False, False)
    assert resolve(config, level.with_pose(15.0)).refinements == 1
    # the height and the readout do not decide the camera's kind
    assert resolve(config, level.with_height(0.5).with_readout(0.03)) == on_level
    # what the config sets is kept
    assert resolve(EstimatorConfig(refinements=3), steep).refinements == 3


@pytest.mark.parametrize(("fields", "message"), [
    # a float count ran the first pair, then failed inside the refinement
    ({"refinements": 1.5}, "refinements=1.5 (expected int | None)"),
    ({"refinements": 100}, "invalid refinements=100"),
    # a string is true: 'no' ran with vertical motion
    ({"vertical_motion": "no"}, "vertical_motion='no' (expected bool | None)"),
    ({"grid": (11.0, 9)}, "grid=(11.0, 9) (expected tuple[int, int])"),
    ({"inlier_px_ipm": "2"}, "inlier_px_ipm='2' (expected float)"),
])
def test_a_config_field_of_the_wrong_type_is_named(fields: dict, message: str) -> None:
    with pytest.raises(InputError, match=re.escape(message)):
        EstimatorConfig(**fields)


def test_numpy_scalars_are_numbers_and_resolve_names_what_it_got() -> None:
    import numpy as np

    config = EstimatorConfig(refinements=np.int64(2), vertical_motion=np.bool_(False),
                             grid=(np.int64(5), 4), inlier_px_ipm=np.float32(2.0))
    assert config.refinements == 2
    with pytest.raises(InputError, match="resolve needs an EstimatorConfig and a Rig, got "
                                         "NoneType and Rig"):
        resolve(None, Rig(CAR.camera(), 1.5, 3.0))  # type: ignore[arg-type]
