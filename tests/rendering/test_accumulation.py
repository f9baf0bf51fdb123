"""Still pictures of IlluminatedVolume: jittered frames accumulated while the view rests.

Scene: a 40³ sphere with a one-voxel edge and a steep opacity ramp (opaque within a
voxel), lit from the viewer's side through a transmittance grid, sampled every voxel
(``step_size = 1``): the case where one offset for all pixels draws wood-grain rings and
one offset per pixel draws speckle, many 8-bit levels deep. 64 × 64 pixels, 8-bit read
back. The reference is the mean of :data:`REFERENCE_FRAMES` accumulated frames of the
same view and step (what jitter averages to). Errors are RMS over the pixels the
sphere covers, in 8-bit levels. Measured (llvmpipe):

=====================================================  =============
picture                                                RMS vs ref.
=====================================================  =============
``jitter=False`` (terraces)                            9.3
one jittered frame (interleaved gradient noise)        10.2
mean of 4 frames                                       2.7
mean of 16 frames (the default ``accumulate``)         0.44
=====================================================  =============

The tolerance :data:`SPECKLE_TOL` lies between: the old pictures (one frame, with or
without jitter) fail it, the accumulated one passes.
"""

import numpy as np
import pytest
from helpers import offscreen_window

from vtkillum.core.camera import Camera
from vtkillum.core.illumination import IlluminationVolume
from vtkillum.core.light_transmittance import light_transmittance
from vtkillum.core.lights import DirectionalLight
from vtkillum.core.scene import Scene
from vtkillum.core.transfer_function import TransferFunction
from vtkillum.core.volume import Volume

pytest.importorskip("vtkmodules.vtkRenderingVolumeOpenGL2")
from vtkmodules.vtkRenderingCore import vtkRenderer

from vtkillum.io.convert import image_data_from_volume
from vtkillum.mappers import IlluminatedVolume, accumulation
from vtkillum.mappers.illuminated_volume_mapper import ACCUMULATE

SIZE = 64
EXPOSURE = 3.0
REFERENCE_FRAMES = 128
SPECKLE_TOL = 2.0  # RMS in 8-bit levels


def sphere_scene(step: float = 1.0):
    """``(volume, scene, illumination)``: the sharp sphere lit from the viewer's side."""
    n = 40
    x = np.linspace(-1.0, 1.0, n)
    X, Y, Z = np.meshgrid(x, x, x, indexing="ij")
    r = np.sqrt(X ** 2 + Y ** 2 + Z ** 2)
    volume = Volume(np.clip((0.7 - r) / (x[1] - x[0]) + 0.5, 0.0, 1.0), origin=(-5.0, 2.0, 1.0))
    tf = TransferFunction([0.0, 0.2, 1.0], [0.0, 0.0, 0.95], [[1.0, 0.9, 0.8]] * 3)
    cam = Camera.looking_at_bounds(volume.bounds, direction=(-0.2, -0.3, -1.0),
                                   view_up=(0.0, 1.0, 0.0))
    cam = Camera(cam.focal_point + 0.6 * (cam.position - cam.focal_point), cam.focal_point,
                 cam.view_up, cam.view_angle)
    scene = Scene(transfer_function=tf, opacity_unit_distance=1.0, camera=cam,
                  lights=[DirectionalLight((0.4, -0.5, -1.0), (10.0, 10.0, 10.0))],
                  step_size=step)
    transmittance = light_transmittance(volume, tf, 1.0, scene.lights, device="cpu")[0]
    return volume, scene, IlluminationVolume.for_volume(volume, transmittance=transmittance)


def show(volume, scene, illumination, **kwargs):
    """``(actor, window)``: an IlluminatedVolume alone in an offscreen window (not rendered)."""
    actor = IlluminatedVolume(image_data_from_volume(volume), scene, illumination=illumination,
                              exposure=EXPOSURE, **kwargs)
    renderer = vtkRenderer()
    renderer.AddVolume(actor)
    return actor, offscreen_window(renderer, scene.camera, SIZE, SIZE)


