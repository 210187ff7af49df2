"""Nominal calibration files: the extrinsics a camera should have, with tolerances and
physical limits, as the drift monitor judges them (YAML; ``data/nominal_*.yaml``)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from numpy.typing import NDArray

from vipm_track.camera import CameraModel
from vipm_track.errors import InputError, InvalidYaml, parse_yaml
from vipm_track.rig import MAX_ANGLE_DEG, Rig, plausible_angle

FloatArray = NDArray[np.float64]


#: each field of ``NominalCalibration`` as the file names it
FILE_KEYS: dict[str, str] = {
    "pitch_deg": "pitch_deg", "roll_deg": "roll_deg", "height_m": "height_m",
    "pitch_tol_deg": "tolerances.pitch_deg", "roll_tol_deg": "tolerances.roll_deg",
    "height_tol_m": "tolerances.height_m", "max_angle_dev_deg": "limits.max_angle_dev_deg",
    "max_height_dev_frac": "limits.max_height_dev_frac",
}


@dataclass(frozen=True)
class NominalCalibration:
    """Nominal extrinsics with tolerances and physical limits (degrees / metres, as in files).

    Deviations within ``*_tol`` count as calibrated; beyond ``max_angle_dev_deg`` in pitch or
    roll, or a height off by more than ``max_height_dev_frac`` of nominal (or ≤ 0), the
    extrinsics are INVALID.
    """

    pitch_deg: float
    roll_deg: float
    height_m: float
    pitch_tol_deg: float = 0.1
    roll_tol_deg: float = 0.1
    height_tol_m: float = 0.005
    max_angle_dev_deg: float = 10.0
    max_height_dev_frac: float = 0.5

    def __post_init__(self) -> None:
        for name, key in FILE_KEYS.items():
            if not math.isfinite(getattr(self, name)):
                raise InputError(f"nominal calibration: {key} must be a finite number")
        for name in ("pitch_deg", "roll_deg"):
            if not plausible_angle(getattr(self, name)):
                raise InputError(f"nominal calibration: {name} must be within "
                                 f"±{MAX_ANGLE_DEG:g}°, got {getattr(self, name)}")
        if self.height_m <= 0:
            raise InputError(f"nominal calibration: height_m must be > 0, got {self.height_m}")
        for name in ("pitch_tol_deg", "roll_tol_deg", "height_tol_m"):
            if getattr(self, name) < 0:
                raise InputError(f"nominal calibration: {FILE_KEYS[name]} must be >= 0, got "
                                 f"{getattr(self, name)}")
        for name in ("max_angle_dev_deg", "max_height_dev_frac"):
            if getattr(self, name) <= 0:
                raise InputError(f"nominal calibration: {FILE_KEYS[name]} must be > 0, got "
                                 f"{getattr(self, name)}")

    def rig(self, camera: CameraModel, readout_s: float = 0.0) -> Rig:
        """``camera`` mounted at this nominal pitch, roll [deg] and height [m], with a
        rolling-shutter readout of ``readout_s`` [s]: the rig the estimator starts from."""
        return Rig(camera, self.height_m, self.pitch_deg, self.roll_deg, readout_s)

    @property
    def values(self) -> FloatArray:
        """(pitch rad, roll rad, height m)."""
        return np.array([math.radians(self.pitch_deg), math.radians(self.roll_deg), self.height_m])

    @property
    def tolerances(self) -> FloatArray:
        """(pitch rad, roll rad, height m)."""
        return np.array([math.radians(self.pitch_tol_deg), math.radians(self.roll_tol_deg),
                         self.height_tol_m])

    @property
    def limits(self) -> FloatArray:
        """Largest plausible |deviation| per axis: (rad, rad, m)."""
        a = math.radians(self.max_angle_dev_deg)
        return np.array([a, a, self.max_height_dev_frac * self.height_m])


def load_nominal(path: str | Path) -> NominalCalibration:
    """Read a nominal-calibration YAML file.

    Keys: ``pitch_deg``, ``roll_deg``, ``height_m`` (required); optional ``tolerances``
    mapping (``pitch_deg``, ``roll_deg``, ``height_m``) and ``limits`` mapping
    (``max_angle_dev_deg``, ``max_height_dev_frac``). Raises :class:`InputError` naming the
    file and the key.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: nominal calibration file not found")
    try:
        doc = parse_yaml(path.read_text(encoding="utf-8"))
    except UnicodeDecodeError as exc:
        raise InputError(f"{path}: not a text file (byte {exc.start}: {exc.reason})") from exc
    except InvalidYaml as exc:
        raise InputError(f"{path}: {exc}") from None
    if not isinstance(doc, dict):
        raise InputError(f"{path}: expected a mapping with pitch_deg, roll_deg, height_m")
    known = ("pitch_deg", "roll_deg", "height_m", "tolerances", "limits")
    unknown = sorted(str(k) for k in doc if k not in known)
    if unknown:
        raise InputError(f"{path}: unknown key(s) {unknown}; expected {sorted(known)}")

    def number(section: dict[str, Any], key: str, where: str) -> float:
        if isinstance(section.get(key), bool):  # YAML's true/yes: float() would take it as 1
            raise InputError(f"{path}: '{where}{key}' is not a number: {section[key]!r}")
        try:
            return float(section[key])
        except KeyError as exc:
            raise InputError(f"{path}: missing key '{where}{key}'") from exc
        except (TypeError, ValueError) as exc:
            raise InputError(f"{path}: '{where}{key}' is not a number: {section[key]!r}") from exc

    kwargs = {k: number(doc, k, "") for k in ("pitch_deg", "roll_deg", "height_m")}
    for section, keys in (
        ("tolerances", {"pitch_deg": "pitch_tol_deg", "roll_deg": "roll_tol_deg",
                        "height_m": "height_tol_m"}),
        ("limits", {"max_angle_dev_deg": "max_angle_dev_deg",
                    "max_height_dev_frac": "max_height_dev_frac"}),
    ):
        sub = doc.get(section) or {}
        if not isinstance(sub, dict):
            raise InputError(f"{path}: '{section}' must be a mapping")
        unknown = set(sub) - set(keys)
        if unknown:
            raise InputError(f"{path}: unknown key(s) {sorted(unknown)} in '{section}'; "
                             f"expected {sorted(keys)}")
        for key, attr in keys.items():
            if key in sub:
                kwargs[attr] = number(sub, key, f"{section}.")
    try:
        return NominalCalibration(**kwargs)
    except InputError as exc:
        raise InputError(f"{path}: {exc}") from exc


def write_nominal(nominal: NominalCalibration, path: str | Path) -> None:
    """Write ``nominal`` in the format ``load_nominal`` reads."""
    doc = {
        "pitch_deg": nominal.pitch_deg, "roll_deg": nominal.roll_deg,
        "height_m": nominal.height_m,
        "tolerances": {"pitch_deg": nominal.pitch_tol_deg, "roll_deg": nominal.roll_tol_deg,
                       "height_m": nominal.height_tol_m},
        "limits": {"max_angle_dev_deg": nominal.max_angle_dev_deg,
                   "max_height_dev_frac": nominal.max_height_dev_frac},
    }
    Path(path).write_text(yaml.safe_dump(doc, sort_keys=False))


__all__ = ["NominalCalibration", "load_nominal", "write_nominal"]
