"""Benchmark: sub-pixel accuracy and speed of vipm_track.poc against OpenCV and scikit-image.

Test data: 128×128 patches of the real texture photographs in ``data/textures`` (gravel,
grass, brick; the same number of pairs from each), with known displacements:

- translations are exact: a mirrored 80-px-margin crop is moved by a Fourier phase ramp
  (exact for band-limited content), then the centre is cut out;
- rotation, scale and perspective cases warp the moving crop with ``cv2.warpPerspective``
  (Lanczos-4) by a homography about the patch centre; the true shift is where the patch
  centre goes;
- independent Gaussian noise (σ grey levels) is added to both patches of every pair.

Methods, side by side on the same pairs in one run:

- ``vipm_track.poc.phase_correlate``: the whole batch in one call (defaults: Hann window,
  band 0.5, weighted Newton peak). Timed as a full pair (both spectra), and again with the
  reference spectra reused (what a sequence costs per pair once a frame's spectra are kept);
- ``cv2.phaseCorrelate`` with a Hann window (``cv2.createHanningWindow``), one pair per call,
  on copies (it writes its window into the caller's arrays);
- ``cv2.phaseCorrelateIterative`` (OpenCV 5, default L2size and maxIters) on raw patches;
- ``skimage.registration.phase_cross_correlation(upsample_factor=100)`` on mean-removed,
  Hann-windowed patches (unwindowed it suffers the edge effects that the window removes).

Errors: RMSE of the shift vector (px) over all pairs, RMSE over the pairs within 0.5 px, and
the outlier rate (error > 0.5 px or no result). Times: ms per pair, median of ``--repeats``
runs (the machine is shared; medians, not means). Writes ``scripts/results/bench_poc.md``.

Usage: ``python scripts/bench_poc.py [--pairs 99] [--repeats 7] [--out FILE]``
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from functools import partial
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from vipm_track.poc import patch_spectra, phase_correlate  # noqa: E402

TEXTURES = ("gravel", "grass", "brick")
MARGIN = 80  # px of real texture around each patch, so warps and shifts never reach its edge


@dataclass(frozen=True)
class Case:
    """One row group of the table: how the moving patch is made from the reference."""

    name: str
    max_shift: float  # px, uniform per axis
    noise: float  # grey levels
    rotation_deg: float = 0.0  # ± uniform
    scale: float = 0.0  # ± uniform relative
    perspective: float = 0.0  # magnitude of the projective row (1/px)
    size: int = 128


CASES = (
    Case("shift ±2 px, σ=2", 2.0, 2.0),
    Case("shift ±8 px, σ=2", 8.0, 2.0),
    Case("shift ±2 px, σ=8", 2.0, 8.0),
    Case("+ rotation ±2°, σ=2", 2.0, 2.0, rotation_deg=2.0),
    Case("+ scale ±2 %, σ=2", 2.0, 2.0, scale=0.02),
    Case("+ perspective, σ=2", 2.0, 2.0, perspective=4e-4),
    Case("256×256, shift ±4 px, σ=2", 4.0, 2.0, size=256),
)


def load_texture(name: str) -> np.ndarray:
    """Grey texture photo as float64 grey levels."""
    image = cv2.imread(str(ROOT / "data" / "textures" / f"{name}.png"), cv2.IMREAD_GRAYSCALE)
    if image is None:
        raise SystemExit(f"texture photo not found: {ROOT / 'data' / 'textures' / name}.png")
    return image.astype(np.float64)


def fourier_shift(image: np.ndarray, dx: float, dy: float) -> np.ndarray:
    """``image`` moved by (dx, dy): out(x) = image(x − d), exact for band-limited content;
    mirrored first so that the periodic extension has no jumps."""
    h, w = image.shape
    big = np.pad(image, ((h // 2, h // 2), (w // 2, w // 2)), mode="symmetric")
    fy = np.fft.fftfreq(big.shape[0])[:, None]
    fx = np.fft.rfftfreq(big.shape[1])[None, :]
    moved = np.fft.irfft2(np.fft.rfft2(big) * np.exp(-2j * np.pi * (fx * dx + fy * dy)),
                          s=big.shape)
    return moved[h // 2: h // 2 + h, w // 2: w // 2 + w]


def make_pairs(case: Case, n: int, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(ref, moving, true shift (dx, dy)) for ``n`` pairs spread over the textures."""
    rng = np.random.default_rng(seed)
    s = case.size
    refs, movs, shifts = [], [], []
    for k in range(n):
        tex = TEXTURE_CACHE[TEXTURES[k % len(TEXTURES)]]
        y0 = int(rng.integers(MARGIN, tex.shape[0] - s - MARGIN + 1))
        x0 = int(rng.integers(MARGIN, tex.shape[1] - s - MARGIN + 1))
        region = tex[y0 - MARGIN: y0 + s + MARGIN, x0 - MARGIN: x0 + s + MARGIN]
        d = rng.uniform(-case.max_shift, case.max_shift, 2)
        if case.rotation_deg == 0 and case.scale == 0 and case.perspective == 0:
            moved = fourier_shift(region, d[0], d[1])
        else:
            c = (region.shape[1] - 1) / 2, (region.shape[0] - 1) / 2  # patch centre
            a = np.radians(rng.uniform(-case.rotation_deg, case.rotation_deg))
            m = 1 + rng.uniform(-case.scale, case.scale)
            phi = rng.uniform(0, 2 * np.pi)
            p = case.perspective * np.array([np.cos(phi), np.sin(phi)])
            warp = np.array([[m * np.cos(a), -m * np.sin(a), 0],
                             [m * np.sin(a), m * np.cos(a), 0],
                             [p[0], p[1], 1.0]])
            to_c = np.array([[1, 0, -c[0]], [0, 1, -c[1]], [0, 0, 1.0]])
            back = np.array([[1, 0, c[0] + d[0]], [0, 1, c[1] + d[1]], [0, 0, 1.0]])
            hom = back @ warp @ to_c  # ref pixel -> moving pixel; centre -> centre + d
            moved = cv2.warpPerspective(region, hom, region.shape[::-1],
                                        flags=cv2.INTER_LANCZOS4, borderMode=cv2.BORDER_REFLECT)
        inner = (slice(MARGIN, MARGIN + s), slice(MARGIN, MARGIN + s))
        refs.append(region[inner] + rng.normal(0, case.noise, (s, s)))
        movs.append(moved[inner] + rng.normal(0, case.noise, (s, s)))
        shifts.append(d)
    return (np.array(refs, np.float32), np.array(movs, np.float32), np.array(shifts))


