"""CAN frame times out of order: a lone stamp far ahead (or behind) of its id's other frames
is skipped and named, the rest of the log kept; a clock that steps back and goes on from
there keeps the log's first clock and is reported as a clock step, unless it is a 32-bit
microsecond clock wrapping around, which is unwrapped (filters.speed_decoder)."""

from __future__ import annotations

import math
import re
from pathlib import Path

import can
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from tests.conftest import shared_data
from vipm_track.cli import main
from vipm_track.filters.can_decode import load_dbc
from vipm_track.filters.speed_decoder import (
    LOOKAHEAD,
    WRAP_S,
    SpeedDecoder,
    _time_order,
    decode_can_log,
)
from vipm_track.filters.wheel_speed import read_speed_csv

FUZZ = settings(max_examples=30, deadline=None, derandomize=True,
                suppress_health_check=[HealthCheck.too_slow])
STAMP = re.compile(r"^\((\d+\.\d+)\)(.*)$")


@pytest.fixture(scope="module")
def data():
    return shared_data("comma2k19_can")


@pytest.fixture(scope="module")
def dbc(data):
    return load_dbc(data / "toyota_2017.dbc")


@pytest.fixture(scope="module")
def lines(data):
    """The first 20,000 lines of the real candump log (1006 rear-wheel samples)."""
    return (data / "rav4_drive.log").read_text().splitlines()[:20000]


@pytest.fixture(scope="module")
def clean(lines, dbc, tmp_path_factory):
    path = tmp_path_factory.mktemp("can") / "clean.log"
    path.write_text("\n".join(lines) + "\n")
    series, summary = decode_can_log(path, dbc)
    assert len(series) == 1006 and summary.bad == 0
    return series


def _wheel_line(lines: list[str], near: int) -> str:
    """The first WHEEL_SPEEDS (0AA) line at or after index ``near``."""
    return next(line for line in lines[near:] if " 0AA#" in line)


def _stamped(line: str, t: float) -> str:
    return STAMP.sub(lambda m: f"({t:.6f}){m[2]}", line)


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    """Where the tests write their logs (one folder: the fuzzed log is rewritten in place)."""
    return tmp_path_factory.mktemp("cantime")


def _write(folder: Path, lines: list[str], name: str) -> Path:
    path = folder / name
    path.write_text("\n".join(lines) + "\n")
    return path


def _shift(lines: list[str], start: int, dt: float) -> list[str]:
    """``lines`` with ``dt`` seconds added to the times from index ``start`` on."""
    return lines[:start] + [_stamped(x, float(STAMP.match(x)[1]) + dt) for x in lines[start:]]


# -- a lone stamp ---------------------------------------------------------------------------

def test_one_far_future_stamp_is_skipped_and_the_rest_kept(lines, dbc, clean, folder):
    k = 1209  # the user's trial: a valid 0AA frame stamped (99999.000000) inserted here
    bad = _write(folder, [*lines[:k], _stamped(_wheel_line(lines, k), 99999.0), *lines[k:]],
                 "t.log")
    series, summary = decode_can_log(bad, dbc)
    np.testing.assert_array_equal(series.t, clean.t)
    np.testing.assert_array_equal(series.speed_mps, clean.speed_mps)
    assert summary.non_monotonic == 1 and not summary.clock_steps
    text = str(summary)
    assert f"{bad}:{k + 1}: WHEEL_SPEEDS (0xAA) time 99999.000000 s jumps ahead" in text
    assert "an outlier, skipped" in text and "1 wanted frames with a time out of order" in text


def test_the_users_log_through_the_cli(lines, data, clean, tmp_path, capsys):
    k = 1209
    bad = [*lines[:1011], _stamped(_wheel_line(lines, 1011), 1.0), *lines[1011:k],
           _stamped(_wheel_line(lines, k), 99999.0), *lines[k:]]
    path = tmp_path / "can_time.log"
    path.write_text("\n".join(bad) + "\n")
    out = tmp_path / "sp.csv"
    rc = main(["can-speed", str(path), "--dbc", str(data / "toyota_2017.dbc"),
               "--out", str(out)])
    err = capsys.readouterr().err
    assert rc == 0
    got = read_speed_csv(out)
    assert len(got) == 1006 and got.t.max() < 99999
    np.testing.assert_allclose(got.t, clean.t, atol=1e-6)
    assert "2 wanted frames with a time out of order (skipped)" in err
    assert f"{path}:1012: WHEEL_SPEEDS (0xAA) time 1.000000 s is not after" in err
    assert f"{path}:1211: WHEEL_SPEEDS (0xAA) time 99999.000000 s jumps ahead" in err


