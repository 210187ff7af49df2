"""Shared fixtures: paths to the real data beside the checkout (skipped where absent)."""

from __future__ import annotations

from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SHARED_DATA = ROOT.parent / "shared" / "data"


def shared_data(*parts: str) -> Path:
    """Path under ../shared/data, or skip the test with a clear message if it is absent."""
    path = SHARED_DATA.joinpath(*parts)
    if not path.exists():
        pytest.skip(f"shared data not found at {path} (the real-data tests need ../shared/data)")
    return path


#: A 1280×720 pinhole camera (fx = fy = 900 px, no distortion) as a ROS camera_info YAML.
CAR_CAMERA_YAML = (
    "image_width: 1280\nimage_height: 720\ncamera_matrix: {rows: 3, cols: 3, data: "
    "[900, 0, 640, 0, 900, 360, 0, 0, 1]}\ndistortion_model: plumb_bob\n"
    "distortion_coefficients: {rows: 1, cols: 5, data: [0, 0, 0, 0, 0]}\n"
)


def write_drive_inputs(run, folder: Path) -> tuple[Path, Path, Path]:
    """Write a drive_sim run as the files a user gives the CLI: ``est.csv`` (estimates table),
    ``speed.csv`` (t,speed_mps) and ``cam.yaml`` (:data:`CAR_CAMERA_YAML`) in ``folder``."""
    from vipm_track.filters.wheel_speed import SpeedSeries, write_speed_csv
    from vipm_track.measurement import measurement_row
    from vipm_track.table import ESTIMATE_COLUMNS, write_table

    write_table(folder / "est.csv", [measurement_row(m) for m in run.measurements],
                ESTIMATE_COLUMNS)
    write_speed_csv(SpeedSeries(run.speed.t, run.speed.speed_mps), folder / "speed.csv")
    (folder / "cam.yaml").write_text(CAR_CAMERA_YAML)
    return folder / "est.csv", folder / "speed.csv", folder / "cam.yaml"


def stop_in_a_turn(seed: int = 0):
    """A ``drive_sim`` cart run turning at 14°/s (curvature 0.25/m at 1 m/s), braking to a 10 s
    stop (8–18 s) in the turn, then driving off straight (the last pairs before the stop
    still see ~1.4°/s); returns (run, first and last index of the stop)."""
    import numpy as np

    from vipm_track.filters.drive_sim import DriveConfig, DriveProfile, simulate_drive

    profile = DriveProfile(
        (0.0, 6.0, 8.0, 18.0, 20.0), (1.0, 1.0, 0.0, 0.0, 1.0), (0.25, 0.25, 0.25, 0.0, 0.0)
    )
    cfg = DriveConfig.preset("cart", duration_s=30.0, height_m=0.7, failure_fraction=0.0)
    run = simulate_drive(cfg, seed, profile)
    still = np.flatnonzero(run.truth.speed == 0.0)
    assert run.truth.t[still[-1]] - run.truth.t[still[0]] >= 9.9
    return run, still[0], still[-1]
