"""What `estimate` warns of after a run, against renders whose truth is known: what a global
shutter assumed stakes (vipm_track/readout_stake.py) where no ``--readout-time`` was given,
and a forward camera driven too slowly for its pitch (filters/forward_slow.py)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from vipm_track.camera import load_camera
from vipm_track.cli import main
from vipm_track.estimator_config import EstimatorConfig
from vipm_track.readout_stake import TYPICAL_READOUT_S, ReadoutStake, readout_stake
from vipm_track.render import Effects
from vipm_track.rig import Rig
from vipm_track.sim import PRESETS, simulate_sequence
from vipm_track.sources import open_source
from vipm_track.table import read_table

CART = PRESETS["cart"]  # 10 fps
READOUT_S = 0.04


@pytest.fixture(scope="module")
def rolling_cart(tmp_path_factory) -> Path:
    """Cart frames read out over 40 ms, estimated as if the shutter were global."""
    folder = tmp_path_factory.mktemp("stake_cart")
    simulate_sequence(CART, 8, folder, seed=61, profile="static",
                      effects=Effects(rolling_shutter=READOUT_S * CART.fps))
    return folder


def test_the_stake_predicts_the_rows_bias(rolling_cart):
    rig = Rig(load_camera(rolling_cart / "camera.yaml"), CART.height_m, CART.pitch_deg)
    stake = readout_stake(open_source(images=rolling_cart / "images"), rig, EstimatorConfig())
    assert stake is not None and stake.matters and stake.pairs == 3
    assert stake.readout_s == TYPICAL_READOUT_S
    # a steep cart at 1.2 m/s: 20 ms of readout is worth about 1.5° of pitch and 4.5 % travel
    assert 1.2 < stake.pitch_deg < 1.8 and -0.06 < stake.travel_rel < -0.03
    assert abs(stake.roll_deg) < 0.1
    # the rows of a 40 ms camera estimated as global are off by twice that, the other way
    est = rolling_cart / "est.csv"
    assert main(["estimate", "--images", str(rolling_cart / "images"), "--height", "0.7",
                 "--pitch", "45", "--readout-time", "0", "--out", str(est), "--quiet"]) == 0
    table, truth = read_table(est), read_table(rolling_cart / "gt.csv")
    ok = table["status"] == "ok"
    bias = np.median(table["pitch_deg"][ok] - truth["pitch_deg"][table["frame"][ok]])
    assert bias == pytest.approx(-stake.pitch_deg * READOUT_S / stake.readout_s, abs=0.15)


def test_estimate_warns_only_where_no_readout_was_given(rolling_cart, capsys):
    base = ["estimate", "--images", str(rolling_cart / "images"), "--height", "0.7",
            "--pitch", "45", "--out", str(rolling_cart / "est2.csv"), "--quiet",
            "--max-frames", "5"]
    assert main(base) == 0
    err = capsys.readouterr().err
    assert "assuming a global shutter (no --readout-time)" in err and "give --readout-time" in err
    for given in ("0", "0.04"):
        assert main([*base, "--readout-time", given]) == 0
        assert "assuming a global shutter" not in capsys.readouterr().err


def test_a_small_stake_does_not_matter():
    assert not ReadoutStake(0.02, 0.1, -0.1, 0.01, 3).matters
    assert ReadoutStake(0.02, 0.0, -0.25, 0.0, 3).matters
    assert ReadoutStake(0.02, 0.0, 0.0, -0.025, 3).matters


def test_estimate_warns_of_a_forward_camera_driven_slowly(tmp_path, capsys):
    # a car at 0.3 m/s, 20 fps: 0.01 camera heights per frame; the rows are ok with a wide σ,
    # but their pitch reads low one way over the whole stretch
    folder = tmp_path / "slow_car"
    simulate_sequence("car", 5, folder, seed=62, profile="static", speed=0.3)
    args = ["estimate", "--images", str(folder / "images"), "--height", "1.5", "--pitch", "3",
            "--readout-time", "0", "--quiet"]
    assert main([*args, "--out", str(tmp_path / "slow.csv")]) == 0
    err = capsys.readouterr().err
    assert "vipm-track estimate: warning:" in err and "travel less than 0.25 camera heights" in err
    fast = tmp_path / "fast_car"
    simulate_sequence("car", 5, fast, seed=62, profile="static", speed=12.0)
    assert main([*args[:2], str(fast / "images"), *args[3:], "--out", str(tmp_path / "f.csv")]) == 0
    assert "travel less than" not in capsys.readouterr().err
