"""Sequence runner plumbing: statuses, rows, flushing, tracking seeds; then the real estimator
end to end on a rendered sequence (checked against its ground truth)."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
import pytest

from vipm_track.camera import CameraModel
from vipm_track.errors import InputError
from vipm_track.geometry import GroundPose, PlanarMotion
from vipm_track.measurement import PairMeasurement, read_measurements
from vipm_track.pipeline import FIRST_FRAME, NO_PREVIOUS, UNREADABLE, WRONG_SIZE, run_sequence
from vipm_track.rig import DEFAULT_PITCH_DEG, Rig
from vipm_track.runs import RunSummary, estimate_sequence, step_row
from vipm_track.sources import ArraySource, open_source
from vipm_track.table import read_table

CAMERA = CameraModel(k=np.array([[50.0, 0, 20], [0, 50.0, 15], [0, 0, 1]]), width=40, height=30)
RIG = Rig(CAMERA, 1.0, DEFAULT_PITCH_DEG)


@dataclass
class _Result:
    """Minimal stand-in for ``PairResult`` (status, poses, motion, to_measurement)."""

    status: str
    motion: PlanarMotion
    pose_curr: GroundPose
    stages: list = field(default_factory=list)
    residual_px: float = 0.1

    def to_measurement(self, frame: int, t: float) -> PairMeasurement:
        ok = self.status == "ok"
        z = np.array([0.5, 0.0, 0.5, 0.0, self.motion.tx, self.motion.tz, self.motion.yaw])
        return PairMeasurement(frame, t, z if ok else np.full(7, np.nan), np.eye(7) * 1e-4,
                               1.0, self.status, 42)


class _FakeEstimator:
    """Reports the mean-brightness change as tz at its nominal pose; fails where the images
    are equal."""

    nominal = GroundPose(0.5, 0.0, 1.0)

    def __init__(self) -> None:
        self.guesses: list = []

    def estimate(self, prev, curr, guess=None, frame_interval_s=None):
        self.guesses.append(guess)
        d = float(curr.mean()) - float(prev.mean())
        status = "ok" if d != 0 else "too few inliers"
        return _Result(status, PlanarMotion(0.0, d / 100.0, 0.0), self.nominal)


def _folder(tmp_path: Path, values: list[int | None], size=(40, 30)) -> Path:
    tmp_path.mkdir(parents=True, exist_ok=True)
    for i, v in enumerate(values):
        path = tmp_path / f"{i:06d}.png"
        if v is None:
            path.write_bytes(b"broken")
        else:
            cv2.imwrite(str(path), np.full((size[1], size[0]), v, np.uint8))
    (tmp_path / "times.txt").write_text("".join(f"{0.1 * i:.3f}\n" for i in range(len(values))))
    return tmp_path


def test_statuses_of_first_unreadable_and_failed_frames(tmp_path: Path) -> None:
    folder = _folder(tmp_path, [10, 20, None, 30, 40, 40, 50])
    steps = list(run_sequence(open_source(images=folder), RIG,
                              tracking=False, estimator=_FakeEstimator()))
    assert [s.frame for s in steps] == list(range(7))
    assert [s.status for s in steps] == [
        FIRST_FRAME, "ok", f"unreadable frame: {folder / '000002.png'}", NO_PREVIOUS, "ok",
        "too few inliers", "ok",
    ]
    np.testing.assert_allclose([s.t for s in steps], 0.1 * np.arange(7))
    assert steps[1].result.motion.tz == pytest.approx(0.1)


def test_rows_are_written_and_read_back_as_measurements(tmp_path: Path) -> None:
    folder = _folder(tmp_path / "img", [10, 20, 20, 35])
    out = tmp_path / "est.csv"
    summary = estimate_sequence(open_source(images=folder), RIG, out, tracking=False,
                                parquet=True, progress=False, estimator=_FakeEstimator())
    assert (summary.frames, summary.ok, summary.pairs) == (4, 2, 3)
    assert "2/4 frames ok" in summary.line() and "1× too few inliers" in summary.line()
    table = read_table(out)
    assert list(table["status"]) == [FIRST_FRAME, "ok", "too few inliers", "ok"]
    np.testing.assert_allclose(table["tz_m"], [np.nan, 0.1, np.nan, 0.15], equal_nan=True)
    assert np.isnan(table["pitch_deg"][0]) and table["pitch_deg"][1] == pytest.approx(
        np.degrees(0.5))
    parquet = read_table(out.with_suffix(".parquet"))
    np.testing.assert_allclose(parquet["tz_m"], table["tz_m"], equal_nan=True)
    ms = read_measurements(out)
    assert [m.ok for m in ms] == [False, True, False, True]


def test_wrong_size_first_frame_fails_fast_later_frames_get_a_row(tmp_path: Path) -> None:
    folder = _folder(tmp_path / "a", [10, 20], size=(41, 30))
    with pytest.raises(InputError, match=r"41×30 px but the camera model is 40×30"):
        list(run_sequence(open_source(images=folder), RIG, estimator=_FakeEstimator()))
    folder = _folder(tmp_path / "b", [10, 20, 30])
    cv2.imwrite(str(folder / "000001.png"), np.zeros((30, 41), np.uint8))
    steps = list(run_sequence(open_source(images=folder), RIG, tracking=False,
                              estimator=_FakeEstimator()))
    assert [s.status for s in steps] == [
        FIRST_FRAME, f"{WRONG_SIZE} 41×30 (camera 40×30): 000001.png", NO_PREVIOUS]


def test_bad_rig_is_an_input_error() -> None:
    for height in (-1.0, 0.0, float("nan"), float("inf")):
        with pytest.raises(InputError, match="rig: height_m must be a positive number"):
            Rig(CAMERA, height, DEFAULT_PITCH_DEG)


def test_row_of_a_step_without_result_has_empty_numbers() -> None:
    from vipm_track.pipeline import SequenceStep

    row = step_row(SequenceStep(3, 0.3, None, FIRST_FRAME), 1.5)
    assert row == {"frame": 3, "t": 0.3, "height_m": 1.5, "status": FIRST_FRAME}
    summary = RunSummary()
    summary.add(SequenceStep(3, 0.3, None, FIRST_FRAME))
    assert summary.frames == 1 and summary.ok == 0


# --- estimate CLI option parsing ---------------------------------------------------------------


def test_parse_grid_and_roi(tmp_path: Path) -> None:
    from vipm_track.commands.estimator_options import parse_grid, parse_roi

    assert parse_grid("11x9") == (11, 9) and parse_grid("5×4") == (5, 4)
    for bad in ("11", "ax9", "1x9"):
        with pytest.raises(InputError, match="--grid"):
            parse_grid(bad)
    mask = parse_roi("10,5,30,25", CAMERA)
    assert mask.shape == (30, 40) and mask.sum() == 20 * 20 and mask[5, 10] and not mask[4, 10]
    with pytest.raises(InputError, match=r"need 0 <= x0 < x1 <= 40"):
        parse_roi("10,5,50,25", CAMERA)
    with pytest.raises(InputError, match="neither a file nor a rectangle"):
        parse_roi("10,5,30", CAMERA)
    polygon = tmp_path / "road.txt"
    polygon.write_text("# x y\n0 29\n39 29\n20 10\n")
    tri = parse_roi(str(polygon), CAMERA)
    assert tri[28, 20] and not tri[5, 20] and not tri[12, 2]
    polygon.write_text("0 29\n39 29\n20 10\n60 40\n")  # drawn on a larger image: was clipped
    with pytest.raises(InputError, match=r"road.txt: line 4: vertex \(60, 40\) lies off the "
                       r"camera image: need 0 <= x <= 40 and 0 <= y <= 30"):
        parse_roi(str(polygon), CAMERA)
    polygon.write_text("0 29\n39 29\n")
    with pytest.raises(InputError, match="at least 3 vertices"):
        parse_roi(str(polygon), CAMERA)
    image = np.zeros((30, 40), np.uint8)
    image[15:, :] = 255
    cv2.imwrite(str(tmp_path / "mask.png"), image)
    assert parse_roi(str(tmp_path / "mask.png"), CAMERA).sum() == 15 * 40
    cv2.imwrite(str(tmp_path / "small.png"), image[:20])
    with pytest.raises(InputError, match="mask is 40×20 px but the camera image is 40×30"):
        parse_roi(str(tmp_path / "small.png"), CAMERA)


# --- the real estimator on a rendered sequence -------------------------------------------------


@pytest.fixture(scope="module")
def cart_sequence(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from vipm_track.sim import simulate_sequence

    folder = tmp_path_factory.mktemp("cart")
    simulate_sequence("cart", 5, folder, seed=3, profile="static")
    return folder


def test_estimate_cli_on_rendered_cart_matches_ground_truth(cart_sequence: Path,
                                                            tmp_path: Path) -> None:
    from vipm_track.cli import main
    from vipm_track.evaluate import frame_errors

    out = tmp_path / "est.csv"
    rc = main(["estimate", "--images", str(cart_sequence / "images"), "--camera",
               str(cart_sequence / "camera.yaml"), "--height", "0.7", "--out", str(out),
               "--parquet", "--quiet", "--columns", "all"])
    assert rc == 0
    est, truth = read_table(out), read_table(cart_sequence / "gt.csv")
    assert list(est["status"]) == [FIRST_FRAME] + ["ok"] * 4
    np.testing.assert_allclose(est["t"], truth["t"])
    errors = frame_errors(est, truth)
    assert errors["frame"].size == 4
    # measured on this static run: pitch ≤ 0.010°, roll ≤ 0.007°, distance ≤ 0.017 %,
    # yaw ≤ 0.0012°; both frames of each pair
    for name in ("pitch_deg", "prev_pitch_deg"):
        assert np.max(np.abs(errors[name])) < 0.04, (name, errors[name])
    for name in ("roll_deg", "prev_roll_deg"):
        assert np.max(np.abs(errors[name])) < 0.03, (name, errors[name])
    assert np.max(np.abs(errors["distance_pct"])) < 0.08
    assert np.max(np.abs(errors["yaw_deg"])) < 0.005
    assert np.all(est["inliers"][1:] >= 12) and np.all(est["patches"][1:] >= est["inliers"][1:])
    assert read_table(out.with_suffix(".parquet"))["status"][1] == "ok"


def test_estimate_cli_columns_follow_a_shaking_camera(tmp_path: Path) -> None:
    # The camera pitches and rolls by 0.2–1.4° between frames here, so each pose column is
    # checked against its own frame: swapped pitch/prev_pitch (or roll) columns are off by
    # the change. Measured: poses ≤ 0.02°, changes within the pair ≤ 0.0014°, travel
    # ≤ 0.76 % (the heave of the shaking profile), yaw ≤ 0.0013°.
    from vipm_track.cli import main
    from vipm_track.evaluate import frame_errors
    from vipm_track.sim import simulate_sequence

    simulate_sequence("cart", 5, tmp_path, seed=3, profile="shaking")
    out = tmp_path / "est.csv"
    assert main(["estimate", "--images", str(tmp_path / "images"), "--camera",
                 str(tmp_path / "camera.yaml"), "--height", "0.7", "--out", str(out),
                 "--quiet"]) == 0
    est, truth = read_table(out), read_table(tmp_path / "gt.csv")
    change = np.abs(np.asarray(truth["pitch_deg"]) - np.asarray(truth["prev_pitch_deg"]))[1:]
    assert change.max() > 1.0 and change.min() > 0.4  # the check below has teeth
    errors = frame_errors(est, truth)
    assert errors["frame"].size == 4
    for name in ("pitch_deg", "prev_pitch_deg", "roll_deg", "prev_roll_deg"):
        assert np.max(np.abs(errors[name])) < 0.06, (name, errors[name])
    for name in ("pitch_change_deg", "roll_change_deg"):
        assert np.max(np.abs(errors[name])) < 0.01, (name, errors[name])
    assert np.max(np.abs(errors["distance_pct"])) < 2.5
    assert np.max(np.abs(errors["yaw_deg"])) < 0.005


def test_tracking_seeds_each_pair_from_the_previous_result(cart_sequence: Path) -> None:
    from vipm_track.camera import load_camera

    camera = load_camera(cart_sequence / "camera.yaml")
    steps = list(run_sequence(open_source(images=cart_sequence / "images", max_frames=4),
                              Rig(camera, 0.7, DEFAULT_PITCH_DEG)))
    assert [s.tracked for s in steps] == [False, False, True, True]
    assert all(s.ok for s in steps[1:])
    # The seed of pair 3 was pair 2's motion: the estimate moved only a little from it.
    assert abs(steps[3].result.motion.tz - steps[2].result.motion.tz) < 0.01


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--grid", "11"], "--grid must look like 11x9"),
        (["--refinements", "-1"], "--refinements must be between 0 and 10"),
        (["--pitch", "95"], r"--pitch must be in \[-10.0, 90.0\] degrees"),
        (["--patch-size", "100"], "--patch-size must be a multiple of 16"),
        (["--roi", "0,0,9000,10"], "--roi '0,0,9000,10': need 0 <= x0 < x1 <= 800"),
        (["--height", "-2"], "--height must be a positive"),
        (["--start", "50"], "--start 50 but the folder has 5 images"),
        (["--workers", "0"], "--workers must be >= 1"),
        (["--chunk-frames", "1"], "--chunk-frames must be >= 2"),
        (["--threads", "0"], "argument --threads: expected a whole number >= 1, got '0'"),
        (["--workers", "2", "--rerun", "x.rrd"], "--rerun .* use it with --workers 1"),
    ],
)
def test_estimate_cli_bad_options_exit_2_with_a_message(
    cart_sequence: Path, tmp_path: Path, capsys: pytest.CaptureFixture, extra: list[str],
    message: str,
) -> None:
    from vipm_track.cli import main

    argv = ["estimate", "--images", str(cart_sequence / "images"), "--camera",
            str(cart_sequence / "camera.yaml"), "--height", "0.7",
            "--out", str(tmp_path / "e.csv"), "--quiet", *extra]
    try:
        rc = main(argv)
    except SystemExit as stop:  # argparse's own checks (option types) exit at parsing
        rc = stop.code
    assert rc == 2
    err = capsys.readouterr().err
    assert "vipm-track estimate: error:" in err
    assert __import__("re").search(message, err), err


@pytest.mark.parametrize("command", ["track", "smooth"])
def test_a_bad_estimator_option_stops_the_filters_before_they_write(
        command: str, cart_sequence: Path, tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    from vipm_track.cli import main

    out = tmp_path / "out.csv"
    rc = main([command, "--images", str(cart_sequence / "images"), "--camera",
               str(cart_sequence / "camera.yaml"), "--height", "0.7", "--pitch", "nan",
               "--out", str(out), "--quiet"])
    assert rc == 2
    assert "--pitch must be in" in capsys.readouterr().err
    assert not out.exists()


def test_estimates_do_not_depend_on_the_thread_count(cart_sequence: Path,
                                                     tmp_path: Path) -> None:
    """One pair's patches correlated on 1 or 3 threads (the large batches split across
    them): the same file, byte for byte."""
    from vipm_track.cli import main
    from vipm_track.workers import set_threads, threads

    base = ["estimate", "--images", str(cart_sequence / "images"), "--camera",
            str(cart_sequence / "camera.yaml"), "--height", "0.7", "--quiet"]
    before = threads()
    try:
        for n in (1, 3):
            assert main([*base, "--threads", str(n), "--out", str(tmp_path / f"{n}.csv")]) == 0
            assert threads() == n
    finally:
        set_threads(before)
    assert (tmp_path / "1.csv").read_bytes() == (tmp_path / "3.csv").read_bytes()
    assert list(read_table(tmp_path / "3.csv")["status"]) == [FIRST_FRAME] + ["ok"] * 4


@pytest.mark.parametrize(("value", "expected"), [("3", 3), ("1", 1), ("0", None), ("two", None)])
def test_thread_count_default_comes_from_the_environment(value: str, expected: int | None
                                                         ) -> None:
    """VIPM_TRACK_THREADS (a Dask worker's setting) sets the default; unusable values are
    ignored (2, or the cores if fewer)."""
    import os
    import subprocess
    import sys

    code = "from vipm_track.workers import threads; print(threads())"
    env = {**os.environ, "VIPM_TRACK_THREADS": value}
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True,
                         text=True, check=True).stdout
    assert int(out) == (expected or min(2, os.cpu_count() or 1))


@pytest.mark.parametrize("workers", [1, 2, 64])
def test_fleet_workers_share_the_cores_as_correlation_threads(workers: int) -> None:
    import os

    from vipm_track.fleet.cluster import worker_environ
    from vipm_track.workers import THREADS_ENV

    env = worker_environ(workers)
    assert env[THREADS_ENV] == max(1, (os.cpu_count() or 1) // workers)
    assert env["OMP_NUM_THREADS"] == 1


def test_chunked_runs_are_the_same_in_one_process_or_two(cart_sequence: Path,
                                                         tmp_path: Path) -> None:
    """Chunks of 2 frames (each estimating the pair across its start, cold): every pair of
    the 5 frames ok and on the truth, rows in frame order, the same file from one process
    as from two; a chunk whose frame before is unreadable says 'no previous frame'."""
    from vipm_track.cli import main
    from vipm_track.evaluate import frame_errors

    base = ["estimate", "--images", str(cart_sequence / "images"), "--camera",
            str(cart_sequence / "camera.yaml"), "--height", "0.7", "--quiet",
            "--chunk-frames", "2"]
    one, two = tmp_path / "one.csv", tmp_path / "two.csv"
    assert main([*base, "--out", str(one)]) == 0
    assert main([*base, "--workers", "2", "--out", str(two)]) == 0
    assert one.read_bytes() == two.read_bytes()
    est, truth = read_table(two), read_table(cart_sequence / "gt.csv")
    assert list(est["frame"]) == [0, 1, 2, 3, 4]
    assert list(est["status"]) == [FIRST_FRAME] + ["ok"] * 4
    errors = frame_errors(est, truth)
    assert np.max(np.abs(errors["pitch_deg"])) < 0.1
    assert np.max(np.abs(errors["distance_pct"])) < 1.0

    images = [cv2.imread(str(p), cv2.IMREAD_GRAYSCALE)
              for p in sorted((cart_sequence / "images").glob("*.png"))]
    images[1] = None  # the frame before the second chunk (frames 2-3)
    from vipm_track.camera import load_camera
    from vipm_track.parallel import run_chunked

    rig = Rig(load_camera(cart_sequence / "camera.yaml"), 0.7, DEFAULT_PITCH_DEG)
    steps = run_chunked(ArraySource(images, truth["t"]), rig, None, True, 1, 2)
    statuses = [s.status for s in steps]
    assert statuses[1].startswith(UNREADABLE)
    assert statuses[:1] + statuses[2:] == [FIRST_FRAME, NO_PREVIOUS, "ok", "ok"]


class _SlowSource(ArraySource):
    """Frames that take a minute to read: a chunk that runs while the run is interrupted."""

    def frames(self, position: int, count: int) -> ArraySource:
        import time

        time.sleep(60)
        return super().frames(position, count)


def test_an_interrupted_parallel_run_ends_without_waiting_for_running_chunks() -> None:
    """Ctrl-C / SIGTERM (a KeyboardInterrupt in the main process) while chunks run in worker
    processes ends the run within seconds: the workers are ended, not waited for."""
    import signal
    import time

    from vipm_track.parallel import run_chunked

    def interrupt(signum, frame):
        raise KeyboardInterrupt

    images = [np.zeros((48, 64), np.uint8)] * 8
    k = np.array([[50.0, 0, 31.5], [0, 50.0, 23.5], [0, 0, 1]])
    rig = Rig(CameraModel(k, 64, 48), 0.7, DEFAULT_PITCH_DEG)
    previous = signal.signal(signal.SIGALRM, interrupt)
    start = time.monotonic()
    try:
        signal.setitimer(signal.ITIMER_REAL, 3.0)
        with pytest.raises(KeyboardInterrupt):
            list(run_chunked(_SlowSource(images, np.arange(8) * 0.1), rig, None, True, 2, 4))
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)
    assert time.monotonic() - start < 15


class _MarkedChunk(ArraySource):
    """A chunk that leaves a mark (``marker``) once all its frames were taken: its run is
    then over."""

    marker: Path

    def __iter__(self):
        yield from super().__iter__()
        self.marker.write_text("done")


class _FirstChunkSlowSource(ArraySource):
    """The first chunk takes a minute to read; the others are read at once and marked."""

    marker: Path

    def frames(self, position: int, count: int) -> ArraySource:
        import time

        if position == 0:
            time.sleep(60)
            return super().frames(position, count)
        chunk = super().frames(position, count)
        marked = _MarkedChunk(chunk.images, chunk.t, chunk.description)
        marked.first_index, marked.marker = chunk.first_index, self.marker
        return marked


def _interrupted_parallel_run(source: ArraySource, chunk_frames: int,
                              ready: Callable[[], bool], poll_s: float,
                              before_interrupt: Callable[[], None] = lambda: None,
                              ) -> tuple[list[int], float]:
    """The frames a two-process ``run_chunked`` over ``source`` yields before Ctrl-C (a
    KeyboardInterrupt from SIGALRM, polled every ``poll_s`` s, once ``ready()`` or after
    50 s; ``before_interrupt`` runs just before it), and the run's seconds."""
    import signal

    from vipm_track.parallel import run_chunked

    k = np.array([[50.0, 0, 31.5], [0, 50.0, 23.5], [0, 0, 1]])
    rig = Rig(CameraModel(k, 64, 48), 0.7, DEFAULT_PITCH_DEG)
    start = time.monotonic()

    def interrupt(signum, frame):
        if ready() or time.monotonic() - start > 50:
            before_interrupt()
            raise KeyboardInterrupt
        signal.setitimer(signal.ITIMER_REAL, poll_s)

    previous = signal.signal(signal.SIGALRM, interrupt)
    frames = []
    try:
        signal.setitimer(signal.ITIMER_REAL, poll_s)
        with pytest.raises(KeyboardInterrupt):
            for step in run_chunked(source, rig, None, True, 2, chunk_frames):
                frames.append(step.frame)
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)
    return frames, time.monotonic() - start


