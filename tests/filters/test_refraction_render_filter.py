"""RefractionRenderFilter: the refraction method (Magnus & Bruckner 2017) as a VTK image filter."""

import numpy as np
import pytest
from vtkmodules.vtkCommonDataModel import vtkDataObject
from vtkmodules.vtkRenderingCore import vtkCamera

from vtkillum.core.camera import Camera
from vtkillum.core.lights import DirectionalLight
from vtkillum.core.refraction.optics import RefractiveOptics
from vtkillum.core.render import render
from vtkillum.core.scene import Scene
from vtkillum.core.tonemap import tonemap
from vtkillum.core.transfer_function import TransferFunction
from vtkillum.filters import RefractionRenderFilter
from vtkillum.filters.refraction_render import RADIANCE_ARRAY, RGB_ARRAY
from vtkillum.io.convert import point_array, transfer_function_to_vtk, volume_from_image_data

W, H = 24, 20  # not square: a swapped width and height shows
TF = TransferFunction([0.0, 0.4, 1.0], [0.0, 0.05, 0.3],
                      [[1.0, 1.0, 1.0], [0.9, 0.7, 0.4], [0.4, 0.6, 1.0]])
CAMERA = Camera((0.6, -0.8, 6.0), (0.0, 0.0, 0.0), (0.0, 1.0, 0.0), 30.0)
LIGHT = ((0.2, -0.4, -1.0), (2.0, 1.8, 1.5))
OPTICS = RefractiveOptics([0.0, 0.5, 1.0], [1.0, 1.3, 1.5], [0.0, 1.0],
                          [[1.0, 1.0, 1.0], [0.9, 0.6, 0.3]])


def blob(make_image):
    """Off-centre blob (so that a flipped or mirrored picture shows) on a 16 x 14 x 12 grid."""
    dims = (16, 14, 12)
    grids = np.meshgrid(*(np.linspace(-1, 1, n) for n in dims), indexing="ij")
    values = np.exp(-3.0 * ((grids[0] - 0.3) ** 2 + grids[1] ** 2 + (grids[2] + 0.2) ** 2))
    return make_image(dims=dims, spacing=(2 / 15, 2 / 13, 2 / 11), origin=(-1.0, -1.0, -1.0),
                      values=values)


def make_filter(optics=None):
    f = RefractionRenderFilter()
    f.SetDevice("cpu")
    color_tf, opacity_tf = transfer_function_to_vtk(TF)
    f.SetColorTransferFunction(color_tf)
    f.SetScalarOpacity(opacity_tf)
    f.SetImageSize(W, H)
    f.SetCamera(CAMERA)
    f.SetLightDirection(*LIGHT[0])
    f.SetLightIrradiance(*LIGHT[1])
    f.SetSoftness(0.2)
    f.SetSampleDistance(1.5)
    f.SetExposure(8.0)
    if optics is not None:
        f.SetOptics(optics)
    return f


def image_rows(out, name):
    """An output array as a picture (H, W[, c]), row 0 at the top."""
    a = point_array(out, name)[:, :, 0]
    return np.swapaxes(a, 0, 1)[::-1]


def test_the_image_is_the_cores_refraction_render(make_image):
    img = blob(make_image)
    f = make_filter(OPTICS)
    out = f.execute(img)
    assert out.GetDimensions() == (W, H, 1)
    assert out.GetPointData().GetScalars().GetName() == RGB_ARRAY
    volume = volume_from_image_data(img)
    scene = Scene(transfer_function=TF, albedo=0.9, camera=CAMERA,
                  lights=[DirectionalLight(*LIGHT)])
    expected = render(volume, scene, "refraction", W, H, device="cpu", optics=OPTICS,
                      softness=0.2, sample_distance=1.5)
    radiance = image_rows(out, RADIANCE_ARRAY)
    assert radiance.shape == (H, W, 3) and radiance.max() > 0.01
    np.testing.assert_allclose(radiance, expected.radiance, rtol=0, atol=1e-6)
    np.testing.assert_allclose(image_rows(out, "alpha"), expected.alpha, rtol=0, atol=1e-6)
    np.testing.assert_array_equal(image_rows(out, RGB_ARRAY),
                                  tonemap(expected.radiance, exposure=8.0, gamma=2.2))
    # Refraction matters here: the same settings without the optics differ.
    straight = render(volume, scene, "refraction", W, H, device="cpu", softness=0.2,
                      sample_distance=1.5)
    assert np.abs(straight.radiance - expected.radiance).max() > 1e-3


