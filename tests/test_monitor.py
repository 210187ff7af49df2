"""Calibration drift monitor: thresholds, nominal files, detection against simulated truth,
HOLD / INVALID / hysteresis, events, and batched vs streaming agreement."""

from __future__ import annotations

import dataclasses
import json
import math
import re
from collections import Counter
from pathlib import Path

import numpy as np
import pytest
from scipy.stats import norm

from vipm_track.errors import InputError
from vipm_track.filters.drive_sim import DriveConfig, MountChange, simulate_drive
from vipm_track.filters.forward_slow import SLOW_FORWARD
from vipm_track.filters.monitor import DriftMonitor, run_monitor, write_events
from vipm_track.filters.monitor_core import MonitorCore
from vipm_track.filters.monitor_inputs import (
    input_arrays,
    inputs_from_measurements,
    monitor_measurements,
    mount_from_state,
)
from vipm_track.filters.monitor_stats import cusum_log_arl, cusum_threshold
from vipm_track.filters.monitor_types import (
    CALIBRATED,
    RECALIBRATE,
    STATES,
    MonitorConfig,
    MonitorInput,
)
from vipm_track.filters.nominal import NominalCalibration, load_nominal, write_nominal

NOMINAL = NominalCalibration(pitch_deg=3.0, roll_deg=0.0, height_m=1.5)
DATA = Path(__file__).resolve().parent / "data"
FPS = 10.0


def drive(duration_s: float, seed: int, changes=(), **overrides):
    cfg = DriveConfig.preset(
        "car", fps=FPS, duration_s=duration_s, mount_changes=tuple(changes),
        mount_random_walk=False, **overrides,
    )
    return simulate_drive(cfg, seed=seed)


def monitor_run(run, nominal=NOMINAL, speed=True, config=None):
    inputs = inputs_from_measurements(run.measurements, run.speed if speed else None)
    return inputs, run_monitor(inputs, nominal, config or MonitorConfig(fps=FPS))


def first_time(outputs, state, after=-math.inf):
    for o in outputs:
        if o.t >= after and o.state == state:
            return o.t
    return None


# --- thresholds -----------------------------------------------------------------------------


def test_threshold_inverts_siegmund():
    for drift in (-0.2, -0.5, -1.0):
        b = cusum_threshold(1e5, drift)
        assert math.exp(cusum_log_arl(b, drift)) == pytest.approx(1e5, rel=1e-6)


def test_threshold_for_a_tolerance_of_many_standard_deviations():
    """A drift so negative that Siegmund's ARL exceeds the target at any threshold (a 5 cm
    height tolerance on millimetre heights) gets a positive threshold whose one-sample tail
    alone keeps the false alarms below the target, not a root-finder's error."""
    arl = 3.6e5
    for drift in (-8.0, -12.0, -40.0):
        assert cusum_log_arl(0.0, drift) > math.log(arl)
        b = cusum_threshold(arl, drift)
        assert b >= 1.0
        assert norm.sf(b - drift) <= 1.0 / arl


def test_threshold_gives_the_simulated_run_length():
    """A CUSUM of N(drift, 1) increments at the computed threshold reaches it after about the
    requested ARL (Siegmund's approximation is good to a few percent)."""
    drift, arl = -0.5, 400.0
    b = cusum_threshold(arl, drift)
    rng = np.random.default_rng(3)
    runs, steps = 4000, 8000
    s = np.zeros(runs)
    hit = np.full(runs, np.nan)
    for k in range(steps):
        s = np.maximum(0.0, s + rng.standard_normal(runs) + drift)
        new = np.isnan(hit) & (s >= b)
        hit[new] = k + 1
        s[new] = -np.inf  # stop
    assert np.isfinite(hit).mean() > 0.99
    assert np.nanmean(hit) == pytest.approx(arl, rel=0.1)


# --- nominal file ---------------------------------------------------------------------------


def test_nominal_round_trip(tmp_path):
    nom = NominalCalibration(2.5, -0.3, 1.42, pitch_tol_deg=0.2, height_tol_m=0.01,
                             max_angle_dev_deg=8.0)
    write_nominal(nom, tmp_path / "n.yaml")
    assert load_nominal(tmp_path / "n.yaml") == nom


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("pitch_deg: 3\nroll_deg: 0\n", "height_m"),
        ("pitch_deg: 3\nroll_deg: zero\nheight_m: 1.5\n", "roll_deg"),
        ("pitch_deg: 3\nroll_deg: 0\nheight_m: -1\n", "height_m must be > 0"),
        ("pitch_deg: 3\nroll_deg: 0\nheight_m: 1.5\ntolerances: {pitch: 1}\n", "pitch"),
        ("[1, 2]\n", "mapping"),
        ("pitch_deg: [3\n", r"bad.yaml: line 2, column 1: not valid YAML \(.*\)$"),
        # a date PyYAML cannot build raised a bare ValueError out of its loader
        ("pitch_deg: 2024-13-45\nroll_deg: 0\nheight_m: 1.5\n",
         r"bad.yaml: not valid YAML \(month must be in 1..12\)$"),
        ("pitch_deg: 450\nroll_deg: 0\nheight_m: 1.5\n", "pitch_deg must be within ±90°, got 450"),
        ("pitch_deg: 3\nroll_deg: 0\nheight_m: 1.5\ntolerance: {pitch_deg: 1}\n",
         r"unknown key\(s\) \['tolerance'\]; expected .*'tolerances'"),
        # YAML's true is not 1°; a bad tolerance or limit is named as the file names it
        ("pitch_deg: true\nroll_deg: 0\nheight_m: 1.5\n", "'pitch_deg' is not a number: True"),
        ("pitch_deg: 3\nroll_deg: 0\nheight_m: 1.5\ntolerances: {roll_deg: -0.1}\n",
         r"tolerances\.roll_deg must be >= 0, got -0\.1"),
        ("pitch_deg: 3\nroll_deg: 0\nheight_m: 1.5\nlimits: {max_height_dev_frac: 0}\n",
         r"limits\.max_height_dev_frac must be > 0, got 0"),
        ("pitch_deg: 3\nroll_deg: 0\nheight_m: 1.5\ntolerances: {pitch_deg: .nan}\n",
         r"tolerances\.pitch_deg must be a finite number"),
    ],
)
def test_nominal_errors_name_file_and_key(tmp_path, text, message):
    path = tmp_path / "bad.yaml"
    path.write_text(text)
    with pytest.raises(InputError, match=message) as info:
        load_nominal(path)
    assert "bad.yaml" in str(info.value)


