"""CAN wheel speed: DBC decoding against cantools and the comma2k19 references, bad-data
accounting, streaming (virtual bus) = batch decoding, time alignment, CSV and CLI."""

from __future__ import annotations

import argparse
import signal
import uuid
from pathlib import Path

import can
import cantools
import numpy as np
import pytest

from tests.conftest import shared_data
from vipm_track.cli import main
from vipm_track.commands.common import add_speed_options
from vipm_track.commands.inputs import speed_from_args
from vipm_track.errors import InputError
from vipm_track.filters.can_decode import DbcError, MessageDecoder, parse_signal_specs, unit_factor
from vipm_track.filters.speed_decoder import SpeedDecoder, decode_bus, decode_can_log
from vipm_track.filters.wheel_speed import (
    SpeedSeries,
    align_to_frames,
    fit_speed_scale,
    read_speed_csv,
    write_speed_csv,
)

WHEELS = ("FL", "FR", "RL", "RR")
ALL_WHEELS = ",".join(f"WHEEL_SPEEDS.WHEEL_SPEED_{w}" for w in WHEELS)
KMH = 1 / 3.6


@pytest.fixture(scope="module")
def data():
    return shared_data("comma2k19_can")


@pytest.fixture(scope="module")
def dbc(data):
    return cantools.database.load_file(str(data / "toyota_2017.dbc"), strict=False)


@pytest.fixture(scope="module")
def messages(data):
    """The real log's 98,800 frames (candump), read once."""
    return list(can.LogReader(str(data / "rav4_drive.log")))


@pytest.fixture(scope="module")
def ref_wheels(data):
    return np.genfromtxt(data / "reference_wheel_speeds.csv", delimiter=",", names=True)


@pytest.fixture(scope="module")
def ref_gnss(data):
    return np.genfromtxt(data / "reference_speed.csv", delimiter=",", names=True)


# -- decoding against references ----------------------------------------------------------------

def test_three_formats_decode_identically(data, dbc):
    out = {}
    for suffix in ("log", "asc", "blf"):
        series, summary = decode_can_log(data / f"rav4_drive.{suffix}", dbc, ALL_WHEELS,
                                         combine="max")
        out[suffix] = (series, summary)
    ref_series, ref_summary = out["log"]
    assert ref_summary.frames == 98_800 and len(ref_series) == 4974
    for suffix in ("asc", "blf"):
        series, summary = out[suffix]
        np.testing.assert_array_equal(series.speed_mps, ref_series.speed_mps)
        # Each format has its own time base (module doc): equal counted from the first frame.
        np.testing.assert_allclose(series.t - summary.t_first, ref_series.t - ref_summary.t_first,
                                   atol=2e-6)
        for name in ("frames", "used", "samples", "other_ids", "unknown_ids", "bad"):
            assert getattr(summary, name) == getattr(ref_summary, name), (suffix, name)
        # the file says "1" and "2", python-can 0 and 1: the summary says which --can-channel
        # takes (the file's "1" picked its other bus)
        line = next(x for x in summary.lines() if "channels:" in x)
        assert "0=53800, 1=45000 (as python-can numbers them, from 0: the file's channel 1 is 0" \
            in line, line
    assert ref_summary.bad == 0
    assert not any("python-can numbers" in x for x in ref_summary.lines())  # can0, can1


def test_matches_reference_wheel_speeds(dbc, messages, ref_wheels):
    for wheel in WHEELS:
        decoder = SpeedDecoder(dbc, f"WHEEL_SPEEDS.WHEEL_SPEED_{wheel}")
        series = decoder.feed_many(messages)
        np.testing.assert_array_equal(series.t, ref_wheels["t"])
        diff_kmh = np.abs(series.speed_mps - ref_wheels[f"{wheel.lower()}_mps"]) * 3.6
        assert diff_kmh.max() <= 0.01, wheel


