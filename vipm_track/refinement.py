"""The two-frame estimator's refinement via virtual IPM (Hirano et al., III-C): both frames
warped onto bird's-eye planes of the current estimate, POC on IPM patches whose moving window
is offset by the displacement the estimate predicts, outliers rejected against that
prediction, LM on the reprojection residual on the IPM planes (eqs. 3-5)."""

from __future__ import annotations

import time

import numpy as np
from numpy.typing import NDArray

from . import ipm
from .displacement_model import DisplacementModel, unpack
from .geometry import (
    apply_homography,
    back_project,
    image_from_ipm_homography,
    ipm_from_image_homography,
)
from .pair_result import STATUS_FEW_INLIERS, PairResult, PatchField, StageFailure
from .patch_match import match_grouped
from .stage_context import StageContext
from .static_content import on_static

FloatArray = NDArray[np.float64]

#: A blur-invariant refinement whose fit keeps fewer than this share of the patches it
#: measured fails (the estimator's next start, if any, takes over): the invariant shifts
#: double the phases' noise, and where the start was degrees off or the blur heavy, 12–19 of
#: some 60 patches agreed on a pose 3–11° off (shaking carts at --motion-blur 0.3: fits
#: keeping under 30 %, 9 of 16 pairs beyond 1.5°; from 30 % on, 1 of 308; docs/blur.md).
BLUR_INVARIANT_MIN_INLIER_SHARE = 0.3


