"""How well a time series pins down its mean when its samples are correlated: batch means.

A filter's covariance says how well the data determine a quantity *if the model is right*.
On real drives the per-frame poses carry slow errors the model does not have (road camber and
slope changes, load shifts, the front end's tracking correlation: on KITTI 07 the variance of
1 s means of the measured roll is 10–20× what the model predicts), and a model-based
interval for a drive's mean mount is then far too narrow. Batch means is the standard
model-free check (as in MCMC output analysis): split the series into ``b`` consecutive
batches; their means scatter as the long-run variance says, so ``std(batch means) / √b`` is
the standard error of the overall mean, with ``b − 1`` degrees of freedom.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike
from scipy.stats import t as student_t


@dataclass(frozen=True)
class MeanUncertainty:
    """Standard error of a series' mean (same unit as the series) from ``batches`` batch
    means; ``half_width95`` = Student-t 97.5 % quantile (``batches − 1`` dof) × ``std``."""

    std: float
    batches: int
    batch_length: int

    @property
    def half_width95(self) -> float:
        return float(student_t.ppf(0.975, self.batches - 1)) * self.std


def batch_means(
    x: ArrayLike, min_batches: int = 5, max_batches: int = 30
) -> MeanUncertainty | None:
    """Standard error of the mean of the finite values of ``x`` (in time order) by batch
    means: ``b = clamp(⌊√n⌋, min_batches, max_batches)`` batches of ``⌊n / b⌋`` samples (the
    first ``n mod b`` samples are dropped). None with fewer than 2 samples per batch."""
    v = np.asarray(x, dtype=float)
    v = v[np.isfinite(v)]
    b = min(max_batches, max(min_batches, math.isqrt(v.size)))
    length = v.size // b
    if length < 2:
        return None
    means = v[v.size - b * length:].reshape(b, length).mean(axis=1)
    return MeanUncertainty(float(np.std(means, ddof=1) / math.sqrt(b)), b, length)
