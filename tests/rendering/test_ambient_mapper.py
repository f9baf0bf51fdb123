"""The OpenGL ambient-scattering mapper agrees with the warp gather (Ament et al. 2013).

Scene: a 24³ volume of two smooth blobs (anisotropic spacing, offset origin, a rotated
direction matrix), a coloured transfer function dense enough to shadow, ``g = 0.4``, one
directional and one point light, ambient radius 3 voxels, a perspective camera. The
same scene goes to

* :class:`AmbientScatteringVolume` in an offscreen VTK window (OSMesa), read back as
  8-bit linear RGB over a black background;
* ``render(volume, scene, method="ambient-scattering", jitter=False)`` (warp, CPU),
  times the same exposure, clipped to [0, 1].

Tolerances, relative to the reference image's maximum, over all pixels and channels:
mean abs error < ``MEAN_TOL`` (1.5e-3) and 99th percentile < ``P99_TOL`` (6e-3);
measured 4e-4 to 8e-4 and 2.3e-3 to 4.3e-3 over the scenes below (the 8-bit read-back
alone costs 1/510 of full scale, 2.3e-3 of the maximum at exposure 0.85). Replacing the
preintegration table by its mean (4.2e-2, 0.39) or the radiance cache by its
extinction-weighted mean (2.9e-2, 0.34) fails the tolerance many times over, so the
comparison sees both.
"""

import copy

import numpy as np
import pytest
from helpers import offscreen_window, pyvista_screenshot, read_window_rgb, rel_errors

from vtkillum.core.camera import Camera
from vtkillum.core.lights import DirectionalLight, PointLight
from vtkillum.core.render import render
from vtkillum.core.resample import resample_points
from vtkillum.core.scene import Scene
from vtkillum.core.transfer_function import TransferFunction
from vtkillum.core.volume import Volume

pytest.importorskip("vtkmodules.vtkRenderingVolumeOpenGL2")
from vtkmodules.util.numpy_support import vtk_to_numpy  # noqa: E402
from vtkmodules.vtkRenderingCore import vtkRenderer  # noqa: E402

from vtkillum.io.convert import image_data_from_volume  # noqa: E402
from vtkillum.mappers import AmbientScatteringVolume, apply_camera_to_vtk  # noqa: E402

MEAN_TOL = 1.5e-3
P99_TOL = 6e-3
WIDTH, HEIGHT = 64, 64
UNIT = 1.0
PEAK = 0.85  # exposure maps the reference's maximum here (inside the 8-bit range)


def blob_volume(scale: float = 1.0) -> Volume:
    n = 24
    x = np.linspace(-1.0, 1.0, n)
    X, Y, Z = np.meshgrid(x, x, x, indexing="ij")
    big = np.exp(-((X + 0.15) ** 2 + Y ** 2 + (Z - 0.1) ** 2) / 0.3)
    small = 0.8 * np.exp(-((X - 0.55) ** 2 + (Y - 0.5) ** 2 + (Z + 0.3) ** 2) / 0.06)
    c, s = np.cos(0.3), np.sin(0.3)
    rotation = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    return Volume(scale * (big + small), spacing=(1.0, 1.15, 0.85), origin=(-3.0, 2.0, 1.0),
                  direction=rotation)


def blob_tf(opacity_scale: float = 1.0) -> TransferFunction:
    return TransferFunction(
        [0.0, 0.15, 0.45, 0.75, 1.0],
        list(opacity_scale * np.array([0.0, 0.0, 0.25, 0.5, 0.6])),
        [[0.1, 0.2, 1.0], [0.1, 0.2, 1.0], [0.2, 1.0, 0.4], [1.0, 0.8, 0.1], [1.0, 0.1, 0.1]],
    )


def make_scene(volume: Volume, anisotropy: float = 0.4, **ambient) -> Scene:
    cam = Camera.looking_at_bounds(volume.bounds, direction=(-0.4, -0.3, -1.0),
                                   view_up=(0.2, 1.0, 0.0))
    cam = Camera(cam.focal_point + 0.6 * (cam.position - cam.focal_point), cam.focal_point,
                 cam.view_up, cam.view_angle)
    centre = volume.bounds.reshape(3, 2).mean(1)
    lights = [DirectionalLight((1.0, -0.3, 0.2), (3.0, 2.4, 1.8)),
              PointLight(centre + np.array([-5.0, 30.0, 5.0]), (800.0, 800.0, 900.0))]
    return Scene(transfer_function=blob_tf(), opacity_unit_distance=UNIT, camera=cam,
                 lights=lights, step_size=0.5 * float(volume.spacing.min()),
                 anisotropy=anisotropy, shading={"shininess": 16.0},
                 options={"ambient_scattering": {"radius": 3.0, **ambient}})


