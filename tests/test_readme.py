"""The README and docs/ say what is true: short README, links that resolve inside the repository,
results tables that are what the benchmarks last wrote, status numbers that quote them, and
set-up and tour commands that exist."""

from __future__ import annotations

import importlib
import re
import shlex
import tomllib

import pytest
from conftest import ROOT, load_script

README = ROOT / "README.md"
DOCS = ROOT / "docs"
RESULTS = ROOT / "scripts" / "results"
LINK = re.compile(r"\[[^\]]*\]\(([^)\s]+)\)")


def _load_update_docs():
    return load_script("update_docs")


def test_readme_is_short():
    lines = README.read_text().splitlines()
    assert len(lines) <= 200, f"README.md has {len(lines)} lines; move detail into docs/"


@pytest.mark.parametrize("page", [README, *sorted(DOCS.glob("*.md"))], ids=lambda p: p.name)
def test_links_resolve_inside_the_repository(page):
    root = ROOT.resolve()
    bad = []
    for target in LINK.findall(page.read_text()):
        if re.match(r"[a-z]+:", target) or target.startswith("#"):
            continue  # a web address or an anchor on the same page
        path = (page.parent / target.split("#")[0]).resolve()
        if not path.is_relative_to(root):
            bad.append(f"{target} (outside the repository)")
        elif not path.exists():
            bad.append(f"{target} (no such file)")
    assert not bad, f"{page.relative_to(ROOT)}: {bad}"


def test_docs_results_are_what_the_benchmarks_last_wrote():
    module = _load_update_docs()
    page = (DOCS / "results.md").read_text()
    assert module.update(page) == page, "run: python scripts/update_docs.py"
    assert page.count("<!-- results:") >= 20
    assert "<!-- results:index -->" in page


def test_conventions_copy_agrees_with_the_shared_one():
    shared = ROOT.parent / "shared" / "CONVENTIONS.md"
    if not shared.is_file():
        pytest.skip(f"{shared} not present")
    ours = (DOCS / "conventions.md").read_text().splitlines()
    missing = [line for line in shared.read_text().splitlines()[1:] if line and line not in ours]
    assert not missing, f"docs/conventions.md differs from {shared}: {missing[:3]}"


# --- the set-up and tour commands -------------------------------------------------------------

def _commands(text: str) -> list[str]:
    """The commands of the indented code blocks, continuation lines joined, comments dropped."""
    out, current = [], ""
    for line in text.splitlines():
        if not line.startswith("    "):
            current = ""
            continue
        part = line.strip().split("  #")[0]
        if part.startswith("#"):
            continue
        current += part.removesuffix("\\").strip() + " "
        if not part.endswith("\\"):
            out.append(current.strip())
            current = ""
    return out


def test_readme_set_up_commands_are_what_ci_runs():
    readme = _commands(README.read_text())
    assert "pip install . && vipm-track demo --out out/demo" in readme
    ci = (ROOT / ".ci" / "run").read_text().strip().splitlines()[-1].strip()
    assert ci == 'pip install ".[test]" && python -m pytest', f".ci/run runs {ci!r}"
    assert ci in readme, "the README's test command is not the one .ci/run runs"


def _parser():
    script = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["scripts"]
    module = importlib.import_module(script["vipm-track"].split(":")[0])
    return module.build_parser()


def test_documented_vipm_track_commands_parse():
    parser = _parser()
    pages = [README, DOCS / "usage.md", DOCS / "demo.md"]
    lines = [c for p in pages for c in _commands(p.read_text())]
    calls = [seg.strip() for c in lines for seg in c.split("&&")
             if seg.strip().startswith("vipm-track ")]
    assert len(calls) >= 20
    for call in calls:
        try:
            parser.parse_args(shlex.split(call)[1:])
        except SystemExit:
            pytest.fail(f"documented command does not parse: {call}")


def test_readme_tour_has_the_five_steps():
    calls = [c.split()[1] for c in _commands(README.read_text()) if c.startswith("vipm-track ")]
    assert calls == ["simulate", "estimate", "smooth", "monitor", "report"]


