"""vipm-track: camera-to-ground extrinsics and planar motion from a monocular vehicle camera."""

from .camera import CameraModel, load_camera
from .geometry import GroundPose, IpmGrid, PlanarMotion
from .rig import Rig

__all__ = ["CameraModel", "GroundPose", "IpmGrid", "PlanarMotion", "Rig", "load_camera"]
__version__ = "0.1.0"

