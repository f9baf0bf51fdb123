"""The illuminated volume mapper (OpenGL path) and the compute path agree with the warp ray caster.

Scene: a 32³ volume of two smooth blobs (anisotropic spacing, offset origin), a
coloured transfer function, a perspective camera, one directional and one point
light with diffuse and specular Phong terms, and an illumination volume computed
analytically from the data: the fluence of a light entering at +y and attenuated
by the optical depth along y, ``φ = E exp(-∫ σt dy)`` (per channel E). The same
illumination volume goes to

* :class:`IlluminatedVolume` in an offscreen VTK window (OSMesa), read back as
  8-bit linear RGB over a black background;
* :func:`vtkillum.core.raycast.render_illuminated` (warp, no jitter, VTK's early
  termination ``1 - 1/255``);
* :class:`ComputeVolumeRenderer` (warp image shown as the renderer's background).

Tolerances, relative to the reference image's maximum, over all pixels and
channels: OpenGL vs warp mean abs error < ``MEAN_TOL`` (3e-3) and 99th percentile
< ``P99_TOL`` (1.2e-2); measured 1.1e-3 and 3.9e-3 (8-bit quantisation alone is
about 6e-4 of the maximum; VTK's samples start one step inside the box and its
opacity comes from a 1D table of the corrected opacity). The same tolerance holds
for OpenGL vs the compute path, for a half-resolution fluence image and in a
pyvista Plotter. A constant fluence (the extinction-weighted mean of the true
one: measured 4.0e-2 / 0.36), the unshadowed default, and mirrored lights (1.2e-2 /
9.4e-2) all fail it. The compute path must show the tone-mapped warp image to
1/255, and the CLI's ``single`` render (it takes no illumination volume) to half
a level of the 8-bit display.
"""

import copy

import numpy as np
import pytest
from helpers import (
    blob_tf,
    blob_volume,
    offscreen_window,
    pyvista_screenshot,
    read_window_rgb,
    rel_errors,
    zoomed_camera,
)

from vtkillum.core.camera import Camera
from vtkillum.core.illumination import IlluminationVolume
from vtkillum.core.lights import DirectionalLight, PointLight
from vtkillum.core.raycast import render_illuminated
from vtkillum.core.scene import Scene
from vtkillum.core.tonemap import tonemap
from vtkillum.core.transfer_function import TransferFunction
from vtkillum.core.volume import Volume

pytest.importorskip("vtkmodules.vtkRenderingVolumeOpenGL2")
from vtkmodules.util.numpy_support import vtk_to_numpy  # noqa: E402
from vtkmodules.util.vtkAlgorithm import VTKPythonAlgorithmBase  # noqa: E402
from vtkmodules.vtkCommonDataModel import vtkImageData  # noqa: E402
from vtkmodules.vtkCommonExecutionModel import (  # noqa: E402
    vtkStreamingDemandDrivenPipeline as SDDP,
)
from vtkmodules.vtkRenderingCore import (  # noqa: E402
    vtkCamera,
    vtkRenderer,
    vtkVolumeProperty,
)

from vtkillum.io.convert import add_point_array, image_data_from_volume, image_like  # noqa: E402
from vtkillum.mappers import (  # noqa: E402
    ComputeVolumeRenderer,
    IlluminatedVolume,
    apply_camera_to_vtk,
    apply_scene_to_volume_property,
    camera_from_vtk,
    scene_from_vtk,
)

MEAN_TOL = 3e-3
P99_TOL = 1.2e-2
WIDTH, HEIGHT = 64, 64
UNIT = 1.3
EARLY_STOP = 1.0 - 1.0 / 255.0  # VTK's g_opacityThreshold
IRRADIANCE = np.array([30.0, 24.0, 18.0])  # bright enough to use the 8-bit range


def slab_fluence(volume: Volume, tf: TransferFunction, scale: float = 1.0) -> np.ndarray:
    """``E exp(-τ)`` with τ the optical depth from the +y face (trapezoid rule on the grid)."""
    sigma = tf.sigma_t(volume.scalars, UNIT)
    h = volume.spacing[1]
    from_top = sigma[:, ::-1, :]
    tau = np.concatenate([np.zeros_like(from_top[:, :1]),
                          np.cumsum(0.5 * (from_top[:, 1:] + from_top[:, :-1]) * h, axis=1)], 1)
    return (scale * np.exp(-tau[:, ::-1, :])[..., None] * IRRADIANCE).astype(np.float32)