# --- numbers in the status table ----------------------------------------------------------------

def _rows(path) -> list[list[str]]:
    """Cells of every Markdown table row of a results file."""
    return _text_rows(path.read_text())


def _text_rows(text: str) -> list[list[str]]:
    """Cells of every Markdown table row of ``text``."""
    return [[c.strip() for c in line.strip().strip("|").split("|")]
            for line in text.splitlines()
            if line.startswith("|") and not line.startswith("| ---")]


def _status(part: str) -> str:
    """The README status row of a part: 'metric | target | now'."""
    row = next((line for line in README.read_text().splitlines()
                if line.startswith(f"| {part} |")), None)
    assert row is not None, f"no status row for {part!r}"
    return row


def _num(cell: str) -> float:
    return float(re.sub(r"[^0-9.+-]", "", cell.split("(")[0].split("/")[0].split()[0]))


def _range(values, fmt: str) -> str:
    lo, hi = min(values), max(values)
    return f"{lo:{fmt}}" if f"{lo:{fmt}}" == f"{hi:{fmt}}" else f"{lo:{fmt}}–{hi:{fmt}}"


def test_status_rows_are_short():
    table = [line for line in README.read_text().splitlines() if line.startswith("| ")]
    assert len(table) >= 15
    assert max(len(line) for line in table) <= 160


def test_front_end_status_quotes_the_results_files():
    poc = next(r for r in _rows(RESULTS / "bench_poc.md") if r[1] == "vipm_track.poc (batch)")
    assert f"| {float(poc[2]):.3f} px; {float(poc[5]):.2f} ms |" in _status("POC")
    acc = {(r[0], r[1]): r for r in _rows(RESULTS / "bench_accuracy.md")}
    static = [acc["Static", q][3].split()[0] for q in ("Pitch [deg]", "Roll [deg]", "Dist. [mm]")]
    assert f"| {static[0]}° / {static[1]}° / {static[2]} mm |" in _status("two-frame estimator")
    weak = "Weak texture (corridor + highlights)"
    pitch, roll = (acc[weak, q][3].split()[0] for q in ("Pitch [deg]", "Roll [deg]"))
    assert f"| {pitch}° / {roll}° |" in _status("weak texture")
    rows = [r for r in _rows(RESULTS / "bench_camera_pitch.md") if r[0] in ("car", "cart")]
    ok = sum(int(r[3].split("/")[0]) for r in rows)
    total = sum(int(r[3].split("/")[1]) for r in rows)
    worst = max(float(r[4]) for r in rows)
    assert f"| {ok}/{total}, pitch within {worst:.3f}° |" in _status("camera pitch")
    rows = [r for r in _rows(RESULTS / "bench_motion_range.md")
            if r[0] in ("car", "cart") and len(r) == 16]  # not the wrong-ok-over-seeds table
    seeds = [r for r in _rows(RESULTS / "bench_motion_range.md") if len(r) == 8
             and r[0] == "cart"]
    wrong = sum(int(r[5]) + int(r[7]) for r in seeds)
    assert f"; {wrong} wrong `ok` over 5 seeds |" in _status("motion per frame")
    # (a row beyond the range may have no ok pair at all: "exit 1")
    most = {p: max(float(r[4]) for r in rows if r[0] == p and "/" in r[6]
                   and r[6].split("/")[0] == r[6].split("/")[1]) for p in ("cart", "car")}
    assert f"| cart {most['cart']:.2f} m, car {most['car']:.2f} m;" in _status("motion per frame")
    rows = [r for r in _rows(RESULTS / "bench_rolling_shutter.md")
            if r[0] in ("car", "cart") and float(r[3]) > 0]
    pitch = max(float(r[9].split("/")[1]) for r in rows)
    dist = max(float(r[10].split("/")[1]) for r in rows)
    assert f"| ≤ {pitch:.3f}° / ≤ {dist:.2f} % |" in _status("rolling shutter")
    blurred = [r for r in _rows(RESULTS / "bench_blur.md") if len(r) == 9 and r[1] == "0.3"]
    ours = [r for r in blurred if r[2] != "plain"]
    plain = [r for r in blurred if r[2] == "plain"]
    flagged = [sum(r[8] != "never" for r in rows) for rows in (ours, plain)]
    assert (f"| {sum(int(r[5]) for r in ours)} ({_range([int(r[5]) for r in plain], 'd')}); "
            f"{flagged[0]} of {len(ours)} ({flagged[1]} of {len(plain)}) |"
            in _status("motion blur"))
    shutter = [r for r in _rows(RESULTS / "bench_shutter.md") if len(r) == 10]
    shaking = [r for r in shutter if r[0].startswith("cart shaking")]
    z = {m: [float(r[8].split("/")[0]) for r in shaking if (r[3] == "without") == (m == "without")]
         for m in ("with", "without")}
    knock = [r[9].split()[1] for r in shutter
             if r[0].startswith("cart knock") and r[3] != "without"]
    missed = all(r[9] == "missed" for r in shutter
                 if r[0].startswith("cart knock") and r[3] == "without")
    assert (f"| {_range(z['with'], '.2f')} ({_range(z['without'], '.1f')}); "
            f"{_range([float(k) for k in knock], '.1f')} s ({'missed' if missed else '?'}) |"
            in _status("shutter + shaking"))
    bound = {r[2]: r for r in _rows(RESULTS / "bench_motion_bound.md") if r[0] == "**all**"}
    rejected, wrong_rejected = re.fullmatch(r"(\d+) \((\d+) wrong\)",
                                            bound["default (10 m/s²)"][6]).groups()
    assert (f"| {bound['default (10 m/s²)'][4]} ({bound['--max-acceleration inf'][4]} without "
            f"the bound); {int(rejected) - int(wrong_rejected)} |"
            in _status("motion between pairs"))
    par = {(r[0], r[1]): r for r in _rows(RESULTS / "bench_parallel.md")}
    two = [par[p, "chunks of 60, 2 processes"][4] for p in ("cart", "car")]
    assert f"| {two[0]} cart, {two[1]} car |" in _status("long recordings")


