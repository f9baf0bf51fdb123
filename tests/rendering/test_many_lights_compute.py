"""The compute path shows ``many-lights`` by its registered name (no mapper changes)."""

import numpy as np
from helpers import offscreen_window, read_window_rgb
from vtkmodules.vtkRenderingCore import vtkRenderer

from vtkillum.core.render import render
from vtkillum.core.tonemap import tonemap
from vtkillum.data.accuracy_suite import _medium_scene, _side_light, cloud
from vtkillum.mappers import ComputeVolumeRenderer
from vtkillum.mappers.camera_bridge import camera_from_vtk

SIZE = 20
OPTIONS = {"count": 32, "avsm_resolution": 8, "jitter": False, "seed": 2}


def test_compute_path_shows_the_many_light_image():
    volume = cloud(16)
    scene = _medium_scene(volume, 6.0, 0.9, 0.3, [_side_light()])
    renderer = vtkRenderer()
    window = offscreen_window(renderer, scene.resolved_camera(volume), SIZE, SIZE)
    shown = ComputeVolumeRenderer(renderer, volume, scene, method="many-lights", device="cpu",
                                  **OPTIONS)
    image = read_window_rgb(window)
    scene.camera = camera_from_vtk(renderer.GetActiveCamera(), aspect=1.0)
    expected = render(volume, scene, "many-lights", SIZE, SIZE, "cpu", **OPTIONS)
    assert shown.result.info["method"] == "many-lights"
    np.testing.assert_allclose(shown.result.radiance, expected.radiance, rtol=1e-5, atol=1e-8)
    shown_rgb = tonemap(expected.radiance, expected.alpha, (0.0, 0.0, 0.0), gamma=1.0)
    assert np.abs(image * 255.0 - shown_rgb).max() <= 1.0
    assert (image.max(-1) > 0.02).mean() > 0.2
    window.Finalize()


def test_many_lights_refine_while_the_camera_rests():
    """Progressive like ``path``: refine() adds VL sets up to max_sets, the mean of the sets."""
    volume = cloud(16)
    scene = _medium_scene(volume, 6.0, 0.9, 0.3, [_side_light()])
    renderer = vtkRenderer()
    window = offscreen_window(renderer, scene.resolved_camera(volume), SIZE, SIZE)
    shown = ComputeVolumeRenderer(renderer, volume, scene, method="many-lights", device="cpu",
                                  max_sets=3, **OPTIONS)
    window.Render()
    assert shown.passes == 1
    first = shown.result.radiance.copy()
    assert shown.refine(5) == 3  # capped at max_sets
    assert shown.result.info["sets"] == 3
    assert not np.array_equal(first, shown.result.radiance)
    assert shown.refine(1) == 3
    window.Finalize()
