"""The illuminated volume mapper (OpenGL path) and the compute path agree with the warp ray caster.

Scene: a 32³ volume of two smooth blobs (anisotropic spacing, offset origin), a
coloured transfer function, a perspective camera, one directional and one point
light with diffuse and specular Phong terms, ``g = 0.3``, and a phase-aware
illumination volume: the per-light transmittance computed by the core on a light
grid of 24³ points (:func:`vtkillum.core.light_transmittance.light_transmittance`)
and a scattered fluence computed analytically from the data, ``φ_s = c exp(-∫ σt dy)``
(per channel c, a light entering at +y). The same illumination volume goes to

* :class:`IlluminatedVolume` in an offscreen VTK window (OSMesa), read back as
  8-bit linear RGB over a black background;
* :func:`vtkillum.core.raycast.render_illuminated` (warp, no jitter, VTK's early
  termination ``1 - 1/255``, the default near-field march of 2 light-grid cells);
* :class:`ComputeVolumeRenderer` (warp image shown as the renderer's background).

Tolerances, relative to the reference image's maximum (exposure puts it at 0.8 of
the 8-bit range), over all pixels and channels: OpenGL vs warp mean abs error <
``MEAN_TOL`` (3e-3) and 99th percentile < ``P99_TOL`` (1.2e-2). Measured (mean / p99):

=====================================================  ===================
case                                                   OpenGL vs warp
=====================================================  ===================
blobs, 2 lights + scattered, Phong, g = 0.3            7.5e-4 / 2.4e-3
blobs, directional, g = +0.6                           7.5e-4 / 2.4e-3
blobs, directional, g = -0.6                           7.4e-4 / 2.4e-3
blobs, point light near the data, g = 0.4              7.4e-4 / 2.4e-3
blobs, 2 lights (directional + point), g = 0.3         7.5e-4 / 2.4e-3
blobs, point light inside the data, g = 0.4            7.4e-4 / 2.4e-3
sharp sphere, half-resolution light grid, g = 0.6      3.0e-4 / 2.4e-3
half-resolution illumination image from a pipeline     7.5e-4 / 2.4e-3
CLI ``transmittance`` vs filter output port, g = 0.5   7.5e-4 / 2.4e-3
=====================================================  ===================

That is the 8-bit read-back alone: the compute path (the warp image, quantised) and
the OpenGL image agree to 1e-6, and in the per-light cases every pixel is within half an
8-bit level of the warp radiance (max abs difference 1.96e-3; asserted < 4/255). The comparison sees every ingredient; these fail it:

=====================================================  ===================
perturbation                                           mean / p99
=====================================================  ===================
constant scattered fluence (its σt-weighted mean)      3.5e-2 / 0.31
no illumination (unshadowed default)                   0.11 / 0.71
lights mirrored                                        1.1e-2 / 7.2e-2
phase ignored (g = 0 for 0.3, blobs)                   5.7e-3 / 3.3e-2
phase ignored (g = 0 for 0.6, sphere)                  1.1e-2 / 0.23
near-field march dropped (``near_cells=0``, sphere)    1.3e-2 / 0.15
=====================================================  ===================

Against exact single scattering (warp ``single``) the sphere's OpenGL image has a
relative RMSE of 0.038 with the march and 0.22 without it (grid-aligned bands). The
compute path must show the tone-mapped warp image to 1/255, and the CLI's ``single``
render (it takes no illumination volume) to half a level of the 8-bit display.
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
from vtkillum.core.light_transmittance import light_transmittance
from vtkillum.core.lights import DirectionalLight, PointLight
from vtkillum.core.raycast import RAYCAST_OPTIONS, render_illuminated, render_single
from vtkillum.core.scene import Scene
from vtkillum.core.tonemap import tonemap
from vtkillum.core.transfer_function import TransferFunction
from vtkillum.core.volume import Volume

pytest.importorskip("vtkmodules.vtkRenderingVolumeOpenGL2")
from vtkmodules.util.numpy_support import vtk_to_numpy
from vtkmodules.util.vtkAlgorithm import VTKPythonAlgorithmBase
from vtkmodules.vtkCommonDataModel import vtkImageData
from vtkmodules.vtkCommonExecutionModel import (
    vtkStreamingDemandDrivenPipeline as SDDP,
)
from vtkmodules.vtkRenderingCore import (
    vtkCamera,
    vtkRenderer,
    vtkVolumeProperty,
)

from vtkillum.io.convert import add_point_array, image_data_from_volume, image_like
from vtkillum.io.illumination_arrays import (
    add_lights_field,
    illumination_arrays,
)
from vtkillum.mappers import (
    ComputeVolumeRenderer,
    IlluminatedVolume,
    apply_camera_to_vtk,
    apply_scene_to_volume_property,
    camera_from_vtk,
    scene_from_vtk,
)
from vtkillum.mappers.illuminated_volume_mapper import NEAR_CELLS

MEAN_TOL = 3e-3
P99_TOL = 1.2e-2
WIDTH, HEIGHT = 64, 64
UNIT = 1.3
EARLY_STOP = 1.0 - 1.0 / 255.0  # VTK's g_opacityThreshold
PEAK = 0.8  # the exposure puts the reference's maximum here (inside the 8-bit range)
IRRADIANCE = np.array([30.0, 24.0, 18.0])  # of the scattered fluence's slab light
LIGHT_GRID = (24, 24, 24)


def slab_fluence(volume: Volume, tf: TransferFunction, scale: float = 1.0) -> np.ndarray:
    """``E exp(-τ)`` with τ the optical depth from the +y face (trapezoid rule on the grid)."""
    sigma = tf.sigma_t(volume.scalars, UNIT)
    h = volume.spacing[1]
    from_top = sigma[:, ::-1, :]
    tau = np.concatenate([np.zeros_like(from_top[:, :1]),
                          np.cumsum(0.5 * (from_top[:, 1:] + from_top[:, :-1]) * h, axis=1)], 1)
    return (scale * np.exp(-tau[:, ::-1, :])[..., None] * IRRADIANCE).astype(np.float32)


def blob_lights(volume: Volume, mirrored: bool = False) -> list:
    m = np.array([-1.0, -1.0, 1.0]) if mirrored else np.ones(3)
    centre = volume.bounds.reshape(3, 2).mean(1)
    return [DirectionalLight(m * np.array([0.6, -1.0, 0.2]), (2.0, 1.6, 1.2)),
            PointLight(centre + m * np.array([25.0, 20.0, 0.0]), (900.0, 900.0, 900.0))]


def make_scene(volume: Volume, mirrored: bool = False, anisotropy: float = 0.3,
               lights=None) -> Scene:
    return Scene(transfer_function=blob_tf(), opacity_unit_distance=UNIT,
                 camera=zoomed_camera(volume), anisotropy=anisotropy,
                 lights=lights if lights is not None else blob_lights(volume, mirrored),
                 step_size=0.5 * float(volume.spacing.min()),
                 shading={"ambient": 0.4, "diffuse": 0.6, "specular": 0.3, "shininess": 20.0})


def direct_light(volume: Volume, scene: Scene, shape=LIGHT_GRID, device: str = "cpu") -> np.ndarray:
    """Per-light transmittance of the scene's lights on a light grid (computed on warp's
    ``device``)."""
    return light_transmittance(volume, scene.transfer_function, UNIT, scene.lights,
                               shape=shape, device=device)[0]


def warp_reference(volume, scene, illumination, **options):
    return render_illuminated(volume, scene, WIDTH, HEIGHT, "cpu", illumination=illumination,
                              jitter=False, early_termination=EARLY_STOP, **options)


def render_opengl(image, scene, illumination, exposure, **kwargs):
    """``(image, actor, window)``: ``image`` read back from an offscreen window."""
    renderer = vtkRenderer()
    kwargs.setdefault("jitter", False)
    actor = IlluminatedVolume(image, scene, illumination=illumination, exposure=exposure,
                              **kwargs)
    renderer.AddVolume(actor)
    window = offscreen_window(renderer, scene.camera, WIDTH, HEIGHT)
    return read_window_rgb(window), actor, window


def within(errors) -> bool:
    return errors[0] < MEAN_TOL and errors[1] < P99_TOL


@pytest.fixture(scope="module")
def setup():
    """Blobs, 2 lights, g = 0.3, transmittance + scattered; the warp reference at PEAK."""
    volume = blob_volume()
    scene = make_scene(volume)
    illumination = IlluminationVolume.for_volume(
        volume, slab_fluence(volume, scene.transfer_function, 0.5), direct_light(volume, scene))
    reference = warp_reference(volume, scene, illumination)
    exposure = PEAK / float(reference.radiance.max())
    reference.radiance[:] *= exposure
    return volume, scene, illumination, reference, exposure


def test_near_cells_default_is_the_warp_casters():
    assert NEAR_CELLS == RAYCAST_OPTIONS["near_cells"]


def test_opengl_mapper_matches_warp_illuminated(setup):
    volume, scene, illumination, reference, exposure = setup
    image, actor, window = render_opengl(image_data_from_volume(volume), scene, illumination,
                                         exposure)
    errors = rel_errors(image, reference.radiance)
    print(f"OpenGL vs warp: mean {errors[0]:.2e}, p99 {errors[1]:.2e} (relative to max)")
    assert within(errors), errors
    assert [l.to_dict() for l in actor.lights] == [l.to_dict() for l in scene.lights]

    def fails(what):
        errors = rel_errors(read_window_rgb(window), reference.radiance)
        print(f"{what}: mean {errors[0]:.2e}, p99 {errors[1]:.2e}")
        assert not within(errors), f"{what} was not detected: {errors}"

    # The comparison sees the scattered texture: a constant one (its mean, weighted by
    # extinction so the brightness roughly matches) fails it ...
    sigma = scene.transfer_function.sigma_t(volume.scalars, UNIT)[..., None]
    mean_phi = (illumination.scattered * sigma).sum((0, 1, 2)) / sigma.sum()
    actor.set_illumination(IlluminationVolume.for_volume(
        volume, np.broadcast_to(mean_phi, illumination.scattered.shape).copy(),
        illumination.transmittance))
    fails("constant scattered fluence")
    # ... and so does the unshadowed default (no illumination set)
    actor.set_illumination(None)
    fails("unshadowed default")
    # ... and lights mirrored in the Phong factor and the direct light
    actor.set_illumination(illumination)
    actor.set_scene(make_scene(volume, mirrored=True))
    fails("mirrored lights")
    # ... and an isotropic phase function in place of the scene's g = 0.3.
    actor.set_scene(make_scene(volume, anisotropy=0.0))
    fails("phase ignored (g = 0)")
    actor.set_scene(scene)
    assert within(rel_errors(read_window_rgb(window), reference.radiance))
    window.Finalize()


CASES = {
    # name: (lights, g, with scattered fluence)
    "directional g=+0.6": (lambda v: [DirectionalLight((0.6, -1.0, 0.2), (2.0, 1.6, 1.2))],
                           0.6, False),
    "directional g=-0.6": (lambda v: [DirectionalLight((0.6, -1.0, 0.2), (2.0, 1.6, 1.2))],
                           -0.6, False),
    "point light g=0.4": (lambda v: [PointLight(v.bounds.reshape(3, 2).mean(1)
                                                + np.array([-6.0, 22.0, 8.0]),
                                                (400.0, 500.0, 600.0))], 0.4, False),
    "two lights g=0.3": (blob_lights, 0.3, True),
    # inside the data, 0.4 voxels from a grid point: I / max(d, r)^2 with r half a voxel
    "point light inside g=0.4": (lambda v: [PointLight(v.origin + v.spacing * np.array(
        [12.0, 15.4, 17.0]), (20.0, 20.0, 20.0))], 0.4, True),
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_opengl_matches_warp_per_light_and_phase(case):
    make_lights, g, scattered = CASES[case]
    volume = blob_volume()
    scene = make_scene(volume, anisotropy=g, lights=make_lights(volume))
    illumination = IlluminationVolume.for_volume(
        volume, slab_fluence(volume, scene.transfer_function, 0.5) if scattered else None,
        direct_light(volume, scene))
    reference = warp_reference(volume, scene, illumination)
    exposure = PEAK / float(reference.radiance.max())
    image, _, window = render_opengl(image_data_from_volume(volume), scene, illumination,
                                     exposure)
    errors = rel_errors(image, exposure * reference.radiance)
    worst = float(np.abs(image - exposure * reference.radiance).max())
    print(f"{case}: OpenGL vs warp mean {errors[0]:.2e}, p99 {errors[1]:.2e}, max {worst:.2e}")
    assert within(errors), errors
    # Every pixel within a few 8-bit levels: e.g. I / d^2 instead of I / max(d, r)^2 next to
    # the light inside the data is off by 0.2 in a pixel.
    assert worst < 4.0 / 255.0, worst
    window.Finalize()


def sharp_sphere():
    """A 40³ sphere with a one-voxel edge, lit from the side: the case that shows rings."""
    n = 40
    x = np.linspace(-1.0, 1.0, n)
    X, Y, Z = np.meshgrid(x, x, x, indexing="ij")
    r = np.sqrt(X ** 2 + Y ** 2 + Z ** 2)
    volume = Volume(np.clip((0.7 - r) / (x[1] - x[0]) + 0.5, 0.0, 1.0),
                    origin=(-5.0, 2.0, 1.0))
    tf = TransferFunction([0.0, 0.5, 1.0], [0.0, 0.3, 0.5], [[1.0, 0.9, 0.8]] * 3)
    cam = Camera.looking_at_bounds(volume.bounds, direction=(-0.2, -0.3, -1.0),
                                   view_up=(0.0, 1.0, 0.0))
    cam = Camera(cam.focal_point + 0.6 * (cam.position - cam.focal_point), cam.focal_point,
                 cam.view_up, cam.view_angle)
    scene = Scene(transfer_function=tf, opacity_unit_distance=1.0, camera=cam, anisotropy=0.6,
                  lights=[DirectionalLight((1.0, -0.2, 0.5), (10.0, 10.0, 10.0))],
                  step_size=0.5)
    # A half-resolution light grid, as LightTransmittanceFilter(OutputScale=0.5) makes.
    transmittance = light_transmittance(volume, tf, 1.0, scene.lights, shape=(20, 20, 20),
                                        device="cpu")[0]
    return volume, scene, IlluminationVolume.for_volume(volume, transmittance=transmittance)


def test_phase_and_near_field_march_on_a_sharp_sphere():
    """The OpenGL path applies the phase and the exact near-field march like the warp caster.

    The warp references: ``transmittance`` (near_cells 2) and ``single`` (exact shadow
    rays). The sphere's edge is one voxel wide and the light grid has half the data's
    resolution, so reading the grid at the sample (near_cells 0) gives grid-aligned bands.
    """
    volume, scene, illumination = sharp_sphere()
    reference = warp_reference(volume, scene, illumination)
    exposure = PEAK / float(reference.radiance.max())
    expected = exposure * reference.radiance
    single = exposure * render_single(volume, scene, WIDTH, HEIGHT, "cpu", jitter=False,
                                      early_termination=EARLY_STOP).radiance
    image, actor, window = render_opengl(image_data_from_volume(volume), scene, illumination,
                                         exposure)
    errors = rel_errors(image, expected)
    print(f"sharp sphere: OpenGL vs warp mean {errors[0]:.2e}, p99 {errors[1]:.2e}")
    assert within(errors), errors

    def rel_rmse(a, b):
        return float(np.sqrt(((a - b) ** 2).mean() / (b ** 2).mean()))

    # Against exact single scattering: close with the march, banded without it.
    with_march = rel_rmse(image, single)
    actor.near_cells = 0.0
    banded = read_window_rgb(window)
    without_march = rel_rmse(banded, single)
    print(f"rel. RMSE vs single: near_cells 2 {with_march:.3f}, near_cells 0 {without_march:.3f}")
    assert with_march < 0.06
    assert without_march > 2.5 * with_march
    dropped = rel_errors(banded, expected)
    print(f"near-field march dropped: mean {dropped[0]:.2e}, p99 {dropped[1]:.2e}")
    assert not within(dropped)
    # The bands are the grid's: the warp caster without the march shows the same image.
    no_march = exposure * warp_reference(volume, scene, illumination, near_cells=0.0).radiance
    assert within(rel_errors(banded, no_march))

    # The phase function: g = 0 in place of the scene's 0.6 fails the comparison.
    actor.near_cells = NEAR_CELLS
    isotropic = copy.copy(scene)
    isotropic.anisotropy = 0.0
    actor.set_scene(isotropic)
    ignored = rel_errors(read_window_rgb(window), expected)
    print(f"phase ignored: mean {ignored[0]:.2e}, p99 {ignored[1]:.2e}")
    assert not within(ignored)
    window.Finalize()


def test_compute_path_shows_warp_image_and_matches_opengl(setup):
    volume, scene, illumination, reference, exposure = setup
    renderer = vtkRenderer()
    window = offscreen_window(renderer, scene.camera, WIDTH, HEIGHT)
    shown = ComputeVolumeRenderer(renderer, volume, scene, method="illumination",
                                  illumination=illumination, device="cpu", jitter=False,
                                  early_termination=EARLY_STOP, exposure=exposure)
    image = read_window_rgb(window)
    expected = tonemap(reference.radiance, reference.alpha, (0.0, 0.0, 0.0), gamma=1.0)
    assert np.abs(image * 255.0 - expected).max() <= 1.0

    gl_image, _, gl_window = render_opengl(image_data_from_volume(volume), scene, illumination,
                                           exposure)
    errors = rel_errors(gl_image, image)
    print(f"OpenGL vs compute path: mean {errors[0]:.2e}, p99 {errors[1]:.2e}")
    assert within(errors), errors

    # A camera move re-renders: the image follows the VTK camera.
    renderer.GetActiveCamera().Azimuth(40.0)
    moved = read_window_rgb(window)
    rotated = copy.copy(scene)
    rotated.camera = camera_from_vtk(renderer.GetActiveCamera())
    again = warp_reference(volume, rotated, illumination)
    expected = tonemap(exposure * again.radiance, again.alpha, (0.0, 0.0, 0.0), gamma=1.0)
    assert np.abs(moved * 255.0 - expected).max() <= 1.0
    assert np.abs(moved - image).mean() > 0.01
    shown.detach()
    assert not renderer.GetTexturedBackground()
    window.Finalize()
    gl_window.Finalize()


def illumination_image(volume, illumination, lights, shape):
    """An illumination filter's output: the arrays of io.illumination_arrays and the lights."""
    image = image_like(image_data_from_volume(volume), shape=shape)
    for name, values in illumination_arrays(illumination, volume, lights, shape).items():
        add_point_array(image, name, values, set_active=name == "fluence")
    add_lights_field(image, lights)
    return image


