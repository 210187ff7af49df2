"""Progress that fits where the output goes: tqdm's bar on a terminal; where stderr is a
file or a pipe (a log, CI, a job scheduler), one plain line every few seconds instead of a
bar redrawn with carriage returns."""

from __future__ import annotations

import sys
from typing import Any, TextIO

from tqdm import tqdm

#: seconds between progress lines when stderr is not a terminal
LOG_INTERVAL_S = 5.0


class _Lines:
    """A text stream that writes each of tqdm's redraws as one line (no ``\\r``)."""

    def __init__(self, stream: TextIO) -> None:
        self._stream = stream

    def write(self, text: str) -> None:
        line = text.replace("\r", "").strip()
        if line:
            self._stream.write(line + "\n")

    def flush(self) -> None:
        self._stream.flush()


def progress_bar(iterable: Any = None, **options: Any) -> tqdm:
    """``tqdm(iterable, **options)`` on stderr: a live bar on a terminal, a line every
    ``LOG_INTERVAL_S`` seconds otherwise (``disable`` and the rest pass through)."""
    stream = sys.stderr
    if stream is not None and stream.isatty():
        return tqdm(iterable, file=stream, **options)
    options.setdefault("mininterval", LOG_INTERVAL_S)
    return tqdm(iterable, file=_Lines(stream or sys.__stderr__), ascii=True, **options)


def redraw_interval_s() -> float:
    """Seconds between redraws of text that changes often (a bar's postfix): a second on a
    terminal, ``LOG_INTERVAL_S`` where each redraw is a line of a log."""
    stream = sys.stderr
    return 1.0 if stream is not None and stream.isatty() else LOG_INTERVAL_S
