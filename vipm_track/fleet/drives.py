"""The drives of a fleet: one subfolder per drive, or a manifest CSV listing them.

A drive folder holds its recording — ``images/`` (timestamps from ``times.txt``), a video,
or a bag (``.bag``, ``.mcap``, ``.db3`` or a rosbag2 folder) — its intrinsics
(``camera.yaml`` or ``calib.txt``; a bag's ``camera_info`` topic otherwise), its
``nominal.yaml`` (``pitch_deg``, ``roll_deg``, ``height_m``, as ``vipm-track monitor``
reads) and optionally a speed (``speed.csv``, or a CAN log with a ``.dbc`` beside it; a
log without a ``.dbc``, such as ``notes.log``, is left alone where there is a ``speed.csv``)
and a ``drive.yaml`` with ``vehicle`` (which vehicle drove it) and ``started`` (sorts the
vehicle's drives in time). A manifest CSV has one row per drive with the columns of
:data:`MANIFEST_COLUMNS`, paths relative to the manifest.
"""

from __future__ import annotations

import csv
import hashlib
from dataclasses import dataclass, fields, replace
from pathlib import Path

from ..bag_source import BAG_SUFFIXES, is_bag
from ..errors import InputError, InvalidYaml, os_error_line, parse_yaml, printable
from ..frame_rates import fps_problem
from ..sinks.fleet_report import started_instant
from ..sources import IMAGE_SUFFIXES

VIDEO_SUFFIXES: frozenset[str] = frozenset({".mp4", ".avi", ".mkv", ".mov", ".webm", ".m4v"})
CAN_SUFFIXES: frozenset[str] = frozenset({".log", ".asc", ".blf", ".trc", ".mf4"})
#: manifest columns; ``drive`` and ``nominal`` and one of images / video / bag are required
MANIFEST_COLUMNS: tuple[str, ...] = ("drive", "images", "video", "bag", "camera", "nominal",
                                     "speed_csv", "can", "dbc", "vehicle", "started", "fps")


@dataclass(frozen=True)
class DriveSpec:
    """Where one drive's inputs are. ``problem`` says why the drive cannot run (its row in
    the fleet summary then carries it and the other drives go on)."""

    drive: str
    images: Path | None = None
    video: Path | None = None
    bag: Path | None = None
    camera: Path | None = None
    nominal: Path | None = None
    speed_csv: Path | None = None
    can: Path | None = None
    dbc: Path | None = None
    vehicle: str = ""
    started: str = ""
    fps: float | None = None
    problem: str = ""

    def input_files(self) -> list[Path]:
        """Every file this drive reads, sorted (a folder's files, recursively)."""
        files: list[Path] = []
        for f in fields(self):
            value = getattr(self, f.name)
            if isinstance(value, Path):
                files += sorted(p for p in value.rglob("*") if p.is_file()) if value.is_dir() \
                    else [value]
                if f.name == "images" and (value.parent / "times.txt").is_file():
                    files.append(value.parent / "times.txt")
        return sorted(set(files))

    def absolute(self) -> DriveSpec:
        """This drive with every path absolute: a Dask worker started in another folder
        reads the same files."""
        return replace(self, **{f.name: getattr(self, f.name).absolute() for f in fields(self)
                                if isinstance(getattr(self, f.name), Path)})

    def input_hash(self, settings: str) -> str:
        """BLAKE2b of this drive's input files (names and contents) and of ``settings``:
        what decides whether an earlier run's outputs still hold."""
        digest = hashlib.blake2b(digest_size=16)
        digest.update(settings.encode())
        for f in fields(self):
            if f.name not in ("images", "video", "bag", "camera", "nominal", "speed_csv",
                              "can", "dbc"):
                digest.update(f"{f.name}={getattr(self, f.name)}".encode())
        for path in self.input_files():
            digest.update(path.name.encode())
            with path.open("rb") as fh:
                while block := fh.read(1 << 20):
                    digest.update(block)
        return digest.hexdigest()