def make_scene(volume: Volume, mirrored: bool = False) -> Scene:
    cam = zoomed_camera(volume)
    m = np.array([-1.0, -1.0, 1.0]) if mirrored else np.ones(3)
    centre = volume.bounds.reshape(3, 2).mean(1)
    lights = [DirectionalLight(m * np.array([0.6, -1.0, 0.2])),
              PointLight(centre + m * np.array([25.0, 20.0, 0.0]), (900.0, 900.0, 900.0))]
    return Scene(transfer_function=blob_tf(), opacity_unit_distance=UNIT, camera=cam,
                 lights=lights, step_size=0.5 * float(volume.spacing.min()),
                 shading={"ambient": 0.4, "diffuse": 0.6, "specular": 0.3, "shininess": 20.0})


def warp_reference(volume, scene, illumination):
    return render_illuminated(volume, scene, WIDTH, HEIGHT, "cpu", illumination=illumination,
                              jitter=False, early_termination=EARLY_STOP)


def within(errors) -> bool:
    return errors[0] < MEAN_TOL and errors[1] < P99_TOL


@pytest.fixture(scope="module")
def setup():
    volume = blob_volume()
    scene = make_scene(volume)
    fluence = slab_fluence(volume, scene.transfer_function)
    illumination = IlluminationVolume.for_volume(volume, fluence)
    reference = warp_reference(volume, scene, illumination)
    assert reference.radiance.max() > 0.5  # uses most of the 8-bit range
    return volume, scene, illumination, reference


def test_opengl_mapper_matches_warp_illuminated(setup):
    volume, scene, illumination, reference = setup
    renderer = vtkRenderer()
    actor = IlluminatedVolume(image_data_from_volume(volume), scene, illumination=illumination)
    renderer.AddVolume(actor)
    window = offscreen_window(renderer, scene.camera, WIDTH, HEIGHT)
    image = read_window_rgb(window)
    errors = rel_errors(image, reference.radiance)
    print(f"OpenGL vs warp: mean {errors[0]:.2e}, p99 {errors[1]:.2e} (relative to max)")
    assert within(errors), errors

    # The comparison sees the texture: a constant fluence (the mean of the true one, per
    # channel, weighted by extinction so the brightness roughly matches) fails it ...
    sigma = scene.transfer_function.sigma_t(volume.scalars, UNIT)[..., None]
    mean_phi = (illumination.fluence * sigma).sum((0, 1, 2)) / sigma.sum()
    actor.set_illumination(np.broadcast_to(mean_phi, illumination.fluence.shape).copy())
    flat = rel_errors(read_window_rgb(window), reference.radiance)
    print(f"constant fluence: {flat}")
    assert not within(flat), f"a constant fluence was not detected: {flat}"
    # ... and so does the unshadowed default (no illumination set)
    actor.set_illumination(None)
    ignored = rel_errors(read_window_rgb(window), reference.radiance)
    assert not within(ignored), f"ignoring the illumination was not detected: {ignored}"
    # ... and so do lights mirrored in the Phong factor.
    actor.set_illumination(illumination)
    actor.set_scene(make_scene(volume, mirrored=True))
    mirrored = rel_errors(read_window_rgb(window), reference.radiance)
    print(f"mirrored lights: {mirrored}")
    assert not within(mirrored), f"mirrored lights were not detected: {mirrored}"
    window.Finalize()


def test_compute_path_shows_warp_image_and_matches_opengl(setup):
    volume, scene, illumination, reference = setup
    renderer = vtkRenderer()
    window = offscreen_window(renderer, scene.camera, WIDTH, HEIGHT)
    shown = ComputeVolumeRenderer(renderer, volume, scene, method="illumination",
                                  illumination=illumination, device="cpu", jitter=False,
                                  early_termination=EARLY_STOP)
    image = read_window_rgb(window)
    expected = tonemap(reference.radiance, reference.alpha, (0.0, 0.0, 0.0), gamma=1.0)
    assert np.abs(image * 255.0 - expected).max() <= 1.0

    gl_renderer = vtkRenderer()
    gl_renderer.AddVolume(IlluminatedVolume(image_data_from_volume(volume), scene,
                                            illumination=illumination))
    gl_window = offscreen_window(gl_renderer, scene.camera, WIDTH, HEIGHT)
    errors = rel_errors(read_window_rgb(gl_window), image)
    print(f"OpenGL vs compute path: mean {errors[0]:.2e}, p99 {errors[1]:.2e}")
    assert within(errors), errors

    # A camera move re-renders: the image follows the VTK camera.
    renderer.GetActiveCamera().Azimuth(40.0)
    moved = read_window_rgb(window)
    rotated = copy.copy(scene)
    rotated.camera = camera_from_vtk(renderer.GetActiveCamera())
    again = warp_reference(volume, rotated, illumination)
    expected = tonemap(again.radiance, again.alpha, (0.0, 0.0, 0.0), gamma=1.0)
    assert np.abs(moved * 255.0 - expected).max() <= 1.0
    assert np.abs(moved - image).mean() > 0.01
    shown.detach()
    assert not renderer.GetTexturedBackground()
    window.Finalize()
    gl_window.Finalize()