def test_nominal_that_is_not_text_names_the_file(tmp_path):
    path = tmp_path / "bad.yaml"
    path.write_bytes(b"pitch_deg: 3\n\xff\xfe\x00garbage")
    with pytest.raises(InputError, match=r"bad\.yaml: not a text file"):
        load_nominal(path)


def test_shipped_nominal_examples_load():
    from pathlib import Path

    files = sorted((Path(__file__).resolve().parents[1] / "data").glob("nominal_*.yaml"))
    assert files, "data/nominal_*.yaml examples missing"
    for f in files:
        load_nominal(f)


# --- detection on simulated drives ----------------------------------------------------------


@pytest.mark.parametrize(
    "change",
    [MountChange(20.0, pitch_deg=1.0), MountChange(20.0, roll_deg=-1.0),
     MountChange(20.0, height_m=0.02)],
    ids=["pitch+1deg", "roll-1deg", "height+2cm"],
)
def test_step_flagged_after_and_never_before(change):
    run = drive(50.0, seed=11, changes=[change], stop_probability=0.0)
    _, out = monitor_run(run)
    assert first_time(out, "RECALIBRATE") is not None
    t_flag = first_time(out, "RECALIBRATE")
    assert 20.0 <= t_flag <= 20.0 + (10.0 if change.height_m else 5.0)
    assert first_time(out, "CALIBRATED") < 20.0
    # the reported new extrinsics: the truth inside the 95 % interval by the end
    last = [o for o in out if o.state != "HOLD"][-1]
    assert last.state == "RECALIBRATE"
    truth = np.array([math.radians(3.0 + change.pitch_deg), math.radians(change.roll_deg),
                      1.5 + change.height_m])
    assert np.all(last.interval95[:, 0] <= truth) and np.all(truth <= last.interval95[:, 1])
    j = int(np.argmax(np.abs([change.pitch_deg, change.roll_deg, change.height_m * 100])))
    assert "pitch roll height".split()[j] in last.reason


def test_height_is_untested_without_wheel_speed():
    run = drive(40.0, seed=12, changes=[MountChange(15.0, height_m=0.03)], stop_probability=0.0)
    inputs, out = monitor_run(run, speed=False)
    assert all(np.isnan(i.pose[2]) for i in inputs)
    assert first_time(out, "RECALIBRATE") is None


def test_nominal_drive_with_outliers_and_stops_has_no_alarm():
    run = drive(600.0, seed=13, outlier_fraction=0.1, stop_probability=0.3)
    _, out = monitor_run(run)
    states = {o.state for o in out}
    assert "RECALIBRATE" not in states and "INVALID" not in states
    assert "HOLD" in states  # stops and failed frames
    assert sum(o.state == "CALIBRATED" for o in out) > 0.8 * sum(o.state != "HOLD" for o in out)


def test_deviation_inside_tolerance_is_calibrated():
    """0.3° off nominal: flagged at 0.1° tolerance, calibrated at 0.5° tolerance."""
    run = drive(120.0, seed=14, changes=[MountChange(0.0, pitch_deg=0.3)], stop_probability=0.0)
    _, tight = monitor_run(run, NOMINAL)
    loose_nom = NominalCalibration(3.0, 0.0, 1.5, pitch_tol_deg=0.5, roll_tol_deg=0.5)
    _, loose = monitor_run(run, loose_nom)
    assert first_time(tight, "RECALIBRATE") is not None
    assert first_time(loose, "RECALIBRATE") is None
    judged = [o.state for o in loose if o.state not in ("HOLD", "UNCALIBRATED")]
    assert judged.count("CALIBRATED") > 0.9 * len(judged)


def test_road_tilt_model_keeps_slowly_tilting_roads_quiet_and_still_flags_a_bump():
    """Roads whose camber and slope wander slowly (0.5°, τ 2 s, as on KITTI 07): the
    flat-ground monitor takes the excursions for a moved camera; told of them, it stays
    quiet on the nominal drives, still flags a 3° bump within seconds, and its threshold and
    new-extrinsics interval account for the wander."""
    flat = MonitorConfig(fps=FPS)
    road = MonitorConfig(fps=FPS, road_std_deg=0.5, road_tau_s=2.0)
    a = math.exp(-1.0 / FPS / 2.0)
    extra = MonitorCore(NOMINAL, road).w_nominal - MonitorCore(NOMINAL, flat).w_nominal
    assert np.allclose(extra, [math.radians(0.5) ** 2 * (1 + a) / (1 - a)] * 2 + [0.0])
    flat_alarms = road_alarms = 0
    for seed in range(4):
        run = drive(300.0, seed=40 + seed, stop_probability=0.0, road_std_deg=0.5, road_tau_s=2.0)
        flat_alarms += first_time(monitor_run(run, config=flat)[1], "RECALIBRATE") is not None
        road_alarms += first_time(monitor_run(run, config=road)[1], "RECALIBRATE") is not None
    assert flat_alarms >= 3 and road_alarms == 0
    run = drive(60.0, seed=44, changes=[MountChange(20.0, pitch_deg=3.0)], stop_probability=0.0,
                road_std_deg=0.5, road_tau_s=2.0)
    _, out = monitor_run(run, config=road)
    t_flag = first_time(out, "RECALIBRATE")
    assert t_flag is not None and 20.0 <= t_flag <= 30.0
    last = [o for o in out if o.state != "HOLD"][-1]
    assert last.interval95[0, 0] <= math.radians(6.0) <= last.interval95[0, 1]
    assert np.diff(last.interval95[0])[0] > math.radians(0.3)  # the road's share of it


