"""Convection step of the convection–diffusion light volume: analytic slabs, walls, point lights,
and the one-sweep solution against the paper's iterated steady state."""

import numpy as np
import pytest
import warp as wp

from vtkillum.core.convection_diffusion.convection import (
    convect_light,
    convect_light_iterated,
    sweep_plan,
)
from vtkillum.core.convection_diffusion.opacity import light_grid_shape, light_grid_sigma
from vtkillum.core.lights import DIRECTIONAL, POINT
from vtkillum.core.transfer_function import TransferFunction
from vtkillum.core.volume import Volume


def sigma_array(values, device):
    return wp.array(np.asarray(values, dtype=np.float32), dtype=wp.float32, device=device)


def slab_transmittance(n, sigma, device, scheme):
    """T along a homogeneous slab of unit thickness lit along +x, n points per unit."""
    h = 1.0 / (n - 1)
    sig = sigma_array(np.full((n, 4, 3), sigma), device)
    T = convect_light(sig, (h, h, h), DIRECTIONAL, (1.0, 0.0, 0.0), scheme=scheme).numpy()
    return np.linspace(0.0, 1.0, n), T[:, 2, 1]


def test_upwind_slab_decays_like_beer_lambert_to_first_order(device):
    sigma = 3.0
    errors = []
    for n in (17, 33, 65):
        x, T = slab_transmittance(n, sigma, device, "upwind")
        h = x[1]
        # The upwind recursion T_i = T_(i-1) / (1 + sigma h) is exp(-sigma x (1 - sigma h / 2 + ...)).
        np.testing.assert_allclose(T, (1.0 + sigma * h) ** -np.arange(n), rtol=2e-5)
        rel = np.abs(T / np.exp(-sigma * x) - 1.0)
        assert rel.max() <= 0.5 * sigma**2 * h * x.max() * 1.05
        errors.append(rel.max())
    assert errors[0] > 1e-2  # the scheme's error is visible on a coarse grid ...
    for coarse, fine in zip(errors, errors[1:]):
        assert 1.7 < coarse / fine < 2.3  # ... and first order: halves with the spacing


@pytest.mark.parametrize("scheme", ["exponential", "characteristics"])
def test_fitted_schemes_are_exact_for_a_slab(device, scheme):
    x, T = slab_transmittance(17, 3.0, device, scheme)
    np.testing.assert_allclose(T, np.exp(-3.0 * x), rtol=2e-5)


def test_oblique_light_through_a_homogeneous_cube(device):
    # Exact: T = exp(-sigma * distance back to the entry face). Short characteristics have
    # the least crosswind smearing; the upwind schemes are first order.
    n, sigma = 24, 1.5
    h = 1.0 / (n - 1)
    d = np.array([1.0, 0.5, 0.2]) / np.linalg.norm([1.0, 0.5, 0.2])
    x = np.stack(np.meshgrid(*(np.arange(n) * h,) * 3, indexing="ij"), -1)
    exact = np.exp(-sigma * np.min(x / d, axis=-1))
    sig = sigma_array(np.full((n, n, n), sigma), device)
    err = {s: np.abs(convect_light(sig, (h, h, h), DIRECTIONAL, d, scheme=s).numpy() - exact).mean()
           for s in ("upwind", "exponential", "characteristics")}
    assert err["characteristics"] < 0.6 * min(err["upwind"], err["exponential"])
    assert err["characteristics"] < 0.015


def test_light_grid_sigma_is_the_transfer_function_extinction(device):
    # alpha = 0.5 per unit distance u = 0.25 -> sigma_t = ln 2 / 0.25 everywhere.
    vol = Volume(np.ones((9, 7, 5)), spacing=(0.25, 0.25, 0.25))
    tf = TransferFunction([0.0, 2.0], [0.5, 0.5])
    for scale in (1.0, 0.5):
        shape = light_grid_shape(vol, scale)
        sigma = light_grid_sigma(vol, tf, 0.25, shape, device).numpy()
        assert sigma.shape == shape
        np.testing.assert_allclose(sigma, np.log(2.0) / 0.25, rtol=1e-5)


