"""The camera's lever arms: its sideways slide in turns and its sway as the body rolls,
measured from the pairs and added to the filters' lateral motion.

The filters' model moves the camera as the vehicle, along its heading, with the body's
pitch and roll as rotations in place (``filters.model``). A real camera sits away from the
points the vehicle rotates about, so its ground frame's origin also moves sideways

- by L·sin Δψ over a pair that turns by Δψ, L metres ahead of the point the vehicle turns
  about (a car's rear axle), and
- by H·Δρ when the body rolls by Δρ (rad; > 0 the right side down) about an axis H metres
  below the camera (a car's roll centre, near the ground).

The filters took both as noise of the pairs' tx (the first as ``NoiseParams.lever_arm_std_m``),
so their own tx lacked them: on KITTI 07 the smoothed lateral motion was 30 mm RMS off per
frame (the pairs' own 10 mm) at a stated σ of 1.3 mm (its 95 % interval held 7.5 % of the
frames); against the truth, L ≈ 1.0 m and H ≈ 1.3–1.5 m leave 3–4 mm.

(L, H) are constants of the rig. They are the slopes of the pairs' lateral residuals against
the filter's (measured tx − filtered tx, metres) on sin Δψ and on the filter's body-roll
change over the pair (not the pair's own, whose error is tied to its tx's): a weighted
least-squares fit with the prior N(0, ``lever_arm_std_m``²) on each, its covariance scaled
up by the residuals' reduced χ² where the pairs scatter more than they state. The filter's
tx becomes tx + L·sin Δψ + H·Δρ, its variance gains the fit's and the roll change's; the
heading, the vehicle's positions, the poses and the mount are the filter's own (a path
chained from the frames' tx takes the slide). One fit per frame from the pairs so far (the
EKF, the fixed lag) or one over the whole drive (the batch); a prior σ of 0 (``--lever-arm-std
0``) holds both arms at 0.
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import TypeVar

import numpy as np
from numpy.typing import NDArray

from vipm_track.measurement import PairMeasurement

from . import model as M
from .filter_common import FrameEstimate, motion_residual

FloatArray = NDArray[np.float64]
Estimate = TypeVar("Estimate", bound=FrameEstimate)

#: a pair whose lateral residual is further than this many σ from what the fit so far
#: predicts does not enter it: a lateral outlier
MAX_Z = 5.0
#: the fewest pairs whose scatter about the fit scales its covariance (fewer: as stated),
#: and from which on the fit gates the pairs (before, one outlier among the first pairs that
#: turn would set the arms and shut the good pairs out)
MIN_PAIRS_FOR_SCATTER = 10


def _regressors(estimate: FrameEstimate) -> FloatArray | None:
    """(sin Δψ, Δρ) of the estimate's pair (radians), None where either is unknown."""
    yaw = estimate.motion[2] if estimate.motion is not None else math.nan
    state = estimate.state
    roll_change = state[M.BODY_ROLL] - state[M.PREV_BODY_ROLL]
    x = np.array([math.sin(yaw), roll_change])
    return x if np.all(np.isfinite(x)) else None


