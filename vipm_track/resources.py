"""Paths to the embedded default data (``data/`` in the repository, ``vipm_track.data`` when
installed as a wheel)."""

from __future__ import annotations

from importlib import resources
from pathlib import Path

_REPO_DATA = Path(__file__).resolve().parents[1] / "data"


def data_path(*parts: str) -> Path:
    """Path of a file or folder under the embedded ``data/`` folder.

    Prefers the repository's ``data/`` (a source checkout), else the installed
    ``vipm_track.data`` package. Raises FileNotFoundError naming both places."""
    candidate = _REPO_DATA.joinpath(*parts)
    if candidate.exists():
        return candidate
    try:
        node = resources.files("vipm_track.data")
    except ModuleNotFoundError:
        node = None
    if node is not None:
        for part in parts:
            node = node.joinpath(part)
        installed = Path(str(node))
        if installed.exists():
            return installed
    raise FileNotFoundError(
        f"embedded data '{'/'.join(parts)}' not found in {_REPO_DATA} nor in the installed "
        "vipm_track.data package"
    )
