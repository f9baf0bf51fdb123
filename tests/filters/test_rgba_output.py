"""The illuminated RGBA output (vtkillum.filters.rgba_output)."""

import math

import numpy as np
import pytest

from vtkillum import DirectionalLight, TransferFunction, Volume
from vtkillum.filters import LightTransmittanceFilter
from vtkillum.filters.ambient_extinction import AmbientExtinctionFilter
from vtkillum.filters.rgba_output import (
    RGBA_ARRAY,
    declare_nominal_range,
    illuminated_rgba,
    with_rgba_output,
)
from vtkillum.io.convert import image_data_from_volume, point_array


def slab_image(shape=(5, 5, 9), spacing=0.125):
    return image_data_from_volume(Volume(np.ones(shape), (spacing,) * 3), "density")


def test_illuminated_rgba_formula():
    tf = TransferFunction([0.0, 1.0], [0.0, 0.5], [[1.0, 0.5, 0.0], [0.2, 0.4, 1.0]])
    s = np.linspace(0.0, 1.0, 8).reshape(2, 2, 2)
    phi = np.full((2, 2, 2, 3), 2.0, dtype=np.float32)
    out = illuminated_rgba(s, tf, albedo=0.5, fluence=phi, exposure=math.pi, dtype="float32")
    expected_rgb = np.clip(math.pi * 0.5 * tf.color(s) * 2.0 / (4 * math.pi), 0, 1)
    np.testing.assert_allclose(out[..., :3], expected_rgb, rtol=1e-6)
    np.testing.assert_allclose(out[..., 3], tf.alpha(s), rtol=1e-6)
    as_bytes = illuminated_rgba(s, tf, 0.5, phi, math.pi, gamma=2.0)
    assert as_bytes.dtype == np.uint8
    np.testing.assert_array_equal(as_bytes[..., :3], np.round(255 * np.sqrt(expected_rgb)))


@pytest.mark.parametrize("kwargs, match", [
    ({"exposure": 0.0}, "Exposure"), ({"gamma": -1.0}, "Gamma"), ({"dtype": "int16"}, "type"),
])
def test_illuminated_rgba_rejects_bad_settings(kwargs, match):
    tf = TransferFunction([0.0, 1.0], [0.0, 1.0])
    with pytest.raises(ValueError, match=match):
        illuminated_rgba(np.zeros((2, 2, 2)), tf, 0.9, np.zeros((2, 2, 2, 3)), **kwargs)
    with pytest.raises(ValueError, match="does not match"):
        illuminated_rgba(np.zeros((2, 2, 2)), tf, 0.9, np.zeros((3, 2, 2, 3)))


def test_transmittance_rgba_is_beer_lambert_at_the_data_resolution():
    f = with_rgba_output(LightTransmittanceFilter)()
    tau = 2.0  # extinction per world unit
    alpha = 1.0 - math.exp(-tau)
    f.SetTransferFunction(TransferFunction([0.0, 1.0], [alpha, alpha]))
    f.SetScalarOpacityUnitDistance(1.0)
    f.SetLights([DirectionalLight((0, 0, -1))])
    f.SetAlbedo(1.0)
    f.SetDevice("cpu")
    f.SetOutputDimensions(3, 3, 5)  # a coarser light grid; the RGBA is at the data grid
    f.SetRGBAType("float32")
    out = f.execute(slab_image())
    assert out.GetDimensions() == (5, 5, 9)
    assert out.GetPointData().GetScalars().GetName() == RGBA_ARRAY
    rgba = point_array(out, RGBA_ARRAY)
    depth = (8 - np.arange(9)) * 0.125
    # Exposure 4 pi, albedo 1, white: the colour is the transmittance (the light grid's
    # points are at depths 0, .25, ..., so the resampled values are exact at those).
    np.testing.assert_allclose(rgba[2, 2, ::2, 0], np.exp(-tau * depth[::2]), rtol=3e-3)
    np.testing.assert_allclose(rgba[..., 3], alpha, rtol=1e-6)
    # The output carries the nominal component range that ParaView/VTK 9.2 need.
    array = out.GetPointData().GetArray(RGBA_ARRAY)
    assert array.GetRange(3) == (0.0, 1.0) and array.GetFiniteRange(0) == (0.0, 1.0)
    # Re-executed (new array), declared again. (Cache hits over time steps: tests/plugin.)
    f.SetExposure(2.0)
    again = f.execute()
    assert again.GetPointData().GetArray(RGBA_ARRAY).GetRange(3) == (0.0, 1.0)


def test_declared_range_is_dropped_when_the_array_changes():
    from vtkmodules.util.numpy_support import numpy_to_vtk

    array = numpy_to_vtk(np.array([[10, 20, 30, 40]] * 3, dtype=np.uint8), deep=True)
    declare_nominal_range(array)
    assert array.GetRange(3) == (0.0, 255.0)
    array.Modified()
    assert array.GetRange(3) == (40.0, 40.0)
    floats = numpy_to_vtk(np.array([[0.5, 0.5, 0.5, 2.0]], dtype=np.float32), deep=True)
    with pytest.raises(ValueError, match="nominal range"):
        declare_nominal_range(floats)


def test_rgba_switched_off_and_missing_light_arrays():
    f = with_rgba_output(LightTransmittanceFilter)()
    f.SetOutputRGBA(False)
    f.SetDevice("cpu")
    out = f.execute(slab_image())
    assert out.GetPointData().GetArray(RGBA_ARRAY) is None
    ambient = with_rgba_output(AmbientExtinctionFilter)()
    ambient.SetComputeRadiance(False)
    ambient.SetDevice("cpu")
    with pytest.raises(ValueError, match="OutputRGBA off"):
        ambient.execute(slab_image())


def test_with_rgba_output_caches_the_class():
    assert with_rgba_output(LightTransmittanceFilter) is with_rgba_output(LightTransmittanceFilter)
    assert issubclass(with_rgba_output(LightTransmittanceFilter), LightTransmittanceFilter)