def test_default_is_rear_wheel_mean_and_tracks_gnss(dbc, messages, ref_wheels, ref_gnss):
    series = SpeedDecoder(dbc).feed_many(messages)
    assert series.signals == ("WHEEL_SPEEDS.WHEEL_SPEED_RL", "WHEEL_SPEEDS.WHEEL_SPEED_RR")
    np.testing.assert_allclose(series.speed_mps, (ref_wheels["rl_mps"] + ref_wheels["rr_mps"]) / 2,
                               atol=0.01 * KMH)
    t, gnss = ref_gnss["t"], ref_gnss["gnss_ins_speed_mps"]
    raw = align_to_frames(series, t)
    assert raw.valid.sum() == t.size - 1  # the first camera frame precedes the first CAN frame
    # Unscaled, the wheels read ~1 % below GNSS (tyre radius): within 0.2 m/s at 8-20 m/s.
    assert np.nanmedian(np.abs(raw.speed_mps - gnss)) <= 0.2
    # Tyre scale fitted on the first half, checked on the second.
    half = t.size // 2
    scale = fit_speed_scale(series, t[:half], gnss[:half])
    assert 1.0 < scale < 1.02
    fixed = align_to_frames(series.scaled(scale), t[half:])
    assert np.nanmedian(np.abs(fixed.speed_mps - gnss[half:])) <= 0.1


# -- the vectorised bit decoder -----------------------------------------------------------------

def test_bit_decoder_matches_cantools_on_every_dbc_signal(dbc):
    rng = np.random.default_rng(3)
    checked = 0
    for msg in dbc.messages:
        if msg.length > 8 or msg.is_multiplexed() or msg.name == "PCS_HUD":
            continue  # cantools cannot unpack PCS_HUD's overlapping signals (non-strict DBC)
        names = [s.name for s in msg.signals if not s.is_float]
        if not names:
            continue
        dec = MessageDecoder(msg, names)
        assert dec.vectorised
        payloads = rng.integers(0, 256, size=(20, msg.length), dtype=np.uint8)
        values, ok = dec.decode(payloads)
        for row, got, good in zip(payloads, values, ok, strict=True):
            want = msg.decode(bytes(row), decode_choices=False, scaling=True)
            np.testing.assert_allclose(got, [want[n] for n in names], rtol=1e-12, atol=1e-9)
            one = dec.decode_one(bytes(row))  # the scalar twin used by live buses
            assert (one is not None) == good
            if good:
                np.testing.assert_array_equal(one, got)
        checked += len(names)
    assert checked > 250  # big- and little-endian, signed and unsigned signals all covered


# -- bad data -------------------------------------------------------------------------------------

def _frame(t, arb_id, data, channel="can0", **kw):
    return can.Message(timestamp=t, arbitration_id=arb_id, data=bytes(data), channel=channel,
                       is_extended_id=False, **kw)


def test_bad_frames_are_counted_and_never_used(dbc, messages):
    wheel = [m for m in messages if m.arbitration_id == 0xAA][:50]
    clean = SpeedDecoder(dbc).feed_many(wheel)
    t_mid = wheel[10].timestamp
    junk = [
        _frame(t_mid + 1e-4, 0xAA, wheel[10].data[:6]),                  # shorter than the DBC
        _frame(t_mid + 2e-4, 0x7FF, b"\x00" * 8),                          # id not in the DBC
        _frame(t_mid + 3e-4, 0xAA, b"\xff" * 8, is_error_frame=True),      # error frame
        _frame(t_mid - 0.5, 0xAA, b"\x7f\xff" * 4),                        # time goes back
        _frame(t_mid + 4e-4, 0xAA, b"\x7f\xff" * 4, channel="can1"),       # filtered channel
        _frame(t_mid + 5e-4, 0xB4, b"\x00" * 8),                           # other DBC id
    ]
    dirty = wheel[:11] + junk + wheel[11:]
    decoder = SpeedDecoder(dbc, channel="can0")
    series = decoder.feed_many(dirty)
    np.testing.assert_array_equal(series.speed_mps, clean.speed_mps)
    np.testing.assert_array_equal(series.t, clean.t)
    s = decoder.summary
    assert (s.length_mismatch, s.unknown_ids, s.error_frames, s.non_monotonic,
            s.other_channel, s.other_ids) == (1, 1, 1, 1, 1, 1)
    assert s.unknown_id_set == {0x7FF} and s.bad == 3
    text = str(s)
    assert "length other than the DBC" in text and "0x7FF" in text


