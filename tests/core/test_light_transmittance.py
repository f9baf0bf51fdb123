"""Shadow-ray transmittance and fluence against Beer–Lambert and inverse-square references."""

import numpy as np
import pytest

from vtkillum.core.light_transmittance import light_transmittance
from vtkillum.core.lights import DirectionalLight, PointLight
from vtkillum.core.transfer_function import TransferFunction
from vtkillum.core.volume import Volume


def grid_points(volume, shape):
    """World positions (nx, ny, nz, 3) of a light grid of ``shape`` covering ``volume``."""
    axes = [np.linspace(0.0, e, n) for e, n in zip(volume.extent, shape)]
    local = np.stack(np.meshgrid(*axes, indexing="ij"), -1)
    return local @ volume.direction.T + volume.origin


def rotation(axis, angle):
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * k @ k


@pytest.mark.parametrize("segment_planes", [0, 16])
def test_homogeneous_medium_matches_beer_lambert(device, segment_planes):
    """Exponential attenuation over the distance to the box exit, for an oblique light
    (12 planes: the default chain marches them all exactly; longer chains are tested in
    test_transmittance_chained.py)."""
    volume = Volume(np.ones((12, 10, 9)), spacing=(0.5, 0.4, 0.6), origin=(1.0, -2.0, 0.5),
                    direction=rotation((1, 2, 3), 0.7))
    alpha, u = 0.4, 0.8
    tf = TransferFunction([0.0, 2.0], [alpha, alpha])
    travel = np.array([0.3, -1.0, 0.5])
    light = DirectionalLight(travel, (1.0, 0.5, 0.25))
    T, phi = light_transmittance(volume, tf, u, [light], device=device)

    sigma = -np.log(1 - alpha) / u
    # Distance from each point to the box, walking against the travel direction (local frame).
    toward = -volume.to_local_direction(light.direction)
    local = grid_points(volume, volume.dims) - volume.origin
    local = local @ volume.direction
    with np.errstate(divide="ignore"):
        t_axis = np.where(toward > 0, (volume.extent - local) / toward,
                          np.where(toward < 0, -local / toward, np.inf))
    d = t_axis.min(-1)
    expected = np.exp(-sigma * d)
    assert T.shape == (1, 12, 10, 9) and T.dtype == np.float32
    np.testing.assert_allclose(T[0], expected, rtol=2e-4, atol=1e-6)
    np.testing.assert_allclose(phi, expected[..., None] * light.irradiance, rtol=2e-4, atol=1e-6)


@pytest.mark.parametrize("segment_planes", [0, 3])
def test_slab_attenuates_by_its_thickness(device, segment_planes):
    """A sharp slab of known thickness between the light and the far side: exp(-sigma d)
    (exact rays, and chained segments every 3 planes: exact for an axis-aligned light)."""
    n = 24
    s = np.zeros((6, 6, n))
    s[:, :, 8:16] = 1.0  # points 8..15: the slab's edges lie half a cell outside them
    volume = Volume(s, spacing=(1.0, 1.0, 0.5))
    alpha = 0.3
    tf = TransferFunction([0.0, 0.499, 0.501, 1.0], [0.0, 0.0, alpha, alpha])
    T, _ = light_transmittance(volume, tf, 1.0, [DirectionalLight((0, 0, -1))],
                               step_size=0.01, device=device, segment_planes=segment_planes)
    thickness = 8 * 0.5  # from z = 7.5 * 0.5 to 15.5 * 0.5
    sigma = -np.log(1 - alpha)
    below = T[0, :, :, :6]
    above = T[0, :, :, 17:]
    np.testing.assert_allclose(above, 1.0, atol=1e-6)
    np.testing.assert_allclose(below, np.exp(-sigma * thickness), rtol=5e-3)


def test_point_light_inverse_square_in_empty_space(device):
    """Fluence I / max(d, r)² from a point light outside and one inside the box, frame rotated
    (r = half the smallest spacing: one grid point lies 0.134 from the inside light)."""
    volume = Volume(np.zeros((9, 8, 7)), spacing=(0.3, 0.4, 0.5), origin=(-1.0, 0.5, 2.0),
                    direction=rotation((0, 0, 1), 0.5))
    tf = TransferFunction([0.0, 1.0], [0.0, 0.0])
    outside = PointLight((4.0, -3.0, 1.0), (8.0, 4.0, 2.0))
    inside = PointLight(volume.origin + volume.direction @ (volume.extent * [0.55, 0.45, 0.5]),
                        (1.0, 1.0, 1.0))
    T, phi = light_transmittance(volume, tf, 1.0, [outside, inside], device=device)
    np.testing.assert_allclose(T, 1.0, atol=1e-6)
    x = grid_points(volume, volume.dims)
    expected = sum(light.intensity / np.maximum(np.sum((x - light.position) ** 2, -1),
                                                0.15**2)[..., None]
                   for light in (outside, inside))
    np.testing.assert_allclose(phi, expected, rtol=1e-4)


