"""Chained shadow-ray segments (directional lights) against the exact per-point shadow rays.

``light_transmittance(..., segment_planes=L)`` marches each point only to a grid plane at
most ``L`` planes towards the light and multiplies by that plane's bilinearly interpolated
transmittance; ``segment_planes=0`` marches every ray to the box exit. The bounds below
were measured on these scenes (the numbers are in the tests' comments) and leave a
margin of about 1.5x: a wrong plane, a wrong interpolation or a wrong light side moves
shadows by many cells and fails them.
"""

import numpy as np
import pytest
from scipy.ndimage import maximum_filter, minimum_filter
from test_light_transmittance import grid_points, rotation

from vtkillum.core.light_transmittance import CHUNK_SAMPLES, light_transmittance
from vtkillum.core.lights import DirectionalLight, PointLight
from vtkillum.core.transfer_function import TransferFunction
from vtkillum.core.volume import Volume


def sharp_blobs(n, count=24, seed=7):
    """``n``³ points of hard-edged balls (one-voxel transition, radius 4-12 % of ``n``)."""
    rng = np.random.default_rng(seed)
    x = np.arange(n, dtype=float)
    xyz = np.stack(np.meshgrid(x, x, x, indexing="ij"), -1)
    s = np.zeros((n, n, n))
    for _ in range(count):
        c = rng.uniform(0, n, 3)
        r = rng.uniform(0.04, 0.12) * n
        s = np.maximum(s, np.clip(r - np.linalg.norm(xyz - c, axis=-1) + 0.5, 0.0, 1.0))
    return s


#: A step of the data at 0.5 to 0.5 opacity per unit: shadow edges a fraction of a cell
#: wide, optical depth up to about 9 through a ball.
SHARP_TF = TransferFunction([0.0, 0.45, 0.55, 1.0], [0.0, 0.0, 0.5, 0.5])