def test_recalibrate_is_held_until_sustained_return():
    """Bumped by 1° at 15 s and back at 30 s: RECALIBRATE until about clear_after_s of calm
    frames after the return, then CALIBRATED."""
    run = drive(70.0, seed=15, stop_probability=0.0,
                changes=[MountChange(15.0, pitch_deg=1.0), MountChange(30.0, pitch_deg=-1.0)])
    cfg = MonitorConfig(fps=FPS, clear_after_s=10.0)
    _, out = monitor_run(run, config=cfg)
    t_flag = first_time(out, "RECALIBRATE")
    assert 15.0 <= t_flag <= 20.0
    t_clear = first_time(out, "CALIBRATED", after=t_flag)
    # calm frames may start a little before the return (the statistics restart after each
    # alarm), so allow a second or two of slack
    assert t_clear is not None and 30.0 + 8.0 <= t_clear <= 30.0 + 20.0
    assert all(o.state in ("RECALIBRATE", "HOLD") for o in out if t_flag <= o.t < t_clear)
    # while held, the reason and the new extrinsics say the camera reads the nominal again
    # since the return (they said "beyond the tolerance" of a median reaching back before it)
    before = [o.reason for o in out if t_flag <= o.t < 29.0 and o.state == "RECALIBRATE"]
    after = [o for o in out if 31.0 <= o.t < t_clear - 1.0 and o.state == "RECALIBRATE"]
    assert before and not any("again" in r or "within the tolerance" in r for r in before)
    back = [o for o in after if "set back?" in o.reason]
    late = [o for o in after if o.t >= 37.0]
    assert late and all("set back?" in o.reason for o in late), [o.reason for o in late]
    assert all(f"from nominal again (median of the {o.frame - 299} frames over the last "
               f"{o.t - 30.0:.1f} s" in o.reason for o in back), back[0].reason
    assert all(o.interval95[0, 0] <= math.radians(3.0) <= o.interval95[0, 1] for o in after)
    # CALIBRATED's mean deviation is of the calm run that cleared it, not the whole drive
    # (it said +0.40° ± 0.05° against a tolerance of 0.1°)
    cleared = next(o for o in out if o.t >= t_clear + 1.0)
    assert cleared.state == "CALIBRATED"
    mean = float(cleared.reason.split("pitch ")[1].split("°")[0])
    assert abs(mean) < 0.1, cleared.reason


def test_invalid_outside_physical_limits_then_uncalibrated():
    run = drive(60.0, seed=16, stop_probability=0.0,
                changes=[MountChange(10.0, pitch_deg=15.0), MountChange(25.0, pitch_deg=-15.0)])
    _, out = monitor_run(run, config=MonitorConfig(fps=FPS, clear_after_s=5.0))
    t_inv = first_time(out, "INVALID")
    assert t_inv is not None and 10.0 <= t_inv <= 12.0
    inv = [o for o in out if o.state == "INVALID"]
    assert "pitch" in inv[0].reason and "limit" in inv[0].reason
    assert first_time(out, "UNCALIBRATED", after=25.0) is not None
    assert out[-1].state in ("CALIBRATED", "HOLD")


# --- HOLD, gating, events -------------------------------------------------------------------


def test_hold_reasons_and_frozen_statistics():
    run = drive(20.0, seed=17, stop_probability=0.0)
    inputs = inputs_from_measurements(run.measurements, run.speed)
    mon = DriftMonitor(NOMINAL, MonitorConfig(fps=FPS))
    outs = [mon.update(i) for i in inputs[:100]]
    assert outs[0].state == "HOLD" and outs[0].reason == "first frame"
    before = mon.core.s.cusum.copy()
    bad = MonitorInput(frame=100, t=10.0, pose=np.array([0.5, 0.5, 3.0]),
                       pose_var=np.full(3, 1e-6), usable=False, hold_reason="too few inliers")
    o = mon.update(bad)
    assert o.state == "HOLD" and o.reason == "too few inliers"
    np.testing.assert_array_equal(mon.core.s.cusum, before)


def test_standstill_is_hold():
    """A stop is HOLD (by the wheel speed, else by the pair's travel in camera heights);
    a crawling vehicle whose pairs are ok is evidence, with or without wheel speed."""
    run = drive(120.0, seed=18, stop_probability=1.0, segment_mean_s=4.0)
    still = run.truth.speed < 0.02
    crawling_ok = (run.truth.speed > 0.1) & (run.status == "ok")
    assert still.any() and (crawling_ok & (run.truth.speed < 1.0)).any()
    for speed in (run.speed, None):
        arr = input_arrays(np.arange(len(run.z)), run.truth.t, run.z, run.covariance, 1.5,
                           run.status, None, speed)
        assert np.all(arr.reason[still] != "")
        assert np.all(arr.reason[crawling_ok] == "")
    # without wheel speed the rule is the travel in camera heights: a robot 10x smaller
    # moving 10x slower (the same image motion) stands and moves on the same frames
    small = input_arrays(np.arange(len(run.z)), run.truth.t,
                         run.z * np.array([1, 1, 1, 1, 0.1, 0.1, 1]), run.covariance, 0.15,
                         run.status, None, None)
    np.testing.assert_array_equal(small.reason, arr.reason)
    # an ok pair that moved 0.1 % of the camera height says nothing: standstill
    z = run.z.copy()
    z[:, 4:6] *= 0.001 * 1.5 / np.maximum(np.hypot(z[:, 4], z[:, 5]), 1e-12)[:, None]
    creeping = input_arrays(np.arange(len(z)), run.truth.t, z, run.covariance, 1.5,
                            run.status, None, None)
    np.testing.assert_array_equal(creeping.reason[run.status == "ok"], "standstill")


def test_gated_frames_hold_only_briefly():
    cfg = MonitorConfig(fps=FPS, max_gated_run_s=0.3)
    mon = DriftMonitor(NOMINAL, cfg)
    states = []
    # (moved after the first seconds, in which the errors' correlation is measured on the
    # frames as they come: there a change widens its own test)
    for k in range(100):
        pose = NOMINAL.values + np.array([math.radians(2.0), 0.0, 0.0]) * (k >= 80)
        inp = MonitorInput(frame=k, t=k / FPS, pose=pose, pose_var=np.array([3e-6, 3e-6, np.nan]),
                           gated=k >= 80)
        states.append(mon.update(inp).state)
    assert states[80:83] == ["HOLD"] * 3
    assert "RECALIBRATE" in states[83:]


