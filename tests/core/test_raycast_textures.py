"""The ray caster's hardware-filtered texture path (CUDA) against its exact array path."""

import numpy as np
import pytest
from test_ambient_textures import blobby

from vtkillum.core.convection_diffusion.render import render_convection_diffusion
from vtkillum.core.illumination import IlluminationVolume
from vtkillum.core.raycast import render_emission, render_illuminated
from vtkillum.core.render import render
from vtkillum.core.textures import textures_available

#: 8-bit interpolation weights: mean difference from the exact path relative to the
#: image's maximum, and the largest single-pixel difference (jitter off, same samples).
MEAN_TOL = 2e-3
MAX_TOL = 3e-2


def _compare(a, b):
    scale = float(np.max(np.abs(b))) or 1.0
    diff = np.abs(a - b) / scale
    return float(diff.mean()), float(diff.max())


def test_option_is_checked_and_reported():
    vol, _, scene = blobby((10, 9, 8))
    with pytest.raises(ValueError, match="textures must be true or false"):
        render_emission(vol, scene, 8, 8, device="cpu", textures="yes")
    res = render_emission(vol, scene, 8, 8, device="cpu")
    assert res.info["textures"] is False  # no texture units on the CPU: the exact path


@pytest.mark.parametrize("method", ["emission", "transmittance"])
def test_textures_match_arrays(device, method):
    if not textures_available(device):
        pytest.skip("texture units need a CUDA device")
    vol, _, scene = blobby()
    exact = render(vol, scene, method, 64, 56, device, jitter=False, textures=False)
    fast = render(vol, scene, method, 64, 56, device, jitter=False)
    assert fast.info["textures"] is True and exact.info["textures"] is False
    mean, worst = _compare(fast.radiance, exact.radiance)
    assert mean < MEAN_TOL and worst < MAX_TOL, (mean, worst)
    mean_a, worst_a = _compare(fast.alpha, exact.alpha)
    assert mean_a < MEAN_TOL and worst_a < MAX_TOL, (mean_a, worst_a)


def test_scattered_fluence_texture(device):
    """An RGB scattered fluence with a large unit (half precision in units of its maximum)
    and two lights' transmittance stacked in one texture."""
    if not textures_available(device):
        pytest.skip("texture units need a CUDA device")
    vol, _, scene = blobby()
    rng = np.random.default_rng(3)
    fluence = (1.0e5 * rng.random((*vol.dims, 3))).astype(np.float32)
    trans = rng.random((2, 12, 11, 10)).astype(np.float32)
    illum = IlluminationVolume.for_volume(vol, fluence, trans)
    exact = render_illuminated(vol, scene, 48, 40, device, illumination=illum, jitter=False,
                               textures=False)
    fast = render_illuminated(vol, scene, 48, 40, device, illumination=illum, jitter=False)
    assert fast.info["textures"] is True
    mean, worst = _compare(fast.radiance, exact.radiance)
    assert mean < MEAN_TOL and worst < MAX_TOL, (mean, worst)


def test_convection_diffusion_through_textures(device):
    if not textures_available(device):
        pytest.skip("texture units need a CUDA device")
    vol, _, scene = blobby()
    exact = render_convection_diffusion(vol, scene, 48, 40, device, jitter=False, textures=False)
    fast = render_convection_diffusion(vol, scene, 48, 40, device, jitter=False)
    mean, worst = _compare(fast.radiance, exact.radiance)
    assert mean < MEAN_TOL and worst < MAX_TOL, (mean, worst)


def test_chained_light_grid_through_textures(device):
    """The chained segments of the light grid read textures on CUDA: within the texture
    units' rounding of the exact sampling."""
    if not textures_available(device):
        pytest.skip("texture units need a CUDA device")
    from vtkillum.core.light_transmittance import light_transmittance

    vol, tf, scene = blobby()
    lights = [scene.lights[0]]  # the directional one: chained
    exact, _ = light_transmittance(vol, tf, 1.0, lights, device=device, textures=False)
    fast, _ = light_transmittance(vol, tf, 1.0, lights, device=device)
    diff = np.abs(fast - exact)
    assert diff.mean() < MEAN_TOL and diff.max() < MAX_TOL, (diff.mean(), diff.max())
