"""IlluminatedVolume while the view moves: ``interactive_near_cells`` and
``interactive_image_sample_distance`` (issue 35).

In a window with an initialised interactor, frame 0 of an accumulation (a drag, or the
still frame that ends it) may march a shorter near field than the frames added at rest.
On the sharp sphere of ``test_mappers.py`` (one-voxel edge, light grid at half the data's
resolution), where the near-field march changes the picture most:

* a moving frame with ``interactive_near_cells = 0`` is, pixel for pixel, the still frame
  of a volume with ``near_cells = 0`` (same sample offsets), and fails the comparison with
  the still ``near_cells = 2`` frame that the default gives;
* the frame added at rest marches ``near_cells`` again (equal to a still window's frame 1),
  so the picture at rest does not depend on the setting;
* ``None`` moves with the still picture's near field (the default is 0: on a GPU it is
  30 % of a moving frame, ``illuminated_volume_mapper.py``'s docstring).

``interactive_image_sample_distance`` (default 2) casts a ray for every second pixel
along x and y while moving: the moving frame is the still picture at a quarter of the
rays (close to it, not equal), and the frames added at rest cast every ray again (equal
to a still window's frame 1). The other tests move at every pixel, to compare exactly.
"""

import numpy as np
import pytest
from helpers import offscreen_window, rel_errors
from test_accumulation import shown as window_levels
from test_mappers import HEIGHT, WIDTH, sharp_sphere, within

pytest.importorskip("vtkmodules.vtkRenderingVolumeOpenGL2")
from vtkmodules.vtkRenderingCore import vtkRenderer
from vtkmodules.vtkRenderingUI import vtkGenericRenderWindowInteractor

from vtkillum.io.convert import image_data_from_volume
from vtkillum.mappers import IlluminatedVolume

EXPOSURE = 3.0


def shown(volume, scene, illumination, interactor: bool, **options):
    """``(window, actor, keep)``: the volume in an offscreen window, showing frame 0 after a
    camera change (a fresh window settles over its first renders)."""
    options = {"interactive_step": 1.0, "interactive_image_sample_distance": 1.0, **options}
    actor = IlluminatedVolume(image_data_from_volume(volume), scene, illumination=illumination,
                              exposure=EXPOSURE, **options)
    renderer = vtkRenderer()
    renderer.AddVolume(actor)
    window = offscreen_window(renderer, scene.camera, WIDTH, HEIGHT)
    keep = [renderer]
    if interactor:  # a drag: VTK's interactor styles raise the window's update rate
        iren = vtkGenericRenderWindowInteractor()
        iren.SetRenderWindow(window)
        iren.Initialize()
        window.SetDesiredUpdateRate(iren.GetDesiredUpdateRate())
        keep.append(iren)
    window.Render()
    window.Render()
    renderer.GetActiveCamera().Azimuth(1.0)  # a camera move: frame 0
    window.Render()
    assert actor.frames == 0
    return window, actor, keep


def shown_rgb(window) -> np.ndarray:
    """What the window shows now, in [0, 1] (no new render: a render would add a frame)."""
    return window_levels(window) / 255.0


def test_moving_frames_read_the_grid_with_interactive_near_cells_0():
    volume, scene, illumination = sharp_sphere()
    still_near0, _, _k1 = shown(volume, scene, illumination, False, near_cells=0.0)
    still, _, _k2 = shown(volume, scene, illumination, False)
    moving, actor, _k3 = shown(volume, scene, illumination, True)
    assert actor.interactive_near_cells == 0.0  # the default
    near0, full, drag = shown_rgb(still_near0), shown_rgb(still), shown_rgb(moving)
    assert full.max() > 0.2  # the picture is lit
    assert np.abs(drag - near0).max() == 0.0
    dropped = rel_errors(drag, full)
    print(f"moving frame (near field 0) vs still (near field 2): mean {dropped[0]:.2e}, "
          f"p99 {dropped[1]:.2e}")
    assert not within(dropped)
    # At rest the added frame marches near_cells again: a still window's frame 1.
    for window in (still, moving):
        window.Render()
    assert actor.frames == 1
    assert np.abs(shown_rgb(moving) - shown_rgb(still)).max() == 0.0
    for window in (still_near0, still, moving):
        window.Finalize()