def shown(window) -> np.ndarray:
    """What the window shows now (8-bit levels), without rendering it again."""
    from vtkmodules.util.numpy_support import vtk_to_numpy
    from vtkmodules.vtkRenderingCore import vtkWindowToImageFilter

    grab = vtkWindowToImageFilter()
    grab.SetInput(window)
    grab.SetInputBufferTypeToRGB()
    grab.ReadFrontBufferOff()
    grab.ShouldRerenderOff()
    grab.Update()
    w, h, _ = grab.GetOutput().GetDimensions()
    rgb = vtk_to_numpy(grab.GetOutput().GetPointData().GetScalars()).reshape(h, w, 3)
    return rgb[::-1].astype(np.float64)


def rms_levels(image, reference) -> float:
    covered = reference.max(axis=-1) > 2.0
    return float(np.sqrt(np.mean((image - reference)[covered] ** 2)))


@pytest.fixture(scope="module")
def sphere():
    """The scene and its reference: the mean of REFERENCE_FRAMES frames (8-bit levels)."""
    volume, scene, illumination = sphere_scene()
    settled = accumulation.SETTLED_LEVELS
    accumulation.SETTLED_LEVELS = -1.0  # all the frames, no early end
    try:
        actor, window = show(volume, scene, illumination, accumulate=REFERENCE_FRAMES)
        assert actor.refine() == REFERENCE_FRAMES
        reference = shown(window)
        window.Finalize()
    finally:
        accumulation.SETTLED_LEVELS = settled
    return volume, scene, illumination, reference


@pytest.fixture
def exact_counts(monkeypatch):
    """Frame counts as asked for: no early end of the accumulation."""
    monkeypatch.setattr(accumulation, "SETTLED_LEVELS", -1.0)


def test_accumulated_still_picture_has_no_speckle_or_terraces(sphere):
    volume, scene, illumination, reference = sphere
    _, window = show(volume, scene, illumination, jitter=False)
    window.Render()
    terraces = rms_levels(shown(window), reference)
    window.Finalize()
    actor, window = show(volume, scene, illumination)
    window.Render()
    speckle = rms_levels(shown(window), reference)
    assert actor.frames == 0
    assert actor.refine(4) == 4
    four = rms_levels(shown(window), reference)
    frames = actor.refine()  # the default: up to ACCUMULATE frames, or settled before
    assert 8 <= frames <= ACCUMULATE == 16
    still = rms_levels(shown(window), reference)
    window.Finalize()
    print(f"RMS vs reference (8-bit levels): jitter=False {terraces:.2f}, one frame "
          f"{speckle:.2f}, 4 frames {four:.2f}, {frames} frames {still:.2f}")
    assert terraces > 2 * SPECKLE_TOL
    assert speckle > 2 * SPECKLE_TOL
    assert still < SPECKLE_TOL / 2 < four < speckle


def test_accumulated_picture_is_unbiased(sphere):
    """The mean brightness is the non-jittered picture's, and the fine-step limit's."""
    volume, scene, illumination, reference = sphere
    actor, window = show(volume, scene, illumination)
    actor.refine()
    accumulated = shown(window)
    window.Finalize()
    _, window = show(volume, scene, illumination, jitter=False)
    window.Render()
    fixed = shown(window)
    window.Finalize()
    fine_scene = sphere_scene(step=0.125)[1]
    _, window = show(volume, fine_scene, illumination, jitter=False)
    window.Render()
    fine = shown(window)
    window.Finalize()
    means = [float(image.mean()) for image in (accumulated, fixed, fine, reference)]
    print("mean level: accumulated {:.3f}, jitter=False {:.3f}, step/8 {:.3f}, "
          "reference {:.3f}".format(*means))
    # Measured 75.4, 76.2, 76.7, 75.4: what is left is the one-voxel step's own bias,
    # which the step midpoints (jitter=False) have too.
    assert abs(means[0] / means[1] - 1.0) < 0.02
    assert abs(means[0] / means[2] - 1.0) < 0.03
    assert abs(means[0] / means[3] - 1.0) < 0.002