def test_out_of_range_values_are_decode_errors(dbc):
    # SPEED.SPEED states [0|250] km/h: raw 0xFFFF -> 655.35 km/h is out of range.
    frames = [_frame(0.01 * i, 0xB4, [0, 0, 0, 0, 0, 0x03, 0xE8, 0]) for i in range(5)]
    frames[2] = _frame(0.02, 0xB4, [0, 0, 0, 0, 0, 0xFF, 0xFF, 0])
    decoder = SpeedDecoder(dbc, "SPEED.SPEED")
    series = decoder.feed_many(frames)
    assert decoder.summary.decode_errors == 1 and len(series) == 4
    np.testing.assert_allclose(series.speed_mps, 10.0 * KMH)


def test_unreadable_candump_line_is_skipped(data, tmp_path):
    lines = (data / "rav4_drive.log").read_text().splitlines()[:2000]
    bad = tmp_path / "bad.log"
    bad.write_text("\n".join([*lines[:700], "(garbage) not a frame", *lines[700:]]) + "\n")
    series, summary = decode_can_log(bad, data / "toyota_2017.dbc")
    full, _ = decode_can_log(data / "rav4_drive.log", data / "toyota_2017.dbc")
    assert summary.frames == 2000 and summary.bad_lines == 1 and not summary.read_errors
    assert f"{bad}:701: " in str(summary)
    np.testing.assert_array_equal(series.speed_mps, full.speed_mps[: len(series)])


# -- streaming / live buses ---------------------------------------------------------------------

def test_feed_equals_feed_many_across_messages(dbc, messages):
    part = messages[:20000]
    for spec, rule in (("WHEEL_SPEEDS.WHEEL_SPEED_RL,SPEED.SPEED", "median"),
                       (ALL_WHEELS, "mean")):
        batch = SpeedDecoder(dbc, spec, combine=rule).feed_many(part)
        stream = SpeedDecoder(dbc, spec, combine=rule)
        samples = [s for s in (stream.feed(m) for m in part) if s is not None]
        t, v = np.array(samples).T
        np.testing.assert_array_equal(t, batch.t)
        np.testing.assert_allclose(v, batch.speed_mps, rtol=1e-12)
        np.testing.assert_array_equal(stream.series().t, t)
        assert np.all(np.diff(batch.t) > 0) and len(batch) > 1000
        mixed = SpeedDecoder(dbc, spec, combine=rule)  # feed() then feed_many() share state
        for m in part[:7000]:
            mixed.feed(m)
        mixed.feed_many(part[7000:])
        np.testing.assert_array_equal(mixed.series().t, batch.t)
        np.testing.assert_allclose(mixed.series().speed_mps, batch.speed_mps, rtol=1e-12)


def _over_a_virtual_bus(data, part, on_sample):
    """``decode_bus`` of the messages ``part`` sent on a fresh virtual bus."""
    channel = f"vipm-{uuid.uuid4().hex}"
    with can.Bus(interface="virtual", channel=channel, preserve_timestamps=True) as tx, \
            can.Bus(interface="virtual", channel=channel) as rx:
        for msg in part:
            tx.send(msg)
        return decode_bus(rx, data / "toyota_2017.dbc", channel=channel,
                          max_messages=len(part), idle_timeout=0.5, on_sample=on_sample)


def test_virtual_bus_streams_speed_to_frame_times(data, messages, ref_wheels, ref_gnss):
    part = [m for m in messages if m.timestamp < messages[0].timestamp + 3.0]
    received: list[tuple[float, float]] = []
    series, summary = _over_a_virtual_bus(data, part, lambda t, v: received.append((t, v)))
    assert summary.frames == len(part) and summary.bad == 0
    assert len(received) == len(series) > 200
    n = len(series)
    np.testing.assert_array_equal(series.t, ref_wheels["t"][:n])
    want = (ref_wheels["rl_mps"][:n] + ref_wheels["rr_mps"][:n]) / 2
    np.testing.assert_allclose(series.speed_mps, want, atol=0.01 * KMH)
    frames = ref_gnss["t"][ref_gnss["t"] < series.t[-1]]
    aligned = align_to_frames(series, frames)
    assert aligned.valid[1:].all() and not aligned.valid[0]
    gnss = ref_gnss["gnss_ins_speed_mps"][1:frames.size]
    assert np.median(np.abs(aligned.speed_mps[1:] - gnss)) < 0.2