def reference(volume, scene, exposure=None):
    """Warp gather without jitter; returns (exposed image clipped to [0, 1], exposure)."""
    result = render(volume, scene, "ambient-scattering", WIDTH, HEIGHT, device="cpu",
                    jitter=False)
    if exposure is None:
        exposure = PEAK / float(result.radiance.max())
    return np.clip(exposure * result.radiance, 0.0, 1.0), exposure


def within(errors) -> bool:
    return errors[0] < MEAN_TOL and errors[1] < P99_TOL


@pytest.fixture(scope="module")
def setup():
    volume = blob_volume()
    scene = make_scene(volume)
    ref, exposure = reference(volume, scene)
    return volume, scene, ref, exposure


def test_opengl_matches_warp_gather_and_uses_table_and_cache(setup, tmp_path):
    volume, scene, ref, exposure = setup
    actor = AmbientScatteringVolume(image_data_from_volume(volume), scene, exposure=exposure,
                                    device="cpu")
    renderer = vtkRenderer()
    renderer.AddVolume(actor)
    window = offscreen_window(renderer, scene.camera, WIDTH, HEIGHT)
    image = read_window_rgb(window)
    errors = rel_errors(image, ref)
    print(f"OpenGL vs warp gather: mean {errors[0]:.2e}, p99 {errors[1]:.2e} (relative to max)")
    assert within(errors), errors
    assert (image.max(-1) > 0.05).mean() > 0.2  # not blank

    # The comparison sees the preintegration table: its mean in place of L~o fails it ...
    table = vtk_to_numpy(actor.inputs.GetOutputDataObject(0).GetPointData().GetScalars())
    table[:] = table.mean()
    table_flat = rel_errors(grab_modified(window, actor.inputs.GetOutputDataObject(0)), ref)
    print(f"constant table: mean {table_flat[0]:.2e}, p99 {table_flat[1]:.2e}")
    assert not within(table_flat), table_flat
    # ... re-running the pipeline restores it ...
    actor.inputs.Modified()
    assert within(rel_errors(read_window_rgb(window), ref))
    # ... and so does the radiance cache: each light's extinction-weighted mean fails it.
    cache = vtk_to_numpy(actor.inputs.radiance_image.GetPointData().GetScalars())
    shape = actor.inputs.radiance_image.GetDimensions()
    sigma = resample_points(actor.state.sigma_t.numpy(), shape).reshape(-1, order="F")[:, None]
    cache[:] = (cache * sigma).sum(0) / sigma.sum()
    cache_flat = rel_errors(grab_modified(window, actor.inputs.radiance_image), ref)
    print(f"constant radiance cache: mean {cache_flat[0]:.2e}, p99 {cache_flat[1]:.2e}")
    assert not within(cache_flat), cache_flat
    window.Finalize()


def test_paper_gather_matches_warp(setup):
    """The paper's Algorithm 1 (``gather="paper"``: L~o, transmittance from x_o) in GLSL, too."""
    volume, _, _, _ = setup
    scene = make_scene(volume, gather="paper")
    ref, exposure = reference(volume, scene)
    actor = AmbientScatteringVolume(image_data_from_volume(volume), scene, exposure=exposure,
                                    device="cpu")
    renderer = vtkRenderer()
    renderer.AddVolume(actor)
    window = offscreen_window(renderer, scene.camera, WIDTH, HEIGHT)
    errors = rel_errors(read_window_rgb(window), ref)
    print(f"paper gather, OpenGL vs warp: mean {errors[0]:.2e}, p99 {errors[1]:.2e}")
    assert within(errors), errors
    # ... and it is another image than the centred gather's
    centred, _ = reference(volume, make_scene(volume), exposure)
    assert not within(rel_errors(read_window_rgb(window), centred))
    window.Finalize()


