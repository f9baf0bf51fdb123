"""Light distribution by tube marching (Ament et al. 2013, eqs. 14-17)."""

import numpy as np
import pytest
import warp as wp

from vtkillum.core.ambient.tube_march import radiance_cache
from vtkillum.core.lights import DirectionalLight, PointLight
from vtkillum.core.volume import Volume
from vtkillum.core.warp_common import make_lights

SIGMA_MAX = 20.0
TAU = np.linspace(0.0, SIGMA_MAX, 201)


def grid(shape, value, device):
    return wp.array(np.full(shape, value, np.float32), dtype=wp.float32, device=device)


def cache_points(shape, extent):
    axes = [np.linspace(0, e, n) for n, e in zip(shape, extent)]
    return np.stack(np.meshgrid(*axes, indexing="ij"), -1)


def test_empty_space_carries_the_unattenuated_light(device):
    shape = (9, 8, 7)
    vol = Volume(np.zeros(shape, np.float32), spacing=(1.0, 1.0, 1.0))
    lights = [DirectionalLight((1, -2, 0.5), (1.0, 0.5, 0.25)),
              PointLight((4.0, 3.0, 10.0), (20.0, 10.0, 5.0))]
    lw = make_lights(lights, vol, device)
    trans = np.exp(-2 * TAU)  # anything with T(0) = 1
    cache = radiance_cache(grid(shape, 0.0, device), vol.spacing, vol.extent, lw, trans,
                           SIGMA_MAX, radius=1.5, scale=1.0, device=device).numpy()
    np.testing.assert_allclose(cache[0], np.broadcast_to([1.0, 0.5, 0.25], cache[0].shape),
                               rtol=1e-6)
    p = cache_points(shape, vol.extent)
    d2 = np.sum((p - np.array([4.0, 3.0, 10.0])) ** 2, axis=-1)
    np.testing.assert_allclose(cache[1], np.array([20.0, 10.0, 5.0]) / d2[..., None], rtol=1e-5)


@pytest.mark.parametrize("radius", [0.75, 2.0])
def test_homogeneous_medium_follows_eqs_15_to_17(device, radius):
    # Constant sigma~: after k whole steps of 2r the front is E T^k; in between it is
    # interpolated linearly (eq. 17). Light enters at x = 0 travelling along +x.
    shape = (21, 3, 3)
    extent = np.array([10.0, 1.0, 1.0])
    spacing = extent / (np.array(shape) - 1)
    sig = 0.3
    trans = np.exp(-1.3 * TAU) * (0.9 + 0.1 * np.cos(TAU))  # some decreasing table
    vol = Volume(np.zeros(shape, np.float32), spacing=spacing)
    lw = make_lights([DirectionalLight((1, 0, 0), (2.0, 2.0, 2.0))], vol, device)
    cache = radiance_cache(grid(shape, sig, device), spacing, extent, lw, trans, SIGMA_MAX,
                           radius=radius, scale=1.0, device=device).numpy()[0, :, 1, 1, 0]
    t = np.interp(radius * sig, TAU, trans)
    x = np.linspace(0, extent[0], shape[0])
    steps = x / (2 * radius)
    k = np.floor(steps)
    eta = steps - k
    ref = 2.0 * ((1 - eta) * t**k + eta * t ** (k + 1))
    np.testing.assert_allclose(cache, ref, rtol=2e-5)


