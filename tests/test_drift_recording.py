"""The drift recording read back: ``monitor --rerun`` on the knocked cart drive
(``tests/data/knock_cart_*``, see ``test_drift_report.py``) logs the nominal with its
tolerances, the mount with its bands, the monitor's events as markers and its states, laid
out by the drift blueprint; images are decimated by time unless asked for in full."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from test_dashboards import FakeResult, entity_rows, fake_stage

from vipm_track.cli import main
from vipm_track.sinks.rerun_blueprint import default_blueprint
from vipm_track.sinks.rerun_read import recording_entities
from vipm_track.sinks.rerun_sink import IMAGE_PERIOD_S, RerunSink
from vipm_track.table import read_table

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT / "tests" / "data"


@pytest.fixture(scope="module")
def monitored(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path, Path]:
    out = tmp_path_factory.mktemp("drift")
    table, rrd, events = out / "mon.csv", out / "mon.rrd", out / "events.jsonl"
    assert main(["monitor", "--estimates", str(DATA / "knock_cart_est.csv"), "--speed-csv",
                 str(DATA / "knock_cart_speed.csv"), "--nominal",
                 str(ROOT / "data" / "nominal_cart.yaml"), "--out", str(table), "--events",
                 str(events), "--quiet", "--rerun", str(rrd)]) == 0
    return table, rrd, events


def test_nominal_and_tolerance_in_every_mount_view(monitored) -> None:
    table, rrd, _ = monitored
    tab = read_table(table)
    nominal = entity_rows(rrd, "/series/pitch/nominal", "Scalars:scalars")
    band = entity_rows(rrd, "/series/height/nominal_band", "Scalars:scalars")
    assert sorted(nominal) == [int(f) for f in tab["frame"]]
    assert {float(v[0]) for v in nominal.values()} == {45.0}
    np.testing.assert_allclose(band[int(tab["frame"][-1])], [0.695, 0.705])


def test_events_are_markers_at_the_monitor_transitions(monitored) -> None:
    """One marker per event in each axis, at the frames events.jsonl names, at the EKF's
    mount then or its new extrinsics; the RECALIBRATE marker sits near the true 46°."""
    table, rrd, events = monitored
    lines = [json.loads(x) for x in events.read_text().splitlines()]
    markers = entity_rows(rrd, "/series/pitch/events", "Scalars:scalars")
    with_mount = [e for e in lines if e.get("filter_mount") or e.get("estimate")]
    assert sorted(markers) == sorted(e["frame"] for e in with_mount)
    last = max(markers)
    assert markers[last][0] == pytest.approx(46.0, abs=0.5)
    rows = recording_entities(rrd)
    states = np.asarray(read_table(table)["monitor_state"], dtype=object)
    assert rows["/monitor/state"] == 1 + int(np.sum(states[1:] != states[:-1]))
    mount = entity_rows(rrd, "/series/pitch/mount", "Scalars:scalars")
    assert mount[max(mount)][0] == pytest.approx(46.0, abs=0.1)
    assert rows["/series/pitch/mount_band"] == rows["/series/pitch/mount"]


def test_drift_blueprint_lays_out_the_calibration() -> None:
    blueprint = default_blueprint("drift")
    views = _views(blueprint.root_container)
    origins = {str(v.origin) for v in views}
    assert {"series/pitch", "series/roll", "series/height", "monitor/state", "camera",
            "log"} <= {o.strip("/") for o in origins}
    with pytest.raises(ValueError, match="layout"):
        default_blueprint("nope")


def _views(container) -> list:
    out = []
    for item in getattr(container, "contents", []):
        if hasattr(item, "origin"):
            out.append(item)
        else:
            out.extend(_views(item))
    return out


def test_images_decimated_by_time_by_default(tmp_path: Path) -> None:
    """50 pairs at 10 Hz: images of one pair every IMAGE_PERIOD_S s by default, every pair
    with image_every=1; without times every 20th pair."""
    rng = np.random.default_rng(1)
    image = rng.integers(0, 255, (120, 160), dtype=np.uint8)
    z = np.array([0.78, 0.01, 0.79, -0.02, 0.0, 0.12, 0.003])
    counts = {}
    for name, options, times in (("default", {"image_every": None}, True),
                                 ("all", {"image_every": 1}, True),
                                 ("untimed", {"image_every": None}, False)):
        rrd = tmp_path / f"{name}.rrd"
        sink = RerunSink.to_file(rrd, **options)
        for k in range(1, 51):
            sink.log_pair(k, 0.1 * k if times else float("nan"),
                          FakeResult("ok", z, [fake_stage("image", rng)]), image)
        sink.finish()
        counts[name] = recording_entities(rrd)["/camera/image"]
    assert counts["default"] == int(np.ceil(5.0 / IMAGE_PERIOD_S - 1e-9))
    assert counts["all"] == 50
    assert counts["untimed"] == 3


def test_cli_image_options(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    """--rerun-all-images and --rerun-image-every exclude each other; --help states the
    default's cost."""
    with pytest.raises(SystemExit):
        main(["estimate", "--images", "x", "--height", "1", "--out", str(tmp_path / "e.csv"),
              "--rerun-all-images", "--rerun-image-every", "3"])
    assert "not allowed with" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["estimate", "--help"])
    assert "under 1 GB" in " ".join(capsys.readouterr().out.split())


@pytest.mark.parametrize("command", ["report", "fleet"])
def test_help_prints_percent_signs_once(command: str, capsys: pytest.CaptureFixture) -> None:
    """A description is printed as written (argparse formats only the options' help):
    "95 %% bands" was printed with both signs."""
    with pytest.raises(SystemExit):
        main([command, "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert "95 % " in text and "%%" not in text
