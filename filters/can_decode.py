"""DBC signals as vectorised decoders: load a DBC, resolve ``MESSAGE.SIGNAL`` specs, decode
many payloads of one message at once with numpy bit operations, convert units to m/s.

cantools parses the DBC; its per-frame ``decode_message`` (tens of µs a frame) is only the
fallback for what the bit arithmetic here does not cover (float signals, multiplexed
signals, payloads longer than 8 bytes).
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import cantools
import numpy as np
from numpy.typing import NDArray

from vipm_track.errors import InputError, printable

#: Speed units a DBC may state, and their factor to m/s (case-insensitive, spaces ignored).
UNIT_TO_MPS: dict[str, float] = {
    "km/h": 1.0 / 3.6, "kmh": 1.0 / 3.6, "kph": 1.0 / 3.6, "km/hr": 1.0 / 3.6,
    "m/s": 1.0, "mps": 1.0, "m/sec": 1.0,
    "mph": 0.44704, "mi/h": 0.44704,
}

#: Wheel-speed signal names for the default "rear wheels" choice: a name mentioning speed
#: (or a wheel) that ends in RL/RR (or REAR_LEFT/REAR_RIGHT).
_REAR_LEFT = re.compile(r"(^|[^A-Z])(RL|REAR_?LEFT|LEFT_?REAR)$")
_REAR_RIGHT = re.compile(r"(^|[^A-Z])(RR|REAR_?RIGHT|RIGHT_?REAR)$")
_WHEELISH = re.compile(r"SPEED|SPD|WHEEL|WHL|VEL")


class DbcError(InputError):
    """A DBC that cannot be loaded, or a signal spec it does not resolve."""


@dataclass(frozen=True)
class SignalSpec:
    """One speed signal: message and signal name, factor from its unit to m/s."""

    message: str
    signal: str
    unit: str
    to_mps: float

    @property
    def name(self) -> str:
        return f"{self.message}.{self.signal}"


def load_dbc(path: str | Path) -> cantools.database.can.Database:
    """The DBC at ``path`` (non-strict: overlapping signals, common in opendbc, are allowed)."""
    path = Path(path)
    if path.is_dir():
        raise DbcError(f"{path}: a folder, not a DBC file")
    if not path.is_file():
        raise DbcError(f"{path}: DBC file not found")
    binary = _binary_offset(path.read_bytes())
    if binary is not None:
        raise DbcError(f"{path}: not a DBC: binary content (byte {binary[1]:#04x} at offset "
                       f"{binary[0]}); a DBC is a text file")
    try:
        db = cantools.database.load_file(str(path), database_format="dbc", strict=False)
    except Exception as exc:  # cantools raises several unrelated types for bad files
        where = re.search(r"line (\d+), column (\d+)", str(exc))
        if where:
            raise DbcError(f"{path}: line {where[1]}, column {where[2]}: not valid DBC syntax "
                           "(cantools)") from None
        raise DbcError(f"{path}: cannot load as DBC: {printable(exc, 200)}") from None
    _check_all_read(path, path.read_text(errors="replace"), db)
    if not db.messages:
        raise DbcError(f"{path}: DBC defines no messages")
    return db


#: A message (``BO_ id name:``) and a signal (`` SG_ name``) statement of a DBC's text.
_MESSAGE_LINE = re.compile(r"BO_\s+(\d+)\s+(\w+)\s*:")
_SIGNAL_LINE = re.compile(r"\s+SG_\s")
#: Vector's holder of signals sent by no message: not a message (cantools leaves it out).
_INDEPENDENT = "VECTOR__INDEPENDENT_SIG_MSG"


def _check_all_read(path: Path, text: str, db: cantools.database.can.Database) -> None:
    """:class:`DbcError` naming the line of a message or signal statement in ``text`` that
    ``db`` lacks. cantools passes over a statement cut short at the end of the file (a DBC
    cut mid-copy loaded with its last message or signal missing, unsaid). Messages are
    matched by frame id and signals counted per message: names may differ (cantools takes
    a long name from its ``SystemMessageLongSymbol`` / ``SystemSignalLongSymbol``)."""
    signals = {(m.frame_id, m.is_extended_frame): len(m.signals) for m in db.messages}
    lines = text.splitlines()
    current: tuple[int, bool] | None = None
    seen: list[int] = []  # line numbers of the current message's signal statements

    def check_signals() -> None:
        if current is not None and len(seen) > signals[current]:
            raise DbcError(f"{path}: line {seen[-1]}: signal statement not read "
                           f"({printable(lines[seen[-1] - 1].strip(), 80)}); is the file cut "
                           "short?")

    for number, line in enumerate(lines, 1):
        if line.startswith("BO_ ") or line.strip() == "BO_":
            check_signals()
            message = _MESSAGE_LINE.match(line)
            current, seen = None, []
            if message is not None and message[2] == _INDEPENDENT:
                continue
            frame_id = int(message[1]) if message is not None else -1
            current = (frame_id & 0x1FFFFFFF, bool(frame_id & 0x80000000))
            if current not in signals:
                raise DbcError(f"{path}: line {number}: message statement not read "
                               f"({printable(line.strip(), 80)}); is the file cut short?")
        elif _SIGNAL_LINE.match(line) or line.strip() == "SG_":
            seen.append(number)
    check_signals()


def _binary_offset(data: bytes) -> tuple[int, int] | None:
    """(offset, byte) of the first control byte (other than tab, CR, LF, FF) in ``data``, or
    None for a text file."""
    match = re.search(rb"[\x00-\x08\x0b\x0e-\x1f\x7f]", data)
    return None if match is None else (match.start(), data[match.start()])


def unit_factor(unit: str | None, where: str) -> float:
    """Factor taking a speed in ``unit`` to m/s; :class:`DbcError` naming ``where`` if unknown."""
    key = (unit or "").replace(" ", "").lower()
    if key not in UNIT_TO_MPS:
        raise DbcError(
            f"{where}: speed unit {unit!r} is not one of {sorted(set(UNIT_TO_MPS))}; state it "
            f"in the signal spec as MSG.SIG:UNIT (e.g. {where}:km/h)")
    return UNIT_TO_MPS[key]


def parse_signal_specs(db: cantools.database.can.Database, specs: str | list[str] | None,
                       dbc_name: str = "DBC") -> list[SignalSpec]:
    """Resolve ``MSG.SIG[:UNIT][,MSG.SIG...]`` against ``db``.

    ``UNIT`` overrides the DBC's unit (needed where the DBC states none). ``None`` or an
    empty spec picks the rear wheels: a message with wheel-speed signals ending in RL and RR.
    """
    if specs is None or (isinstance(specs, str) and not specs.strip()):
        return default_rear_wheels(db, dbc_name)
    items = specs.split(",") if isinstance(specs, str) else list(specs)
    out: list[SignalSpec] = []
    for raw in (s.strip() for s in items):
        if not raw:
            continue
        name, _, unit_override = raw.partition(":")
        msg_name, dot, sig_name = name.partition(".")
        if not dot or not msg_name or not sig_name:
            raise DbcError(f"signal spec {raw!r}: expected MESSAGE.SIGNAL[:UNIT]")
        try:
            msg = db.get_message_by_name(msg_name)
        except KeyError:
            close = [m.name for m in db.messages if msg_name.lower() in m.name.lower()][:8]
            raise DbcError(f"{dbc_name}: no message {msg_name!r} (similar: {close})") from None
        try:
            sig = msg.get_signal_by_name(sig_name)
        except KeyError:
            names = [s.name for s in msg.signals]
            raise DbcError(f"{dbc_name}: message {msg_name} has no signal {sig_name!r} "
                           f"(it has {names})") from None
        unit = unit_override.strip() or (sig.unit or "")
        factor = unit_factor(unit, f"{msg.name}.{sig.name}")
        out.append(SignalSpec(msg.name, sig.name, unit, factor))
    if not out:
        raise DbcError(f"signal spec {specs!r} names no signal")
    return out


def default_rear_wheels(db: cantools.database.can.Database,
                        dbc_name: str = "DBC") -> list[SignalSpec]:
    """The rear-wheel speed signals of ``db`` (one message with both RL and RR), or an error."""
    found = []
    for msg in db.messages:
        left = [s for s in msg.signals
                if _WHEELISH.search(s.name.upper()) and _REAR_LEFT.search(s.name.upper())]
        right = [s for s in msg.signals
                 if _WHEELISH.search(s.name.upper()) and _REAR_RIGHT.search(s.name.upper())]
        if len(left) == 1 and len(right) == 1:
            found.append((msg, left[0], right[0]))
    if len(found) != 1:
        what = "no message" if not found else f"several messages ({[f[0].name for f in found]})"
        raise DbcError(f"{dbc_name}: {what} with rear wheel speeds (signals ending in RL and RR); "
                       "give --signals MSG.SIG[,MSG.SIG...]")
    msg, left, right = found[0]
    return [SignalSpec(msg.name, s.name, s.unit or "", unit_factor(s.unit, f"{msg.name}.{s.name}"))
            for s in (left, right)]


class MessageDecoder:
    """Decodes chosen signals of one DBC message from many payloads at once.

    ``decode(payloads)`` takes an (N, length) uint8 array and returns (N, n_signals) physical
    values (DBC units, before the unit conversion) and an (N,) mask of rows within the DBC's
    stated [min, max] ranges.
    """

    def __init__(self, message: cantools.database.can.Message, signal_names: list[str]):
        self.message = message
        self.length = int(message.length)
        self.signals = [message.get_signal_by_name(n) for n in signal_names]
        self.vectorised = self.length <= 8 and not message.is_multiplexed() and not any(
            s.is_float or s.multiplexer_ids for s in self.signals)
        # Bit layout per signal: (little-endian word?, LSB position in that word, length,
        # signed, scale, offset). Motorola start bits are the MSB in sawtooth numbering
        # (byte*8 + bit); in the big-endian word of the whole payload that is the position
        # 8*(length-1-byte) + bit.
        self._layout = []
        for sig in self.signals:
            if sig.byte_order == "little_endian":
                little, lsb = True, sig.start
            else:
                msb = 8 * (self.length - 1 - sig.start // 8) + sig.start % 8
                little, lsb = False, msb - sig.length + 1
            self._layout.append((little, lsb, sig.length, bool(sig.is_signed),
                                 float(sig.scale), float(sig.offset)))
        lo = [s.minimum for s in self.signals]
        hi = [s.maximum for s in self.signals]
        # A [0|0] range (common in DBCs) means "not stated": cantools reports None for it.
        stated = [a is not None and b is not None and a != b for a, b in zip(lo, hi, strict=True)]
        self._lo = np.array([a if ok else -np.inf for a, ok in zip(lo, stated, strict=True)])
        self._hi = np.array([b if ok else np.inf for b, ok in zip(hi, stated, strict=True)])
        self._lo_list, self._hi_list = self._lo.tolist(), self._hi.tolist()

    def decode(self, payloads: NDArray[np.uint8]) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
        payloads = np.asarray(payloads, dtype=np.uint8).reshape(-1, self.length)
        if self.vectorised:
            values = self._decode_bits(payloads)
        else:
            values = self._decode_cantools(payloads)
        ok = np.all(np.isfinite(values) & (values >= self._lo) & (values <= self._hi), axis=1)
        return values, ok

    def _decode_bits(self, payloads: NDArray[np.uint8]) -> NDArray[np.float64]:
        n, length = payloads.shape
        wide = payloads.astype(np.uint64)
        shifts = np.arange(length, dtype=np.uint64) * np.uint64(8)
        little = np.bitwise_or.reduce(wide << shifts, axis=1) if n else np.zeros(0, np.uint64)
        big = np.bitwise_or.reduce(wide << shifts[::-1], axis=1) if n else np.zeros(0, np.uint64)
        out = np.empty((n, len(self.signals)), dtype=np.float64)
        for j, (is_little, lsb, nbits, signed, scale, offset) in enumerate(self._layout):
            word = little if is_little else big
            raw = (word >> np.uint64(lsb)) & np.uint64((1 << nbits) - 1)
            value = raw.astype(np.int64)
            if signed:
                value = np.where(value >= 1 << (nbits - 1), value - (1 << nbits), value)
            out[:, j] = value * scale + offset
        return out

    def decode_one(self, data: bytes) -> list[float] | None:
        """Physical values of one payload (DBC units), or None if undecodable or out of the
        DBC's range: the scalar twin of :meth:`decode` for live buses (a few µs a frame)."""
        if not self.vectorised:
            values, ok = self.decode(np.frombuffer(data, dtype=np.uint8))
            return values[0].tolist() if ok[0] else None
        little = int.from_bytes(data, "little")
        big = int.from_bytes(data, "big")
        out = []
        for (is_little, lsb, nbits, signed, scale, offset), lo, hi in zip(
                self._layout, self._lo_list, self._hi_list, strict=True):
            raw = ((little if is_little else big) >> lsb) & ((1 << nbits) - 1)
            if signed and raw >= 1 << (nbits - 1):
                raw -= 1 << nbits
            value = raw * scale + offset
            if not lo <= value <= hi:
                return None
            out.append(value)
        return out

    def _decode_cantools(self, payloads: NDArray[np.uint8]) -> NDArray[np.float64]:
        out = np.full((len(payloads), len(self.signals)), np.nan)
        names = [s.name for s in self.signals]
        for i, row in enumerate(payloads):
            try:
                decoded = self.message.decode(bytes(row), decode_choices=False, scaling=True)
                out[i] = [float(decoded[n]) for n in names]
            except Exception:  # counted as a decode error by the caller (NaN row)
                continue
        return out
