"""The interleaved plane sweep (Magnus & Bruckner 2017, Algorithm 1) against references.

* η ≡ 1, m ≡ white reduces to the project's single scattering (``single``,
  ``transmittance``) with one directional light;
* a Luneburg lens focuses parallel light on its far side, with the on-axis
  brightening the intensity law predicts;
* the intensity correction conserves the flux through a lens;
* the medium colour tints light and view rays by ``m`` per unit distance.
"""

import sys
from pathlib import Path

import numpy as np
import pytest

from vtkillum.core.camera import Camera
from vtkillum.core.lights import DirectionalLight
from vtkillum.core.refraction.optics import RefractiveOptics
from vtkillum.core.refraction.render import render_refraction
from vtkillum.core.render import render
from vtkillum.core.scene import Scene
from vtkillum.core.transfer_function import TransferFunction
from vtkillum.core.volume import Volume

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from helpers import blob_tf, blob_volume, zoomed_camera  # noqa: E402


def rel_rmse(a, b):
    return float(np.sqrt(np.mean((a - b) ** 2)) / np.sqrt(np.mean(b ** 2)))


def blob_scene(g=0.3):
    volume = blob_volume()
    camera = zoomed_camera(volume)
    light = DirectionalLight(camera.forward + np.array([0.5, -0.4, 0.2]), (3.0, 3.0, 3.0))
    return volume, Scene(transfer_function=blob_tf(), lights=[light], camera=camera, anisotropy=g)


def test_identity_optics_reduce_to_single_scattering(device):
    """η ≡ 1, m ≡ white, no blur: the sweep renders the project's single scattering."""
    volume, scene = blob_scene(g=0.3)
    step = 0.5 * float(volume.spacing.min())
    ours = render_refraction(volume, scene, 40, 40, device, sample_distance=0.5, softness=0.0)
    single = render(volume, scene, "single", 40, 40, device, jitter=False, step_size=step)
    assert ours.info["planes"] > 40
    assert rel_rmse(ours.radiance, single.radiance) < 0.01
    assert ours.radiance.sum() / single.radiance.sum() == pytest.approx(1.0, abs=0.01)
    assert np.abs(ours.alpha - single.alpha).max() < 0.01
    transmittance = render(volume, scene, "transmittance", 40, 40, device, jitter=False,
                           step_size=step)
    assert rel_rmse(ours.radiance, transmittance.radiance) < 0.03


def test_identity_ignores_blur_and_defaults(device):
    """Constant η (any value) bends nothing; the direction filter changes nothing then, and a
    constant η of 1.5 renders like η ≡ 1 (to float rounding of the directions)."""
    volume, scene = blob_scene(g=0.0)
    a = render_refraction(volume, scene, 24, 24, device, direction_blur=0.0)
    b = render_refraction(volume, scene, 24, 24, device, direction_blur=1.0,
                          optics=RefractiveOptics([0.0], [1.5]))
    np.testing.assert_allclose(a.radiance, b.radiance, rtol=1e-3, atol=1e-6)


def test_the_identity_test_can_fail(device):
    """A refractive index that varies with the data changes the picture measurably."""
    volume, scene = blob_scene()
    optics = RefractiveOptics([0.0, 1.0], [1.0, 1.3])
    plain = render_refraction(volume, scene, 32, 32, device)
    bent = render_refraction(volume, scene, 32, 32, device, optics=optics)
    assert rel_rmse(bent.radiance, plain.radiance) > 0.05


# --- Luneburg lens ------------------------------------------------------------------------------
R = 10.0
CENTRE = np.array([18.0, 18.0, 14.0])


def luneburg(n=(37, 37, 40)):
    """Data (r/R)² around CENTRE (voxel units); η = sqrt(2 - (r/R)²) inside, 1 outside."""
    x, y, z = (np.arange(k, dtype=np.float64) for k in n)
    X, Y, Z = np.meshgrid(x, y, z, indexing="ij")
    s = ((X - CENTRE[0]) ** 2 + (Y - CENTRE[1]) ** 2 + (Z - CENTRE[2]) ** 2) / R ** 2
    knots = np.linspace(0.0, 1.0, 65)
    optics = RefractiveOptics(np.r_[knots, 1e3], np.r_[np.sqrt(2.0 - knots), 1.0])
    return Volume(s.astype(np.float32)), optics


