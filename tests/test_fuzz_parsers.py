"""Every parser of a user's file, fuzzed: random truncation, bit flips, a field of the wrong
type, lines dropped or repeated. Each must give a result or an ``InputError`` whose message
names the file and prints no control characters, never another exception; a text CAN log must
read on past a damaged line. Deterministic (``derandomize``) and offline."""

from __future__ import annotations

import itertools
import re
import tempfile
from pathlib import Path

import cv2
import numpy as np
import pytest
from conftest import CAR_CAMERA_YAML, ROOT, shared_data
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from vipm_track.errors import InputError

FUZZ = settings(max_examples=30, deadline=None, derandomize=True,
                suppress_health_check=[HealthCheck.too_slow])
CONTROL = re.compile(r"[\x00-\x08\x0b-\x1f\x7f]")
#: Values of the wrong type (or out of range) a field may be replaced with.
WRONG = ["abc", "", "-1", "0", "7.5", "nan", "inf", "1e400", "[1, 2]", "{a: 1}", "null", "0x",
         "\x00", "é", "9" * 30, "1.5.2", "true", ";", "#", "'"]
TOKEN = re.compile(rb"[^\s,:\[\]{}()]+")


@st.composite
def mutations(draw, seed: bytes) -> bytes:
    """``seed`` damaged once: cut, a bit flipped, a token replaced by a wrong value, a line
    dropped or repeated."""
    data = bytearray(seed)
    kind = draw(st.sampled_from(["cut", "flip", "token", "drop", "repeat"]))
    if kind == "cut":
        return bytes(data[: draw(st.integers(0, len(data)))])
    if kind == "flip":
        for _ in range(draw(st.integers(1, 3))):
            i = draw(st.integers(0, len(data) - 1))
            data[i] ^= 1 << draw(st.integers(0, 7))
        return bytes(data)
    if kind == "token":
        tokens = list(TOKEN.finditer(seed))
        m = tokens[draw(st.integers(0, len(tokens) - 1))]
        value = draw(st.sampled_from(WRONG)).encode()
        return seed[: m.start()] + value + seed[m.end():]
    lines = seed.splitlines(keepends=True)
    i = draw(st.integers(0, len(lines) - 1))
    if kind == "drop":
        del lines[i]
    else:
        lines.insert(i, lines[i])
    return b"".join(lines)


def _check(parse, path: Path, data: bytes):
    """``parse(path)`` of ``data`` written to ``path``: its result, or None after an
    InputError that names the file and prints cleanly. Any other exception fails the test."""
    path.write_bytes(data)
    try:
        return parse(path)
    except InputError as exc:
        text = str(exc)
        assert str(path) in text or path.name in text, text
        assert not CONTROL.search(text.replace("\n", "")), repr(text)
        return None


def _tmp(name: str) -> Path:
    folder = Path(tempfile.mkdtemp(prefix="fuzz"))
    return folder / name


# -- camera files -----------------------------------------------------------------------------

def _opencv_yaml() -> bytes:
    path = _tmp("cv.yaml")
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    fs.write("camera_matrix", np.array([[900.0, 0, 640], [0, 900, 360], [0, 0, 1]]))
    fs.write("distortion_coefficients", np.array([[0.1, -0.05, 0.0, 0.0, 0.0]]))
    fs.write("image_width", 1280)
    fs.write("image_height", 720)
    fs.release()
    return path.read_bytes()


OPENCV_YAML = _opencv_yaml()
KITTI_CALIB = (b"P0: 7.070912e+02 0.000000e+00 6.018873e+02 0.000000e+00 0.000000e+00 "
               b"7.070912e+02 1.831104e+02 0.000000e+00 0.000000e+00 0.000000e+00 1.000000e+00 "
               b"0.000000e+00\nP1: 7.070912e+02 0.000000e+00 6.018873e+02 -3.798145e+02 "
               b"0.000000e+00 7.070912e+02 1.831104e+02 0.000000e+00 0.000000e+00 0.000000e+00 "
               b"1.000000e+00 0.000000e+00\n")