def test_an_interrupted_bus_keeps_what_it_decoded(data, messages):
    """Ctrl-C while listening to a bus threw every decoded sample away (``can-speed --bus``
    wrote nothing); like a log's, they are kept and the interrupt is said."""
    part = [m for m in messages if m.timestamp < messages[0].timestamp + 2.0]

    def interrupt_at_100(t, v):
        if len(received) == 100:
            raise KeyboardInterrupt
        received.append((t, v))

    received: list[tuple[float, float]] = []
    try:
        series, summary = _over_a_virtual_bus(data, part, interrupt_at_100)
    except KeyboardInterrupt:
        pytest.fail("the interrupt went on with the 100 decoded samples")
    assert summary.interrupted and len(series) == 101 and len(received) == 100


class _InterruptedRead(can.Message):
    """A frame whose payload read delivers a Ctrl-C: the interrupt lands after next(), in the
    loop's body, where ``can-speed`` lost every frame read before it."""

    armed = False

    @property
    def data(self):
        if self.armed:
            self.armed = False  # once: the message's own checks read it too
            signal.raise_signal(signal.SIGINT)
        return self._data

    @data.setter
    def data(self, value):
        self._data = value


def test_deferred_interrupts_note_ctrl_c_and_leave_an_ignored_one_ignored():
    """A worker process ignores Ctrl-C (the whole group gets it): reading a CAN log there
    must not start taking it."""
    import os

    from vipm_track.errors import interrupts_deferred

    before = signal.getsignal(signal.SIGINT)
    try:
        with interrupts_deferred() as flag:
            os.kill(os.getpid(), signal.SIGINT)
        assert flag.requested and signal.getsignal(signal.SIGINT) is before
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        with interrupts_deferred() as flag:
            os.kill(os.getpid(), signal.SIGINT)
        assert not flag.requested and signal.getsignal(signal.SIGINT) is signal.SIG_IGN
    finally:
        signal.signal(signal.SIGINT, before)


def test_an_interrupt_during_the_decode_is_not_lost(dbc, messages, monkeypatch):
    """Ctrl-C while the read frames were decoded was noted and then dropped: the command
    wrote every sample and exited 0 as if it had not come."""
    original = SpeedDecoder._process

    def interrupted(self, batches):
        signal.raise_signal(signal.SIGINT)
        return original(self, batches)

    monkeypatch.setattr(SpeedDecoder, "_process", interrupted)
    decoder = SpeedDecoder(dbc)
    series = decoder.feed_many(messages[:5000])
    assert decoder.summary.interrupted and len(series) > 100


@pytest.mark.parametrize("at", [5000, 15000])
def test_an_interrupt_between_reads_keeps_what_was_read(dbc, messages, at):
    part = list(messages[:20000])
    wanted = next(i for i, m in enumerate(part) if m.arbitration_id == 0xAA and i >= at)
    m = part[wanted]
    part[wanted] = _InterruptedRead(timestamp=m.timestamp, arbitration_id=m.arbitration_id,
                                    data=m.data, channel=m.channel, is_extended_id=False)
    part[wanted].armed = True
    whole = SpeedDecoder(dbc).feed_many(messages[:20000])
    decoder = SpeedDecoder(dbc)
    try:
        series = decoder.feed_many(part)
    except KeyboardInterrupt:
        pytest.fail("the interrupt went on with every frame read before it")
    assert decoder.summary.interrupted and decoder.summary.frames == wanted + 1
    kept = whole.t <= m.timestamp
    assert 0.2 * at / 20000 * len(whole) < len(series) == kept.sum()
    np.testing.assert_array_equal(series.t, whole.t[kept])
    np.testing.assert_array_equal(series.speed_mps, whole.speed_mps[kept])