def axial_scene(light_direction=(0.0, 0.0, 1.0), opacity=0.0):
    """Parallel camera looking along +z at the lens; transparent unless ``opacity``."""
    camera = Camera((CENTRE[0], CENTRE[1], -60.0), (CENTRE[0], CENTRE[1], 0.0), (0.0, 1.0, 0.0),
                    parallel_projection=True, parallel_scale=18.0)
    tf = TransferFunction([0.0], [opacity])
    return Scene(transfer_function=tf, lights=[DirectionalLight(light_direction, (1, 1, 1))],
                 camera=camera)


def light_planes(volume, scene, optics, device, **options):
    result = render_refraction(volume, scene, 37, 37, device, optics=optics, record_light=True,
                               **options)
    g = result.info["geometry"]
    planes = result.info["light_planes"]
    light = np.array([planes[j]["light"] for j in sorted(planes)])
    direction = np.array([planes[j]["direction"] for j in sorted(planes)])
    depth = g.z0 + np.arange(len(light)) * g.dz - 60.0  # camera at z = -60
    return g, light, direction, depth


def on_axis(g, image):
    from scipy.ndimage import map_coordinates

    ax = (np.zeros(2) - g.grid_origin) / g.texel
    return float(map_coordinates(image, [[ax[1]], [ax[0]]], order=1)[0])


def test_luneburg_lens_focuses_on_its_far_side(device):
    """η = sqrt(2 - (r/R)²) focuses parallel light on the sphere's far pole: the brightest
    point of the light field lies within one voxel of it, and on the axis the light
    brightens as the intensity law predicts for the lens's elliptical ray paths:
    ``1 / cos² τ`` with ``sin τ - cos τ = z / R`` (2 at the centre, 5.9 at z = R/2)."""
    volume, optics = luneburg()
    g, light, _, depth = light_planes(volume, axial_scene(), optics, device,
                                      sample_distance=0.5, light_buffer_scale=0.5,
                                      max_concentration=1000.0)
    red = light[..., 0]
    k, b, a = np.unravel_index(np.argmax(red), red.shape)
    peak = np.array([g.grid_origin[0] + a * g.texel, g.grid_origin[1] + b * g.texel,
                     depth[k] - CENTRE[2]])
    assert np.linalg.norm(peak - [0.0, 0.0, R]) <= 1.0
    for z in (0.0, 0.5 * R):
        j = int(round((z + CENTRE[2] + 60.0 - g.z0) / g.dz))
        tau = np.pi / 4 + np.arcsin((depth[j] - CENTRE[2]) / R / np.sqrt(2.0))
        assert on_axis(g, red[j]) == pytest.approx(1.0 / np.cos(tau) ** 2, rel=0.2)
    # Without the intensity correction the rays still bend but no caustic forms.
    _, flat, _, _ = light_planes(volume, axial_scene(), optics, device, sample_distance=0.5,
                                 light_buffer_scale=0.5, max_concentration=1000.0,
                                 intensity_correction=False)
    assert flat.max() <= 1.0 + 1e-5 and red.max() > 50.0


def weak_lens(n=(32, 32, 44), contrast=0.03):
    """A smooth gradient-index lens: data exp(-r²/50) around (15.5, 15.5, 12), η = 1 + 0.03 s.
    It concentrates the light about threefold on its axis by the end of the box, before its
    focus (no caustic inside the volume)."""
    x, y, z = (np.arange(k, dtype=np.float64) for k in n)
    X, Y, Z = np.meshgrid(x, y, z, indexing="ij")
    r2 = (X - 15.5) ** 2 + (Y - 15.5) ** 2 + (Z - 12.0) ** 2
    s = np.exp(-r2 / 50.0)
    return Volume(s.astype(np.float32)), RefractiveOptics([0.0, 1.0], [1.0, 1.0 + contrast])