def test_an_interrupted_parallel_run_keeps_the_chunks_that_finished(tmp_path: Path) -> None:
    """Interrupted while the first chunk still runs, a parallel run yields the steps of the
    later chunk that finished before it passes the interruption on: nothing computed is
    lost."""
    source = _FirstChunkSlowSource([np.zeros((48, 64), np.uint8)] * 8, np.arange(8) * 0.1)
    source.marker = tmp_path / "second chunk done"
    # a second after the second chunk's run is over (its result is back by then)
    frames, _ = _interrupted_parallel_run(source, 4, lambda: source.marker.exists() and
                                          source.marker.stat().st_mtime < time.time() - 1, 0.5)
    assert source.marker.exists()
    assert frames == [4, 5, 6, 7]


class _SlowlyReadChunk(ArraySource):
    """A chunk whose frames take 0.4 s each to read; reading frame 2 leaves a mark."""

    marker: Path

    def __iter__(self):
        for frame in super().__iter__():
            time.sleep(0.4)
            if frame.index == 2:
                self.marker.write_text("frame 2 read")
            yield frame


class _SlowlyReadSource(ArraySource):
    marker: Path

    def frames(self, position: int, count: int) -> ArraySource:
        chunk = super().frames(position, count)
        slow = _SlowlyReadChunk(chunk.images, chunk.t, chunk.description)
        slow.first_index, slow.marker = chunk.first_index, self.marker
        return slow


