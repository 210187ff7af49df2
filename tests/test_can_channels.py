"""The speed message on several channels: copies that agree (a gateway mirroring the bus) are
decoded from one channel, said in the summary; copies that differ are refused, naming the
message and its channels, until ``--can-channel`` chooses one (filters.speed_decoder)."""

from __future__ import annotations

import io
import itertools
from pathlib import Path

import can
import numpy as np
import pytest

from tests.conftest import shared_data
from vipm_track.cli import main
from vipm_track.errors import InputError
from vipm_track.filters.can_decode import load_dbc
from vipm_track.filters.speed_decoder import MIRROR_WINDOW_S, SpeedDecoder, decode_can_log
from vipm_track.filters.wheel_speed import read_speed_csv

WHEEL_ID, SPEED_ID = 0xAA, 0xB4
DELAY_S = 0.0002  # the copy's lag behind the original (a gateway's)


@pytest.fixture(scope="module")
def data():
    return shared_data("comma2k19_can")


@pytest.fixture(scope="module")
def dbc(data):
    return load_dbc(data / "toyota_2017.dbc")


@pytest.fixture(scope="module")
def head(data):
    """The real log's frames of its first 8,000 lines (about 400 WHEEL_SPEEDS frames), all
    on can0 (channel 0 in a Vector log) with their candump channel names dropped."""
    with open(data / "rav4_drive.log") as fh:
        text = "".join(itertools.islice(fh, 8000))
    return list(can.CanutilsLogReader(io.StringIO(text)))


@pytest.fixture(scope="module")
def zero_kmh(dbc):
    """A WHEEL_SPEEDS payload of 0 km/h on every wheel."""
    msg = dbc.get_message_by_frame_id(WHEEL_ID)
    return bytes(msg.encode({s.name: 0.0 for s in msg.signals}))


def _on(msg: can.Message, channel: str | int | None, dt: float = 0.0,
        data: bytes | None = None) -> can.Message:
    return can.Message(timestamp=msg.timestamp + dt, arbitration_id=msg.arbitration_id,
                       data=msg.data if data is None else data, channel=channel,
                       is_extended_id=msg.is_extended_id, dlc=msg.dlc)


def _with_copies(frames: list[can.Message], suffix: str, ids: tuple[int, ...] = (WHEEL_ID,),
                 payload: bytes | None = None, every: int = 1,
                 delay: float = DELAY_S) -> list[can.Message]:
    """``frames`` on the first channel and, ``delay`` [s] after each ``every``-th frame of
    ``ids``, a copy on the second (with ``payload``, else the same), in time order."""
    main_ch, copy_ch = ("can0", "can1") if suffix == "log" else (0, 1)
    out: list[can.Message] = []
    n = 0
    for m in frames:
        out.append(_on(m, main_ch))
        if m.arbitration_id in ids:
            if n % every == 0:
                out.append(_on(m, copy_ch, delay, payload))
            n += 1
    return sorted(out, key=lambda m: m.timestamp)


def _write(path: Path, frames: list[can.Message]) -> Path:
    with can.Logger(str(path)) as log:
        for m in frames:
            log.on_message_received(m)
    return path


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    return tmp_path_factory.mktemp("canch")


@pytest.fixture(scope="module", params=["log", "asc"])
def suffix(request):
    return request.param


@pytest.fixture(scope="module")
def clean(head, dbc, folder, suffix):
    """The slice alone, decoded."""
    series, summary = decode_can_log(_write(folder / f"clean.{suffix}",
                                            [_on(m, "can0" if suffix == "log" else 0)
                                             for m in head]), dbc)
    assert len(series) > 350 and summary.bad == 0
    return series


@pytest.fixture(scope="module")
def reference(head, dbc):
    """The slice alone, decoded in memory (the times of the candump log)."""
    return SpeedDecoder(dbc).feed_many([_on(m, "can0") for m in head])


def _cli(capsys, log: Path, data: Path, out: Path, *extra: str) -> tuple[int, str]:
    rc = main(["can-speed", str(log), "--dbc", str(data / "toyota_2017.dbc"), "--out", str(out),
               *extra])
    return rc, capsys.readouterr().err


# -- copies that differ ---------------------------------------------------------------------

def test_the_speed_message_on_two_channels_with_different_payloads_is_refused(
        head, zero_kmh, data, folder, suffix, clean, tmp_path, capsys):
    """The user's log: every WHEEL_SPEEDS frame of can0 again on can1 0.2 ms later, at 0 km/h.
    Decoded together (exit 0, samples alternating 7.9 / 0.0 m/s, no word of it, before)."""
    frames = _with_copies(head, suffix, payload=zero_kmh)
    log = _write(folder / f"zero.{suffix}", frames)
    out = tmp_path / "s.csv"
    rc, err = _cli(capsys, log, data, out)
    n = sum(m.arbitration_id == WHEEL_ID for m in head)
    main_ch, copy_ch = ("can0", "can1") if suffix == "log" else ("0", "1")
    assert rc == 2 and not out.exists()
    assert "WHEEL_SPEEDS (0xAA)" in err
    assert f"{main_ch} ({n} frames), {copy_ch} ({n} frames)" in err
    assert (f"{n} of its {n} frames on {copy_ch} have no frame with the same payload on "
            f"{main_ch}") in err
    assert f"--can-channel {main_ch}" in err
    # the channel chosen: the speed of can0 alone
    rc, err = _cli(capsys, log, data, out, "--can-channel", main_ch)
    assert rc == 0
    got = read_speed_csv(out)
    np.testing.assert_allclose(got.t, clean.t, atol=1e-6)
    np.testing.assert_allclose(got.speed_mps, clean.speed_mps, atol=1e-9)