@FUZZ
@given(st.data())
def test_camera_ros_yaml(data):
    from vipm_track.camera import load_camera

    _check(load_camera, _tmp("cam.yaml"), data.draw(mutations(CAR_CAMERA_YAML.encode())))


@FUZZ
@given(st.data())
def test_camera_opencv_yaml(data):
    from vipm_track.camera import load_camera

    _check(load_camera, _tmp("cv.yaml"), data.draw(mutations(OPENCV_YAML)))


@FUZZ
@given(st.data())
def test_kitti_calib(data):
    from vipm_track.camera import load_camera

    _check(load_camera, _tmp("calib.txt"), data.draw(mutations(KITTI_CALIB)))


# -- frame times, tables ----------------------------------------------------------------------

@FUZZ
@given(st.data())
def test_times_txt(data):
    from vipm_track.sources import read_times

    seed = "".join(f"{0.1 * k:.6e}\n" for k in range(8)).encode()
    times = _check(read_times, _tmp("times.txt"), data.draw(mutations(seed)))
    if times is not None:
        assert np.all(np.isfinite(times)) and np.all(np.diff(times) > 0)


ESTIMATES = b"".join((ROOT / "tests" / "data" / "kitti07_estimates.csv")
                     .read_bytes().splitlines(keepends=True)[:14])


def _read_estimates(path: Path):
    from vipm_track.commands.inputs import read_estimates

    ms = read_estimates(str(path))
    frames = [m.frame for m in ms]
    assert frames == sorted(set(frames))  # each frame once, in order
    assert all(b.t > a.t for a, b in itertools.pairwise(ms))
    return ms


def test_estimates_csv_damaged_cells_named():
    """A frame number that is no index (7.5 was read as frame 7) and a standard deviation of
    zero (a singular smoother) are errors that name the row and the column."""
    from vipm_track.table import read_table

    lines = ESTIMATES.decode().splitlines(keepends=True)
    header = lines[0].strip().split(",")
    for column, value, message in (
            ("frame", "7.5", r"row 4, column 'frame': '7.5' is not a frame index"),
            ("tz_std_m", "0", r"row 4 \(frame \d+\): tz_std_m = 0.0 is not a standard "
                              "deviation"),
            # one corrupt number wrecked the smoother's summary (an interval of ±inf)
            ("pitch_deg", "1e300", r"row 4 \(frame \d+\): pitch_deg = 1e\+300 is not an "
                                   "angle within ±90°"),
            ("yaw_deg", "inf", r"yaw_deg = inf is not an angle"),
            ("height_m", "-0.7", r"height_m = -0.7 is not a height > 0")):
        cells = lines[3].rstrip("\n").split(",")
        cells[header.index(column)] = value
        path = _tmp("est.csv")
        path.write_text("".join(lines[:3]) + ",".join(cells) + "\n" + "".join(lines[4:]))
        with pytest.raises(InputError, match=message):
            _read_estimates(path)
    assert read_table(path, quiet=True)["frame"].dtype == np.int64


@FUZZ
@given(st.sampled_from(["prev_pitch_deg", "pitch_deg", "prev_roll_deg", "roll_deg", "yaw_deg"]),
       st.floats(allow_nan=False), st.booleans())
def test_estimates_csv_angle_beyond_its_range_named(column, value, negative):
    limit = 90.0 if "pitch" in column else 180.0
    value = (limit + abs(value) + 1e-6) * (-1 if negative else 1)
    lines = ESTIMATES.decode().splitlines(keepends=True)
    header = lines[0].strip().split(",")
    cells = lines[5].rstrip("\n").split(",")
    cells[header.index(column)] = repr(value)
    path = _tmp("est.csv")
    path.write_text("".join(lines[:5]) + ",".join(cells) + "\n" + "".join(lines[6:]))
    with pytest.raises(InputError, match=rf"row 6 \(frame \d+\): {column} = .* is not an angle"):
        _read_estimates(path)


