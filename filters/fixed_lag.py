"""Fixed-lag smoother: Gauss–Newton over a sliding window of the smoother's factor graph.

The window holds the frames of the last ``lag_s`` seconds plus one anchor frame. Its cost is
the factor graph of ``filters.smoother`` (the same factors, evaluated for all pairs at once by
``window_rows.stacked_rows``) plus a Gaussian prior on the anchor: the marginal of everything
that already left the window (a Schur complement, linearised where the frame left, as in
every sliding-window estimator). The information matrix of a window is block tridiagonal in
frame order, so one Gauss–Newton step is a banded Cholesky solve (LAPACK ``pbtrf``) of
11 × (window length) unknowns.

Each new frame starts where its pair's measured motion puts it (``smoother.dead_reckoned``,
as the batch's initial guess; ``model.propagate_pose`` without a usable pair) and the window
is re-solved (warm start, usually 1–2 steps); a frame is reported once ``lag_s`` of later
data is in, with its joint marginal covariance with the previous frame (read off the last
block of the Cholesky factor, the window being ordered newest first), then marginalised.

Why not gtsam's ``IncrementalFixedLagSmoother``: a Python ``CustomFactor`` gets a *copy* of
all values of iSAM2's window for every call, which made it ~140 frames/s; this window runs
at 650–900 frames/s (2 s lag) with the same model and answers (a test checks that with a lag
longer than the drive it equals ``smooth_batch``): the rows (``window_rows``) and their
normal equations (``_add_rows``) are compiled loops, the rest is LAPACK and small numpy.
"""

from __future__ import annotations

import contextlib
import ctypes
import dataclasses
import glob
import math
import os
from collections.abc import Iterator
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from numpy.typing import NDArray
from scipy.linalg.lapack import dpbtrf, dpbtrs

from vipm_track.compiled import kernel
from vipm_track.measurement import PairMeasurement

from . import model as M
from . import window_rows as W
from .body_scale import pairs_to_start
from .mount_change import MountChangeDetector, jump_variance
from .smoother import BodyTracker, _initial_guess, _make_frame, _skipped, _status, dead_reckoned
from .smoother_config import SmoothedFrame, SmootherConfig

FloatArray = NDArray[np.float64]

_D = W.FRAME_DIM
# frame-variable order (window_rows.FRAME_DIM) → index in the model's 16-state
_STATE_OF_VAR = np.array(
    [M.POS_X, M.POS_Y, M.HEADING, M.SPEED, M.YAW_RATE, M.MOUNT_PITCH, M.MOUNT_ROLL,
     M.MOUNT_HEIGHT, M.MOUNT_YAW, M.BODY_PITCH, M.BODY_ROLL]
)
# 16×22 map from (frame k-1, frame k) variables to the model's 16-state of frame k
_T_STATE = np.zeros((M.STATE_DIM, 2 * _D))
_T_STATE[_STATE_OF_VAR, _D + np.arange(_D)] = 1.0
_T_STATE[[M.PREV_POS_X, M.PREV_POS_Y, M.PREV_HEADING], [0, 1, 2]] = 1.0
_T_STATE[[M.PREV_BODY_PITCH, M.PREV_BODY_ROLL], [9, 10]] = 1.0
_FIELDS = tuple(f.name for f in dataclasses.fields(W.StackedPairs))


class _PairStore:
    """The window's pair constants (``window_rows.StackedPairs`` fields, one row per pair) in
    growable arrays: appended at the end, dropped from either end, viewed without copying."""

    def __init__(self) -> None:
        self._arrays: dict[str, np.ndarray] = {}
        self._lo = self._hi = 0

    def __len__(self) -> int:
        return self._hi - self._lo

    def append(self, row: dict[str, object]) -> None:
        cap = len(next(iter(self._arrays.values()))) if self._arrays else 0
        if self._hi == cap:  # full: move the rows to the front of arrays twice their number
            n = len(self)
            new_cap = max(64, 2 * n)
            self._arrays = {
                f: _moved(self._arrays.get(f), self._lo, self._hi, new_cap, row[f])
                for f in _FIELDS
            }
            self._lo, self._hi = 0, n
        for f in _FIELDS:
            self._arrays[f][self._hi] = row[f]
        self._hi += 1

    def pop_front(self) -> None:
        self._lo += 1

    def pop_back(self) -> None:
        self._hi -= 1

    def field(self, name: str, i: int) -> np.ndarray:
        """Pair ``i``'s (from the front) row of field ``name``, a view to change in place."""
        return self._arrays[name][self._lo + i]

    def view(self, n: int | None = None) -> W.StackedPairs:
        """The pairs (the first ``n`` only, if given) as StackedPairs of array views."""
        hi = self._hi if n is None else self._lo + n
        return W.StackedPairs(**{f: a[self._lo : hi] for f, a in self._arrays.items()})


