"""Which camera pitches `vipm-track estimate` handles, with and without ``--pitch``.

Renders a short ``gradual`` sequence per preset and pitch (``vipm_track.sim``; the preset's
camera, height, speed and frame rate, only the pitch changed) and runs the issue's command
line on it — without ``--pitch`` (the cold start's nominal pose searched where the default
fails, ``vipm_track.nominal_search``) and with the true nominal ``--pitch`` — then scores
every pair against the rendered truth.

    python scripts/bench_camera_pitch.py [--frames 6] [--out scripts/results/bench_camera_pitch.md]
"""

from __future__ import annotations

import argparse
import contextlib
import io
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from vipm_track.cli import main as cli_main  # noqa: E402
from vipm_track.sim import PRESETS, simulate_sequence  # noqa: E402
from vipm_track.table import read_table  # noqa: E402

FloatArray = NDArray[np.float64]

PITCHES = {"car": (0.0, 3.0, 6.0, 10.0, 15.0, 20.0, 30.0),
           "cart": (5.0, 15.0, 25.0, 45.0, 60.0, 75.0, 80.0, 88.0)}


def render(folder: Path, preset_name: str, pitch_deg: float, frames: int):
    """The sequence of one row written to ``folder``; returns (preset, trajectory)."""
    preset = replace(PRESETS[preset_name], pitch_deg=pitch_deg)
    return preset, simulate_sequence(preset, frames, folder, seed=5, profile="gradual")


def pair_errors(folder: Path, preset, traj, extra: list[str],
                stderr: list[str] | None = None) -> tuple[int, int, FloatArray, FloatArray, str]:
    """Run ``estimate`` (``extra`` options) on the sequence in ``folder``: (exit code, pairs,
    the ok pairs' pitch errors [deg] and distance errors [%], nominal pitch found or ''); its
    stderr lines appended to ``stderr`` if given."""
    out = folder / "est.csv"
    err = io.StringIO()
    with contextlib.redirect_stderr(err):
        rc = cli_main(["estimate", "--images", str(folder / "images"), "--camera",
                       str(folder / "camera.yaml"), "--height", str(preset.height_m),
                       "--out", str(out), *extra])
    if stderr is not None:
        stderr.extend(err.getvalue().splitlines())
    n = len(traj) - 1
    if rc != 0:
        return rc, n, np.zeros(0), np.zeros(0), ""
    table = read_table(out)
    ok = np.asarray(table["status"][1:] == "ok")
    found = next((line.split("nominal pose now pitch ")[1].split("°")[0]
                  for line in err.getvalue().splitlines() if "nominal pose now" in line), "")
    pitch = np.abs(table["pitch_deg"][1:][ok] - np.degrees(traj.pitch[1:][ok]))
    truth = np.array([traj.motion(k).distance for k in range(1, ok.size + 1)])[ok]
    dist = np.abs(np.hypot(table["tx_m"][1:][ok], table["tz_m"][1:][ok]) / truth - 1.0) * 100
    return rc, ok.size, pitch, dist, found


def score(folder: Path, preset, traj, extra: list[str], stderr: list[str] | None = None,
          ) -> tuple[str, str, str, str]:
    """Run ``estimate`` (``extra`` options); (ok pairs, max pitch error °, max distance
    error %, nominal pitch found or ''); its stderr lines appended to ``stderr`` if given."""
    rc, n, pitch, dist, found = pair_errors(folder, preset, traj, extra, stderr)
    if rc != 0:
        return f"exit {rc}", "", "", ""
    if not pitch.size:
        return f"0/{n}", "—", "—", found
    return f"{pitch.size}/{n}", f"{pitch.max():.3f}", f"{dist.max():.2f}", found


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=6, help="frames per sequence")
    ap.add_argument("--out", default=str(ROOT / "scripts" / "results" / "bench_camera_pitch.md"))
    args = ap.parse_args(argv)
    t0 = time.perf_counter()
    header = ("| preset | pitch ° | true pitch ° | no --pitch: ok | max pitch err ° | "
              "max distance err % | nominal found ° | --pitch: ok | max pitch err ° | "
              "max distance err % |")
    lines = [
        "# Camera pitch coverage of `vipm-track estimate`",
        "",
        f"One rendered `gradual` sequence of {args.frames} frames per row (`vipm_track.sim` "
        "preset with only the pitch changed, the profile then moving it by a few degrees: "
        "car 1280×720, h 1.5 m, 20 fps, ~12 m/s; cart 800×600, h 0.7 m, 10 fps, ~1.2 m/s), "
        "run as `vipm-track estimate --images DIR --camera CAMERA.yaml --height H` "
        "(tracking), without and with `--pitch` (the preset's pitch). Errors: max over the "
        "pairs with status ok. *nominal found*: the pose the search settled on where the "
        "default cold start (60°) failed or converged more than 5° from 60° (empty: it "
        "converged near 60°).",
        "",
        header, "|" + " --- |" * 10,
    ]
    print(header)
    with tempfile.TemporaryDirectory() as tmp:
        for name, pitches in PITCHES.items():
            for pitch in pitches:
                folder = Path(tmp) / f"{name}_{pitch:g}"
                preset, traj = render(folder, name, pitch, args.frames)
                auto = score(folder, preset, traj, [])
                given = score(folder, preset, traj, ["--pitch", f"{pitch:g}"])
                truth = np.degrees(traj.pitch)
                row = (f"| {name} | {pitch:g} | {truth.min():.1f} to {truth.max():.1f} | "
                       f"{' | '.join(auto)} | {' | '.join(given[:3])} |")
                print(row, flush=True)
                lines.append(row)
    lines += [
        "",
        "Near nadir (pitch → 90°) the conventions' pose angles degenerate: roll is a rotation "
        "about the optical axis, which there is the vertical, the same rotation as the pair's "
        "yaw, and a sideways tilt has no angle. Down to 86° the pairs converge (pitch and "
        "travel checked here; the roll there is nearly the pair's yaw and is not checked); "
        "at 90° itself the estimator is not built for it.",
    ]
    write_report(lines, args.out, t0, "python scripts/bench_camera_pitch.py")
    return 0


def write_report(lines: list[str], out: str | Path, t0: float, command: str) -> None:
    """Write a results document: ``lines``, the wall time since ``t0``
    (``time.perf_counter``) and the ``command`` that made it."""
    lines = [*lines, "", f"Wall time {time.perf_counter() - t0:.0f} s on a shared 2-core machine.",
             "", f"Command: `{command}`."]
    path = Path(out)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(lines) + "\n")
    print(f"wrote {path}", file=sys.stderr)


if __name__ == "__main__":
    raise SystemExit(main())