@FUZZ
@given(st.data())
def test_estimates_csv(data):
    _check(_read_estimates, _tmp("est.csv"), data.draw(mutations(ESTIMATES)))


def _parquet_seed() -> bytes:
    from vipm_track.table import ESTIMATE_COLUMNS, TableWriter, read_table

    src = _tmp("est.csv")
    src.write_bytes(ESTIMATES)
    table = read_table(src)
    out = src.with_name("copy.csv")
    with TableWriter(out, ESTIMATE_COLUMNS, parquet_path=out.with_suffix(".parquet")) as w:
        for i in range(len(table["frame"])):
            w.write({c: table[c][i] for c in table})
    return out.with_suffix(".parquet").read_bytes()


@FUZZ
@given(st.data())
def test_estimates_parquet(data):
    seed = _parquet_seed_cached()
    _check(_read_estimates, _tmp("est.parquet"), data.draw(mutations(seed)))


_PARQUET: list[bytes] = []


def _parquet_seed_cached() -> bytes:
    if not _PARQUET:
        _PARQUET.append(_parquet_seed())
    return _PARQUET[0]


@FUZZ
@given(st.data())
def test_speed_csv(data):
    from vipm_track.filters.wheel_speed import read_speed_csv

    seed = ("t,speed_mps\n" + "".join(f"{0.02 * k:.6f},{5 + 0.01 * k:.5f}\n"
                                       for k in range(20))).encode()
    series = _check(read_speed_csv, _tmp("speed.csv"), data.draw(mutations(seed)))
    if series is not None:
        assert np.all(np.diff(series.t) > 0) and np.all(np.isfinite(series.speed_mps))
        assert np.all(np.abs(series.speed_mps) <= 100.0)


# -- CAN logs, DBC ----------------------------------------------------------------------------

_CAN: dict[str, object] = {}


def _can(fmt: str) -> tuple[bytes, object]:
    """(a 400-frame log of the RAV4 drive in format ``fmt``, the loaded DBC)."""
    import can

    from vipm_track.filters.can_decode import load_dbc

    folder = shared_data("comma2k19_can")
    if "dbc" not in _CAN:
        _CAN["dbc"] = load_dbc(folder / "toyota_2017.dbc")
        msgs = list(can.LogReader(str(folder / "rav4_drive.log")))[:3000]
        # keep the wheel-speed frames and a few others, so every line matters
        _CAN["msgs"] = [m for m in msgs if m.arbitration_id in (0xAA, 0xB4)][:300] + msgs[:100]
        _CAN["msgs"].sort(key=lambda m: m.timestamp)
    if fmt not in _CAN:
        path = _tmp(f"drive.{fmt}")
        with can.Logger(str(path)) as writer:
            for m in _CAN["msgs"]:
                writer.on_message_received(m)
        _CAN[fmt] = path.read_bytes()
    return _CAN[fmt], _CAN["dbc"]


@pytest.mark.parametrize("fmt", ["log", "asc", "trc", "csv", "blf"])
@FUZZ
@given(data=st.data())
def test_can_logs(fmt, data):
    from vipm_track.filters.speed_decoder import decode_can_log

    seed, dbc = _can(fmt)
    damaged = data.draw(mutations(seed))
    result = _check(lambda p: decode_can_log(p, dbc), _tmp(f"drive.{fmt}"), damaged)
    if result is None or fmt == "blf":
        return
    _, summary = result
    lines = damaged.count(b"\n") + 1
    frames = seed.count(b"\n") - (len(seed.splitlines()) - len(_CAN["msgs"]))
    # a text log reads on past a damaged line: every frame line is a frame or a counted skip
    # (a flipped newline joins two lines; a cut or dropped line loses its frames)
    if len(damaged) == len(seed):
        assert summary.frames + summary.bad_lines >= frames - 2, (summary, lines)
    for line in summary.lines():
        assert not CONTROL.search(line)


