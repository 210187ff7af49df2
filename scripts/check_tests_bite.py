"""Do the tests fail when the code is wrong? A small mutation check.

Each mutant replaces one snippet of the source with a typical mistake (a sign flip, swapped
columns, a dropped term, an off-by-one, a threshold moved) in a *copy* of the working tree
(tracked and untracked-not-ignored files; the repository itself is never modified), runs the
fast tests that cover that part there and records which of them fail. A mutant no test
fails on is "survived": a test is missing. The unmutated copy is run first; a test that
fails there is left out of the attribution.

    python scripts/check_tests_bite.py [--only NAME ...] [--list] [--timeout 900]

Prints a Markdown table and writes it to ``scripts/results/check_tests_bite.md``. The
copy sits in a temporary folder beside a link to ``../shared`` so the real-data tests run.
"""

from __future__ import annotations

import argparse
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "scripts" / "results" / "check_tests_bite.md"

#: fast tests per part (files or node ids), run on every mutant of that part
ESTIMATOR_TESTS = (
    "tests/test_estimator.py", "tests/test_pipeline.py", "tests/test_geometry.py",
    "tests/test_render_independent.py",
)
EKF_TESTS = ("tests/test_ekf.py", "tests/test_kitti.py::test_filters_follow_the_real_kitti_drive")
SMOOTHER_TESTS = (
    "tests/test_smoother.py", "tests/test_kitti.py::test_filters_follow_the_real_kitti_drive",
    "tests/test_kitti.py::test_smoothed_summary_interval_is_honest_on_the_real_drive",
)
MONITOR_TESTS = (
    "tests/test_monitor.py", "tests/test_monitor_timing.py",
    "tests/test_kitti.py::test_monitor_on_the_real_drive_measures_its_errors_correlation",
)
TABLE_TESTS = (
    "tests/test_pipeline.py", "tests/test_table_roundtrip.py", "tests/test_ekf.py",
    "tests/test_kitti.py::test_stored_kitti_estimates_score_as_stated",
)
RENDER_TESTS = ("tests/test_render_independent.py",)
LEVER_ARM_TESTS = ("tests/test_lever_arm.py", "tests/test_row_correlation.py")
CHAIN_TESTS = ("tests/test_pair_chain.py", "tests/test_pipeline.py")


@dataclass(frozen=True)
class Mutant:
    """One mistake: ``old`` (found exactly once in ``path``) replaced by ``new``."""

    name: str
    part: str
    what: str
    path: str
    old: str
    new: str
    tests: tuple[str, ...]


_EARLY_KNOCK = ("tests/test_smoother.py::"
                "test_fixed_lag_follows_a_knock_before_its_online_test_is_armed")
_FOLLOWED_KNOCK = ("tests/test_smoother.py::"
                   "test_a_fixed_lag_summary_warns_of_a_step_its_mount_did_not_follow")


