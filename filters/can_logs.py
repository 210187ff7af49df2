"""CAN log files read record by record with python-can's readers, past bad records.

python-can's text readers (candump ``.log``, Vector ``.asc``, PCAN ``.trc``, ``.csv``) stop at
the first line they cannot parse (an exception ends their generator) or pass over it without
a word. Here they read from a line feed that numbers the lines: a line that raised is noted
with its number and reading resumes after it; a line the reader passed over is noted too,
unless it is one of the format's own non-frame lines (header, comments, events). Binary
formats (``.blf``, ``.mf4``, ``.db``) are read by ``can.LogReader``; a damaged record there
ends the reading (the container cannot be resynchronised), noted with the frame index.

Nothing read from a file is echoed raw: notes pass through ``vipm_track.errors.printable``.
"""

from __future__ import annotations

import gzip
import logging
import re
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from vipm_track.errors import InputError, printable

#: Suffixes read line by line, and the python-can reader class of each.
TEXT_READERS: dict[str, str] = {
    ".log": "CanutilsLogReader", ".asc": "ASCReader", ".trc": "TRCReader", ".csv": "CSVReader",
}
#: What each text format's lines look like, for the reason a line is not one of them.
TEXT_FORMATS: dict[str, str] = {
    ".log": "candump -l line '(time) iface id#data'", ".asc": "Vector ASC line",
    ".trc": "PCAN TRC line", ".csv": "python-can CSV row 'timestamp,arbitration_id,...'",
}
#: Suffixes python-can's ``LogReader`` reads (``.mf4`` needs asammdf).
LOG_SUFFIXES = (*TEXT_READERS, ".blf", ".mf4", ".db")

#: Lines of each text format that are not frames and not errors (stripped, any case).
_META: dict[str, re.Pattern[str]] = {
    ".log": re.compile(r"^$"),
    ".asc": re.compile(
        r"^($|//|date\s|base\s|(no\s+)?internal\s+events\s+logged|begin\s+triggerblock"
        r"|end\s+triggerblock|\d+\.\d+\s+(start\s+of\s+measurement|[a-z](?<!canfd)\S*"
        r"|\d+\s+(statistic|j1939|sv:|status)))", re.IGNORECASE),
    ".trc": re.compile(r"^($|;)"),
    ".csv": re.compile(r"^$"),
}
#: What a resumed reader is fed first so that its header step consumes it, not a frame line
#: (the .asc reader drops the first line after its header; the .trc reader skips comments;
#: the .csv reader skips one header line).
_RESUME_LINE = {".log": "\n", ".asc": "\n", ".trc": ";\n", ".csv": "\n"}


def log_suffix(path: Path) -> str:
    """The format suffix of a log name (``.asc`` of ``drive.asc.gz``); InputError if python-can
    does not read it."""
    suffixes = [s.lower() for s in path.suffixes]
    if suffixes and suffixes[-1] == ".gz":
        suffixes = suffixes[:-1]
    if not suffixes or suffixes[-1] not in LOG_SUFFIXES:
        raise InputError(f"{path}: unsupported CAN log type (python-can reads "
                         f"{', '.join(LOG_SUFFIXES)}, optionally .gz)")
    return suffixes[-1]


class _LineFeed:
    """The lines of a (possibly gzipped) text file as a text-mode file for a python-can
    reader: numbered, undecodable bytes replaced, the lines read since :meth:`taken` kept."""

    def __init__(self, fh: Any) -> None:
        self._fh = fh
        self.lineno = 0
        self.pending: list[tuple[int, str]] = []
        self._inject: list[str] = []

    def __iter__(self) -> _LineFeed:
        return self

    def __next__(self) -> str:
        if self._inject:
            return self._inject.pop()
        raw = self._fh.readline()
        if not raw:
            raise StopIteration
        self.lineno += 1
        line = raw.decode("utf-8", errors="replace")
        self.pending.append((self.lineno, line))
        return line

    def readline(self) -> str:
        try:
            return next(self)
        except StopIteration:
            return ""

    def inject(self, line: str) -> None:
        """Give ``line`` (not counted) before the next line of the file."""
        self._inject.append(line)

    def taken(self) -> list[tuple[int, str]]:
        """The (number, text) of the lines read since the last call."""
        out, self.pending = self.pending, []
        return out

    def close(self) -> None:
        pass


@contextmanager
def _quiet_python_can() -> Iterator[None]:
    # python-can logs a warning with the raw text of a line it cannot parse; the caller
    # counts and names those lines instead
    log = logging.getLogger("can")
    level = log.level
    log.setLevel(logging.CRITICAL)
    try:
        yield
    finally:
        log.setLevel(level)