def test_homogeneous_medium_is_beer_lambert_where_light_enters_the_light_side(device):
    """Exact (float32) where the light reaches every point of a chain's stencil through the
    light-side face; next to the side faces the box edge is a kink of T that the
    interpolation smooths (measured max |dT| 0.038 with L = 4, 0.031 with L = 16)."""
    R = rotation((1, 2, 3), 0.7)
    volume = Volume(np.ones((36, 30, 26)), spacing=(0.5, 0.4, 0.6), origin=(1.0, -2.0, 0.5),
                    direction=R)
    alpha, u = 0.4, 4.0
    tf = TransferFunction([0.0, 2.0], [alpha, alpha])
    sigma = -np.log(1 - alpha) / u
    local = (grid_points(volume, volume.dims) - volume.origin) @ volume.direction
    index = np.stack(np.meshgrid(*[np.arange(n) for n in volume.dims], indexing="ij"), -1)
    # Directions towards the light in the local frame: each axis dominant once, signs mixed.
    for toward in [(0.8, 0.45, -0.4), (-0.35, 0.5, 0.8), (0.4, -0.9, -0.35)]:
        w = np.asarray(toward) / np.linalg.norm(toward)
        light = DirectionalLight(-(R @ w))
        with np.errstate(divide="ignore"):
            t_axis = np.where(w > 0, (volume.extent - local) / w,
                              np.where(w < 0, -local / w, np.inf))
        expected = np.exp(-sigma * t_axis.min(-1))
        a = int(np.argmax(np.abs(w)))
        planes = index[..., a] if w[a] < 0 else volume.dims[a] - 1 - index[..., a]
        for segment_planes in (4, 16):
            T, phi = light_transmittance(volume, tf, u, [light], device=device,
                                         segment_planes=segment_planes)
            # Chain links behind each point; each widens the stencil by one cell.
            links = np.maximum(0, -(-(planes - segment_planes) // segment_planes))
            entry = local + (planes * volume.spacing[a] / abs(w[a]))[..., None] * w
            inner = np.ones(T.shape[1:], bool)
            for b in {0, 1, 2} - {a}:
                margin = (links + 1) * volume.spacing[b]
                inner &= (entry[..., b] >= margin) & (entry[..., b] <= volume.extent[b]
                                                      - margin)
            assert inner.mean() > 0.25 and links.max() >= (4 if segment_planes == 4 else 1)
            np.testing.assert_allclose(T[0][inner], expected[inner], rtol=2e-5)
            np.testing.assert_allclose(T[0], expected, atol=0.05)
            np.testing.assert_allclose(phi[..., 0], T[0] * light.irradiance[0], rtol=1e-6)


@pytest.mark.parametrize("axis", [0, 1, 2])
@pytest.mark.parametrize("sign", [1, -1])
def test_axis_aligned_light_equals_the_exact_rays(device, axis, sign):
    """Any data, a rotated box with anisotropic spacing: the chain reads grid points only.
    (Power-of-two spacings and step: both marches take the same samples.)"""
    rng = np.random.default_rng(11)
    s = rng.random((26, 21, 23)) ** 3
    s[8:14] *= 3.0
    R = rotation((1, -2, 0.5), 1.1)
    volume = Volume(s, spacing=(0.5, 0.25, 1.0), origin=(3.0, 1.0, -2.0), direction=R)
    tf = TransferFunction([0.0, 0.5, 3.0], [0.0, 0.6, 0.99])
    light = [DirectionalLight(R @ (sign * np.eye(3)[axis]))]
    exact, phi_exact = light_transmittance(volume, tf, 1.0, light, segment_planes=0,
                                           step_size=0.125, device=device)
    chained, phi = light_transmittance(volume, tf, 1.0, light, segment_planes=3,
                                       step_size=0.125, device=device)
    assert exact.min() < 1e-2  # deep shadows: the stop and the product are exercised
    # Measured max |dT| 3.4e-7 (float32 rounding of the products).
    np.testing.assert_allclose(chained, exact, rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(phi, phi_exact, rtol=1e-5, atol=1e-6)


SHARP_DIRECTIONS = [(1.0, 0.45, -0.3), (-0.35, -1.0, 0.55), (0.5, -0.4, -1.0),
                    (-1.0, 0.7, 0.6)]


@pytest.fixture(scope="module")
def blob_volume():
    return Volume(sharp_blobs(56), spacing=(1.0, 0.8, 1.2))


@pytest.mark.parametrize("travel", SHARP_DIRECTIONS)
def test_sharp_shadows_move_at_most_two_cells(blob_volume, travel):
    """56³ grid, hard-edged balls, oblique lights (each axis dominant, negative components).

    Measured with L = 16 (L = 8, 32): mean |dT| 7.3e-3, 1.8e-2, 7.6e-3, 5.7e-3 (8.2e-3 to
    2.4e-2; 3.0e-3 to 9.3e-3), the mean of dT (bias) at most 1.1e-3, max |dT| 0.66-0.85 (a
    sharp shadow edge a cell off). Every chained value lies within the exact grid's range
    over the 5³ points around it to 0.016: the shadows are blurred by about a cell, as
    sqrt(N / L f(1 - f)) says (56 planes, 3 links), not moved.
    """
    light = [DirectionalLight(travel)]
    exact = light_transmittance(blob_volume, SHARP_TF, 1.0, light, segment_planes=0,
                                device="cpu")[0][0]
    errors = {}
    for segment_planes in (8, 16):
        chained = light_transmittance(blob_volume, SHARP_TF, 1.0, light, device="cpu",
                                      segment_planes=segment_planes)[0][0]
        diff = chained - exact
        errors[segment_planes] = np.abs(diff).mean()
        assert errors[segment_planes] < 0.035
        assert abs(diff.mean()) < 2e-3
    assert errors[16] < errors[8]  # fewer interpolations, less blur
    assert errors[16] < 0.025 and exact.min() < 1e-4
    lo = minimum_filter(exact, size=5, mode="nearest")
    hi = maximum_filter(exact, size=5, mode="nearest")
    assert np.all(chained >= lo - 0.025) and np.all(chained <= hi + 0.025)


def test_several_lights_on_a_grid_unlike_the_data(device):
    """Two directional lights and a point light, light grid shape unlike the data's: the
    point light keeps the exact rays, the directional ones stay within the blur bounds."""
    volume = Volume(sharp_blobs(40, count=14, seed=3)[:, 4:36, :],
                    spacing=(0.7, 0.5, 0.6), direction=rotation((0, 1, 1), 0.4))
    centre = volume.bounds.reshape(3, 2).mean(1)
    lights = [DirectionalLight((0.6, -1.0, 0.35), (1.0, 0.8, 0.6)),
              PointLight(centre + (3.0, 25.0, -4.0), (400.0, 400.0, 400.0)),
              DirectionalLight((-1.0, 0.3, -0.8), (0.2, 0.3, 1.0))]
    shape = (30, 44, 25)
    exact, phi_exact = light_transmittance(volume, SHARP_TF, 1.0, lights, shape=shape,
                                           segment_planes=0, device=device)
    chained, phi = light_transmittance(volume, SHARP_TF, 1.0, lights, shape=shape,
                                       segment_planes=6, device=device)
    assert chained.shape == (3, *shape) and phi.shape == (*shape, 3)
    np.testing.assert_array_equal(chained[1], exact[1])
    for li in (0, 2):
        # L = 6 on 44 and 30 planes: measured mean |dT| 1.9e-2 and 1.0e-2, the exact
        # grid's range over 3³ points holds to 0.089 and 0.075.
        assert np.abs(chained[li] - exact[li]).mean() < 0.03
        assert exact[li].min() < 0.05
        lo = minimum_filter(exact[li], size=3, mode="nearest")
        hi = maximum_filter(exact[li], size=3, mode="nearest")
        assert np.all(chained[li] >= lo - 0.13) and np.all(chained[li] <= hi + 0.13)
    # The fluence is still sum_l T_l E_l.
    x = grid_points(volume, shape)
    e_point = lights[1].intensity / np.maximum(np.sum((x - lights[1].position) ** 2, -1),
                                               1e-12)[..., None]
    expected = (chained[0][..., None] * lights[0].irradiance + chained[1][..., None] * e_point
                + chained[2][..., None] * lights[2].irradiance)
    np.testing.assert_allclose(phi, expected, rtol=1e-4, atol=1e-6)
    # Measured 1.2e-2 of the mean fluence.
    assert np.abs(phi - phi_exact).mean() < 0.02 * np.abs(phi_exact).mean()


def test_split_slabs_give_the_same_grid(monkeypatch):
    """Slab launches split into chunks of a few points (Ctrl-C, progress) change nothing."""
    volume = Volume(sharp_blobs(20, count=6, seed=5), spacing=(0.5, 0.6, 0.4))
    light = [DirectionalLight((0.5, 1.0, -0.4))]  # y dominant: 20 planes, slabs 0-4, 5-8, ...
    whole = light_transmittance(volume, SHARP_TF, 1.0, light, segment_planes=4, device="cpu")
    calls = []
    monkeypatch.setitem(CHUNK_SAMPLES, "cpu", 1000)
    split = light_transmittance(volume, SHARP_TF, 1.0, light, segment_planes=4, device="cpu",
                                progress=calls.append)
    assert len(calls) > 5 * 4  # more launches than slabs
    assert calls[-1] == 1.0 and np.all(np.diff(calls) > 0)
    np.testing.assert_array_equal(split[0], whole[0])
    np.testing.assert_array_equal(split[1], whole[1])
    assert whole[0].min() < 0.5


@pytest.mark.parametrize("bad", [-1, 2.5, True, "16"])
def test_bad_segment_planes_is_rejected(bad):
    volume = Volume(np.ones((4, 4, 4)))
    tf = TransferFunction([0.0, 1.0], [0.2, 0.2])
    with pytest.raises(ValueError, match="segment_planes"):
        light_transmittance(volume, tf, 1.0, [DirectionalLight((1, 1, 0))], device="cpu",
                            segment_planes=bad)


def test_none_is_the_exact_rays():
    volume = Volume(sharp_blobs(24, count=8, seed=2))
    light = [DirectionalLight((0.3, -1.0, 0.6))]
    exact = light_transmittance(volume, SHARP_TF, 1.0, light, segment_planes=0, device="cpu")
    none = light_transmittance(volume, SHARP_TF, 1.0, light, segment_planes=None, device="cpu")
    chained = light_transmittance(volume, SHARP_TF, 1.0, light, segment_planes=3, device="cpu")
    np.testing.assert_array_equal(none[0], exact[0])
    assert np.abs(chained[0] - exact[0]).max() > 1e-3  # the chain is another computation


def test_rendered_image_barely_changes(device):
    """``transmittance`` pictures from the chained and the exact light grid (the grid the
    ``transmittance`` method builds, the default L = 16 on 48 planes): measured relative
    mean difference 1.7e-3 of the mean radiance (1.9e-3 at 96², 7.2e-3 with L = 8)."""
    from vtkillum.core.camera import Camera
    from vtkillum.core.illumination import IlluminationVolume
    from vtkillum.core.raycast import render_illuminated
    from vtkillum.core.scene import Scene

    volume = Volume(sharp_blobs(48, count=16, seed=9))
    centre = volume.bounds.reshape(3, 2).mean(1)
    scene = Scene(transfer_function=TransferFunction([0.0, 0.45, 0.55, 1.0],
                                                     [0.0, 0.0, 0.3, 0.3]),
                  albedo=0.9, anisotropy=0.3,
                  lights=[DirectionalLight((0.7, -1.0, -0.45), (2.0, 2.0, 2.0))],
                  camera=Camera(centre + (20.0, 30.0, 110.0), centre, (0, 1, 0), 30.0))
    tf = scene.resolved_transfer_function(volume)
    u = scene.resolved_unit_distance(volume)
    images = {}
    for segment_planes in (0, 16):
        T = light_transmittance(volume, tf, u, scene.lights, segment_planes=segment_planes,
                                device=device)[0]
        illumination = IlluminationVolume.for_volume(volume, transmittance=T)
        images[segment_planes] = render_illuminated(volume, scene, 48, 48, device,
                                                    illumination=illumination,
                                                    jitter=False).radiance
    exact, chained = images[0], images[16]
    assert exact.mean() > 0 and np.abs(exact - chained).max() > 0
    assert np.abs(chained - exact).mean() < 3e-3 * exact.mean()
