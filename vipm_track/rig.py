"""The camera rig: a camera and its nominal mounting on the vehicle (:class:`Rig`).

One place for each fact of the set-up the estimator rests on: the intrinsics, the nominal
pitch and roll of the camera against the ground (degrees, CONVENTIONS.md signs: pitch > 0
looking down, roll > 0 the image's right edge dipping toward the ground), its height above
the ground [m] and the rolling shutter's readout [s]. The estimator's settings
(``estimator_config.EstimatorConfig``) hold how it runs, never what the rig is.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from .camera import CameraModel
from .errors import InputError
from .geometry import GroundPose

#: the nominal pitch where nothing says otherwise: the paper's cold start, a steep camera
#: [deg]
DEFAULT_PITCH_DEG = 60.0
#: the nominal pitches a vehicle camera that sees the ground can have [deg]: from slightly up
#: (a forward camera) to straight down
PITCH_RANGE_DEG = (-10.0, 90.0)


#: the largest pitch or roll of a camera against the ground [deg]: straight down, or on its
#: side (a pitch of 450° is a typing error, not a camera)
MAX_ANGLE_DEG = 90.0
#: the longest rolling-shutter readout [s]: a frame read over more than a second is no
#: video camera's
MAX_READOUT_S = 1.0


def plausible_angle(deg: float) -> bool:
    """A finite pitch or roll within ±:data:`MAX_ANGLE_DEG`."""
    return _finite(deg) and abs(deg) <= MAX_ANGLE_DEG


@dataclass(frozen=True)
class Rig:
    """A camera and its nominal mounting.

    Attributes
    ----------
    camera : intrinsics (and distortion) of the camera.
    height_m : height of the camera centre above the ground [m]: the scale of every
        translation (CONVENTIONS.md).
    pitch_deg, roll_deg : nominal pose of the camera against the ground [deg]: where the
        estimator's cold start begins, which decides its region of interest and its
        level/steep defaults (``estimator_config.resolve``).
    readout_s : rolling shutter: time from the exposure of the image's first row to its
        last [s] (0: a global shutter).
    """

    camera: CameraModel
    height_m: float
    pitch_deg: float
    roll_deg: float = 0.0
    readout_s: float = 0.0

    def __post_init__(self) -> None:
        if not isinstance(self.camera, CameraModel):
            raise InputError(f"rig: camera must be a CameraModel (camera.load_camera(PATH)), "
                             f"got {self.camera!r:.80}")
        checks = (
            ("height_m", _finite(self.height_m) and self.height_m > 0,
             "must be a positive number of metres"),
            ("pitch_deg", plausible_angle(self.pitch_deg),
             f"must be a number of degrees within ±{MAX_ANGLE_DEG:g}"),
            ("roll_deg", plausible_angle(self.roll_deg),
             f"must be a number of degrees within ±{MAX_ANGLE_DEG:g}"),
            ("readout_s", _finite(self.readout_s) and 0 <= self.readout_s <= MAX_READOUT_S,
             f"must be a number of seconds in [0, {MAX_READOUT_S:g}]"),
        )
        for name, ok, why in checks:
            if not ok:
                raise InputError(f"rig: {name} {why}, got {getattr(self, name)!r}")

    @property
    def nominal_pose(self) -> GroundPose:
        """The nominal pose (pitch, roll [rad], height [m])."""
        return GroundPose(float(np.radians(self.pitch_deg)), float(np.radians(self.roll_deg)),
                          float(self.height_m))

    def with_pose(self, pitch_deg: float, roll_deg: float | None = None) -> Rig:
        """This rig at nominal pitch ``pitch_deg`` and roll ``roll_deg`` [deg] (None: its
        own roll)."""
        return dataclasses.replace(self, pitch_deg=float(pitch_deg), roll_deg=float(
            self.roll_deg if roll_deg is None else roll_deg))

    def with_height(self, height_m: float) -> Rig:
        """This rig at camera height ``height_m`` [m]."""
        return dataclasses.replace(self, height_m=float(height_m))

    def with_readout(self, readout_s: float) -> Rig:
        """This rig with a rolling-shutter readout of ``readout_s`` [s] (0: global shutter)."""
        return dataclasses.replace(self, readout_s=float(readout_s))


def _finite(value: object) -> bool:
    """Whether ``value`` is a finite real number (bools and strings are not)."""
    if isinstance(value, bool) or not isinstance(value, (int, float, np.floating, np.integer)):
        return False
    return math.isfinite(float(value))
