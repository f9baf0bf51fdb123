"""PhotonDensityFilter: outputs in the illumination-volume convention, incremental updates
after transfer-function edits equal a fresh execution, and the light volume renders close to
the path tracer."""

import numpy as np
import pytest

from vtkillum.core.light_transmittance import SEGMENT_PLANES
from vtkillum.core.raycast import render_illuminated
from vtkillum.core.render import render
from vtkillum.data.accuracy_suite import _medium_scene, _side_light, smooth_ball
from vtkillum.filters import LightTransmittanceFilter, PhotonDensityFilter
from vtkillum.io.convert import image_data_from_volume, point_array
from vtkillum.io.illumination_arrays import illumination_from_image

REFERENCE = __import__("pathlib").Path(__file__).parents[1] / "core" / "data" / \
    "photon_ball_path.npz"


def ball_setup(optical_diameter=8.0):
    volume = smooth_ball(24)
    scene = _medium_scene(volume, optical_diameter, 0.95, 0.3, [_side_light()])
    return volume, scene


def configured(volume, scene, **props):
    f = PhotonDensityFilter()
    f.SetDevice("cpu")
    f.SetInputData(image_data_from_volume(volume))
    f.SetTransferFunction(scene.transfer_function)
    f.SetScalarOpacityUnitDistance(scene.opacity_unit_distance)
    f.SetAlbedo(scene.albedo)
    f.SetAnisotropy(scene.anisotropy)
    f.RemoveAllLights()
    for light in scene.lights:
        f.AddDirectionalLight(light.direction, light.irradiance)
    f.SetPhotons(20000)
    for name, value in props.items():
        getattr(f, f"Set{name}")(value)
    return f


def test_outputs_and_transmittance():
    volume, scene = ball_setup()
    f = configured(volume, scene)
    f.Update()
    out = f.GetOutputDataObject(0)
    assert out.GetDimensions() == volume.dims
    scattered = point_array(out, "scattered_fluence")
    assert scattered.shape == (*volume.dims, 3) and scattered.min() >= 0 and scattered.max() > 0
    t = LightTransmittanceFilter()
    t.SetDevice("cpu")
    t.SetInputData(image_data_from_volume(volume))
    t.SetTransferFunction(scene.transfer_function)
    t.SetScalarOpacityUnitDistance(scene.opacity_unit_distance)
    t.RemoveAllLights()
    t.AddDirectionalLight(scene.lights[0].direction, scene.lights[0].irradiance)
    t.SetSegmentPlanes(SEGMENT_PLANES)  # the photon filter's grid: light_transmittance's default
    t.Update()
    np.testing.assert_allclose(point_array(out, "transmittance"),
                               point_array(t.GetOutputDataObject(0), "transmittance"), atol=1e-6)
    assert f.GetLastUpdateStats()["mode"] == "full"


def test_photons_only_has_no_transmittance():
    volume, scene = ball_setup()
    f = configured(volume, scene, DirectLight="photons", MaxOrder=1, OutputScale=0.5)
    f.Update()
    out = f.GetOutputDataObject(0)
    assert out.GetPointData().GetArray("transmittance") is None
    assert point_array(out, "scattered_fluence").max() > 0
    assert out.GetDimensions() == (12, 12, 12)


def test_light_volume_renders_close_to_path_tracer():
    """The photon-density volume in the ray caster (exact direct light + scattered photons):
    within 8 % of the path tracer on the thick ball where 76 % of the light is scattered
    more than once (the transmittance-only volume is off by 70 %)."""
    volume, scene = ball_setup()
    ref = np.load(REFERENCE)["radiance"]
    f = configured(volume, scene, Photons=40000, Passes=4, Radius=1.5)
    f.Update()
    illumination = illumination_from_image(f.GetOutputDataObject(0), volume)
    image = render_illuminated(volume, scene, 24, 24, "cpu", illumination=illumination)
    err = np.sqrt(np.mean((image.radiance - ref) ** 2)) / np.sqrt(np.mean(ref ** 2))
    assert err < 0.08, err
    direct = render(volume, scene, "transmittance", 24, 24, "cpu").radiance
    assert np.sqrt(np.mean((direct - ref) ** 2)) / np.sqrt(np.mean(ref ** 2)) > 0.5


def test_transfer_function_edit_is_incremental_and_exact():
    """Equal to a fresh filter with the same settings. (With the automatic radius an
    update keeps the radius of the first trace, which a fresh filter would choose from the
    edited photons: the comparison needs a given one.)"""
    volume, scene = ball_setup(4.0)
    f = configured(volume, scene, Radius=2.0)
    f.Update()
    from vtkillum.core.transfer_function import TransferFunction

    tf = scene.transfer_function
    edited = TransferFunction(tf.scalars, tf.opacity,
                              [[1.0, 1.0, 1.0], [1.0, 1.0, 1.0], [0.9, 0.5, 0.3]])
    f.SetTransferFunction(edited)
    f.Update()
    stats = f.GetLastUpdateStats()
    assert stats["mode"] == "incremental" and 0 < stats["photon_fraction"] <= 1.0
    fresh = configured(volume, scene, Radius=2.0)
    fresh.SetTransferFunction(edited)
    fresh.Update()
    for name in ("scattered_fluence", "transmittance"):
        np.testing.assert_array_equal(point_array(f.GetOutputDataObject(0), name),
                                      point_array(fresh.GetOutputDataObject(0), name))


def test_properties():
    f = PhotonDensityFilter()
    mtime = f.GetMTime()
    f.SetPhotons(0)  # the default: automatic
    assert f.GetMTime() == mtime  # unchanged value: no Modified()
    f.SetRadius(3)
    assert f.GetRadius() == 3.0 and f.GetMTime() > mtime
    f.SetRadius(0.0)  # automatic
    for setter, bad in (("SetPhotons", -1), ("SetRadius", -2.0),
                        ("SetMaxOrder", -1), ("SetPasses", 0), ("SetDirectLight", "both"),
                        ("SetStepSize", -1.0), ("SetSeed", -3)):
        with pytest.raises(ValueError):
            getattr(f, setter)(bad)
    f.HistorygramsOff()
    assert f.GetHistorygrams() is False