def test_one_copy_that_differs_is_enough_to_refuse(head, dbc, zero_kmh, folder):
    frames = _with_copies(head, "log")
    k = next(i for i, m in enumerate(frames) if m.channel == "can1" and i > len(frames) // 2)
    frames[k] = _on(frames[k], "can1", data=zero_kmh)
    with pytest.raises(InputError, match=r"\(1 of its \d+ frames on can1 have no frame with the"):
        decode_can_log(_write(folder / "one_bad.log", frames), dbc)


def test_streaming_refuses_the_mix_too(head, dbc, zero_kmh):
    """``feed`` (``live --bus``, ``can-speed --bus``): the frames of the first channel the
    message came on are decoded; a copy that differs raises, and nothing is mixed before."""
    decoder = SpeedDecoder(dbc)
    samples = []
    with pytest.raises(InputError, match=r"WHEEL_SPEEDS \(0xAA\).* can0 .* can1 .*"
                       r"--can-channel can0"):
        for m in _with_copies(head, "log", payload=zero_kmh):
            sample = decoder.feed(m)
            if sample is not None:
                samples.append(sample[1])
    assert samples and min(samples) > 5.0  # can0's 7.9 m/s only, never can1's 0
    assert "--can-channel can0" in str(decoder.summary)


# -- copies that agree, or nothing to decide ------------------------------------------------

def test_a_mirrored_bus_is_decoded_on_one_channel_and_says_which(
        head, dbc, folder, suffix, clean):
    frames = _with_copies(head, suffix, ids=(WHEEL_ID, SPEED_ID))
    series, summary = decode_can_log(_write(folder / f"mirror.{suffix}", frames), dbc)
    np.testing.assert_array_equal(series.t, clean.t)
    np.testing.assert_array_equal(series.speed_mps, clean.speed_mps)
    n = sum(m.arbitration_id == WHEEL_ID for m in head)
    main_ch, copy_ch = ("can0", "can1") if suffix == "log" else ("0", "1")
    assert summary.other_channel == n and summary.bad == 0
    assert (f"WHEEL_SPEEDS (0xAA) decoded on channel {main_ch} only: its {n} frames on "
            f"{copy_ch} are identical copies") in str(summary)


def test_streaming_a_mirrored_bus_gives_the_logs_samples(head, dbc, reference):
    frames = _with_copies(head, "log")
    decoder = SpeedDecoder(dbc)
    for m in frames:
        decoder.feed(m)
    series = decoder.series()
    np.testing.assert_array_equal(series.t, reference.t)
    np.testing.assert_array_equal(series.speed_mps, reference.speed_mps)
    # a copy logged before its original (the first frame seen on the mirror) is a copy too
    early = [_on(m, "can1", -0.5 * MIRROR_WINDOW_S) if m.channel == "can1" else m
             for m in frames]
    again = SpeedDecoder(dbc)
    for m in early:
        again.feed(m)
    np.testing.assert_array_equal(again.series().speed_mps, reference.speed_mps)


def test_copies_a_gateway_delays_by_20_ms_are_copies(head, dbc, folder, reference):
    """A gateway forwarding the bus 20 ms late: its copies, identical payloads, were refused
    as "different payloads" (the window was 5 ms); log and stream decode can0's samples."""
    frames = _with_copies(head, "log", delay=0.02)
    series, summary = decode_can_log(_write(folder / "gateway.log", frames), dbc)
    np.testing.assert_array_equal(series.speed_mps, reference.speed_mps)
    assert "are identical copies" in str(summary)
    stream = SpeedDecoder(dbc)
    for m in frames:
        stream.feed(m)
    np.testing.assert_array_equal(stream.series().speed_mps, reference.speed_mps)


def test_only_the_message_decoded_counts(head, dbc, zero_kmh, folder, reference):
    """SPEED (0xB4) on both buses with other payloads: not the message decoded, no matter."""
    frames = _with_copies(head, "log", ids=(SPEED_ID,), payload=bytes(8))
    series, summary = decode_can_log(_write(folder / "other_id.log", frames), dbc)
    np.testing.assert_array_equal(series.speed_mps, reference.speed_mps)
    assert "identical copies" not in str(summary)


def test_a_log_without_channels_has_nothing_to_choose(head, dbc, reference):
    series = SpeedDecoder(dbc).feed_many([_on(m, None) for m in head])
    np.testing.assert_array_equal(series.speed_mps, reference.speed_mps)


def test_a_live_bus_reader_stops_on_disagreeing_copies_and_keeps_why(data, head, zero_kmh):
    """Refused frame by frame on a live bus, the decoder's error ended the bus thread with a
    traceback and the run went on with a silent wheel speed; the reader now ends and keeps
    the error for ``run_live`` to report (exit 2)."""
    import threading

    from vipm_track.live_sources import BusReader

    frames = iter(_with_copies(head, "log", payload=zero_kmh))

    class Bus:
        def recv(self, timeout: float) -> can.Message | None:
            return next(frames, None)

    decoder = SpeedDecoder(data / "toyota_2017.dbc")
    stop = threading.Event()
    reader = BusReader(Bus(), decoder.feed, stop)
    reader.start()
    reader.join(30.0)
    stop.set()
    assert not reader.is_alive()
    assert isinstance(reader.failure, InputError) and "--can-channel" in str(reader.failure)