def find_drives(drives: str | Path) -> list[DriveSpec]:
    """The drives of a folder (one subfolder each, sorted by name) or of a manifest CSV.
    InputError where ``drives`` is neither or holds no drive."""
    path = Path(drives)
    if path.is_file():
        specs = read_manifest(path)
    elif path.is_dir():
        specs = [drive_in_folder(p) for p in sorted(path.iterdir()) if p.is_dir()
                 and not p.name.startswith((".", "_"))]
    else:
        raise InputError(f"{path}: not found (give a folder of drives or a manifest CSV)")
    if not specs:
        raise InputError(f"{path}: no drives (a folder with one subfolder per drive, or a "
                         "manifest CSV)")
    names = [s.drive for s in specs]
    repeated = sorted({n for n in names if names.count(n) > 1})
    if repeated:
        raise InputError(f"{path}: drive names repeat: {', '.join(repeated)}")
    return specs


def drive_in_folder(folder: Path) -> DriveSpec:
    """The drive of one folder (see the module doc); its ``problem`` says what is missing,
    or why its ``drive.yaml`` cannot be read."""
    files = sorted(p for p in folder.iterdir() if not p.name.startswith("."))

    def first(suffixes: frozenset[str] | tuple[str, ...], *names: str) -> Path | None:
        return next((p for p in files if p.is_file() and (p.suffix.lower() in suffixes
                                                           or p.name in names)), None)

    try:
        info, bad_info = _drive_yaml(folder / "drive.yaml"), ""
    except InputError as exc:  # this drive's problem: the other drives go on
        info, bad_info = {}, str(exc)
    images = folder / "images" if (folder / "images").is_dir() else None
    bag = folder if is_bag(folder) else next((p for p in files if is_bag(p)), None)
    video = first(VIDEO_SUFFIXES)
    camera = first(frozenset(), "camera.yaml", "camera.yml", "camera_info.yaml", "calib.txt")
    speed_csv = folder / "speed.csv" if (folder / "speed.csv").is_file() else None
    can, dbc = first(CAN_SUFFIXES), first(frozenset({".dbc"}))
    if dbc is None and speed_csv is not None:
        can = None  # no DBC to decode it: a stray log (notes.log) beside the drive's speed
    spec = DriveSpec(
        drive=folder.name, images=images, video=video, bag=bag, camera=camera,
        nominal=folder / "nominal.yaml" if (folder / "nominal.yaml").is_file() else None,
        speed_csv=speed_csv, can=can, dbc=dbc if can else None,
        vehicle=str(info.get("vehicle", "")), started=str(info.get("started", "")),
    )
    return _with_problem(spec, bad_info) if bad_info else _checked(spec, str(folder))


def _drive_yaml(path: Path) -> dict:
    """``vehicle`` and ``started`` of a drive.yaml ({} where there is none); InputError
    naming the file (and line and column) where it cannot be read or holds anything else."""
    if not path.is_file():
        return {}
    try:
        doc = parse_yaml(path.read_text(encoding="utf-8"))
    except OSError as exc:
        raise InputError(os_error_line(exc, str(path))) from None
    except UnicodeDecodeError as exc:
        raise InputError(f"{path}: not a text file (byte {exc.start}: {exc.reason})") from None
    except InvalidYaml as exc:
        raise InputError(f"{path}: {exc}") from None
    if not isinstance(doc, dict):
        raise InputError(f"{path}: expected a mapping with 'vehicle' and/or 'started'")
    unknown = sorted(str(k) for k in set(doc) - {"vehicle", "started"})
    if unknown:
        raise InputError(f"{path}: unknown key(s) {unknown}; expected 'vehicle' and/or "
                         "'started'")
    if "started" in doc:
        check_started(doc["started"], str(path))
    return doc


def check_started(value: object, where: str) -> None:
    """InputError (at ``where``) for a ``started`` that is no ISO 8601 time: the report
    orders a vehicle's drives by it, which it could only do as text."""
    if started_instant(str(value)) is None:
        raise InputError(f"{where}: started {printable(str(value), 60)!r} is no ISO 8601 date "
                         "or time (e.g. 2024-05-01 or 2024-05-01T09:00:00+02:00)")