def test_kitti_status_quotes_the_results_files():
    rows = _rows(RESULTS / "kitti.md")
    row = _status("KITTI 07")
    ok = next(r for r in rows if r[0] == "frames with status ok")[1]  # "154/159 (96.9 %)"
    yaw = next(r for r in rows if r[0] == "yaw-change error, median")[1]
    n, mean, _sd, lo, hi = next(r for r in rows if r[0].startswith("seeds × heights"))[1:6]
    share = ok.split("(")[1].rstrip(")")
    assert f"| {share}; {mean} ({n} draws, {_num(lo):.2f}–{hi}); {yaw} |" in row
    filters = {r[0].split(" (")[0]: r for r in _rows(RESULTS / "kitti_filters.md")}
    batch, pairs = filters["batch"], filters["pairs"]
    assert (f"| {batch[2]} / {batch[4]} (pairs {pairs[2]} / {pairs[4]}) |"
            in _status("KITTI 07 smoothed"))


def test_filter_status_quotes_the_results_files():
    rows = _rows(RESULTS / "bench_filters.md")
    ekf = [r for r in rows if len(r) == 13 and r[1] == "ekf"]
    angles = [float(r[c]) for r in ekf for c in (2, 3)]
    heights = [float(r[6]) for r in ekf if "speed" in r[0]]
    assert f"| {_range(angles, '.3f')}°; {_range(heights, '.2f')} % |" in _status("EKF")
    ratios = [r for r in rows if len(r) == 11 and r[0] != "scenario"]

    def ratio(method):
        return _range([_num(r[c]) for r in ratios if r[1] == method for c in (6, 7)], ".2f")

    assert f"| {ratio('batch')} / {ratio('fixed-lag 2 s')} |" in _status("smoother")
    speed = {r[0]: r[3] for r in _rows(RESULTS / "bench_smoother.md")}
    assert f"| {speed['batch']} / {speed['fixed-lag 2 s']} |" in _status("smoother speed")