def test_absorbing_medium_is_beer_lambert(device):
    # With the albedo-0 transmittance exp(-2 tau), whole steps reproduce exp(-sigma x).
    shape = (41, 2, 2)
    extent = np.array([8.0, 1.0, 1.0])
    spacing = extent / (np.array(shape) - 1)
    vol = Volume(np.zeros(shape, np.float32), spacing=spacing)
    lw = make_lights([DirectionalLight((-1, 0, 0), (1.0, 1.0, 1.0))], vol, device)
    sig, radius = 0.5, 0.2
    cache = radiance_cache(grid(shape, sig, device), spacing, extent, lw, np.exp(-2 * TAU),
                           SIGMA_MAX, radius=radius, scale=1.0, device=device).numpy()
    x = np.linspace(0, extent[0], shape[0])
    depth = extent[0] - x  # the light comes from +x
    whole = np.isclose(np.mod(depth / (2 * radius) + 0.5, 1.0), 0.5)  # on a step boundary
    assert whole.sum() == 21
    got = cache[0, :, 0, 0, 0]
    np.testing.assert_allclose(got[whole], np.exp(-sig * depth[whole]), rtol=1e-5)
    # in between, eq. 17 interpolates linearly: a little above the exponential
    assert np.all(got[~whole] >= np.exp(-sig * depth[~whole]))
    np.testing.assert_allclose(got[~whole], np.exp(-sig * depth[~whole]), rtol=6e-3)


def test_point_light_inside_starts_at_the_light(device):
    shape = (11, 11, 11)
    vol = Volume(np.zeros(shape, np.float32))
    pos = np.array([5.0, 5.0, 5.0])
    lw = make_lights([PointLight(pos, (1.0, 1.0, 1.0))], vol, device)
    sig, radius = 0.2, 0.5
    cache = radiance_cache(grid(shape, sig, device), vol.spacing, vol.extent, lw,
                           np.exp(-2 * TAU), SIGMA_MAX, radius=radius, scale=1.0,
                           device=device).numpy()[0, ..., 0]
    p = cache_points(shape, vol.extent)
    d = np.linalg.norm(p - pos, axis=-1)
    far = d > 0.5
    # marching starts at the light (a light outside would start at the box face)
    t = np.exp(-2 * radius * sig)
    k = np.floor(d / (2 * radius))
    eta = d / (2 * radius) - k
    ref = ((1 - eta) * t**k + eta * t ** (k + 1)) / np.maximum(d, 1e-6) ** 2
    np.testing.assert_allclose(cache[far], ref[far], rtol=1e-4)


def test_shadow_behind_an_occluder_and_cache_resolution(device):
    shape = (17, 9, 9)
    sig = np.zeros(shape, np.float32)
    sig[4:7, :, :] = 3.0  # a slab across the light's path
    vol = Volume(np.zeros(shape, np.float32))
    lw = make_lights([DirectionalLight((1, 0, 0))], vol, device)
    cache = radiance_cache(wp.array(sig, dtype=wp.float32, device=device), vol.spacing,
                           vol.extent, lw, np.exp(-1.5 * TAU), SIGMA_MAX, radius=1.0,
                           scale=0.5, device=device)
    assert cache.shape == (9, 5, 5)
    line = cache.numpy()[0, :, 2, 2, 0]
    assert line[0] == pytest.approx(1.0)
    assert np.all(np.diff(line) <= 1e-7)
    # The slab's line integral (point values 0, 3, 3, 3, 0 at x = 3..7, trilinear) is 9 over
    # steps of 2r = 2: sum of the steps' r * mean(sigma~) is 4.5, so T = exp(-1.5 * 4.5).
    table = np.exp(-1.5 * TAU)  # looked up linearly between its entries, as the kernel does
    assert line[-1] == pytest.approx(np.interp(0.75, TAU, table) ** 2 * np.exp(-1.5 * 3.0),
                                     rel=1e-4)
    # The paper's one sample per step, at the step's centre (x = 5), sees sigma~ = 3 once.
    paper = radiance_cache(wp.array(sig, dtype=wp.float32, device=device), vol.spacing,
                           vol.extent, lw, np.exp(-1.5 * TAU), SIGMA_MAX, radius=1.0,
                           scale=0.5, device=device, substeps=1).numpy()[0, -1, 2, 2, 0]
    assert paper == pytest.approx(np.exp(-1.5 * 3.0), rel=1e-3)
    with pytest.raises(ValueError, match="radiance_cache_scale"):
        radiance_cache(wp.array(sig, dtype=wp.float32, device=device), vol.spacing, vol.extent,
                       lw, np.exp(-TAU), SIGMA_MAX, radius=1.0, scale=0.0, device=device)


