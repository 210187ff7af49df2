"""vipm-track: camera-to-ground extrinsics and planar motion from a monocular vehicle camera."""

import importlib.util
import sys
from pathlib import Path

from .camera import CameraModel, load_camera
from .geometry import GroundPose, IpmGrid, PlanarMotion

__all__ = ["CameraModel", "GroundPose", "IpmGrid", "PlanarMotion", "load_camera"]
__version__ = "0.1.0"


def _checkout_filters() -> None:
    """Make ``vipm_track.filters`` importable from a source checkout, where its folder
    ``filters/`` sits beside this package (the layout asked for); the wheel ships it inside
    the package (pyproject's ``package-dir``), where this finds it in place and does
    nothing. Registering the folder under its packaged name keeps one import path for
    both."""
    here = Path(__file__).resolve().parent
    folder = here.parent / "filters"
    name = f"{__name__}.filters"
    if (here / "filters").is_dir() or name in sys.modules or not (
            folder / "__init__.py").is_file():
        return
    spec = importlib.util.spec_from_file_location(
        name, folder / "__init__.py", submodule_search_locations=[str(folder)])
    if spec is None or spec.loader is None:
        return
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    spec.loader.exec_module(module)
    globals()["filters"] = module  # what the import system sets on a parent package


_checkout_filters()
