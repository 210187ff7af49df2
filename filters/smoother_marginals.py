"""Marginal covariances of the smoother's states from its linearised graph: the
block-tridiagonal sweep ``block_marginals`` (equal to ``gtsam.Marginals``, in O(n)) and the
state layout it reads (``BLOCK_LETTERS``: pose X, speed V, yaw rate W, mount M, height H, yaw
offset Y, body B)."""

from __future__ import annotations

import gtsam
import numpy as np
from numpy.typing import NDArray

from . import factors as F
from . import model as M

FloatArray = NDArray[np.float64]

#: the variables of a frame in the order of its marginal blocks
BLOCK_LETTERS = "XVWMHYB"


def states_of(values: gtsam.Values, n: int) -> FloatArray:
    """(n, 16) states (filters.model layout) of key indices 0..n-1; frame 0's prev slots NaN."""
    u = gtsam.utilities
    s = np.full((n, M.STATE_DIM), np.nan)
    vec = {c: np.asarray(u.extractVectors(values, c)).reshape(n, -1) for c in "VWMHYB"}
    pose = np.asarray(u.extractPose2(values)).reshape(n, 3)  # Pose2 (x, y, θ) = model (y, x, ψ)
    s[:, [M.MOUNT_PITCH, M.MOUNT_ROLL]] = vec["M"]
    s[:, M.MOUNT_HEIGHT] = vec["H"][:, 0]
    s[:, M.MOUNT_YAW] = vec["Y"][:, 0]
    s[:, M.BODY] = vec["B"]
    s[:, M.SPEED] = vec["V"][:, 0]
    s[:, M.YAW_RATE] = vec["W"][:, 0]
    s[:, M.POS_X], s[:, M.POS_Y], s[:, M.HEADING] = pose[:, 1], pose[:, 0], pose[:, 2]
    s[1:, M.PREV_BODY] = s[:-1, M.BODY]
    s[1:, M.PREV_POSE] = s[:-1, M.POSE]
    return s


# layout of a frame's block in the block-tridiagonal information matrix: letter → offset, dim
_DIMS = {"X": 3, "V": 1, "W": 1, "M": 2, "H": 1, "Y": 1, "B": 2}
_BLOCK = {
    c: (sum(_DIMS[d] for d in BLOCK_LETTERS[: BLOCK_LETTERS.index(c)]), _DIMS[c])
    for c in BLOCK_LETTERS
}
_BLOCK_DIM = sum(_DIMS.values())
# state indices (model layout) of each block entry, for frame k and (prev slots) frame k-1
_STATE_OF_BLOCK = np.array(
    [
        M.POS_X,
        M.POS_Y,
        M.HEADING,
        M.SPEED,
        M.YAW_RATE,
        M.MOUNT_PITCH,
        M.MOUNT_ROLL,
        M.MOUNT_HEIGHT,
        M.MOUNT_YAW,
        M.BODY_PITCH,
        M.BODY_ROLL,
    ]
)


def block_marginals(lin: gtsam.GaussianFactorGraph, n: int) -> tuple[FloatArray, FloatArray]:
    """Marginal covariances of every frame's variables from the linearised graph of ``n``
    frames whose factors only join consecutive frames: (n, D, D) blocks Σ_k and (n-1, D, D)
    cross blocks Σ_{k-1,k} in the tangent layout ``_BLOCK`` (D = 11).

    The information matrix AᵀA is block tridiagonal in frame order, so a forward Schur
    complement and a backward covariance sweep (as in a Rauch–Tung–Striebel smoother) give
    exactly the blocks ``gtsam.Marginals`` would, in O(n) small dense operations."""
    from scipy import sparse

    d = _BLOCK_DIM
    ij = lin.sparseJacobian_()
    rows, cols, vals = ij[0].astype(np.int64) - 1, ij[1].astype(np.int64) - 1, ij[2]
    n_cols = n * d
    keep = cols < n_cols  # the last column holds b
    a = sparse.csr_matrix(
        (vals[keep], (rows[keep], cols[keep])), shape=(int(rows.max()) + 1, n_cols)
    )
    # natural ordering = keys sorted: letters alphabetically, then frame index
    perm = np.empty(n_cols, dtype=np.int64)
    col = 0
    for c in sorted(BLOCK_LETTERS):
        off, dim = _BLOCK[c]
        frames = np.repeat(np.arange(n), dim)
        comp = np.tile(np.arange(dim), n)
        perm[col : col + n * dim] = frames * d + off + comp
        col += n * dim
    info = (a.T @ a).tocoo()
    r, c_, v = perm[info.row], perm[info.col], info.data
    fr, fc = r // d, c_ // d
    if np.any(np.abs(fr - fc) > 1):
        raise ValueError("graph is not block tridiagonal in frame order")
    diag = np.zeros((n, d, d))
    upper = np.zeros((max(n - 1, 0), d, d))
    sel = fr == fc
    np.add.at(diag, (fr[sel], r[sel] % d, c_[sel] % d), v[sel])
    sel = fc == fr + 1
    np.add.at(upper, (fr[sel], r[sel] % d, c_[sel] % d), v[sel])
    s_inv = np.empty((n, d, d))
    s = diag[0]
    for k in range(n):
        if k > 0:
            s = diag[k] - upper[k - 1].T @ s_inv[k - 1] @ upper[k - 1]
        s_inv[k] = np.linalg.inv(s)
    sigma = np.empty((n, d, d))
    cross = np.empty((max(n - 1, 0), d, d))
    sigma[-1] = s_inv[-1]
    for k in range(n - 2, -1, -1):
        g = s_inv[k] @ upper[k]
        cross[k] = -g @ sigma[k + 1]
        sigma[k] = s_inv[k] - cross[k] @ g.T
    sigma = 0.5 * (sigma + np.swapaxes(sigma, 1, 2))
    return sigma, cross