def test_mapper_follows_illumination_data_and_resolution(setup):
    volume, scene, illumination, reference = setup
    # A half-resolution fluence image covering the same box, as an illumination filter outputs.
    coarse_shape = (17, 17, 17)
    fine = slab_fluence(volume, scene.transfer_function)
    from vtkillum.core.resample import resample_points

    coarse = resample_points(fine, coarse_shape)
    fluence_image = image_like(image_data_from_volume(volume), shape=coarse_shape)
    array = add_point_array(fluence_image, "fluence", coarse, set_active=True)

    renderer = vtkRenderer()
    actor = IlluminatedVolume(image_data_from_volume(volume), scene, illumination=fluence_image)
    renderer.AddVolume(actor)
    window = offscreen_window(renderer, scene.camera, WIDTH, HEIGHT)
    first = read_window_rgb(window)
    coarse_reference = warp_reference(volume, scene, IlluminationVolume.for_volume(volume, coarse))
    errors = rel_errors(first, coarse_reference.radiance)
    assert within(errors), errors

    # Editing the array in place (and marking it modified) re-uploads on the next render.
    vtk_to_numpy(array)[:] *= 0.5
    array.Modified()
    second = read_window_rgb(window)
    covered = coarse_reference.radiance > 0.1
    ratio = second[covered] / first[covered]
    assert abs(float(np.median(ratio)) - 0.5) < 0.02, np.median(ratio)

    # A new illumination object replaces the old one.
    actor.set_illumination(IlluminationVolume.for_volume(volume, 0.75 * coarse))
    third = read_window_rgb(window)
    assert abs(float(np.median(third[covered] / first[covered])) - 0.75) < 0.02
    window.Finalize()


class TimeSeries(VTKPythonAlgorithmBase):
    """Image source with time steps 0, 1, 2: the data, or a constant fluence 10 (1 + t)."""

    def __init__(self, reference, scalars=None):
        VTKPythonAlgorithmBase.__init__(self, nInputPorts=0, nOutputPorts=1,
                                        outputType="vtkImageData")
        self.reference, self.scalars, self.times = reference, scalars, []

    def RequestInformation(self, request, inInfo, outInfo):
        info = outInfo.GetInformationObject(0)
        info.Set(SDDP.WHOLE_EXTENT(), self.reference.GetExtent(), 6)
        info.Set(SDDP.TIME_STEPS(), [0.0, 1.0, 2.0], 3)
        info.Set(SDDP.TIME_RANGE(), [0.0, 2.0], 2)
        return 1

    def RequestData(self, request, inInfo, outInfo):
        info = outInfo.GetInformationObject(0)
        t = info.Get(SDDP.UPDATE_TIME_STEP()) if info.Has(SDDP.UPDATE_TIME_STEP()) else 0.0
        self.times.append(t)
        out = vtkImageData.GetData(outInfo)
        out.CopyStructure(self.reference)
        if self.scalars is None:
            dims = tuple(out.GetDimensions())
            add_point_array(out, "fluence", np.full(dims + (3,), 10.0 * (1.0 + t)), set_active=True)
        else:
            add_point_array(out, "scalars", self.scalars, set_active=True)
        return 1


def test_mapper_follows_time_steps(setup):
    volume, scene, _, _ = setup
    reference = image_data_from_volume(volume)
    data = TimeSeries(reference, volume.scalars)
    light = TimeSeries(image_like(reference, shape=(9, 9, 9)))
    actor = IlluminatedVolume(data.GetOutputPort(), scene, illumination=light)
    renderer = vtkRenderer()
    renderer.AddVolume(actor)
    window = offscreen_window(renderer, scene.camera, WIDTH, HEIGHT)
    first = read_window_rgb(window)
    actor.set_time(2.0)
    later = read_window_rgb(window)
    assert data.times[-1] == light.times[-1] == 2.0
    covered = first > 0.05
    assert abs(float(np.median(later[covered] / first[covered])) - 3.0) < 0.1
    executions = len(light.times)
    read_window_rgb(window)  # same time, nothing modified: no re-execution
    assert len(light.times) == executions
    window.Finalize()


