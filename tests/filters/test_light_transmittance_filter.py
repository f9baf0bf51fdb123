"""LightTransmittanceFilter: arrays, world geometry, resolution and time steps."""

import numpy as np
import pytest
from helpers import constant_opacity_filter
from vtkmodules.vtkCommonDataModel import vtkDataObject

from vtkillum.core.transfer_function import TransferFunction
from vtkillum.filters import LightTransmittanceFilter
from vtkillum.io.convert import point_array


def homogeneous(make_image, dims=(10, 8, 6), direction=None):
    img = make_image(dims=dims, spacing=(0.5, 0.5, 0.5), origin=(2.0, 1.0, -1.0),
                     values=np.ones(dims))
    if direction is not None:
        img.SetDirectionMatrix(*np.asarray(direction).reshape(-1))
    return img


def make_filter(alpha=0.5):
    return constant_opacity_filter(LightTransmittanceFilter, alpha)


def test_arrays_and_beer_lambert_in_world_space(make_image):
    # The grid's x axis points along world -y: a light travelling along world -y crosses the
    # box along i, entering at i = 0.
    rot = np.array([[0, 1, 0], [-1, 0, 0], [0, 0, 1]])
    img = homogeneous(make_image, direction=rot)
    f = make_filter()
    f.AddDirectionalLight((0, -1, 0), (1.0, 2.0, 3.0))
    f.AddPointLight((0, 0, 0), (1.0, 1.0, 1.0))
    out = f.execute(img)
    pd = out.GetPointData()
    names = [pd.GetArrayName(i) for i in range(pd.GetNumberOfArrays())]
    assert names == ["density", "fluence", "transmittance", "scattered_fluence"]
    assert out.GetPointData().GetScalars().GetName() == "fluence"
    assert out.GetFieldData().GetArray("vtkillum_lights").GetNumberOfTuples() == 2
    T = point_array(out, "transmittance")
    assert T.shape == (10, 8, 6, 2)
    T0 = T[..., 0]
    x = np.arange(10) * 0.5  # distance travelled inside the box
    np.testing.assert_allclose(T0[:, 3, 2], np.exp(-np.log(2.0) * x), rtol=2e-4)
    assert point_array(out, "fluence").shape == (10, 8, 6, 3)
    assert np.all(T[..., 1] <= 1.0)
    assert not np.any(point_array(out, "scattered_fluence"))


def test_half_resolution_light_volume(make_image):
    f = make_filter()
    f.AddDirectionalLight((1, 0, 0))
    f.SetOutputScale(0.5)
    img = homogeneous(make_image)
    out = f.execute(img)
    assert out.GetDimensions() == (5, 4, 3)
    np.testing.assert_allclose(out.GetBounds(), img.GetBounds())
    x = np.linspace(0.0, 4.5, 5)
    np.testing.assert_allclose(point_array(out, "transmittance")[:, 1, 1],
                               np.exp(-np.log(2.0) * x), rtol=2e-4)
    f.SetStepSize(0.05)  # a property of its own: re-executes
    before = f.GetMTime()
    f.SetStepSize(0.05)
    assert f.GetMTime() == before
    out = f.execute()
    np.testing.assert_allclose(point_array(out, "fluence")[:, 1, 1, 0], np.exp(-np.log(2.0) * x),
                               rtol=2e-4)
    with pytest.raises(ValueError, match="StepSize"):
        f.SetStepSize(-1.0)


def test_time_series_is_cached(time_source):
    f = LightTransmittanceFilter()
    f.SetDevice("cpu")
    f.SetInputConnection(time_source.GetOutputPort())
    f.SetTransferFunction(TransferFunction([0.0, 6.0], [0.0, 0.6]))
    results = {t: point_array(f.execute(time=t), "fluence").copy() for t in (0.0, 1.0, 2.0)}
    assert not np.allclose(results[0.0], results[2.0])  # denser later: different light volumes
    for t in (1.0, 0.0, 2.0):
        out = f.execute(time=t)
        assert out.GetInformation().Get(vtkDataObject.DATA_TIME_STEP()) == t
        np.testing.assert_array_equal(point_array(out, "fluence"), results[t])
    assert time_source.calls == [0.0, 1.0, 2.0]
    assert f.GetCacheStatistics().hits == 3


def test_needs_a_light(make_image):
    f = make_filter()
    with pytest.raises(ValueError, match="no lights"):
        f.execute(homogeneous(make_image))


def test_lights_field_keeps_the_source_radius(make_image):
    from vtkillum.io.illumination_arrays import lights_from_field

    f = make_filter()
    f.AddDirectionalLight((0, -1, 0), (1.0, 2.0, 3.0))
    f.AddPointLight((0, 0, 0), (1.0, 1.0, 1.0))
    f._lights[1].radius = 0.75  # the filter API has no radius setter; the core light does
    f.Modified()
    lights = lights_from_field(f.execute(homogeneous(make_image)))
    assert lights[0].kind == 0 and np.allclose(lights[0].irradiance, (1, 2, 3))
    assert lights[1].kind == 1 and lights[1].radius == 0.75


def test_segment_planes(make_image):
    """Chained segments by default (16 planes), exact rays with 0: a different (blurred)
    grid; both run distributed under MPI (nothing to refuse)."""
    dims = (24, 20, 18)
    rng = np.random.default_rng(5)
    img = make_image(dims=dims, spacing=(0.5, 0.5, 0.5), origin=(0.0, 0.0, 0.0),
                     values=(rng.random(dims) > 0.7).astype(float))
    f = make_filter(0.6)
    f.AddDirectionalLight((0.5, -0.3, -1.0), (1.0, 1.0, 1.0))
    assert f.GetSegmentPlanes() == 16 and f.distributed_unsupported() is None
    f.SetSegmentPlanes(4)
    chained = point_array(f.execute(img), "transmittance")
    f.SetSegmentPlanes(0)
    assert f.distributed_unsupported() is None
    exact = point_array(f.execute(img), "transmittance")
    diff = np.abs(chained - exact)
    assert 0 < diff.mean() < 0.05
    with pytest.raises(ValueError, match="SegmentPlanes must be >= 0"):
        f.SetSegmentPlanes(-1)
    assert f.GetSegmentPlanes() == 0