MUTANTS: tuple[Mutant, ...] = (
    # --- estimator (and the geometry it shares with the renderer) ----------------------------
    Mutant("geometry-pitch-sign", "estimator", "sign flip: R_GC = Rx(+pitch)·Rz(roll)",
           "vipm_track/geometry.py",
           "c, s = np.cos(np.asarray(pitch, dtype=float)), np.sin(np.asarray(pitch, dtype=float))",
           "c, s = np.cos(np.asarray(pitch, dtype=float)), -np.sin(np.asarray(pitch, dtype=float))",
           ESTIMATOR_TESTS),
    Mutant("geometry-roll-sign", "estimator", "sign flip: R_GC = Rx(−pitch)·Rz(−roll)",
           "vipm_track/geometry.py",
           "cr, sr = np.cos(np.asarray(roll, dtype=float)), np.sin(np.asarray(roll, dtype=float))",
           "cr, sr = np.cos(np.asarray(roll, dtype=float)), -np.sin(np.asarray(roll, dtype=float))",
           ESTIMATOR_TESTS),
    Mutant("measurement-prev-curr-swapped", "estimator",
           "swapped: the pair's measurement packs frame k's pose first",
           "vipm_track/pair_result.py",
           "z = pack(self.pose_prev, self.pose_curr, self.motion)[:7]",
           "z = pack(self.pose_curr, self.pose_prev, self.motion)[:7]", ESTIMATOR_TESTS),
    Mutant("guess-off-by-one-frame", "estimator",
           "off-by-one: tracking seeds the next pair with frame k−1's pose",
           "vipm_track/pair_result.py",
           "return cls(result.pose_curr, result.pose_curr,",
           "return cls(result.pose_prev, result.pose_prev,",
           ESTIMATOR_TESTS),
    Mutant("motion-yaw-sign", "estimator", "sign flip: the unpacked yaw",
           "vipm_track/displacement_model.py",
           "PlanarMotion(float(x[4]), float(x[5]), float(x[6])),",
           "PlanarMotion(float(x[4]), float(x[5]), -float(x[6])),", ESTIMATOR_TESTS),
    Mutant("motion-bound-unconfirmed", "estimator",
           "dropped rule: a pair that agreed with nothing before it rejects the next",
           "vipm_track/pair_chain.py", "if conflict is not None and before.confirmed:",
           "if conflict is not None:", CHAIN_TESTS),
    Mutant("motion-bound-speed-only", "estimator",
           "simplified: the bound compares speeds, not velocities (a sideways lock passes)",
           "vipm_track/pair_chain.py", "change = now.velocity - before.velocity",
           "change = np.array([0.0, np.hypot(*now.velocity) - np.hypot(*before.velocity)])",
           CHAIN_TESTS),
    Mutant("wrong-minimum-guard-off", "estimator",
           "threshold: a cold start's inlier share needs 0 % (the wrong-minimum guard off)",
           "vipm_track/cold_start.py", "need = RETRY_MIN_INLIER_SHARE if retry else "
           "COLD_MIN_INLIER_SHARE", "need = 0.0", ESTIMATOR_TESTS),
    Mutant("covariance-10x", "estimator", "scale: the reported std 10× too small",
           "vipm_track/pair_result.py",
           "return np.sqrt(np.clip(np.diag(self.covariance), 0.0, None))",
           "return 0.1 * np.sqrt(np.clip(np.diag(self.covariance), 0.0, None))",
           ESTIMATOR_TESTS),
    Mutant("blur-invariant-phase-not-doubled", "estimator",
           "dropped term: the blur-invariant spectra keep the plain phase",
           "vipm_track/poc_kernels.py",
           "sr, si = (re * re - im * im) / weight_h, 2 * re * im / weight_h",
           "sr, si = re, im", ("tests/test_poc.py", *ESTIMATOR_TESTS)),
    Mutant("blur-invariant-share-rule-off", "estimator",
           "threshold: a blur-invariant fit on any share of its patches is taken",
           "vipm_track/refinement.py", "BLUR_INVARIANT_MIN_INLIER_SHARE = 0.3",
           "BLUR_INVARIANT_MIN_INLIER_SHARE = 0.0", ESTIMATOR_TESTS),
    Mutant("shutter-rate-term-from-frame-k-1", "estimator",
           "swapped columns: the rolling shutter's unknown rate taken for frame k-1's",
           "vipm_track/bundle.py", "n, [N_PARAMS + 3, N_PARAMS + 4])",
           "n, [N_PARAMS + 1, N_PARAMS + 2])",
           ("tests/test_bundle.py", *ESTIMATOR_TESTS)),
    # --- renderer ----------------------------------------------------------------------------
    Mutant("render-texel-half-offset", "renderer",
           "off-by-half: texel centres at (u + 0.5)·mpt",
           "vipm_track/render.py",
           "texel_from_world = np.array([[1 / s, 0.0, 0.0], [0.0, -1 / s, 0.0], [0.0, 0.0, 1.0]])",
           "texel_from_world = np.array([[1 / s, 0.0, 0.5], [0.0, -1 / s, 0.0], [0.0, 0.0, 1.0]])",
           RENDER_TESTS),
    Mutant("rolling-shutter-centred", "renderer",
           "off-by-half: rolling-shutter rows timed from the image centre, not row 0",
           "vipm_track/sim.py",
           "centre = k + readout * (0.5 * (r0 + r1 - 1)) / camera.height",
           "centre = k + readout * (0.5 * (r0 + r1 - 1) - 0.5 * camera.height) / camera.height",
           RENDER_TESTS),
    # --- EKF ---------------------------------------------------------------------------------
    Mutant("ekf-no-pair-update", "EKF", "dropped term: pairs never update the state",
           "filters/ekf.py", "        if keep:\n            rows = np.array(keep)",
           "        if False:\n            rows = np.array(keep)", EKF_TESTS),
    Mutant("ekf-pair-noise-100x", "EKF", "scale: pair covariance 100× too large",
           "filters/ekf.py", "r = self._cfg.noise.pair_covariance(m.covariance, m.z[6])",
           "r = 100.0 * self._cfg.noise.pair_covariance(m.covariance, m.z[6])", EKF_TESTS),
    Mutant("ekf-gate-100x-tight", "EKF", "threshold: the pose/motion gate 100× too tight",
           "filters/ekf.py", "self._gate_pose = float(chi2.ppf(self._cfg.gate_probability, 4))",
           "self._gate_pose = 0.01 * float(chi2.ppf(self._cfg.gate_probability, 4))",
           EKF_TESTS),
    Mutant("model-scale-inverted", "EKF", "inverted: tx, tz scaled by h_m / h0",
           "filters/model.py", "    k = height_assumed / h_m\n    # np.array",
           "    k = h_m / height_assumed\n    # np.array", EKF_TESTS),
    Mutant("model-yaw-sign", "EKF", "sign flip: the expected pair's yaw",
           "filters/model.py", "        pose_curr[2] - pose_prev[2],\n    ]).T",
           "        pose_prev[2] - pose_curr[2],\n    ]).T", EKF_TESTS),
    Mutant("ekf-wheel-speed-ignored", "EKF", "dropped term: wheel speeds never applied",
           "filters/ekf.py", "            speed_nis, speed_gated = self._update_speed(speed)",
           "            speed_nis, speed_gated = float('nan'), False", EKF_TESTS),
    # --- smoother ----------------------------------------------------------------------------
    Mutant("smoother-pairs-weightless", "smoother",
           "dropped term: pair factors carry no information (covariance × 10⁶)",
           "filters/smoother.py", "cov = cfg.noise.pair_covariance(m.covariance, m.z[6])\n",
           "cov = 1e6 * cfg.noise.pair_covariance(m.covariance, m.z[6])\n", SMOOTHER_TESTS),
    Mutant("smoother-no-speed", "smoother", "dropped term: no wheel-speed factor",
           "filters/smoother.py", "    if math.isfinite(speed):\n        out.append(F.speed_factor",
           "    if False:\n        out.append(F.speed_factor", SMOOTHER_TESTS),
    Mutant("smoother-dt-off-by-one", "smoother",
           "off-by-one: each frame's interval is the next one's",
           "filters/smoother.py", "dts = np.concatenate([[0.0], np.diff(t)])",
           "dts = np.concatenate([np.diff(t), [0.0]])", SMOOTHER_TESTS),
    # --- monitor -----------------------------------------------------------------------------
    Mutant("monitor-threshold-3x", "monitor", "threshold: alarm at 3× the CUSUM threshold",
           "filters/monitor_core.py", "alarm = usable & (top >= 1.0) & ~invalid_now",
           "alarm = usable & (top >= 3.0) & ~invalid_now", MONITOR_TESTS),
    Mutant("monitor-one-sided", "monitor", "dropped term: only the upward CUSUM side",
           "filters/monitor_core.py", "signed = np.stack([u, -u], axis=2)[..., None]",
           "signed = np.stack([u, u], axis=2)[..., None]", MONITOR_TESTS),
    Mutant("monitor-no-road-term", "monitor", "dropped term: the road tilt's variance",
           "filters/monitor_core.py", "w = (sv / (rho * rho) + road_lrv) * s.corr_factor",
           "w = sv / (rho * rho) * s.corr_factor", MONITOR_TESTS),
    Mutant("monitor-errors-taken-white", "monitor",
           "dropped factor: the errors' measured correlation left out of the test's variance",
           "filters/monitor_core.py", "w = (sv / (rho * rho) + road_lrv) * s.corr_factor",
           "w = sv / (rho * rho) + road_lrv", MONITOR_TESTS),
    Mutant("monitor-correlation-not-delayed", "monitor",
           "missing delay: a change's own innovations widen its test at once",
           "filters/monitor_core.py",
           "s.corr_factor = np.where(np.isfinite(s.corr_recent[..., 0]), s.corr_recent[..., 0],",
           "s.corr_factor = np.where(False, s.corr_recent[..., 0],", MONITOR_TESTS),
    Mutant("monitor-calibrated-interval-sign", "monitor",
           "sign flip: CALIBRATED where the mean minus (not plus) its interval is within bounds",
           "filters/monitor_core.py",
           "beyond = np.abs(mean) + self.config.calibrate_within_z * se > self.calibrated_bound()",
           "beyond = np.abs(mean) - self.config.calibrate_within_z * se > self.calibrated_bound()",
           MONITOR_TESTS),
    Mutant("monitor-clear-off-by-one", "monitor",
           "off-by-one: RECALIBRATE clears one frame late",
           "filters/monitor_core.py",
           "base = np.where(recal & (s.quiet >= self.clear_frames), CALIBRATED, base)",
           "base = np.where(recal & (s.quiet > self.clear_frames), CALIBRATED, base)",
           MONITOR_TESTS),
    Mutant("monitor-calibrated-without-mean", "monitor",
           "dropped condition: CALIBRATED without the mean deviation within the tolerance",
           "filters/monitor_core.py",
           "settled = enough & (kept | within)", "settled = enough", MONITOR_TESTS),
    Mutant("monitor-offset-clipped-to-tolerance", "monitor",
           "dropped floor: a frame's innovation clipped to 3 σ even inside the tolerance",
           "filters/monitor_core.py",
           "lim = np.maximum(cfg.huber_k * np.sqrt(sv + road_var), self._clip_floor)",
           "lim = cfg.huber_k * np.sqrt(sv + road_var)", MONITOR_TESTS),
    Mutant("monitor-one-frame-alarm", "monitor",
           "dropped cap: one frame can carry a test over its threshold",
           "filters/monitor_core.py",
           "new = np.maximum(0.0, s.cusum + np.minimum(inc, cap))",
           "new = np.maximum(0.0, s.cusum + inc)", MONITOR_TESTS),
    Mutant("monitor-calibrated-keeps-untested-axis", "monitor",
           "dropped condition: CALIBRATED kept when an axis untested on entering is tested",
           "filters/monitor_core.py",
           "kept = (base == CALIBRATED) & ~np.any(tested & ~s.vouched, axis=1)",
           "kept = base == CALIBRATED", MONITOR_TESTS),
    Mutant("readout-stake-sign", "estimator",
           "sign flip: the stake's travel change taken the other way round",
           "vipm_track/readout_stake.py",
           "r.motion.distance / base[j].motion.distance - 1.0",
           "base[j].motion.distance / r.motion.distance - 1.0",
           ("tests/test_estimate_warnings.py",)),
    Mutant("monitor-body-window-in-pairs", "monitor",
           "unit: the body std's measuring span in pairs, not seconds",
           "filters/monitor_types.py", "math.ceil(self.body_window_min_s * self.fps)",
           "math.ceil(self.body_window_min_s)", MONITOR_TESTS),
    Mutant("mount-sigma-not-widened", "EKF",
           "dropped term: the mount's σ not widened by the pairs' error correlation",
           "filters/row_correlation.py", "mount_cov=estimate.mount_cov * s)",
           "mount_cov=estimate.mount_cov)",
           ("tests/test_row_correlation.py", "tests/test_ekf.py")),
    Mutant("rows-kept-after-the-last", "table reader",
           "greedy: each row kept if after the last kept (one corrupt row drops the rest)",
           "vipm_track/increasing.py",
           "for i in np.flatnonzero(ending + starting - 1 == total).tolist():\n"
           "        if ending[i] == len(out) + 1 and (not out or v[i] > v[out[-1]]):",
           "for i in range(v.size):\n        if not out or v[i] > v[out[-1]]:",
           ("tests/test_increasing.py",)),
    Mutant("odd-first-frame-is-a-wrong-camera", "estimator",
           "threshold: the first frame of another size fails the run",
           "vipm_track/pipeline.py",
           "if sum(s.status.startswith(WRONG_SIZE) for s in held) >= FIRST_SIZE_FRAMES:",
           "if True:", ("tests/test_pipeline.py", "tests/test_kitti.py")),
    Mutant("given-pitch-unquestioned", "estimator",
           "tolerance ×10: a given pitch the travel contradicts passes",
           "vipm_track/commands/inputs.py",
           "if abs(off) <= GIVEN_PITCH_TOLERANCE_DEG + 3.0 * travel.standard_error_deg:",
           "if abs(off) <= 10 * GIVEN_PITCH_TOLERANCE_DEG + 3.0 * travel.standard_error_deg:",
           ("tests/test_kitti.py",)),
    # --- table writer ------------------------------------------------------------------------
    Mutant("table-pitch-prev-swapped", "table writer", "swapped columns: pitch ↔ prev_pitch",
           "vipm_track/measurement.py",
           '        "pitch_deg": val(z[2]),\n        "roll_deg": val(z[3]),',
           '        "pitch_deg": val(z[0]),\n        "roll_deg": val(z[3]),', TABLE_TESTS),
    Mutant("table-std-in-radians", "table writer", "unit: std columns written in radians",
           "vipm_track/measurement.py",
           "s = np.where(_ANGLE, np.degrees(m.std), m.std)", "s = m.std", TABLE_TESTS),
    Mutant("table-3-decimals", "table writer", "precision: floats written with 3 decimals",
           "vipm_track/table.py", 'return repr(float(f"{v:.{digits}g}"))',
           'return f"{v:.3f}"', TABLE_TESTS),
    Mutant("table-reader-skips-row", "table writer", "off-by-one: the reader drops the first row",
           "vipm_track/table.py", "header = [h.strip() for h in next(reader)]",
           "header = [h.strip() for h in next(reader)]; next(reader, None)", TABLE_TESTS),
    Mutant("lever-arm-sway-dropped", "filters' motion",
           "dropped term: the camera's sway as the body rolls left out of its lateral motion",
           "filters/lever_arm.py",
           "roll_change = state[M.BODY_ROLL] - state[M.PREV_BODY_ROLL]",
           "roll_change = 0.0 * state[M.BODY_ROLL]", LEVER_ARM_TESTS),
    Mutant("lever-arm-fit-variance-dropped", "filters' motion",
           "dropped term: the lever arms' own uncertainty not in the lateral motion's σ",
           "filters/lever_arm.py", "cov[0, 0] += x @ cov_arms @ x", "cov[0, 0] += 0.0",
           LEVER_ARM_TESTS),
    Mutant("lever-arm-height-unscaled", "filters' motion",
           "unit: the pair's lateral motion taken at the assumed height, not in metres",
           "filters/filter_common.py", "    return m.z[4:7] * scale - motion,",
           "    return m.z[4:7] - motion,",
           LEVER_ARM_TESTS),
    Mutant("lever-arm-batch-causal", "filters' motion",
           "wrong fit: the batch's frames take the arms of the pairs up to each, not the drive's",
           "filters/smoothing.py",
           "frames = widened_drive(corrected_drive(frames, by_frame, lever_std), by_frame)",
           "frames = widened_drive([LeverArm(lever_std).corrected(f, by_frame.get(f.frame)) "
           "for f in frames], by_frame)", LEVER_ARM_TESTS),
    Mutant("motion-sigma-not-widened", "filters' motion",
           "dropped term: the frame's motion σ not widened by its pairs' error correlation",
           "filters/row_correlation.py",
           "out.update(motion_cov=estimate.motion_cov * np.outer(scale[2:], scale[2:]))",
           "out.update(motion_cov=estimate.motion_cov)", LEVER_ARM_TESTS),
    Mutant("monitor-step-search-off", "monitor",
           "dropped step: the new extrinsics always the median since the CUSUM's change time",
           "filters/monitor.py", "            if step > 0:\n", "            if False:\n",
           (*MONITOR_TESTS, "tests/test_monitor_segments.py")),
    Mutant("monitor-step-ignores-road", "monitor",
           "dropped term: a told road's wander not counted against a step",
           "filters/monitor.py",
           "factor = core.s.corr_factor[0] * np.nanmedian([h.road for h in window], axis=0)",
           "factor = core.s.corr_factor[0] * np.ones_like(window[0].road)",
           (*MONITOR_TESTS, "tests/test_monitor_segments.py")),
    Mutant("late-pair-in-heave", "filters' motion",
           "guard dropped: a late pair's height residual taken against another frame's",
           "filters/heave.py", "if estimate.t <= t_before:", "if False:",
           ("tests/test_lever_arm.py", "tests/test_heave.py")),
    Mutant("camera-matrix-strided", "estimator",
           "layout: a camera matrix kept as the strided view it was read as",
           "vipm_track/camera.py", "k = np.ascontiguousarray(self.k, dtype=float)",
           "k = np.asarray(self.k, dtype=float)", ("tests/test_kitti.py",)),
    Mutant("interrupted-chunk-runs-on", "nothing lost",
           "stop request ignored: an interrupted chunk runs on and its pairs are lost",
           "vipm_track/parallel.py", "        if _stop_requested is not None and "
           "_stop_requested.is_set():\n            break", "        pass",
           ("tests/test_pipeline.py",)),
    Mutant("crop-batch-unzeroed", "estimator",
           "zeroing dropped: a patch leaving the image keeps whatever its memory held",
           "vipm_track/poc_kernels.py", "            out[k] = 0.0\n            continue\n"
           "        total = 0.0", "            continue\n        total = 0.0",
           ("tests/test_poc.py",)),
    Mutant("nominal-travel-first-pairs", "estimator",
           "the cold start's travel and ground fit from the drive's first pairs, not spread",
           "vipm_track/nominal_search.py", "MIN_STRETCH = 3\n", "MIN_STRETCH = 10**9\n",
           ("tests/test_nominal_search.py",)),
    Mutant("nominal-ground-fit-first-pairs", "estimator",
           "the spread travel checked against a ground fit on the drive's first pairs",
           "vipm_track/nominal_search.py",
           "spread = spread_pairs(source, camera, confirm_pairs, max_frames)",
           "spread = pairs[i:i + confirm_pairs]", ("tests/test_nominal_search.py",)),
    Mutant("nominal-stretches-not-bridged", "estimator",
           "a stretch's travel pair cannot run on into the next (a slow start loses it)",
           "vipm_track/nominal_search.py", "STRETCHES_BRIDGED = 2\n", "STRETCHES_BRIDGED = 1\n",
           ("tests/test_nominal_search.py",)),
    Mutant("nominal-scattered-travel-ignored", "estimator",
           "a ground fit far from travel whose pairs scatter is taken for the camera's pose",
           "vipm_track/nominal_search.py",
           "    return _off_axis_travel(search, travel) or _off_travel_pitch(search, travel)",
           "    return _off_axis_travel(search, travel)", ("tests/test_nominal_search.py",)),
    Mutant("long-baseline-never", "estimator",
           "dropped feature: a slow level camera's pair is never read over a longer baseline",
           "vipm_track/pair_chain.py",
           "self._long_baseline = tracking and _reads_long_baselines(estimator)",
           "self._long_baseline = False",
           ("tests/test_long_baseline.py",)),
    Mutant("long-baseline-pose-not-taken", "estimator",
           "dropped update: the longer pair's pose is estimated and then not taken",
           "vipm_track/long_baseline.py",
           "    x = x + gain @ (y - x[_POSE])\n",
           "    x = x + 0.0 * gain @ (y - x[_POSE])\n",
           ("tests/test_long_baseline.py",)),
    Mutant("long-baseline-frame-r-unheld", "estimator",
           "wrong guess: the earlier frame seeded with frame k's pose, not its own estimate",
           "vipm_track/long_baseline.py",
           "guess = PairGuess(after.pose_prev, newest.pose_curr, motion)",
           "guess = PairGuess(newest.pose_curr, newest.pose_curr, motion)",
           ("tests/test_long_baseline.py",)),
    Mutant("long-baseline-composed-backwards", "estimator",
           "wrong order: the pairs between composed from frame k back to the earlier frame",
           "vipm_track/long_baseline.py",
           "motion, after = compose_motion(pair.motion, motion), pair",
           "motion, after = compose_motion(motion, pair.motion), pair",
           ("tests/test_long_baseline.py",)),
    Mutant("long-baseline-spread-steers", "estimator",
           "dropped step: a second start's spread left in the covariance that sets the gain",
           "vipm_track/long_baseline.py",
           "cov = np.asarray(result.covariance, dtype=float) - extra",
           "cov = np.asarray(result.covariance, dtype=float)",
           ("tests/test_long_baseline.py",)),
    Mutant("long-baseline-with-vertical-motion", "estimator",
           "dropped condition: a fit with vertical motion conditioned on pitch and roll alone",
           "vipm_track/pair_chain.py",
           "and not config.vertical_motion and config.long_baseline_heights > 0)",
           "and config.long_baseline_heights > 0)",
           ("tests/test_long_baseline.py",)),
    Mutant("long-baseline-in-tight-turns", "estimator",
           "dropped rule: a tight turn's pair is read over the longer baseline too",
           "vipm_track/long_baseline.py",
           "TIGHT_TURN_DEG_PER_M = 4.0\n", "TIGHT_TURN_DEG_PER_M = math.inf\n",
           ("tests/test_long_baseline.py",)),
    Mutant("long-baseline-on-shaking-bodies", "estimator",
           "dropped rule: a shaking body's pair is read over the longer baseline too",
           "vipm_track/long_baseline.py",
           "SHAKING_DEG_PER_S = 4.0\n", "SHAKING_DEG_PER_S = math.inf\n",
           ("tests/test_long_baseline.py",)),
    Mutant("tracking-never-restarts-from-nominal", "estimator",
           "a tracked pose that wandered into a wrong basin is kept",
           "vipm_track/pair_chain.py",
           "    chosen, dropped = (other, result) if better else (result, other)",
           "    chosen, dropped = (result, other)",
           ("tests/test_traffic_verdicts.py", "tests/test_pair_chain.py")),
    Mutant("second-start-spread-ignored", "estimator",
           "a pair whose two starts found two minima states the one it keeps as sure",
           "vipm_track/pair_chain.py",
           "    spread = np.outer(d, d)",
           "    spread = np.zeros((7, 7))",
           ("tests/test_traffic_verdicts.py", "tests/test_pair_chain.py")),
    Mutant("chain-without-second-start", "estimator",
           "the chain never starts a wandered tracked pair from the nominal",
           "vipm_track/pair_chain.py",
           '        if guess is not None and result.status == "ok":',
           "        if False:", ("tests/test_pair_chain.py", "tests/test_pipeline.py")),
    Mutant("chain-prepares-each-start", "estimator",
           "a live camera's pair is prepared again for its second start or cold retry",
           "vipm_track/pair_chain.py",
           "            prepared = prepare_images(self.estimator, prev, curr)",
           "            prepared = None", ("tests/test_pair_chain.py",)),
    Mutant("cold-retry-prepares-again", "estimator",
           "a live camera's failed tracked pair is prepared again for its cold retry",
           "vipm_track/pair_chain.py",
           "            result = estimate_pair(self.estimator, prev, curr, None, dt, prepared)",
           "            result = estimate_pair(self.estimator, prev, curr, None, dt)",
           ("tests/test_pair_chain.py",)),
    Mutant("table-height-not-checked", "table",
           "an ok row without its assumed height is fed to the filters (the batch smoother's "
           "system indeterminate)",
           "vipm_track/measurement.py",
           "                    and math.isfinite(self.height_assumed))",
           "                    and True)",
           ("tests/test_nothing_lost.py", "tests/test_pipeline.py")),
    Mutant("table-units-not-checked", "table",
           "a table in nanoseconds or millimetres is read as seconds and metres",
           "vipm_track/measurement.py",
           "    if not consecutive.any():\n        return\n    problem",
           "    if True:\n        return\n    problem",
           ("tests/test_pipeline.py",)),
    Mutant("monitor-slow-by-nominal", "monitor",
           "a steep camera against a level nominal is held as a slow forward camera",
           "filters/monitor_inputs.py",
           "slow_pairs(z, h0, min_travel_frac_forward) & level_pitches(np.degrees(z[:, 2]))",
           "slow_pairs(z, h0, min_travel_frac_forward)",
           ("tests/test_monitor.py",)),
    Mutant("yaml-value-error-escapes", "table",
           "a date YAML cannot build (2024-13-45) escapes as a traceback",
           "vipm_track/errors.py",
           "    except (ValueError, TypeError, OverflowError) as exc:\n        raise InvalidYaml",
           "    except (TypeError, OverflowError) as exc:\n        raise InvalidYaml",
           ("tests/test_monitor.py::test_nominal_errors_name_file_and_key",)),
    Mutant("bus-interrupt-drops-samples", "table",
           "Ctrl-C while listening to a CAN bus throws the decoded samples away",
           "filters/speed_decoder.py",
           "    except KeyboardInterrupt:\n        decoder.summary.interrupted = True",
           "    except ZeroDivisionError:\n        decoder.summary.interrupted = True",
           ("tests/test_wheel_speed.py::test_an_interrupted_bus_keeps_what_it_decoded",)),
    Mutant("fleet-relative-paths", "table",
           "a fleet hands its scheduler's workers paths relative to this folder",
           "vipm_track/commands/fleet.py",
           "    specs = [spec.absolute() for spec in find_drives(args.drives)]",
           "    specs = find_drives(args.drives)",
           ("tests/test_fleet.py::test_relative_paths_reach_the_workers_absolute",)),
    Mutant("fleet-dataset-every-folder", "table",
           "the fleet's dataset serves every done drive folder in OUT, an earlier run's too",
           "vipm_track/fleet/cluster.py",
           '               if r["status"] == "ok" and r["drive"] is not None]',
           '               if r["drive"] is not None] + list(out.glob("drive=*"))',
           ("tests/test_fleet.py::test_the_dataset_serves_the_last_runs_drives",)),
    Mutant("failed-drive-folder-kept", "table",
           "a drive that failed leaves its empty partition folder",
           "vipm_track/fleet/drive_run.py",
           "    with contextlib.suppress(OSError):  # absent, or holding the user's own files\n"
           "        folder.rmdir()",
           "    with contextlib.suppress(OSError):  # absent, or holding the user's own files\n"
           "        pass",
           ("tests/test_fleet.py::test_drives_ok_and_broken_ones_are_rows",)),
    Mutant("camera-matrix-unchecked", "table",
           "a camera matrix whose last row is not 0 0 1 is taken (its fx, fy, cx, cy read)",
           "vipm_track/camera.py",
           "    if np.all(np.abs(fixed) <= 1e-9):\n        return None",
           "    if True:\n        return None",
           ("tests/test_camera.py",)),
    Mutant("fisheye-without-coefficients-pinhole", "table",
           "a fisheye lens whose coefficients are all zero is taken for a pinhole camera",
           "vipm_track/camera.py",
           "return self.is_fisheye or bool(np.any(self.distortion != 0))",
           "return bool(np.any(self.distortion != 0))",
           ("tests/test_camera.py",)),
    Mutant("times-first-of-two-numbers", "table",
           "an 'index time' line of times.txt is read by its first number",
           "vipm_track/sources.py",
           "        if any(_is_number(f) for f in fields[1:]):",
           "        if False:",
           ("tests/test_sources.py",)),
    Mutant("speed-scale-unchecked", "table",
           "a wheel speed 3.6x the images' travel (km/h) goes without a word",
           "filters/speed_check.py",
           "    if pairs >= MIN_SCALE_PAIRS and not (",
           "    if pairs < 0 and not (",
           ("tests/test_speed_check.py",)),
    Mutant("speed-clock-offset-unchecked", "table",
           "a wheel speed on a clock 0.5 s off goes without a word",
           "filters/speed_check.py",
           "    if abs(fit.offset_s) > max(MIN_OFFSET_S, OFFSET_SIGMAS * fit.std_s):",
           "    if abs(fit.offset_s) > 1e9:",
           ("tests/test_speed_check.py",)),
    Mutant("no-std-knock-not-looked-for", "smoother",
           "without the marginals the drive summary looks for no knock",
           "filters/drive_summary.py",
           "        steps = _pairs_steps(t, measurements, step_test)",
           "        steps = []",
           ("tests/test_smoother.py::test_the_drive_summary_is_of_the_mount_since_a_knock",)),
    Mutant("marginals-interrupt-drops-estimate", "smoother",
           "Ctrl-C while the batch computes its marginals throws the converged estimate away",
           "filters/smoother.py",
           "        except KeyboardInterrupt:  # the estimate has converged: it is kept, without"
           " its σ\n            interrupted = True",
           "        except ZeroDivisionError:\n            interrupted = True",
           ("tests/test_nothing_lost.py::"
            "test_ctrl_c_while_the_batch_computes_its_marginals_keeps_the_estimate",)),
    Mutant("estimator-options-with-a-table", "table",
           "estimator options given with --estimates are silently ignored",
           "vipm_track/commands/estimator_options.py",
           "    if given:\n        raise InputError(",
           "    if given and False:\n        raise InputError(",
           ("tests/test_option_checks.py",)),
    Mutant("track-unfollowed-step-silent", "ekf",
           "a knock the EKF's change test missed goes without a word",
           "filters/mount_change.py",
           "    if not missed:\n        return \"\"",
           "    if True:\n        return \"\"",
           ("tests/test_ekf.py::"
            "test_track_warns_of_a_step_its_mount_change_test_did_not_find",)),
    Mutant("monitor-second-axis-unsaid", "monitor",
           "a second axis off while RECALIBRATE is held is neither said nor announced",
           "filters/monitor.py",
           "        off = self._axes_off(interval) if state == \"RECALIBRATE\" else set()",
           "        off = set()",
           ("tests/test_monitor.py::test_a_second_change_while_recalibrate_is_held_is_said",)),
    Mutant("monitor-moved-again-unseen", "monitor",
           "dropped check: a second knock while RECALIBRATE is held waits for the step test",
           "filters/monitor.py", "            if cut is not None:\n", "            if False:\n",
           ("tests/test_monitor.py::"
            "test_the_interval_holds_the_camera_soon_after_a_second_change",)),
    Mutant("monitor-moved-again-forgotten", "monitor",
           "dropped memory: a second move found on one frame is looked for again on the next",
           "filters/monitor.py",
           "                self._step_at = moved if self._step_at is None else max(self._step_at, "
           "moved)\n", "",
           ("tests/test_monitor.py::test_a_second_move_found_stays_found",)),
    Mutant("clock-offset-residuals-independent", "filters' motion",
           "dropped term: the clock offset's σ counts correlated residuals as independent",
           "filters/clock_offset.py", "    std *= correlation_inflation(residual[used_v])\n",
           "    pass\n",
           ("tests/test_speed_check.py",)),
    Mutant("start-direction-from-aliased-pairs", "filters' motion",
           "guard dropped: a drive at 30 m/s starts in its first pairs' direction",
           "filters/model.py",
           "        if known.size and float(np.median(known)) > REVERSING_MAX_SPEED_MPS:",
           "        if False:",
           ("tests/test_reversing.py",)),
    Mutant("can-interrupt-mid-batch", "wheel speed",
           "an interrupt raised in the read loop's body (handlers not deferred)",
           "vipm_track/errors.py",
           "        with _interrupts_to(note, keep_ignored=True):\n",
           "        with _interrupts_to(signal.getsignal(signal.SIGINT), keep_ignored=True):\n",
           ("tests/test_wheel_speed.py::test_an_interrupt_between_reads_keeps_what_was_read",)),
    Mutant("drift-rate-from-lagging-mount", "report",
           "wrong series: the drift rate fitted to the filter's mount, which lags a knock",
           "vipm_track/sinks/drift_summary.py",
           "    if tx.size < 4 or np.ptp(x) == 0:\n",
           "    if True:\n",
           ("tests/test_drift_report.py",)),
    Mutant("creep-reported-at-lagging-mount", "report",
           "threshold moved: a creeping axis keeps the filter's lagging mount as its value",
           "vipm_track/sinks/drift_summary.py",
           "    if fit.creeps and abs(fit.rate) > DRIFT_SIGMAS * fit.rate_std:\n",
           "    if fit.creeps and abs(fit.rate) > 1e9 * fit.rate_std:\n",
           ("tests/test_drift_report.py",)),
    Mutant("monitor-creep-read-from-median", "monitor",
           "dropped branch: a creeping mount's new extrinsics from the frames' median alone",
           "filters/monitor.py",
           "            line = self._line_end(np.array([h.t for h in hist])[ok], d,\n",
           "            line = None and self._line_end(np.array([h.t for h in hist])[ok], d,\n",
           ("tests/test_monitor.py::test_new_extrinsics_of_a_creeping_mount_are_where_it_is_now",)),
    Mutant("images-sorted-as-text", "table",
           "wrong key: an image folder sorted as text (frame_10 before frame_2)",
           "vipm_track/sources.py",
           "        key=lambda p: (natural_key(p.name), p.name))",
           "        key=lambda p: p.name)",
           ("tests/test_sources.py",)),
    Mutant("fisheye-flag-ignored", "table",
           "dropped key: OpenCV's fisheye_model: 1 read as plumb_bob",
           "vipm_track/camera.py",
           "        fisheye = _flag(fs.getNode(\"fisheye_model\"), path, \"fisheye_model\")\n",
           "        fisheye = False\n",
           ("tests/test_camera.py",)),
    Mutant("times-in-milliseconds-taken", "table",
           "bound dropped: frame times 100 s apart taken as seconds",
           "vipm_track/frame_rates.py",
           "    if 1.0 / high <= interval <= 1.0 / low:\n",
           "    if True:\n",
           ("tests/test_sources.py", "tests/test_option_checks.py")),
    Mutant("live-data-back-without-data", "live",
           "'data back' announced while the watchdog's reason still holds",
           "vipm_track/live_monitor.py",
           "        if self._holds:\n",
           "        if False:\n",
           ("tests/test_live.py::test_a_wheel_speed_that_never_came_is_no_data_back",)),
    Mutant("summary-height-unchecked", "filters",
           "dropped check: the summary's height the smoothed mount's whatever the pairs say",
           "filters/drive_summary.py",
           "            if i == 2 and abs(offset) > 1.96",
           "            if False and abs(offset) > 1.96",
           ("tests/test_smoother.py::test_smooth_summary_height_of_a_swinging_camera_holds_its_mean",)),
    Mutant("fixed-lag-never-holds", "filters",
           "dropped hold: fixed-lag frames reported while a mount change builds up",
           "filters/fixed_lag.py",
           "        holding = math.isfinite(self._mount_change.pending_since(HOLD_AT))\n",
           "        holding = False\n",
           ("tests/test_smoother.py::test_fixed_lag_holds_the_mount_across_a_knock_its_test_calls_late",)),
    Mutant("fixed-lag-stale-held-frames", "filters",
           "kept stash: held frames reported as they were before the mount's jump",
           "filters/fixed_lag.py",
           "        if out:  # the held frames are reported as the window has them after the jump\n"
           "            self._held.clear()\n",
           "",
           ("tests/test_smoother.py::test_fixed_lag_holds_the_mount_across_a_knock_its_test_calls_late",)),
    Mutant("live-speed-silence-holds-frames", "live",
           "held input: frames withheld from the monitor while the wheel speed is silent",
           "vipm_track/live_monitor.py",
           "        for decided in self.online.step(m, a.t):\n",
           "        for decided in self.online.step(m, a.t, self._holds.get(\"speed\", \"\")):\n",
           ("tests/test_live.py::test_a_knock_while_the_wheel_speed_is_silent_is_no_calibrated_camera",)),
    Mutant("live-same-state-event-dropped", "live",
           "dropped event: an axis going off within RECALIBRATE not announced",
           "vipm_track/live_monitor.py",
           "        elif out.event is not None and (out.state != self._reported or "
           "out.state != \"HOLD\"):",
           "        elif out.event is not None and out.state != self._reported:",
           ("tests/test_live.py::test_an_axis_going_off_within_recalibrate_is_announced",)),
    Mutant("report-unfollowed-step-kept", "sinks",
           "dropped check: the report's current value a mount that never followed the frames' step",
           "vipm_track/sinks/drift_summary.py",
           "    if level is not None and abs(level[0] - current) > Z95",
           "    if False and abs(level[0] - current) > Z95",
           ("tests/test_drift_report.py",)),
    Mutant("fleet-resume-ignores-outputs", "fleet",
           "dropped check: a done drive skipped though its tables are gone",
           "vipm_track/fleet/drive_run.py",
           "    problem = _outputs_problem(folder)\n",
           "    problem = \"\"\n",
           ("tests/test_fleet.py::test_resume_redoes_a_drive_whose_outputs_are_gone",)),
    Mutant("fleet-drive-partition-inferred", "fleet",
           "inferred type: drive=01 read as the integer 1",
           "vipm_track/fleet/cluster.py",
           "DRIVE_PARTITIONING = ds.partitioning(pa.schema([(\"drive\", pa.string())]), "
           "flavor=\"hive\")",
           "DRIVE_PARTITIONING = \"hive\"",
           ("tests/test_fleet.py::test_numeric_drive_names_stay_apart_and_text",)),
    Mutant("can-disagreeing-copies-mixed", "can",
           "dropped refusal: a speed message's differing copies on two channels decoded together",
           "filters/speed_decoder.py",
           "        wanted.refused = text\n        self.summary.notes.append(text)\n"
           "        raise InputError(text)\n",
           "        return\n",
           ("tests/test_can_channels.py",)),
    Mutant("live-speed-hold-over-alarm", "live",
           "HOLD said over an alarm: silent wheels withdraw a pitch alarm, raised again after",
           "vipm_track/live_monitor.py",
           "                over_alarm = key == \"speed\" and self._reported in ALARMS\n",
           "                over_alarm = False\n",
           ("tests/test_live.py::test_wheel_speed_silent_during_an_alarm_holds_only_the_height",)),
    Mutant("can-wrap-needs-busy-bus", "can",
           "tight bound: a wrap-around unwrapped only with frames within 5 ms across it",
           "filters/speed_decoder.py",
           "        if -WRAP_TOLERANCE_S <= WRAP_S - back <= WRAP_GAP_S:\n",
           "        if abs(back - WRAP_S) <= WRAP_TOLERANCE_S:\n",
           ("tests/test_can_time_order.py",)),
    Mutant("can-mirror-window-5ms", "can",
           "tight bound: a gateway's copies 20 ms late refused as another signal",
           "filters/speed_decoder.py",
           "MIRROR_WINDOW_S = 0.05\n",
           "MIRROR_WINDOW_S = 0.005\n",
           ("tests/test_can_channels.py",)),
    Mutant("fixed-lag-hold-unbounded", "filters",
           "dropped bound: frames held for as long as a change builds up, to the drive's end",
           "filters/fixed_lag.py",
           "MAX_HOLD_S = 5.0\n",
           "MAX_HOLD_S = 1e9\n",
           ("tests/test_smoother.py::test_a_change_that_never_comes_holds_frames_no_longer_than_the_bound",)),
    Mutant("fixed-lag-step-watch-off", "filters",
           "dropped check: the fixed lag's step watch finds a knock and the window ignores it",
           "filters/fixed_lag.py",
           "            out.append(self._jump(j, onset, s))\n",
           "            pass\n",
           (_EARLY_KNOCK, _FOLLOWED_KNOCK)),
    Mutant("step-watch-from-the-window", "filters",
           "dropped part: the step watch's series starts after the bootstrap frames",
           "filters/fixed_lag.py",
           "                self._steps.add(m.t, float(m.z[2]), float(m.z[3]))\n        convex",
           "                pass\n        convex",
           (_EARLY_KNOCK, _FOLLOWED_KNOCK,
            "tests/test_smoother.py::test_fixed_lag_looks_for_a_knock_in_the_frames_it_started_on")),
    Mutant("fixed-lag-no-last-step-test", "filters",
           "dropped check: the drive's end is not tested for a knock between two blocks' tests",
           "filters/fixed_lag.py",
           "self._watched_jumps(self._t_last, last=True)",
           "self._watched_jumps(self._t_last, last=False)",
           ("tests/test_smoother.py::test_fixed_lag_tests_for_a_knock_once_more_at_the_drive_s_end",)),
    Mutant("step-watch-last-pair-waits", "filters",
           "dropped condition: the last pair waits for the next block's test like any other",
           "filters/step_watch.py",
           "(t < self._next_test and not last)",
           "t < self._next_test",
           ("tests/test_step_watch.py::test_the_last_pair_is_tested_whenever_it_comes",)),
    Mutant("ekf-step-watch-off", "filters",
           "dropped check: the EKF's step watch finds a knock and the mount is not re-opened",
           "filters/ekf.py",
           "            step[j], onset[j] = d, at\n",
           "            pass\n",
           ("tests/test_drift_report.py::"
            "test_a_track_table_whose_mount_missed_an_early_knock_reports_where_the_frames_sit",)),
    Mutant("fixed-lag-watch-refinds-calls", "filters",
           "dropped call: the step watch is not told the online test's changes",
           "filters/fixed_lag.py",
           "            self._steps.followed(onset, int(j))\n",
           "            pass\n",
           ("tests/test_smoother.py::test_fixed_lag_jumps_once_at_a_knock_both_its_tests_find",)),
    Mutant("step-watch-threshold-batch", "filters",
           "threshold: the step watch's test at the batch's 5 (a road's wander called)",
           "filters/step_watch.py",
           "THRESHOLD = 10.0\n",
           "THRESHOLD = 5.0\n",
           ("tests/test_step_watch.py",)),
)