def test_an_interrupted_parallel_run_keeps_the_pairs_of_running_chunks(tmp_path: Path) -> None:
    """Interrupted while both chunks still run, a parallel run yields the pairs each had
    estimated (in frame order, a gap after the first chunk's) before it passes the
    interruption on, and ends within seconds; also where the SIGTERM went to the whole
    process group (a service stopped), the workers too."""
    import multiprocessing
    import os
    import signal

    source = _SlowlyReadSource([np.zeros((48, 64), np.uint8)] * 40, np.arange(40) * 0.1)
    source.marker = tmp_path / "frame 2 read"

    def sigterm_to_the_workers() -> None:
        for worker in multiprocessing.active_children():
            os.kill(worker.pid, signal.SIGTERM)

    frames, seconds = _interrupted_parallel_run(source, 20, source.marker.exists, 0.2,
                                                sigterm_to_the_workers)
    assert seconds < 40  # a chunk's 20 frames take 8 s to read: it was not waited for
    first, second = [f for f in frames if f < 20], [f for f in frames if f >= 20]
    assert first[:3] == [0, 1, 2] and first == list(range(len(first))) and len(first) < 20
    assert second and second == list(range(20, 20 + len(second))) and len(second) < 20


def test_estimate_cli_bad_camera_file(cart_sequence: Path, tmp_path: Path,
                                      capsys: pytest.CaptureFixture) -> None:
    from vipm_track.cli import main

    bad = tmp_path / "camera.yaml"
    bad.write_text("image_width: 800\nimage_height: 600\n")
    assert main(["estimate", "--images", str(cart_sequence / "images"), "--camera", str(bad),
                 "--height", "0.7", "--out", str(tmp_path / "e.csv")]) == 2
    assert "field 'camera_matrix': missing" in capsys.readouterr().err