def test_camera_move_restarts_the_accumulation(sphere, exact_counts):
    volume, scene, illumination, reference = sphere
    actor, window = show(volume, scene, illumination)
    window.Render()
    assert actor.refine() == ACCUMULATE
    renderer = window.GetRenderers().GetFirstRenderer()
    renderer.GetActiveCamera().Azimuth(5.0)
    window.Render()
    assert actor.frames == 0
    moved = shown(window)
    # The same view in a fresh window: the first render there is the same single frame.
    fresh_actor, fresh = show(volume, scene, illumination)
    fresh.GetRenderers().GetFirstRenderer().GetActiveCamera().DeepCopy(
        renderer.GetActiveCamera())
    fresh.Render()
    assert fresh_actor.frames == 0
    assert np.abs(moved - shown(fresh)).max() <= 1.0
    fresh.Finalize()
    window.Render()
    assert actor.frames == 1
    # Back to the first view: a change again, the mean starts over.
    renderer.GetActiveCamera().Azimuth(-5.0)
    window.Render()
    assert actor.frames == 0
    assert actor.refine() == ACCUMULATE
    assert rms_levels(shown(window), reference) < SPECKLE_TOL / 2
    window.Finalize()


def test_converged_mean_is_held_and_edits_restart(sphere, exact_counts):
    volume, scene, illumination, reference = sphere
    actor, window = show(volume, scene, illumination, accumulate=6)
    actor.refine()
    converged = shown(window)
    for _ in range(3):  # the volume draws nothing, the stored mean is written back
        window.Render()
        assert actor.frames == 6
        assert np.array_equal(shown(window), converged)
    actor.exposure = EXPOSURE / 2  # an edit: frame 0 of the new picture
    window.Render()
    assert actor.frames == 0
    assert shown(window).mean() < 0.75 * converged.mean()
    assert actor.refine() == 6
    actor.accumulate = 3  # fewer frames: starts over and stops at 3
    window.Render()
    assert actor.frames == 0
    assert actor.refine() == 3
    window.Render()
    assert actor.frames == 3
    window.Finalize()


def test_no_accumulation_without_jitter_or_frames(sphere):
    volume, scene, illumination, reference = sphere
    for kwargs in ({"jitter": False}, {"accumulate": 0}):
        actor, window = show(volume, scene, illumination, **kwargs)
        window.Render()
        first = shown(window)
        for _ in range(3):
            window.Render()
            assert actor.frames == 0
            assert np.array_equal(shown(window), first), kwargs
        assert actor.refine() == 0
        window.Finalize()
    with pytest.raises(ValueError, match="accumulate"):
        IlluminatedVolume(image_data_from_volume(volume), scene, accumulate=-1)
    lonely = IlluminatedVolume(image_data_from_volume(volume), scene)
    with pytest.raises(ValueError, match="no renderer"):
        lonely.refine()


def test_a_view_the_offsets_do_not_change_settles_early():
    """Smooth data (the blobs, a soft transfer function): a frame soon moves the mean by
    less than half an 8-bit level, so the mean is complete and further frames cost
    nothing."""
    from helpers import blob_tf, blob_volume, zoomed_camera

    volume = blob_volume()
    scene = Scene(transfer_function=blob_tf(), camera=zoomed_camera(volume),
                  lights=[DirectionalLight((0.6, -1.0, 0.2), (2.0, 2.0, 2.0))])
    actor, window = show(volume, scene, None)
    frames = actor.refine()
    assert 2 <= frames < ACCUMULATE
    settled = shown(window)
    window.Render()
    assert actor.frames == frames
    assert np.array_equal(shown(window), settled)
    window.Finalize()


