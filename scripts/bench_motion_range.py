"""How far per frame the vehicle may move for `vipm-track estimate`, with and without ``--pitch``.

Renders a short sequence per preset, profile and speed (``vipm_track.sim``: the preset's
camera, height and pitch; frame rate and speed changed) and runs the issue's command line on
it, without ``--pitch`` (the nominal pose searched where the default cold start fails), with
the preset's pitch, and for level cameras also with ``--vertical-motion`` (steep ones have it
on by default), then scores every pair against the rendered truth (the same score as
``bench_camera_pitch.py``).

    python scripts/bench_motion_range.py [--frames 8] [--out scripts/results/bench_motion_range.md]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from bench_camera_pitch import pair_errors, score, write_report  # noqa: E402

from vipm_track.estimator_config import LEVEL_MAX_PITCH_DEG  # noqa: E402
from vipm_track.sim import PRESETS, simulate_sequence  # noqa: E402

#: (preset, profile, frame rate [Hz], speed [m/s]) per row
ROWS: tuple[tuple[str, str, float, float], ...] = (
    ("cart", "gradual", 10.0, 1.2),
    ("cart", "gradual", 10.0, 2.4),
    ("cart", "gradual", 10.0, 3.6),
    ("cart", "gradual", 10.0, 4.8),
    ("cart", "gradual", 10.0, 6.0),
    ("cart", "gradual", 10.0, 7.0),  # beyond the range: pairs fail, none wrong
    ("cart", "gradual", 10.0, 8.0),
    ("cart", "shaking", 10.0, 1.2),
    ("cart", "shaking", 10.0, 3.0),
    ("cart", "shaking", 5.0, 1.2),
    ("car", "gradual", 20.0, 12.0),
    ("car", "gradual", 20.0, 25.0),
    ("car", "gradual", 20.0, 40.0),
    ("car", "gradual", 10.0, 25.0),
    ("car", "shaking", 20.0, 12.0),
    ("car", "shaking", 20.0, 25.0),
    ("car", "shaking", 10.0, 12.0),
)
#: (profile, speed [m/s]) of the cart at 10 fps scored over ``SEEDS`` for wrong `ok` pairs
SEED_ROWS: tuple[tuple[str, float], ...] = tuple(
    (profile, speed) for profile in ("static", "gradual") for speed in (3.6, 4.8, 6.0, 7.0, 8.0))
SEEDS = (0, 1, 2, 3, 4)
#: an `ok` pair further than this from the truth is wrong (pitch [deg], distance [%])
WRONG_PITCH_DEG, WRONG_DISTANCE_PCT = 1.5, 10.0


def wrong_ok_over_seeds(tmp: Path, frames: int) -> list[str]:
    """Table rows: per ``SEED_ROWS`` row, the cart's pairs over ``SEEDS``, without and with
    ``--pitch``: ok pairs and the ok pairs beyond ``WRONG_PITCH_DEG`` / ``WRONG_DISTANCE_PCT``."""
    preset = PRESETS["cart"]
    rows = []
    for profile, speed in SEED_ROWS:
        counts = {"auto": [0, 0, 0], "given": [0, 0, 0]}  # pairs, ok, wrong ok
        for seed in SEEDS:
            folder = tmp / f"seeds_{profile}_{speed:g}_{seed}"
            traj = simulate_sequence(preset, frames, folder, seed=seed, profile=profile,
                                     fps=10.0, speed=speed)
            for key, extra in (("auto", []), ("given", ["--pitch", f"{preset.pitch_deg:g}"])):
                _, n, pitch, dist, _ = pair_errors(folder, preset, traj, extra)
                wrong = int(np.count_nonzero((pitch > WRONG_PITCH_DEG)
                                             | (dist > WRONG_DISTANCE_PCT)))
                for i, v in enumerate((n, pitch.size, wrong)):
                    counts[key][i] += v
        cells = " | ".join(f"{ok}/{n} | {wrong}" for n, ok, wrong in counts.values())
        row = f"| cart | {profile} | {speed:g} | {speed / 10.0:.2f} | {cells} |"
        print(row, flush=True)
        rows.append(row)
    return rows


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=8, help="frames per sequence")
    ap.add_argument("--out", default=str(ROOT / "scripts" / "results" / "bench_motion_range.md"))
    args = ap.parse_args(argv)
    t0 = time.perf_counter()
    header = ("| preset | profile | fps | speed m/s | m/frame | travel / height | "
              "no --pitch: ok | max pitch err ° | max distance err % | nominal found ° | "
              "--pitch: ok | max pitch err ° | max distance err % | "
              "--pitch --vertical-motion: ok | max pitch err ° | max distance err % |")
    lines = [
        "# Motion per frame that `vipm-track estimate` handles",
        "",
        f"One rendered sequence of {args.frames} frames per row (`vipm_track.sim` preset, "
        "seed 5, with the frame rate and speed of the row: cart 800×600, h 0.7 m, pitch 45°; "
        "car 1280×720, h 1.5 m, pitch 3°), run as `vipm-track estimate --images DIR --camera "
        "CAMERA.yaml --height H` (tracking), without and with `--pitch` (the preset's pitch), and "
        "for the level car also with `--vertical-motion` (on by default for the steep cart: "
        "—). "
        "Errors: max over the pairs with status ok. *nominal found*: the pose the search "
        "settled on where the default cold start (60°) failed or converged more than 5° from "
        "60° (empty: it converged near 60°). *shaking* moves pitch and roll by up to ±2.4° / "
        "±1.8° at 1–3 Hz (the paper's cart): at 10 fps that is up to ~4° between frames, and "
        "heaves the body by up to ±1.5 % of the camera height (2 cm per frame on the car).",
        "",
        header, "|" + " --- |" * 16,
    ]
    print(header)
    with tempfile.TemporaryDirectory() as tmp:
        for name, profile, fps, speed in ROWS:
            preset = PRESETS[name]
            folder = Path(tmp) / f"{name}_{profile}_{fps:g}_{speed:g}"
            traj = simulate_sequence(preset, args.frames, folder, seed=5, profile=profile,
                                     fps=fps, speed=speed)
            step = float(np.median([traj.motion(k).distance for k in range(1, len(traj))]))
            auto = score(folder, preset, traj, [])
            pitch = ["--pitch", f"{preset.pitch_deg:g}"]
            given = score(folder, preset, traj, pitch)
            heave = (score(folder, preset, traj, [*pitch, "--vertical-motion"])[:3]
                     if preset.pitch_deg < LEVEL_MAX_PITCH_DEG else ("—", "—", "—"))
            row = (f"| {name} | {profile} | {fps:g} | {speed:g} | {step:.2f} | "
                   f"{step / preset.height_m:.2f} | {' | '.join(auto)} | "
                   f"{' | '.join(given[:3])} | {' | '.join(heave)} |")
            print(row, flush=True)
            lines.append(row)
        lines += [
            "",
            f"Wrong `ok` pairs over seeds {SEEDS[0]}–{SEEDS[-1]}: the cart at 10 fps, one "
            f"sequence of {args.frames} frames per seed (texture, pose profile), the same two "
            f"command lines; *wrong*: `ok` pairs more than {WRONG_PITCH_DEG:g}° (pitch) or "
            f"{WRONG_DISTANCE_PCT:g} % (distance) from the truth.",
            "",
            "| preset | profile | speed m/s | m/frame | no --pitch: ok | wrong | --pitch: ok | "
            "wrong |",
            "|" + " --- |" * 8,
            *wrong_ok_over_seeds(Path(tmp), args.frames),
        ]
    write_report(lines, args.out, t0, "python scripts/bench_motion_range.py")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