TEXTURE_CACHE = {name: load_texture(name) for name in TEXTURES}


# ------------------------------------------------------------------------ methods
# Each takes (ref, moving) float32 batches and returns (N, 2) shifts as (dx, dy) with
# moving(x) ≈ ref(x − shift); NaN for no result.


def ours(ref: np.ndarray, mov: np.ndarray) -> np.ndarray:
    return phase_correlate(ref, mov)[0]


def cv2_phase_correlate(ref: np.ndarray, mov: np.ndarray) -> np.ndarray:
    win = cv2.createHanningWindow(ref.shape[1:][::-1], cv2.CV_32F)
    out = np.empty((len(ref), 2))
    for k in range(len(ref)):
        (dx, dy), _ = cv2.phaseCorrelate(ref[k].copy(), mov[k].copy(), win)
        out[k] = dx, dy
    return out


def cv2_iterative(ref: np.ndarray, mov: np.ndarray) -> np.ndarray:
    out = np.empty((len(ref), 2))
    for k in range(len(ref)):
        out[k] = cv2.phaseCorrelateIterative(ref[k].copy(), mov[k].copy())
    return out


def skimage_upsampled(ref: np.ndarray, mov: np.ndarray) -> np.ndarray:
    from skimage.registration import phase_cross_correlation

    h, w = ref.shape[1:]
    win = np.outer(np.hanning(h), np.hanning(w))
    out = np.empty((len(ref), 2))
    for k in range(len(ref)):
        a = (ref[k] - ref[k].mean()) * win
        b = (mov[k] - mov[k].mean()) * win
        shift, _, _ = phase_cross_correlation(a, b, upsample_factor=100)
        out[k] = -shift[1], -shift[0]  # skimage: (row, col) that registers moving onto ref
    return out


METHODS: dict[str, Callable[[np.ndarray, np.ndarray], np.ndarray]] = {
    "vipm_track.poc (batch)": ours,
    "cv2.phaseCorrelate (Hann)": cv2_phase_correlate,
    "cv2.phaseCorrelateIterative": cv2_iterative,
    "skimage upsample=100 (Hann)": skimage_upsampled,
}


def check_signs() -> None:
    """Every method must agree with the convention on an integer crop (moving = ref moved
    by (+5, −3)); a wrong sign would make every row meaningless."""
    tex = TEXTURE_CACHE["gravel"]
    ref = tex[200:328, 200:328].astype(np.float32)[None]
    mov = tex[203:331, 195:323].astype(np.float32)[None]  # content moves by (+5, −3)
    for name, fn in METHODS.items():
        got = fn(ref, mov)[0]
        if not np.allclose(got, [5.0, -3.0], atol=0.3):
            raise SystemExit(f"{name}: sign check failed, got {got} for (5, -3)")


