"""Trilinear resampling of point grids onto another resolution of the same box."""

import numpy as np
import pytest

from vtkillum.core.resample import resample_points


def test_resample_is_trilinear():
    # A trilinear function is reproduced exactly by trilinear interpolation.
    def f(x, y, z):
        return 1 + 2 * x - y + 0.5 * z + 0.25 * x * y * z

    fine = np.stack(np.meshgrid(*(np.linspace(0, 1, n) for n in (9, 5, 7)), indexing="ij"), -1)
    coarse = np.stack(np.meshgrid(*(np.linspace(0, 1, n) for n in (4, 6, 3)), indexing="ij"), -1)
    out = resample_points(f(*np.moveaxis(fine, -1, 0)), (4, 6, 3))
    assert out.shape == (4, 6, 3)
    # (9 -> 4 points) is not nested, so this is a real interpolation test.
    np.testing.assert_allclose(out, f(*np.moveaxis(coarse, -1, 0)), rtol=1e-5)
    rgb = np.stack([fine[..., 0], fine[..., 1], fine[..., 2]], -1)
    np.testing.assert_allclose(resample_points(rgb, (4, 6, 3)), coarse, atol=1e-6)


def test_resample_refuses_degenerate_grids():
    with pytest.raises(ValueError, match=">= 2 points"):
        resample_points(np.zeros((4, 4, 4)), (1, 4, 4))


def test_resample_reproduces_a_linear_field_and_keeps_equal_shapes():
    i, j, k = np.meshgrid(np.arange(5), np.arange(4), np.arange(6), indexing="ij")
    f = (1.0 + 2 * i + 3 * j - k).astype(np.float32)
    out = resample_points(f, (9, 3, 11))
    x, y, z = np.meshgrid(np.linspace(0, 4, 9), np.linspace(0, 3, 3), np.linspace(0, 5, 11),
                          indexing="ij")
    np.testing.assert_allclose(out, 1 + 2 * x + 3 * y - z, atol=1e-5)
    np.testing.assert_array_equal(resample_points(f, f.shape), f)