def test_events_are_json_lines_on_state_changes(tmp_path):
    run = drive(40.0, seed=19, changes=[MountChange(20.0, pitch_deg=1.0)], stop_probability=0.0)
    _, out = monitor_run(run)
    n = write_events(out, tmp_path / "ev.jsonl")
    lines = [json.loads(x) for x in (tmp_path / "ev.jsonl").read_text().splitlines()]
    assert n == len(lines) >= 3
    # Events announce state changes; a HOLD only once it has lasted min_hold_event_s (1 s),
    # stamped with the frame it began.
    hold_s = MonitorConfig().min_hold_event_s
    expected, announced, i = [], None, 0
    while i < len(out):
        j = i
        while j < len(out) and out[j].state == out[i].state:
            j += 1
        state = out[i].state
        long_enough = state != "HOLD" or out[j - 1].t - out[i].t >= hold_s - 1e-9
        if state != announced and long_enough:
            expected.append((state, out[i].frame))
            announced = state
        i = j
    assert [(e["state"], e["frame"]) for e in lines] == expected
    assert sum(o.state == "HOLD" for o in out) > sum(e["state"] == "HOLD" for e in lines)
    # min_hold_event_s = 0: one event per change of the per-frame state.
    _, every = monitor_run(run, config=MonitorConfig(fps=FPS, min_hold_event_s=0.0))
    changes = [o for i, o in enumerate(every) if i == 0 or o.state != every[i - 1].state]
    assert [o.event["state"] for o in every if o.event] == [o.state for o in changes]
    recal = next(e for e in lines if e["state"] == "RECALIBRATE")
    assert set(recal) >= {"t", "frame", "state", "estimate", "interval95", "reason"}
    lo, hi = recal["interval95"]["pitch_deg"]
    assert lo <= recal["estimate"]["pitch_deg"] <= hi
    assert recal["estimate"]["pitch_deg"] > 3.5


def test_batched_core_matches_streams():
    runs = [drive(30.0, seed=20 + i, changes=[MountChange(10.0, roll_deg=0.8 * i)])
            for i in range(3)]
    arrs = [input_arrays(np.arange(len(r.z)), r.truth.t, r.z, r.covariance, 1.5, r.status,
                         None, r.speed) for r in runs]
    # the streams' body std adapted to their frames (``DriftMonitor``) is not the batch's
    config = MonitorConfig(fps=FPS, body_window_s=0.0)
    core = MonitorCore(NOMINAL, config, batch=3)
    codes = np.array([
        core.step(np.array([a.t[k] for a in arrs]), np.stack([a.pose[k] for a in arrs]),
                  np.stack([a.pose_var[k] for a in arrs]),
                  np.array([a.usable[k] for a in arrs]))
        for k in range(len(arrs[0].t))
    ])
    for i, r in enumerate(runs):
        _, out = monitor_run(r, config=config)
        assert [STATES[c] for c in codes[:, i]] == [o.state for o in out]
    assert (codes[:, 0] == CALIBRATED).any() and (codes[:, 2] == RECALIBRATE).any()


def test_mount_from_ekf_like_state():
    class S:
        status = "ok"
        mount = np.array([0.05, 0.0, 1.5])
        mount_cov = np.eye(3) * 1e-6
        gated = "motion"

    m, c, g = mount_from_state(S())
    assert m is not None and c.shape == (3, 3) and g is False
    S.gated = "pose+motion"
    assert mount_from_state(S())[2] is True


# --- command line ---------------------------------------------------------------------------


@pytest.fixture
def cli_inputs(tmp_path):
    """An estimates CSV and a wheel-speed CSV of a drive bumped by 1° pitch at 30 s, a
    camera file and the shipped car nominal calibration."""
    from conftest import ROOT, write_drive_inputs

    run = drive(50.0, seed=21, changes=[MountChange(30.0, pitch_deg=1.0)], stop_probability=0.0)
    write_drive_inputs(run, tmp_path)
    nominal = ROOT / "data" / "nominal_car.yaml"
    return tmp_path, nominal


def test_cli_monitor_from_estimates(cli_inputs):
    from vipm_track.cli import main
    from vipm_track.table import read_table

    d, nominal = cli_inputs
    rc = main(["monitor", "--estimates", str(d / "est.csv"), "--camera", str(d / "cam.yaml"),
               "--speed-csv", str(d / "speed.csv"), "--nominal", str(nominal),
               "--out", str(d / "mon.csv"), "--events", str(d / "ev.jsonl"), "--quiet"])
    assert rc == 0
    table = read_table(d / "mon.csv")
    states, t = table["monitor_state"], table["t"]
    assert not np.any(states[t < 30.0] == "RECALIBRATE")
    flagged = t[states == "RECALIBRATE"]
    assert len(flagged) and 30.0 <= flagged.min() <= 33.0
    last = np.flatnonzero(states == "RECALIBRATE")[-1]
    assert table["new_pitch_lo_deg"][last] <= 4.0 <= table["new_pitch_hi_deg"][last]
    assert np.nanmax(np.abs(table["mount_height_m"] - 1.5)) < 0.05  # EKF ran with speed
    events = [json.loads(x) for x in (d / "ev.jsonl").read_text().splitlines()]
    assert any(e["state"] == "RECALIBRATE" and e["filter_mount"] for e in events)
    # every event has the same keys (the first had no filter_mount: a reader's KeyError)
    assert all(list(e) == list(events[0]) for e in events)


def test_cli_monitor_says_the_height_went_untested_without_wheel_speed(cli_inputs, capsys):
    """Without wheel speed the height cannot be tested: CALIBRATED says so in its reason, the
    run says so on stderr, the deviation column is empty; with it, none of that."""
    from vipm_track.cli import main
    from vipm_track.table import read_table

    d, nominal = cli_inputs
    for speed in ([], ["--speed-csv", str(d / "speed.csv")]):
        rc = main(["monitor", "--estimates", str(d / "est.csv"), "--camera", str(d / "cam.yaml"),
                   "--nominal", str(nominal), "--out", str(d / "mon.csv"),
                   "--columns", "all", "--max-frames", "400", *speed])
        assert rc == 0
        err = capsys.readouterr().err
        table = read_table(d / "mon.csv")
        calibrated = table["reason"][table["monitor_state"] == "CALIBRATED"]
        assert len(calibrated)
        untested = [("height not tested" in r) for r in calibrated]
        if speed:
            assert not any(untested) and "height not tested" not in err
            assert np.isfinite(table["dev_height_m"]).any()
        else:
            assert all(untested) and "height not tested" in err
            assert not np.isfinite(table["dev_height_m"].astype(float)).any()