def test_footprint_average_keeps_a_thin_wall_on_a_coarse_grid(device):
    # A one-voxel opaque wall between light-grid points: point sampling would miss it.
    s = np.zeros((17, 5, 5), np.float32)
    s[9] = 1.0
    vol = Volume(s)
    tf = TransferFunction([0.0, 1.0], [0.0, 0.999])
    sigma = light_grid_sigma(vol, tf, 1.0, (9, 3, 3), device).numpy()
    depth = sigma[:, 1, 1].sum() * 2.0  # optical depth along x on the coarse grid
    x = np.linspace(0.0, 16.0, 160001)
    exact = np.trapezoid(tf.sigma_t(np.interp(x, np.arange(17), s[:, 2, 2]), 1.0), x)
    assert exact == pytest.approx(2.0, rel=0.05)
    assert 0.6 * exact < depth < 1.1 * exact  # point samples at x = 8, 10 would give 0


@pytest.mark.parametrize("scheme", ["upwind", "exponential", "characteristics"])
def test_no_light_behind_an_opaque_wall(device, scheme):
    # Wall of alpha = 1 (clamped to 1 - 1e-6) two light-grid points thick at x = 10..11.
    n = (24, 8, 8)
    s = np.zeros(n, np.float32)
    s[10:12] = 1.0
    vol = Volume(s)
    tf = TransferFunction([0.0, 1.0], [0.0, 1.0])
    sigma = light_grid_sigma(vol, tf, 1.0, n, device)
    T = convect_light(sigma, (1.0, 1.0, 1.0), DIRECTIONAL, (1.0, 0.0, 0.0), scheme=scheme).numpy()
    np.testing.assert_allclose(T[:10], 1.0, atol=1e-6)  # vacuum in front: fully lit
    limit = 6e-3 if scheme == "upwind" else 1e-9  # upwind: 1 / (1 + 13.8)**2
    assert T[12:].max() < limit


def test_oblique_light_behind_wall_casts_a_soft_shadow_in_the_right_place(device):
    # A wall over the lower half of the box; light travels along (1, -0.3): the shadow's
    # upper edge leaves the wall's top at (9.5, 9.5) and drops 0.3 per unit of x.
    n = (20, 20, 4)
    sig = np.zeros(n, np.float32)
    sig[8:10, :10, :] = 1e4
    T = convect_light(sigma_array(sig, device), (1.0, 1.0, 1.0), DIRECTIONAL,
                      (1.0, -0.3, 0.0)).numpy()[:, :, 2]
    np.testing.assert_allclose(T[:, 10:], 1.0, atol=1e-6)  # above the wall: never blocked
    assert T[10:12, :4].max() < 1e-3  # right behind the wall
    # First-order upwind smears the edge (the paper's soft shadows), centred on the ray.
    edge = np.interp(0.5, T[19, :12], np.arange(12))
    assert edge == pytest.approx(9.5 - 0.3 * 9.5, abs=1.0)
    assert np.all((T >= 0) & (T <= 1))


def test_interior_point_light_lights_its_room_and_nothing_leaks(device):
    # Hollow opaque box (walls 2 points thick) with a point light inside, vacuum outside.
    n = 24
    sig = np.zeros((n, n, n), np.float32)
    sig[4:20, 4:20, 4:20] = 1e3
    sig[6:18, 6:18, 6:18] = 0.0
    light = np.array([11.3, 12.1, 10.7])
    T = convect_light(sigma_array(sig, device), (1.0, 1.0, 1.0), POINT, light,
                      source_radius=2.0).numpy()
    inside = np.zeros_like(sig, bool)
    inside[6:18, 6:18, 6:18] = True
    outside = np.ones_like(sig, bool)
    outside[4:20, 4:20, 4:20] = False
    np.testing.assert_allclose(T[inside], 1.0, atol=1e-6)  # vacuum room: unattenuated
    assert T[outside].max() < 1e-12


