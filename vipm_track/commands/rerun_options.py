"""The rerun flags of a command (``common.add_rerun_options``) turned into a sink: the
command-line face of ``sinks.rerun_open.open_sink``."""

from __future__ import annotations

import argparse
from typing import Any

from ..sinks.rerun_open import open_sink
from ..sinks.rerun_sink import RerunSink


def wants_rerun(args: argparse.Namespace) -> bool:
    """Whether the parsed rerun flags ask for a recording."""
    return bool(getattr(args, "rerun", None) or getattr(args, "rerun_spawn", False)
                or getattr(args, "rerun_connect", None))


def sink_from_args(args: argparse.Namespace, app_id: str, **options: Any) -> RerunSink | None:
    """The sink the ``--rerun OUT.rrd`` / ``--rerun-spawn`` / ``--rerun-connect ADDR`` flags ask
    for (any combination), or None. ``--rerun-image-every`` and ``--rerun-jpeg-quality`` are
    read where the parser has them; ``options`` override them."""
    every = getattr(args, "rerun_image_every", None)
    if getattr(args, "rerun_all_images", False):
        every = 1
    settings = {
        "image_every": every,
        "jpeg_quality": getattr(args, "rerun_jpeg_quality", 75),
        **options,
    }
    return open_sink(app_id, getattr(args, "rerun", None), getattr(args, "rerun_spawn", False),
                     getattr(args, "rerun_connect", None), **settings)