def test_interrupted_run_keeps_the_rows_written(tmp_path: Path) -> None:
    folder = _folder(tmp_path / "img", [10, 20, 30, 40, 50])
    out = tmp_path / "est.csv"

    def interrupt_at_frame_2(step) -> None:
        if step.frame == 2:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        estimate_sequence(open_source(images=folder), RIG, out, tracking=False,
                          progress=False, on_step=interrupt_at_frame_2,
                          estimator=_FakeEstimator())
    table = read_table(out)
    assert list(table["frame"]) == [0, 1, 2]
    np.testing.assert_allclose(table["tz_m"][1:], [0.1, 0.1])


@pytest.mark.parametrize(("choice", "steep", "expected"), [
    ("auto", True, (True, True, 6.0)),
    ("auto", False, (False, False, 0.0)),
    ("uniform", True, (False, False, 0.0)),
    ("noise", False, (True, True, 6.0)),
])
def test_refinement_weights_option_sets_the_estimator(choice: str, steep: bool,
                                                      expected: tuple) -> None:
    import argparse

    from vipm_track.commands.estimator_options import (
        add_estimator_options,
        build_config,
        build_rig,
    )
    from vipm_track.estimator import TwoFrameEstimator
    from vipm_track.sim import PRESETS

    parser = argparse.ArgumentParser()
    add_estimator_options(parser)
    preset = PRESETS["cart" if steep else "car"]
    args = parser.parse_args(["--refinement-weights", choice, "--pitch", str(preset.pitch_deg)])
    camera = preset.camera()
    est = TwoFrameEstimator(build_rig(args, camera, preset.height_m), build_config(args, camera))
    got = (est.config.weight_patches, est.config.recentre_windows,
           est.config.inlier_median_factor)
    assert got == expected


