"""Opening a recording: a :class:`RerunSink` writing to an .rrd file, to a viewer it spawns
and/or to a viewer at an address (:func:`open_sink`); the viewer address as a gRPC URL
(:func:`grpc_url`)."""

from __future__ import annotations

import socket
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any
from urllib.parse import urlsplit

from ..errors import InputError
from .rerun_sink import IMAGE_PERIOD_S, RerunSink


def open_sink(app_id: str, path: str | Path | None = None, spawn: bool = False,
              connect: str | None = None, image_every: int | None = None,
              jpeg_quality: int = 75, image_period_s: float = IMAGE_PERIOD_S,
              layout: str = "estimate") -> RerunSink | None:
    """A sink recording to the .rrd file ``path``, to a viewer it spawns (``spawn``) and/or to
    a viewer at ``connect`` (``host:port`` or a ``rerun+http://`` URL), any combination; None
    where none is asked for. ``image_every``: log every n-th frame's images (None: one every
    ``image_period_s`` seconds); ``jpeg_quality`` of the logged images; ``layout``: the
    viewer's (``rerun_blueprint.default_blueprint``)."""
    if not (path or spawn or connect):
        return None
    # rerun is imported when a recording is made: the CLI starts without it
    import rerun as rr

    sinks: list[Any] = []
    rec = rr.RecordingStream(app_id)
    if path:
        path = Path(path)
        if path.is_dir():
            raise InputError(f"--rerun {path}: is a folder; give a .rrd file name")
        path.parent.mkdir(parents=True, exist_ok=True)
        sinks.append(rr.FileSink(str(path)))
    if spawn:
        try:
            rr.spawn(connect=False, recording=rec)
        except Exception as exc:  # the viewer binary may be missing or fail to start
            raise InputError(f"--rerun-spawn: could not start the rerun viewer: {exc}") from exc
        sinks.append(rr.GrpcSink())
    if connect:
        url = grpc_url(connect)
        why = _unreachable(url)
        if why:
            # said once, here: rerun's own retries took 19 s and printed four log lines
            print(f"vipm-track: warning: --rerun-connect {connect}: no rerun viewer answers "
                  f"({why}); nothing is streamed to it", file=sys.stderr)
        else:
            sinks.append(rr.GrpcSink(url))
    if not sinks:
        return None
    rec.set_sinks(*sinks)
    return RerunSink(rec, image_every=image_every, jpeg_quality=jpeg_quality,
                     image_period_s=image_period_s, layout=layout)


def _unreachable(url: str, timeout_s: float = 2.0) -> str:
    """Why nothing listens at a viewer URL's host and port ("" where something does)."""
    parts = urlsplit(url)
    try:
        with socket.create_connection((parts.hostname or "127.0.0.1", parts.port or 9876),
                                      timeout=timeout_s):
            return ""
    except OSError as exc:
        return exc.strerror or str(exc) or type(exc).__name__


def grpc_url(address: str) -> str:
    """Viewer URL from ``--rerun-connect``: a full ``rerun+http://host:port/proxy`` URL, or
    ``host:port`` / ``host`` (port 9876)."""
    address = address.strip()
    if "://" in address:
        if not address.startswith(("rerun://", "rerun+http://", "rerun+https://")):
            raise InputError(f"--rerun-connect {address}: the scheme must be rerun+http(s)://")
        return address
    if not address:
        raise InputError("--rerun-connect needs host:port")
    host, _, port = address.partition(":")
    if port and not port.isdigit():
        raise InputError(f"--rerun-connect {address}: port must be a number")
    return f"rerun+http://{host or '127.0.0.1'}:{port or 9876}/proxy"


__all__: Sequence[str] = ["grpc_url", "open_sink"]