def test_two_volumes_in_one_renderer_share_one_mean(sphere, exact_counts):
    """Both volumes take the frame index from the renderer's one accumulator: the mean is
    summed once (not the mean of a mean), and the picture equals one volume's when the
    other is outside the view."""
    volume, scene, illumination, reference = sphere
    actor, window = show(volume, scene, illumination)
    other = IlluminatedVolume(image_data_from_volume(Volume(
        np.ones((4, 4, 4)), origin=(500.0, 500.0, 500.0))), Scene())
    renderer = window.GetRenderers().GetFirstRenderer()
    renderer.AddVolume(other)
    window.Render()
    assert actor.refine() == ACCUMULATE
    assert other.frames == actor.frames
    assert rms_levels(shown(window), reference) < SPECKLE_TOL / 2
    window.Finalize()


def test_accumulation_in_a_pyvista_plotter(sphere, exact_counts):
    """pyvista windows (multisampled frame buffer) accumulate the same way.

    The reference is made in the plotter: where the rasteriser shades every sample of a
    multisampled pixel (llvmpipe) a single frame is already the mean of several rays.
    """
    pv = pytest.importorskip("pyvista")
    from vtkillum.mappers import apply_camera_to_vtk

    volume, scene, illumination, _ = sphere
    actor = IlluminatedVolume(image_data_from_volume(volume), scene, illumination=illumination,
                              exposure=EXPOSURE, accumulate=REFERENCE_FRAMES)
    plotter = pv.Plotter(off_screen=True, window_size=(SIZE, SIZE))
    plotter.set_background("black")
    plotter.add_actor(actor)
    plotter.camera_position = [tuple(scene.camera.position), tuple(scene.camera.focal_point),
                               tuple(scene.camera.view_up)]
    apply_camera_to_vtk(scene.camera, plotter.renderer.GetActiveCamera())
    plotter.renderer.ResetCameraClippingRange()
    assert plotter.render_window.GetMultiSamples() > 0
    assert actor.refine() == REFERENCE_FRAMES
    reference = plotter.screenshot(return_img=True).astype(np.float64)
    actor.accumulate = ACCUMULATE
    plotter.render()
    single = plotter.screenshot(return_img=True).astype(np.float64)
    assert actor.refine() == ACCUMULATE
    still = plotter.screenshot(return_img=True).astype(np.float64)
    plotter.close()
    print(f"pyvista: one frame {rms_levels(single, reference):.2f}, accumulated "
          f"{rms_levels(still, reference):.2f} levels RMS")
    assert rms_levels(still, reference) < SPECKLE_TOL / 2
    assert rms_levels(single, reference) > 2 * rms_levels(still, reference)


def test_an_interactor_refines_while_the_view_rests(sphere, exact_counts):
    """With an initialised interactor each frame asks for the next one through a one-shot
    timer (here a generic interactor whose host fires the timers by hand), not during a
    drag."""
    from vtkmodules.vtkCommonCore import vtkCommand
    from vtkmodules.vtkInteractionStyle import vtkInteractorStyleTrackballCamera
    from vtkmodules.vtkRenderingUI import vtkGenericRenderWindowInteractor

    volume, scene, illumination, reference = sphere
    actor, window = show(volume, scene, illumination, accumulate=4)
    interactor = vtkGenericRenderWindowInteractor()
    interactor.SetRenderWindow(window)
    pending = []
    interactor.AddObserver(vtkCommand.CreateTimerEvent,
                           lambda caller, event: pending.append(caller.GetTimerEventPlatformId()))
    interactor.Initialize()  # renders: the volume attaches the renderer's accumulator
    window.Render()  # frame 0: asks for a timer
    # A timer that fires during a drag renders nothing; the still render at its end resumes.
    style = vtkInteractorStyleTrackballCamera()
    interactor.SetInteractorStyle(style)
    style.StartRotate()
    interactor.SetTimerEventPlatformId(pending.pop(0))
    interactor.TimerEvent()
    assert actor.frames == 0 and not pending
    style.EndRotate()  # renders at the still update rate: the camera rests, frame 1
    assert actor.frames == 1
    fired = 0
    while pending and fired < 10:
        interactor.SetTimerEventPlatformId(pending.pop(0))
        interactor.TimerEvent()  # renders the next frame
        fired += 1
    assert actor.frames == 4
    assert fired == 3  # one frame per timer, none once the mean has converged
    interactor.SetRenderWindow(None)
    window.Finalize()
