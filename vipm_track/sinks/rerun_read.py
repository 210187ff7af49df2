"""Reading a recording back: what an .rrd file holds, entity by entity."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from ..errors import InputError


def recording_entities(path: str | Path, static: bool = False) -> dict[str, int]:
    """Rows per entity path of the recording in an .rrd file, read back with rerun's chunk
    reader: what a test or a user checks a recording holds. Only rows on the timelines,
    unless ``static`` (then only the static rows: styles, properties)."""
    # rerun is imported when a recording is read: importing this module stays cheap
    from rerun.chunk import RrdReader

    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: recording not found")
    counts: dict[str, int] = {}
    for chunk in RrdReader(path).stream():
        if chunk.is_static != static:
            continue
        counts[chunk.entity_path] = counts.get(chunk.entity_path, 0) + chunk.num_rows
    return counts


__all__: Sequence[str] = ["recording_entities"]