@pytest.mark.parametrize(("flag", "expected"), [
    ([], 0), (["--refinement-resolution", "full"], 0), (["--refinement-resolution", "half"], 1),
])
def test_refinement_resolution_option_sets_the_estimator(flag: list[str], expected: int) -> None:
    import argparse

    from vipm_track.commands.estimator_options import add_estimator_options, build_config
    from vipm_track.sim import PRESETS

    parser = argparse.ArgumentParser()
    add_estimator_options(parser)
    assert build_config(parser.parse_args(flag), PRESETS["car"].camera()).ipm_poc_level == expected
    with pytest.raises(SystemExit) as exit_info:
        parser.parse_args(["--refinement-resolution", "quarter"])
    assert exit_info.value.code == 2


@pytest.mark.parametrize(("flag", "steep", "expected"), [
    ([], True, True), ([], False, False),
    (["--vertical-motion"], False, True), (["--no-vertical-motion"], True, False),
])
def test_vertical_motion_option_sets_the_estimator(flag: list[str], steep: bool,
                                                   expected: bool) -> None:
    import argparse

    from vipm_track.commands.estimator_options import (
        add_estimator_options,
        build_config,
        build_rig,
    )
    from vipm_track.estimator import TwoFrameEstimator
    from vipm_track.sim import PRESETS

    parser = argparse.ArgumentParser()
    add_estimator_options(parser)
    preset = PRESETS["cart" if steep else "car"]
    args = parser.parse_args([*flag, "--pitch", str(preset.pitch_deg)])
    camera = preset.camera()
    est = TwoFrameEstimator(build_rig(args, camera, preset.height_m), build_config(args, camera))
    assert est.config.vertical_motion is expected