def test_mapper_follows_illumination_data_and_resolution(setup):
    volume, scene, _, _, _ = setup
    # A half-resolution illumination image covering the same box, as the filters output,
    # carrying its lights; the scene given to the mapper has other (default) lights.
    coarse_shape = (17, 17, 17)
    from vtkillum.core.resample import resample_points

    coarse = IlluminationVolume.for_volume(
        volume, resample_points(slab_fluence(volume, scene.transfer_function, 0.5), coarse_shape),
        direct_light(volume, scene, coarse_shape))
    image = illumination_image(volume, coarse, scene.lights, coarse_shape)
    reference = warp_reference(volume, scene, coarse)
    exposure = PEAK / float(reference.radiance.max())
    other_lights = copy.copy(scene)
    other_lights.lights = [DirectionalLight((0.0, 0.0, 1.0))]
    first, actor, window = render_opengl(image_data_from_volume(volume), other_lights, image,
                                         exposure)
    assert [l.to_dict() for l in actor.lights] == [l.to_dict() for l in scene.lights]
    errors = rel_errors(first, exposure * reference.radiance)
    print(f"half-resolution image from a pipeline: mean {errors[0]:.2e}, p99 {errors[1]:.2e}")
    assert within(errors), errors

    # Editing the arrays in place (and marking them modified) re-uploads on the next render;
    # the source is linear in both.
    for name in ("transmittance", "scattered_fluence"):
        array = image.GetPointData().GetArray(name)
        vtk_to_numpy(array)[:] *= 0.5
        array.Modified()
    second = read_window_rgb(window)
    covered = first > 0.1
    ratio = second[covered] / first[covered]
    assert abs(float(np.median(ratio)) - 0.5) < 0.02, np.median(ratio)

    # A new illumination object replaces the old one (now with the scene's lights).
    actor.set_illumination(IlluminationVolume.for_volume(volume, 0.75 * coarse.scattered))
    assert [l.to_dict() for l in actor.lights] == [l.to_dict() for l in other_lights.lights]
    third = read_window_rgb(window)
    scattered_only = warp_reference(volume, other_lights,
                                    IlluminationVolume.for_volume(volume, 0.75 * coarse.scattered))
    assert within(rel_errors(third, exposure * scattered_only.radiance))
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
    volume, scene, _, _, _ = setup
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
    volume, scene, illumination, reference, exposure = setup
    grid = pv.wrap(image_data_from_volume(volume))
    actor = IlluminatedVolume(grid, scene, illumination=illumination, exposure=exposure,
                              jitter=False)
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


