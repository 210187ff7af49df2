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