def _copy_tree(dest: Path) -> Path:
    """Copy tracked and untracked-not-ignored files of the working tree to ``dest/repo``, with
    ``dest/shared`` linking to the real ``../shared``; returns the copy's root."""
    files = subprocess.run(["git", "ls-files", "-co", "--exclude-standard", "-z"], cwd=ROOT,
                           check=True, capture_output=True).stdout.decode().split("\0")
    repo = dest / "repo"
    for name in filter(None, files):
        src = ROOT / name
        target = repo / name
        if src.is_symlink():  # (vipm_track/filters: left out, the tests imported the
            target.parent.mkdir(parents=True, exist_ok=True)  # installed, unmutated filters)
            target.symlink_to(os.readlink(src))
            continue
        if not src.is_file():
            continue
        target.parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(src, target)
    shared = ROOT.parent / "shared"
    if shared.exists():
        (dest / "shared").symlink_to(shared)
    return repo


def _env(repo: Path) -> dict[str, str]:
    env = dict(os.environ)
    env["PYTHONPATH"] = str(repo) + os.pathsep + env.get("PYTHONPATH", "")
    env["PYTHONDONTWRITEBYTECODE"] = "1"
    return env


def _run_tests(repo: Path, tests: tuple[str, ...], timeout: float) -> tuple[set[str], str]:
    """Failing test ids (FAILED/ERROR, and xfail(strict) that passed) of one pytest run, and
    a note ('' or 'timeout' / 'collection error')."""
    cmd = [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "-rfEX",
           "--no-header", "-o", "addopts=", *tests]
    try:
        out = subprocess.run(cmd, cwd=repo, env=_env(repo), capture_output=True, text=True,
                             timeout=timeout)
    except subprocess.TimeoutExpired:
        return set(), "timeout"
    text = out.stdout + out.stderr
    failed = set(re.findall(r"^(?:FAILED|ERROR|XPASS)\s+(\S+)", text, flags=re.M))
    failed = {f.split(" - ")[0] for f in failed}
    note = ""
    if out.returncode not in (0, 1) and not failed:
        note = f"pytest exit {out.returncode}: " + text.strip().splitlines()[-1][:120]
    return failed, note


