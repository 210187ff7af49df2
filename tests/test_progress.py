"""Progress that fits where the output goes (vipm_track.progress)."""

from __future__ import annotations

from vipm_track.cli import main
from vipm_track.progress import progress_bar


def test_a_redirected_stderr_gets_lines_not_carriage_returns(capsys):
    assert list(progress_bar(range(3), desc="work", unit="item", mininterval=0)) == [0, 1, 2]
    err = capsys.readouterr().err
    assert "\r" not in err
    lines = err.splitlines()
    assert lines[-1].startswith("work: 100%") and "3/3" in lines[-1]
    assert all(line.strip() for line in lines)


def test_a_command_logs_progress_as_lines(tmp_path, capsys):
    assert main(["simulate", "--preset", "cart", "--frames", "3", "--out", str(tmp_path)]) == 0
    err = capsys.readouterr().err
    assert "\r" not in err and "simulate cart: 100%" in err


def test_estimate_and_track_log_progress_with_totals(tmp_path, capsys):
    """``estimate`` and ``track --images`` with stderr redirected: plain lines, the image
    folder's frame count as the total."""
    assert main(["simulate", "--preset", "cart", "--frames", "4", "--out", str(tmp_path)]) == 0
    capsys.readouterr()
    images = str(tmp_path / "images")
    assert main(["estimate", "--images", images, "--height", "0.7", "--pitch", "45",
                 "--refinements", "0", "--out", str(tmp_path / "est.csv")]) == 0
    err = capsys.readouterr().err
    assert "\r" not in err and "4/4" in err
    # three frames are too few for the EKF to start (exit 1); the progress is the point
    assert main(["track", "--images", images, "--height", "0.7", "--pitch", "45",
                 "--refinements", "0", "--max-frames", "3",
                 "--out", str(tmp_path / "track.csv")]) == 1
    err = capsys.readouterr().err
    assert "\r" not in err and "track: 100%" in err and "3/3" in err