@pytest.mark.parametrize("where", ["first", "burst", "last-but-one"])
def test_stamps_ahead_anywhere_in_the_log(lines, dbc, clean, folder, where):
    wheel = [i for i, x in enumerate(lines) if " 0AA#" in x]
    if where == "first":  # the id's first frame: nothing before it to compare with
        k, n = wheel[0], 1
    elif where == "burst":  # as many in a row as the look-ahead covers
        k, n = 5000, LOOKAHEAD
    else:
        k, n = wheel[-2], 1
    extra = [_stamped(_wheel_line(lines, k), 99999.0 + 0.01 * j) for j in range(n)]
    path = _write(folder, [*lines[:k], *extra, *lines[k:]], f"{where}.log")
    series, summary = decode_can_log(path, dbc)
    np.testing.assert_array_equal(series.t, clean.t)
    assert summary.non_monotonic == n and not summary.clock_steps


def test_a_longer_run_ahead_is_taken_as_the_clock(dbc):
    # LOOKAHEAD + 1 frames ahead, then the old clock: the run is kept, what follows it is
    # behind it and skipped as a clock step (the longer the run, the likelier it is real)
    frames = [_frame(0.01 * i) for i in range(50)]
    frames[20:20] = [_frame(100.0 + 0.01 * j) for j in range(LOOKAHEAD + 1)]
    decoder = SpeedDecoder(dbc)
    series = decoder.feed_many(frames)
    assert len(series) == 20 + LOOKAHEAD + 1 and decoder.summary.non_monotonic == 30
    assert len(decoder.summary.clock_steps) == 1


# -- the clock steps back -------------------------------------------------------------------

def test_a_clock_reset_keeps_the_log_before_it_and_says_where(lines, dbc, clean, folder):
    step = 10000
    path = _write(folder, _shift(lines, step, -100.0), "reset.log")
    series, summary = decode_can_log(path, dbc)
    before = clean.t < float(STAMP.match(lines[step])[1])
    np.testing.assert_array_equal(series.t, clean.t[before])
    np.testing.assert_array_equal(series.speed_mps, clean.speed_mps[before])
    first = next(i for i in range(step, len(lines)) if " 0AA#" in lines[i]) + 1
    assert summary.non_monotonic == int((~before).sum()) == 503
    (text,) = summary.clock_steps
    assert text.startswith(f"{path}:{first}: WHEEL_SPEEDS (0xAA) time steps back 99.97")
    assert "its 503 frames up to line" in text and "split the log here" in text
    assert f"clock step: {path}:{first}: " in str(summary)


def test_a_small_step_back_skips_until_the_old_clock_is_passed(lines, dbc, clean, folder):
    step, dt = 10000, -0.2
    path = _write(folder, _shift(lines, step, dt), "step.log")
    series, summary = decode_can_log(path, dbc)
    t_step = float(STAMP.match(lines[step])[1])
    t_run = clean.t[clean.t < t_step][-1]
    shifted = clean.t + np.where(clean.t >= t_step, dt, 0.0)
    keep = (clean.t < t_step) | (shifted > t_run)
    np.testing.assert_allclose(series.t, shifted[keep], atol=1e-9)
    np.testing.assert_array_equal(series.speed_mps, clean.speed_mps[keep])
    assert summary.non_monotonic == int((~keep).sum()) > LOOKAHEAD
    (text,) = summary.clock_steps
    assert "decoding goes on at line" in text and "passes the old clock again" in text


# -- the rule on its own --------------------------------------------------------------------