class LeverArm:
    """The fit of the lever arms (L, H) (module doc), fed in frame order with each estimate
    and its pair; :meth:`corrected` gives an estimate's tx with the camera's slide added."""

    def __init__(self, prior_std_m: float) -> None:
        """``prior_std_m``: the prior σ of each arm, metres; 0 holds both at 0 (the filters'
        ``--lever-arm-std 0``: the camera moves as the vehicle)."""
        if not prior_std_m >= 0:
            raise ValueError(f"prior_std_m must be >= 0, got {prior_std_m}")
        self.enabled = prior_std_m > 0
        self._prior_info = np.eye(2) / (float(prior_std_m) ** 2 if self.enabled else 1.0)
        self._info = self._prior_info.copy()  # Σ x xᵀ/v + the prior's
        self._moment = np.zeros(2)  # Σ x r / v
        self._chi2_sum = 0.0  # Σ r²/v
        self._pairs = 0

    @property
    def arms_m(self) -> FloatArray:
        """(L, H), metres: the camera ahead of the point the vehicle turns about, and above
        the axis its body rolls about."""
        return np.linalg.solve(self._info, self._moment)

    @property
    def covariance(self) -> FloatArray:
        """2×2 covariance of :attr:`arms_m`, widened by the pairs' scatter about the fit."""
        return np.linalg.inv(self._info) * self._scatter()

    def _scatter(self) -> float:
        """The pairs' reduced χ² about the fit, at least 1 (1 before enough pairs)."""
        if self._pairs < MIN_PAIRS_FOR_SCATTER:
            return 1.0
        # Σ (r − xᵀθ)²/v by the sums (the prior's share of the information taken out)
        arms = self.arms_m
        chi2 = self._chi2_sum - arms @ self._moment - arms @ self._prior_info @ arms
        return max(1.0, chi2 / (self._pairs - 2))

    def observe(self, estimate: FrameEstimate, m: PairMeasurement | None,
                gate: LeverArm | None = None) -> None:
        """Take ``m``'s lateral residual against ``estimate`` into the fit, where the filter
        applied the pair (not gated, not late: a late pair's estimate is another frame's) and
        it :meth:`fits` ``gate`` (default: this fit, from its ``MIN_PAIRS_FOR_SCATTER``-th
        pair on)."""
        if not self.enabled or m is None or estimate.frame != m.frame:
            return
        x, residual = _regressors(estimate), motion_residual(estimate, m)
        if x is None or residual is None:
            return
        r, v = float(residual[0][0]), float(residual[1][0])
        if not (math.isfinite(r) and math.isfinite(v) and v > 0):
            return
        if gate is not None:
            if not gate.fits(r, x, v):
                return
        elif self._pairs >= MIN_PAIRS_FOR_SCATTER and not self.fits(r, x, v):
            return
        self._info += np.outer(x, x) / v
        self._moment += x * r / v
        self._chi2_sum += r * r / v
        self._pairs += 1

    def fits(self, residual: float, x: FloatArray, var: float) -> bool:
        """Whether a pair's lateral ``residual`` (m, stated variance ``var`` m², regressors
        ``x``) is within ``MAX_Z`` σ of the fit, the pairs' scatter about it counted."""
        scatter = self._scatter()
        predicted = var * scatter + x @ np.linalg.inv(self._info) @ x * scatter
        return (residual - x @ self.arms_m) ** 2 <= MAX_Z**2 * predicted

    def apply(self, estimate: Estimate) -> Estimate:
        """``estimate`` with L·sin Δψ + H·Δρ added to its tx, and their variance to tx's."""
        x = _regressors(estimate)
        if not self.enabled or x is None or not np.all(np.isfinite(estimate.motion)):
            return estimate
        (ahead, above), cov_arms = self.arms_m, self.covariance
        yaw = float(estimate.motion[2])
        jac = np.eye(3)
        jac[0, 2] = ahead * math.cos(yaw)
        cov = jac @ estimate.motion_cov @ jac.T
        p = estimate.covariance
        roll_change_var = (p[M.BODY_ROLL, M.BODY_ROLL] + p[M.PREV_BODY_ROLL, M.PREV_BODY_ROLL]
                           - 2.0 * p[M.BODY_ROLL, M.PREV_BODY_ROLL])
        if math.isfinite(roll_change_var):
            cov[0, 0] += above**2 * max(roll_change_var, 0.0)
        cov[0, 0] += x @ cov_arms @ x
        shifted = estimate.motion.copy()
        shifted[0] += x @ np.array([ahead, above])
        return replace(estimate, motion=shifted, motion_cov=cov)

    def corrected(self, estimate: Estimate, m: PairMeasurement | None) -> Estimate:
        """:meth:`observe` then :meth:`apply`: the fit of the pairs up to this one."""
        self.observe(estimate, m)
        return self.apply(estimate)


def corrected_drive(estimates: list[Estimate], measurements: dict[int, PairMeasurement],
                    prior_std_m: float) -> list[Estimate]:
    """A whole drive's estimates (a batch) with the slide of the fit over all its pairs;
    ``measurements`` by frame. Fitted twice: the second time every pair is gated against the
    first fit, so that an outlier among the drive's first turning pairs is left out too."""
    first = LeverArm(prior_std_m)
    for e in estimates:
        first.observe(e, measurements.get(e.frame))
    lever = LeverArm(prior_std_m)
    for e in estimates:
        lever.observe(e, measurements.get(e.frame), gate=first)
    return [lever.apply(e) for e in estimates]
