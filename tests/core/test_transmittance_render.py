"""The ``transmittance`` method (cached shadow volume + ray casting) against ``single``."""

import numpy as np
import pytest

from vtkillum.core.camera import Camera
from vtkillum.core.lights import DirectionalLight, PointLight
from vtkillum.core.render import render
from vtkillum.core.scene import Scene
from vtkillum.core.transfer_function import TransferFunction
from vtkillum.core.volume import Volume


def _scene_and_volume(g=0.0):
    n = 24
    x = np.linspace(-1, 1, n)
    X, Y, Z = np.meshgrid(x, x, x, indexing="ij")
    blob = np.exp(-((X - 0.2) ** 2 + Y**2 + (Z + 0.1) ** 2) / 0.3)
    volume = Volume(blob, spacing=(2 / (n - 1),) * 3, origin=(-1, -1, -1))
    scene = Scene(
        transfer_function=TransferFunction([0.0, 1.0], [0.0, 0.8], [[1, 1, 1], [1, 0.7, 0.5]]),
        albedo=0.9, anisotropy=g,
        lights=[DirectionalLight((1.0, -0.5, -0.3), (1.0, 1.0, 1.0)),
                PointLight((0.0, 1.6, 0.4), (2.0, 2.0, 2.0))],
        camera=Camera((0.3, 0.4, 4.0), (0, 0, 0), (0, 1, 0), 35.0),
    )
    return volume, scene


def test_agrees_with_single_for_isotropic_scattering(device):
    volume, scene = _scene_and_volume()
    cached = render(volume, scene, "transmittance", 40, 40, device, jitter=False)
    direct = render(volume, scene, "single", 40, 40, device, jitter=False)
    ref = direct.radiance.max()
    err = np.abs(cached.radiance - direct.radiance) / ref
    # The light grid is the data grid: only the trilinear interpolation of T differs.
    assert err.mean() < 0.01 and np.percentile(err, 99) < 0.05
    assert np.allclose(cached.alpha, direct.alpha, atol=1e-5)
    assert cached.info["light_volume_shape"] == volume.dims


def test_coarse_light_grid_stays_close(device):
    volume, scene = _scene_and_volume()
    fine = render(volume, scene, "transmittance", 32, 32, device, jitter=False)
    coarse = render(volume, scene, "transmittance", 32, 32, device, jitter=False,
                    light_volume_scale=0.5)
    assert coarse.info["light_volume_shape"] == (13, 13, 13)
    assert np.abs(coarse.radiance - fine.radiance).mean() < 0.05 * fine.radiance.max()


def test_bad_scale():
    volume, scene = _scene_and_volume()
    with pytest.raises(ValueError, match="light_volume_scale"):
        render(volume, scene, "transmittance", 8, 8, "cpu", light_volume_scale=0)


def test_camera_change_reuses_the_light_volumes_an_edit_does_not(device, monkeypatch):
    """Camera-independent work is kept with the Volume between renders (interactive windows)."""
    from vtkillum.core import transmittance_render
    from vtkillum.core.camera import Camera

    calls = []
    original = transmittance_render.light_transmittance

    def counting(*args, **kwargs):
        calls.append(1)
        return original(*args, **kwargs)

    monkeypatch.setattr(transmittance_render, "light_transmittance", counting)
    volume, scene = _scene_and_volume()
    render(volume, scene, "transmittance", 16, 16, device)
    scene.camera = Camera((2.0, 0.4, 3.0), (0, 0, 0), (0, 1, 0), 35.0)
    render(volume, scene, "transmittance", 16, 16, device)
    assert len(calls) == 1
    scene.lights = scene.lights[:1]
    render(volume, scene, "transmittance", 16, 16, device)
    assert len(calls) == 2

    cd_first = render(volume, scene, "convection-diffusion", 16, 16, device)
    assert cd_first.info["convection_diffusion"]["opacity"]
    scene.camera = Camera((0.3, 0.4, 4.0), (0, 0, 0), (0, 1, 0), 35.0)
    cd_moved = render(volume, scene, "convection-diffusion", 16, 16, device)
    stats = cd_moved.info["convection_diffusion"]
    assert not stats["opacity"] and not stats["convected"] and not stats["diffused"]

    scene.transfer_function = TransferFunction([0.0, 1.0], [0.0, 0.5])
    cd_edited = render(volume, scene, "convection-diffusion", 16, 16, device)
    assert cd_edited.info["convection_diffusion"]["opacity"]
    assert not np.allclose(cd_edited.radiance, cd_moved.radiance)