def test_estimates_table_keeps_the_full_covariance(tmp_path: Path) -> None:
    from vipm_track.measurement import measurement_row
    from vipm_track.table import CORRELATION_COLUMNS, ESTIMATE_COLUMNS, read_table, write_table

    rng = np.random.default_rng(2)
    a = rng.normal(size=(7, 7))
    cov = a @ a.T * 1e-6 + np.eye(7) * 1e-8
    z = rng.normal(0, 0.05, 7)
    ms = [PairMeasurement(1, 0.1, z, cov, 1.5),
          PairMeasurement(2, 0.2, np.full(7, np.nan), np.full((7, 7), np.nan), 1.5, "no motion")]
    path = tmp_path / "est.csv"
    write_table(path, [measurement_row(m) for m in ms], ESTIMATE_COLUMNS)
    back = read_measurements(path)
    np.testing.assert_allclose(back[0].covariance, cov, rtol=1e-12, atol=1e-24)
    np.testing.assert_allclose(back[0].z, z, rtol=1e-12)
    assert not back[1].ok
    # an older table without the correlation columns: diagonal
    columns = read_table(path)
    old = [c for c in columns if c not in CORRELATION_COLUMNS]
    rows = [{c: columns[c][i] for c in old} for i in range(2)]
    write_table(tmp_path / "old.csv", rows, [c for c in ESTIMATE_COLUMNS if c in old])
    np.testing.assert_allclose(read_measurements(tmp_path / "old.csv")[0].covariance,
                               np.diag(np.diag(cov)), rtol=1e-12, atol=1e-24)
    # a coefficient outside [-1, 1] names row, frame and column
    rows = [{c: columns[c][i] for c in columns} for i in range(2)]
    rows[0]["corr_pitch__tz"] = 1.5
    write_table(tmp_path / "bad.csv", rows, ESTIMATE_COLUMNS)
    with pytest.raises(InputError, match=r"row 2 \(frame 1\): corr_pitch__tz = 1.5"):
        read_measurements(tmp_path / "bad.csv")
    # without a status column a row without numbers is no measurement, not an "ok" row
    # lacking them (which the reader warns about)
    from vipm_track.measurement import MISSING_NUMBERS, in_sequence

    rows = [{c: columns[c][i] for c in columns if c != "status"} for i in range(2)]
    write_table(tmp_path / "no_status.csv", rows, [c for c in ESTIMATE_COLUMNS if c != "status"])
    lines = (tmp_path / "no_status.csv").read_text().splitlines()
    header = lines[0].split(",")
    drop = header.index("status")
    (tmp_path / "no_status.csv").write_text("\n".join(
        ",".join(cell for j, cell in enumerate(line.split(",")) if j != drop)
        for line in lines) + "\n")
    back = read_measurements(tmp_path / "no_status.csv")
    assert [m.status for m in back] == ["ok", MISSING_NUMBERS]
    assert not in_sequence(back)[1].missing
    # a standard deviation of zero (an exact measurement: a singular smoother) or below
    for name, value in (("tz_std_m", 0.0), ("pitch_std_deg", -0.5)):
        rows = [{c: columns[c][i] for c in columns} for i in range(2)]
        rows[0][name] = value
        write_table(tmp_path / "bad_std.csv", rows, ESTIMATE_COLUMNS)
        with pytest.raises(InputError, match=rf"row 2 \(frame 1\): {name} = {value} is not a "
                           "standard deviation"):
            read_measurements(tmp_path / "bad_std.csv")


