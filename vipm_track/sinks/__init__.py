"""Sinks: where results go besides the per-frame tables (rerun dashboards, plot reports).

``rerun_sink`` logs a run to a rerun recording / viewer (``rerun_open`` opens one,
``rerun_sequence`` and ``rerun_filters`` feed it sequence, filter and monitor runs,
``rerun_blueprint`` lays out its views, ``rerun_read`` reads a recording back); ``report``
turns a finished per-frame table (and optional ground truth) into PNG plots and a Markdown
summary. Both import their heavy dependency (rerun, matplotlib) only when used.
"""

from __future__ import annotations

__all__ = [
    "report",
    "rerun_blueprint",
    "rerun_filters",
    "rerun_open",
    "rerun_read",
    "rerun_sequence",
    "rerun_sink",
]