def test_point_light_in_homogeneous_medium_follows_exp_along_axes(device):
    n = 25
    sigma = 0.4
    sig = sigma_array(np.full((n, n, n), sigma), device)
    light = np.array([12.0, 12.0, 12.0])
    T = convect_light(sig, (1.0, 1.0, 1.0), POINT, light, source_radius=2.0).numpy()
    d = np.arange(n) - 12.0
    # On the axis lines through the light the direction is axis-aligned: exact.
    np.testing.assert_allclose(T[:, 12, 12], np.exp(-sigma * np.abs(d)), rtol=1e-5)
    np.testing.assert_allclose(T[12, :, 12], np.exp(-sigma * np.abs(d)), rtol=1e-5)
    # Along a 45-degree diagonal short characteristics step from point to point: exact too.
    diag = np.array([T[12 + k, 12 + k, 12] for k in range(13)])
    np.testing.assert_allclose(diag, np.exp(-sigma * np.sqrt(2) * np.arange(13)), rtol=1e-5)
    # Elsewhere close, and monotone along rays.
    idx = np.stack(np.meshgrid(*(np.arange(n),) * 3, indexing="ij"), -1)
    exact = np.exp(-sigma * np.linalg.norm(idx - light, axis=-1))
    assert np.abs(T - exact).mean() < 0.01
    upwind = convect_light(sig, (1.0, 1.0, 1.0), POINT, light, 2.0, scheme="upwind").numpy()
    assert np.abs(upwind - exact).mean() > np.abs(T - exact).mean()


def test_point_light_outside_enters_through_the_faces_that_see_it():
    plan = sweep_plan(POINT, (-5.0, 3.0, 20.0), (8, 8, 8), (1.0, 1.0, 1.0))
    np.testing.assert_array_equal(plan.inflow, [0, -1, 7])  # x = 0 and z = max faces
    plan = sweep_plan(DIRECTIONAL, (0.0, -1.0, 1e-9), (8, 8, 8), (1.0, 1.0, 1.0))
    np.testing.assert_array_equal(plan.inflow, [-1, 7, -1])
    assert plan.wavefronts == 8 and plan.primary == 1


def test_directional_characteristics_sweep_by_layers_along_the_dominant_axis():
    """Short characteristics of a directional light all interpolate one layer back along the
    axis of largest |u_a| / h_a: one launch per layer of that axis, not per wavefront."""
    shape, h = (12, 10, 9), (1.0, 0.6, 1.2)
    plan = sweep_plan(DIRECTIONAL, (0.3, -0.5, 0.8), shape, h)
    assert plan.layers and plan.primary == 1 and plan.wavefronts == 10  # 0.5/0.6 > 0.8/1.2
    plan = sweep_plan(DIRECTIONAL, (0.3, -0.5, 0.8), shape, h, scheme="upwind")
    assert not plan.layers and plan.wavefronts == 12 + 10 + 9 - 2  # in-layer neighbours
    plan = sweep_plan(POINT, (5.3, 3.1, 4.4), shape, h)
    assert not plan.layers  # the interpolation axis changes from point to point


@pytest.mark.parametrize("vec", [(1.0, 1.0, 0.5), (0.7, -0.7, 0.7), (0.0, 0.3, -1.0)])
def test_layer_sweep_with_tied_axes_equals_the_iterated_steady_state(device, rng, vec):
    """Directions whose |u_a| / h_a tie (the layer axis is the first of them) or vanish."""
    sig = sigma_array(rng.uniform(0.0, 0.6, (11, 11, 11)), device)
    swept = convect_light(sig, (1.0, 1.0, 1.0), DIRECTIONAL, vec).numpy()
    iterated, _ = convect_light_iterated(sig, (1.0, 1.0, 1.0), DIRECTIONAL, vec,
                                         tolerance=1e-8)
    np.testing.assert_allclose(swept, iterated.numpy(), atol=2e-6)


@pytest.mark.parametrize("scheme", ["upwind", "exponential", "characteristics"])
@pytest.mark.parametrize("kind, vec", [
    (DIRECTIONAL, (0.3, -0.5, 0.8)),
    (DIRECTIONAL, (-1.0, 0.0, 0.01)),
    (POINT, (5.3, 3.1, 4.4)),  # inside
    (POINT, (-3.0, 2.0, 20.0)),  # outside
])
def test_one_sweep_equals_the_iterated_steady_state(device, rng, kind, vec, scheme):
    sig = sigma_array(rng.uniform(0.0, 0.6, (12, 10, 9)), device)
    h = (1.0, 0.8, 1.2)
    swept = convect_light(sig, h, kind, vec, source_radius=2.0, scheme=scheme).numpy()
    iterated, steps = convect_light_iterated(sig, h, kind, vec, source_radius=2.0,
                                             tolerance=1e-8, scheme=scheme)
    np.testing.assert_allclose(swept, iterated.numpy(), atol=2e-6)
    assert steps >= 16  # iterating needs many full passes for what one ordered sweep does
    assert np.all((swept >= 0) & (swept <= 1))
