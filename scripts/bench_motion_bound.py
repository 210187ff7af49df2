"""The bound on the motion between pairs (``--max-acceleration``, ``pair_chain``): the `ok`
rows it takes away, and whether they were wrong, at and beyond the motion range and on drives
well within it.

Per scenario and seed, a rendered drive (``vipm_track.sim``; seeds no other benchmark uses)
estimated through the command line in tracking mode at the preset's nominal pitch, once with
the default bound (10 m/s²) and once without it (``--max-acceleration inf``). Per run: the `ok`
rows, those wrong (the travel vector more than 10 % of the travel or pitch or roll more than
1.5° from the truth), those beyond 3σ (tx, tz, pitch or roll), and the rows marked
``implausible motion``; for these, how many were wrong in the run without the bound (the same
frame's row). Where a rejected pair's successor then starts cold, the two runs may differ
after it.

    python scripts/bench_motion_bound.py [--seeds 301 302 303] [--jobs 2] [--cache DIR] [--out FILE]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from bench_camera_pitch import write_report  # noqa: E402

from vipm_track.cli import main as cli_main  # noqa: E402
from vipm_track.pair_chain import STATUS_IMPLAUSIBLE_MOTION  # noqa: E402
from vipm_track.sim import PRESETS, simulate_sequence  # noqa: E402
from vipm_track.table import read_table  # noqa: E402

FRAMES = 60
WRONG_DEG, WRONG_TRAVEL = 1.5, 0.10
#: name → (preset, profile, fps, speed [m/s], traffic): beyond the motion range
#: (docs/results.md: car 2.45 m, cart 0.59 m per frame; shaking less), at its edge, and
#: well within it
SCENARIOS: dict[str, tuple[str, str, float, float, str | None]] = {
    "car shaking, 2.5 m/frame": ("car", "shaking", 10.0, 25.0, None),
    "car shaking, 1.8 m/frame": ("car", "shaking", 10.0, 18.0, None),
    "car gradual, 2.8 m/frame": ("car", "gradual", 10.0, 28.0, None),
    "cart gradual, 0.65 m/frame": ("cart", "gradual", 10.0, 6.5, None),
    "cart shaking, 0.4 m/frame": ("cart", "shaking", 10.0, 4.0, None),
    "car turn, 0.6 m/frame": ("car", "turn", 20.0, 12.0, None),
    "car in traffic, shaking, 0.6 m/frame": ("car", "shaking", 20.0, 12.0, "mix"),
    "car knock, 0.6 m/frame": ("car", "knock", 20.0, 12.0, None),
}
VARIANTS = {"default (10 m/s²)": [], "--max-acceleration inf": ["--max-acceleration", "inf"]}


def drive(name: str, seed: int, cache: Path) -> Path:
    """The rendered drive's folder (rendered once)."""
    preset, profile, fps, speed, traffic = SCENARIOS[name]
    folder = cache / f"{''.join(c if c.isalnum() else '_' for c in name)}_s{seed}"
    if not ((folder / "images").is_dir()
            and len(list((folder / "images").glob("*.png"))) == FRAMES):
        simulate_sequence(preset, FRAMES, folder, seed=seed, profile=profile, fps=fps,
                          speed=speed, traffic=traffic)
    return folder


def wrong_rows(est: dict, truth: dict) -> dict[str, np.ndarray]:
    """Per row of ``est``: ok, wrong and beyond 3σ (module doc; bool arrays). The travel is
    compared as a vector, at the height the row assumed (a pair measures travel over
    height: the true travel is scaled by the assumed over the true height of frame k-1)."""
    index = {int(f): i for i, f in enumerate(truth["frame"])}
    t = np.array([index[int(f)] for f in est["frame"]], int)
    ok = np.asarray(est["status"], object) == "ok"
    scale = est["height_m"] / truth["prev_height_m"][t]
    true = {a: truth[f"{a}_m"][t] * scale for a in ("tx", "tz")}
    with np.errstate(invalid="ignore", divide="ignore"):
        travel_error = np.hypot(est["tx_m"] - true["tx"], est["tz_m"] - true["tz"])
        errors = {a: est[f"{a}_deg"] - truth[f"{a}_deg"][t] for a in ("pitch", "roll")}
        z = [(est[f"{a}_m"] - true[a]) / est[f"{a}_std_m"] for a in ("tx", "tz")]
        z += [errors[a] / est[f"{a}_std_deg"] for a in errors]
        wrong = ((travel_error > WRONG_TRAVEL * np.hypot(true["tx"], true["tz"]))
                 | (np.abs(errors["pitch"]) > WRONG_DEG) | (np.abs(errors["roll"]) > WRONG_DEG))
        beyond = np.any(np.abs(np.array(z)) > 3, axis=0)
    return {"ok": ok, "wrong": ok & wrong, "beyond": ok & beyond}