def test_virtual_bus_speed_streams_into_the_ekf_and_makes_height_observable(dbc):
    """A simulated drive's wheel speed, encoded as the DBC's WHEEL_SPEEDS frames, goes over a
    virtual bus; each camera frame steps the EKF with its pair measurement and the latest
    speed decoded off the bus. The true height is 2 % above the nominal one: the metric speed
    pulls the filter to it, while without speed the height stays at the nominal."""
    from vipm_track.filters.drive_sim import DriveConfig, simulate_drive
    from vipm_track.filters.ekf import ExtrinsicsEKF
    from vipm_track.filters.ekf_state import EkfConfig

    cfg = DriveConfig.preset("car", duration_s=20.0, height_m=1.53, height_assumed_m=1.5)
    run = simulate_drive(cfg, seed=2)
    spec = dbc.get_message_by_name("WHEEL_SPEEDS")
    frames = [
        can.Message(timestamp=float(t), arbitration_id=spec.frame_id, is_extended_id=False,
                    data=spec.encode({**{f"WHEEL_SPEED_{w}": v * 3.6 for w in WHEELS},
                                      **{f"WHEEL_SPEED_{w}_FAULT": 0 for w in WHEELS}}))
        for t, v in zip(run.speed.t, run.speed.speed_mps, strict=True)
    ]
    decoder = SpeedDecoder(dbc)  # default: mean of the rear wheels
    ekf = ExtrinsicsEKF(EkfConfig(height_m=cfg.h0, noise=cfg.noise))
    blind = ExtrinsicsEKF(EkfConfig(height_m=cfg.h0, noise=cfg.noise))
    channel = f"vipm-{uuid.uuid4().hex}"
    states, blind_states, latest, sent = [], [], None, 0
    with can.Bus(interface="virtual", channel=channel, preserve_timestamps=True) as tx, \
            can.Bus(interface="virtual", channel=channel) as rx:
        for m in run.measurements:
            while sent < len(frames) and frames[sent].timestamp <= m.t:
                tx.send(frames[sent])
                sent += 1
            while (msg := rx.recv(timeout=0.0)) is not None:
                latest = decoder.feed(msg) or latest
            speed = latest[1] if latest is not None and m.t - latest[0] < 0.1 else None
            states.append(ekf.step(m, speed=speed))
            blind_states.append(blind.step(m))
    assert decoder.summary.used == sent == len(frames) and decoder.summary.bad == 0
    np.testing.assert_allclose(decoder.series().speed_mps, run.speed.speed_mps[:sent],
                               atol=0.006 * KMH)
    t = run.truth.t
    late = t > 10.0
    h = np.array([s.mount[2] for s in states])
    h_blind = np.array([s.mount[2] for s in blind_states])
    assert np.all(np.abs(h[late] / run.truth.mount_height[late] - 1.0) < 0.01)
    assert np.all(np.abs(h_blind[late] / run.truth.mount_height[late] - 1.0) > 0.015)
    pitch = np.array([s.mount[0] for s in states])
    err = np.degrees(pitch[late] - run.truth.mount_pitch[late])
    assert np.sqrt(np.mean(err**2)) < 0.1


# -- alignment ------------------------------------------------------------------------------------

def test_align_interpolates_and_reports_gaps():
    t = np.r_[np.arange(0.0, 5.0, 0.01), np.arange(6.0, 10.0, 0.01)]  # 1 s gap at 5..6 s
    series = SpeedSeries(t, 3.0 + 0.5 * t, source="synthetic")
    frames = np.arange(-1.0, 12.0, 0.05) + 100.0
    aligned = align_to_frames(series, frames, clock_offset=100.0, max_gap=0.2)
    inside = (frames >= 100.0) & (frames <= 100.0 + t[-1])
    in_gap = (frames > 100.0 + t[499]) & (frames < 106.0)
    np.testing.assert_array_equal(aligned.valid, inside & ~in_gap)
    np.testing.assert_allclose(aligned.speed_mps[aligned.valid],
                               3.0 + 0.5 * (frames[aligned.valid] - 100.0), atol=1e-9)
    np.testing.assert_allclose(aligned.gaps, [[104.99, 106.0]], atol=1e-9)
    assert aligned.n_before == 20 and aligned.n_after > 0
    assert any("speed gap" in line for line in aligned.lines())


def test_clocks_that_do_not_overlap_are_a_clear_error():
    series = SpeedSeries(np.arange(0.0, 60.0, 0.01), np.full(6000, 8.0), source="rav4.asc")
    with pytest.raises(InputError, match=r"rav4.asc.*do not overlap.*--clock-offset"):
        align_to_frames(series, np.arange(46408.5, 46468.5, 0.05))
    ok = align_to_frames(series, np.arange(46408.5, 46468.5, 0.05), clock_offset=46408.58)
    assert ok.valid.mean() > 0.95


# -- units, specs, files, CLI ---------------------------------------------------------------------

