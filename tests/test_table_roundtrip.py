"""Estimates tables: a measurement written as a row and read back is the same measurement,
and the file's text says what CONVENTIONS.md says (checked with the csv module, not with
the project's reader)."""

from __future__ import annotations

import csv
import errno
import tempfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from vipm_track.measurement import PairMeasurement, measurement_row, read_measurements
from vipm_track.table import BASE_COLUMNS, ESTIMATE_COLUMNS, TableWriter, write_table

_ANGLE = np.array([True, True, True, True, False, False, True])
_Z_COLUMNS = ("prev_pitch_deg", "prev_roll_deg", "pitch_deg", "roll_deg", "tx_m", "tz_m",
              "yaw_deg")
_STD_COLUMNS = ("prev_pitch_std_deg", "prev_roll_std_deg", "pitch_std_deg", "roll_std_deg",
                "tx_std_m", "tz_std_m", "yaw_std_deg")


def _measurement(frame: int, seed: int, ok: bool = True) -> PairMeasurement:
    rng = np.random.default_rng(seed)
    z = rng.normal(0.0, 0.3, 7) if ok else np.full(7, np.nan)
    a = rng.normal(size=(7, 7))
    cov = (a @ a.T + 7 * np.eye(7)) * rng.uniform(1e-8, 1e-3)
    if not ok:
        cov = np.full((7, 7), np.nan)
    return PairMeasurement(frame=frame, t=0.1 * frame + rng.uniform(0, 0.01), z=z,
                           covariance=cov, height_assumed=1.0 + rng.uniform(0, 1),
                           status="ok" if ok else "too few inliers",
                           inliers=int(rng.integers(12, 99)))


@settings(max_examples=25, deadline=None)
@given(seeds=st.lists(st.integers(0, 2**31), min_size=1, max_size=6),
       failed=st.lists(st.booleans(), min_size=6, max_size=6))
def test_measurements_survive_the_table_exactly(seeds: list[int], failed: list[bool]) -> None:
    ms = [_measurement(k + 1, s, ok=not failed[k]) for k, s in enumerate(seeds)]
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "est.csv"
        write_table(path, [measurement_row(m) for m in ms], ESTIMATE_COLUMNS)
        back = read_measurements(path)
        with path.open(newline="") as f:
            text_rows = list(csv.DictReader(f))
        header = next(csv.reader(path.open(newline="")))
    assert header[:len(BASE_COLUMNS)] == list(BASE_COLUMNS)
    assert len(back) == len(ms) == len(text_rows)
    for m, b, row in zip(ms, back, text_rows, strict=True):
        assert (b.frame, b.status, b.inliers) == (m.frame, m.status, m.inliers)
        # 15 significant digits in the file (docs/formats.md): t as 0.3, not 0.30000000000000004
        assert b.t == float(f"{m.t:.15g}")
        assert b.height_assumed == float(f"{m.height_assumed:.15g}")
        assert int(row["frame"]) == m.frame and row["status"] == m.status
        if not m.ok:
            assert not b.ok and all(row[c] == "" for c in _Z_COLUMNS)
            continue
        # radians and metres in memory, degrees and metres in the file, to 15 digits
        np.testing.assert_allclose(b.z, m.z, rtol=1e-14, atol=0)
        np.testing.assert_allclose(b.covariance, m.covariance, rtol=1e-12, atol=1e-30)
        text_z = np.array([float(row[c]) for c in _Z_COLUMNS])
        text_std = np.array([float(row[c]) for c in _STD_COLUMNS])
        np.testing.assert_allclose(text_z, np.where(_ANGLE, np.degrees(m.z), m.z), rtol=1e-14)
        np.testing.assert_allclose(text_std, np.where(_ANGLE, np.degrees(m.std), m.std),
                                   rtol=1e-14)


class _DiskFillsUp:
    """A raw file that takes ``room`` more bytes, then fails as a full disk does: the write
    that reaches the limit stores part of its bytes and the next raises ENOSPC."""

    def __init__(self, raw, room: int) -> None:
        self.raw, self.room = raw, room

    def write(self, data) -> int:
        if self.room <= 0:
            raise OSError(errno.ENOSPC, "No space left on device")
        n = self.raw.write(bytes(data[: self.room]))
        self.room -= n
        return n

    def __getattr__(self, name):
        return getattr(self.raw, name)


def test_a_disk_that_fills_up_mid_row_leaves_only_complete_rows(tmp_path):
    """A full disk left the table cut in the middle of a row."""
    path = tmp_path / "t.csv"
    writer = TableWriter(path, ["pitch_deg"])
    writer.write({"frame": 0, "t": 0.0, "pitch_deg": 1.5})
    writer._file = _DiskFillsUp(writer._file, room=7)
    with pytest.raises(OSError, match="No space left") as info:
        writer.write({"frame": 1, "t": 0.1, "pitch_deg": 2.25})
    assert info.value.filename == str(path)
    writer._file = writer._file.raw
    writer.close()
    header, row, *rest = path.read_text().split("\n")
    assert header.startswith("frame,t,") and row.startswith("0,0.0,") and rest == [""]


def test_a_folder_given_as_a_table_is_named_so(tmp_path):
    """`report FOLDER` said "file not found" for a folder that is there."""
    from vipm_track.table import TableError, read_table

    with pytest.raises(TableError, match="a folder, not a table"):
        read_table(tmp_path)


def test_a_text_file_that_is_no_table_is_named_by_its_header(tmp_path):
    """A README given as estimates said "line 3: 2 cells but the header has 1 (a cut or
    damaged row)"; it lacks the table's columns, and that is what the error says."""
    from vipm_track.table import TableError, read_table

    path = tmp_path / "notes.md"
    path.write_text("# notes\n\nfirst, then the rest\n")
    with pytest.raises(TableError, match=r"missing column\(s\) \['frame', 't'\]; header is "
                                         r"\['# notes'\]"):
        read_table(path)
