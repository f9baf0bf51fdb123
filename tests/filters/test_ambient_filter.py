"""AmbientExtinctionFilter: arrays, resolution, Table 1 invalidation, errors."""

import numpy as np
import pytest

from vtkillum.core.ambient.cache import AmbientScatteringCache
from vtkillum.core.ambient.sat import ambient_extinction, cube_mean_reference
from vtkillum.core.transfer_function import TransferFunction
from vtkillum.filters.ambient_extinction import AmbientExtinctionFilter
from vtkillum.io.convert import point_array


def make_filter(radius=2.0):
    f = AmbientExtinctionFilter()
    f.SetDevice("cpu")
    f.SetTransferFunction(TransferFunction([0.0, 1.0], [0.0, 0.6]))
    f.SetScalarOpacityUnitDistance(0.5)
    f.SetRadius(radius)
    f.RemoveAllLights()
    f.AddDirectionalLight((1, -1, 0), (1.0, 0.5, 0.25))
    return f


def test_arrays_match_the_core(make_image):
    img = make_image(dims=(10, 8, 6), spacing=(0.5, 0.5, 0.5))
    f = make_filter()
    f.AddPointLight((2.0, 2.0, 2.0), (3.0, 3.0, 3.0))
    out = f.execute(img)
    pd = out.GetPointData()
    names = [pd.GetArrayName(i) for i in range(pd.GetNumberOfArrays())]
    assert names[-4:] == ["ambient_extinction", "ambient_radiance", "ambient_radiance_0",
                          "ambient_radiance_1"]
    assert pd.GetScalars().GetName() == "ambient_extinction"
    values = point_array(out, names[0])
    sigma = TransferFunction([0.0, 1.0], [0.0, 0.6]).sigma_t(values, 0.5)
    # radius 2 voxels of spacing 0.5 = 1 world unit
    ref = cube_mean_reference(sigma, (0.5, 0.5, 0.5), 1.0)
    np.testing.assert_allclose(point_array(out, "ambient_extinction"), ref, rtol=2e-3, atol=1e-5)
    r0, r1 = point_array(out, "ambient_radiance_0"), point_array(out, "ambient_radiance_1")
    assert r0.shape == (10, 8, 6, 3)
    np.testing.assert_allclose(point_array(out, "ambient_radiance"), r0 + r1, rtol=1e-6)
    # colour of the light, attenuated: never more than the light's irradiance
    assert np.all(r0 <= np.array([1.0, 0.5, 0.25]) + 1e-6)
    assert r0.min() < 0.9 * r0.max()


def test_half_resolution_radiance_cache(make_image):
    img = make_image(dims=(12, 10, 8), spacing=(0.5, 0.5, 0.5))
    f = make_filter()
    f.SetOutputScale(0.5)
    out = f.execute(img)
    assert out.GetDimensions() == (6, 5, 4)
    np.testing.assert_allclose(out.GetBounds(), img.GetBounds())
    full = ambient_extinction(
        TransferFunction([0.0, 1.0], [0.0, 0.6]).sigma_t(point_array(img, "density"), 0.5),
        (0.5, 0.5, 0.5), 1.0, "cpu").numpy()
    got = point_array(out, "ambient_extinction")
    # corners of the output grid coincide with input points
    assert got[0, 0, 0] == pytest.approx(full[0, 0, 0], rel=1e-5)
    assert got[-1, -1, -1] == pytest.approx(full[-1, -1, -1], rel=1e-5)
    assert point_array(out, "ambient_radiance_0").shape == (6, 5, 4, 3)


def test_table1_invalidation_through_the_filter(make_image):
    img = make_image(dims=(8, 8, 8))
    f = make_filter()
    f.execute(img)
    cache = f.GetAmbientCache()
    assert isinstance(cache, AmbientScatteringCache)
    assert cache.stats == {"sat": 1, "extinction": 1, "radiance": 1}
    f.SetAnisotropy(0.5)
    f.execute()
    assert cache.stats == {"sat": 1, "extinction": 1, "radiance": 2}
    f.SetLight(0, "directional", (0, 0, 1), (1, 1, 1))
    f.execute()
    assert cache.stats == {"sat": 1, "extinction": 1, "radiance": 3}
    f.SetRadius(3.0)
    f.execute()
    assert cache.stats == {"sat": 1, "extinction": 2, "radiance": 4}
    f.GetScalarOpacity().AddPoint(0.5, 0.9)  # editing the VTK function re-executes
    f.execute()
    assert cache.stats == {"sat": 2, "extinction": 3, "radiance": 5}
    mtime = f.GetMTime()
    f.SetRadius(3.0)  # unchanged: not modified
    assert f.GetMTime() == mtime


def test_extinction_only_and_errors(make_image):
    img = make_image(dims=(6, 6, 6))
    f = make_filter()
    f.RemoveAllLights()
    with pytest.raises(ValueError, match="ComputeRadianceOff"):
        f.execute(img)
    f.ComputeRadianceOff()
    out = f.execute(img)
    names = [out.GetPointData().GetArrayName(i) for i in range(out.GetPointData().GetNumberOfArrays())]
    assert "ambient_extinction" in names and "ambient_radiance" not in names
    with pytest.raises(ValueError, match="Radius"):
        f.SetRadius(0.0)
    with pytest.raises(ValueError, match="RadiusUnits"):
        f.SetRadiusUnits("mm")
    f.SetRadiusUnits("world")
    assert f.GetRadiusUnits() == "world"