def test_cli_monitor_rows_saying_ok_have_their_numbers(cli_inputs):
    """CONVENTIONS.md: a row's status is ``ok`` only with its numbers. While the EKF waits for
    its first pairs the monitor has no pose to write, so those rows say so, as ``track``'s do
    (they said ``ok`` with empty numbers)."""
    from vipm_track.cli import main
    from vipm_track.filters.track import WAITING
    from vipm_track.table import read_table

    d, nominal = cli_inputs
    assert main(["monitor", "--estimates", str(d / "est.csv"), "--nominal", str(nominal),
                 "--out", str(d / "mon.csv"), "--quiet"]) == 0
    table = read_table(d / "mon.csv")
    ok = table["status"] == "ok"
    assert np.all(np.isfinite(np.asarray(table["pitch_deg"], float)[ok]))
    waiting = table["status"] == WAITING
    assert waiting.any() and np.all(np.isnan(np.asarray(table["pitch_deg"], float)[waiting]))


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--nominal", "missing.yaml"], "missing.yaml"),
        (["--images", "somewhere"], "exactly one of"),
        (["--false-alarms-per-hour", "0"], "false-alarms-per-hour"),
        # a rate beyond one per frame asked the CUSUM for a run length below one sample
        # (a ValueError traceback before)
        (["--false-alarms-per-hour", "1e12"], "at most one per frame"),
        (["--road-std", "-0.5"], "--road-std"),
        (["--road-tau", "0"], "--road-tau"),
        # 1e200 overflowed into CALIBRATED on a knocked camera; 1e300 a NaN traceback
        (["--road-std", "1e200"], "--road-std must be in [0, 10] degrees, got 1e+200"),
        (["--road-tau", "1e300"], "--road-tau must be in (0, 3600] seconds, got 1e+300"),
    ],
)
def test_cli_monitor_errors_exit_2(cli_inputs, capsys, extra, message):
    from vipm_track.cli import main

    d, nominal = cli_inputs
    args = ["monitor", "--estimates", str(d / "est.csv"), "--camera", str(d / "cam.yaml"),
            "--nominal", str(nominal), "--out", str(d / "mon.csv"), "--quiet"]
    for i in range(0, len(extra), 2):
        if extra[i] in args:
            args[args.index(extra[i]) + 1] = extra[i + 1]
        else:
            args += extra[i:i + 2]
    assert main(args) == 2
    assert message in capsys.readouterr().err


def test_cli_monitor_estimates_without_std_columns(cli_inputs, capsys):
    from vipm_track.cli import main

    d, nominal = cli_inputs
    (d / "bad.csv").write_text("frame,t,pitch_deg,roll_deg,height_m,tx_m,tz_m,yaw_deg,status\n"
                               "0,0.0,3,0,1.5,0,1,0,ok\n")
    assert main(["monitor", "--estimates", str(d / "bad.csv"), "--camera", str(d / "cam.yaml"),
                 "--nominal", str(nominal), "--out", str(d / "mon.csv"), "--quiet"]) == 2
    assert "bad.csv" in capsys.readouterr().err


def test_height_needs_speed_without_gaps():
    from vipm_track.filters.drive_sim import SpeedSamples

    run = drive(30.0, seed=22, stop_probability=0.0)
    keep = (run.speed.t < 10.0) | (run.speed.t > 12.0)  # a 2 s hole in the wheel speed
    holed = SpeedSamples(run.speed.t[keep], run.speed.speed_mps[keep])
    arr = input_arrays(np.arange(len(run.z)), run.truth.t, run.z, run.covariance, 1.5,
                       run.status, None, holed)
    t = run.truth.t
    ok = arr.usable
    assert np.all(np.isnan(arr.pose[(t > 10.05) & (t < 11.95), 2]))
    good = ok & ((t < 9.9) | (t > 12.2)) & (t > 0.2) & (t < 29.8)
    assert np.all(np.isfinite(arr.pose[good, 2]))
    assert np.nanmedian(np.abs(arr.pose[good, 2] - 1.5)) < 0.01


# --- forward cameras driving slowly -----------------------------------------------------------


def _read_slow(run, pitch_bias_deg: float, travel_gain: float):
    """``run``'s pairs as a level camera's front end reads them at crawling speed: the pitch
    low and the travel long, pair after pair (docs/kitti.md, "Slow driving": −0.6° and +3 %
    on car renders at 4 m/s)."""
    out = []
    for m in run.measurements:
        z = m.z.copy()
        z[[0, 2]] += math.radians(pitch_bias_deg)
        z[4:6] *= travel_gain
        out.append(dataclasses.replace(m, z=z))
    return out


def test_a_forward_camera_is_not_judged_on_slow_pairs():
    """A car at 3 m/s whose pairs read −0.6° and +3 % (what the renders show at that speed)
    with its camera where it belongs: the monitor called RECALIBRATE ("height −4 cm") within
    half a second. Its slow pairs are now held; the same pairs at 12 m/s are judged."""
    slow = drive(60.0, seed=5, speed_min_mps=3.0, speed_max_mps=3.0, stop_probability=0.0)
    biased = _read_slow(slow, -0.6, 1.03)
    _, outs = monitor_measurements(biased, NOMINAL, slow.speed)
    states = Counter(o.state for o in outs)
    assert states["HOLD"] >= len(outs) - 2, states
    assert Counter(o.reason for o in outs).most_common(1)[0][0] == SLOW_FORWARD
    # without the rule the same pairs call the camera knocked
    _, ungated = monitor_measurements(biased, NOMINAL, slow.speed, min_travel_frac_forward=0.0)
    assert {"DRIFTING", "RECALIBRATE"} & {o.state for o in ungated}
    # fast pairs are judged: the same bias at 12 m/s is found
    fast = drive(60.0, seed=5, speed_min_mps=12.0, speed_max_mps=12.0, stop_probability=0.0)
    _, outs = monitor_measurements(_read_slow(fast, -0.6, 1.0), NOMINAL, fast.speed)
    assert "RECALIBRATE" in {o.state for o in outs}
    assert SLOW_FORWARD not in {o.reason for o in outs}


