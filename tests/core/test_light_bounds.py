"""Point lights are bounded everywhere: I / max(d, r)**2 in every method (issue 15, rows 1, 3)."""

import numpy as np
import pytest

from vtkillum.core.camera import Camera
from vtkillum.core.lights import MAX_VALUE, DirectionalLight, PointLight, light_from_dict
from vtkillum.core.render import render
from vtkillum.core.scene import Scene
from vtkillum.core.transfer_function import TransferFunction
from vtkillum.core.volume import Volume


def blob24():
    x = np.arange(24) - 11.5
    X, Y, Z = np.meshgrid(x, x, x, indexing="ij")
    return Volume((0.92 * np.exp(-(X**2 + Y**2 + Z**2) / 60.0)).astype(np.float32))


def light_on_a_grid_point():
    """The probe's case: a point light exactly on grid point (12, 12, 12), inside the blob."""
    volume = blob24()
    scene = Scene(transfer_function=TransferFunction([0.0, 0.92], [0.0, 0.3]),
                  lights=[PointLight((12, 12, 12), (50, 50, 50))],
                  camera=Camera((11.5, 11.5, 70.0), (11.5, 11.5, 11.5), (0, 1, 0), 30.0))
    return volume, scene


def test_light_on_a_grid_point_gives_the_same_bounded_image_in_every_method(device):
    """Before: transmittance 4e10, single 0.34, path 1.7 on this scene. Now every method
    evaluates I / max(d, r)^2 with r half a voxel: single scattering agrees with the path
    tracer's single-scattering estimate (measured: 22.8 / 22.6 vs 23.0 +- 0.3)."""
    volume, scene = light_on_a_grid_point()
    path = render(volume, scene, "path", 32, 32, device, spp=256, seed=3, max_bounces=1)
    images = {m: render(volume, scene, m, 32, 32, device).radiance
              for m in ("single", "transmittance", "convection-diffusion", "ambient-scattering")}
    ref = path.radiance.astype(np.float64)
    for method, img in images.items():
        assert np.all(np.isfinite(img)) and img.min() >= 0, method
        assert img.max() < 50 * ref.max(), (method, img.max(), ref.max())
    sigma = np.sqrt(path.info["radiance_variance"].sum())
    for method in ("single", "transmittance"):
        total = images[method].astype(np.float64).sum()
        assert abs(total - ref.sum()) < 0.03 * ref.sum() + 3 * sigma, (method, total, ref.sum())


def test_source_radius_caps_the_irradiance(device):
    volume, scene = light_on_a_grid_point()
    small = render(volume, scene, "single", 16, 16, device).radiance
    scene.lights = [PointLight((12, 12, 12), (50, 50, 50), radius=4.0)]
    big = render(volume, scene, "single", 16, 16, device).radiance
    assert big.max() < small.max()  # a larger sphere spreads the same power over more area


def test_lights_beyond_float32_are_refused_with_a_clear_error():
    with pytest.raises(ValueError, match="overflow"):
        DirectionalLight((0, 0, -1), (1e40, 1, 1))
    # A world may use any length unit (vtkillum.core.units), so the light is refused where
    # it meets the volume's scale: by render, before anything runs.
    far = PointLight((1e20, 0, 0), (1, 1, 1))
    volume, scene = light_on_a_grid_point()
    scene.lights = [far]
    with pytest.raises(ValueError, match="directional light"):
        render(volume, scene, "single", 8, 8, "cpu")
    with pytest.raises(ValueError, match="radius"):
        PointLight((0, 0, 0), (1, 1, 1), radius=-1)
    assert MAX_VALUE == 1e30
    # The largest accepted values still give finite images.
    volume, scene = light_on_a_grid_point()
    scene.lights = [DirectionalLight((0, 0, -1), (MAX_VALUE,) * 3),
                    PointLight((1e15, 0, 0), (MAX_VALUE,) * 3)]
    for method in ("single", "transmittance", "ambient-scattering", "convection-diffusion"):
        img = render(volume, scene, method, 8, 8, "cpu").radiance
        assert np.all(np.isfinite(img)), method


def test_radius_round_trips_through_the_scene_file():
    light = light_from_dict({"type": "point", "position": [1, 2, 3], "intensity": [1, 1, 1],
                             "radius": 0.25}, 0)
    assert light.radius == 0.25
    assert light_from_dict(light.to_dict()).radius == 0.25
    assert "radius" not in PointLight((0, 0, 0)).to_dict()