def test_point_light_inside_medium_marches_only_to_the_light(device):
    volume = Volume(np.ones((11, 11, 11)), spacing=(0.2, 0.2, 0.2))
    tf = TransferFunction([0.0, 1.0], [0.5, 0.5])
    light = PointLight((1.0, 1.0, 1.0), (1.0, 1.0, 1.0))  # the centre point
    T, _ = light_transmittance(volume, tf, 1.0, [light], device=device)
    d = np.linalg.norm(grid_points(volume, volume.dims) - light.position, axis=-1)
    np.testing.assert_allclose(T[0], np.exp(-np.log(2.0) * d), rtol=2e-4, atol=1e-6)


@pytest.mark.parametrize("segment_planes", [0, 3])
def test_opaque_wall_casts_a_full_shadow(device, segment_planes):
    s = np.zeros((16, 8, 8))
    s[7:9] = 1.0
    volume = Volume(s)
    tf = TransferFunction([0.0, 0.5, 1.0], [0.0, 0.999, 0.999])
    T, phi = light_transmittance(volume, tf, 1.0, [DirectionalLight((1, 0, 0), (2, 2, 2))],
                                 device=device, segment_planes=segment_planes)
    assert np.all(T[0, :6] > 0.999)  # in front of the wall (light comes from x = 0)
    assert np.all(T[0, 10:] < 1e-4)  # behind it
    assert np.all(phi[10:] < 2e-4)


@pytest.mark.parametrize("segment_planes", [0, 2])
def test_lower_resolution_grid_covers_the_same_box(device, segment_planes):
    volume = Volume(np.ones((17, 9, 9)), spacing=(0.25, 0.5, 0.5))
    tf = TransferFunction([0.0, 1.0], [0.2, 0.2])
    T, phi = light_transmittance(volume, tf, 1.0, [DirectionalLight((-1, 0, 0))], shape=(5, 3, 4),
                                 device=device, segment_planes=segment_planes)
    assert T.shape == (1, 5, 3, 4) and phi.shape == (5, 3, 4, 3)
    x = np.linspace(0.0, 4.0, 5)  # light from +x: distance 4 - x
    np.testing.assert_allclose(T[0, :, 1, 2], np.exp(np.log(0.8) * (4.0 - x)), rtol=2e-4)


@pytest.mark.parametrize("shape", [(1, 4, 4), (4, 4), (4.5, 4, 4), "abc"])
def test_bad_shape_is_rejected(shape):
    volume = Volume(np.ones((4, 4, 4)))
    tf = TransferFunction([0.0, 1.0], [0.2, 0.2])
    with pytest.raises(ValueError, match="shape"):
        light_transmittance(volume, tf, 1.0, [DirectionalLight((1, 0, 0))], shape=shape,
                            device="cpu")


def test_no_lights_is_an_error():
    volume = Volume(np.ones((4, 4, 4)))
    with pytest.raises(ValueError, match="at least one light"):
        light_transmittance(volume, TransferFunction([0.0], [0.5]), 1.0, [], device="cpu")


@pytest.mark.parametrize("segment_planes", [0, 16, 5])
def test_deep_in_opaque_data_the_shadow_stays_dark(device, segment_planes):
    """Optical depths 0 to 40 across a homogeneous cube: where T > 1e-4 it is Beer-Lambert
    to 1e-3 (relative), and deeper the march may stop early but never reports more than
    SHADOW_STOP_T (a stop at the primary ray's 1e-2 once left such points 100x too bright)."""
    from vtkillum.core.warp_common import SHADOW_STOP_T

    n = 41
    volume = Volume(np.ones((n, 4, 4)), spacing=(1.0, 1.0, 1.0))
    sigma = 1.0  # optical depth 1 per voxel
    tf = TransferFunction([0.0, 2.0], [1 - np.exp(-sigma), 1 - np.exp(-sigma)])
    T, _ = light_transmittance(volume, tf, 1.0, [DirectionalLight((1.0, 0.0, 0.0))],
                               device=device, segment_planes=segment_planes)
    depth = np.arange(n, dtype=np.float64)  # light enters at x = 0
    exact = np.exp(-sigma * depth)
    t = T[0, :, 2, 2].astype(np.float64)
    visible = exact > 1e-4
    np.testing.assert_allclose(t[visible], exact[visible], rtol=1e-3)
    assert np.all(t[~visible] <= np.maximum(exact[~visible], SHADOW_STOP_T) * 1.0001)
