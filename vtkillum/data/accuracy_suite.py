"""The accuracy suite: scenes on which every method is compared with the path tracer.

Each entry builds a volume and a scene at a requested resolution, so that the same
scenes serve the tests (small), the CPU benchmark and the GPU benchmark
(``benchmarks/accuracy.py``, whose output is ``docs/accuracy.md``). Together they
cover thin and thick media, albedo 0.5, 0.9, 0.95 and 0.99, anisotropy −0.3, 0,
0.4 and 0.8, directional and point lights, and a layered CT-like volume.

Extinction is set by optical thickness rather than by opacity so that the scenes
keep their character at any resolution: :func:`sigma_transfer_function` builds
the opacity transfer function that gives a wanted ``sigma_t`` (1/world unit) with
the unit distance ``u`` the scene uses.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from vtkillum.core.camera import Camera
from vtkillum.core.lights import DirectionalLight, PointLight
from vtkillum.core.scene import Scene
from vtkillum.core.transfer_function import TransferFunction
from vtkillum.core.volume import Volume
from vtkillum.data.procedural import _fbm, _smoothstep, ct_phantom, default_scene, smoke_plume


@dataclass(frozen=True)
class SuiteScene:
    """One scene of the suite.

    Attributes
    ----------
    name : str
    description : str
        Medium, albedo, g and lights in words (the table's first column).
    build : callable
        ``build(n) -> (Volume, Scene)`` with about ``n`` points along the longest axis.
    thick : bool
        Optically thick with albedo >= 0.9: where multiple scattering dominates.
    """

    name: str
    description: str
    build: Callable[[int], tuple]
    thick: bool = False


def sigma_transfer_function(scalars, sigma_t, colors, unit_distance: float) -> TransferFunction:
    """Opacity transfer function giving extinction ``sigma_t`` at ``scalars`` for ``u``.

    ``alpha = 1 - exp(-sigma_t * u)``, the inverse of the project's
    ``sigma_t = -ln(1 - alpha) / u``.
    """
    alpha = 1.0 - np.exp(-np.asarray(sigma_t, dtype=np.float64) * float(unit_distance))
    return TransferFunction(scalars, np.minimum(alpha, 0.999999), colors)


def cloud(n: int = 64, seed: int = 3) -> Volume:
    """A cumulus-like cloud: a ball in [-1, 1]³ whose edge is eroded by fractal noise.

    Density in [0, 1]: 1 inside, smooth over about 0.15 world units at the edge,
    wisps where the noise pushes the boundary out.
    """
    n = int(n)
    h = 2.0 / (n - 1)
    x = -1.0 + h * np.arange(n)
    X, Y, Z = np.meshgrid(x, x, x, indexing="ij", sparse=True)
    rng = np.random.default_rng(seed)
    lattices = [rng.random((16, 16, 16), dtype=np.float32) for _ in range(4)]
    q = np.stack(np.broadcast_arrays(2.5 * X, 2.5 * Y, 2.5 * Z), -1).astype(np.float32)
    noise = _fbm(q + 5.3, lattices)
    r = np.sqrt(X * X + Y * Y + Z * Z * 1.2)
    edge = r + 0.9 * (noise - 0.5)
    density = _smoothstep(0.78, 0.6, edge)
    return Volume(density.astype(np.float32), (h, h, h), (-1.0, -1.0, -1.0))


def smooth_ball(n: int = 64, radius: float = 0.7) -> Volume:
    """A homogeneous ball in [-1, 1]³ with an edge ramp of two voxels."""
    n = int(n)
    h = 2.0 / (n - 1)
    x = -1.0 + h * np.arange(n)
    X, Y, Z = np.meshgrid(x, x, x, indexing="ij", sparse=True)
    r = np.sqrt(X * X + Y * Y + Z * Z)
    return Volume(np.clip((radius - r) / (2 * h) + 0.5, 0.0, 1.0).astype(np.float32),
                  (h, h, h), (-1.0, -1.0, -1.0))


def _cube_camera(direction=(0.55, 0.35, 1.0), distance: float = 5.2) -> Camera:
    d = np.asarray(direction, dtype=np.float64)
    d /= np.linalg.norm(d)
    return Camera(distance * d, (0.0, 0.0, 0.0), (0.0, 1.0, 0.0), 30.0)


def _medium_scene(volume, optical_diameter, albedo, g, lights, colour=(1.0, 1.0, 1.0)):
    """A scene whose dense part has ``optical_diameter`` across 1.4 world units."""
    u = float(volume.mean_spacing())
    sigma = optical_diameter / 1.4
    tf = sigma_transfer_function([0.0, 0.05, 1.0], [0.0, 0.0, sigma], [colour] * 3, u)
    return Scene(transfer_function=tf, opacity_unit_distance=u, albedo=albedo, anisotropy=g,
                 lights=lights, camera=_cube_camera(), background=(0.0, 0.0, 0.0))


def _side_light(e=3.0):
    return DirectionalLight((-1.0, -0.6, -0.5), (e, e, e))


def _thin_plume(n):
    volume = smoke_plume(shape=(n * 2 // 3, n * 2 // 3, n))
    scene = default_scene("plume", volume)
    scene.opacity_unit_distance = 0.2  # 5x thinner than the built-in scene
    scene.albedo, scene.anisotropy = 0.9, 0.0
    scene.lights = [DirectionalLight((1.0, 0.5, -0.6), (10.0, 10.0, 10.0))]
    scene.background = np.zeros(3)
    return volume, scene


def _thick_cloud(n):
    volume = cloud(n)
    return volume, _medium_scene(volume, 30.0, 0.95, 0.4, [_side_light()])


def _forward_ball(n):
    volume = smooth_ball(n)
    return volume, _medium_scene(volume, 20.0, 0.99, 0.8, [_side_light()])


def _absorbing_point(n):
    volume = cloud(n)
    light = PointLight((0.4, 1.6, 0.9), (12.0, 11.0, 10.0))
    return volume, _medium_scene(volume, 12.0, 0.5, -0.3, [light], colour=(1.0, 0.9, 0.8))


def _cloud_point(n):
    volume = cloud(n)
    light = PointLight((-1.5, 1.2, 0.8), (20.0, 20.0, 20.0))
    return volume, _medium_scene(volume, 15.0, 0.9, 0.4, [light])


def _ct(n):
    volume = ct_phantom(n)
    scene = default_scene("ct", volume)
    scene.background = np.zeros(3)
    return volume, scene


SUITE: dict[str, SuiteScene] = {s.name: s for s in [
    SuiteScene("thin-plume", "smoke plume, thin, albedo 0.9, g 0, directional", _thin_plume),
    SuiteScene("thick-cloud", "cloud, optical diameter 30, albedo 0.95, g 0.4, directional",
               _thick_cloud, thick=True),
    SuiteScene("forward-ball", "ball, optical diameter 20, albedo 0.99, g 0.8, directional",
               _forward_ball, thick=True),
    SuiteScene("absorbing-cloud", "cloud, optical diameter 12, albedo 0.5, g -0.3, point light",
               _absorbing_point),
    SuiteScene("cloud-point", "cloud, optical diameter 15, albedo 0.9, g 0.4, point light",
               _cloud_point, thick=True),
    SuiteScene("ct-layered", "CT phantom (skin, tissue, lesion, bone), albedo 0.9, g 0, "
               "2 directional", _ct),
]}


def build(name: str, n: int):
    """``(Volume, Scene)`` of suite scene ``name`` with about ``n`` points per axis."""
    if name not in SUITE:
        raise ValueError(f"unknown suite scene {name!r}; known: {sorted(SUITE)}")
    return SUITE[name].build(int(n))
