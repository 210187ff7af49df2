"""The rolling shutter's readout found from the frames (vipm_track.readout_search,
``--readout-time auto``), against rendered sequences whose readout is known."""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import numpy as np
import pytest

from tests.conftest import shared_data
from vipm_track.camera import load_camera
from vipm_track.commands.common import seconds_or_auto
from vipm_track.estimator_config import EstimatorConfig
from vipm_track.readout_search import _pooled_vertex, search_readout
from vipm_track.render import Effects
from vipm_track.rig import Rig
from vipm_track.sim import PRESETS, simulate_sequence
from vipm_track.sources import open_source

CART = PRESETS["cart"]  # 10 fps: a frame interval of 100 ms


def _render(folder: Path, readout_frames: float, frames: int = 7):
    return simulate_sequence(CART, frames, folder, seed=5, profile="gradual",
                             effects=Effects(rolling_shutter=readout_frames))


@pytest.fixture(scope="module")
def rolling_cart(tmp_path_factory) -> tuple[Path, object]:
    """Cart frames read out over half the frame interval (50 ms)."""
    folder = tmp_path_factory.mktemp("rolling_cart")
    return folder, _render(folder, 0.5)


def _search(folder: Path, pitch_deg: float, **kwargs):
    rig = Rig(load_camera(folder / "camera.yaml"), CART.height_m, pitch_deg)
    return search_readout(open_source(images=folder / "images"), rig, EstimatorConfig(),
                          **kwargs)


def test_rolling_shutter_readout_is_found(rolling_cart):
    # unmodelled, this readout costs the cart 3.3° of pitch and 11 % of travel; the fit's
    # residual is smallest at the rendered readout
    folder, _ = rolling_cart
    found = _search(folder, CART.pitch_deg, max_pairs=3, scan_pairs=4)
    assert found is not None and found.pairs == 3 and found.determined
    assert found.interval_s == pytest.approx(0.1)
    assert found.readout_s == pytest.approx(0.05, abs=0.004), found.line()
    assert 0 < found.std_s < 0.004 and not found.global_shutter
    assert found.candidates_s == pytest.approx(np.linspace(0.0, 0.1, 11))
    cost = np.asarray(found.cost_px2)
    assert cost[0] > 10 * cost.min()  # the global-shutter fit is far worse
    assert found.line().startswith(f"--readout-time auto: {found.readout_s * 1e3:.1f} ± ")
    assert "0.48 frame intervals" in found.line()


def test_global_shutter_is_found_as_such(tmp_path):
    _render(tmp_path, 0.0, frames=4)
    found = _search(tmp_path, CART.pitch_deg, max_pairs=3, scan_pairs=3)
    assert found is not None
    assert found.readout_s < 0.004, found.line()
    assert found.determined and found.global_shutter
    assert "a global shutter within 2σ" in found.line()
    assert int(np.argmin(found.cost_px2)) == 0


def test_cli_estimates_with_the_readout_it_finds(rolling_cart, capsys):
    from vipm_track.cli import main
    from vipm_track.table import read_table

    folder, traj = rolling_cart
    out = folder / "est.csv"
    assert main(["estimate", "--images", str(folder / "images"), "--camera",
                 str(folder / "camera.yaml"), "--height", str(CART.height_m), "--pitch",
                 str(CART.pitch_deg), "--readout-time", "auto", "--out", str(out)]) == 0
    assert "vipm-track: --readout-time auto: 4" in capsys.readouterr().err  # 48 ms
    est = read_table(out)
    assert list(est["status"][1:]) == ["ok"] * 6
    pitch_err = np.abs(est["pitch_deg"][1:] - np.degrees(traj.pitch[1:]))
    travel = np.array([traj.motion(k).distance for k in range(1, 7)])
    dist_err = np.abs(np.hypot(est["tx_m"][1:], est["tz_m"][1:]) / travel - 1.0)
    assert pitch_err.max() < 0.15 and dist_err.max() < 0.01, (pitch_err, dist_err)


def test_option_takes_seconds_or_auto():
    assert seconds_or_auto(" AUTO ") == "auto"
    assert seconds_or_auto("0.033") == pytest.approx(0.033)
    with pytest.raises(argparse.ArgumentTypeError, match="expected seconds or 'auto'"):
        seconds_or_auto("fast")


def test_cli_rejects_a_bad_readout(tmp_path, capsys):
    from vipm_track.cli import main

    with pytest.raises(SystemExit):
        main(["estimate", "--images", str(tmp_path), "--camera", "c.yaml", "--height", "1",
              "--readout-time", "fast", "--out", str(tmp_path / "e.csv")])
    assert "--readout-time: expected seconds or 'auto', got 'fast'" in capsys.readouterr().err


def test_kitti_global_shutter_gets_no_readout():
    # KITTI's cameras have a global shutter; on its forward view the ground spans few rows and
    # the fit's residual does not change with the readout (a readout of 87 ms, fitted to that
    # jitter, moved the travel by -8 %): the search must not invent one
    data = shared_data("kitti07")
    camera = load_camera(data / "calib.txt")
    found = search_readout(open_source(images=data / "image_0"), Rig(camera, 1.65, 1.0),
                           EstimatorConfig())
    assert found is not None
    assert not found.determined or found.global_shutter, found.line()
    if not found.determined:
        assert "not determined" in found.line() and "--readout-time SECONDS" in found.line()


def test_vertex_of_noisy_parabolas():
    # squared residuals grow with the square of the readout error: the pooled vertex and the
    # spread of the pairs' own vertices come back; a pair failing at a readout far from the
    # best one does not matter, one failing inside the window is left out
    rng = np.random.default_rng(0)
    readouts = np.linspace(0.0, 0.1, 11)
    truth = np.array([0.031, 0.033, 0.035, 0.032, 0.034, 0.033])
    cost = 0.05 + 40.0 * (readouts[:, None] - truth[None, :]) ** 2
    cost *= 1.0 + 0.01 * rng.standard_normal(cost.shape)
    cost[10, 0] = np.nan  # failed far away: kept
    cost[3, 1] = np.nan  # failed inside the window: dropped
    vertex, std, used, pooled = _pooled_vertex(readouts, cost)
    assert used == 5
    assert vertex == pytest.approx(np.mean(truth[[0, 2, 3, 4, 5]]), abs=0.001)
    assert 0.0 < std < 0.002
    assert np.isfinite(pooled[:10]).all() and np.isnan(pooled[10])
    # concave (no minimum): the grid's best; too few pairs: None
    flat = np.tile(-((readouts - 0.05) ** 2)[:, None], (1, 3)) + 1.0
    assert _pooled_vertex(readouts, flat)[0] in (0.0, 0.1)
    assert _pooled_vertex(readouts, cost[:, :1]) is None
    assert math.isnan(_pooled_vertex(readouts, cost[:, [0, 2]])[1])
