"""Whole-array checks and copies on the device (:mod:`vtkillum.core.device_arrays`).

They see any float32 array (scalar or vector elements, any rank) as two axes, rows and
columns: one warp axis indexes at most 2³¹ values, fewer than a 1024³ grid of vec3 holds
(3.2 billion floats), and the reduction counts its elements in 64 bits.
"""

import numpy as np
import pytest
import warp as wp

from vtkillum.core.device_arrays import array_stats, clamp_max, flat_float, scaled_nonnegative


def test_stats_and_copies_of_vector_and_4d_arrays_match_numpy(device):
    rng = np.random.default_rng(11)
    fluence = rng.normal(size=(5, 7, 9, 3)).astype(np.float32)
    fluence[1, 2, 3, 0] = np.nan
    fluence[4, 6, 8, 2] = np.inf
    grid = wp.array(fluence, dtype=wp.vec3, device=device)
    assert flat_float(grid).shape == (5 * 7, 9 * 3)
    bad, lo, hi = array_stats(grid)
    finite = fluence[np.isfinite(fluence)]
    assert (bad, lo, hi) == (2, float(finite.min()), float(finite.max()))
    transmittance = rng.random((3, 4, 6, 5)).astype(np.float32) * 1.2
    t = wp.array(transmittance, dtype=wp.float32, device=device)
    assert array_stats(t) == (0, float(transmittance.min()), float(transmittance.max()))
    assert np.array_equal(clamp_max(t, 1.0).numpy(), np.minimum(transmittance, 1.0))
    finite_fluence = np.nan_to_num(fluence, posinf=5.0)  # it takes checked grids
    scaled = scaled_nonnegative(wp.array(finite_fluence, dtype=wp.vec3, device=device), 2.0)
    assert np.array_equal(scaled.numpy(), np.maximum(finite_fluence, 0.0) * np.float32(2.0))


def test_an_empty_array_has_no_stats():
    with pytest.raises(ValueError, match="empty"):
        array_stats(wp.zeros((0, 3), dtype=wp.float32, device="cpu"))
