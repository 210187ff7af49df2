"""A bare MCAP file cut short (a logger that died, a copy that stopped): its complete records
made readable again.

An MCAP file ends in a footer and its closing magic, and ``rosbags`` refuses one without them
("File end magic is invalid"). Its records are ``opcode (u8), length (u64 LE), body``, so the
complete ones are found by walking the lengths from the header on; :func:`repaired_copy` writes
them to a temporary copy closed by a data-end record, a footer without a summary and the magic,
which a reader then scans record by record (the MCAP specification's own recovery). A chunk
cut part-way is left out whole, with the messages in it.
"""

from __future__ import annotations

import atexit
import shutil
import struct
import tempfile
from pathlib import Path

MAGIC = b"\x89MCAP0\r\n"
_HEAD = struct.Struct("<BQ")
_FOOTER, _DATA_END = 0x02, 0x0F
#: the records that close a data section with no summary: DataEnd (crc 0 = not given), then
#: Footer (summary start 0 = none, summary offset start 0, crc 0) and the closing magic
_CLOSING = (_HEAD.pack(_DATA_END, 4) + struct.pack("<I", 0)
            + _HEAD.pack(_FOOTER, 20) + struct.pack("<QQI", 0, 0, 0) + MAGIC)

_copies: dict[tuple[str, int, int], tuple[Path, int]] = {}  # file version: (copy, kept)
_folder: Path | None = None


def complete_length(path: str | Path) -> int | None:
    """Bytes of the MCAP file ``path`` up to the end of its last complete data record (before
    any data-end record); None where it does not start as an MCAP file or is whole (its
    footer read)."""
    with Path(path).open("rb") as fh:
        if fh.read(len(MAGIC)) != MAGIC:
            return None
        size = fh.seek(0, 2)
        position = len(MAGIC)
        while position + _HEAD.size <= size:
            fh.seek(position)
            opcode, length = _HEAD.unpack(fh.read(_HEAD.size))
            end = position + _HEAD.size + length
            if end > size:
                break
            if opcode == _FOOTER:
                return None
            if opcode == _DATA_END:  # the summary after it is no data
                break
            position = end
        return position


def repaired_copy(path: str | Path) -> tuple[Path, int, int] | None:
    """A readable copy of the cut MCAP file ``path`` (module doc) in a temporary folder removed
    at exit, with the bytes it keeps and the file's size; None where ``path`` is no cut MCAP
    file or keeps no record past its header. One copy per file version."""
    global _folder
    path = Path(path)
    stat = path.stat()
    key = (str(path.resolve()), stat.st_size, stat.st_mtime_ns)
    if key in _copies:  # a bag is opened once per pass over it: the file walked once
        return (*_copies[key], stat.st_size)
    kept = complete_length(path)
    if kept is None:
        return None
    with path.open("rb") as fh:
        fh.seek(len(MAGIC))
        _, length = _HEAD.unpack(fh.read(_HEAD.size))
    if kept <= len(MAGIC) + _HEAD.size + length:  # the header record alone: nothing to read
        return None
    if _folder is None:
        _folder = Path(tempfile.mkdtemp(prefix="vipm-mcap-"))
        atexit.register(shutil.rmtree, _folder, True)
    copy = _folder / f"{len(_copies)}_{path.name}"
    with path.open("rb") as src, copy.open("wb") as dst:
        remaining = kept
        while remaining:
            block = src.read(min(remaining, 1 << 24))
            if not block:
                break
            dst.write(block)
            remaining -= len(block)
        dst.write(_CLOSING)
    _copies[key] = (copy, kept)
    return copy, kept, stat.st_size


__all__ = ["MAGIC", "complete_length", "repaired_copy"]