def test_eta_one_table_equals_the_default_and_eta_changes_the_picture(make_image):
    img = blob(make_image)
    default = image_rows(make_filter().execute(img), RADIANCE_ARRAY)
    f = make_filter()
    f.AddRefractiveIndexPoint(0.0, 1.0)
    f.AddRefractiveIndexPoint(1.0, 1.0)
    f.AddMediumColorPoint(0.5, 1.0, 1.0, 1.0)
    np.testing.assert_array_equal(image_rows(f.execute(img), RADIANCE_ARRAY), default)
    # Rows in any order (sorted by value): 1.5 at the core bends the rays.
    f.RemoveAllRefractiveIndexPoints()
    f.AddRefractiveIndexPoint(1.0, 1.5)
    f.AddRefractiveIndexPoint(0.0, 1.0)
    assert f.GetOptics().eta.tolist() == [1.0, 1.5]
    bent = image_rows(f.execute(img), RADIANCE_ARRAY)
    assert np.abs(bent - default).mean() > 1e-3 * default.mean()


def test_automatic_camera_and_vtk_camera(make_image):
    img = blob(make_image)
    f = make_filter()
    f.SetCamera(None)  # frames the data
    auto = image_rows(f.execute(img), RADIANCE_ARRAY)
    assert (auto.max(axis=-1) > 1e-4).mean() > 0.05
    camera = vtkCamera()
    camera.SetPosition(*CAMERA.position)
    camera.SetFocalPoint(*CAMERA.focal_point)
    camera.SetViewUp(*CAMERA.view_up)
    f.SetCamera(camera)
    assert f.GetCamera().to_dict() == CAMERA.to_dict()
    mtime = f.GetMTime()
    f.SetCamera(camera)  # unchanged: no re-execution
    assert f.GetMTime() == mtime


def test_image_size_and_time_steps(time_source):
    f = RefractionRenderFilter()
    f.SetDevice("cpu")
    f.SetImageSize(9, 7)
    f.SetLightDirection(0.0, 0.0, -1.0)
    f.SetCameraPosition(2.0, 1.5, 10.0)
    f.SetCameraFocalPoint(2.0, 1.5, 1.0)
    f.SetInputConnection(time_source.GetOutputPort())
    f.UpdateTimeStep(1.0)
    out = f.GetOutputDataObject(0)
    assert out.GetDimensions() == (9, 7, 1)
    assert out.GetInformation().Get(out.DATA_TIME_STEP()) == 1.0
    assert point_array(out, RGB_ARRAY).dtype == np.uint8


@pytest.mark.parametrize("setup, message", [
    (lambda f: f.AddRefractiveIndexPoint(0.5, -1.0),
     "RefractiveIndex: eta must be > 0 at every control point"),
    (lambda f: f.AddRefractiveIndexPoint(0.5, 0.0),
     "RefractiveIndex: eta must be > 0 at every control point"),
    (lambda f: [f.AddRefractiveIndexPoint(0.5, 1.2), f.AddRefractiveIndexPoint(0.5, 1.3)],
     "RefractiveIndex: two control points at value 0.5"),
    (lambda f: f.AddMediumColorPoint(0.5, 1.0, 1.2, 1.0), r"MediumColor: R G B must lie in \[0, 1\]"),
    (lambda f: f.SetLightDirection(1.0, 0.0, 0.0),
     "LightDirection: .*within 85 degrees of the view direction"),
    (lambda f: f.SetCameraViewUp(0.0, 0.0, 1.0), "CameraViewUp must not be parallel"),
    (lambda f: f.AddLight(DirectionalLight((0, 0, -1))) if hasattr(f, "AddLight")
     else f.AddDirectionalLight((0, 0, -1)), "exactly one distant light"),
])
def test_bad_input_is_an_error_naming_the_property(make_image, setup, message):
    f = make_filter()
    f.SetCamera(Camera((0.0, 0.0, 6.0), (0.0, 0.0, 0.0), (0.0, 1.0, 0.0)))
    setup(f)
    with pytest.raises(ValueError, match=message):
        f.execute(blob(make_image))
    assert f.GetOutputDataObject(0).GetNumberOfPoints() == 0  # no picture


