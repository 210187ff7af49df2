"""The compiled kernels' decorator (vipm_track.compiled)."""

from __future__ import annotations

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


def test_the_first_compile_of_a_project_kernel_is_announced_once(capsys, monkeypatch):
    from vipm_track import compiled

    monkeypatch.setattr(compiled._FirstCompileNotice, "said", False)

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
