"""The compute path shows ``many-lights``: its image, progressive sets, edits that keep the
virtual lights."""

import copy

import numpy as np
from helpers import offscreen_window, read_window_rgb
from vtkmodules.vtkRenderingCore import vtkRenderer

from vtkillum.core.render import render
from vtkillum.core.tonemap import tonemap
from vtkillum.data.accuracy_suite import _medium_scene, _side_light, cloud
from vtkillum.mappers import ComputeVolumeRenderer
from vtkillum.mappers.camera_bridge import camera_from_vtk

SIZE = 20
OPTIONS = {"count": 32, "avsm_resolution": 8, "jitter": False, "seed": 2, "sets": 1}


def shown_cloud(scene=None, **options):
    """A cloud in an offscreen window shown by a many-lights compute renderer:
    ``(volume, scene, renderer, window, shown)``."""
    volume = cloud(16)
    if scene is None:
        scene = _medium_scene(volume, 6.0, 0.9, 0.3, [_side_light()])
    renderer = vtkRenderer()
    window = offscreen_window(renderer, scene.resolved_camera(volume), SIZE, SIZE)
    shown = ComputeVolumeRenderer(renderer, volume, scene, method="many-lights", device="cpu",
                                  **options, **OPTIONS)
    return volume, scene, renderer, window, shown


def test_compute_path_shows_the_many_light_image():
    volume, scene, renderer, window, shown = shown_cloud()
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
    _volume, _scene, _renderer, window, shown = shown_cloud(max_sets=3)
    window.Render()
    assert shown.passes == 1
    first = shown.result.radiance.copy()
    assert shown.refine(5) == 3  # capped at max_sets
    assert shown.result.info["sets"] == 3
    assert not np.array_equal(first, shown.result.radiance)
    assert shown.refine(1) == 3
    window.Finalize()


def test_many_lights_edit_keeps_the_lights_and_regenerates_progressively():
    """A transfer-function edit through set_scene: the next image is the paper's immediate
    update of the same VLs, refine() regenerates the stale paths a fraction per pass, and
    once none is stale the image equals a fresh renderer's with the edited scene."""
    from vtkillum.core.transfer_function import TransferFunction

    volume, scene, _renderer, window, shown = shown_cloud(update_fraction=0.3)
    window.Render()
    before = shown.result.radiance.copy()
    tracer = shown._tracer
    tf = scene.transfer_function
    edited = copy.copy(scene)
    edited.transfer_function = TransferFunction(tf.scalars, np.asarray(tf.opacity) * 2.0,
                                                tf.colors)
    shown.set_scene(edited)
    window.Render()
    assert shown._tracer is tracer  # the VLs were kept
    assert shown.result.info["stale_paths"] > 0
    assert not np.array_equal(before, shown.result.radiance)
    frames = 0
    while shown.result.info["stale_paths"] > 0:
        shown.refine(1)
        assert shown.refined
        frames += 1
        assert frames < 10
    assert frames >= 2  # a fraction of the paths per pass

    *_, other_window, fresh = shown_cloud(edited, update_fraction=0.3)
    other_window.Render()
    np.testing.assert_allclose(shown.result.radiance, fresh.result.radiance, rtol=1e-4,
                               atol=1e-7)

    # Other many-lights options: a new set of lights.
    more = copy.copy(edited)
    more.options = copy.deepcopy(edited.options)
    more.options["many_lights"]["avsm_nodes"] = 6
    shown.set_scene(more)
    window.Render()
    assert shown._tracer is not tracer
    window.Finalize()
    other_window.Finalize()