def _moved(
    old: np.ndarray | None, lo: int, hi: int, cap: int, example: object
) -> np.ndarray:
    """A (cap, …) array shaped for rows like ``example`` holding ``old[lo:hi]`` first."""
    ex = np.asarray(example)
    new = np.zeros((cap, *ex.shape), dtype=ex.dtype)
    if old is not None:
        new[: hi - lo] = old[lo:hi]
    return new


@dataclass(frozen=True)
class _LastSolve:
    """What the window's last Gauss–Newton step leaves for the output and marginalisation."""

    factor: FloatArray  # banded Cholesky factor (reversed order)
    norms: FloatArray  # (n-1, 2) Gaussian norms of the pair blocks
    first: tuple[FloatArray, FloatArray, FloatArray] | None  # anchor pair's r, J, point


class SolveError(RuntimeError):
    """The window's normal equations are not positive definite (a variable lost all
    constraints, or the numbers blew up)."""


class FixedLagSmoother:
    """Sliding-window smoother over ``config.lag_s`` seconds. Feed frames with ``step``; it
    returns the frames that have ``lag_s`` of later data (smoothed with it), oldest first;
    ``finish`` returns the rest, smoothed with the data there is."""

    def __init__(self, config: SmootherConfig | None = None) -> None:
        cfg = config or SmootherConfig(lag_s=2.0)
        if cfg.lag_s <= 0:
            raise ValueError("FixedLagSmoother needs lag_s > 0 (use smooth_batch for 0)")
        self._cfg = cfg
        self._loss = (cfg.loss, cfg.pair_loss_k(4), cfg.pair_loss_k(3))
        self._speed_loss = (cfg.speed_loss, cfg.loss_k(1))
        self._start_pose: tuple[float, float, float] = (0.0, 0.0, 0.0)
        self._reset: tuple[int, str] | None = None
        #: frames before the window starts: (pair, wheel speed, body std)
        self._boot: list[tuple[PairMeasurement, float, FloatArray]] = []
        self._body = BodyTracker(cfg)
        self._start_pairs = pairs_to_start(cfg.init_pairs, cfg.body_window_s,
                                           cfg.body_window_min_pairs)
        self._mount_change = MountChangeDetector(cfg.mount_change)
        self._started = False
        self._t_last = -math.inf
        self._last_speed_t = -math.inf
        self._direction = 1.0  # of travel, model.travel_direction
        self._still: dict[int, bool] = {}  # frame → standstill, until the frame is emitted
        self._clear()

    # --- public ------------------------------------------------------------------------------

    def step(self, m: PairMeasurement, speed: float = float("nan")) -> list[SmoothedFrame]:
        """Add frame ``m`` (with the wheel speed at its time, m/s, NaN if none); return the
        frames that are now final."""
        if not (math.isfinite(m.t) and m.t > self._t_last):
            return [_skipped(m, f"time {m.t} not after the previous frame's")]
        self._t_last = m.t
        self._still[m.frame] = bool(M.standstill_states(speed, m.status, self._cfg.noise))
        body_std = self._body.observe(m)
        if not self._started:
            self._boot.append((m, speed, body_std))
            if sum(b.ok for b, _, _ in self._boot[1:]) < self._start_pairs:
                return []
            boot, self._boot = self._boot, []
            with one_blas_thread():
                return self._start(boot)
        saved = self._x.copy()
        self._append(m, speed, body_std)
        with one_blas_thread():
            try:
                self._solve()
            except SolveError as exc:
                self._x = saved
                return self._restart(m, speed, body_std, exc)
            return self._emit(final=False)

    def finish(self) -> list[SmoothedFrame]:
        """Frames still in the window (and any never started), smoothed with the data there is."""
        if not self._started:
            if not self._boot:
                return []
            boot, self._boot = self._boot, []
            with one_blas_thread():
                return self._start(boot, final=True)
        with one_blas_thread():
            return self._emit(final=True)

    # --- window storage ------------------------------------------------------------------------

    def _clear(self) -> None:
        self._ms: list[PairMeasurement] = []  # frames lo … hi-1
        self._x = np.zeros((0, _D))  # estimates of the window's frames
        self._c = _PairStore()  # pair constants of frames lo+1 … hi-1
        self._prior: tuple[FloatArray, FloatArray] | None = None  # (R, μ) on the anchor
        self._emitted = 0  # frames of the window already reported (the anchor, if 1)
        # the last solve: factor, pair norms, and the anchor pair's rows (r, J) with the point
        # (anchor and next frame) they were linearised at; None once the window changes
        self._last: _LastSolve | None = None

    def _pairs(self) -> W.StackedPairs:
        return self._c.view()

    def _append(self, m: PairMeasurement, speed: float, body_std: FloatArray) -> None:
        """Add frame ``m`` to the window, started from the newest one moved by its pair (by
        the motion model without a usable pair); ``body_std``: its body std, rad."""
        prev_m, prev = self._ms[-1], self._x[-1]
        dt = m.t - prev_m.t
        if math.isfinite(speed):
            self._last_speed_t = m.t
        metric = m.t - self._last_speed_t <= self._cfg.speed_timeout_s
        new = prev.copy()
        if m.ok:
            # the pair's own motion, as the batch's initial guess: a prediction from the last
            # speed and yaw rate can be so far off after a manoeuvre that the robust loss
            # rejects the pair, and every later one (the estimate locks onto the old motion)
            new[0:3] = dead_reckoned((prev[0], prev[1], prev[2]), prev[7], prev[8], m)
            new[3:5] = M.pair_rates(m.z, prev[7], m.height_assumed, dt)
            new[9:11] = m.z[2:4] - prev[5:7]
        else:
            new[0:3] = M.propagate_pose(prev[0], prev[1], prev[2], prev[3], prev[4], dt)
            new[9:11] = 0.0
        self._direction = M.travel_direction(self._direction, speed, m.z if m.ok else None)
        speed = M.signed_speed(speed, self._direction)
        if math.isfinite(speed):
            new[3] = speed
        for i in M.standstill_states(speed, m.status, self._cfg.noise):
            new[3 if i == M.SPEED else 4] = 0.0  # standing: start from the pseudo-measurement
        self._push_pair(m, dt, speed, metric, body_std)
        self._ms.append(m)
        self._x = np.vstack([self._x, new])
        self._last = None
        if m.ok:
            self._watch_mount(m, dt, prev, body_std)

    def _watch_mount(
        self, m: PairMeasurement, dt: float, prev: FloatArray, body_std: FloatArray
    ) -> None:
        """Feed the mount-change test (``filters.mount_change``) the newest pair's angles
        against the window's prediction (the newest frame's mount plus its decayed body); on a
        step, let the mount jump into the frame where it began (or the window's oldest pair,
        if that frame is final already)."""
        decay, _ = M.body_transition(dt, self._cfg.noise, body_std)
        cov = self._cfg.noise.pair_covariance(m.covariance, m.z[6])
        innovation = m.z[2:4] - (prev[5:7] + decay * prev[9:11])
        step = self._mount_change.update(m.t, innovation, body_std**2 + np.diag(cov)[2:4])
        for j in np.flatnonzero(np.isfinite(step)):
            onset = self._mount_change.onset[j]
            # pair p joins frames p and p + 1 of the window
            p = next((i for i in range(len(self._c)) if self._ms[i + 1].t >= onset),
                     len(self._c) - 1)
            jump = np.zeros(2)
            jump[j] = jump_variance(step[j])
            pm = self._ms[p + 1]
            W.apply_mount_jump(self._c.field("lin_jac", p), self._c.field("lin_b", p), pm,
                               pm.t - self._ms[p].t, self._cfg.noise, jump)

    def _push_pair(
        self, m: PairMeasurement, dt: float, speed: float, metric: bool, body_std: FloatArray
    ) -> None:
        row = W.pair_constants(
            m, dt, speed, self._cfg.noise, self._cfg.cross_track_std_m, bool(metric),
            self._cfg.motion_given_pose, body_std,
        )
        self._c.append(row)

    # --- start / restart -----------------------------------------------------------------------

    def _start(
        self, boot: list[tuple[PairMeasurement, float, FloatArray]], final: bool = False
    ) -> list[SmoothedFrame]:
        """Open a window on the bootstrap frames (the batch's initial guess), solve it."""
        cfg = self._cfg
        ms = [b for b, _, _ in boot]
        sp = np.array([s for _, s, _ in boot], dtype=float)
        t = np.array([b.t for b in ms])
        dts = np.concatenate([[0.0], np.diff(t)])
        g = _initial_guess(ms, sp, dts, cfg.height_m, self._start_pose, cfg.noise)
        sp, self._direction = g.wheel_speed, g.direction
        self._clear()
        self._started = True
        x = np.zeros((len(ms), _D))
        x[:, 0:3] = g.pose
        x[:, 3], x[:, 4] = g.speed, g.yaw_rate
        x[:, 5:7], x[:, 7], x[:, 8] = g.mount, g.height, g.yaw_m
        x[:, 9:11] = g.body
        self._x = x
        self._ms = list(ms)
        self._prior = _first_prior(x[0], sp[0], cfg, ms[0].status)
        for i in range(1, len(ms)):
            if math.isfinite(sp[i]):
                self._last_speed_t = float(t[i])
            metric = t[i] - self._last_speed_t <= cfg.speed_timeout_s
            # the bootstrap frames with the shaking all of them showed
            self._push_pair(ms[i], float(dts[i]), float(sp[i]), bool(metric), boot[-1][2])
        if math.isfinite(sp[0]):
            self._last_speed_t = max(self._last_speed_t, float(t[0]))
        try:
            self._solve(max_iterations=cfg.max_iterations)
        except SolveError as exc:  # nothing to fall back on: report the frames as skipped
            self._started = False
            why = f"smoother could not start: {exc}"
            return [_skipped(b, why) for b in ms]
        return self._emit(final=final)

    def _restart(
        self, m: PairMeasurement, speed: float, body_std: FloatArray, exc: Exception
    ) -> list[SmoothedFrame]:
        """Emit the window from the last good solution, then start a new window at ``m``
        (bootstrapped again, continuing the trajectory), as the EKF resets."""
        why = f"smoother restarted: {exc}"
        # drop m (the last frame, appended before the failed solve)
        self._ms.pop()
        self._c.pop_back()
        self._x = self._x[: len(self._ms)]
        self._last = None
        try:
            out = self._emit(final=True)
        except SolveError:
            out = [_skipped(w, why) for w in self._ms[self._emitted :]]
        good = [f for f in out if np.all(np.isfinite(f.position))]
        if good:
            last = good[-1]
            self._start_pose = (float(last.position[0]), float(last.position[1]), last.heading)
        self._reset = (m.frame, why)
        self._started = False
        self._boot = [(m, speed, body_std)]
        self._clear()
        return out

    # --- Gauss–Newton over the window ----------------------------------------------------------

    def _normal_equations(self) -> tuple[FloatArray, FloatArray, FloatArray, tuple | None]:
        """Normal equations of the window at the current estimate: the information matrix in
        LAPACK's upper band storage (2D × nD) of the *reversed* variable order (newest frame
        first, so the last blocks of its Cholesky factor belong to the oldest frames), the
        gradient (n, D) in frame order, the pair blocks' Gaussian norms (n-1, 2), and the
        anchor pair's (r, J, point) (None for one frame)."""
        x = self._x
        n = len(x)
        ab = np.zeros((2 * _D, n * _D), order="F")
        g = np.zeros(n * _D)
        norms = np.zeros((0, 2))
        first = None
        if n > 1:
            r, j, norms = W.stacked_rows(x[:-1], x[1:], self._pairs(), self._loss, self._speed_loss)
            _add_pair_rows(j, r, ab, g)
            first = (r[0], j[0], x[0:2].reshape(-1).copy())
        rp, mu = self._prior  # type: ignore[misc]
        _add_rows(rp, rp @ (x[0] - mu), 0, ab, g)
        return ab, g.reshape(n, _D), norms, first

    def _factor(self, ab: FloatArray) -> FloatArray:
        """Banded upper Cholesky factor of the band ``ab`` of ``_normal_equations``."""
        # LAPACK directly (scipy's cholesky_banded wrapper costs as much as the factorisation)
        if not np.all(np.isfinite(ab)):
            raise SolveError("window information not finite")
        cb, info = dpbtrf(ab, lower=0, overwrite_ab=1)
        if info != 0:
            raise SolveError(f"window information not positive definite (leading minor {info})")
        return cb

    def _solve(self, max_iterations: int | None = None) -> None:
        """Gauss–Newton steps until a step's predicted decrease of the cost is below
        ``lag_tolerance_chi2`` (at most ``lag_max_iterations`` steps; warm-started, so what
        is left carries over to the next frame's solve). Keeps the last factor for
        ``_oldest_marginal``."""
        cfg = self._cfg
        for _ in range(max_iterations or cfg.lag_max_iterations):
            ab, g, norms, first = self._normal_equations()
            cb = self._factor(ab)
            sol, info = dpbtrs(cb, g.reshape(-1)[::-1], lower=0)
            if info != 0:
                raise SolveError(f"banded solve failed (LAPACK info {info})")
            delta = -sol[::-1].reshape(-1, _D)
            if not np.all(np.isfinite(delta)):
                raise SolveError("Gauss-Newton step is not finite")
            self._x = self._x + delta
            self._last = _LastSolve(cb, norms, first)
            if -0.5 * float(g.reshape(-1) @ delta.reshape(-1)) <= cfg.lag_tolerance_chi2:
                break

    def _oldest_marginal(self) -> tuple[FloatArray, FloatArray]:
        """Joint covariance (2D × 2D) of the window's two oldest frames, and the Gaussian norms
        of the pair joining them: from the last solve's factor if the window has not changed
        since, else at the current estimate."""
        if self._last is None:
            ab, _, norms, first = self._normal_equations()
            self._last = _LastSolve(self._factor(ab), norms, first)
        cb, norms = self._last.factor, self._last.norms
        n = len(self._x)
        k = min(2, n) * _D
        last = n * _D - k
        i, j = np.triu_indices(k)  # j - i < k <= 2D: every upper entry is in the band
        u = np.zeros((k, k))
        u[i, j] = cb[2 * _D - 1 + i - j, last + j]
        # reversed order: undo with [::-1]
        info = (u.T @ u)[::-1, ::-1]
        return np.linalg.inv(info), norms[0] if len(norms) else np.full(2, np.nan)

    # --- output and marginalisation ------------------------------------------------------------

    def _emit(self, final: bool) -> list[SmoothedFrame]:
        """Frames with ≥ ``lag_s`` of later data (all if ``final``), oldest first; each
        reported frame but the newest leaves the window (it stays as the anchor)."""
        out: list[SmoothedFrame] = []
        t_new = self._ms[-1].t if self._ms else -math.inf
        while self._emitted < len(self._ms):
            m = self._ms[self._emitted]
            if not final and t_new - m.t < self._cfg.lag_s:
                break
            cov, norms, note = self._marginal_or_nan()
            if self._emitted == 0:  # the very first frame: no previous one
                state = np.full(M.STATE_DIM, np.nan)
                state[_STATE_OF_VAR] = self._x[0]
                p = np.full((M.STATE_DIM, M.STATE_DIM), np.nan)
                p[np.ix_(_STATE_OF_VAR, _STATE_OF_VAR)] = cov[:_D, :_D]
                out.append(self._frame(m, state, p, None, note))
                self._emitted = 1
                continue
            # emitted == 1: report frame lo+1 with the anchor lo as its previous frame
            state = _T_STATE @ self._x[0:2].reshape(-1)
            out.append(self._frame(m, state, _T_STATE @ cov @ _T_STATE.T, norms, note))
            try:
                self._marginalise()
            except SolveError as exc:  # the frame is out; the run goes on from it
                self._reanchor(exc)
        return out

    def _marginal_or_nan(self) -> tuple[FloatArray, FloatArray, str]:
        """``_oldest_marginal`` and an empty note, or NaN (the frame is still reported, with
        its estimate) and a note saying why there is no covariance."""
        try:
            return (*self._oldest_marginal(), "")
        except SolveError as exc:
            k = min(2, len(self._x)) * _D
            return np.full((k, k), np.nan), np.full(2, np.nan), f"no covariance: {exc}"

    def _reanchor(self, exc: SolveError) -> None:
        """The anchor could not be folded into a prior: drop it and anchor the window on
        the frame just reported, with the first frame's prior around its estimate (the
        trajectory continues; the next frame reported is marked ``reset``)."""
        self._drop_anchor()
        self._prior = _first_prior(self._x[0], float("nan"), self._cfg, self._ms[0].status)
        self._emitted = 1
        if len(self._ms) > 1:
            self._reset = (self._ms[1].frame, f"smoother re-anchored: {exc}")

    def _frame(
        self,
        m: PairMeasurement,
        state: FloatArray,
        cov: FloatArray,
        norms: FloatArray | None,
        note: str = "",
    ) -> SmoothedFrame:
        pair = None if norms is None or not m.ok else (float(norms[0]), float(norms[1]))
        if not self._cfg.marginals:
            cov = np.full((M.STATE_DIM, M.STATE_DIM), np.nan)
        status, gated = _status(m, pair, self._cfg)
        reason = "" if pair else m.status
        if self._reset is not None and self._reset[0] == m.frame:
            status, reason = "reset", self._reset[1]
        if note:
            reason = f"{reason}; {note}" if reason else note
        return _make_frame(m, state, cov, status, gated, reason,
                           self._still.pop(m.frame, False))

    def _marginalise(self) -> None:
        """Fold the anchor (and the factors joining it to the next frame) into a Gaussian
        prior on the next frame, which becomes the anchor."""
        x = self._x
        if self._last is not None and self._last.first is not None:
            # the last solve's linearisation of the pair, its residual moved to the estimate
            # (the Gauss–Newton model: the step since is small, the frame converged over lag_s)
            r0, j0, at = self._last.first
            r0 = r0 + j0 @ (x[0:2].reshape(-1) - at)
        else:
            first = self._c.view(1)
            r, j, _ = W.stacked_rows(x[0:1], x[1:2], first, self._loss, self._speed_loss)
            r0, j0 = r[0], j[0]
        rp, mu = self._prior  # type: ignore[misc]
        a = np.zeros((_D + W.PAIR_ROWS, 2 * _D))
        a[:_D, :_D] = rp
        a[_D:] = j0
        b = np.concatenate([rp @ (x[0] - mu), r0])
        h, g = a.T @ a, a.T @ b
        k = np.linalg.solve(h[:_D, :_D], np.hstack([h[:_D, _D:], g[:_D, None]]))
        hs = h[_D:, _D:] - h[_D:, :_D] @ k[:, :_D]
        gs = g[_D:] - h[_D:, :_D] @ k[:, _D]
        hs = 0.5 * (hs + hs.T)
        try:
            rs = np.linalg.cholesky(hs).T
        except np.linalg.LinAlgError as exc:
            raise SolveError(f"marginal prior not positive definite ({exc})") from None
        self._prior = (rs, x[1] - np.linalg.solve(hs, gs))
        self._drop_anchor()

    def _drop_anchor(self) -> None:
        """Remove the anchor frame and the pair joining it to the next one from the window."""
        self._ms.pop(0)
        self._c.pop_front()
        self._x = self._x[1:]
        self._last = None


