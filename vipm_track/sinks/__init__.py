"""Sinks: where results go besides the per-frame tables (rerun dashboards, plot reports).

``rerun_sink`` logs live runs to a rerun recording / viewer; ``report`` turns a finished
per-frame table (and optional ground truth) into PNG plots and a Markdown summary. Both
import their heavy dependency (rerun, matplotlib) only when used.
"""

from __future__ import annotations

__all__ = ["report", "rerun_sink"]
