"""Text files as the project reads them: every table, list and calibration file."""

from __future__ import annotations

from pathlib import Path


def read_text(path: str | Path) -> str:
    """Text of a file: undecodable bytes and NULs become U+FFFD (so a damaged line fails
    where it is, with its number, rather than the whole file failing to decode), and a
    leading UTF-8 byte-order mark (what spreadsheet programs save as "CSV UTF-8") is
    dropped."""
    text = Path(path).read_bytes().decode("utf-8", errors="replace").replace("\x00", "\ufffd")
    return text.removeprefix("\ufeff")
