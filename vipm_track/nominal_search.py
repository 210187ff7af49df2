"""The nominal pose for the cold start when the user gives none (no ``--pitch``).

The estimator starts cold from the rig's nominal pitch (``Rig.pitch_deg``; without one the
paper's 60°, ``rig.DEFAULT_PITCH_DEG``), which also decides its region of interest, its
steep/forward-camera defaults and the window of plausible poses (``max_deviation_deg``
around it). A forward-looking camera
(a car's, pitch ~0–5°) does not converge from 60°. Before a run without ``--pitch``,
:func:`search_nominal_pose` cold-starts the first pair in which the view moves (pixels, not
patches: a drive may start standing) from the rig's pitch; only if that fails — "no
motion" included, since the 60° start's patches on a level camera sit partly on the sky,
which stands still — does it try the pair from each of ``CANDIDATE_PITCHES_DEG`` and keep the
converged estimate with the smallest residual (a wrong start that converges — a steep pitch
with a short travel on a level camera, the pitch/travel trade-off's second minimum — fits
the patches worse). A default start that converges far (more than ``SETTLE_PITCH_DEG``) from the
rig's pitch is kept too: a camera 35° down converges from 60° but sits on the edge of
the plausible window, and half its frames would be rejected as implausible. The pose is
settled on the next few pairs (the median pose of pairs started from it, repeated until it
stops moving) and becomes the run's nominal pose (``Rig.with_pose``), exactly as if given
with ``--pitch/--roll`` — but for a roll within ``CAMBER_ROLL_DEG`` of level, which the first
frames' road camber explains as well as the camera, so the nominal roll stays 0 there.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, NamedTuple

import numpy as np

from .errors import InputError
from .estimator import TwoFrameEstimator
from .estimator_config import REFINEMENT_WEIGHTING
from .pair_chain import estimate_pair
from .pair_result import STATUS_NO_MOTION, STATUS_OK
from .pipeline import config_with, prepare_image
from .static_content import noise_sigma, stands_still
from .travel_direction import (
    AGREE_DEG,
    MAX_OFF_AXIS_DEG,
    MIN_AGREEING_SHARE,
    MIN_PAIRS,
    TravelPitch,
    median_standard_error,
    pitch_from_travel,
    travels_over,
)

if TYPE_CHECKING:
    from collections.abc import Iterable, Iterator

    from numpy.typing import NDArray

    from .camera import CameraModel
    from .estimator_config import EstimatorConfig
    from .pair_result import PairResult
    from .rig import Rig
    from .sources import Frame, FrameSource

#: pairs the direction of travel is measured on, spread over the search's frames as the pairs
#: that give the roll are (:func:`spread_pairs`): the mount's pose, not the body's when the
#: drive starts (docs/traffic.md, "The nominal from pairs spread over the drive")
TRAVEL_PAIRS = 15
#: frames a stretch needs for its pair to be spread (fewer: the pairs one after another)
MIN_STRETCH = 3
#: a stretch's pair may run on into the next: this many stretches in all (a slow start)
STRETCHES_BRIDGED = 2
#: cold-start pitches tried when the rig's fails [deg], steep to level
CANDIDATE_PITCHES_DEG: tuple[float, ...] = (75.0, 40.0, 25.0, 12.0, 5.0, 1.0)
#: a found roll within this of level is the road's camber over the first frames, not the
#: camera's (KITTI 07 starts at 1.5°); the nominal roll stays 0 [deg]
CAMBER_ROLL_DEG = 3.0
#: a camera found below this pitch is forward-looking: its travel must be in view [deg]
LEVEL_PITCH_DEG = 15.0
#: pairs whose directions of travel lie within this of their mean agree on it [deg]
TRAVEL_AGREE_DEG = 10.0
#: the ground fit's pitch may differ from the direction of travel's by this [deg]
GROUND_AGREE_DEG = 2.0
#: a default cold start that converges more than this from the rig's pitch moves the
#: nominal pose to where it converged [deg]
SETTLE_PITCH_DEG = 5.0
#: a pose the ground fit found is the camera's only where at least this share of the pairs it
#: is settled on converge from it: a steep cart at 0.52 m per frame, its travel not
#: measurable, converged from the 1° start on one pair of six, at pitch 4.6° (truth 44.7°),
#: and printed `ok` rows 40° off; right poses converge on 6 of 6
MIN_SETTLED_SHARE = 0.5


@dataclass(frozen=True)
class NominalSearch:
    """A nominal pose found on the pair (``frames``) [deg], from the start ``start_pitch_deg``
    (the rig's ``default_pitch_deg`` failed there, or converged far from it:
    ``default_failed`` False). ``roll_deg`` is the nominal roll: the ``measured_roll_deg``,
    or 0 where that is within ``CAMBER_ROLL_DEG`` of level."""

    pitch_deg: float
    measured_roll_deg: float
    start_pitch_deg: float
    default_pitch_deg: float
    frames: tuple[int, int]
    pairs: int = 1  # pairs whose median it is
    default_failed: bool = True
    travel: TravelPitch | None = None  # the pitch against the travel, where it was needed
    undetermined: str = ""  # why the pose found is not the camera's ("": it is)

    @property
    def determined(self) -> bool:
        return not self.undetermined

    @property
    def roll_deg(self) -> float:
        return self.measured_roll_deg if abs(self.measured_roll_deg) > CAMBER_ROLL_DEG else 0.0

    def line(self) -> str:
        if self.undetermined:
            return (f"no --pitch given and the nominal pose was not determined: "
                    f"{self.undetermined}; every pair is marked \"no nominal pose\" (give "
                    f"--pitch/--roll)")
        frames = f"frames {self.frames[0]}-{self.frames[1]}"
        if self.travel is not None and self.travel.determined:
            return (f"no --pitch given; the direction of travel over {self.travel.pairs} "
                    f"pairs spread over the drive's first frames puts the camera at pitch "
                    f"{self.pitch_deg:.1f}° ({self.travel.agreeing} pairs within "
                    f"{AGREE_DEG:g}°) and the ground fit from there at roll "
                    f"{self.measured_roll_deg:.1f}° (median of {self.pairs} pairs); nominal "
                    f"pose now pitch {self.pitch_deg:.1f}°, roll {self.roll_deg:.1f}° (give "
                    f"--pitch/--roll to set it)")
        start = (f"the cold start from {self.default_pitch_deg:g}° failed on {frames}; from "
                 f"{self.start_pitch_deg:g}° it" if self.default_failed else
                 f"the cold start from {self.default_pitch_deg:g}° on {frames}")
        return (f"no --pitch given and {start} converged to pitch {self.pitch_deg:.1f}°, roll "
                f"{self.measured_roll_deg:.1f}° (median of {self.pairs} pairs); nominal pose "
                f"now pitch {self.pitch_deg:.1f}°, roll {self.roll_deg:.1f}° (give "
                f"--pitch/--roll to set it)")


@dataclass(frozen=True)
class NominalNotFound:
    """No start converged on the first pairs that move: the run goes from the rig's pose,
    which says so (``reason``: the frames tried and how each start failed)."""

    reason: str
    default_pitch_deg: float

    def line(self) -> str:
        return (f"no --pitch given and the nominal pose was not found: {self.reason}; the run "
                f"starts from the default pitch {self.default_pitch_deg:g}° (give "
                "--pitch/--roll: about 0-5° for a forward camera)")


class MovingPair(NamedTuple):
    """Two consecutive frames in which the view moved: indices, prepared images, and the
    time between them [s]."""

    frames: tuple[int, int]
    before: np.ndarray
    image: np.ndarray
    interval_s: float


def search_nominal_pose(
    source: FrameSource,
    rig: Rig,
    config: EstimatorConfig,
    max_pairs: int = 11,
    max_frames: int = 300,
    max_failed_pairs: int = 3,
    confirm_pairs: int = 6,
) -> NominalSearch | NominalNotFound | None:
    """Find a nominal pose on the first ``max_pairs`` pairs of ``source`` in which the view
    moves, within its first ``max_frames`` frames, started from ``rig`` (module doc; a drive
    that starts standing is searched from where it moves).

    The pose from the start that converges best on the first failing pair is then settled
    on up to ``confirm_pairs`` pairs from there (``_settle``): a single pair's pitch is noisy
    (±1° on KITTI's first frames), and a forward camera's pose prior pulls each cold start
    towards its nominal. None where the rig's pitch converges within
    ``SETTLE_PITCH_DEG`` of itself on the first pair with motion (nothing to change) or where
    no pair moves; :class:`NominalNotFound` where no start converges on ``max_failed_pairs``
    pairs (the run then goes from ``rig``). A pair the default start calls "no motion"
    although the view moved is a failing pair; one that every start calls so (traffic past
    a standing vehicle) is skipped."""
    camera = rig.camera
    pairs = moving_pairs(source, camera, max_pairs, max_frames)
    # the default start alone: a forward camera fails from 60° however its pitch is stepped
    default = TwoFrameEstimator(rig, config_with(config, cold_pitch_steps_deg=()))
    failed: list[str] = []  # each failing pair: its frames and the default start's status
    travel: TravelPitch | None = None
    for i, pair in enumerate(pairs):
        starts: list[tuple[float, PairResult]] = []
        stepped = False  # whether ``starts`` are the stepped ones
        result = estimate_pair(default, pair.before, pair.image, None, pair.interval_s)
        if result.status == STATUS_OK:
            if result.pose_curr is None or abs(math.degrees(result.pose_curr.pitch)
                                               - rig.pitch_deg) <= SETTLE_PITCH_DEG:
                return None
            found: tuple[float, PairResult] | None = (rig.pitch_deg, result)
        else:
            if travel is None:
                travel = travel_pitch_over(source, camera, max_frames)
            if travel.determined:
                spread = spread_pairs(source, camera, confirm_pairs, max_frames)
                if len(spread) < confirm_pairs // 2:  # a drive standing most of its window
                    spread = pairs[i:i + confirm_pairs]
                return _from_travel(rig, config, spread, travel)
            # "no motion" included: the view moved (``moving_pairs``), so the default
            # start's patches sat on what did not (a level camera's sky)
            # each start alone first; stepped off its pitch only where none converges
            starts = _converging_starts(rig, config, pair)
            if not starts and _can_step(config):
                starts, stepped = _converging_starts(rig, config, pair, stepped=True), True
            if not starts and result.status == STATUS_NO_MOTION:
                continue  # nothing moved in any start's view either: traffic past a standing car
            failed.append(f"{pair.frames[0]}-{pair.frames[1]} ({result.status})")
            found = starts[0] if starts else None
        if found is not None:
            settled_on = pairs[i:i + confirm_pairs]
            search = _settled_search(rig, config, settled_on, found, result, travel)
            if search.undetermined and found[1] is not result:
                # a start's minimum that most pairs do not settle from: the others' in turn,
                # then the starts stepped off their pitch (a right start can fail where a
                # wrong minimum converged)
                more = ([] if stepped or not _can_step(config) else
                        _converging_starts(rig, config, pair, stepped=True))
                for other in [*starts[1:], *more]:
                    retry = _settled_search(rig, config, settled_on, other, result, travel)
                    if not retry.undetermined:
                        return retry
            return search
        if len(failed) >= max_failed_pairs:
            break
    if not failed:
        return None
    return NominalNotFound(
        f"no cold start (from {rig.pitch_deg:g}°, the other starts"
        f"{'' if travel is None or travel.determined else ', the direction of travel'}) "
        f"converged on the pairs of frames {', '.join(failed)}", rig.pitch_deg)


def travel_pitch_over(source: FrameSource, camera: CameraModel, max_frames: int,
                      roll: float = 0.0) -> TravelPitch:
    """The pitch against the direction of travel (``travel_direction``) with ``roll`` [rad],
    over up to ``TRAVEL_PAIRS`` pairs spread over the first ``max_frames`` frames of
    ``source``, one from each of :func:`_stretches`: the mount's pitch, not the body's over
    the drive's first second. Where the stretches are too short to spread, or too few of
    them give a pair (a slow short drive), the pairs one after another from the start."""
    parts = _stretches(source, TRAVEL_PAIRS, max_frames)
    if parts is not None:
        spread = pitch_from_travel(
            [t for part in parts for t in travels_over(_prepared(part, camera), camera, 1)],
            roll)
        if spread.pairs >= MIN_PAIRS:
            return spread
    window = itertools.islice(source, max_frames)
    return pitch_from_travel(travels_over(_prepared(window, camera), camera, TRAVEL_PAIRS),
                             roll)


def spread_pairs(source: FrameSource, camera: CameraModel, count: int, max_frames: int
                 ) -> list[MovingPair]:
    """Up to ``count`` pairs of ``source`` in which the view moves, spread over its first
    ``max_frames`` frames: the first of each of :func:`_stretches` (or, where they are too
    short or the source cannot be split, :func:`moving_pairs` a stride apart)."""
    parts = _stretches(source, count, max_frames)
    if parts is None:
        stride = max(1, min(len(source), max_frames) // max(count, 1))
        return moving_pairs(source, camera, count, max_frames, stride)
    return [p for part in parts for p in moving_pairs(part, camera, 1, len(part))]


def _stretches(source: FrameSource, count: int, max_frames: int) -> list[FrameSource] | None:
    """``count`` parts of the first ``max_frames`` frames of ``source``, starting evenly
    spread, each running on into the next (up to ``STRETCHES_BRIDGED`` stretches: a pair
    taken from its start may need more frames where the view moves slowly); None where a
    stretch would be shorter than ``MIN_STRETCH`` frames or the source cannot be split. Each
    part is read from its own start (a seek in a video; a bag skips the messages before it),
    at most ``STRETCHES_BRIDGED`` times the window's frames in all."""
    try:
        window = min(len(source), max_frames)
        stretch = window // count
        if stretch < MIN_STRETCH:
            return None
        return [source.frames(start, min(STRETCHES_BRIDGED * stretch, window - start))
                for start in range(0, stretch * count, stretch)]
    except NotImplementedError:  # (a FrameSource of an application's own)
        return None


def _prepared(frames: Iterable[Frame], camera: CameraModel) -> Iterator[tuple[int, NDArray]]:
    """``(index, image)`` of the readable ``frames`` as the estimator takes them."""
    for frame in frames:
        image = _prepared_image(frame, camera)
        if image is not None:
            yield frame.index, image


def _prepared_image(frame: Frame, camera: CameraModel) -> NDArray | None:
    """The frame's image as the estimator takes it; None where it has none or the wrong
    size."""
    try:
        return None if frame.image is None else prepare_image(frame, camera)
    except ValueError:
        return None


def _from_travel(
    rig: Rig, config: EstimatorConfig, pairs: list[MovingPair], travel: TravelPitch,
) -> NominalSearch:
    """The nominal pose of a camera whose pitch the direction of travel gave: the roll of
    the ground fit started from that pitch (level), the pitch again with that roll. Not
    determined where the ground fit's pitch disagrees with the travel's by more than
    ``GROUND_AGREE_DEG`` (vehicles or walls taken for the ground) or its roll is implausible
    (``EstimatorConfig.max_roll_deg``)."""
    frames = pairs[0].frames
    try:
        estimator = TwoFrameEstimator(rig.with_pose(round(travel.pitch_deg, 1)), config)
    except InputError as exc:  # no ground in view at that pitch
        return NominalSearch(round(travel.pitch_deg, 1), rig.roll_deg,
                             round(travel.pitch_deg, 1), rig.pitch_deg, frames, 0,
                             travel=travel, undetermined=f"at the direction of travel's pitch "
                             f"{travel.pitch_deg:.1f}° the {exc}")
    poses = [r.pose_curr for p in pairs
             if (r := estimate_pair(estimator, p.before, p.image, None, p.interval_s)
                 ).status == STATUS_OK and r.pose_curr is not None]
    if not poses:  # the ground fit from the travel's pitch failed: the nominal roll stays
        return NominalSearch(round(travel.pitch_deg, 1), rig.roll_deg,
                             round(travel.pitch_deg, 1), rig.pitch_deg, frames, 0,
                             travel=travel)
    pitches = np.degrees([p.pitch for p in poses])
    ground_pitch = float(np.median(pitches))
    # the body pitches on its suspension from pair to pair: the median of a few pairs is
    # only as sure as their scatter says
    ground_se = median_standard_error(float(np.median(np.abs(pitches - ground_pitch))),
                                      len(poses))
    roll = math.degrees(float(np.median([p.roll for p in poses])))
    search = NominalSearch(round(travel.pitch_deg, 1), round(roll, 1),
                           round(travel.pitch_deg, 1), rig.pitch_deg, frames,
                           len(poses), travel=travel)
    undetermined = _implausible_roll(search, rig, config)
    tolerance = _ground_tolerance(ground_se)
    if not undetermined and abs(ground_pitch - travel.pitch_deg) > tolerance:
        undetermined = (f"the ground fit's pitch {ground_pitch:.1f}° (median of {len(poses)} "
                        f"pairs) disagrees with the direction of travel's "
                        f"{travel.pitch_deg:.1f}° (more than {tolerance:.1f}°: vehicles or "
                        f"walls taken for the ground?)")
    if undetermined:
        return replace(search, undetermined=undetermined)
    with_roll = pitch_from_travel(list(travel.travels), math.radians(search.roll_deg)) \
        if search.roll_deg else travel
    return replace(search, pitch_deg=round(with_roll.pitch_deg, 1), travel=with_roll)


def _contradicts_travel(search: NominalSearch, travel: TravelPitch | None) -> str:
    """Why a level camera found by the ground fit contradicts the direction of travel ("" where
    nothing contradicts it): its travel measured far off its axis (a forward-looking camera
    sees its focus of expansion: the fit found a second minimum), or a pitch further from the
    travel's than those pairs leave room for (:func:`_off_travel_pitch`)."""
    if travel is None or not search.pitch_deg < LEVEL_PITCH_DEG:
        return ""
    return _off_axis_travel(search, travel) or _off_travel_pitch(search, travel)


def _off_axis_travel(search: NominalSearch, travel: TravelPitch) -> str:
    """Why the travel lies off a level camera's axis (:func:`_contradicts_travel`). Only
    travel that at least two pairs agree on (``TRAVEL_AGREE_DEG``, and most of those with a
    direction) is evidence: where the corners cannot be tracked (a car at 2.5 m per frame)
    the few pairs that fit an essential matrix point anywhere (42° and 80° from the ground
    normal)."""
    if not travel.off_axis_deg > MAX_OFF_AXIS_DEG or len(travel.directions) < 2:
        return ""
    directions = np.array(travel.directions)
    mean = directions.sum(axis=0)
    mean /= np.linalg.norm(mean)
    apart = np.degrees(np.arccos(np.clip(directions @ mean, -1.0, 1.0)))
    agreeing = int(np.count_nonzero(apart <= TRAVEL_AGREE_DEG))
    if agreeing < max(2, MIN_AGREEING_SHARE * len(directions)):
        return ""
    return (f"the ground fit found a forward-looking camera (pitch {search.pitch_deg:.1f}°, "
            f"roll {search.measured_roll_deg:.1f}°) but the direction of travel lies "
            f"{travel.off_axis_deg:.0f}° off its axis")


def _off_travel_pitch(search: NominalSearch, travel: TravelPitch) -> str:
    """Why the ground fit's pitch is not the camera's although the direction of travel did
    not determine one: enough pairs gave a forward direction (``MIN_PAIRS``) but their
    pitches scattered (a body pitching over the drive), and the fit's pitch lies further from
    their median, at the fit's roll, than :func:`_ground_tolerance` allows. Scattered, the
    travel still bounds the pitch, and in slow dense traffic the ground fit can settle on the
    vehicles (docs/traffic.md, "KITTI's camera in slow dense traffic"). Pairs that agree on
    a pitch no camera that sees the ground has (``pitch_from_travel``) are no evidence."""
    at_roll = pitch_from_travel(list(travel.travels), math.radians(search.measured_roll_deg))
    if at_roll.pairs < MIN_PAIRS or not (at_roll.scattered or at_roll.determined):
        return ""
    tolerance = _ground_tolerance(at_roll.standard_error_deg)
    if abs(search.pitch_deg - at_roll.pitch_deg) <= tolerance:
        return ""
    why = at_roll.reason or f"{at_roll.agreeing} of them agree at that roll"
    return (f"the ground fit found pitch {search.pitch_deg:.1f}°, roll "
            f"{search.measured_roll_deg:.1f}°, but the direction of travel over "
            f"{at_roll.pairs} pairs puts the pitch at {at_roll.pitch_deg:.1f}° (more than "
            f"{tolerance:.1f}° apart; {why}): vehicles or walls taken for the ground?")


def _ground_tolerance(travel_se_deg: float) -> float:
    """How far [deg] the ground fit's pitch may lie from a pitch of the direction of travel
    whose standard error is ``travel_se_deg`` [deg]: ``GROUND_AGREE_DEG`` and three of it."""
    return GROUND_AGREE_DEG + 3.0 * travel_se_deg


def _few_settled(search: NominalSearch, tried: int) -> str:
    """Why the search's pose, the median of ``search.pairs`` of the ``tried`` pairs it was
    settled on, is one pair's wrong minimum rather than the camera's ("" where enough pairs
    converge from it: ``MIN_SETTLED_SHARE``)."""
    if search.pairs >= MIN_SETTLED_SHARE * tried:
        return ""
    return (f"the ground fit found pitch {search.pitch_deg:.1f}°, roll "
            f"{search.measured_roll_deg:.1f}° on {search.pairs} of the {tried} pairs it was "
            f"tried on; the others do not converge from it")


def _implausible_roll(search: NominalSearch, rig: Rig, config: EstimatorConfig) -> str:
    """Why the search's roll is not a vehicle camera's on ``rig`` ("" where it is
    plausible)."""
    if abs(search.measured_roll_deg - rig.roll_deg) <= config.max_roll_deg:
        return ""
    return (f"the ground fit settled at roll {search.measured_roll_deg:.1f}° (pitch "
            f"{search.pitch_deg:.1f}°), beyond the plausible ±{config.max_roll_deg:g}° of "
            f"{rig.roll_deg:g}° (--max-roll; --roll for a camera mounted rolled)")


def _settled_search(
    rig: Rig, config: EstimatorConfig, settled_on: list[MovingPair],
    found: tuple[float, PairResult], default_result: PairResult, travel: TravelPitch | None,
) -> NominalSearch:
    """The search's pose settled on ``settled_on`` from the start ``found`` (pitch [deg],
    its result on the first pair), with why it is not the camera's where it is not."""
    start, r = found
    assert r.pose_curr is not None
    pitch, roll, n = _settle(rig, config, settled_on, r.pose_curr.pitch, r.pose_curr.roll)
    search = NominalSearch(round(math.degrees(pitch), 1), round(math.degrees(roll), 1),
                           start, rig.pitch_deg, settled_on[0].frames, n,
                           default_failed=r is not default_result, travel=travel)
    return replace(search, undetermined=_implausible_roll(search, rig, config)
                   or _contradicts_travel(search, travel)
                   or _few_settled(search, len(settled_on)))


def _converging_starts(
    rig: Rig, config: EstimatorConfig, pair: MovingPair, stepped: bool = False,
) -> list[tuple[float, PairResult]]:
    """The starts of ``CANDIDATE_PITCHES_DEG`` (deg) whose cold start on the pair converges,
    with their results, smallest residual first; ``stepped``: each start also stepped off
    its pitch (``cold_pitch_steps_deg``: fast motion needs a start within ~5° of the truth),
    at three times the cost.

    The settings that shape the residual itself are the same for every start (seven
    parameters, patches weighted alike, the fixed inlier threshold): with the per-camera
    defaults a steep start had an eighth parameter and a self-tightening threshold, and on
    a real level camera a steep start beat the level ones by that alone, settling far from
    the truth. The region of interest, the number of refinements and the pose prior still
    follow each start's camera type."""
    alike = {"vertical_motion": False, **REFINEMENT_WEIGHTING["uniform"]}
    out: list[tuple[float, PairResult]] = []
    for start in CANDIDATE_PITCHES_DEG:
        if abs(start - rig.pitch_deg) < 1.0:
            continue
        steps = config.cold_pitch_steps_deg if stepped else ()
        try:
            estimator = TwoFrameEstimator(rig.with_pose(start), config_with(
                config, cold_pitch_steps_deg=steps, **alike))
        except InputError:  # too few interest points from this start
            continue
        r = estimate_pair(estimator, pair.before, pair.image, None, pair.interval_s)
        if r.status == STATUS_OK and r.pose_curr is not None:
            out.append((start, r))
    return sorted(out, key=lambda found: found[1].residual_px)


def _can_step(config: EstimatorConfig) -> bool:
    """Whether ``config`` steps cold starts off their pitch (None: the camera type's default
    steps; () turns stepping off)."""
    return config.cold_pitch_steps_deg != ()


def _settle(
    rig: Rig, config: EstimatorConfig,
    pairs: list[MovingPair],
    pitch: float, roll: float, rounds: int = 3, tolerance_deg: float = 0.3,
) -> tuple[float, float, int]:
    """Fixed point of "nominal → median pose of the pairs cold-started from it" (radians),
    from (``pitch``, ``roll``), at most ``rounds`` rounds; with the number of pairs behind
    the last median."""
    n = 1
    for _ in range(rounds):
        estimator = TwoFrameEstimator(rig.with_pose(round(math.degrees(pitch), 1),
                                                    round(math.degrees(roll), 1)), config)
        poses = [r.pose_curr for p in pairs
                 if (r := estimate_pair(estimator, p.before, p.image, None, p.interval_s)
                     ).status == STATUS_OK
                 and r.pose_curr is not None]
        if not poses:
            break
        new = float(np.median([p.pitch for p in poses]))
        roll, n = float(np.median([p.roll for p in poses])), len(poses)
        moved = abs(new - pitch)
        pitch = new
        if moved < math.radians(tolerance_deg):
            break
    return pitch, roll, n


def moving_pairs(
    source: FrameSource, camera: CameraModel, max_pairs: int, max_frames: int,
    stride: int = 1,
) -> list[MovingPair]:
    """Consecutive readable pairs in which the view moved
    (``static_content.stands_still``: a drive that starts at a standstill), the first
    ``max_pairs`` of them within the first ``max_frames`` frames (an unreadable or
    wrong-size frame breaks the chain), each pair's first frame at least ``stride`` frames
    after the last pair's (1: every pair)."""
    out, prev, next_n = [], None, 0
    for n, frame in enumerate(source):
        if n >= max_frames or len(out) >= max_pairs:
            break
        image = _prepared_image(frame, camera)
        current = None if image is None else (frame.index, image, noise_sigma(image), frame.t)
        if current is not None and prev is not None and n - 1 >= next_n and not stands_still(
                prev[1], image, (prev[2], current[2])):
            out.append(MovingPair((prev[0], frame.index), prev[1], image, frame.t - prev[3]))
            next_n = n - 1 + stride
        prev = current
    return out
