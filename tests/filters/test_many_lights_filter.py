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
    # the same VLs as the core's, mapped through the direction matrix (the state works in
    # canonical units, vtkillum.core.units: lengths over the world length of one unit)
    local = f.state.vls.position * (blob.GetSpacing()[0] / f.state.volume.spacing[0])
    np.testing.assert_allclose(world, local @ ROTATION.T + np.array([2.0, 1.0, -1.0]),
                               rtol=1e-5, atol=1e-5)
    radius = vtk_to_numpy(pd.GetArray("radius"))
    # automatic clamping radius: one per set, at most a quarter of the box's smallest side
    assert np.all(radius > 0) and np.all(radius == radius[0])
    assert radius[0] <= 0.25 * 9 * 0.5 + 1e-6
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
    ("SetCount", 0), ("SetVSLRadius", -1.0), ("SetAVSMNodes", 1),
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


# --- edits: what a transfer-function edit re-runs ------------------------------------------------
# Colours whose red channel is 1 at every node: the largest channel (which the walk's Russian
# roulette reads) stays 1 everywhere, so a new walk with the same seed draws the same paths.
RED_ONE = [[1.0, 0.5, 0.2], [1.0, 0.9, 0.4], [1.0, 0.2, 0.6]]
DARK = [[0.9, 0.5, 0.2], [0.6, 0.6, 0.6], [0.3, 0.5, 0.7]]
WALK = {"walk_kernel", "build_kernel__locals__build", "segment_depth_kernel", "freeze_kernel"}


@pytest.fixture
def launches(monkeypatch):
    """Counts of warp kernel launches by kernel name (cleared by the test as it goes)."""
    import collections

    import warp as wp

    counts = collections.Counter()
    launch = wp.launch

    def counting(kernel, *args, **kwargs):
        counts[getattr(kernel, "key", str(kernel))] += 1
        return launch(kernel, *args, **kwargs)

    monkeypatch.setattr(wp, "launch", counting)
    return counts


def light_grid_launches(launches) -> int:
    """Launches of the direct light's grid: exact rays or chained segments (directional
    lights' default, :mod:`vtkillum.core.light_transmittance`)."""
    return launches["transmittance_kernel"] + launches["chained_kernel"]


def arrays(f, out):
    names = ("fluence", "transmittance", "scattered_fluence")
    radiance = vtk_to_numpy(f.GetVirtualLightsOutput().GetPointData().GetArray("radiance"))
    return {**{n: point_array(out, n) for n in names}, "radiance": radiance.copy()}


def assert_same(a, b):
    for name in a:
        np.testing.assert_allclose(a[name], b[name], rtol=2e-5, atol=1e-7, err_msg=name)


def test_colour_edit_reweights_the_walk_and_equals_a_fresh_one(blob, launches):
    f = make_filter()
    f.execute(blob)
    assert launches["walk_kernel"] > 0 and light_grid_launches(launches) > 0
    state = f.state
    launches.clear()
    edited = TransferFunction(TF.scalars, TF.opacity, RED_ONE)
    f.SetTransferFunction(edited)
    after = arrays(f, f.execute(blob))
    # eq. 6 once and one gather; no walk, no shadow map, no transmittance
    assert launches["contribution_kernel"] == 1 and launches["fluence_kernel"] == 1
    assert not WALK & set(launches) and light_grid_launches(launches) == 0
    assert f.state is state
    fresh = make_filter()
    fresh.SetTransferFunction(edited)
    assert_same(after, arrays(fresh, fresh.execute(blob)))
    assert not np.allclose(after["scattered_fluence"][..., 0], after["scattered_fluence"][..., 2])


