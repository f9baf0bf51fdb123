"""ManyLightsFilter: the illumination volume on port 0, the virtual lights on port 1."""

import numpy as np
import pytest
from vtkmodules.util.numpy_support import vtk_to_numpy

from vtkillum.core.many_lights.cache import ManyLightsState
from vtkillum.core.many_lights.gather import gather_params, scattered_fluence
from vtkillum.core.many_lights.render import parse_options
from vtkillum.core.render import render
from vtkillum.core.scene import Scene
from vtkillum.core.transfer_function import TransferFunction
from vtkillum.filters import ManyLightsFilter
from vtkillum.io.convert import point_array, volume_from_image_data
from vtkillum.io.illumination_arrays import illumination_from_image

ROTATION = np.array([[0, 1, 0], [-1, 0, 0], [0, 0, 1]], float)
TF = TransferFunction([0.0, 0.2, 1.0], [0.0, 0.05, 0.6])


def make_filter(count=40):
    f = ManyLightsFilter()
    f.SetDevice("cpu")
    f.SetTransferFunction(TF)
    f.SetScalarOpacityUnitDistance(0.5)
    f.SetCount(count)
    f.SetAVSMResolution(8)
    f.SetSeed(3)
    return f


@pytest.fixture
def blob(make_image):
    img = make_image(dims=(14, 12, 10), spacing=(0.5, 0.5, 0.5), origin=(2.0, 1.0, -1.0))
    img.SetDirectionMatrix(*ROTATION.reshape(-1))
    return img


def test_outputs_and_world_placement(blob):
    f = make_filter()
    out = f.execute(blob)
    pd = out.GetPointData()
    names = [pd.GetArrayName(i) for i in range(pd.GetNumberOfArrays())]
    assert names[-3:] == ["fluence", "transmittance", "scattered_fluence"]
    scattered = point_array(out, "scattered_fluence")
    assert scattered.shape == (14, 12, 10, 3) and scattered.max() > 0 and scattered.min() >= 0
    assert point_array(out, "transmittance").shape == (14, 12, 10)  # one light
    lights = f.GetVirtualLightsOutput()
    n = lights.GetNumberOfPoints()
    assert n >= 40 and lights.GetNumberOfVerts() == n
    pd = lights.GetPointData()
    for name, comps in (("position", 3), ("radiance", 3), ("radius", 1),
                        ("incident_direction", 3), ("path", 1), ("vertex", 1),
                        ("creation", 1)):
        assert pd.GetArray(name).GetNumberOfComponents() == comps, name
        assert pd.GetArray(name).GetNumberOfTuples() == n
    world = vtk_to_numpy(lights.GetPoints().GetData())
    np.testing.assert_allclose(vtk_to_numpy(pd.GetArray("position")), world)
    bounds = np.array(blob.GetBounds()).reshape(3, 2)
    assert np.all(world >= bounds[:, 0] - 1e-4) and np.all(world <= bounds[:, 1] + 1e-4)
    # the same VLs as the core's, mapped through the direction matrix
    local = f.state.vls.position
    np.testing.assert_allclose(world, local @ ROTATION.T + np.array([2.0, 1.0, -1.0]),
                               rtol=1e-5, atol=1e-5)
    radius = vtk_to_numpy(pd.GetArray("radius"))
    assert np.all(radius > 0) and np.all(radius <= 2.0 * 0.5 + 1e-6)
    assert np.all(vtk_to_numpy(pd.GetArray("radiance")) >= 0)
    np.testing.assert_allclose(np.linalg.norm(vtk_to_numpy(pd.GetArray("incident_direction")),
                                              axis=1), 1.0, rtol=1e-5)


def test_scattered_fluence_is_the_cores(blob):
    f = make_filter()
    out = f.execute(blob)
    volume = volume_from_image_data(blob)
    scene = Scene(transfer_function=TF, opacity_unit_distance=0.5, lights=f.GetLights())
    opts = parse_options({"count": 40, "avsm_resolution": 8, "seed": 3}, volume, scene)
    state = ManyLightsState(volume, scene, opts, "cpu")
    gp = gather_params(opts["step_size"], False, 3, opts["early_termination"], 1, "avsm",
                       opts["vl_step"], 1.0)
    expected = scattered_fluence(state.medium, state.virtual_lights(), state.maps(), gp,
                                 (14, 12, 10), volume.extent, "cpu")
    np.testing.assert_allclose(point_array(out, "scattered_fluence"), expected, rtol=1e-5,
                               atol=1e-9)


def test_properties_modify_once_and_time_cache_keeps_the_lights(blob):
    f = make_filter()
    f.execute(blob)
    n = f.GetVirtualLightsOutput().GetNumberOfPoints()
    mtime = f.GetMTime()
    f.SetCount(40)
    f.SetTransmittance("avsm")
    assert f.GetMTime() == mtime
    f.Update()  # cached: the VLs of port 1 are still there
    assert f.GetVirtualLightsOutput().GetNumberOfPoints() == n
    f.SetCount(80)
    assert f.GetMTime() > mtime
    f.SetVirtualLights("point")
    f.Update()
    lights = f.GetVirtualLightsOutput()
    assert lights.GetNumberOfPoints() >= 80
    assert np.all(vtk_to_numpy(lights.GetPointData().GetArray("radius")) == 0)


@pytest.mark.parametrize("setter, value", [
    ("SetCount", 0), ("SetVSLRadius", 0.0), ("SetVSLRadius", -1.0), ("SetAVSMNodes", 1),
    ("SetAVSMResolution", 1), ("SetTransmittance", "exact"), ("SetDensityScale", 0.0),
    ("SetVirtualLights", "area"),
])
def test_bad_properties(setter, value):
    with pytest.raises(ValueError):
        getattr(ManyLightsFilter(), setter)(value)


def test_illumination_volume_renders_like_the_gather(make_image):
    """The isotropic scattered fluence on the grid (g = 0) against the per-sample gather."""
    img = make_image(dims=(16, 16, 16), spacing=(0.25, 0.25, 0.25), origin=(0, 0, 0))
    f = make_filter(count=64)
    f.SetVSLRadius(1.5)
    out = f.execute(img)
    volume = volume_from_image_data(img)
    scene = Scene(transfer_function=TF, opacity_unit_distance=0.5, lights=f.GetLights())
    illumination = illumination_from_image(out, volume)
    assert illumination.scattered is not None and illumination.n_lights == 1
    grid = render(volume, scene, "illumination", 24, 24, "cpu", illumination=illumination,
                  jitter=False)
    gathered = render(volume, scene, "many-lights", 24, 24, "cpu", count=64, seed=3,
                      avsm_resolution=8, vsl_radius=1.5, jitter=False, view_samples=16)
    single = render(volume, scene, "single", 24, 24, "cpu", jitter=False).radiance
    ms_grid = grid.radiance - single
    ms_gather = gathered.info["multiple"]
    assert ms_gather.sum() > 0.05 * single.sum()
    assert abs(ms_grid.sum() / ms_gather.sum() - 1.0) < 0.2