def _short(test: str) -> str:
    return test.removeprefix("tests/").replace(".py::", "::")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--only", nargs="*", help="mutant names to run (default: all)")
    parser.add_argument("--list", action="store_true", help="list the mutants and exit")
    parser.add_argument("--timeout", type=float, default=900.0,
                        help="seconds per pytest run (a run past it counts as caught)")
    parser.add_argument("--out", type=Path, default=RESULTS)
    args = parser.parse_args(argv)
    mutants = [m for m in MUTANTS if not args.only or m.name in args.only]
    if args.list:
        for m in mutants:
            print(f"{m.name:32s} {m.part:13s} {m.what}")
        return 0
    start = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="bite-") as tmp:
        repo = _copy_tree(Path(tmp))
        probe = subprocess.run([sys.executable, "-c", "import vipm_track, filters; "
                                "import vipm_track.filters as f; print(vipm_track.__file__); "
                                "print(filters.__file__); print(f.__file__)"],
                               cwd=repo, env=_env(repo), capture_output=True, text=True)
        if not all(line.startswith(str(repo)) for line in probe.stdout.split()):
            print(f"the copy does not import its own modules:\n{probe.stdout}{probe.stderr}",
                  file=sys.stderr)
            return 2
        all_tests = tuple(dict.fromkeys(t for m in mutants for t in m.tests))
        print(f"baseline: {len(all_tests)} test selections on the unmutated copy ...",
              flush=True)
        broken, note = _run_tests(repo, all_tests, args.timeout)
        if note:
            print(f"baseline run: {note}", file=sys.stderr)
            return 2
        if broken:
            print(f"failing without any mutant (left out): {sorted(broken)}", flush=True)
        rows = []
        for m in mutants:
            path = repo / m.path
            original = path.read_text()
            count = original.count(m.old)
            if count != 1:
                rows.append((m, None, f"snippet found {count}× in {m.path}: mutant out of date"))
                print(f"{m.name}: snippet found {count}×", flush=True)
                continue
            path.write_text(original.replace(m.old, m.new))
            t0 = time.perf_counter()
            try:
                failed, note = _run_tests(repo, m.tests, args.timeout)
            finally:
                path.write_text(original)
            caught = sorted(failed - broken)
            rows.append((m, caught, note))
            verdict = "caught" if caught or note == "timeout" else "SURVIVED"
            print(f"{m.name}: {verdict} by {len(caught)} tests ({time.perf_counter() - t0:.0f} s)"
                  f"{' ' + note if note else ''}", flush=True)
    text = _report(rows, broken, time.perf_counter() - start)
    print(text)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(text)
    survived = [m.name for m, caught, note in rows if not caught and note != "timeout"]
    return 1 if survived else 0