def state_covariances(
    states: FloatArray, sigma: FloatArray, cross: FloatArray, chunk: int = 4096
) -> FloatArray:
    """(n, 16, 16) model-layout covariances of n consecutive frames from their block marginals
    (``block_marginals``: Σ_k and the cross blocks Σ_{k-1,k}); Pose2 tangents mapped to
    (x, y, ψ). Frame 0's prev slots are NaN. Computed in chunks of ``chunk`` frames."""
    n, d = len(states), _BLOCK_DIM
    xo, bo = _BLOCK["X"][0], _BLOCK["B"][0]
    out = np.empty((n, M.STATE_DIM, M.STATE_DIM))
    for lo in range(0, n, chunk):
        hi = min(n, lo + chunk)
        m = hi - lo
        psi = states[lo:hi, M.HEADING]
        psi_prev = np.where(np.arange(lo, hi) > 0, states[lo:hi, M.PREV_HEADING], 0.0)
        tk = np.zeros((m, M.STATE_DIM, 2 * d))
        tk[:, _STATE_OF_BLOCK, d + np.arange(d)] = 1.0
        tk[:, M.POSE, d + xo : d + xo + 3] = F.tangent_jacobian(psi)
        tk[:, M.PREV_BODY, bo : bo + 2] = np.eye(2)
        tk[:, M.PREV_POSE, xo : xo + 3] = F.tangent_jacobian(psi_prev)
        joint = np.zeros((m, 2 * d, 2 * d))
        joint[:, d:, d:] = sigma[lo:hi]
        first = max(lo, 1)
        joint[first - lo :, :d, :d] = sigma[first - 1 : hi - 1]
        joint[first - lo :, :d, d:] = cross[first - 1 : hi - 1]
        joint[first - lo :, d:, :d] = np.swapaxes(cross[first - 1 : hi - 1], 1, 2)
        out[lo:hi] = tk @ joint @ np.swapaxes(tk, 1, 2)
    if n:
        out[0, M.PREV_BODY, :] = out[0, :, M.PREV_BODY] = np.nan
        out[0, M.PREV_POSE, :] = out[0, :, M.PREV_POSE] = np.nan
    return out


def block_norms(
    graph_factors: dict[int, tuple[gtsam.CustomFactor, gtsam.CustomFactor]], values: gtsam.Values
) -> dict[int, tuple[float, float]]:
    """Whitened (Gaussian) norms of each key index's pose and motion pair blocks."""
    out = {}
    for k, (fp, fm) in graph_factors.items():
        out[k] = tuple(  # type: ignore[assignment]
            float(
                np.sqrt(
                    _gaussian_part(f.noiseModel()).squaredMahalanobisDistance(
                        f.unwhitenedError(values)
                    )
                )
            )
            for f in (fp, fm)
        )
    return out


def _gaussian_part(noise: gtsam.noiseModel.Base) -> gtsam.noiseModel.Base:
    """The Gaussian model inside a robust one (its ``whiten`` would apply the M-estimator)."""
    return noise.noise() if isinstance(noise, gtsam.noiseModel.Robust) else noise