class LogRecords:
    """The messages of a CAN log; ``position`` is the latest one's (``kind``: its ``line``
    number in a text log, its ``frame`` index in a binary one). ``on_bad(position, why)``
    hears of every line or record that gave no message and is not one of the format's
    non-frame lines."""

    def __init__(self, path: str | Path, on_bad: Callable[[int, str], None]) -> None:
        self.path = Path(path)
        if not self.path.is_file():
            raise InputError(f"{self.path}: " + ("a folder, not a CAN log" if self.path.is_dir()
                                                 else "CAN log not found"))
        self.suffix = log_suffix(self.path)
        self.kind = "line" if self.suffix in TEXT_READERS else "frame"
        self.on_bad = on_bad
        #: why reading ended before the end of the file (binary logs), else None
        self.stopped: str | None = None
        self.position = 0

    def __iter__(self) -> Iterator[Any]:
        with _quiet_python_can():
            if self.kind == "line":
                yield from self._text()
            else:
                yield from self._binary()

    def _text(self) -> Iterator[Any]:
        import can

        reader_class = getattr(can, TEXT_READERS[self.suffix])
        meta = _META[self.suffix]
        gz = self.path.suffix.lower() == ".gz"
        with (gzip.open(self.path, "rb") if gz else self.path.open("rb")) as fh:
            feed = _LineFeed(fh)
            reader = reader_class(feed)
            last_failed = -1
            while True:
                try:
                    pending = feed.pending
                    for msg in reader:
                        if len(pending) == 1:  # the usual case: one line, one frame
                            self.position = pending[0][0]
                            pending.clear()
                        else:
                            lines = feed.taken()
                            pending = feed.pending
                            self._passed_over(lines[:-1], meta)
                            self.position = lines[-1][0] if lines else feed.lineno
                        yield msg
                    self._passed_over(feed.taken(), meta)
                    return
                except (Exception, UnicodeError) as exc:  # readers raise assorted types
                    lines = feed.taken()
                    if lines:
                        self._passed_over(lines[:-1], meta)
                        self.on_bad(lines[-1][0],
                                    f"not a {TEXT_FORMATS[self.suffix]} ({_why(exc)})")
                    elif feed.lineno == last_failed:
                        self.position = feed.lineno
                        self.stopped = f"{_why(exc)}; reading stopped there"
                        return
                    last_failed = feed.lineno
                    feed.inject(_RESUME_LINE[self.suffix])

    def _passed_over(self, lines: list[tuple[int, str]], meta: re.Pattern[str]) -> None:
        for number, text in lines:
            stripped = text.strip()
            if meta.match(stripped) or (self.suffix == ".csv" and number == 1):
                continue
            self.on_bad(number, "not a CAN frame the reader understands")

    def _binary(self) -> Iterator[Any]:
        import can

        if self.path.stat().st_size == 0:  # the reader's own words: "unpack requires ..."
            raise InputError(f"{self.path}: empty file, no CAN log in it")
        try:
            reader = can.LogReader(str(self.path))
        except Exception as exc:
            # python-can says NotImplementedError (not ImportError) where asammdf is missing
            mf4 = "asammdf" in str(exc)
            if mf4 or isinstance(exc, ImportError):
                hint = (" (the mf4 extra: pip install 'vipm-track[mf4]', or '.[mf4]' in a "
                        "checkout)" if mf4 else "")
                raise InputError(f"{self.path}: this log format needs an optional "
                                 f"package{hint}: {printable(exc)}") from None
            raise InputError(f"{self.path}: cannot open as a CAN log: {_why(exc)}") from None
        index = 0
        try:
            iterator = iter(reader)
            while True:
                try:
                    msg = next(iterator)
                except StopIteration:
                    self._check_complete(reader, index)
                    return
                except Exception as exc:
                    self.position = index
                    self.stopped = (f"unreadable record ({_why(exc)}); the rest of the file "
                                    "cannot be read")
                    return
                self.position = index
                yield msg
                index += 1
        finally:
            stop = getattr(reader, "stop", None)
            if stop is not None:
                stop()

    def _check_complete(self, reader: Any, index: int) -> None:
        """A BLF whose header announces more bytes than the file holds was cut short (a copy
        or a recording that ended early): its frames stop early, so say so in ``stopped``."""
        announced = getattr(reader, "file_size", None)
        if not isinstance(announced, int) or announced <= 0:
            return
        size = self.path.stat().st_size
        if size < announced:
            self.position = index
            self.stopped = (f"the file holds {size} bytes but its header says {announced}: cut "
                            f"short, only its first {index} frames could be read")


def _why(exc: BaseException) -> str:
    return printable(f"{type(exc).__name__}: {exc}", 160)
