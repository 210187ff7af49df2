"""The camera's pitch against its direction of travel, from sparse flow over several pairs.

A vehicle moves along the road, so the direction of its camera's travel (the focus of
expansion) lies in the road plane: with roll φ the travel direction d in the camera frame C
satisfies ``d · n_C = 0`` for the road normal ``n_C = (sin φ cos θ, cos φ cos θ, sin θ)``,
which gives the pitch θ for any yaw of the camera against the motion (:func:`travel_pitch`).
The direction of each pair comes from the essential matrix of tracked corners
(``cv2.findEssentialMat`` with RANSAC, ``cv2.recoverPose``) — the whole static scene, not the
ground alone, so it needs no ground model and no nominal pose: it is what a cold start of a
forward-looking camera can rest on. Vehicles in lanes beside or ahead move parallel to us;
their flow radiates from the same focus of expansion, and what crosses it is the robust fit's
outliers. A single pair's direction scatters by ~0.7° in pitch on real frames (the body
pitches on its suspension); :func:`pitch_from_travel` takes the median of several and
requires them to agree.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from .camera import CameraModel
from .rig import PITCH_RANGE_DEG

#: corners tracked per pair, and their minimum spacing [px]
MAX_CORNERS = 2000
CORNER_SPACING_PX = 7
#: a corner whose backward track misses its start by more than this is dropped [px]
ROUND_TRIP_PX = 0.5
#: inlier threshold of the essential matrix's robust fit [px]
EPIPOLAR_PX = 0.5
#: the essential matrix's robust fit. MAGSAC++ (``cv2.USAC_MAGSAC``) halves a pair's scatter
#: on KITTI 07 and the traffic renders (``scripts/results/bench_travel_direction.md``) but on
#: a steep camera's planar view it takes the plane's mirror solution where RANSAC does not,
#: and the cold start then lost its check on a wrong level minimum (docs/traffic.md)
ESSENTIAL_METHOD = cv2.RANSAC
#: fewer essential-matrix inliers than this leave a pair's direction unknown
MIN_INLIERS = 60
#: corners that move less than this carry no direction (a car ahead at our speed) [px]
MIN_FLOW_PX = 1.0
#: a pair's pitch agrees with the median within this [deg]
AGREE_DEG = 1.5
#: pairs needed, and the share of them that must agree with their median
MIN_PAIRS = 5
MIN_AGREEING_SHARE = 0.6
#: a travel direction more than this off the optical axis is not a forward camera's [deg]
MAX_OFF_AXIS_DEG = 40.0

_LK = dict(winSize=(21, 21), maxLevel=5,
           criteria=(cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 30, 0.01))


@dataclass(frozen=True)
class PairTravel:
    """Direction of travel over one pair: a unit vector in the first frame's camera frame C,
    pointing ahead (z ≥ 0: a reversing vehicle's direction is flipped, its pitch is the same),
    the essential matrix's inliers and the rotation between the frames [deg]."""

    frames: tuple[int, int]
    direction: NDArray[np.float64]
    inliers: int
    rotation_deg: float


@dataclass(frozen=True)
class TravelPitch:
    """The camera pitch against the travel over several pairs [deg]: the median of the
    pairs' pitches, how many pairs gave a direction and how many of those agree with the
    median (within ``AGREE_DEG``), their median absolute deviation; ``reason`` says why it
    is not ``determined`` ("" where it is)."""

    pitch_deg: float
    pairs: int
    agreeing: int
    spread_deg: float
    reason: str = ""
    off_axis_deg: float = math.nan  # median angle of all pairs' directions off the axis
    #: the pairs it was taken over (None: no direction), for :func:`pitch_from_travel` at
    #: another roll
    travels: tuple[PairTravel | None, ...] = ()


    @property
    def determined(self) -> bool:
        return not self.reason

    @property
    def scattered(self) -> bool:
        """Whether too few of the pairs agree with their median pitch
        (:func:`too_few_agree`)."""
        return too_few_agree(self.agreeing, self.pairs)

    @property
    def standard_error_deg(self) -> float:
        """The standard error of :attr:`pitch_deg`, the pairs' median, from their scatter."""
        return median_standard_error(self.spread_deg, self.pairs)

    @property
    def directions(self) -> tuple[NDArray[np.float64], ...]:
        """Every pair's direction that was found (camera frame; those off the axis
        included)."""
        return tuple(tr.direction for tr in self.travels if tr is not None)


def travels_over(images: Iterable[tuple[int, NDArray]], camera: CameraModel,
                 max_pairs: int = 15, min_flow_px: float = 6.0) -> list[PairTravel | None]:
    """Directions of travel over up to ``max_pairs`` pairs of grey images ``(index, image)``
    of ``camera``, each pair from a reference frame to the first later frame whose corners
    moved ``min_flow_px`` (median) from it — a slow start or a stop is bridged by a longer
    pair instead of many pairs too short to fix a direction; None for a pair that fits no
    essential matrix."""
    out: list[PairTravel | None] = []
    ref: tuple[int, NDArray[np.uint8]] | None = None
    for index, image in images:
        if len(out) >= max_pairs:
            break
        grey = _grey_u8(image)
        if ref is None:
            ref = index, grey
            continue
        tracks = _tracks(ref[1], grey)
        if tracks is None:
            ref = index, grey  # nothing to track (a dark or blank frame): start again
            continue
        if np.median(np.linalg.norm(tracks[1] - tracks[0], axis=1)) < min_flow_px:
            continue
        out.append(_direction(*tracks, camera, (ref[0], index)))
        ref = index, grey
    return out


def pair_travel(before: NDArray, image: NDArray, camera: CameraModel,
                frames: tuple[int, int] = (0, 1), method: int = ESSENTIAL_METHOD
                ) -> PairTravel | None:
    """The direction of travel between two grey images of ``camera`` (as read: distorted
    points are undistorted); None where too few corners fit one essential matrix.
    ``method``: ``cv2.findEssentialMat``'s robust fit."""
    tracks = _tracks(_grey_u8(before), _grey_u8(image))
    return None if tracks is None else _direction(*tracks, camera, frames, method)


def _tracks(prev: NDArray[np.uint8], curr: NDArray[np.uint8]
            ) -> tuple[NDArray[np.float64], NDArray[np.float64]] | None:
    """Corners of ``prev`` and where they are in ``curr`` [px], those tracked both ways."""
    p0 = cv2.goodFeaturesToTrack(prev, MAX_CORNERS, 0.01, CORNER_SPACING_PX)
    if p0 is None or len(p0) < MIN_INLIERS:
        return None
    p1, st, _ = cv2.calcOpticalFlowPyrLK(prev, curr, p0, None, **_LK)
    back, st_back, _ = cv2.calcOpticalFlowPyrLK(curr, prev, p1, None, **_LK)
    a, b, back = p0.reshape(-1, 2), p1.reshape(-1, 2), back.reshape(-1, 2)
    keep = ((st.ravel() == 1) & (st_back.ravel() == 1)
            & (np.linalg.norm(back - a, axis=1) < ROUND_TRIP_PX))
    if np.count_nonzero(keep) < MIN_INLIERS:
        return None
    return a[keep].astype(np.float64), b[keep].astype(np.float64)


def _direction(a: NDArray[np.float64], b: NDArray[np.float64], camera: CameraModel,
               frames: tuple[int, int], method: int = ESSENTIAL_METHOD) -> PairTravel | None:
    """The pair's travel from its tracked corners ``a`` → ``b`` [px, as read]."""
    moved = np.linalg.norm(b - a, axis=1) >= MIN_FLOW_PX
    if np.count_nonzero(moved) < MIN_INLIERS:
        return None
    a, b = a[moved], b[moved]
    if camera.has_distortion:
        a, b = camera.undistort_points(a), camera.undistort_points(b)
    e, mask = cv2.findEssentialMat(a, b, camera.k, method, 0.999, EPIPOLAR_PX)
    if e is None or e.shape != (3, 3):
        return None  # several solutions stacked: a degenerate (planar or static) view
    inliers, r, t, _ = cv2.recoverPose(e, a, b, camera.k, mask=mask)
    if inliers < MIN_INLIERS:
        return None
    centre = (-r.T @ t).ravel()  # the second camera's centre in the first's frame
    centre /= np.linalg.norm(centre)
    if centre[2] < 0:
        centre = -centre
    rotation = math.degrees(float(np.linalg.norm(cv2.Rodrigues(r)[0])))
    return PairTravel(frames, centre, int(inliers), rotation)


def too_few_agree(agreeing: int, pairs: int) -> bool:
    """Whether ``agreeing`` of ``pairs`` pitches within ``AGREE_DEG`` of their median are fewer
    than ``MIN_AGREEING_SHARE`` of them: the pairs' directions disagree."""
    return agreeing < MIN_AGREEING_SHARE * pairs


def median_standard_error(mad: float, n: int) -> float:
    """The standard error of the median of ``n`` values whose median absolute deviation from
    it is ``mad`` (1.25 · 1.48 MAD / √n, as for a normal scatter), in ``mad``'s unit; inf
    for none."""
    return 1.86 * mad / math.sqrt(n) if n > 0 else math.inf


def travel_pitch(direction: NDArray, roll: float = 0.0) -> float:
    """Pitch [rad] of a camera with ``roll`` [rad] whose travel ``direction`` (camera frame)
    lies in the ground plane (module doc)."""
    d = np.asarray(direction, dtype=float)
    return math.atan2(-(d[0] * math.sin(roll) + d[1] * math.cos(roll)), d[2])


def pitch_from_travel(travels: list[PairTravel | None], roll: float = 0.0) -> TravelPitch:
    """The pitch [deg] the pairs' travel directions agree on (module doc), with ``roll``
    [rad]; not determined where fewer than ``MIN_PAIRS`` pairs gave a forward direction, or
    fewer than ``MIN_AGREEING_SHARE`` of them agree with their median."""
    known = [tr for tr in travels if tr is not None]
    off_axis = [math.degrees(math.acos(min(1.0, tr.direction[2]))) for tr in known]
    median_off = float(np.median(off_axis)) if off_axis else math.nan
    forward = [tr for tr, off in zip(known, off_axis, strict=True) if off <= MAX_OFF_AXIS_DEG]
    if not forward:
        return TravelPitch(math.nan, 0, 0, math.nan,
                           f"no pair of {len(travels)} gave a forward direction of travel",
                           median_off, tuple(travels))
    pitches = np.degrees([travel_pitch(tr.direction, roll) for tr in forward])
    median = float(np.median(pitches))
    agreeing = int(np.count_nonzero(np.abs(pitches - median) <= AGREE_DEG))
    spread = float(np.median(np.abs(pitches - median)))
    reason = ""
    if len(forward) < MIN_PAIRS:
        reason = f"{len(forward)} of {len(travels)} pairs gave a direction (need {MIN_PAIRS})"
    elif too_few_agree(agreeing, len(forward)):
        reason = (f"the pairs' directions disagree: {agreeing} of {len(forward)} within "
                  f"{AGREE_DEG:g}° of their median pitch {median:.1f}°")
    elif not PITCH_RANGE_DEG[0] <= median <= PITCH_RANGE_DEG[1]:
        # a body pitching by degrees between frames turns the flow as travel would
        reason = (f"the pairs' directions give a pitch of {median:.1f}°, outside the "
                  f"{PITCH_RANGE_DEG[0]:g}° to {PITCH_RANGE_DEG[1]:g}° of a camera that sees "
                  "the ground")
    return TravelPitch(median, len(forward), agreeing, spread, reason, median_off,
                       tuple(travels))


def _grey_u8(image: NDArray) -> NDArray[np.uint8]:
    img = np.asarray(image)
    if img.ndim == 3:
        img = cv2.cvtColor(img.astype(np.uint8), cv2.COLOR_BGR2GRAY)
    if img.dtype != np.uint8:
        img = np.clip(np.rint(img), 0, 255).astype(np.uint8)
    return img