class _WatchedSource:
    """A source that records how far it has been read and may fail at one position."""

    description = "watched frames"

    def __init__(self, inner, fail_at: int | None = None) -> None:
        self.inner, self.fail_at = inner, fail_at
        self.read: list[int] = []
        self.events: dict[int, threading.Event] = {}

    def __iter__(self):
        for position, frame in enumerate(self.inner):
            if position == self.fail_at:
                raise InputError(f"{self.description}: frame {position} is corrupt")
            self.read.append(position)
            self.events.setdefault(position, threading.Event()).set()
            yield frame


@pytest.fixture
def two_threads():
    from vipm_track.workers import set_threads, threads

    before = threads()
    set_threads(2)
    yield
    set_threads(before)


def _cart(cart_sequence: Path, frames: int):
    from vipm_track.camera import load_camera

    camera = load_camera(cart_sequence / "camera.yaml")
    return (open_source(images=cart_sequence / "images", max_frames=frames),
            Rig(camera, 0.7, DEFAULT_PITCH_DEG))


def test_the_next_frame_is_read_and_prepared_while_a_pair_is_estimated(
        cart_sequence: Path, two_threads) -> None:
    from vipm_track.estimator import TwoFrameEstimator

    inner, rig = _cart(cart_sequence, 4)
    source = _WatchedSource(inner)
    prepared_ahead = []

    preparing_threads = set()

    class Watching(TwoFrameEstimator):
        def prepare_pair(self, prev, curr):
            preparing_threads.add(threading.current_thread().name)
            return super().prepare_pair(prev, curr)

        def estimate(self, prev, curr, guess=None, frame_interval_s=None, prepared=None):
            # pair (k-1, k) is estimated while frame k+1 is being read on the other thread
            k = len(prepared_ahead) + 1
            if k + 1 < len(inner):
                event = source.events.setdefault(k + 1, threading.Event())
                prepared_ahead.append(event.wait(10.0))
            assert prepared is not None and prepared.curr.image.dtype == np.float32
            return super().estimate(prev, curr, guess, frame_interval_s, prepared)

    steps = list(run_sequence(source, rig, estimator=Watching(rig)))
    assert prepared_ahead == [True, True]
    assert [s.status for s in steps] == [FIRST_FRAME, "ok", "ok", "ok"]
    assert len(preparing_threads) == 1
    assert next(iter(preparing_threads)).startswith("vipm-read-ahead")