def _checked(spec: DriveSpec, where: str) -> DriveSpec:
    """``spec`` with ``problem`` set where it cannot run."""
    recordings = [n for n in ("images", "video", "bag") if getattr(spec, n) is not None]
    problem = ""
    if not recordings:
        problem = (f"{where}: no recording (images/, a video, or a bag: "
                   f"{', '.join(BAG_SUFFIXES)} or a rosbag2 folder)")
    elif len(recordings) > 1:
        problem = f"{where}: several recordings ({', '.join(recordings)}); keep one"
    elif spec.nominal is None:
        problem = f"{where}: no nominal.yaml (pitch_deg, roll_deg, height_m)"
    elif spec.camera is None and spec.bag is None:
        problem = f"{where}: no camera.yaml or calib.txt"
    elif spec.can is not None and spec.dbc is None:
        problem = f"{where}: CAN log {spec.can.name} without a .dbc to decode it"
    images = spec.images
    if images is not None and images.is_dir() and not any(
            p.suffix.lower() in IMAGE_SUFFIXES for p in images.iterdir()):
        problem = problem or f"{spec.images}: no images"
    return _with_problem(spec, problem)


def _with_problem(spec: DriveSpec, problem: str) -> DriveSpec:
    return DriveSpec(**{**{f.name: getattr(spec, f.name) for f in fields(spec)},
                        "problem": problem})


def read_manifest(path: Path) -> list[DriveSpec]:
    """The drives a manifest CSV lists (header row of :data:`MANIFEST_COLUMNS`, any order,
    empty cells for what a drive lacks; paths relative to the manifest). InputError naming
    the file, line and column for an unknown column, a missing drive name or a bad fps."""
    try:
        text = path.read_text(encoding="utf-8-sig")  # (a BOM: a spreadsheet's CSV)
    except UnicodeDecodeError as exc:
        raise InputError(f"{path}: not a text file (byte {exc.start}); a manifest is CSV") \
            from None
    rows = list(csv.reader(text.splitlines()))
    if not rows:
        raise InputError(f"{path}: empty manifest; expected a header with "
                         f"{', '.join(MANIFEST_COLUMNS)}")
    header = [h.strip() for h in rows[0]]
    unknown = [h for h in header if h not in MANIFEST_COLUMNS]
    if unknown or "drive" not in header:
        raise InputError(f"{path}: line 1: unknown column(s) {unknown or ''} or no 'drive'; "
                         f"expected {', '.join(MANIFEST_COLUMNS)}")
    specs = []
    for lineno, cells in enumerate(rows[1:], start=2):
        if not any(c.strip() for c in cells):
            continue
        if len(cells) != len(header):
            raise InputError(f"{path}: line {lineno}: {len(cells)} cells, the header has "
                             f"{len(header)}")
        row = {h: c.strip() for h, c in zip(header, cells, strict=True)}
        if not row["drive"] or "/" in row["drive"] or row["drive"].startswith("."):
            raise InputError(f"{path}: line {lineno}: column drive: a name without '/' is "
                             f"needed, got {printable(row['drive'], 60)!r}")
        fps = None
        if row.get("fps"):
            try:
                fps = float(row["fps"])
            except ValueError:
                fps = float("nan")
            if problem := fps_problem(fps):
                raise InputError(f"{path}: line {lineno}: column fps must be {problem} "
                                 f"({printable(row['fps'], 60)!r})")
        if row.get("started"):
            check_started(row["started"], f"{path}: line {lineno}: column started")
        paths = {k: (path.parent / v) for k, v in row.items()
                 if v and k in ("images", "video", "bag", "camera", "nominal", "speed_csv",
                                "can", "dbc")}
        missing = [f"{k} {p}" for k, p in paths.items() if not p.exists()]
        spec = DriveSpec(drive=row["drive"], vehicle=row.get("vehicle", ""),
                         started=row.get("started", ""), fps=fps, **paths)
        if missing:
            spec = _with_problem(spec, f"{path}: line {lineno}: not found: "
                                 + ", ".join(missing))
        else:
            spec = _checked(spec, f"{path}: line {lineno}")
        specs.append(spec)
    return specs