def _first_prior(
    x0: FloatArray, speed: float, cfg: SmootherConfig, status: str = ""
) -> tuple[FloatArray, FloatArray]:
    """Square-root information R and mean of the first frame's prior (the batch's
    ``_prior_factors``, the wheel speed at that frame and the standstill if it stands; pair
    status ``status``)."""
    nz = cfg.noise
    sig = np.array(
        [1e-3, 1e-3, 1e-3, nz.prior_speed_std_mps, math.radians(nz.prior_yaw_rate_std_dps)]
        + [math.radians(nz.prior_mount_angle_std_deg)] * 2
        + [nz.prior_height_std_rel * cfg.height_m, math.radians(nz.prior_mount_yaw_std_deg)]
        + [math.radians(nz.initial_body_std_deg)] * 2
    )
    info = 1.0 / sig**2
    mu = x0.copy()
    mu[7], mu[8], mu[9:11] = cfg.height_m, 0.0, 0.0
    if math.isfinite(speed):
        iv = 1.0 / nz.speed_meas_var(speed)
        mu[3] = (info[3] * mu[3] + iv * speed) / (info[3] + iv)
        info[3] += iv
    still = M.standstill_states(speed, status, nz)
    for i, var in zip(still, nz.standstill_var(still), strict=True):
        j = 3 if i == M.SPEED else 4  # measured as 0
        mu[j] = info[j] * mu[j] / (info[j] + 1.0 / var)
        info[j] += 1.0 / var
    return np.diag(np.sqrt(info)), mu


