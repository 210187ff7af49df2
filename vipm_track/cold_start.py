"""Cold starts of the two-frame estimator: where a pair has no guess, the parameter vector
its first stage starts from (the nominal pose, a coarse pass on the downsampled image pair,
or the translation on the nominal pose's virtual IPM), and the check that throws out a cold
start that converged to a wrong minimum."""

from __future__ import annotations

import time

import cv2
import numpy as np
from numpy.typing import NDArray

from . import ipm, poc
from .displacement_model import SteadyPoseModel
from .geometry import GroundPose, PlanarMotion, back_project
from .pair_result import STATUS_FEW_INLIERS, STATUS_OK, PairResult, mark_failed
from .stage_context import StageContext
from .static_content import PATCH_MAX_SHARE, on_static

FloatArray = NDArray[np.float64]

#: a steep camera's cold start (either start) is kept only where at least this share of its
#: last stage's measured patches are inliers: far from the true pose, with the frames half a
#: view apart, it can converge to a wrong minimum that a quarter of the patches agree with
#: (rendered cart at 0.6 m per frame: 22-29 % inliers and 90 % short); right ones have
#: 74-100 %, 78-82 % with an obstacle over a fifth of the view
COLD_MIN_INLIER_SHARE = 0.4
#: share of the measured patches that a cold start off the nominal pitch must have as inliers
#: in its last stage: more starts, more wrong minima to land in (the cart at 0.6 m per frame
#: from 65°: 43 % of the patches and 89 % short; KITTI 07 in a sharp turn from 2° below its
#: nominal: 29 % and 46 % long), while the starts that find the truth there have 100 %. Right
#: pairs of real scenes can have less (KITTI's 28-59 %): those stay failed, as without it
RETRY_MIN_INLIER_SHARE = 0.6
#: a steep camera's cold start (either start, and its retries) is kept only where at least
#: this share of the patches visible in both frames correlate (POC peak at least
#: ``CORRELATED_PEAK_RATIO`` of its inliers' median) at the pose it converged to: on a ground
#: texture that repeats, a shift by one period can make 40-64 % of the measured patches
#: inliers (rendered cart at 0.7-0.8 m per frame: `ok` 0.8 m short), as many as some right
#: starts have, but the images are aligned only where the texture repeats: the inliers
#: correlate (median peak 0.47-0.71) and the rest not at all (0.05-0.09): 17-37 % of the
#: patches in view. In right steep cold starts (bench_camera_pitch, bench_accuracy, weak and
#: noisy textures) at least 59 % do, 100 % where no patch correlates well (peaks about 0.1)
COLD_MIN_CORRELATED_SHARE = 0.5
#: a patch correlates, for ``COLD_MIN_CORRELATED_SHARE``, where its POC peak is at least this
#: share of the median peak of the stage's inliers
CORRELATED_PEAK_RATIO = 0.5


def _polygon_mask(size: tuple[int, int], polygon: FloatArray) -> NDArray[np.bool_]:
    """Pixels (height, width) of an image of ``size`` (width, height) inside the convex
    ``polygon`` (pixels)."""
    mask = np.zeros((size[1], size[0]), np.uint8)
    if len(polygon) >= 3:
        cv2.fillConvexPoly(mask, np.round(polygon).astype(np.int32), 1)
    return mask.astype(bool)