def test_exposure_scales_the_volume_not_the_background(setup):
    """The display is ``exposure * L + (1 - alpha) * background``: a pixel the volume does
    not cover shows the renderer's background as it is, whatever the exposure."""
    volume, scene, illumination, reference, exposure = setup
    renderer = vtkRenderer()
    window = offscreen_window(renderer, scene.camera, WIDTH, HEIGHT)
    renderer.SetBackground(0.2, 0.3, 0.4)
    shown = ComputeVolumeRenderer(renderer, volume, scene, method="illumination",
                                  illumination=illumination, device="cpu", jitter=False,
                                  early_termination=EARLY_STOP, exposure=3.0 * exposure)
    window.Render()
    image = shown.display_image()
    expected = tonemap(3.0 * exposure * shown.result.radiance, shown.result.alpha,
                       (0.2, 0.3, 0.4), gamma=1.0)
    assert np.abs(image.astype(int) - expected).max() <= 1
    empty = shown.result.alpha == 0.0
    assert empty.any()
    assert np.all(image[empty] == np.rint(255 * np.array([0.2, 0.3, 0.4])).astype(np.uint8))
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
    volume, scene, _, _, _ = setup
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


def test_cli_transmittance_matches_filter_and_opengl_mapper(tmp_path):
    """Three ways, one picture: the CLI's ``transmittance`` render (shadow volume computed by
    the core, ray cast by warp), and the OpenGL mapper and the compute path fed a
    ``LightTransmittanceFilter``'s output (transmittance and lights through the pipeline;
    the mapper's own scene has the default light), with g = 0.5."""
    cli = pytest.importorskip("vtkillum.cli")
    from vtkmodules.vtkIOXML import vtkXMLImageDataWriter

    from vtkillum.core.scene import save_scene
    from vtkillum.filters import LightTransmittanceFilter

    volume = blob_volume()
    scene = make_scene(volume, anisotropy=0.5)
    scene.lights = [DirectionalLight((0.6, -1.0, 0.2), IRRADIANCE / 10.0),
                    PointLight(volume.bounds.reshape(3, 2).mean(1) + np.array([-6.0, 22.0, 8.0]),
                               (400.0, 500.0, 600.0))]
    image = image_data_from_volume(volume)
    writer = vtkXMLImageDataWriter()
    writer.SetFileName(str(tmp_path / "blobs.vti"))
    writer.SetInputData(image)
    writer.Write()
    save_scene(scene, tmp_path / "scene.json")
    status = cli.main(["render", str(tmp_path / "blobs.vti"), "--scene", str(tmp_path / "scene.json"),
                       "--method", "transmittance", "--size", str(WIDTH), str(HEIGHT),
                       "--option", "jitter=false", "--option", f"early_termination={EARLY_STOP}",
                       "--device", "cpu", "--quiet", "--output", str(tmp_path / "cli.npz")])
    assert status == 0
    cli_radiance = np.load(tmp_path / "cli.npz")["radiance"]
    exposure = PEAK / float(cli_radiance.max())

    light = LightTransmittanceFilter()
    light.SetDevice("cpu")
    light.SetInputData(image)
    light.SetTransferFunction(scene.transfer_function)
    light.SetScalarOpacityUnitDistance(UNIT)
    light.SetLights(scene.lights)
    mapper_scene = copy.copy(scene)
    mapper_scene.lights = Scene().lights
    gl_image, actor, window = render_opengl(image, mapper_scene, light.GetOutputPort(), exposure)
    assert [l.to_dict() for l in actor.lights] == [l.to_dict() for l in scene.lights]
    errors = rel_errors(gl_image, exposure * cli_radiance)
    print(f"CLI transmittance vs OpenGL: mean {errors[0]:.2e}, p99 {errors[1]:.2e}")
    assert within(errors), errors
    window.Finalize()

    # The compute path reads the same filter output, its lights included.
    renderer = vtkRenderer()
    window = offscreen_window(renderer, scene.camera, WIDTH, HEIGHT)
    shown = ComputeVolumeRenderer(renderer, volume, mapper_scene, method="illumination",
                                  illumination=light.GetOutputDataObject(0), device="cpu",
                                  jitter=False, early_termination=EARLY_STOP, exposure=exposure)
    assert [l.to_dict() for l in shown.lights] == [l.to_dict() for l in scene.lights]
    computed = read_window_rgb(window)
    assert within(rel_errors(computed, exposure * cli_radiance))
    window.Finalize()