@pytest.mark.parametrize(("times", "kept", "kinds"), [
    ([1, 2, 3, 4], [1, 2, 3, 4], []),
    ([1, 2, 99, 3, 4], [1, 2, 3, 4], ["ahead"]),
    ([99, 1, 2, 3], [1, 2, 3], ["ahead"]),
    ([1, 2, 99, 98, 3, 4], [1, 2, 3, 4], ["ahead", "ahead"]),
    ([1, 2, -5, 3, 4], [1, 2, 3, 4], ["behind"]),
    ([1, 2, 99, -5, 3], [1, 2, 3], ["ahead", "behind"]),
    ([1, 2, math.nan, 3, math.inf, 4], [1, 2, 3, 4], ["nan", "nan"]),
    ([1, 2, 2, 3], [1, 2, 3], ["behind"]),
    # a few frames behind that go on in time: out of order one by one, not a clock step
    ([*range(10, 30), 1, 2, 3], list(range(10, 30)), ["behind"] * 3),
    # more than LOOKAHEAD of them, behind more than LOOKAHEAD kept frames: a clock step
    ([*range(10, 30), *range(1, 11)], list(range(10, 30)), ["step"]),
    ([*range(10, 30), *range(1, 11), 30], [*range(10, 31)], ["step"]),
])
def test_time_order(times, kept, kinds):
    t = np.array(times, dtype=float)
    keep, skips = _time_order(t)
    assert t[keep].tolist() == kept
    assert [s.kind for s in skips] == kinds
    assert keep.sum() + sum(s.count for s in skips) == t.size


def test_time_order_starts_from_the_running_time():
    keep, skips = _time_order(np.arange(1.0, 13.0), t_run=10.0)
    assert keep.sum() == 2 and keep[-2:].all()
    assert [(s.kind, s.count, s.t_run, s.resumed) for s in skips] == [("step", 10, 10.0, 10)]


def test_kept_frames_the_stream_comes_back_below_are_dropped_after_all():
    # LOOKAHEAD frames far ahead, each with a window mostly ahead too (so kept at first); the
    # stream then goes on below them for more than LOOKAHEAD frames: they were the outliers
    t = np.array([1, 2, 500, 501, 502, 503, 3, 504, 505, 506, 507, *range(4, 40)], dtype=float)
    keep, skips = _time_order(t)
    assert t[keep].tolist() == [1, 2, *range(3, 40)]
    assert [s.kind for s in skips] == ["ahead"] * LOOKAHEAD
    assert {s.last for s in skips} == {6} and {s.t_run for s in skips} == {2.0}


@settings(max_examples=200, deadline=None, derandomize=True)
@given(st.lists(st.one_of(st.floats(-1e6, 1e6), st.sampled_from([math.nan, math.inf])),
                max_size=60),
       st.floats(-1e6, 1e6) | st.just(-math.inf))
def test_time_order_keeps_a_strictly_increasing_part_and_accounts_for_the_rest(times, t_run):
    t = np.array(times, dtype=float)
    keep, skips = _time_order(t, t_run)
    kept = t[keep]
    assert np.all(np.diff(kept) > 0) and np.all(kept > t_run)
    # every frame is kept or left out once, with a reason
    assert keep.sum() + sum(s.count for s in skips) == t.size
    assert len({s.index for s in skips}) == len(skips)
    assert not any(keep[s.index] for s in skips)
    if np.all(np.isfinite(t)) and np.all(np.diff(t) > 0) and (t.size == 0 or t[0] > t_run):
        assert keep.all() and not skips


@settings(max_examples=200, deadline=None, derandomize=True)
@given(st.lists(st.floats(1e-3, 1.0), min_size=30, max_size=120),
       st.lists(st.tuples(st.integers(0, 10**6), st.sampled_from([-1.0, 1.0]),
                          st.floats(50.0, 1e5)), max_size=4),
       st.integers(1, LOOKAHEAD))
def test_far_outliers_apart_are_all_that_is_left_out(steps, outliers, burst):
    # an increasing stream; far off it (more than its span), a few lone stamps or a burst of
    # up to LOOKAHEAD, each at least 2 * LOOKAHEAD frames from the next and from the ends
    # (a stamp far behind the first frame, or ahead of the last, is in order)
    t = np.cumsum(steps)
    n_slots = (len(t) - 2 * LOOKAHEAD) // (3 * LOOKAHEAD)
    slots = sorted({1 + pos % n_slots for pos, _, _ in outliers if n_slots >= 1})
    bad: list[int] = []
    times = t.tolist()
    for k, slot in enumerate(slots):
        at = slot * 3 * LOOKAHEAD + len(bad)
        _, sign, far = outliers[k]
        n = burst if k == 0 and sign > 0 else 1
        times[at:at] = [t[-1] + far + j if sign > 0 else t[0] - far - j for j in range(n)]
        bad.extend(range(at, at + n))
    keep, skips = _time_order(np.array(times))
    assert sorted(np.flatnonzero(~keep).tolist()) == bad
    assert sorted(s.index for s in skips) == bad and {s.kind for s in skips} <= {"ahead", "behind"}