def test_monitor_status_quotes_the_results_files():
    rows = _rows(RESULTS / "bench_monitor.md")
    steps = [r for r in rows if r[0] == "shaking 0.2°" and r[1] in ("pitch step 0.5°",
                                                                      "roll step 0.5°")]
    medians = [float(r[2]) for r in steps]
    p95 = [float(r[3]) for r in steps]
    clean = [r for r in rows if len(r) == 7 and r[1] in ("clean", "10 % outliers")]
    rates = [float(r[4]) for r in clean]
    assert (f"| {_range(medians, '.1f')} s / {_range(p95, '.1f')} s; {_range(rates, '.2f')} "
            "per h |" in _status("monitor"))
    kitti = _rows(RESULTS / "kitti_monitor.md")
    flat = [r for r in kitti if r[1] == "flat (default)"]
    road = [r for r in kitti if r[1] == "road 0.5° / 2 s"]
    assert road and all(set(r[2].split(", ")) == {"never"} for r in road)
    drifting = [float(r[3].rstrip(" %")) for r in flat]
    assert (f"| RECALIBRATE {flat[0][2]} (DRIFTING {_range(drifting, '.0f')} %); never |"
            in _status("monitor on roads"))
    verdicts = _rows(RESULTS / "bench_verdicts.md")
    monitored = [r for r in verdicts if len(r) == 16]
    knock = [float(x) for r in monitored if r[0].startswith(("cart knock", "car knock"))
             for x in r[11].split(" / ")]
    hours = next(r for r in verdicts if len(r) == 5 and r[0].startswith("cart, simulated"))
    wrong = [r[15].split(" (")[0] for r in monitored if r[15][:1].isdigit()]
    assert (f"| {_range(knock, '.1f')} s; {hours[2]} in {hours[1]} h; "
            f"{sum(int(n) for n in wrong)} |" in _status("verdicts"))


def test_mount_steps_status_quotes_the_results_file():
    rows = [r for r in _rows(RESULTS / "bench_mount_steps.md") if len(r) == 8
            and r[0] != "drive"]
    knocks = [r for r in rows if "knock" in r[0]]
    found = sum(int(r[1].split("/")[0]) for r in knocks)
    total = sum(int(r[1].split("/")[1]) for r in knocks)
    cover = [float(x) for r in knocks + [r for r in rows if "drift" in r[0]]
             for x in r[5].split(" / ")]
    false = sum(int(r[2]) for r in rows) + sum(int(r[3]) for r in rows if "drift" not in r[0])
    assert (f"| {found}/{total}; {_range(cover, '.0f')} %; {false} |"
            in _status("knocks, creeping mounts"))


def test_heave_status_quotes_the_results_file():
    rows = [r for r in _rows(RESULTS / "bench_heave.md") if len(r) == 8 and r[0] != "drive"]

    def shares(profile: str, col: int) -> list[float]:
        return [float(r[col].split(" / ")[1]) for r in rows if profile in r[0]]

    now = f"{_range(shares('shaking', 3), '.0f')} % / {_range(shares('height', 3), '.0f')} %"
    before = f"{_range(shares('shaking', 4), '.0f')} % / {_range(shares('height', 4), '.0f')} %"
    assert f"| {now} ({before}) |" in _status("frame height σ")
    summaries = [r for r in _rows(RESULTS / "bench_heave.md") if len(r) == 4
                 and "height" in r[0]]
    held = [[int(c.split(" / ")[2].split(" of ")[i]) for r in summaries for c in r[2:]]
            for i in (0, 1)]
    total = sum(held[1]) // 2
    assert (f"| {sum(held[0][::2])} of {total} ({sum(held[0][1::2])} of {total}) |"
            in _status("drive height"))