@pytest.mark.parametrize("call, message", [
    (lambda f: f.SetSampleDistance(0.0), "SampleDistance must be > 0"),
    (lambda f: f.SetSampleDistance(-1.0), "SampleDistance must be > 0"),
    (lambda f: f.SetImageSize(0, 10), "ImageSize must be two whole numbers"),
    (lambda f: f.SetLightDirection(0, 0, 0), "LightDirection .* must not be 0 0 0"),
    (lambda f: f.SetLightIrradiance(1, -1, 1), "LightIrradiance must not be negative"),
    (lambda f: f.SetCameraViewAngle(180), "CameraViewAngle must lie in"),
    (lambda f: f.SetSoftness(float("nan")), "Softness must be a number >= 0"),
])
def test_bad_settings_are_refused_by_name(call, message):
    with pytest.raises(ValueError, match=message):
        call(RefractionRenderFilter())


@pytest.mark.parametrize("camera", [
    CAMERA, Camera((3.0, -4.0, 2.0), (0.1, 0.2, -0.1), (0.0, 0.0, 1.0), 40.0),
    Camera((3.0, -4.0, 2.0), (0.1, 0.2, -0.1), (0.0, 0.0, 1.0), parallel_projection=True,
           parallel_scale=1.3)])
def test_image_plane_puts_each_pixel_on_its_ray(camera):
    """Camera.image_plane: pixel (i, j) (j = 0 at the bottom) lies on the ray of column i,
    row H - 1 - j, in the plane through the focal point facing the camera."""
    origin, spacing, direction = camera.image_plane(W, H)
    assert spacing[0] == pytest.approx(spacing[1])
    assert np.allclose(direction.T @ direction, np.eye(3))
    assert np.allclose(direction[:, 2], -camera.forward)
    assert np.linalg.det(direction) == pytest.approx(1.0)  # right-handed
    starts, rays = camera.ray_directions(W, H)
    for i, j in ((0, 0), (W - 1, 0), (5, H - 1), (W // 2, H // 3)):
        point = origin + i * spacing[0] * direction[:, 0] + j * spacing[1] * direction[:, 1]
        assert np.dot(point - camera.focal_point, camera.forward) == pytest.approx(0, abs=1e-9)
        start, ray = starts[H - 1 - j, i], rays[H - 1 - j, i]
        offset = point - start
        assert np.linalg.norm(np.cross(offset, ray)) == pytest.approx(0, abs=1e-9)


def test_place_facing_camera_puts_the_output_on_the_image_plane(make_image):
    img = blob(make_image)
    f = make_filter()
    assert not f.GetPlaceFacingCamera()  # the default: pixel units
    out = f.execute(img)
    assert out.GetOrigin() == (0.0, 0.0, 0.0) and out.GetSpacing() == (1.0, 1.0, 1.0)
    pixels = point_array(out, RGB_ARRAY).copy()
    mtime = f.GetMTime()
    f.SetPlaceFacingCamera(True)
    assert f.GetMTime() > mtime
    out = f.execute(img)
    origin, spacing, direction = CAMERA.image_plane(W, H)
    assert np.allclose(out.GetOrigin(), origin) and np.allclose(out.GetSpacing(), spacing)
    matrix = out.GetDirectionMatrix()
    assert np.allclose([[matrix.GetElement(r, c) for c in range(3)] for r in range(3)],
                       direction)
    assert np.array_equal(point_array(out, RGB_ARRAY), pixels)  # the same picture
    info = f.GetOutputInformation(0)  # the pipeline information says the same
    assert np.allclose(info.Get(vtkDataObject.ORIGIN()), origin)
    f.SetCamera(None)  # the automatic camera frames the data: the plane through its centre
    out = f.execute(img)
    bounds = np.asarray(out.GetBounds()).reshape(3, 2).mean(axis=1)
    data = np.asarray(img.GetBounds()).reshape(3, 2).mean(axis=1)
    assert np.allclose(bounds, data, atol=1e-9)
