"""Accuracy and consistency of a filter's estimates against a simulated drive's truth.

A method (EKF, fixed-lag smoother, batch smoother, ...) is evaluated through
:class:`Estimates`, plain per-frame arrays, so every method is judged by the same code:
RMS of the mount angles after a settling time, height error, NEES of the mount + body
states and NIS of the pairs, with their chi-square bounds.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.stats import chi2

from .drive_sim import DriveRun, DriveTruth

FloatArray = NDArray[np.float64]

#: components of ``Estimates.states`` (and of the truth) in order
STATE_FIELDS: tuple[str, ...] = (
    "mount_pitch", "mount_roll", "mount_height", "body_pitch", "body_roll",
)


@dataclass(frozen=True)
class Estimates:
    """Per-frame estimates of one method over one drive (n frames; rad, m).

    ``states`` (n, 5) = (pitch_m, roll_m, h_m, b_pitch, b_roll), ``covariances`` (n, 5, 5)
    their covariance (NaN before the method has an estimate); ``nis`` (n,) the 7-dof NIS of
    each applied pair (NaN where none, e.g. for a smoother); ``resets`` how often the method
    re-initialised."""

    states: FloatArray
    covariances: FloatArray
    nis: FloatArray
    resets: int = 0
    #: (n, 3) vehicle pose (x, y, heading) in the world of ``filters.model``, where known
    poses: FloatArray | None = None


def truth_states(truth: DriveTruth) -> FloatArray:
    """(n, 5) true (pitch_m, roll_m, h_m, b_pitch, b_roll) of a drive."""
    return np.stack([getattr(truth, f) for f in STATE_FIELDS], axis=1)


def rms_after(t: FloatArray, error: FloatArray, t_min: float) -> float:
    """RMS of ``error`` over the frames at ``t`` ≥ ``t_min`` (NaN errors count as missing)."""
    sel = (t >= t_min) & np.isfinite(error)
    return float(np.sqrt(np.mean(error[sel] ** 2))) if np.any(sel) else float("nan")


def nees(est: Estimates, truth: DriveTruth, components: Sequence[int]) -> FloatArray:
    """(n,) normalised estimation error squared over ``components`` of ``STATE_FIELDS``
    (NaN where the method has no estimate)."""
    idx = list(components)
    e = est.states[:, idx] - truth_states(truth)[:, idx]
    p = est.covariances[:, idx][:, :, idx]
    out = np.full(len(e), np.nan)
    good = np.all(np.isfinite(e), axis=1) & np.all(np.isfinite(p), axis=(1, 2))
    out[good] = np.einsum("ni,ni->n", e[good], np.linalg.solve(p[good], e[good][..., None])[..., 0])
    return out


def chi2_bounds(dof: int, n_avg: int, probability: float = 0.95) -> tuple[float, float]:
    """Two-sided bounds of the mean of ``n_avg`` independent χ²(dof) values."""
    lo, hi = chi2.ppf([(1 - probability) / 2, (1 + probability) / 2], dof * n_avg)
    return float(lo / n_avg), float(hi / n_avg)


@dataclass(frozen=True)
class RunScores:
    """Scores of one method on one drive (degrees / percent as named)."""

    pitch_rms_deg: float
    roll_rms_deg: float
    raw_pitch_rms_deg: float
    raw_roll_rms_deg: float
    height_err_max_pct: float
    resets: int


def score_run(
    run: DriveRun, est: Estimates, settle_s: float = 5.0, height_settle_s: float = 10.0
) -> RunScores:
    """Mount pitch/roll RMS after ``settle_s`` (method and raw per-frame estimates of the
    current frame against the mount) and the largest height error after ``height_settle_s``."""
    tr = run.truth
    raw = np.where(run.status == "ok", 1.0, np.nan)
    err_h = np.abs(est.states[:, 2] - tr.mount_height) / tr.mount_height
    sel = tr.t >= height_settle_s
    raw_pitch, raw_roll = raw * (run.z[:, 2] - tr.mount_pitch), raw * (run.z[:, 3] - tr.mount_roll)
    return RunScores(
        pitch_rms_deg=np.degrees(rms_after(tr.t, est.states[:, 0] - tr.mount_pitch, settle_s)),
        roll_rms_deg=np.degrees(rms_after(tr.t, est.states[:, 1] - tr.mount_roll, settle_s)),
        raw_pitch_rms_deg=np.degrees(rms_after(tr.t, raw_pitch, settle_s)),
        raw_roll_rms_deg=np.degrees(rms_after(tr.t, raw_roll, settle_s)),
        height_err_max_pct=100.0 * float(np.nanmax(err_h[sel])) if np.any(sel) else float("nan"),
        resets=est.resets,
    )


@dataclass(frozen=True)
class Consistency:
    """Monte Carlo consistency over M runs: average NEES / NIS and their 95 % bounds.

    ``anees`` is the NEES averaged over runs and time; ``anees_bounds`` the bounds of an
    M-run average at one time (Bar-Shalom), ``anees_inside`` the fraction of times whose
    M-run average lies inside them. ``anis*`` the same for the pairs' 7-dof NIS (times where
    every run applied a pair). ``nis_pooled`` averages all applied pairs' NIS; for a perfectly
    matched model it lies in ``nis_pooled_bounds`` (very tight for thousands of pairs)."""

    dof: int
    anees: float
    anees_bounds: tuple[float, float]
    anees_inside: float
    anis: float
    anis_bounds: tuple[float, float]
    anis_inside: float
    nis_pooled: float
    nis_pooled_bounds: tuple[float, float]


def consistency(
    runs: Sequence[DriveRun], ests: Sequence[Estimates], components: Sequence[int],
    settle_s: float = 5.0,
) -> Consistency:
    """NEES / NIS consistency of a method over Monte Carlo ``runs`` of equal length."""
    m = len(runs)
    t = runs[0].truth.t
    late = t >= settle_s
    dof = len(list(components))
    ne = np.stack([nees(e, r.truth, components) for r, e in zip(runs, ests, strict=True)])
    ne_t = np.mean(ne[:, late], axis=0)
    ne_t = ne_t[np.isfinite(ne_t)]
    lo, hi = chi2_bounds(dof, m)
    ni = np.stack([e.nis for e in ests])[:, late]
    ni_t = np.mean(ni, axis=0)
    ni_t = ni_t[np.isfinite(ni_t)]
    nlo, nhi = chi2_bounds(7, m)
    pooled = ni[np.isfinite(ni)]
    return Consistency(
        dof=dof, anees=float(np.mean(ne_t)), anees_bounds=(lo, hi),
        anees_inside=float(np.mean((ne_t >= lo) & (ne_t <= hi))),
        anis=float(np.mean(ni_t)) if len(ni_t) else float("nan"), anis_bounds=(nlo, nhi),
        anis_inside=float(np.mean((ni_t >= nlo) & (ni_t <= nhi))) if len(ni_t) else float("nan"),
        nis_pooled=float(np.mean(pooled)) if len(pooled) else float("nan"),
        nis_pooled_bounds=chi2_bounds(7, max(len(pooled), 1)),
    )


def from_filter_states(states: Sequence[object]) -> Estimates:
    """:class:`Estimates` of a list of ``filters.ekf.FilterState`` (NIS only of fully
    applied pairs: a gated pair's NIS is an outlier's, not the filter's)."""
    from . import model as M

    idx = [M.MOUNT_PITCH, M.MOUNT_ROLL, M.MOUNT_HEIGHT, M.BODY_PITCH, M.BODY_ROLL]
    x = np.stack([s.state[idx] for s in states])  # type: ignore[attr-defined]
    p = np.stack([s.covariance[np.ix_(idx, idx)] for s in states])  # type: ignore[attr-defined]
    nis = np.array([s.nis if s.status == "ok" else np.nan for s in states])  # type: ignore[attr-defined]
    resets = sum(1 for s in states if s.status == "reset")  # type: ignore[attr-defined]
    poses = None
    if all(hasattr(s, "position") and hasattr(s, "heading") for s in states):
        poses = np.array([[*s.position, s.heading] for s in states])  # type: ignore[attr-defined]
    return Estimates(states=x, covariances=p, nis=nis, resets=resets, poses=poses)
