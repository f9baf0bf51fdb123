"""The many-light estimate converges to the path tracer (paper eqs. 4–5, issue 10).

* Point VLs, no clamping, many VL sets, exact (ray-marched) transmittance, on a thin
  low-albedo cloud: the multiple-scattering energy of the sets, combined as one
  estimate, agrees with the path tracer's (full minus single scattering) within the
  spread of the per-set estimates, and the image agrees block by block.
* Virtual spherical lights with the shrinking radius of the progressive renderer on a
  thick, high-albedo cloud (multiple scattering ~85 % of the light): within 5 % of the
  path tracer's energy.

The path tracer uses sub-pixel jitter and the many-light renderer pixel centres, so
images are compared on 4 x 4 pixel blocks.
"""

import numpy as np
import pytest

from vtkillum.core.many_lights.render import ManyLightsRenderer
from vtkillum.core.render import render
from vtkillum.data.accuracy_suite import _medium_scene, _side_light, cloud

SIZE = 16


def blocks(image, b=4):
    h, w, c = image.shape
    return image.reshape(h // b, b, w // b, b, c).mean((1, 3))


def block_rmse(image, reference):
    a, r = blocks(image), blocks(reference)
    return float(np.sqrt(np.mean((a - r) ** 2)) / np.sqrt(np.mean(r ** 2)))


@pytest.fixture(scope="module")
def thin():
    volume = cloud(SIZE)
    scene = _medium_scene(volume, 3.0, 0.5, 0.3, [_side_light()])
    full = render(volume, scene, "path", SIZE, SIZE, "cpu", spp=4096, seed=5)
    single = render(volume, scene, "path", SIZE, SIZE, "cpu", spp=4096, seed=7, max_bounces=1)
    return volume, scene, full.radiance, full.radiance - single.radiance


def test_point_lights_converge_to_path_on_thin_low_albedo(thin):
    volume, scene, full, multiple = thin
    renderer = ManyLightsRenderer(volume, scene, SIZE, SIZE, "cpu", count=64,
                                  virtual_lights="point", transmittance="ray-marching", seed=2)
    per_set, paths = [], []
    energy, n_paths = 0.0, 0
    for _ in range(64):
        renderer.run(1)
        per_set.append(renderer._multiple.sum() - energy)
        paths.append(renderer._paths - n_paths)
        energy, n_paths = renderer._multiple.sum(), renderer._paths
    per_set = np.array(per_set) / np.array(paths) / multiple.sum()
    result = renderer.result()
    ratio = result.info["multiple"].sum() / multiple.sum()
    spread = per_set.std() / np.sqrt(len(per_set))
    assert spread < 0.05, spread
    assert abs(ratio - 1.0) < 4 * spread + 0.01, (ratio, spread)
    assert multiple.sum() > 0.2 * full.sum()  # a scene where the multiple part matters
    assert abs(result.radiance.sum() / full.sum() - 1.0) < 0.04
    assert block_rmse(result.radiance, full) < 0.06


def test_spherical_lights_with_shrinking_radius_on_thick_high_albedo():
    volume = cloud(SIZE)
    scene = _medium_scene(volume, 20.0, 0.95, 0.4, [_side_light()])
    reference = render(volume, scene, "path", SIZE, SIZE, "cpu", spp=2048, seed=5).radiance
    single = render(volume, scene, "single", SIZE, SIZE, "cpu").radiance
    renderer = ManyLightsRenderer(volume, scene, SIZE, SIZE, "cpu", count=256,
                                  transmittance="ray-marching")
    renderer.run(32)
    result = renderer.result()
    assert result.info["radius_shrink"] == pytest.approx(32 ** (-1 / 3))
    assert single.sum() < 0.25 * reference.sum()  # multiple scattering dominates
    assert abs(result.radiance.sum() / reference.sum() - 1.0) < 0.05
    assert block_rmse(result.radiance, reference) < 0.10