def grab_modified(window, image):
    image.GetPointData().GetScalars().Modified()
    image.Modified()
    return read_window_rgb(window)


@pytest.mark.parametrize("device_upload", [False, True])
def test_edits_recompute_what_table1_says(setup, device_upload):
    """Each edit recomputes its stages and re-uploads only their textures: from the host
    images, or (``device_upload``) written from the cache's device into VTK's textures,
    the images untouched."""
    volume, scene, ref, exposure = setup
    image_data = image_data_from_volume(volume)
    actor = AmbientScatteringVolume(image_data, scene, exposure=exposure, device="cpu",
                                    device_upload=device_upload)
    renderer = vtkRenderer()
    renderer.AddVolume(actor)
    window = offscreen_window(renderer, scene.camera, WIDTH, HEIGHT)
    first = read_window_rgb(window)
    stats = dict(actor.cache.stats)
    assert stats == {"sat": 1, "extinction": 1, "radiance": 1}

    # Camera move: nothing recomputed.
    renderer.GetActiveCamera().Azimuth(15.0)
    moved = read_window_rgb(window)
    assert actor.cache.stats == stats and np.abs(moved - first).mean() > 1e-3
    apply_camera_to_vtk(scene.camera, renderer.GetActiveCamera())

    # Anisotropy: only the radiance cache; the image follows the warp gather at the new g.
    backward = copy.copy(scene)
    backward.anisotropy = -0.5
    kept = (actor.inputs.data_image.GetMTime(), actor.inputs.extinction_image.GetMTime(),
            actor.inputs.optics_image.GetMTime())
    cache_time = actor.inputs.radiance_image.GetMTime()
    actor.set_scene(backward)
    image = read_window_rgb(window)
    assert actor.cache.stats == {"sat": 1, "extinction": 1, "radiance": 2}
    # ... and only the radiance cache's texture (and the small table) is re-uploaded.
    assert (actor.inputs.data_image.GetMTime(), actor.inputs.extinction_image.GetMTime(),
            actor.inputs.optics_image.GetMTime()) == kept
    if device_upload:  # the radiance cache's texture written from the device
        assert actor.inputs.writer.writes == 1, actor.inputs.writer.last_error
        assert actor.inputs.radiance_image.GetMTime() == cache_time
    else:
        assert actor.inputs.radiance_image.GetMTime() > cache_time
    ref_g, _ = reference(volume, backward, exposure)
    errors = rel_errors(image, ref_g)
    print(f"g = -0.5: mean {errors[0]:.2e}, p99 {errors[1]:.2e}")
    assert within(errors), errors
    assert not within(rel_errors(image, ref))

    # Radius: extinction and radiance, not the SAT.
    actor.set_options(radius=5.0)
    image = read_window_rgb(window)
    assert actor.cache.stats == {"sat": 1, "extinction": 2, "radiance": 3}
    if device_upload:  # σ̃t and the radiance cache
        assert actor.inputs.writer.writes == 3, actor.inputs.writer.last_error
    ref_r, _ = reference(volume, make_scene(volume, -0.5, radius=5.0), exposure)
    assert within(rel_errors(image, ref_r)), rel_errors(image, ref_r)

    # Transfer function, with the specular lobe and ambient occlusion on: everything.
    edited = make_scene(volume, -0.5, radius=5.0, specular=0.5, ambient_occlusion=True)
    edited.transfer_function = blob_tf(0.6)
    actor.set_scene(edited)
    actor.set_options(radius=None)  # the scene's radius is the same: nothing to redo
    image = read_window_rgb(window)
    assert actor.cache.stats == {"sat": 2, "extinction": 3, "radiance": 4}
    if device_upload:
        assert actor.inputs.writer.writes == 5, actor.inputs.writer.last_error
    ref_tf, _ = reference(volume, edited, exposure)
    errors = rel_errors(image, ref_tf)
    print(f"TF + specular + AO: mean {errors[0]:.2e}, p99 {errors[1]:.2e}")
    assert within(errors), errors

    # Data edited in place through the pipeline (array.Modified()): everything again.
    scalars = vtk_to_numpy(image_data.GetPointData().GetScalars())
    scalars *= 0.8
    image_data.GetPointData().GetScalars().Modified()
    image = read_window_rgb(window)
    assert actor.cache.stats["sat"] == 3
    ref_data, _ = reference(blob_volume(0.8), edited, exposure)
    assert within(rel_errors(image, ref_data)), rel_errors(image, ref_data)
    window.Finalize()