def test_a_steep_camera_is_judged_at_any_speed():
    steep = NominalCalibration(pitch_deg=45.0, roll_deg=0.0, height_m=0.7)
    run = simulate_drive(DriveConfig.preset("cart", duration_s=30.0, mount_random_walk=False,
                                            stop_probability=0.0), seed=3)
    _, outs = monitor_measurements(run.measurements, steep, run.speed)
    assert SLOW_FORWARD not in {o.reason for o in outs}
    assert Counter(o.state for o in outs)["CALIBRATED"] > len(outs) / 2


def test_a_level_nominal_does_not_hold_a_steep_camera_as_slow():
    """A cart's camera (45°, 0.7 m) monitored against a car's nominal file (3°, 1.5 m): its
    pairs travel under a quarter of the nominal height, and the monitor held every frame as
    "slow for a forward camera" (HOLD throughout, exit 0). Slowness is judged by each pair's
    own pitch: the frames are judged, and the camera 42° off is INVALID."""
    level = NominalCalibration(pitch_deg=3.0, roll_deg=0.0, height_m=1.5)
    run = simulate_drive(DriveConfig.preset("cart", duration_s=20.0, mount_random_walk=False,
                                            stop_probability=0.0), seed=4)
    _, outs = monitor_measurements(run.measurements, level, run.speed)
    states = Counter(o.state for o in outs)
    assert SLOW_FORWARD not in {o.reason for o in outs}
    assert states["INVALID"] > len(outs) / 2, states
    assert any("exceeds the limit" in o.reason for o in outs if o.state == "INVALID")


def test_the_drive_summary_says_when_a_forward_camera_drove_slowly():
    from vipm_track.filters.forward_slow import slow_drive_note

    slow = drive(20.0, seed=6, speed_min_mps=3.0, speed_max_mps=3.0, stop_probability=0.0)
    note = slow_drive_note(slow.measurements)
    assert note.startswith(f"{sum(m.ok for m in slow.measurements)} of the ") and "(100%)" in note
    assert "these pairs' median: 0.20)" in note  # 3 m/s at 10 fps, 1.5 m: 0.2 heights a frame
    fast = drive(20.0, seed=6, speed_min_mps=12.0, speed_max_mps=12.0, stop_probability=0.0)
    assert slow_drive_note(fast.measurements) == ""
    cart = simulate_drive(DriveConfig.preset("cart", duration_s=20.0, stop_probability=0.0),
                          seed=6)
    assert slow_drive_note(cart.measurements) == ""  # a steep camera: no such error


def test_a_sway_the_first_second_had_not_shown_is_not_a_mount_change(tmp_path, monkeypatch):
    """A correctly mounted car camera (rendered: ``simulate --preset car --frames 120 --seed
    112 --profile shaking --obstacle``, estimated with ``--pitch 3``) whose body sways by
    ±2.4° at 1–3 Hz: its first 10 pairs (0.5 s) sat on a crest, then the pitch fell 3.9° in
    0.3 s. Measured on those 10 pairs alone, the shaking looked small and the fall a mount
    change (RECALIBRATE at 0.8 s, for the rest of the drive); the body std is taken as
    measured only over a second of frames. Over the 6 s of this drive the sway leaves the
    mean mount uncertain (±0.4°): the monitor says so (UNCALIBRATED), it does not vouch."""
    from conftest import ROOT

    from vipm_track.cli import main
    from vipm_track.table import read_table

    def states() -> np.ndarray:
        out = tmp_path / "mon.csv"
        assert main(["monitor", "--estimates", str(DATA / "car_sway_est.csv"),
                     "--speed-csv", str(DATA / "car_sway_speed.csv"),
                     "--nominal", str(ROOT / "data" / "nominal_car.yaml"),
                     "--out", str(out), "--quiet"]) == 0
        return read_table(out)["monitor_state"]

    now = states()
    assert not {"RECALIBRATE", "DRIFTING"} & set(now) and np.sum(now == "UNCALIBRATED") >= 100
    # the errors' measured correlation (the sway's innovations run on) widens the test too:
    # without it the sway still read as DRIFTING, and with the half-period window RECALIBRATE
    from_noise = MonitorConfig.from_noise.__func__
    monkeypatch.setattr(MonitorConfig, "from_noise", classmethod(
        lambda cls, noise, **kw: from_noise(cls, noise, correlation_tau_s=0.0, **kw)))
    assert "DRIFTING" in set(states())
    monkeypatch.setattr(MonitorConfig, "body_min_pairs",
                        property(lambda self: self.body_window_min_pairs))
    assert np.sum(states() == "RECALIBRATE") > 50


def _first_alarms(runs, config: MonitorConfig) -> np.ndarray:
    """First RECALIBRATE time (s; inf: none) of each drive, the drives judged as one batch."""
    arrs = [input_arrays(np.arange(len(r.z)), r.truth.t, r.z, r.covariance, 1.5, r.status,
                         None, r.speed) for r in runs]
    core = MonitorCore(NOMINAL, config, batch=len(runs))
    first = np.full(len(runs), np.inf)
    for k in range(len(arrs[0].t)):
        t = np.array([a.t[k] for a in arrs])
        codes = core.step(t, np.stack([a.pose[k] for a in arrs]),
                          np.stack([a.pose_var[k] for a in arrs]),
                          np.array([a.usable[k] for a in arrs]))
        first = np.where((codes == RECALIBRATE) & np.isinf(first), t, first)
    return first


def test_a_step_is_judged_by_the_error_correlation_measured_before_it():
    """The errors' long-run variance is measured on the innovations, and a mount step makes
    them run on: judged by the factor measured 5 s earlier, a 0.5° step on the model's drives
    is flagged as fast as with the errors taken as independent (median 1.9 s over 100 drives,
    bench_monitor.md); judged by the factor of the moment, it widens its own test."""
    runs = [drive(45.0, seed=60 + i, changes=[MountChange(30.0, pitch_deg=0.5)],
                  stop_probability=0.0) for i in range(12)]
    delays = {name: _first_alarms(runs, MonitorConfig(fps=FPS, **kw)) - 30.0
              for name, kw in (("white", {"correlation_tau_s": 0.0}), ("delayed", {}),
                               ("at once", {"correlation_delay_s": 0.0}))}
    assert np.all(np.isfinite(delays["delayed"])) and np.median(delays["delayed"]) <= 3.0
    mean = {name: float(np.mean(d)) for name, d in delays.items()}  # s: 2.3, 2.4, 2.8
    assert mean["delayed"] <= mean["white"] + 0.2, mean
    assert mean["at once"] >= mean["delayed"] + 0.3, mean


