"""The patch-correlation thread pool: the same results for any thread count, safe to change
while other threads correlate, usable in a forked child."""

from __future__ import annotations

import multiprocessing
import sys
import threading

import numpy as np
import pytest

from vipm_track import patch_match, workers

RNG = np.random.default_rng(0)
IMAGE = (RNG.random((400, 400)) * 255).astype(np.float32)
MOVED = np.roll(IMAGE, (3, -2), axis=(0, 1))
CENTRES = np.column_stack([RNG.uniform(80, 320, 40), RNG.uniform(80, 320, 40)])
SIZES = np.array([64] * 20 + [32] * 20)


def _correlate() -> tuple[np.ndarray, np.ndarray]:
    return patch_match.match_grouped(IMAGE, MOVED, CENTRES, SIZES, np.zeros((40, 2)))


@pytest.fixture
def two_threads():
    before = workers.threads()
    workers.set_threads(2)
    yield
    workers.set_threads(before)


def test_the_shift_is_found_on_any_thread_count(two_threads) -> None:
    shift, peak = _correlate()
    np.testing.assert_allclose(shift, np.tile([-2.0, 3.0], (40, 1)), atol=0.15)
    for n in (1, 3):
        workers.set_threads(n)
        again = _correlate()
        assert np.array_equal(again[0], shift) and np.array_equal(again[1], peak)


def test_changing_the_count_while_others_correlate_loses_nothing(two_threads) -> None:
    reference = _correlate()
    errors: list[str] = []
    stop = threading.Event()

    def correlate_on() -> None:
        while not stop.is_set():
            try:
                shift, peak = _correlate()
                assert np.array_equal(shift, reference[0]) and np.array_equal(peak, reference[1])
            except Exception as exc:  # any failure is the finding
                errors.append(repr(exc))

    correlators = [threading.Thread(target=correlate_on) for _ in range(2)]
    for c in correlators:
        c.start()
    try:
        for i in range(300):
            workers.set_threads(2 + i % 2)
    finally:
        stop.set()
        for c in correlators:
            c.join()
    assert errors == []


def _child_peak_sum(_: int) -> float:
    return float(np.sum(_correlate()[1]))


@pytest.mark.skipif(sys.platform == "win32", reason="fork is POSIX only")
def test_a_forked_child_correlates_after_the_parent_did(two_threads) -> None:
    expected = float(np.sum(_correlate()[1]))  # the parent's pool exists now
    with multiprocessing.get_context("fork").Pool(1) as pool:
        assert pool.apply_async(_child_peak_sum, (0,)).get(timeout=60) == expected


def _fourier_shifted(image: np.ndarray, shift: tuple[float, float]) -> np.ndarray:
    """``image`` (periodic) with its content moved by ``shift`` = (dx, dy) pixels."""
    fy = np.fft.fftfreq(image.shape[0])[:, None]
    fx = np.fft.fftfreq(image.shape[1])[None, :]
    phase = np.exp(-2j * np.pi * (fx * shift[0] + fy * shift[1]))
    return np.real(np.fft.ifft2(np.fft.fft2(image) * phase)).astype(np.float32)


# broadband texture (amplitude ~ 1/f up to the Nyquist frequency), as real ground shows
_F = np.hypot(np.fft.fftfreq(400)[:, None], np.fft.fftfreq(400)[None, :])
BROADBAND = np.real(np.fft.ifft2(np.fft.fft2(RNG.standard_normal((400, 400)))
                                 / np.maximum(_F, 0.01))).astype(np.float32)
BROADBAND *= 30 / BROADBAND.std()


@pytest.mark.parametrize("shift", [(3.3, -2.6), (-5.75, 0.4), (0.5, 6.5), (1.5, -1.5)])
@pytest.mark.parametrize("offset", [(0.0, 0.0), (3.0, -3.0)])
def test_a_pyramid_level_finds_the_full_resolution_shift(shift, offset) -> None:
    moved = _fourier_shifted(BROADBAND, shift)
    centres = 2 * np.round(CENTRES / 2)  # on the halved grid, as the refinement puts them
    offsets = np.tile(offset, (40, 1))
    # level 1: the band reaches the halved Nyquist frequency, where the shifts lock towards
    # the halved grid (measured: errors up to 0.068 px, 0.038 px on average at some shifts)
    for level, tolerance, bias in ((0, 0.01, 0.003), (1, 0.08, 0.045)):
        found, peak = patch_match.match_grouped(BROADBAND, moved, centres, SIZES * 2, offsets,
                                                recentre=True, level=level)
        assert np.all(peak > 0.5)
        error = found - np.array(shift)
        assert np.max(np.abs(error)) < tolerance, (level, error)
        assert np.max(np.abs(error.mean(axis=0))) < bias, (level, error.mean(axis=0))


def test_patches_too_small_for_the_level_are_not_matched() -> None:
    sizes = np.array([64] * 20 + [12] * 20)
    found, peak = patch_match.match_grouped(IMAGE, MOVED, CENTRES, sizes, np.zeros((40, 2)),
                                            level=1)
    assert np.all(peak[20:] == 0) and np.all(np.isnan(found[20:]))
    assert np.all(peak[:20] > 0)