def test_pyvista_plotter_add_actor(setup):
    pv = pytest.importorskip("pyvista")
    volume, scene, illumination, reference = setup
    grid = pv.wrap(image_data_from_volume(volume))
    actor = IlluminatedVolume(grid, scene, illumination=illumination)
    shot = pyvista_screenshot(actor, scene.camera, WIDTH, HEIGHT)
    assert shot.shape[:2] == (HEIGHT, WIDTH)
    assert shot.max() > 0.5 and (shot.max(-1) > 0.05).mean() > 0.3  # not blank
    errors = rel_errors(shot[..., :3], reference.radiance)
    assert within(errors), errors


def test_cli_single_matches_compute_path(tmp_path):
    """The CLI takes no illumination volume, so its ``single`` render is compared instead."""
    cli = pytest.importorskip("vtkillum.cli")
    pytest.importorskip("vtkillum.io.readers")
    pytest.importorskip("vtkillum.data.builtin")
    from vtkmodules.vtkIOXML import vtkXMLImageDataWriter

    from vtkillum.core.scene import save_scene

    volume = blob_volume()
    scene = make_scene(volume)
    writer = vtkXMLImageDataWriter()
    writer.SetFileName(str(tmp_path / "blobs.vti"))
    writer.SetInputData(image_data_from_volume(volume))
    writer.Write()
    save_scene(scene, tmp_path / "scene.json")
    status = cli.main(["render", str(tmp_path / "blobs.vti"),
                       "--scene", str(tmp_path / "scene.json"), "--method", "single",
                       "--size", str(WIDTH), str(HEIGHT), "--option", "jitter=false",
                       "--device", "cpu", "--quiet", "--output", str(tmp_path / "single.npz")])
    assert status == 0
    radiance = np.load(tmp_path / "single.npz")["radiance"]
    exposure = 0.9 / float(radiance.max())

    renderer = vtkRenderer()
    window = offscreen_window(renderer, scene.camera, WIDTH, HEIGHT)
    # No reference kept: the renderer's observer keeps the compute path alive.
    ComputeVolumeRenderer(renderer, volume, scene, method="single", device="cpu",
                          exposure=exposure, jitter=False)
    image = read_window_rgb(window)
    # Same numbers up to the 8-bit display: |shown - exposure L| <= half a level.
    assert np.abs(image - np.clip(exposure * radiance, 0.0, 1.0)).max() <= 0.5 / 255 + 1e-6
    assert (image.max(-1) > 0.05).mean() > 0.3
    window.Finalize()


def test_progressive_path_refines_and_restarts():
    volume = Volume(np.pad(np.ones((6, 6, 6)), 1), spacing=(1.0, 1.0, 1.0))
    scene = Scene(transfer_function=TransferFunction([0.0, 1.0], [0.0, 0.5]),
                  options={"path": {"spp": 5, "max_bounces": 2, "seed": 3}})
    renderer = vtkRenderer()
    window = offscreen_window(renderer, scene.resolved_camera(volume), WIDTH, HEIGHT)
    window.SetSize(16, 16)
    shown = ComputeVolumeRenderer(renderer, volume, scene, method="path", device="cpu")
    window.Render()
    assert shown.passes == 1
    assert shown.refine(2) == 3
    assert shown.refine(10) == 5  # stops at spp
    window.Render()  # camera at rest: no restart
    assert shown.passes == 5
    renderer.GetActiveCamera().Elevation(10.0)
    window.Render()
    assert shown.passes == 1
    assert shown.result.alpha.max() > 0.5
    window.Finalize()