def _report(rows, broken: set[str], seconds: float) -> str:
    n_caught = sum(1 for _, caught, note in rows if caught or note == "timeout")
    lines = [
        "# Do the tests bite? A mutation check",
        "",
        f"{n_caught} of {len(rows)} mutants caught. Each mutant is one typical mistake put into a "
        "copy of the source; the tests listed ran on it and those that failed are named (the "
        "first 6, then a count). Command: `python scripts/check_tests_bite.py` "
        f"({seconds / 60:.0f} min on this machine, 2 shared cores).",
        "",
        "| mutant | part | mistake | caught by |",
        "| --- | --- | --- | --- |",
    ]
    for m, caught, note in rows:
        if caught is None:
            cell = f"not run: {note}"
        elif caught:
            names = [_short(c) for c in caught]
            cell = ", ".join(f"`{n}`" for n in names[:6])
            if len(names) > 6:
                cell += f" and {len(names) - 6} more"
        elif note == "timeout":
            cell = "the tests ran past the timeout (counted as caught)"
        else:
            cell = f"**survived**{': ' + note if note else ''}"
        lines.append(f"| `{m.name}` | {m.part} | {m.what} | {cell} |")
    if broken:
        lines += ["", "Failing on the unmutated copy (left out of the table): "
                  + ", ".join(f"`{_short(b)}`" for b in sorted(broken))]
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    raise SystemExit(main())