def test_pyvista_plotter_add_actor(setup):
    pv = pytest.importorskip("pyvista")
    volume, scene, ref, exposure = setup
    actor = AmbientScatteringVolume(pv.wrap(image_data_from_volume(volume)), scene,
                                    exposure=exposure, device="cpu")
    shot = pyvista_screenshot(actor, scene.camera, WIDTH, HEIGHT)
    assert shot.shape[:2] == (HEIGHT, WIDTH)
    assert shot.max() > 0.5 and (shot.max(-1) > 0.05).mean() > 0.2  # not blank
    assert within(rel_errors(shot[..., :3], ref)), rel_errors(shot[..., :3], ref)


def test_bad_inputs_raise_clear_errors(setup):
    volume, scene, _, _ = setup
    image = image_data_from_volume(volume)
    many = copy.copy(scene)
    many.lights = [DirectionalLight((0, -1, 0))] * 5
    with pytest.raises(ValueError, match="at most 4 lights"):
        AmbientScatteringVolume(image, many, device="cpu")
    with pytest.raises(ValueError, match="unknown ambient-scattering option"):
        AmbientScatteringVolume(image, scene, device="cpu", jitter=True)
    with pytest.raises(ValueError, match="radius must be positive"):
        AmbientScatteringVolume(image, scene, device="cpu", radius=-1.0)
    with pytest.raises(TypeError, match="vtkImageData"):
        AmbientScatteringVolume(np.zeros((4, 4, 4)), scene, device="cpu")
    with pytest.raises(ValueError, match="array_name"):
        AmbientScatteringVolume(image, scene, array_name="missing", device="cpu")


def test_fewer_rays_while_an_interactor_moves_the_view(setup):
    """While an interactor style interacts (the window's desired update rate is the
    interactor's), the mapper casts one ray per 2 × 2 pixels, with samples twice as far
    apart: a coarser picture of the same scene; at the still rate every ray at the scene's
    step again (the gather's picture)."""
    from vtkmodules.vtkRenderingUI import vtkGenericRenderWindowInteractor

    volume, scene, ref, exposure = setup
    actor = AmbientScatteringVolume(image_data_from_volume(volume), scene, exposure=exposure,
                                    device="cpu")
    assert actor.interactive_image_sample_distance == 2.0 and actor.interactive_step == 2.0
    renderer = vtkRenderer()
    renderer.AddVolume(actor)
    window = offscreen_window(renderer, scene.camera, WIDTH, HEIGHT)
    interactor = vtkGenericRenderWindowInteractor()
    interactor.SetRenderWindow(window)
    interactor.Initialize()
    still = read_window_rgb(window)
    assert actor.mapper.GetImageSampleDistance() == 1.0
    assert within(rel_errors(still, ref))
    window.SetDesiredUpdateRate(interactor.GetDesiredUpdateRate())  # a drag
    moving = read_window_rgb(window)
    assert actor.mapper.GetImageSampleDistance() == 2.0
    coarse = rel_errors(moving, ref)
    print(f"moving (2 x 2 pixels a ray) vs gather: mean {coarse[0]:.2e}, p99 {coarse[1]:.2e}")
    assert not within(coarse) and coarse[0] < 3e-2
    # each coarsening alone changes the picture
    actor.interactive_image_sample_distance = 1.0
    step_only = read_window_rgb(window)
    assert np.abs(step_only - still).max() > 0.0 and rel_errors(step_only, ref)[0] < 3e-2
    actor.interactive_step = 1.0
    assert np.abs(read_window_rgb(window) - still).max() == 0.0
    actor.interactive_image_sample_distance = actor.interactive_step = 2.0
    window.SetDesiredUpdateRate(interactor.GetStillUpdateRate())  # the drag ends
    assert np.abs(read_window_rgb(window) - still).max() == 0.0
    with pytest.raises(ValueError, match="interactive_image_sample_distance"):
        actor.interactive_image_sample_distance = 0.5
    with pytest.raises(ValueError, match="interactive_step"):
        actor.interactive_step = 0.5
    window.Finalize()