def test_camera_and_scene_bridge_round_trip():
    cam = Camera((1.0, 2.0, 9.0), (0.5, 0.0, 0.0), (0.0, 1.0, 0.2), 35.0)
    back = camera_from_vtk(apply_camera_to_vtk(cam, vtkCamera()))
    for name in ("position", "focal_point", "view_angle", "parallel_projection"):
        assert np.allclose(getattr(back, name), getattr(cam, name))
    assert np.allclose(back.basis(), cam.basis())
    parallel = Camera((0, 0, 5), (0, 0, 0), (0, 1, 0), parallel_projection=True, parallel_scale=2.5)
    assert camera_from_vtk(apply_camera_to_vtk(parallel, vtkCamera())).parallel_scale == 2.5

    horizontal = apply_camera_to_vtk(cam, vtkCamera())
    horizontal.UseHorizontalViewAngleOn()
    horizontal.SetViewAngle(60.0)
    with pytest.raises(ValueError, match="aspect"):
        camera_from_vtk(horizontal)
    vertical = camera_from_vtk(horizontal, aspect=2.0)
    assert np.isclose(np.tan(np.radians(vertical.view_angle) / 2) * 2.0, np.tan(np.radians(30.0)))
    shifted = vtkCamera()
    shifted.SetWindowCenter(0.2, 0.0)
    with pytest.raises(ValueError, match="WindowCenter"):
        camera_from_vtk(shifted)

    volume = blob_volume()
    scene = make_scene(volume)
    prop = apply_scene_to_volume_property(scene, volume, vtkVolumeProperty())
    again = scene_from_vtk(prop, apply_camera_to_vtk(cam, vtkCamera()), base=scene)
    v = np.linspace(-0.5, 1.5, 101)
    assert np.allclose(again.transfer_function.alpha(v), scene.transfer_function.alpha(v))
    assert np.allclose(again.transfer_function.color(v), scene.transfer_function.color(v))
    assert again.opacity_unit_distance == pytest.approx(UNIT)
    assert [l.to_dict() for l in again.lights] == [l.to_dict() for l in scene.lights]
    assert again.shading == scene.shading
    assert np.allclose(again.camera.position, cam.position)


def test_bad_inputs_raise_clear_errors(setup):
    volume, scene, illumination, _ = setup
    image = image_data_from_volume(volume)
    with pytest.raises(TypeError, match="vtkImageData"):
        IlluminatedVolume(np.zeros((4, 4, 4)), scene)
    with pytest.raises(ValueError, match="array_name"):
        IlluminatedVolume(image, scene, array_name="missing")
    many = Scene(lights=[DirectionalLight((0, -1, 0))] * 9)
    with pytest.raises(ValueError, match="at most 8 lights"):
        IlluminatedVolume(image, many)
    with pytest.raises(ValueError, match="illumination volume"):
        ComputeVolumeRenderer(vtkRenderer(), volume, scene, method="illumination")
    with pytest.raises(ValueError, match="unknown method"):
        ComputeVolumeRenderer(vtkRenderer(), volume, scene, method="nope")
    wrong_box = image_like(image, shape=(8, 8, 8))
    wrong_box.SetOrigin(0.0, 0.0, 0.0)
    add_point_array(wrong_box, "fluence", np.ones((8, 8, 8, 3)))
    with pytest.raises(ValueError, match="does not cover"):
        IlluminatedVolume(image, scene, illumination=wrong_box)


def test_cli_transmittance_matches_opengl_mapper(tmp_path):
    """Three ways, one picture: the CLI's ``transmittance`` render (shadow volume computed by
    the core, ray cast by warp), and the OpenGL mapper fed the same shadow volume, agree
    within the OpenGL-vs-warp tolerance."""
    cli = pytest.importorskip("vtkillum.cli")
    from vtkmodules.vtkIOXML import vtkXMLImageDataWriter

    from vtkillum.core.light_transmittance import light_transmittance
    from vtkillum.core.scene import save_scene

    volume = blob_volume()
    scene = make_scene(volume)
    scene.lights = [DirectionalLight((0.6, -1.0, 0.2), IRRADIANCE)]
    writer = vtkXMLImageDataWriter()
    writer.SetFileName(str(tmp_path / "blobs.vti"))
    writer.SetInputData(image_data_from_volume(volume))
    writer.Write()
    save_scene(scene, tmp_path / "scene.json")
    status = cli.main(["render", str(tmp_path / "blobs.vti"), "--scene", str(tmp_path / "scene.json"),
                       "--method", "transmittance", "--size", str(WIDTH), str(HEIGHT),
                       "--option", "jitter=false", "--option", f"early_termination={EARLY_STOP}",
                       "--device", "cpu", "--quiet", "--output", str(tmp_path / "cli.npz")])
    assert status == 0
    cli_radiance = np.load(tmp_path / "cli.npz")["radiance"]
    assert cli_radiance.max() > 0.3

    _, fluence = light_transmittance(volume, scene.transfer_function, UNIT, scene.lights,
                                     device="cpu")
    renderer = vtkRenderer()
    actor = IlluminatedVolume(image_data_from_volume(volume), scene,
                              illumination=IlluminationVolume.for_volume(volume, fluence))
    renderer.AddVolume(actor)
    window = offscreen_window(renderer, scene.camera, WIDTH, HEIGHT)
    errors = rel_errors(read_window_rgb(window), cli_radiance)
    print(f"CLI transmittance vs OpenGL: mean {errors[0]:.2e}, p99 {errors[1]:.2e}")
    assert within(errors), errors
    window.Finalize()
