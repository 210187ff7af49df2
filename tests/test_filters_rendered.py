"""End to end on a rendered sequence: images → estimator → EKF / smoother / monitor through the
commands (``vipm-track estimate``, ``track --images``, ``smooth``, ``monitor``) with a
simulated wheel speed, the filtered mount checked against the renderer's ground truth.

The sequence is the sim's ``drift`` profile (cart preset): a slow linear mount drift under
1–3 Hz body shaking, so the raw per-frame pitch/roll are ~0.2° off the mount while the
filters must find the mount; the nominal height given to the commands is 2 % below the true
one, so only the wheel speed can bring the height right.
"""

from __future__ import annotations

import numpy as np
import pytest

from vipm_track.cli import main
from vipm_track.sim import PRESETS, simulate_sequence
from vipm_track.table import read_table

N_FRAMES = 40
SETTLE = 15  # frames (1.5 s at 10 fps) before the mount is scored
PRESET = PRESETS["cart"]
H_NOMINAL = PRESET.height_m / 1.02


@pytest.fixture(scope="module")
def seq(tmp_path_factory):
    out = tmp_path_factory.mktemp("rendered")
    simulate_sequence("cart", N_FRAMES, out, seed=3, profile="drift")
    return out


@pytest.fixture(scope="module")
def gt(seq):
    return read_table(seq / "gt.csv")


def _inputs(seq) -> list[str]:
    return ["--camera", str(seq / "camera.yaml"), "--height", f"{H_NOMINAL:.6f}"]


def _mount_errors(table, gt, prefix: str) -> dict[str, np.ndarray]:
    """Filtered-mount and raw-measurement errors against the true mount after SETTLE, deg."""
    rows = table["frame"].astype(int)
    keep = rows >= SETTLE
    out = {}
    for axis in ("pitch", "roll"):
        truth = gt[f"mount_{axis}_deg"][rows[keep]]
        out[axis] = table[f"{prefix}{axis}_deg"][keep] - truth
    return out


def _rms(x: np.ndarray) -> float:
    assert np.all(np.isfinite(x)), "filter output missing after settling"
    return float(np.sqrt(np.mean(x**2)))


@pytest.fixture(scope="module")
def estimates(seq, tmp_path_factory):
    est = tmp_path_factory.mktemp("est") / "est.csv"
    rc = main(["estimate", "--images", str(seq / "images"), *_inputs(seq), "--pitch", "45",
               "--out", str(est), "--quiet"])
    assert rc == 0
    return est


def test_drift_profile_ground_truth_separates_mount_and_body(gt):
    t = gt["t"]
    slope = np.polyfit(t, gt["mount_pitch_deg"], 1)[0]
    assert slope == pytest.approx(0.01, rel=1e-6)  # sim.DRIFT_RATE_DPS
    body = gt["pitch_deg"] - gt["mount_pitch_deg"]
    assert 0.15 < np.std(body) < 0.5 and abs(np.mean(body)) < 0.15
    assert np.allclose(gt["height_m"], gt["mount_height_m"])


def test_track_images_with_wheel_speed_finds_the_mount_and_height(seq, gt, tmp_path):
    out = tmp_path / "track.csv"
    rc = main(["track", "--images", str(seq / "images"), *_inputs(seq), "--pitch", "45",
               "--vehicle", "cart", "--speed-csv", str(seq / "speed.csv"),
               "--out", str(out), "--quiet", "--columns", "all"])
    assert rc == 0
    table = read_table(out)
    assert len(table["frame"]) == N_FRAMES
    assert np.sum(table["meas_status"] == "ok") >= N_FRAMES - 3
    filt = _mount_errors(table, gt, "mount_")
    raw = _mount_errors(table, gt, "meas_")
    for axis in ("pitch", "roll"):
        ok = np.isfinite(raw[axis])
        assert _rms(filt[axis]) < 0.08, axis
        assert _rms(filt[axis]) < 0.5 * _rms(raw[axis][ok]), axis
    # the filtered frame pose (mount + body) follows the 1–3 Hz shaking: not worse than raw
    rows = table["frame"].astype(int)
    keep = (rows >= SETTLE) & np.isfinite(table["meas_pitch_deg"])
    for axis in ("pitch", "roll"):
        truth = gt[f"{axis}_deg"][rows[keep]]
        pose = _rms(table[f"{axis}_deg"][keep] - truth)
        raw = _rms(table[f"meas_{axis}_deg"][keep] - truth)
        assert pose <= raw, (axis, pose, raw)
    # 2 % wrong nominal height; the wheel speed pulls it to the truth
    h_err = table["mount_height_m"][-5:] / gt["mount_height_m"][-5:] - 1.0
    assert np.all(np.abs(h_err) < 0.005)
    assert np.all(np.isfinite(table["wheel_speed_mps"][1:]))


def test_smooth_and_monitor_on_the_estimates_with_wheel_speed(seq, gt, estimates, tmp_path):
    out = tmp_path / "smooth.csv"
    rc = main(["smooth", "--estimates", str(estimates), "--height", f"{H_NOMINAL:.6f}",
               "--vehicle", "cart", "--speed-csv", str(seq / "speed.csv"),
               "--out", str(out), "--quiet"])
    assert rc == 0
    table = read_table(out)
    filt = _mount_errors(table, gt, "mount_")
    for axis in ("pitch", "roll"):
        assert _rms(filt[axis]) < 0.08, axis
    h_err = table["mount_height_m"][SETTLE:] / gt["mount_height_m"][SETTLE:] - 1.0
    assert np.all(np.abs(h_err) < 0.005)

    nominal = tmp_path / "nominal.yaml"
    nominal.write_text(f"pitch_deg: {PRESET.pitch_deg}\nroll_deg: 0.0\nheight_m: {H_NOMINAL}\n"
                       "tolerances: {pitch_deg: 0.2, roll_deg: 0.2, height_m: 0.005}\n")
    mon = tmp_path / "monitor.csv"
    rc = main(["monitor", "--estimates", str(estimates), "--camera", str(seq / "camera.yaml"),
               "--nominal", str(nominal), "--speed-csv", str(seq / "speed.csv"),
               "--out", str(mon), "--quiet", "--columns", "all"])
    assert rc == 0
    table = read_table(mon)
    assert len(table["frame"]) == N_FRAMES
    # the monitor's EKF sees the same drive: its mount ends near the true one
    last = -1
    assert table["mount_pitch_deg"][last] == pytest.approx(gt["mount_pitch_deg"][last], abs=0.08)
    assert table["mount_height_m"][last] == pytest.approx(PRESET.height_m, rel=0.005)
    # measured height (wheel distance / estimated travel) is tested: dev_height is finite
    assert np.isfinite(table["dev_height_m"][SETTLE:]).any()