def _global_shift(prev: NDArray, curr: NDArray, inside: NDArray[np.bool_], min_peak: float,
                  levels: int = 2) -> FloatArray:
    """Translation (dx, dy), pixels, of the content from ``prev`` to ``curr`` by one POC
    over both whole images, outside ``inside`` (the visible moving ground) filled with
    the mean grey so that the border of the view, fixed in both, does not pull the peak to
    zero. Tried at ``levels`` scales (1, 1/2, …): a pose off the nominal one stretches the
    far ground unevenly, which a coarser plane tolerates better; the highest peak wins.
    Zero where no peak reaches ``min_peak``."""
    h, w = prev.shape[:2]
    if inside.sum() < 256:
        return np.zeros(2)
    planes = []
    for image in (prev, curr):
        plane = np.array(image, np.float32)
        plane[~inside] = float(plane[inside].mean())
        planes.append(plane)
    best, best_peak = np.zeros(2), min_peak
    for level in range(levels):
        f = 2 ** level
        size = (w // f // 2 * 2, h // f // 2 * 2)
        if min(size) < 16:
            break
        pair = [cv2.resize(plane, size, interpolation=cv2.INTER_AREA) for plane in planes]
        shift, peak = poc.phase_correlate(pair[0], pair[1])
        if peak >= best_peak:
            best, best_peak = np.asarray(shift, float) * np.array([w, h]) / size, peak
    return best


def _upper_quartile(peaks: FloatArray) -> float:
    """75th percentile of the POC peaks of the patches that were measured (peak > 0): how
    well the better windows correlate; 0 where none was."""
    measured = peaks[peaks > 0]
    return float(np.percentile(measured, 75)) if measured.size else 0.0


def cold_vector(context: StageContext, pitch_step: float) -> FloatArray:
    """Parameter vector of a cold start: both frames at the nominal pose with its pitch
    moved by ``pitch_step`` (radians), no motion."""
    pitch0, roll0 = context.nominal.pitch + pitch_step, context.nominal.roll
    x0 = np.array([pitch0, roll0, pitch0, roll0, 0.0, 0.0, 0.0])
    return np.append(x0, 0.0) if context.config.vertical_motion else x0


def cold_start_ipm(context: StageContext, prev: NDArray, curr: NDArray, pitch_step: float,
                   result: PairResult) -> FloatArray:
    """Cold start of a forward camera: both frames on the nominal pose's ground plane,
    where the motion is nearly one translation (tx, tz) at the nominal pose (yaw 0).

    On the downsampled planes (``coarse_scale``) one POC over the whole visible ground
    finds the translation however far the vehicle moved (a fast car moves further per
    frame than a patch is long); the patches, their windows offset by it, then give
    its median (robust to a turn and to what is not ground)."""
    cfg = context.config
    x0 = cold_vector(context, pitch_step)
    pose = GroundPose(x0[2], x0[3], context.height)
    t0 = time.perf_counter()
    grid = ipm.choose_grid(context.k, pose, PlanarMotion(0.0, 0.0, 0.0), context.centres,
                           cfg.patch_ipm, cfg.ipm_resolution_scale, cfg.ipm_max_side)
    s = max(cfg.coarse_scale, 1)
    size = (max(grid.width // s, 1), max(grid.height // s, 1))
    small_p = cv2.resize(ipm.warp(prev, context.k, pose, grid), size,
                         interpolation=cv2.INTER_AREA)
    small_c = cv2.resize(ipm.warp(curr, context.k, pose, grid), size,
                         interpolation=cv2.INTER_AREA)
    result.timings["warp"] += time.perf_counter() - t0
    q = grid.pixel_from_ground(back_project(context.k, pose, context.centres))
    # content fixed to the camera (hood, overlay) correlates at zero shift: left out
    q = q[np.all(np.isfinite(q), axis=1) & ~on_static(context.static, context.centres)]
    patch = int(min(cfg.coarse_patch, (min(size) - 2) // 16 * 16))
    if len(q) == 0 or patch < 16:
        return x0
    t0 = time.perf_counter()
    polygon = ipm.visible_polygon(context.k, pose, grid,
                                  (context.camera.width, context.camera.height),
                                  context.horizon_margin_px)
    inside = _polygon_mask(size, (polygon - (s - 1) / 2) / s)
    # and out of the global shift, which it pulls to zero
    fixed = cv2.resize(ipm.warp(context.static, context.k, pose, grid), size,
                       interpolation=cv2.INTER_AREA) > PATCH_MAX_SHARE
    shift = _global_shift(small_p, small_c, inside & ~fixed, cfg.min_peak)
    half = patch / 2
    centres = np.round(np.clip((q - (s - 1) / 2) / s, [half, half],
                               [size[0] - 1 - half, size[1] - 1 - half]))
    # Windows at zero offset (slow motion) or at the global shift (fast): the global one
    # only where its windows correlate clearly better (twice the upper-quartile peak),
    # since in sharp turns neither is a translation and the zero offset fails safer.
    disp, peaks = poc.match_patches(small_p, small_c, centres, patch)
    if np.any(np.round(shift)):
        moved = poc.match_patches(small_p, small_c, centres, patch, np.round(shift))
        if _upper_quartile(moved[1]) > 2.0 * _upper_quartile(peaks):
            disp, peaks = moved
    result.timings["poc"] += time.perf_counter() - t0
    good = peaks >= max(cfg.min_peak, cfg.coarse_peak_ratio * float(np.max(peaks)))
    if not good.any():
        return x0
    du, dv = np.median(disp[good], axis=0) * s * grid.metres_per_pixel
    # Ground content moves by -t in the new frame: IPM u grows with X, v shrinks with Z.
    x0[4], x0[5] = -du, dv
    return x0


def coarse(
    context: StageContext, prev: NDArray, curr: NDArray, x0: FloatArray,
    rng: np.random.Generator, result: PairResult,
) -> tuple[FloatArray, FloatArray]:
    """Cold start: displacements on a downsampled pair, a quick fit, and the patch
    offsets it predicts at full resolution (zero offsets where it cannot tell)."""
    cfg = context.config
    s = cfg.coarse_scale
    t0 = time.perf_counter()
    size = (curr.shape[1] // s, curr.shape[0] // s)
    small_p = cv2.resize(prev, size, interpolation=cv2.INTER_AREA)
    small_c = cv2.resize(curr, size, interpolation=cv2.INTER_AREA)
    patch = int(min(cfg.coarse_patch, (min(size) - 2) // 16 * 16))
    half = patch / 2
    coarse_centres = np.round(
        np.clip((context.centres - (s - 1) / 2) / s, [half, half],
                [size[0] - 1 - half, size[1] - 1 - half])
    )
    disp, peaks = poc.match_patches(small_p, small_c, coarse_centres, patch)
    result.timings["poc"] += time.perf_counter() - t0
    pix = coarse_centres * s + (s - 1) / 2
    # Content fixed in the image (the vehicle's body, lens dirt, reflections) correlates
    # perfectly at zero shift while the ground moves: not ground, whatever its peak.
    mag = np.linalg.norm(np.nan_to_num(disp), axis=1) * s
    valid = peaks >= cfg.min_peak
    if not valid.any():
        return x0, np.zeros_like(context.centres)
    static = mag < max(cfg.min_motion_px, 0.1 * float(np.median(mag[valid])))
    # Patches whose content left the window still give a (lower) peak; trust the ones
    # that correlate nearly as well as the best moving ones.
    moving = valid & ~static
    if not moving.any():
        return x0, np.zeros_like(context.centres)
    floor = cfg.coarse_peak_ratio * float(np.percentile(peaks[moving], 90))
    usable = moving & (peaks >= max(cfg.min_peak, floor))
    if usable.sum() < cfg.min_inliers:
        return x0, np.zeros_like(context.centres)
    model = SteadyPoseModel(context.k, context.height, pix, pix + disp * s,
                            **context.model_args(cfg.coarse_inlier_px))
    fit = context.fit(model, SteadyPoseModel.reduce(x0), usable, cfg.n_subsets,
                      cfg.coarse_inlier_px, rng, result)
    if fit.inliers.sum() < cfg.min_inliers or not fit.converged:
        return x0, np.zeros_like(context.centres)
    x = model.full(fit.x)
    if len(x0) > len(x):
        x = np.append(x, x0[len(x):])
    return x, context.predicted_displacements(x)


def reject_wrong_minimum(result: PairResult, steep: bool, min_peak: float,
                         retry: bool = False) -> None:
    """Fail a cold-start ``result`` that converged to a wrong minimum: a ``steep`` camera's
    whose last stage has fewer than ``COLD_MIN_INLIER_SHARE`` of its measured patches
    (visible in both frames, POC peak at least ``min_peak``) as inliers, or fewer than
    ``COLD_MIN_CORRELATED_SHARE`` of its visible patches correlating as its inliers do.
    ``retry`` (a start off the nominal pitch, ``cold_pitch_steps_deg``): any camera, and
    ``RETRY_MIN_INLIER_SHARE``."""
    if not (steep or retry) or result.status != STATUS_OK or not result.stages:
        return
    need = RETRY_MIN_INLIER_SHARE if retry else COLD_MIN_INLIER_SHARE
    stage = result.stages[-1]
    visible = stage.sizes > 0
    measured = visible & (stage.peaks >= min_peak)
    share = float(np.sum(stage.inliers & measured) / max(int(measured.sum()), 1))
    if share < need:
        mark_failed(result, STATUS_FEW_INLIERS,
                    f"cold start converged with {share:.0%} of the measured patches "
                    f"inliers (need {need:.0%}): a wrong minimum")
        return
    if not steep:
        return
    # share >= need > 0: the stage has measured inliers
    inlier_peak = float(np.median(stage.peaks[stage.inliers & measured]))
    correlated = float(np.sum(visible & (stage.peaks >= CORRELATED_PEAK_RATIO * inlier_peak))
                       / max(int(visible.sum()), 1))
    if correlated < COLD_MIN_CORRELATED_SHARE:
        mark_failed(result, STATUS_FEW_INLIERS,
                    f"cold start converged where {correlated:.0%} of the patches in view "
                    f"correlate (POC peak ≥ {CORRELATED_PEAK_RATIO:g} × the inliers' median "
                    f"{inlier_peak:.2f}; need {COLD_MIN_CORRELATED_SHARE:.0%}): a wrong minimum "
                    f"on repeating texture")

# --- stages -----------------------------------------------------------------------------