def _reported_at(out, t):
    """The first output at or after ``t`` with new extrinsics."""
    return next(o for o in out if o.t >= t and o.estimate is not None)


@pytest.mark.parametrize("seed", [5001, 5004, 5005, 5006])
def test_new_extrinsics_at_the_alarm_are_of_the_frames_after_the_step(seed):
    """A 1° roll step: the CUSUM's change time reached 3.6 s before it (its small design
    shift had been above zero since), and the median of frames mostly from before the step
    reported −0.2° ± 0.37° at the alarm; the step found in the whitening filter's
    innovations gives the frames after it."""
    run = drive(30.0, seed=seed, changes=[MountChange(20.0, roll_deg=-1.0)])
    _, out = monitor_run(run, nominal=NominalCalibration(3.0, 0.0, 1.5, 0.1, 0.1, 0.005))
    alarm = next(o for o in out if o.event is not None and o.state == "RECALIBRATE")
    assert 20.0 <= alarm.t <= 22.0
    roll = math.degrees(alarm.estimate[1])
    lo, hi = np.degrees(alarm.interval95[1])
    assert abs(roll + 1.0) < 0.6 and lo <= -1.0 <= hi, (roll, lo, hi)


@pytest.mark.parametrize("second, truth", [(1.0, 5.0), (-1.0, 3.0)], ids=["further", "set-back"])
def test_new_extrinsics_follow_a_second_change_while_held(second, truth):
    """Knocked +1° at 15 s, then +1° more (or set back) at 35 s, RECALIBRATE held: the
    reported pitch is the camera's since the second change (the median since the first
    alarm gave 4.5° for 5° at the end, a 95 % interval of ± 0.06° around it)."""
    run = drive(60.0, seed=21, stop_probability=0.0,
                changes=[MountChange(15.0, pitch_deg=1.0), MountChange(35.0, pitch_deg=second)])
    cfg = MonitorConfig(fps=FPS, clear_after_s=30.0)  # held to the end in both cases
    _, out = monitor_run(run, config=cfg)
    at = _reported_at(out, 45.0)
    assert at.state == "RECALIBRATE"
    pitch = math.degrees(at.estimate[0])
    lo, hi = np.degrees(at.interval95[0])
    assert abs(pitch - truth) < 0.1 and lo <= truth <= hi, (pitch, lo, hi)


def test_the_interval_holds_the_camera_soon_after_a_second_change(tmp_path):
    """A rendered cart monitored against a nominal 2° below its camera (RECALIBRATE from the
    first seconds), then knocked +1° at 7.2 s: the step test took 3.5 s to find the knock
    while RECALIBRATE was held, and the new extrinsics' 95 % interval, the median of frames
    of both mounts, missed the camera all that time (the same on renders of a car). From
    half a second after the knock the interval holds the truth."""
    from vipm_track.cli import main
    from vipm_track.table import read_table

    nominal = tmp_path / "nominal.yaml"
    nominal.write_text("pitch_deg: 43.0\nroll_deg: 0.0\nheight_m: 0.7\n")
    out = tmp_path / "m.csv"
    assert main(["monitor", "--estimates", str(DATA / "knock_cart_est.csv"), "--nominal",
                 str(nominal), "--speed-csv", str(DATA / "knock_cart_speed.csv"), "--out",
                 str(out), "--quiet"]) == 0
    rows, truth = read_table(out), read_table(DATA / "knock_cart_gt.csv")
    true_pitch = dict(zip(truth["frame"], truth["mount_pitch_deg"], strict=True))
    knock = float(truth["t"][np.flatnonzero(truth["mount_pitch_deg"] > 45.5)[0]])
    held = [k for k, (t, state) in enumerate(zip(rows["t"], rows["monitor_state"], strict=True))
            if state == "RECALIBRATE" and t >= knock + 0.5]
    assert len(held) > 80
    missed = [float(rows["t"][k]) for k in held
              if not (rows["new_pitch_lo_deg"][k] <= true_pitch[rows["frame"][k]]
                      <= rows["new_pitch_hi_deg"][k])]
    assert missed == []
    # once found, the frames since the move are the ones read (and said), not both mounts'
    since = [float(re.search(r"frames over the last ([0-9.]+) s", rows["reason"][k]).group(1))
             for k in held if rows["t"][k] >= knock + 1.0]
    late = [rows["t"][k] - knock for k in held if rows["t"][k] >= knock + 1.0]
    assert since and all(s <= t + 0.6 for s, t in zip(since, late, strict=True)), since


def test_a_second_move_found_stays_found(tmp_path):
    """A noisy rendered cart (``simulate --preset cart --frames 100 --profile knock --noise 8
    --seed 14``, ``estimate --height 0.7 --readout-time 0 --pitch 45``) against a nominal 2°
    off, knocked +1° at 4.8 s: the recent frames read apart from the rest on some frames
    and not on the next, and the reported pitch flipped between both mounts five times;
    once found, the frames since the move are read until a step says otherwise."""
    from vipm_track.cli import main
    from vipm_track.table import read_table

    nominal = tmp_path / "nominal.yaml"
    nominal.write_text("pitch_deg: 47.0\nroll_deg: 0.0\nheight_m: 0.7\ntolerances:\n"
                       "  pitch_deg: 0.2\n  roll_deg: 0.2\n  height_m: 0.005\n")
    out = tmp_path / "m.csv"
    assert main(["monitor", "--estimates", str(DATA / "cart_knock_noisy_est.csv"), "--nominal",
                 str(nominal), "--speed-csv", str(DATA / "cart_knock_noisy_speed.csv"), "--out",
                 str(out), "--quiet"]) == 0
    rows = read_table(out)
    held = np.asarray(rows["monitor_state"], dtype=object) == "RECALIBRATE"
    pitch = np.asarray(rows["new_pitch_deg"], float)[held]
    t = np.asarray(rows["t"], float)[held]
    jumps = t[1:][np.abs(np.diff(pitch)) > 0.2]
    assert len(jumps) == 1 and 4.8 <= jumps[0] <= 6.0, jumps
    assert abs(pitch[-1] - 46.0) < 0.2


