"""Convection–diffusion against the unbiased path tracer (issue 8's targets, small sizes).

Thick high-albedo media (albedo >= 0.9): relative RMSE <= 0.20 and the image sum within
10 % of the path tracer's; thin media: no worse than the previous default (Zhang & Ma's
model without diffusion, i.e. isotropic single scattering from the light volume).
The relative RMSE is ``||img - ref|| / ||ref||`` over pixels and channels; the
convection–diffusion image is rendered at 2x2 samples per pixel and box-filtered, as the
path tracer's pixels are (jittered sub-pixel positions). 32^3 volumes, 32x32 images,
512 samples per pixel (the reference's own noise is about 0.04 of this measure).
"""

import numpy as np
import pytest

from vtkillum.core.camera import Camera
from vtkillum.core.lights import DirectionalLight, PointLight
from vtkillum.core.render import render
from vtkillum.core.scene import Scene
from vtkillum.core.transfer_function import TransferFunction
from vtkillum.core.volume import Volume
from vtkillum.data.builtin import builtin_scene, load_builtin
from vtkillum.data.procedural import _fbm

SIZE, SS, SPP = 32, 2, 512


def ball(n=32, radius=0.7, edge=0.08):
    g = np.linspace(-1, 1, n)
    x, y, z = np.meshgrid(g, g, g, indexing="ij")
    r = np.sqrt(x**2 + y**2 + z**2)
    return Volume(np.clip((radius - r) / edge + 0.5, 0, 1).astype(np.float32),
                  spacing=(2 / (n - 1),) * 3, origin=(-1, -1, -1))


def cloud(n=32, seed=3):
    """An ellipsoidal cloud with fractal noise, optical diameter about 40."""
    g = np.linspace(-1, 1, n)
    x, y, z = np.meshgrid(g, g, g, indexing="ij")
    rng = np.random.default_rng(seed)
    lattices = [rng.random((8, 8, 8)).astype(np.float32) for _ in range(4)]
    noise = _fbm(np.stack([x, y, z], -1) * 2.0 + 4.0, lattices, 4)
    r = np.sqrt((x / 0.85) ** 2 + (y / 0.6) ** 2 + (z / 0.75) ** 2)
    d = np.clip((1.0 - r) * 2.5 + (noise - 0.5) * 2.0, 0, 1)
    return Volume(d.astype(np.float32), spacing=(2 / (n - 1),) * 3, origin=(-1, -1, -1))


def camera(vol):
    return Camera.looking_at_bounds(vol.bounds, direction=(0.3, -0.2, -1.0), view_up=(0, 1, 0))


def scene(name):
    if name.startswith("ball"):
        v = ball()
        tf = TransferFunction([0.0, 1.0], [0.0, 1 - np.exp(-0.6)])  # optical radius ~6.5
        albedo = {"ball90": 0.9, "ball99": 0.99, "ball99g8": 0.99}[name]
        g = 0.8 if name == "ball99g8" else 0.0  # strongly forward: delta-Eddington's case
        return v, Scene(transfer_function=tf, opacity_unit_distance=v.mean_spacing(),
                        albedo=albedo, anisotropy=g,
                        lights=[DirectionalLight((1.0, -0.5, -0.3), (3, 3, 3))],
                        camera=camera(v))
    if name == "cloud":
        v = cloud()
        tf = TransferFunction([0.0, 1.0], [0.0, 1 - np.exp(-2.0)])
        return v, Scene(transfer_function=tf, opacity_unit_distance=v.mean_spacing(),
                        albedo=0.95, anisotropy=0.4,
                        lights=[DirectionalLight((1.0, -0.6, -0.4), (3, 3, 3))], camera=camera(v))
    if name == "point":
        v = cloud()
        tf = TransferFunction([0.0, 1.0], [0.0, 1 - np.exp(-1.0)], [[1, 1, 1], [1.0, 0.8, 0.6]])
        return v, Scene(transfer_function=tf, opacity_unit_distance=v.mean_spacing(),
                        albedo=0.9, lights=[PointLight((1.3, 0.8, 0.9), (12, 12, 12))],
                        camera=camera(v))
    spec = {"plume": "builtin:plume:32", "ct": "builtin:ct:32"}[name]
    v = load_builtin(spec)
    return v, builtin_scene(spec, v)


