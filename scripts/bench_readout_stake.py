"""Does the warning that a global shutter was assumed tell the truth (vipm_track/readout_stake.py)?

Rendered drives with a global shutter and with rolling shutters of 20-40 ms, estimated through
the command line as a user without the datasheet would (`estimate` at the nominal pitch, no
`--readout-time`), then with the true `--readout-time`. Per drive: whether `estimate` warned,
the stake it measured for a 20 ms readout (pitch, travel), that stake scaled to the drive's
true readout (the bias it predicts for the rows), the bias the rows have (median error of the
`ok` rows' pitch and travel against the render's truth) and what is left of it with the
true readout given. Rendered drives are cached under ``--cache``.

    python scripts/bench_readout_stake.py [--jobs 2] [--cache DIR] [--out FILE]
"""

from __future__ import annotations

import argparse
import contextlib
import io
import sys
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from bench_shutter import Case, drive  # noqa: E402

from vipm_track.camera import load_camera  # noqa: E402
from vipm_track.cli import main as cli_main  # noqa: E402
from vipm_track.estimator_config import EstimatorConfig  # noqa: E402
from vipm_track.readout_stake import readout_stake  # noqa: E402
from vipm_track.rig import Rig  # noqa: E402
from vipm_track.sim import PRESETS  # noqa: E402
from vipm_track.sources import open_source  # noqa: E402
from vipm_track.table import read_table  # noqa: E402

CASES = [
    Case(f"{preset} {profile}", preset, profile, seed, frames, readout_s)
    for preset, profile, seed, frames, readout_s in (
        ("cart", "static", 601, 40, 0.0),
        ("cart", "static", 601, 40, 0.02),
        ("cart", "static", 601, 40, 0.04),
        ("cart", "shaking", 602, 40, 0.02),
        ("cart", "turn", 603, 40, 0.03),
        ("car", "static", 604, 60, 0.0),
        ("car", "static", 604, 60, 0.02),
        ("car", "shaking", 605, 60, 0.03),
        ("car", "turn", 606, 60, 0.02),
    )
]


def biases(est: dict, truth: dict) -> tuple[float, float]:
    """Median pitch error [°] and median relative travel error of the `ok` rows."""
    index = {int(f): i for i, f in enumerate(truth["frame"])}
    ok = np.flatnonzero(np.asarray(est["status"], object) == "ok")
    t = np.array([index[int(est["frame"][i])] for i in ok], int)
    pitch = est["pitch_deg"][ok] - truth["pitch_deg"][t]
    travel = (np.hypot(est["tx_m"][ok], est["tz_m"][ok])
              / np.hypot(truth["tx_m"][t], truth["tz_m"][t]) - 1.0)
    return float(np.median(pitch)), float(np.median(travel))


def run(case: Case, cache: Path) -> dict:
    folder = drive(case, cache)
    preset = PRESETS[case.preset]
    truth = read_table(folder / "gt.csv")
    base = ["estimate", "--images", str(folder / "images"), "--height", str(preset.height_m),
            "--pitch", str(preset.pitch_deg), "--threads", "1"]
    err = io.StringIO()
    with contextlib.redirect_stderr(err):
        cli_main([*base, "--out", str(folder / "est_assumed.csv"), "--quiet"])
        cli_main([*base, "--out", str(folder / "est_given.csv"), "--quiet",
                  "--readout-time", str(case.readout_s)])
    rig = Rig(load_camera(folder / "camera.yaml"), preset.height_m, preset.pitch_deg)
    stake = readout_stake(open_source(images=folder / "images"), rig, EstimatorConfig())
    return {
        "warned": "assuming a global shutter" in err.getvalue(),
        "stake": stake,
        "assumed": biases(read_table(folder / "est_assumed.csv"), truth),
        "given": biases(read_table(folder / "est_given.csv"), truth),
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--jobs", type=int, default=2, help="processes rendering and estimating")
    ap.add_argument("--cache",
                    default=str(Path(tempfile.gettempdir()) / "vipm_bench_readout_stake"))
    ap.add_argument("--out", default=str(ROOT / "scripts" / "results" / "bench_readout_stake.md"))
    args = ap.parse_args(argv)
    cache = Path(args.cache)
    cache.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    with ProcessPoolExecutor(max_workers=max(1, args.jobs)) as pool:
        results = list(pool.map(run, CASES, [cache] * len(CASES)))
    rows = []
    for case, r in zip(CASES, results, strict=True):
        s = r["stake"]
        scale = case.readout_s / s.readout_s
        rows.append(
            f"| {case.name} | {case.seed} | {case.readout_s * 1e3:.0f} | "
            f"{'yes' if r['warned'] else 'no'} | {s.pitch_deg:+.2f}° / {s.travel_rel:+.1%} | "
            f"{-scale * s.pitch_deg:+.2f}° / {-scale * s.travel_rel:+.1%} | "
            f"{r['assumed'][0]:+.2f}° / {r['assumed'][1]:+.1%} | "
            f"{r['given'][0]:+.2f}° / {r['given'][1]:+.1%} |")
        print(rows[-1], flush=True)
    text = "\n".join([
        "# A global shutter assumed: the warning against the truth "
        "(scripts/bench_readout_stake.py)",
        "",
        "Rendered drives (cart 10 fps, car 20 fps; seeds not seen before), `estimate` at the "
        "nominal pitch without `--readout-time` and with the true one. *stake*: what "
        "`estimate` measured a 20 ms readout would move (pitch, travel; "
        "`vipm_track/readout_stake.py`); *predicted*: minus that, scaled to the true readout "
        "(the bias it implies for rows that assume a global shutter); *assumed* and *given*: "
        "the median error of the `ok` rows' pitch and travel against the truth without and "
        "with the true `--readout-time`.",
        "",
        "<!-- results:bench_readout_stake -->",
        "| drive | seed | true readout ms | warned | stake at 20 ms: pitch / travel "
        "| predicted bias | bias, global shutter assumed | bias, true readout given |",
        "| --- | --- | --- | --- | --- | --- | --- | --- |",
        *rows,
        "<!-- /results:bench_readout_stake -->",
        "",
        f"Whole benchmark {time.perf_counter() - t0:.0f} s on a shared 2-core machine.",
        "",
        "Command: `python scripts/bench_readout_stake.py`",
        "",
    ])
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(text)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