def test_other_status_rows_quote_the_results_files():
    can = {r[0]: r[1] for r in _rows(RESULTS / "bench_can.md")}
    decode = can["decode 100 k WHEEL_SPEEDS frames (4 signals), batch (numpy bit decode)"]
    gnss = can["same, tyre scale 1.0095 fitted on the first 30 s, checked on the last 30 s"]
    assert f"| {decode}; {gnss} |" in _status("CAN")
    rows = [r for r in _rows(RESULTS / "bench_clock_offset.md") if len(r) == 12
            and r[0] in ("car", "cart")]
    drives = sum(int(r[3].split("/")[1]) for r in rows)
    wrong = sum(int(r[5]) for r in rows)
    rms = [float(r[6]) for r in rows]
    assert f"| {wrong} of {drives}; {_range(rms, '.1f')} ms |" in _status("clock offset")
    rerun = [r for r in _rows(RESULTS / "bench_rerun.md") if len(r) == 7 and r[0] != "preset"]
    hour = [float(r[3]) for r in _rows(RESULTS / "bench_rerun.md")
            if len(r) == 4 and r[1].startswith("default")]
    assert (f"| {_range([float(r[5]) for r in rerun], '.1f')} %; {_range(hour, '.2f')} GB |"
            in _status("dashboards"))
    bite = (RESULTS / "check_tests_bite.md").read_text()
    caught, total = re.search(r"(\d+) of (\d+) mutants caught", bite).groups()
    assert f"| {caught} of {total} |" in _status("tests")
    rows_text, filters_text = (RESULTS / "bench_traffic.md").read_text().split(
        "The filters on them", 1)
    traffic = [r for r in _text_rows(rows_text) if len(r) == 19 and r[0] != "run"]
    filtered = [r for r in _text_rows(filters_text) if len(r) == 17 and r[0] != "run"]
    def kitti_rows(rows: list[list[str]]) -> list[list[str]]:
        """KITTI 07's rows without --pitch, one per subset seed (each a draw)."""
        return [r for r in rows if r[0].startswith("KITTI 07") and "no --pitch" in r[0]]

    def cells(rows: list[list[str]], column: int, fmt: str) -> str:
        values = [float(r[column]) for r in rows]
        return _range([int(v) for v in values] if fmt == "d" else values, fmt)

    renders = [r for r in traffic if "seed" in r[0] and "no --pitch" in r[0]
               and not r[0].startswith("KITTI")]
    kitti = kitti_rows(traffic)
    assert len(kitti) >= 3
    tracked = [int(r[1]) for r in filtered]
    assert (f"| {cells(renders, 2, 'd')} ({cells(renders, 3, 'd')} > 3σ), "
            f"{cells(kitti, 2, 'd')} ({cells(kitti, 3, 'd')}); {_range(tracked, 'd')}; "
            f"{cells(kitti, 5, '.2f')} / {cells(kitti, 6, '.2f')} |"
            in _status("traffic, forward camera"))
    given = [r for r in filtered if "seed" in r[0] and not r[0].startswith("KITTI")]
    kitti_filtered = kitti_rows(filtered)
    assert (f"| {cells(renders, 11, '.2f')} / {cells(renders, 12, '.1f')} %; "
            f"{cells(kitti, 11, '.2f')} / {cells(kitti, 12, '.1f')} % |"
            in _status("traffic, distance"))
    assert (f"| {cells(given, 14, '.2f')} / {cells(given, 15, '.1f')} %; "
            f"{cells(kitti_filtered, 14, '.2f')} / {cells(kitti_filtered, 15, '.1f')} % |"
            in _status("traffic, distance smoothed"))
    assert (f"| {cells(given, 9, '.2f')} / {cells(given, 10, '.2f')}; "
            f"{cells(kitti_filtered, 9, '.2f')} / {cells(kitti_filtered, 10, '.2f')} |"
            in _status("traffic, filter σ"))
    rows_text, filters_text = (RESULTS / "bench_traffic_kitti_rig.md").read_text().split(
        "The filters on them", 1)
    kitti_rig = [r for r in _text_rows(rows_text) if len(r) == 19 and r[0] != "run"]
    smoothed = [int(r[5]) for r in _text_rows(filters_text) if len(r) == 17 and r[0] != "run"]
    assert (f"| {cells(kitti_rig, 2, 'd')} ({cells(kitti_rig, 3, 'd')}); "
            f"{_range(smoothed, 'd')} |" in _status("traffic, KITTI's camera"))
    ours = next(r for r in _rows(RESULTS / "bench_realtime.md") if r[0] == "vipm-track (ours)")
    assert f"| {ours[1]}; {ours[3]} |" in _status("speed, real frames")
    fleet = {r[0]: r for r in _rows(RESULTS / "bench_fleet.md") if len(r) == 6}
    loop, dask = fleet["sequential loop"], fleet["fleet, 2 workers"]
    assert f"| {dask[2]} vs {loop[2]} ({dask[3]}) |" in _status("fleet")
    live = [r for r in _rows(RESULTS / "bench_live.md") if len(r) == 12 and r[0] == "10"]
    assert (f"| {_range([float(r[9]) for r in live], '.2f')} s; "
            f"{max(int(r[10]) for r in live)}; {_range([float(r[11]) for r in live], '.2f')} s |"
            in _status("live monitoring"))


