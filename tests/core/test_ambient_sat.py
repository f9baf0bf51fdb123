"""Ambient extinction from a summed-area table (Ament et al. 2013, eqs. 12-13)."""

import numpy as np
import pytest
import warp as wp

from vtkillum.core.ambient.cache import world_radius
from vtkillum.core.ambient.sat import (
    CUBE_HALF_WIDTH,
    ambient_extinction,
    cube_half_width,
    cube_mean_reference,
    sigma_t_grid,
    summed_area_table,
)
from vtkillum.core.transfer_function import TransferFunction
from vtkillum.core.volume import Volume
from vtkillum.core.warp_common import make_medium


def test_cube_has_the_sphere_volume():
    h = cube_half_width(3.0, (1.0, 1.0, 1.0))
    assert np.prod(2 * h) == pytest.approx(4 / 3 * np.pi * 27)
    np.testing.assert_allclose(cube_half_width(3.0, (1.0, 2.0, 0.5)),
                               CUBE_HALF_WIDTH * 3.0 / np.array([1.0, 2.0, 0.5]))
    with pytest.raises(ValueError, match="positive"):
        cube_half_width(0.0, (1, 1, 1))


def test_cube_mean_equals_brute_force(device, rng):
    # random volumes and radii (fractional cube faces, cubes larger than the volume,
    # cubes smaller than a voxel), anisotropic spacing, every voxel including the edges
    for _ in range(6):
        shape = tuple(rng.integers(3, 13, size=3))
        spacing = rng.uniform(0.5, 2.0, size=3)
        radius = float(rng.choice([rng.uniform(0.1, 0.6), rng.uniform(0.6, 6.0),
                                   rng.uniform(6.0, 20.0)]))
        sig = (rng.random(shape) * rng.uniform(0.1, 10.0)).astype(np.float32)
        got = ambient_extinction(sig, spacing, radius, device).numpy()
        ref = cube_mean_reference(sig, spacing, radius)
        np.testing.assert_allclose(got, ref, rtol=2e-6, atol=1e-6 * sig.max())


def test_integer_cube_is_the_zero_padded_box_mean(device, rng):
    # h + 1/2 integral: the cube covers whole voxels; outside the volume counts as empty
    sig = rng.random((9, 7, 8)).astype(np.float32)
    half = 2
    radius = (half + 0.5) / CUBE_HALF_WIDTH
    got = ambient_extinction(sig, (1, 1, 1), radius, device).numpy()
    padded = np.pad(sig.astype(np.float64), half)
    n = 2 * half + 1
    ref = np.empty(sig.shape)
    for i, j, k in np.ndindex(sig.shape):
        ref[i, j, k] = padded[i:i + n, j:j + n, k:k + n].mean()
    np.testing.assert_allclose(got, ref, rtol=1e-6)


def test_summed_area_table_is_exclusive_prefix_sum(device, rng):
    sig = rng.random((4, 5, 6)).astype(np.float32)
    sat = summed_area_table(sig, device).numpy()
    ref = np.zeros((5, 6, 7))
    ref[1:, 1:, 1:] = sig.astype(np.float64).cumsum(0).cumsum(1).cumsum(2)
    np.testing.assert_allclose(sat, ref, rtol=1e-12)
    assert sat.dtype == np.float64


def test_large_volume_keeps_precision(device):
    # 96^3 voxels of sigma ~ 1000: SAT corners reach 9e11. A float32 table would lose
    # the sub-voxel cube sums entirely (its spacing there is ~6e4); float64 keeps them.
    n = 96
    x = np.arange(n)
    sig = (1000.0 + 0.001 * ((x[:, None, None] + 2 * x[None, :, None] + 3 * x[None, None, :])
                             % 7)).astype(np.float32)
    radius = 0.4 / CUBE_HALF_WIDTH  # h = 0.4 voxel: the mean is the voxel's own value
    got = ambient_extinction(sig, (1, 1, 1), radius, device).numpy()
    np.testing.assert_allclose(got, sig, rtol=2e-7)


def test_sigma_t_grid_matches_transfer_function(device, rng):
    vol = Volume(rng.random((6, 5, 4)).astype(np.float32), spacing=(0.5, 0.5, 0.5))
    tf = TransferFunction([0.0, 0.3, 1.0], [0.0, 0.5, 0.9])
    m = make_medium(vol, tf, 0.5, device=device)
    got = sigma_t_grid(m, device).numpy()
    np.testing.assert_allclose(got, tf.sigma_t(vol.scalars, 0.5), rtol=2e-3, atol=1e-4)


def test_radius_units():
    assert world_radius(4, "voxels", (0.5, 1.0, 1.5)) == pytest.approx(4.0)
    assert world_radius(2.5, "world", (0.5, 1.0, 1.5)) == pytest.approx(2.5)
    with pytest.raises(ValueError, match="voxels"):
        world_radius(1.0, "mm", (1, 1, 1))
    with pytest.raises(ValueError, match="positive"):
        world_radius(-1.0, "world", (1, 1, 1))


def test_reuses_a_given_table(device, rng):
    sig = rng.random((5, 6, 7)).astype(np.float32)
    sat = summed_area_table(sig, device)
    a = ambient_extinction(wp.array(sig, dtype=wp.float32, device=device), (1, 1, 1), 2.0,
                           device, sat=sat).numpy()
    np.testing.assert_allclose(a, cube_mean_reference(sig, (1, 1, 1), 2.0), rtol=1e-5)


def test_window_and_line_walk_passes_agree():
    """The two evaluations of a separable pass (a thread per point summing its window, used
    along the contiguous axis for short windows; a thread per line walking it) give the
    same sums, for windows shorter than a cell to longer than the line."""
    import warp as wp

    from vtkillum.core.ambient.sat import box_pass_kernel, box_window_kernel

    a = np.random.default_rng(0).random((9, 11, 40)).astype(np.float32)
    src = wp.array(a, device="cpu")
    for half in (0.3, 1.7, 3.2, 12.5, 45.0):
        window = wp.empty(a.shape, dtype=wp.float32, device="cpu")
        walk = wp.empty(a.shape, dtype=wp.float32, device="cpu")
        wp.launch(box_window_kernel, dim=a.shape, inputs=[src, window, half, 1.0], device="cpu")
        wp.launch(box_pass_kernel, dim=(9, 11), inputs=[src, walk, 2, half, 1.0], device="cpu")
        np.testing.assert_allclose(window.numpy(), walk.numpy(), rtol=1e-6, atol=1e-6)
        # the line's total where the window covers all of it
        if half > 41:
            np.testing.assert_allclose(walk.numpy(), np.broadcast_to(
                a.sum(-1, keepdims=True, dtype=np.float64), a.shape), rtol=1e-6)
