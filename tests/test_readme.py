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


# --- numbers in the status prose -------------------------------------------------------------

RESULTS = ROOT / "scripts" / "results"


def _rows(path) -> list[list[str]]:
    """Cells of every Markdown table row of a results file."""
    return [[c.strip() for c in line.strip().strip("|").split("|")]
            for line in path.read_text().splitlines()
            if line.startswith("|") and not line.startswith("| ---")]


def _status(part: str) -> str:
    readme = (ROOT / "README.md").read_text()
    return next(line for line in readme.splitlines() if line.startswith(f"| {part} |"))


def _pct(cell: str) -> float:
    return float(cell.replace("%", "").replace("°", "").strip())


def test_kitti_status_quotes_the_results_files():
    rows = _rows(RESULTS / "kitti.md")
    row = _status("KITTI 07")
    ok = next(r for r in rows if r[0] == "frames with status ok")[1]  # "154/159 (96.9 %)"
    assert f"{ok.split()[0]} pairs ok ({ok.split('(')[1]}" in row
    yaw = next(r for r in rows if r[0] == "yaw-change error, median")[1]
    assert f"{yaw} median yaw error" in row
    n, mean, sd, lo, hi = next(r for r in rows if r[0].startswith("seeds × heights"))[1:6]
    assert f"**{mean} mean, sd {sd}, over {n} draws**" in row
    assert f"range {_pct(lo):.2f}–{_pct(hi):.2f} %" in row
    seeds = [r for r in rows if r[0].isdigit()]
    assert f"seed 0 (the CLI's default run) {seeds[0][2]}" in row
    p95 = [_pct(r[4]) for r in seeds]
    assert f"p95 {min(p95):.2f}–{max(p95):.2f} % over seeds 0–{len(seeds) - 1}" in row
    # the filters' rows of kitti_filters.md
    filters = {r[0].split(" (")[0]: r for r in _rows(RESULTS / "kitti_filters.md")}
    ekf, fixed, batch = filters["EKF"], filters["fixed-lag 2 s"], filters["batch"]
    assert f"EKF {ekf[2]}, p95 {ekf[4]}" in row
    med = sorted(_pct(r[2]) for r in (fixed, batch))
    p95s = sorted(_pct(r[4]) for r in (fixed, batch))
    assert f"{med[0]:.2f}–{med[1]:.2f} % median, p95 {p95s[0]:.2f}–{p95s[1]:.2f} %" in row
    pairs = filters["pairs"]
    assert f"(pairs {pairs[2]}, p95 {pairs[4]})" in row
    fl_mgp = filters["fixed-lag 2 s, motion given pose"]
    b_mgp = filters["batch, motion given pose"]
    assert f"{fl_mgp[2]} (fixed-lag 2 s) / {b_mgp[2]} (batch)" in row
    assert f"p95 {_pct(fl_mgp[4]):.2f} / {_pct(b_mgp[4]):.2f} %" in row


def test_poc_and_monitor_status_quote_the_results_files():
    poc = next(r for r in _rows(RESULTS / "bench_poc.md") if r[1] == "vipm_track.poc (batch)")
    row = _status("POC")
    assert f"{float(poc[2]):.3f} px RMSE" in row and f"{float(poc[5]):.2f} ms per 128²" in row
    rows = _rows(RESULTS / "bench_monitor.md")
    steps = [r for r in rows if r[0] == "shaking 0.2°" and r[1] in ("pitch step 0.5°",
                                                                      "roll step 0.5°")]
    medians = {r[2] for r in steps}
    p95 = sorted(float(r[3]) for r in steps)
    row = _status("monitor")
    assert len(medians) == 1 and f"0.5° step flagged in {medians.pop()} s median" in row
    assert f"/ {p95[0]}–{p95[-1]} s p95" in row
    clean = [r for r in rows if len(r) == 7 and r[1] in ("clean", "10 % outliers")]
    rates = sorted(float(r[4]) for r in clean)
    assert f"{rates[0]:.2f}–{rates[-1]:.2f} false alarms per hour" in row
    road = next(r for r in rows if r[:2] == ["road tilt", "road model 0.5° / 2 s"]
                and len(r) == 6)
    assert f"raised {road[3]} false alarm in {road[2]} h" in row