# -- one stamp anywhere, fuzzed -------------------------------------------------------------

def _frame(t: float, data: bytes = bytes([0x27, 0x3F, 0x27, 0x35, 0x27, 0x26, 0x27, 0x1D])):
    return can.Message(timestamp=t, arbitration_id=0xAA, data=data, channel="can0",
                       is_extended_id=False)


@pytest.fixture(scope="module")
def head(lines, dbc, folder):
    """The first 8,000 lines (about 400 WHEEL_SPEEDS frames) and their decoded speed."""
    head = lines[:8000]
    series, _ = decode_can_log(_write(folder, head, "head.log"), dbc)
    return head, series


@FUZZ
@given(position=st.integers(0, 400), stamp=st.one_of(
    st.floats(allow_nan=True, allow_infinity=True),
    st.floats(46408.0, 46414.0), st.sampled_from([0.0, 1.0, 99999.0, -1.0, 4.6e4])))
def test_one_bad_stamp_anywhere_in_a_log_loses_no_other_sample(head, dbc, folder, position,
                                                             stamp):
    head, want = head
    wheel = [i for i, x in enumerate(head) if " 0AA#" in x]
    p = min(position, len(wheel) - 1)
    k = wheel[p]
    times = [float(STAMP.match(head[i])[1]) for i in wheel]
    text = f"{stamp:.6f}" if math.isfinite(stamp) else str(stamp)
    stamp = float(text)
    if stamp in times:  # a copy of a real time takes that frame's place: not this test
        return
    bad = [*head[:k], STAMP.sub(lambda m: f"({text}){m[2]}", head[k]), *head[k:]]
    path = _write(folder, bad, "fuzz.log")
    series, summary = decode_can_log(path, dbc)
    got = dict(zip(series.t.tolist(), series.speed_mps.tolist(), strict=True))
    lost = [t for t, v in zip(want.t.tolist(), want.speed_mps.tolist(), strict=True)
            if got.get(t) != v]
    before = times[p - 1] if p else -math.inf
    assert not summary.clock_steps and summary.bad <= 1
    if before < stamp < times[p]:  # in order: a frame like any other
        assert not lost and len(series) == len(want) + 1 and summary.bad == 0
    elif times[max(p - 2, 0)] < stamp < times[min(p + 1, len(times) - 1)]:
        # one frame out of place (a swapped pair): the stamp or its neighbour is left out
        assert len(lost) <= 1 and len(series) == len(want) and summary.non_monotonic == 1
    else:  # out of line: skipped for its time (or, if candump cannot write it, a bad line)
        assert not lost and len(series) == len(want) and summary.bad == 1
        assert summary.non_monotonic + summary.bad_lines == 1
        assert f"{path}:{k + 1}: " in str(summary)


def test_feed_and_feed_many_agree_on_a_stamp_behind(dbc):
    frames = [_frame(0.01 * i) for i in range(40)]
    frames.insert(20, _frame(-3.0))
    batch = SpeedDecoder(dbc).feed_many(frames)
    stream = SpeedDecoder(dbc)
    for m in frames:
        stream.feed(m)
    np.testing.assert_array_equal(stream.series().t, batch.t)
    assert len(batch) == 40 and stream.summary.examples == batch.summary.examples == [
        "CAN: frame 20: WHEEL_SPEEDS (0xAA) time -3.000000 s is not after its frames before "
        "it (0.190000 s): out of order, skipped"]


# -- a 32-bit microsecond clock wrapping around ---------------------------------------------

def _wrapped(lines: list[str], at_s: float, step: float = WRAP_S) -> list[str]:
    """``lines`` on a 32-bit microsecond clock that reaches 2^32 µs ``at_s`` seconds in, and
    there steps back by ``step`` (a wrap-around: 2^32 µs)."""
    t0 = float(STAMP.match(lines[0])[1])
    out = []
    for line in lines:
        u = round((float(STAMP.match(line)[1]) - t0 + WRAP_S - at_s) * 1e6) * 1e-6
        out.append(_stamped(line, u - step if u >= WRAP_S else u))
    return out


