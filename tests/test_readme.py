"""The README's results tables are exactly what the benchmarks last wrote."""

from __future__ import annotations

import importlib.util

from conftest import ROOT


def test_readme_results_tables_match_scripts_results():
    spec = importlib.util.spec_from_file_location(
        "update_readme", ROOT / "scripts" / "update_readme.py"
    )
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    readme = (ROOT / "README.md").read_text()
    assert module.update(readme) == readme, "run: python scripts/update_readme.py"
    assert readme.count("<!-- results:") >= 8