def refine(
    context: StageContext, prev: NDArray, curr: NDArray, x: FloatArray,
    rng: np.random.Generator, result: PairResult, loose: bool = False,
) -> FloatArray:
    """One virtual-IPM refinement from the estimate ``x``; ``loose`` widens the outlier
    gate (×3) and fits random subsets, for a start that is only a guess."""
    cfg = context.config
    pose_p, pose_c, motion = unpack(x, context.height)
    t0 = time.perf_counter()
    grid = ipm.choose_grid(context.k, pose_p, motion, context.centres, cfg.patch_ipm,
                           cfg.ipm_resolution_scale, cfg.ipm_max_side)
    ipm_p = ipm.warp(prev, context.k, pose_p, grid)
    # Patch centres: interest points on the previous virtual IPM plane, on whole pixels.
    # (on the halved planes' grid where the correlation runs there: an odd centre would be
    # measured a pixel away from where its displacement is used)
    step = 2**cfg.ipm_poc_level
    q_p = step * np.round(grid.pixel_from_ground(back_project(context.k, pose_p,
                                                              context.centres)) / step)
    valid = np.all(np.isfinite(q_p), axis=1)
    q_p = np.where(valid[:, None], q_p, 0.0)
    pixels_prev = apply_homography(image_from_ipm_homography(context.k, pose_p, grid), q_p)
    plane_from_image = ipm_from_image_homography(context.k, pose_c, grid)
    pred = DisplacementModel(context.k, context.height, pixels_prev, q_p, plane_from_image,
                             **context.shutter()).predict(x) - q_p
    pred = np.where(np.isfinite(pred), pred, 0.0)
    size_img = (context.camera.width, context.camera.height)
    poly_p = ipm.visible_polygon(context.k, pose_p, grid, size_img, context.horizon_margin_px)
    poly_c = ipm.visible_polygon(context.k, pose_c, grid, size_img, context.horizon_margin_px)
    if cfg.moved_ipm:
        # Frame k's plane moved onto frame k-1's by the estimate: the patches match
        # with no offset and no rotation between them (POC assumes a translation; a
        # turn's rotation within a patch biased its shift by the texture's layout).
        moved = ipm.moved_pixels_matrix(grid, motion)
        ipm_c = ipm.warp(curr, context.k, pose_c, grid, motion)
        poly_c = apply_homography(np.linalg.inv(moved), poly_c)
        # zero but for the rolling shutter's part of the motion
        offsets = np.round(apply_homography(np.linalg.inv(moved), q_p + pred) - q_p)
    else:
        ipm_c = ipm.warp(curr, context.k, pose_c, grid)
        offsets = np.round(pred)
    # sizes in steps that stay SIZE_STEP on the halved planes (patches batch by size; finer
    # steps made more, smaller batches, and a worse p95 travel error on KITTI 07)
    sizes = ipm.patch_sizes(grid, poly_p, poly_c, q_p, offsets, cfg.patch_ipm,
                            cfg.min_patch_ipm, ipm.SIZE_STEP * step)
    sizes[~valid] = 0
    result.timings["warp"] += time.perf_counter() - t0

    t0 = time.perf_counter()
    # recentre: the Hann windows of a patch pair overlap less the further the content
    # moved from the window offset, which pulls the POC estimate towards that offset
    # (about 2 % of the gap, i.e. of the previous estimate's error)
    disp, peaks = match_grouped(ipm_p, ipm_c, q_p, sizes, offsets,
                                recentre=cfg.recentre_windows, level=cfg.ipm_poc_level,
                                blur_invariant=cfg.blur_invariant_ipm)
    if cfg.moved_ipm:
        disp = apply_homography(moved, q_p + disp) - q_p
    result.timings["poc"] += time.perf_counter() - t0

    usable = (sizes > 0) & (peaks >= cfg.min_peak) & ~on_static(context.static, pixels_prev)
    measured = int(usable.sum())
    dev = np.linalg.norm(disp - pred, axis=1)
    usable &= dev <= cfg.refine_outlier_px * (3.0 if loose else 1.0)
    whitening = (ipm.patch_noise_whitening(plane_from_image, q_p + disp, sizes, cfg.patch_ipm)
                 if cfg.weight_patches else None)
    model = DisplacementModel(
        context.k, context.height, pixels_prev, q_p + disp, plane_from_image=plane_from_image,
        point_whitening=whitening, **context.model_args(cfg.inlier_px_ipm),
    )
    if usable.sum() < cfg.min_inliers:
        raise StageFailure(
            STATUS_FEW_INLIERS,
            f"refinement {len(result.stages)}: {int(usable.sum())} IPM patches agree with "
            f"the previous estimate (need {cfg.min_inliers})",
        )
    n_subsets = max(cfg.refine_subsets, 20) if loose else cfg.refine_subsets
    inlier_px = cfg.inlier_px_ipm * (2.0 if loose else 1.0)
    fit = context.fit(model, x, usable, n_subsets, inlier_px, rng, result,
                      cfg.inlier_median_factor)
    kept = int(fit.inliers.sum())
    if cfg.blur_invariant_ipm and kept < BLUR_INVARIANT_MIN_INLIER_SHARE * measured:
        raise StageFailure(
            STATUS_FEW_INLIERS,
            f"refinement {len(result.stages)}: the fit keeps {kept} of the {measured} IPM "
            f"patches measured (need {BLUR_INVARIANT_MIN_INLIER_SHARE:.0%} with blur-invariant "
            "POC)",
        )
    result.stages.append(PatchField("ipm", q_p, disp, peaks, fit.inliers, sizes, grid))
    if cfg.keep_images:
        result.ipm_images = (ipm_p, ipm_c)
    context.accept(fit, result, f"refinement {len(result.stages) - 1}")
    return fit.x


def refine_all(
    context: StageContext, prev: NDArray, curr: NDArray, x: FloatArray, n: int, loose: bool,
    rng: np.random.Generator, result: PairResult,
) -> FloatArray:
    """``n`` refinements from ``x``, the first with the wide gate when ``loose``. A
    refinement after the first that fails keeps the previous one's estimate (noted in
    ``result.reason``) instead of failing the pair."""
    for i in range(n):
        try:
            x = refine(context, prev, curr, x, rng, result, loose=loose and i == 0)
        except StageFailure as failure:
            if i == 0:
                raise
            note = f"refinement {i + 1} of {n} not used ({failure.reason})"
            result.reason = f"{result.reason}; {note}" if result.reason else note
            break
    return x