def test_units_and_signal_specs(dbc):
    assert unit_factor("km/h", "x") == pytest.approx(1 / 3.6)
    assert unit_factor("MPH", "x") == pytest.approx(0.44704)
    assert unit_factor("m/s", "x") == 1.0
    with pytest.raises(DbcError, match=r"GEAR.*unit 'rpm'.*MSG.SIG:UNIT"):
        unit_factor("rpm", "GEAR")
    with pytest.raises(DbcError, match=r"ENCODER.*unit ''"):
        parse_signal_specs(dbc, "SPEED.ENCODER")
    spec = parse_signal_specs(dbc, "SPEED.ENCODER:m/s")[0]
    assert spec.to_mps == 1.0 and spec.name == "SPEED.ENCODER"
    with pytest.raises(DbcError, match="no message 'WHEELSPEED'"):
        parse_signal_specs(dbc, "WHEELSPEED.RL")
    with pytest.raises(DbcError, match=r"MESSAGE\.SIGNAL"):
        parse_signal_specs(dbc, "WHEEL_SPEEDS")


def test_no_rear_wheels_in_dbc_needs_signals(tmp_path):
    path = tmp_path / "tiny.dbc"
    path.write_text('VERSION ""\n\nBU_: X\n\nBO_ 100 SPD: 2 X\n'
                    ' SG_ VEHICLE_SPEED : 7|16@0+ (0.01,0) [0|300] "km/h" X\n')
    with pytest.raises(DbcError, match=r"no message with rear wheel speeds.*--signals"):
        SpeedDecoder(path)
    dec = SpeedDecoder(path, "SPD.VEHICLE_SPEED")
    assert dec.feed(_frame(1.0, 100, [0x03, 0xE8])) == (1.0, pytest.approx(10 * KMH))


def test_speed_csv_roundtrip_and_bad_rows(tmp_path):
    # written at 15 significant digits like every table (6 decimals lost a Unix time's µs
    # remainder and a slow speed's fourth digit)
    series = SpeedSeries(np.array([1.7e9 + 0.1234567, 1.7e9 + 1.0, 1.7e9 + 1.5]),
                         np.array([0.012345678901, 2.5, 3.25]))
    path = write_speed_csv(series, tmp_path / "s.csv")
    back = read_speed_csv(path)
    np.testing.assert_allclose(back.t, series.t, rtol=0, atol=1e-9)
    np.testing.assert_allclose(back.speed_mps, series.speed_mps, rtol=1e-14)
    assert not list(tmp_path.glob("*.partial"))
    path.write_text("t,speed_mps\n0.1,1\n0.2,oops\n0.3,2\n0.25,5\n0.4,nan\n0.45,1e9\n"
                    "0.5,3\n")
    back = read_speed_csv(path)
    np.testing.assert_allclose(back.t, [0.1, 0.3, 0.5])
    assert back.summary.bad_rows == 3 and back.summary.non_monotonic == 1
    assert any("1e+09 m/s is no ground vehicle's" in line for line in back.summary.examples)
    text = "\n".join(back.summary.lines())  # a CSV's rows, not a CAN log's frames
    assert "7 rows read" in text and "1 rows with a time out of order with the rows around" in text
    assert "frames" not in text
    (tmp_path / "w.csv").write_text("time,v\n1,2\n")
    with pytest.raises(InputError, match=r"w.csv.*speed_mps"):
        read_speed_csv(tmp_path / "w.csv")


def test_speed_from_args(data, tmp_path):
    parser = argparse.ArgumentParser()
    add_speed_options(parser)
    assert speed_from_args(parser.parse_args([])) is None
    with pytest.raises(InputError, match="needs --dbc"):
        speed_from_args(parser.parse_args(["--can", str(data / "rav4_drive.blf")]))
    lines: list[str] = []
    args = parser.parse_args(["--can", str(data / "rav4_drive.blf"), "--dbc",
                              str(data / "toyota_2017.dbc"), "--speed-scale", "1.01",
                              "--clock-offset", "46408.584", "--can-channel", "can0"])
    series = speed_from_args(args, progress=False, report=lines.append)
    ref = np.genfromtxt(data / "reference_wheel_speeds.csv", delimiter=",", names=True)
    np.testing.assert_allclose(series.t, ref["t"], atol=2e-6)
    np.testing.assert_allclose(series.speed_mps, 1.01 * (ref["rl_mps"] + ref["rr_mps"]) / 2,
                               atol=0.02 * KMH)
    assert "98800 frames read" in lines[0]
    csv_path = write_speed_csv(series, tmp_path / "s.csv")
    again = speed_from_args(parser.parse_args(["--speed-csv", str(csv_path),
                                               "--clock-offset", "1"]), report=lines.append)
    np.testing.assert_allclose(again.t, series.t + 1, atol=1e-6)