def rel_rmse(img, ref):
    return float(np.sqrt(((img - ref) ** 2).sum() / (ref**2).sum()))


def convection_diffusion(vol, sc, device, **options):
    r = render(vol, sc, "convection-diffusion", SIZE * SS, SIZE * SS, device=device, seed=1,
               **options)
    return r.radiance.reshape(SIZE, SS, SIZE, SS, 3).mean(axis=(1, 3))


@pytest.fixture(scope="module")
def references():
    cache = {}

    def get(name, vol, sc, device):
        if (name, device) not in cache:
            cache[name, device] = render(vol, sc, "path", SIZE, SIZE, device=device, spp=SPP,
                                         seed=5).radiance
        return cache[name, device]

    return get


@pytest.mark.parametrize("name", ["cloud", "ball90", "ball99", "point"])
def test_thick_high_albedo_media_match_the_path_tracer(device, references, name):
    vol, sc = scene(name)
    ref = references(name, vol, sc, device)
    img = convection_diffusion(vol, sc, device)
    error, energy = rel_rmse(img, ref), img.sum() / ref.sum()
    old = convection_diffusion(vol, sc, device, diffusion_model="paper")  # the old default
    old_error, old_energy = rel_rmse(old, ref), old.sum() / ref.sum()
    print(f"{name}: physical {error:.3f} / {energy:.3f}; old default {old_error:.3f} / "
          f"{old_energy:.3f}")
    assert error <= 0.20 and abs(energy - 1.0) <= 0.10
    # The targets discriminate: without multiple scattering the same scenes fail them.
    assert old_error > 0.3 and old_energy < 0.7


@pytest.mark.parametrize("name", ["plume", "ct"])
def test_thin_and_layered_media_no_worse_than_before(device, references, name):
    vol, sc = scene(name)
    ref = references(name, vol, sc, device)
    img = convection_diffusion(vol, sc, device)
    error, energy = rel_rmse(img, ref), img.sum() / ref.sum()
    paper = convection_diffusion(vol, sc, device, diffusion_model="paper")  # the scene's sigma_hat_s
    old = convection_diffusion(vol, sc, device, diffusion_model="paper", scattering=[0.0] * 3)
    print(f"{name}: physical {error:.3f} / {energy:.3f}; paper {rel_rmse(paper, ref):.3f}; "
          f"old default {rel_rmse(old, ref):.3f}")
    assert error <= rel_rmse(old, ref) and error <= rel_rmse(paper, ref)
    assert error <= 0.25 and abs(energy - 1.0) <= 0.15


def test_delta_scaling_is_what_brings_forward_scattering_within_the_targets(device, references):
    """Albedo 0.99, g 0.8: without δ-Eddington scaling the diffusion seeds the scattered
    light where the beam enters, and the lit side is far too bright (here 0.36 / 1.25;
    scaled 0.28 / 1.07: the energy within the target; the rel. RMSE reaches it at the
    suite's 96^3, 0.175 / 1.08 in docs/accuracy.md, not on this 32^3 ball)."""
    vol, sc = scene("ball99g8")
    ref = references("ball99g8", vol, sc, device)
    plain = convection_diffusion(vol, sc, device, delta_scaling=False)
    scaled = convection_diffusion(vol, sc, device)
    print(f"ball99g8: plain {rel_rmse(plain, ref):.3f} / {plain.sum() / ref.sum():.3f}; "
          f"delta {rel_rmse(scaled, ref):.3f} / {scaled.sum() / ref.sum():.3f}")
    assert rel_rmse(scaled, ref) < rel_rmse(plain, ref) - 0.05
    assert abs(scaled.sum() / ref.sum() - 1.0) <= 0.10 < abs(plain.sum() / ref.sum() - 1.0)
