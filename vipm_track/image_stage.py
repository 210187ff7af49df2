"""The two-frame estimator's first stage, the initial estimation on the image plane (Hirano
et al., III-B): POC displacement of square patches at the interest points, obvious outliers
dropped, LM over the parameters on random subsets."""

from __future__ import annotations

import time

import numpy as np
from numpy.typing import NDArray

from .cold_start import coarse, cold_vector
from .displacement_model import DisplacementModel
from .geometry import rotation_parallax
from .pair_result import STATUS_NO_MOTION, STATUS_NO_TEXTURE, PairResult, PatchField, StageFailure
from .patch_match import match_grouped
from .roi import shrink_to_image
from .stage_context import StageContext
from .static_content import on_static

FloatArray = NDArray[np.float64]


def check_parallax(context: StageContext, disp: NDArray, usable: NDArray[np.bool_]) -> None:
    """Fail the pair as "no motion" where a pure rotation explains the matched field
    (``disp`` (N, 2) of the ``usable`` patches) to within ``min_motion_px`` (median): a
    standing vehicle's camera still pitches and rolls (engine, passengers, wind), which
    moves the image by pixels, but without translation the pose against the ground is
    unobservable and the fit diverges."""
    use = usable & np.isfinite(disp).all(axis=1)
    if use.sum() < 3:
        return
    centres = context.centres[use]
    residual, angle = rotation_parallax(context.k, centres, centres + disp[use])
    parallax = float(np.median(residual))
    if parallax < context.config.min_motion_px:
        raise StageFailure(
            STATUS_NO_MOTION,
            f"a rotation of {np.degrees(angle):.2f}° explains the image motion to "
            f"{parallax:.2f} px < {context.config.min_motion_px} px (median): without "
            "translation the pose against the ground is unobservable",
        )


def image_stage(
    context: StageContext,
    prev: NDArray,
    curr: NDArray,
    start: FloatArray | None,
    rng: np.random.Generator,
    result: PairResult,
    pitch_step: float = 0.0,
) -> FloatArray:
    """Parameter vector after the initial estimation on the image plane (III-B), accepted
    into ``result``: POC of the image patches, their windows offset by what ``start``
    predicts (cold: from :mod:`cold_start`'s coarse pass, nominal pose with its pitch moved
    by ``pitch_step`` radians), obvious outliers dropped, robust LM over the parameters."""
    cfg = context.config
    if start is not None:
        x0 = start
        offsets = context.predicted_displacements(x0)
    else:
        x0 = cold_vector(context, pitch_step)
        offsets = np.zeros_like(context.centres)
        if cfg.coarse_scale > 1:
            x0, offsets = coarse(context, prev, curr, x0, rng, result)

    offsets = np.round(offsets)
    sizes = shrink_to_image(context.centres + offsets, context.sizes, context.camera.width,
                            context.camera.height, cfg.min_patch_image)
    t0 = time.perf_counter()
    disp, peaks = match_grouped(prev, curr, context.centres, sizes, offsets)
    result.timings["poc"] += time.perf_counter() - t0

    usable = (sizes > 0) & (peaks >= cfg.min_peak) & ~on_static(context.static, context.centres)
    n_textured = int(usable.sum())
    if n_textured < cfg.min_inliers:
        raise StageFailure(
            STATUS_NO_TEXTURE,
            f"only {n_textured} of {len(peaks)} patches correlate (POC peak ≥ "
            f"{cfg.min_peak}); the ground shows too little texture",
        )
    mag = np.where(usable, np.linalg.norm(np.nan_to_num(disp), axis=1), np.inf)
    median_mag = float(np.median(mag[usable]))
    if median_mag < cfg.min_motion_px:
        raise StageFailure(
            STATUS_NO_MOTION,
            f"median displacement {median_mag:.2f} px < {cfg.min_motion_px} px: without "
            "motion the pose against the ground is unobservable",
        )
    usable &= mag <= cfg.max_displacement_factor * median_mag + cfg.patch_image / 8
    check_parallax(context, disp, usable)
    model = DisplacementModel(context.k, context.height, context.centres, context.centres + disp,
                              **context.model_args(cfg.inlier_px_image))
    fit = context.fit(model, x0, usable, cfg.n_subsets, cfg.inlier_px_image, rng, result)
    result.stages.append(PatchField("image", context.centres, disp, peaks, fit.inliers, sizes))
    context.accept(fit, result, "initial estimate")
    return fit.x