@kernel
def _add_rows(jac, r, first, ab, g):  # pragma: no cover (compiled)
    """Add the rows (jac, r) over variables ``first`` … to the band ``ab`` (upper storage of
    the reversed matrix, see ``FixedLagSmoother._normal_equations``) and the gradient ``g``,
    touching only each row's non-zero columns (a pair's rows are sparse: ~860 of 10 000
    products)."""
    nn = ab.shape[1]
    u = ab.shape[0] - 1
    cols = np.empty(jac.shape[1], np.int64)
    for i in range(jac.shape[0]):
        cnt = 0
        for c in range(jac.shape[1]):
            if jac[i, c] != 0.0:
                cols[cnt] = c
                cnt += 1
        for a in range(cnt):
            p = first + cols[a]
            va = jac[i, cols[a]]
            g[p] += va * r[i]
            # original entry (p, q), p ≤ q, is entry (nn-1-q, nn-1-p) of the reversed matrix
            for b in range(a, cnt):
                q = first + cols[b]
                ab[u + p - q, nn - 1 - p] += va * jac[i, cols[b]]


@kernel
def _add_pair_rows(jac, r, ab, g):  # pragma: no cover (compiled)
    """``_add_rows`` of every pair k (frames k, k+1 of the window)."""
    d = jac.shape[2] // 2
    for k in range(jac.shape[0]):
        _add_rows(jac[k], r[k], k * d, ab, g)