def test_none_moves_with_the_still_near_field():
    volume, scene, illumination = sharp_sphere()
    still, _, _k1 = shown(volume, scene, illumination, False)
    moving, actor, _k2 = shown(volume, scene, illumination, True, interactive_near_cells=None)
    assert actor.interactive_near_cells is None
    assert np.abs(shown_rgb(moving) - shown_rgb(still)).max() == 0.0
    actor.interactive_near_cells = 0.0  # the default
    with pytest.raises(ValueError, match="interactive_near_cells"):
        actor.interactive_near_cells = -1.0
    for window in (still, moving):
        window.Finalize()


def test_moving_frames_cast_fewer_rays_and_the_rest_every_ray():
    volume, scene, illumination = sharp_sphere()
    still, _, _k1 = shown(volume, scene, illumination, False)
    moving, actor, _k2 = shown(volume, scene, illumination, True, interactive_near_cells=None,
                               interactive_image_sample_distance=2.0)
    assert actor.GetMapper().GetImageSampleDistance() == 2.0
    full, drag = shown_rgb(still), shown_rgb(moving)
    assert full.max() > 0.2
    coarse = rel_errors(drag, full)
    print(f"moving frame (every second pixel) vs still: mean {coarse[0]:.2e}, "
          f"p99 {coarse[1]:.2e}")
    assert np.abs(drag - full).max() > 0.0  # drawn at a quarter of the rays
    assert coarse[0] < 3e-2  # ... of the same picture
    for window in (still, moving):
        window.Render()
    assert actor.frames == 1
    assert actor.GetMapper().GetImageSampleDistance() == 1.0
    assert np.abs(shown_rgb(moving) - shown_rgb(still)).max() == 0.0
    for bad in (0.5, float("nan"), 64.0):
        with pytest.raises(ValueError, match="interactive_image_sample_distance"):
            actor.interactive_image_sample_distance = bad
    assert actor.interactive_image_sample_distance == 2.0
    for window in (still, moving):
        window.Finalize()


def test_scripts_with_an_interactor_draw_still_frames():
    """pyvista initialises an interactor even off screen: a camera moved by a script (a
    screenshot, a camera path) is not a drag, so its frame casts every ray at the scene's
    step and near field; a drag (the style's start) is coarse, and the render at its end
    (the style's stop, at the still rate) is full quality again."""
    from vtkmodules.vtkInteractionStyle import vtkInteractorStyleTrackballCamera

    volume, scene, illumination = sharp_sphere()
    still, _, _k1 = shown(volume, scene, illumination, False)
    scripted, actor, keep = shown(volume, scene, illumination, False)
    iren = vtkGenericRenderWindowInteractor()
    iren.SetRenderWindow(scripted)
    style = vtkInteractorStyleTrackballCamera()
    iren.SetInteractorStyle(style)
    iren.Initialize()
    for window in (still, scripted):
        window.GetRenderers().GetFirstRenderer().GetActiveCamera().Azimuth(1.0)
        window.Render()
    assert actor.frames == 0 and actor.GetMapper().GetImageSampleDistance() == 1.0
    assert np.abs(shown_rgb(scripted) - shown_rgb(still)).max() == 0.0
    actor.interactive_image_sample_distance = 2.0
    style.StartRotate()  # a drag
    scripted.GetRenderers().GetFirstRenderer().GetActiveCamera().Azimuth(1.0)
    scripted.Render()
    assert actor.frames == 0 and actor.GetMapper().GetImageSampleDistance() == 2.0
    style.EndRotate()  # renders at the still rate: every ray
    assert actor.GetMapper().GetImageSampleDistance() == 1.0
    iren.SetRenderWindow(None)
    for window in (still, scripted):
        window.Finalize()