def test_a_32_bit_microsecond_clock_wrapping_around_is_unwrapped(lines, data, clean, folder,
                                                                 capsys):
    """The user's log wraps 5 s in: 92 % of it was left out as after a clock step, exit 0,
    and its span printed as negative (-4234.975 s)."""
    path = _write(folder, _wrapped(lines, 5.0), "wrap.log")
    out = folder / "wrap.csv"
    rc = main(["can-speed", str(path), "--dbc", str(data / "toyota_2017.dbc"),
               "--out", str(out)])
    err = capsys.readouterr().err
    assert rc == 0
    got = read_speed_csv(out)
    assert len(got) == len(clean) == 1006
    np.testing.assert_allclose(got.t, clean.t - clean.t[0] + got.t[0], atol=2e-6)
    np.testing.assert_allclose(got.speed_mps, clean.speed_mps, atol=1e-9)
    assert "32-bit microsecond clock wrapping around" in err and "added to the times" in err
    assert "clock step" not in err and "(-" not in err
    span = re.search(r"time span \S+ \.\. \S+ s \((\S+) s\)", err)
    assert span and 11.0 < float(span[1]) < 13.0


def test_a_stream_unwraps_the_clock_as_a_log_does(lines, dbc, folder):
    path = _write(folder, _wrapped(lines, 5.0), "wrap_stream.log")
    batch, _ = decode_can_log(path, dbc)
    stream = SpeedDecoder(dbc)
    for msg in can.LogReader(str(path)):
        stream.feed(msg)
    np.testing.assert_array_equal(stream.series().t, batch.t)
    assert stream.summary.notes and "wrapping around" in stream.summary.notes[0]


def test_a_frame_stamped_before_the_wrap_logged_after_it_stays_before(dbc):
    times = [WRAP_S - 0.003, WRAP_S - 0.002, 0.0005, WRAP_S - 0.0015, 0.001, 0.002]
    series = SpeedDecoder(dbc).feed_many([_frame(round(t, 6)) for t in times])
    np.testing.assert_allclose(series.t, [WRAP_S - 0.003, WRAP_S - 0.002, WRAP_S + 0.0005,
                                          WRAP_S + 0.001, WRAP_S + 0.002], atol=1e-6)
    assert series.summary.non_monotonic == 1 and not series.summary.clock_steps


def test_a_wrap_across_a_quiet_bus_or_in_a_log_of_one_message_is_unwrapped(lines, dbc, clean,
                                                                           folder):
    """Only 5 ms between the frames across the wrap were taken for one: a log of the wheel
    speeds alone (12 ms apart) wrapping lost 58 % of them as after a clock reset, and so did a
    log whose bus was quiet for half a second there."""
    wheels = [line for line in _wrapped(lines, 5.0) if " 0AA#" in line]
    series, summary = decode_can_log(_write(folder, wheels, "wrap_wheels.log"), dbc)
    np.testing.assert_allclose(series.t - series.t[0], clean.t - clean.t[0], atol=2e-6)
    assert not summary.clock_steps and "wrapping around" in summary.notes[0]
    t = np.array([float(STAMP.match(line)[1]) for line in _wrapped(lines, 5.0)])
    quiet = [line for line, ti in zip(_wrapped(lines, 5.0), t, strict=True)
             if not WRAP_S - 0.3 < ti < WRAP_S and not 0 <= ti < 0.2]
    series, summary = decode_can_log(_write(folder, quiet, "wrap_quiet.log"), dbc)
    assert len(series) == len(clean) - 41 and not summary.clock_steps, summary.clock_steps
    assert re.search(r"wrapping around .* 50\d\.\d ms after the frame before", summary.notes[0])


def test_a_step_back_near_a_wrap_but_not_one_is_left_out_and_counted(lines, dbc, folder):
    """30 s short of 2^32 µs: no wrap-around, a clock step, whose frames are left out saying
    how many of the log's they are; the span never printed negative."""
    path = _write(folder, _wrapped(lines, 5.0, WRAP_S - 30.0), "near_wrap.log")
    series, summary = decode_can_log(path, dbc)
    assert 380 < len(series) < 450 and not summary.notes
    (text,) = summary.clock_steps
    n = summary.non_monotonic
    assert n == 1006 - len(series)
    assert f"its {n} frames up to line" in text and f"({round(100 * n / 1006)} % of its 1006 " \
        "frames)" in text
    assert f"the speed samples of all {n} are left out" in text and "not unwrapped" in text
    report = str(summary)
    assert "(-" not in report and "the clock steps back in between" in report