def test_point_light_irradiance_is_held_within_one_radius(device):
    # Within r of a point light the ambient sphere contains it: I / r², not a 1/d² spike.
    shape = (9, 9, 9)
    vol = Volume(np.zeros(shape, np.float32))
    pos = np.array([4.0, 4.0, 4.0])  # on a cache point
    lw = make_lights([PointLight(pos, (8.0, 4.0, 2.0))], vol, device)
    radius = 2.0
    cache = radiance_cache(grid(shape, 0.0, device), vol.spacing, vol.extent, lw,
                           np.exp(-2 * TAU), SIGMA_MAX, radius=radius, scale=1.0,
                           device=device).numpy()[0]
    d = np.linalg.norm(cache_points(shape, vol.extent) - pos, axis=-1)
    ref = np.array([8.0, 4.0, 2.0]) / np.maximum(d, radius)[..., None] ** 2
    assert np.all(np.isfinite(cache))
    np.testing.assert_allclose(cache, ref, rtol=1e-5)
    np.testing.assert_allclose(cache[4, 4, 4], [2.0, 1.0, 0.5], rtol=1e-6)


@pytest.mark.parametrize("radius", [2.0, 4.0])
def test_thin_shell_shadows_wherever_it_lies_on_the_step_grid(device, radius):
    """A shell thinner than r (optical depth 3) across a directional light, moved in half-voxel
    steps through one whole tube step of 2r: the front behind it must not depend on where the
    shell falls between the step's samples. With the paper's one sample of sigma~ per step at the
    sphere's centre it slips between the samples (the SAT cube's half-width is only 0.81 r) and
    the light behind it varies from the shadowed value up to 1 (no shadow at all)."""
    from vtkillum.core.ambient.sat import ambient_extinction

    shape = (81, 9, 9)
    vol = Volume(np.zeros(shape, np.float32))
    lw = make_lights([DirectionalLight((1, 0, 0))], vol, device)
    trans = np.exp(-2 * TAU)  # absorption only: the front behind is exp(-3) whatever r is

    def front(x0, substeps=None):
        sig = np.zeros(shape, np.float32)
        i = int(np.floor(x0))
        sig[i], sig[i + 1] = 3.0 * (1 - (x0 - i)), 3.0 * (x0 - i)  # optical depth 3
        st = ambient_extinction(sig, (1, 1, 1), radius, device)
        c = radiance_cache(st, (1, 1, 1), vol.extent, lw, trans, SIGMA_MAX, radius, 1.0,
                           device, substeps=substeps).numpy()
        return float(c[0, 60, 4, 4, 0])

    positions = np.arange(30.0, 30.0 + 2 * radius + 1e-6, 0.5)
    fronts = np.array([front(x) for x in positions])
    np.testing.assert_allclose(fronts, np.exp(-3.0), rtol=0.03)
    paper = np.array([front(x, substeps=1) for x in positions])
    assert paper.max() > 3 * np.exp(-3.0)  # the leak this test guards against


def _shell_front(device, radius, x0, shape=(81, 9, 9), samples=None, tube="field",
                 direction=(1, 0, 0), probe=(60, 4, 4)):
    """The front at ``probe`` behind a one-voxel shell (optical depth 3) at ``x0`` along x,
    across a directional light, absorption only; tube sampling as the cache's options."""
    from vtkillum.core.ambient.sat import ambient_extinction
    from vtkillum.core.ambient.tube_march import step_extinction_field

    vol = Volume(np.zeros(shape, np.float32))
    lw = make_lights([DirectionalLight(direction)], vol, device)
    sig = np.zeros(shape, np.float32)
    i = int(np.floor(x0))
    sig[i], sig[i + 1] = 3.0 * (1 - (x0 - i)), 3.0 * (x0 - i)
    st = ambient_extinction(sig, (1, 1, 1), radius, device)
    field = None
    if tube == "field":
        field = step_extinction_field(st, (1, 1, 1), radius, device, samples=samples or 1)
    c = radiance_cache(st, (1, 1, 1), vol.extent, lw, np.exp(-2 * TAU), SIGMA_MAX, radius, 1.0,
                       device, substeps=samples, step_field=field).numpy()
    return float(c[(0,) + tuple(probe) + (0,)])