def median_ms_per_pair(fn: Callable[[], object], n_pairs: int, repeats: int,
                       budget_s: float = 3.0) -> float:
    """Median over ``repeats`` runs (fewer once ``budget_s`` is spent: the slow methods)."""
    times: list[float] = []
    while len(times) < repeats and (not times or sum(times) < budget_s):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return float(np.median(times)) * 1e3 / n_pairs


def errors(est: np.ndarray, true: np.ndarray) -> tuple[float, float, float]:
    """(RMSE px over the pairs with a result, RMSE over those within 0.5 px, outlier
    fraction: error > 0.5 px or no result)."""
    err = np.linalg.norm(est - true, axis=1)
    found = np.isfinite(err)
    good = found & (err <= 0.5)
    rmse_all = float(np.sqrt(np.mean(np.square(err[found])))) if found.any() else float("nan")
    rmse_in = float(np.sqrt(np.mean(np.square(err[good])))) if good.any() else float("nan")
    return rmse_all, rmse_in, float(1 - good.mean())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--pairs", type=int, default=99, help="pairs per case (default 99)")
    parser.add_argument("--repeats", type=int, default=7, help="timing repeats (median)")
    parser.add_argument("--seed", type=int, default=2024)
    parser.add_argument("--out", type=Path, default=ROOT / "scripts" / "results" / "bench_poc.md")
    args = parser.parse_args()

    check_signs()
    rows = []
    for i, case in enumerate(CASES):
        ref, mov, true = make_pairs(case, args.pairs, args.seed + i)
        for name, fn in METHODS.items():
            est = fn(ref, mov)
            ms = median_ms_per_pair(partial(fn, ref, mov), len(ref), args.repeats)
            rows.append((case.name, name, *errors(est, true), ms))
            print(f"{case.name:28s} {name:30s} rmse {rows[-1][2]:.4f} px "
                  f"outliers {rows[-1][4]:6.1%}  {ms:.3f} ms/pair", file=sys.stderr)
        if case.size == 128 and case.noise == 2.0 and case.max_shift == 2.0 and i == 0:
            spectra = patch_spectra(ref)
            ms = median_ms_per_pair(partial(phase_correlate, None, mov, ref_spectra=spectra),
                                    len(ref), args.repeats)
            est = phase_correlate(None, mov, ref_spectra=spectra)[0]
            rows.append((case.name, "vipm_track.poc (ref spectra reused)", *errors(est, true),
                         ms))

    lines = [
        "# Phase correlation benchmark (`scripts/bench_poc.py`)",
        "",
        f"{args.pairs} pairs per case of real texture photos (gravel, grass, brick in turn); "
        "translations by exact Fourier shift, rotation/scale/perspective by Lanczos-4 "
        "warps about the patch centre; Gaussian noise σ on both patches. Error = "
        "|estimated − true| of the shift vector (the true shift is where the patch centre "
        "goes); RMSE over the pairs with a result. Outlier: error > 0.5 px or no result. "
        f"Time: ms per pair, median of {args.repeats} runs of the whole batch "
        f"(ours: one batched call; the others: a loop over pairs). Machine: "
        f"{platform.machine()}, {os.cpu_count()} cores shared with other jobs while "
        "measured, so times are noisy; compare within one run.",
        "",
        "| case | method | RMSE px | RMSE ≤0.5 px | outliers | ms / pair |",
        "| --- | --- | ---: | ---: | ---: | ---: |",
    ]
    for case, method, rmse_all, rmse_in, outl, ms in rows:
        lines.append(f"| {case} | {method} | {rmse_all:.4f} | {rmse_in:.4f} | "
                     f"{outl:.1%} | {ms:.3f} |")
    lines += [
        "",
        "Notes: rotation, scale and perspective spread the displacement over the patch, so "
        "the correlation peak blurs. Under perspective the window-weighted mean displacement "
        "itself differs from the centre's by about p·Var_w(x) ≈ 0.13 px for p = 4e-4 /px and "
        "a 128-px Hann window, which bounds every method there (hence the estimator's IPM "
        "plane). Targets: RMSE ≤ 0.02 px on the first row, ≤ 0.25 ms per pair in a batch of "
        "99.",
    ]
    table = "\n".join(lines) + "\n"
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(table, encoding="utf-8")
    print(table)
    print(f"wrote {args.out}", file=sys.stderr)


if __name__ == "__main__":
    main()
