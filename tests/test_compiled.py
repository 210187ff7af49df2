"""The compiled kernels' decorator (vipm_track.compiled)."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap

import numpy as np

from vipm_track.compiled import kernel


def _generated(name: str, body: str):
    """A function whose source file does not exist (numba can cache it nowhere)."""
    ns: dict[str, object] = {}
    exec(compile(body, "<generated>", "exec"), ns)
    return ns[name]


def test_a_kernel_without_a_cache_location_still_compiles_and_runs():
    twice = kernel(_generated("twice", "def twice(a):\n    return 2.0 * a\n"))
    np.testing.assert_array_equal(twice(np.arange(3.0)), [0.0, 2.0, 4.0])
    assert hasattr(twice, "signatures") and twice.signatures  # compiled, not plain Python


def test_the_first_compile_of_a_project_kernel_is_announced_once(capsys, monkeypatch,
                                                                   tmp_path):
    from vipm_track import compiled

    monkeypatch.setattr(compiled._NOTICE, "said", False)
    monkeypatch.setattr(compiled._NOTICE, "marker", str(tmp_path / "marker"))

    def generated(name: str, module: str):
        ns: dict[str, object] = {"__name__": module}
        exec(compile(f"def {name}(a):\n    return a + 1.0\n", "<generated>", "exec"), ns)
        return kernel(ns[name])

    other = generated("elsewhere", "some_package.kernels")
    assert other(1.0) == 2.0
    assert "compiling" not in capsys.readouterr().err  # not one of the project's kernels
    first, second = (generated(n, "vipm_track.generated") for n in ("first", "second"))
    assert first(1.0) == second(1.0) == 2.0
    err = capsys.readouterr().err
    assert err.count("vipm-track: compiling numerical kernels") == 1


_COMPILE_IN_TWO_PROCESSES = textwrap.dedent("""
    import multiprocessing
    from vipm_track.compiled import kernel

    def compile_one(tag):
        ns = {"__name__": "vipm_track.generated"}
        exec(compile(f"def k{tag}(a):\\n    return a + {tag}.0\\n", "<generated>", "exec"), ns)
        return kernel(ns[f"k{tag}"])(1.0)

    if __name__ == "__main__":
        assert compile_one(1) == 2.0
        with multiprocessing.get_context("spawn").Pool(2) as pool:
            assert pool.map(compile_one, [2, 3]) == [3.0, 4.0]
""")


def test_a_run_and_its_worker_processes_announce_the_compile_once(tmp_path):
    """The demo's estimate runs in worker processes that each compile: the notice came
    three times."""
    script = tmp_path / "two_processes.py"
    script.write_text(_COMPILE_IN_TWO_PROCESSES)
    env = {k: v for k, v in os.environ.items() if k != "VIPM_TRACK_COMPILE_NOTICE_MARKER"}
    env["TMPDIR"] = str(tmp_path)  # where the run's marker lies, until it ends
    run = subprocess.run([sys.executable, str(script)], capture_output=True, text=True,
                         timeout=120, env=env)
    assert run.returncode == 0, run.stderr
    assert run.stderr.count("vipm-track: compiling numerical kernels") == 1
    assert not list(tmp_path.glob("vipm-track-compile-*"))