def test_cli_can_speed(data, tmp_path, capsys):
    out = tmp_path / "speed.csv"
    times = tmp_path / "times.txt"
    gnss = np.genfromtxt(data / "reference_speed.csv", delimiter=",", names=True)
    np.savetxt(times, gnss["t"], fmt="%.6f")
    rc = main(["can-speed", str(data / "rav4_drive.log"), "--dbc", str(data / "toyota_2017.dbc"),
               "--frame-times", str(times), "--out", str(out)])
    assert rc == 0
    got = read_speed_csv(out)
    assert len(got) == gnss.size - 1
    assert np.median(np.abs(got.speed_mps - gnss["gnss_ins_speed_mps"][1:])) <= 0.2
    err = capsys.readouterr().err
    assert "98800 frames read" in err and "1199 of 1200 frames" in err
    rc = main(["can-speed", str(data / "rav4_drive.log"), "--dbc", str(data / "toyota_2017.dbc"),
               "--signals", "SPEED.SPEDD", "--out", str(out)])
    assert rc == 2
    assert "message SPEED has no signal 'SPEDD'" in capsys.readouterr().err
    rc = main(["can-speed", str(tmp_path / "missing.log"), "--dbc",
               str(data / "toyota_2017.dbc"), "--out", str(out)])
    assert rc == 2 and "CAN log not found" in capsys.readouterr().err


@pytest.mark.parametrize("suffix", ["trc", "csv", "mf4"])
def test_other_python_can_formats(dbc, messages, tmp_path, suffix):
    part = messages[:3000]
    path = tmp_path / f"part.{suffix}"
    with can.Logger(str(path)) as writer:
        for m in part:
            writer.on_message_received(m)
    series, summary = decode_can_log(path, dbc)
    want = SpeedDecoder(dbc).feed_many(part)
    assert summary.frames == len(part) and summary.bad == 0
    np.testing.assert_allclose(series.speed_mps, want.speed_mps, atol=1e-12)
    np.testing.assert_allclose(np.diff(series.t), np.diff(want.t), atol=2e-4)
    if suffix == "trc":  # PCAN numbers buses from 1: the channel to give is no can0
        lines = "\n".join(summary.lines())
        assert "channels: 1=1626, 2=1374 (as the file numbers them, from 1" in lines


def test_an_mf4_without_asammdf_says_what_to_install(dbc, tmp_path, monkeypatch):
    """python-can raises NotImplementedError for a missing asammdf: it read 'cannot open as
    a CAN log' under a usage page that listed .mf4 as supported."""
    def no_asammdf(path, **kwargs):
        raise NotImplementedError("The asammdf package was not found. Install python-can "
                                  "with the optional dependency [mf4] to use the MF4Reader.")

    monkeypatch.setattr(can, "LogReader", no_asammdf)
    (tmp_path / "drive.mf4").write_bytes(b"MDF     4.10    ")
    with pytest.raises(InputError, match=r"drive.mf4: this log format needs an optional "
                       r"package \(the mf4 extra: pip install 'vipm-track\[mf4\]', or "
                       r"'.\[mf4\]' in a checkout\): The asammdf package"):
        decode_can_log(tmp_path / "drive.mf4", dbc)


@pytest.mark.parametrize("command", ["smooth", "track"])
def test_speed_scale_zero_is_refused(tmp_path, capsys, command):
    # `--speed-scale 0` was read as no scale (the speed used unscaled, exit 0)
    from vipm_track.cli import main

    data = Path(__file__).parent / "data"
    rc = main([command, "--estimates", str(data / "knock_cart_est.csv"), "--vehicle", "cart",
               "--speed-csv", str(data / "knock_cart_speed.csv"), "--speed-scale", "0",
               "--out", str(tmp_path / "out.csv")])
    assert rc == 2 and "--speed-scale 0.0 must be a positive number" in capsys.readouterr().err