def run(name: str, seed: int, cache: Path) -> list[tuple[str, dict]]:
    """Both variants on one drive: (variant, numbers) each."""
    folder = drive(name, seed, cache)
    preset = PRESETS[SCENARIOS[name][0]]
    truth = read_table(folder / "gt.csv")
    tables = {}
    for variant, extra in VARIANTS.items():
        est = folder / f"est_{'bound' if not extra else 'inf'}.csv"
        cli_main(["estimate", "--images", str(folder / "images"), "--camera",
                  str(folder / "camera.yaml"), "--height", repr(preset.height_m), "--pitch",
                  repr(preset.pitch_deg), "--threads", "1", *extra, "--out", str(est),
                  "--quiet"])
        tables[variant] = read_table(est)
    without = wrong_rows(tables["--max-acceleration inf"], truth)
    out = []
    for variant, table in tables.items():
        rows = wrong_rows(table, truth)
        rejected = np.asarray(table["status"], object) == STATUS_IMPLAUSIBLE_MOTION
        out.append((variant, {
            "ok": f"{rows['ok'].sum()}/{len(rows['ok']) - 1}",
            "wrong": int(rows["wrong"].sum()),
            "beyond": int(rows["beyond"].sum()),
            "rejected": int(rejected.sum()),
            "rejected_wrong": int((rejected & without["wrong"]).sum()),
        }))
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[301, 302, 303])
    ap.add_argument("--jobs", type=int, default=2, help="processes rendering and estimating")
    ap.add_argument("--cache", default=str(Path(tempfile.gettempdir()) / "vipm_bench_motion_bound"))
    ap.add_argument("--out", default=str(ROOT / "scripts" / "results" / "bench_motion_bound.md"))
    args = ap.parse_args(argv)
    cache = Path(args.cache)
    cache.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    jobs = [(name, seed) for name in SCENARIOS for seed in args.seeds]
    with ProcessPoolExecutor(max_workers=max(1, args.jobs)) as pool:
        results = list(pool.map(run, *zip(*jobs, strict=True), [cache] * len(jobs)))
    rows = []
    totals = {v: np.zeros(4, int) for v in VARIANTS}
    for (name, seed), runs in zip(jobs, results, strict=True):
        for variant, m in runs:
            rejected = (f"{m['rejected']} ({m['rejected_wrong']} wrong)" if m["rejected"]
                        else "0")
            rows.append(f"| {name} | {seed} | {variant} | {m['ok']} | {m['wrong']} | "
                        f"{m['beyond']} | {rejected} |")
            totals[variant] += [m["wrong"], m["beyond"], m["rejected"], m["rejected_wrong"]]
            print(rows[-1], flush=True)
    for variant, (wrong, beyond, rejected, rejected_wrong) in totals.items():
        rows.append(f"| **all** | | {variant} | | {wrong} | {beyond} | "
                    f"{rejected} ({rejected_wrong} wrong) |")
    write_report([
        "# The bound on the motion between pairs (scripts/bench_motion_bound.py)",
        "",
        f"{FRAMES} rendered frames per drive (seeds {', '.join(map(str, args.seeds))}), "
        "`vipm-track estimate` in tracking mode at the preset's nominal pitch with the default "
        "bound on the motion and without it. *wrong*: `ok` rows with the travel vector more than "
        "10 % of the travel or pitch or roll more than 1.5° from the truth (the travel at the "
        "height the row assumed); *beyond 3σ*: in tx, tz, pitch or roll; *rejected*: "
        "rows marked `implausible motion`, and how many of those frames' rows were wrong without "
        "the bound.",
        "",
        "<!-- results:bench_motion_bound -->",
        "| scenario | seed | bound | ok | wrong | beyond 3σ | rejected |",
        "| --- | --- | --- | --- | --- | --- | --- |",
        *rows,
        "<!-- /results:bench_motion_bound -->",
    ], args.out, t0,
        f"python scripts/bench_motion_bound.py --seeds {' '.join(map(str, args.seeds))}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