@pytest.mark.parametrize("light", [(0.0, 0.0, 1.0), (0.45, 0.0, 1.0)])
def test_intensity_correction_conserves_flux(device, light):
    """α = 0, white medium: the flux Σ L cos θ h² through the last plane behind the lens equals
    the flux through the first (within 5 %), while the light is redistributed."""
    volume, optics = weak_lens()
    scene = axial_scene(light)
    scene.camera = Camera((15.5, 15.5, -60.0), (15.5, 15.5, 0.0), (0.0, 1.0, 0.0),
                          parallel_projection=True, parallel_scale=16.0)
    g, L, V, _ = light_planes(volume, scene, optics, device)
    cos = V[..., 2] / np.linalg.norm(V, axis=-1)
    flux = (L[..., 0] * cos).sum((1, 2)) * g.texel ** 2
    assert flux[-1] == pytest.approx(flux[0], rel=0.05)
    assert L[-1, ..., 0].max() > 1.3  # a real lens: the light is concentrated behind it
    assert np.abs(flux[1:] / flux[0] - 1.0).max() < 0.05  # on every plane


def test_medium_colour_tints_light_and_view(device):
    """A transparent slab (α = 0) of medium colour m before a white wall: the wall is seen
    through it and lit through it, so it is tinted by m^((ℓ_view + ℓ_light) / u)."""
    n = (12, 40, 40)  # wide in y: the oblique light reaches the wall through the slab
    z = np.arange(n[2], dtype=np.float64)
    slab = ((z >= 8) & (z <= 16)).astype(np.float64)  # 8 units thick, a one-voxel ramp
    wall = (z >= 30).astype(np.float64)
    # The wall at -1: its edge ramp (0 -> -1) does not pass through the slab's value.
    data = np.broadcast_to(slab - wall, n).astype(np.float32)
    volume = Volume(data)
    m = np.array([0.8, 0.5, 0.3])
    u = 2.0
    tf = TransferFunction([-1.0, -0.5, 0.0, 1.0], [0.5, 0.0, 0.0, 0.0])
    optics = RefractiveOptics([0.0], [1.0], [0.0, 1.0], [[1, 1, 1], m])
    theta = np.radians(30.0)
    camera = Camera((5.5, 19.5, -50.0), (5.5, 19.5, 0.0), (0.0, 1.0, 0.0), parallel_projection=True,
                    parallel_scale=2.0)
    scene = Scene(transfer_function=tf, opacity_unit_distance=u, camera=camera,
                  lights=[DirectionalLight((0.0, np.sin(theta), np.cos(theta)), (1, 1, 1))])
    tinted = render_refraction(volume, scene, 8, 8, device, optics=optics)
    clear = render_refraction(volume, scene, 8, 8, device)
    ratio = tinted.radiance[3:5, 3:5].mean((0, 1)) / clear.radiance[3:5, 3:5].mean((0, 1))
    # m_tf over the slab's ramps is piecewise linear in s: integrate -ln m(s(z)) / u exactly.
    zz = np.linspace(0.0, 29.0, 29001)
    s = np.interp(zz, z, slab)
    kappa = optics.kappa(s, u)
    optical = np.trapezoid(kappa, zz, axis=0)  # per unit length along z
    expected = np.exp(-optical * (1.0 + 1.0 / np.cos(theta)))
    np.testing.assert_allclose(ratio, expected, rtol=0.02)
    assert ratio[2] < 0.05 < ratio[0]  # visibly coloured
    # Without a background to composite, alpha is 1 - (1 - A) mean(M): the medium counts.
    np.testing.assert_allclose(1.0 - tinted.alpha[3:5, 3:5],
                               (1.0 - clear.alpha[3:5, 3:5]) * np.exp(-optical).mean(), rtol=0.02)