@pytest.mark.parametrize("seed", [0, 1, 2, 3, 5])
def test_a_told_roads_wander_makes_no_steps_of_the_new_extrinsics(seed):
    """A 1° knock on a road whose tilt wanders 0.4° (the monitor told: --road-std 0.4): the
    step search took the wander for steps and the reported pitch jumped by 0.5–0.9° from one
    frame to the next while RECALIBRATE was held; it must stand out of the told wander, and a
    step once found stays found (found, lost and found again, the pitch flipped between
    0.75° and 1.06° off nominal from frame to frame)."""
    run = drive(60.0, seed=seed, changes=[MountChange(15.0, pitch_deg=1.0)],
                road_std_deg=0.4, stop_probability=0.0)
    cfg = MonitorConfig.from_noise(run.config.noise, fps=FPS, road_std_deg=0.4, road_tau_s=2.0,
                                   clear_after_s=100.0)
    _, out = monitor_run(run, nominal=NominalCalibration(3.0, 0.0, 1.5, 0.1, 0.1, 0.005),
                         config=cfg)
    held = [o for o in out if o.state == "RECALIBRATE"]
    pitch = np.degrees([o.estimate[0] for o in held])
    jumps = np.abs(np.diff(pitch))
    assert len(held) > 100 and np.count_nonzero(jumps > 0.2) <= 1, jumps[jumps > 0.2]
    assert not any("set back?" in o.reason for o in held)
    lo, hi = np.degrees(held[-1].interval95[0])
    assert lo <= 4.0 <= hi


def test_an_interval_beyond_the_bound_is_said_to_be_beyond_it(tmp_path, capsys):
    """A cart 1° steeper than its nominal: while the change test collects, the mean deviation
    +1.04° ± 0.62° lay wholly beyond the 0.25° bound, and the reason said it was "not shown
    within 0.25° yet"."""
    import re

    from vipm_track.cli import main
    from vipm_track.table import read_table

    nominal = tmp_path / "nominal.yaml"
    nominal.write_text("pitch_deg: 44.0\nroll_deg: 0.0\nheight_m: 0.7\n")
    out = tmp_path / "m.csv"
    assert main(["monitor", "--estimates", str(DATA / "cart_shaking_est.csv"), "--nominal",
                 str(nominal), "--out", str(out), "--quiet"]) == 0
    said = {"beyond": 0, "within": 0}
    for reason in read_table(out)["reason"]:
        found = re.search(r"so far, pitch ([+-][\d.]+)° ± ([\d.]+)°, (lies beyond|is not shown "
                          r"within) ([\d.]+)°", str(reason))
        if found:
            mean, half, words, bound = found.groups()
            beyond = abs(float(mean)) - float(half) > float(bound)
            assert words == ("lies beyond" if beyond else "is not shown within"), reason
            said["beyond" if beyond else "within"] += 1
    assert said["beyond"] >= 1, said


def test_a_second_change_while_recalibrate_is_held_is_said(tmp_path):
    """The knocked cart (pitch +1° at 7.2 s) against a nominal 3 cm too high: RECALIBRATE for
    the height at once, and the knock then showed only in the new-pitch columns — no event,
    and every reason spoke of the height alone."""
    import json

    from vipm_track.cli import main
    from vipm_track.table import read_table

    nominal = tmp_path / "nominal.yaml"
    nominal.write_text("pitch_deg: 45.0\nroll_deg: 0.0\nheight_m: 0.73\ntolerances:\n"
                       "  pitch_deg: 0.2\n  roll_deg: 0.2\n  height_m: 0.005\n")
    out, events = tmp_path / "m.csv", tmp_path / "e.jsonl"
    assert main(["monitor", "--estimates", str(DATA / "knock_cart_est.csv"), "--nominal",
                 str(nominal), "--speed-csv", str(DATA / "knock_cart_speed.csv"), "--events",
                 str(events), "--out", str(out), "--quiet"]) == 0
    said = [json.loads(line) for line in events.read_text().splitlines()]
    assert [e["state"] for e in said] == ["UNCALIBRATED", "RECALIBRATE", "RECALIBRATE"]
    assert said[1]["reason"].startswith("height changed") and "too" not in said[1]["reason"]
    assert "; pitch reads off too: 95 % +0." in said[2]["reason"]
    assert 7.2 < said[2]["t"] < 9.5  # the knock at 7.2 s
    table = read_table(out)
    before = np.asarray(table["t"]) < 7.2
    assert not any("reads off too" in str(r) for r in np.asarray(table["reason"])[before])


def test_new_extrinsics_of_a_creeping_mount_are_where_it_is_now():
    """The mount creeping +1.5° over 30 s: the median of the frames since the change lagged
    it, and its interval held the camera in about half the flagged frames; the line through
    them ends on it. A step of the same size is still read from the frames after it."""
    covered = []
    for seed in (31, 32):
        run = drive(60.0, seed=seed, stop_probability=0.0,
                    changes=[MountChange(15.0, pitch_deg=1.5, duration_s=30.0)])
        _, out = monitor_run(run)
        truth = np.degrees(run.truth.mount_pitch)
        for o in out:
            if o.state in ("DRIFTING", "RECALIBRATE") and o.estimate is not None and o.t >= 25:
                lo, hi = np.degrees(o.interval95[0])
                covered.append(lo <= truth[int(o.frame)] <= hi)
    assert len(covered) > 300 and np.mean(covered) >= 0.85, np.mean(covered)
    run = drive(60.0, seed=31, stop_probability=0.0, changes=[MountChange(20.0, pitch_deg=1.5)])
    _, out = monitor_run(run)
    at = _reported_at(out, 40.0)
    assert "end of the drift line" not in at.reason
    assert abs(math.degrees(at.estimate[0]) - 4.5) < 0.1