@settings(max_examples=15, deadline=None, derandomize=True)
@given(st.data())
def test_dbc(data):
    from vipm_track.filters.can_decode import load_dbc

    seed = (shared_data("comma2k19_can") / "toyota_2017.dbc").read_bytes()
    _check(load_dbc, _tmp("car.dbc"), data.draw(mutations(seed)))


@settings(max_examples=40, deadline=None, derandomize=True)
@given(st.data())
def test_a_dbc_cut_within_a_statement_names_its_line(data):
    """cantools passed over a message or signal statement cut short at the end of the file
    and loaded the rest: a DBC cut mid-copy was used with a message or signal missing."""
    from vipm_track.filters.can_decode import DbcError, load_dbc

    text = (shared_data("comma2k19_can") / "toyota_2017.dbc").read_text()
    lines = text.splitlines(keepends=True)
    statements = [i for i, line in enumerate(lines) if line.lstrip().startswith(("BO_ ", "SG_ "))
                  and not line.startswith("BO_TX_BU_")]
    i = data.draw(st.sampled_from(statements))
    # cut before the statement's last token (its nodes): a cut within that leaves a valid
    # statement naming another node ("XXX" cut to "X")
    keep = data.draw(st.integers(4, lines[i].rstrip().rindex(" ")))
    path = _tmp("cut.dbc")
    path.write_text("".join(lines[:i]) + lines[i][:keep])
    with pytest.raises(DbcError, match=rf": line {i + 1}(, column \d+)?: "):
        load_dbc(path)
    if i > statements[0]:  # cut where a statement begins: all of it read
        path.write_text("".join(lines[:i]))
        assert load_dbc(path).messages


def test_a_dbc_with_vectors_long_names_is_read_whole():
    """CANdb++ writes names over 32 characters cut, with the whole name in a
    SystemMessageLongSymbol / SystemSignalLongSymbol attribute, which cantools takes: the
    check that every statement was read must not take the renamed ones for unread."""
    from vipm_track.filters.can_decode import load_dbc

    path = _tmp("long.dbc")
    path.write_text(
        'VERSION ""\n\nNS_ :\n\nBS_:\n\nBU_: ECU\n\n'
        "BO_ 100 VeryLongMessageNameThatIsTruncat: 8 ECU\n"
        ' SG_ VeryLongSignalNameThatIsTruncated : 0|16@1+ (0.01,0) [0|250] "km/h" ECU\n'
        ' SG_ Other : 16|8@1+ (1,0) [0|255] "" ECU\n\n'
        'BA_DEF_ BO_ "SystemMessageLongSymbol" STRING ;\n'
        'BA_DEF_ SG_ "SystemSignalLongSymbol" STRING ;\n'
        'BA_ "SystemMessageLongSymbol" BO_ 100 "VeryLongMessageNameThatIsTruncatedByVector";\n'
        'BA_ "SystemSignalLongSymbol" SG_ 100 VeryLongSignalNameThatIsTruncated '
        '"VeryLongSignalNameThatIsTruncatedByVectorToo";\n')
    (message,) = load_dbc(path).messages
    assert message.name == "VeryLongMessageNameThatIsTruncatedByVector"
    assert len(message.signals) == 2


# -- nominal calibration (filters.nominal.load_nominal) ----------------------------------------

NOMINAL = (ROOT / "data" / "nominal_car.yaml").read_bytes()


def _load_nominal(path: Path):
    from vipm_track.filters.nominal import load_nominal

    return load_nominal(path)


@FUZZ
@given(st.data())
def test_nominal_yaml(data):
    damaged = data.draw(mutations(NOMINAL))
    try:
        damaged.decode("utf-8")
    except UnicodeDecodeError:  # the next test
        return
    _check(_load_nominal, _tmp("nominal.yaml"), damaged)


def test_nominal_yaml_with_undecodable_bytes():
    _check(_load_nominal, _tmp("nominal.yaml"), b"\xa3" + NOMINAL[1:])