@pytest.mark.parametrize("radius,samples", [(2.0, 1), (4.0, 1), (4.0, 2), (2.5, 1)])
def test_step_field_collects_the_shell_wherever_it_lies(device, radius, samples):
    """One sample of the step field per step of 2r (or ``samples``, each of its share): the
    boxes of consecutive steps tile an axis-aligned path, so the optical depth collected is
    the shell's, exactly, wherever the shell lies between the samples (the paper's single
    sample of sigma~ lets it through: the test above)."""
    positions = np.arange(30.0, 30.0 + 2 * radius + 1e-6, 0.5)
    # (wide enough that the box around the probe stays clear of the border, where sigma~'s
    # cube reaches outside the volume)
    fronts = np.array([_shell_front(device, radius, x, (81, 17, 17), samples=samples,
                                    probe=(60, 8, 8)) for x in positions])
    # (the table is interpolated linearly between its entries: ~1 % above exp(-3))
    np.testing.assert_allclose(fronts, np.exp(-3.0), rtol=0.02)
    assert np.ptp(fronts) < 0.02 * np.exp(-3.0)  # the same wherever the shell lies


def test_step_field_on_a_diagonal_light_stays_close_to_the_mean_along_the_step(device):
    """Along a diagonal the boxes no longer tile the path; the box's smooth footprint keeps
    the shell's shadow within a few per cent of the exact mean along each step (midpoint
    rule, a sample per data spacing), wherever the shell lies."""
    radius, shape = 3.0, (64, 40, 40)
    direction = (1.0, 0.6, 0.4)
    probe = (54, 26, 26)  # behind the shell, on rays that enter through the -x face

    def fronts(tube):
        return np.array([_shell_front(device, radius, x, shape, tube=tube, direction=direction,
                                      probe=probe) for x in np.arange(30.0, 36.01, 1.0)])

    exact = fronts("midpoint")
    np.testing.assert_allclose(exact, exp_depth := np.exp(-3.0 * np.sqrt(1.52)), rtol=0.1)
    field = fronts("field")
    np.testing.assert_allclose(field, exact, rtol=0.08)
    assert np.ptp(field) < 0.1 * exp_depth


def test_step_field_keeps_homogeneous_media_and_validates(device):
    """A constant sigma~ is its own box mean: the field march equals eqs. 15-17 exactly, on
    the field's coarser grid too; a grid that is not 3D is refused."""
    from vtkillum.core.ambient.tube_march import step_extinction_field

    shape = (21, 5, 6)
    st = grid(shape, 0.3, device)
    field = step_extinction_field(st, (0.5, 1.0, 2.0), 1.3, device).numpy()
    np.testing.assert_allclose(field, 0.3, rtol=1e-6)
    vol = Volume(np.zeros(shape, np.float32))
    lw = make_lights([DirectionalLight((1, -1, 0.5))], vol, device)
    args = (st, vol.spacing, vol.extent, lw, np.exp(-1.3 * TAU), SIGMA_MAX, 1.3, 1.0, device)
    np.testing.assert_allclose(
        radiance_cache(*args, step_field=step_extinction_field(st, vol.spacing, 1.3, device)).numpy(),
        radiance_cache(*args, substeps=1).numpy(), rtol=1e-6)
    with pytest.raises(ValueError, match="step field must be a 3D grid"):
        radiance_cache(*args, step_field=grid((1, 4, 4), 0.3, device))
    with pytest.raises(ValueError, match="radius must be positive"):
        step_extinction_field(st, vol.spacing, 0.0, device)