def test_a_source_failing_mid_run_raises_after_the_steps_before_it(
        cart_sequence: Path, two_threads) -> None:
    inner, rig = _cart(cart_sequence, 4)
    steps = []
    with pytest.raises(InputError, match="frame 3 is corrupt"):
        for step in run_sequence(_WatchedSource(inner, fail_at=3), rig):
            steps.append(step)
    assert [s.status for s in steps] == [FIRST_FRAME, "ok", "ok"]


def test_a_run_stopped_early_leaves_no_reading_thread(cart_sequence: Path, two_threads) -> None:
    inner, rig = _cart(cart_sequence, 5)
    source = _WatchedSource(inner)
    steps = run_sequence(source, rig)
    assert next(steps).status == FIRST_FRAME
    assert next(steps).ok
    steps.close()  # as a Ctrl-C in the consumer does
    assert not [t for t in threading.enumerate() if t.name.startswith("vipm-read-ahead")]
    read = list(source.read)
    assert read in ([0, 1, 2], [0, 1, 2, 3])  # at most the frame in the making, then no more
    time.sleep(0.2)
    assert source.read == read


def test_a_failed_preparation_ahead_leaves_the_pair_to_the_estimator(
        cart_sequence: Path, two_threads) -> None:
    """Preparing ahead is an optimisation: where it raises, the estimator prepares the pair
    itself (as without read-ahead) and reports what it meets there."""
    from vipm_track.estimator import TwoFrameEstimator

    inner, rig = _cart(cart_sequence, 3)

    class Failing(TwoFrameEstimator):
        def prepare_pair(self, prev, curr):
            if threading.current_thread().name.startswith("vipm-read-ahead"):
                raise RuntimeError("out of memory on the read-ahead thread")
            return super().prepare_pair(prev, curr)

    steps = list(run_sequence(_WatchedSource(inner), rig, estimator=Failing(rig)))
    assert [s.status for s in steps] == [FIRST_FRAME, "ok", "ok"]


@pytest.mark.parametrize("odd", [4, 5])
def test_first_frames_of_another_size_fail_the_run_only_where_five_do(tmp_path, odd):
    """One odd first frame was taken for a wrong camera (InputError, nothing written). The
    first frames of another size are now held back: four are frames of the wrong size and
    the run goes on; five are a wrong camera, raised before any row is yielded."""
    from conftest import render_small_drive

    from vipm_track.camera import load_camera
    from vipm_track.rig import Rig
    from vipm_track.sources import open_source

    folder = render_small_drive(tmp_path / "d", frames=8)
    for k in range(odd):
        path = folder / "images" / f"{k:06d}.png"
        cv2.imwrite(str(path), cv2.resize(cv2.imread(str(path)), (320, 240)))
    source = open_source(images=folder / "images")
    rig = Rig(load_camera(folder / "camera.yaml"), 0.7, 45.0)
    steps = run_sequence(source, rig)
    if odd == 5:
        with pytest.raises(InputError, match=r"image is 320×240 px but the camera model is "
                                             r"400×300"):
            next(steps)
        return
    statuses = [s.status for s in steps]
    assert all(s.startswith("wrong image size 320×240") for s in statuses[:4])
    assert statuses[4] == "first frame" and statuses[5:] == ["ok"] * 3


def test_estimates_in_other_units_are_named(tmp_path: Path) -> None:
    """A table in nanoseconds or millimetres (one converted by hand) went through: speeds of
    1e-9 or 1,200 m/s, a 1e300 m travel wrecking the filters' sums. The reader names them."""
    from vipm_track.measurement import measurement_row
    from vipm_track.table import ESTIMATE_COLUMNS, write_table

    rng = np.random.default_rng(3)
    t = np.arange(20) * 0.1
    ms = [PairMeasurement(k, t[k], np.r_[rng.normal(0, 0.01, 4), 0.01, 0.5, 0.001],
                          np.eye(7) * 1e-6, 1.5) for k in range(1, 20)]
    rows = [measurement_row(m) for m in ms]

    def read(edit) -> list[PairMeasurement]:
        path = tmp_path / "est.csv"
        write_table(path, [edit(dict(r), i) for i, r in enumerate(rows)], ESTIMATE_COLUMNS)
        return read_measurements(path)

    assert len(read(lambda r, i: r)) == 19  # 5 m/s, 0.1 s apart: fine
    with pytest.raises(InputError, match=r"consecutive frames are 1e\+08 s apart .*seconds"):
        read(lambda r, i: {**r, "t": r["t"] * 1e9})
    with pytest.raises(InputError, match=r"travel 500.1 m per frame 0.1 s apart, 5001 m/s"):
        read(lambda r, i: {**r, "tz_m": r["tz_m"] * 1000, "tx_m": r["tx_m"] * 1000})
    with pytest.raises(InputError, match=r"row 7 \(frame 6\): tz_m = 1e\+300 is not a travel"):
        read(lambda r, i: {**r, "tz_m": 1e300} if i == 5 else r)
    # one fast row among slow ones is not a unit: only medians decide
    assert len(read(lambda r, i: {**r, "tz_m": 500.0} if i == 5 else r)) == 19
