"""Errors the user can act on: the CLI prints their message (file, frame, field) and exits 2
(:class:`InputError`) or 1 (:class:`NothingUsable`)."""

from __future__ import annotations

import re
import signal
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any


class InputError(ValueError):
    """Bad input: a file, frame, field or option that cannot be used, named in the message."""


class NothingUsable(RuntimeError):
    """The run went through its input but nothing in it was usable (every frame failed):
    the message counts the statuses; the CLI exits 1."""


_UNPRINTABLE = re.compile(r"[\x00-\x08\x0b-\x1f\x7f-\x9f\ufffd]")


def printable(text: object, limit: int = 400) -> str:
    """``text`` safe for a terminal: control characters and undecodable bytes shown as
    ``\\xNN`` escapes (a garbage file's bytes are never echoed raw), cut at ``limit``
    characters."""
    s = _UNPRINTABLE.sub(lambda m: m.group().encode("unicode_escape").decode("ascii"), str(text))
    return s if len(s) <= limit else s[: limit - 3] + "..."


def os_error_line(exc: OSError, what: str = "") -> str:
    """One line for an OS error (permissions, disk full, not a directory): the path and the
    reason, no traceback."""
    path = exc.filename if exc.filename is not None else what
    reason = exc.strerror or type(exc).__name__
    extra = f" -> {exc.filename2}" if getattr(exc, "filename2", None) else ""
    return printable(f"{path}{extra}: {reason}" if path else reason)


def yaml_error_line(exc: Exception) -> str:
    """One line for a YAML parse error: ``line L, column C: not valid YAML (problem)``
    (PyYAML's own text spans several lines and names ``<unicode string>``)."""
    mark = getattr(exc, "problem_mark", None)
    where = f"line {mark.line + 1}, column {mark.column + 1}: " if mark is not None else ""
    problem = getattr(exc, "problem", None) or (str(exc).splitlines() or [type(exc).__name__])[0]
    return f"{where}not valid YAML ({printable(problem)})"


class InvalidYaml(InputError):
    """A YAML text that does not parse, or holds a value YAML cannot build; the message is
    the problem only (the caller names the file)."""


def parse_yaml(text: str) -> object:
    """``yaml.safe_load(text)``, any failure an :class:`InvalidYaml`: a syntax error (with its
    line and column) or a value PyYAML cannot build (a date such as 2024-13-45 raises a
    plain ``ValueError`` inside it)."""
    import yaml  # only the commands that read YAML files pay for it

    try:
        return yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise InvalidYaml(yaml_error_line(exc)) from None
    except (ValueError, TypeError, OverflowError) as exc:
        raise InvalidYaml(f"not valid YAML ({printable(exc)})") from None


def interrupted_in(exc: BaseException) -> bool:
    """Whether ``exc`` carries a Ctrl-C / SIGTERM: a KeyboardInterrupt that arrived inside a
    compiled kernel comes back as a ``SystemError`` whose cause or context it is."""
    seen: set[int] = set()
    cause: BaseException | None = exc
    while cause is not None and id(cause) not in seen:
        if isinstance(cause, KeyboardInterrupt):
            return True
        seen.add(id(cause))
        cause = cause.__cause__ or cause.__context__
    return False


@contextmanager
def interrupts_held() -> Iterator[None]:
    """Ctrl-C and SIGTERM ignored while the block runs: what an interrupt left to write (the
    rows it cut short, the summary) is written whole even when the user presses Ctrl-C again.
    The handlers are restored after; from a thread other than the main one, nothing is held
    (only the main thread may set them)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    with _interrupts_to(signal.SIG_IGN, keep_ignored=False):
        yield


@contextmanager
def _interrupts_to(handler: Any, keep_ignored: bool) -> Iterator[None]:
    """SIGINT and SIGTERM sent to ``handler`` while the block runs (main thread only), each
    restored after; with ``keep_ignored``, a signal ignored now is left ignored."""
    previous = {sig: signal.getsignal(sig) for sig in (signal.SIGINT, signal.SIGTERM)}
    if keep_ignored:
        previous = {sig: old for sig, old in previous.items() if old is not signal.SIG_IGN}
    for sig in previous:
        signal.signal(sig, handler)
    try:
        yield
    finally:
        for sig, old in previous.items():
            signal.signal(sig, old)


@dataclass
class InterruptFlag:
    """Set by :func:`interrupts_deferred` when Ctrl-C or SIGTERM arrives."""

    requested: bool = False


_deferring = False  # an interrupts_deferred block is open (on the main thread)


@contextmanager
def interrupts_deferred() -> Iterator[InterruptFlag]:
    """Ctrl-C and SIGTERM noted on the yielded flag, not raised, while the block runs: a loop
    that checks ``flag.requested`` between its steps stops where its state is whole (an
    interrupt raised mid-step could leave half of it). The handlers are restored after; a
    signal ignored stays ignored; from a thread other than the main one (which never gets
    the interrupt) nothing is changed and the flag stays unset, and within another such
    block the outer block's flag takes it (its owner acts on it)."""
    global _deferring
    flag = InterruptFlag()
    if threading.current_thread() is not threading.main_thread() or _deferring:
        # nested: the outer block's flag takes the interrupt and its owner acts on it
        yield flag
        return

    def note(signum: int, frame: object) -> None:
        flag.requested = True

    _deferring = True
    try:
        # a signal ignored (a worker process's Ctrl-C, which reaches the whole group) stays so
        with _interrupts_to(note, keep_ignored=True):
            yield flag
    finally:
        _deferring = False