def test_colour_albedo_and_light_colour_edits_are_the_eq6_estimator(blob, launches):
    """A darker colour and albedo change the Russian roulette: the reweighted walk is the
    core's contribution update (exactly), and as bright as new walks on average."""
    f = make_filter()
    f.execute(blob)
    launches.clear()
    f.SetTransferFunction(TransferFunction(TF.scalars, TF.opacity, DARK))
    f.SetAlbedo(0.7)
    f.SetLight(0, "directional", f.GetLight(0).direction, (2.0, 1.0, 0.5))
    out = f.execute(blob)
    assert not WALK & set(launches) and light_grid_launches(launches) == 0
    volume = volume_from_image_data(blob)
    scene = Scene(transfer_function=TF, opacity_unit_distance=0.5, lights=[f.GetLight(0)])
    opts = parse_options({"count": 40, "avsm_resolution": 8, "seed": 3}, volume, scene)
    state = ManyLightsState(volume, Scene(transfer_function=TF, opacity_unit_distance=0.5), opts,
                            "cpu")
    edited = Scene(transfer_function=TransferFunction(TF.scalars, TF.opacity, DARK), albedo=0.7,
                   opacity_unit_distance=0.5, lights=f.GetLights())
    assert state.update(edited)["edits"] == ["color", "albedo", "light-color"]
    gp = gather_params(opts["step_size"], False, 3, opts["early_termination"], 1, "avsm",
                       opts["vl_step"], 1.0)
    expected = scattered_fluence(state.medium, state.virtual_lights(), state.maps(), gp,
                                 (14, 12, 10), volume.extent, "cpu")
    np.testing.assert_allclose(point_array(out, "scattered_fluence"), expected, rtol=1e-5,
                               atol=1e-9)
    # unbiased: the energy of eight edited sets against eight new walks
    edited_sum = fresh_sum = 0.0
    for seed in range(8):
        f = make_filter(count=128)
        f.SetSeed(seed)
        f.execute(blob)
        f.SetTransferFunction(TransferFunction(TF.scalars, TF.opacity, DARK))
        f.SetAlbedo(0.7)
        edited_sum = edited_sum + point_array(f.execute(blob), "scattered_fluence").sum((0, 1, 2))
        fresh = make_filter(count=128)
        fresh.SetSeed(seed)
        fresh.SetTransferFunction(TransferFunction(TF.scalars, TF.opacity, DARK))
        fresh.SetAlbedo(0.7)
        fresh_sum = fresh_sum + point_array(fresh.execute(blob), "scattered_fluence").sum((0, 1, 2))
    np.testing.assert_allclose(edited_sum / fresh_sum, 1.0, atol=0.1)


def test_the_same_transfer_function_again_launches_nothing(blob, launches):
    f = make_filter()
    before = arrays(f, f.execute(blob))
    launches.clear()
    f.SetTransferFunction(TransferFunction(TF.scalars, TF.opacity))  # new VTK functions
    assert_same(before, arrays(f, f.execute(blob)))
    assert sum(launches.values()) == 0, dict(launches)


@pytest.mark.parametrize("edit", ["opacity", "anisotropy", "clear"])
def test_opacity_and_hg_anisotropy_edits_walk_anew(blob, launches, edit):
    f = make_filter()
    f.execute(blob)
    launches.clear()
    fresh = make_filter()
    if edit == "opacity":
        for g in (f, fresh):
            g.SetTransferFunction(TransferFunction(TF.scalars, [0.0, 0.1, 0.3]))
    elif edit == "anisotropy":
        for g in (f, fresh):
            g.SetAnisotropy(0.5)  # HG sampling draws directions with g
    else:
        f.ClearCache()
        f.Modified()  # (ClearCache alone does not re-execute)
    after = arrays(f, f.execute(blob))
    assert launches["walk_kernel"] > 0 and light_grid_launches(launches) > 0
    assert_same(after, arrays(fresh, fresh.execute(blob)))


def test_anisotropy_edit_with_isotropic_sampling_keeps_the_walk(blob, launches):
    f = make_filter()
    f.SetPhaseSampling("isotropic")
    f.execute(blob)
    launches.clear()
    f.SetAnisotropy(0.5)
    after = arrays(f, f.execute(blob))
    assert not WALK & set(launches) and launches["contribution_kernel"] == 1
    fresh = make_filter()
    fresh.SetPhaseSampling("isotropic")
    fresh.SetAnisotropy(0.5)
    assert_same(after, arrays(fresh, fresh.execute(blob)))


def test_new_data_walks_anew(blob, make_image, launches):
    f = make_filter()
    f.execute(blob)
    launches.clear()
    values = 0.9 * point_array(blob, "density")
    other = make_image(dims=(14, 12, 10), spacing=(0.5, 0.5, 0.5), origin=(2.0, 1.0, -1.0),
                       values=values)
    other.SetDirectionMatrix(*ROTATION.reshape(-1))
    f.execute(other)
    assert launches["walk_kernel"] > 0


def test_another_output_grid_keeps_the_walk(blob, launches):
    f = make_filter()
    f.execute(blob)
    launches.clear()
    f.SetOutputScale(0.5)
    after = arrays(f, f.execute(blob))
    assert not WALK & set(launches) and light_grid_launches(launches) > 0
    fresh = make_filter()
    fresh.SetOutputScale(0.5)
    assert_same(after, arrays(fresh, fresh.execute(blob)))