def test_shutter_assumed_status_quotes_the_results_file():
    rows = [r for r in _rows(RESULTS / "bench_readout_stake.md") if len(r) == 8
            and r[1].isdigit()]
    warned = sum(r[3] == "yes" for r in rows)

    def pitch(cell: str) -> float:
        return float(cell.split("°")[0])

    off = [abs(pitch(r[5]) - pitch(r[6])) for r in rows if float(r[2]) > 0
           and r[0] != "car shaking"]
    shaking = next(abs(pitch(r[5]) - pitch(r[6])) for r in rows if r[0] == "car shaking")
    assert (f"| {warned}/{len(rows)}; off by {_range(off, '.2f')}° "
            f"(car shaking {shaking:.2f}°) |" in _status("shutter assumed"))


def test_monitor_extrinsics_status_quotes_the_results_file():
    rows = [r for r in _rows(RESULTS / "bench_monitor_estimates.md") if len(r) == 11
            and r[0] != "case"]
    steps = [r for r in rows if " step " in r[0] and "road" not in r[0]]
    second = [r for r in rows if "more at" in r[0]]
    ramp = [r for r in rows if "ramp" in r[0]]
    at_alarm = [float(r[4].rstrip(" %")) for r in steps]
    held = [float(r[9].split(" %")[0]) for r in second]
    ramp_held = [float(r[9].split(" %")[0]) for r in ramp]
    assert (f"| {_range(at_alarm, '.0f')} %; {_range(held, '.0f')} % (renders 90–100 %); "
            f"{_range(ramp_held, '.0f')} % (was 48) |" in _status("monitor's new extrinsics"))


def test_lateral_motion_status_quotes_the_results_file():
    rows = {(r[0], r[1]): r for r in _rows(RESULTS / "bench_lateral_motion.md") if len(r) == 7}
    batch, ekf = (rows[("KITTI 07 (3 tables)", f)] for f in ("batch", "EKF"))

    def rms(cell: str) -> str:
        return cell.split(" / ")[0]

    def cover(cell: str) -> str:
        return cell.split(" / ")[1]

    assert (f"| {rms(batch[2])} / {rms(ekf[2])} mm ({rms(batch[4])} / {rms(ekf[4])}); "
            f"{cover(batch[3])} / {cover(ekf[3])} % |" in _status("lateral motion per frame"))


def test_slow_driving_status_quotes_the_results_file():
    rows = [r for r in _rows(RESULTS / "bench_long_baseline.md")
            if len(r) == 8 and "open road" in r[0] and "shaking" not in r[0]]

    def pitch(camera: str, variant: str) -> list[float]:
        return sorted(float(r[3]) for r in rows if r[0].startswith(camera) and variant in r[0])

    def cell(values: list[float], joined: bool) -> str:
        text = [f"{v:.2f}".replace("-", "−") for v in values]
        return ", ".join(text) if joined else f"{text[0]}–{text[-1]}"

    car = f"{cell(pitch('car,', 'default'), False)}° ({cell(pitch('car,', 'alone'), False)}°)"
    kitti = (f"{cell(pitch('KITTI', 'default'), True)}° "
             f"({cell(pitch('KITTI', 'alone'), True)}°)")
    assert f"| {car}; {kitti} |" in _status("slow driving")