@lru_cache(maxsize=1)
def _scipy_openblas() -> ctypes.CDLL | None:
    import scipy

    where = os.path.join(os.path.dirname(scipy.__file__), os.pardir, "scipy.libs")
    libs = glob.glob(os.path.join(where, "*openblas*"))
    for path in libs:
        try:
            lib = ctypes.CDLL(path)
            lib.openblas_set_num_threads_local.restype = ctypes.c_int
            lib.openblas_set_num_threads_local.argtypes = [ctypes.c_int]
            return lib
        except (OSError, AttributeError):
            continue
    return None


@contextlib.contextmanager
def one_blas_thread() -> Iterator[None]:
    """Run the block with scipy's OpenBLAS single-threaded (this thread only), if it is the
    bundled OpenBLAS; else do nothing.

    LAPACK's band Cholesky of a window is a few hundred level-2 BLAS calls on 21-wide blocks:
    OpenBLAS's thread hand-offs make it 20–40× slower on a busy 2-core machine (measured:
    ~100 µs single-threaded, 2–4 ms with 2 threads)."""
    lib = _scipy_openblas()
    if lib is None:
        yield
        return
    old = lib.openblas_set_num_threads_local(1)
    try:
        yield
    finally:
        lib.openblas_set_num_threads_local(old)