def test_jitter_keeps_the_mean_and_varies_per_pixel(setup):
    """``jitter=True`` (the default) offsets each pixel's samples: same energy, other pixels."""
    volume, scene, illumination, reference, exposure = setup
    fixed, _, window = render_opengl(image_data_from_volume(volume), scene, illumination,
                                     exposure, jitter=False)
    window.Finalize()
    jittered, actor, window = render_opengl(image_data_from_volume(volume), scene, illumination,
                                            exposure, jitter=True)
    assert actor.jitter
    window.Finalize()
    assert abs(jittered.sum() / fixed.sum() - 1.0) < 0.01
    assert np.abs(jittered - fixed).max() > 2.0 / 255.0
    assert rel_errors(jittered, reference.radiance)[0] < 2 * MEAN_TOL


def test_volume_survives_its_window_and_shows_in_a_new_one(setup):
    volume, scene, illumination, reference, exposure = setup
    first, actor, window = render_opengl(image_data_from_volume(volume), scene, illumination,
                                         exposure)
    window.Finalize()
    renderer = vtkRenderer()
    renderer.AddVolume(actor)
    again = read_window_rgb(offscreen_window(renderer, scene.camera, WIDTH, HEIGHT))
    assert np.abs(again - first).max() <= 1.0 / 255.0
    assert within(rel_errors(again, reference.radiance))
