"""IlluminationFilterBase: output grid, MTime, time steps and cache, input checks, lights."""

import gc

import numpy as np
import pytest
from vtkmodules.vtkCommonCore import vtkWeakReference
from vtkmodules.vtkCommonDataModel import vtkDataObject, vtkPiecewiseFunction, vtkPolyData
from vtkmodules.vtkCommonExecutionModel import vtkStreamingDemandDrivenPipeline as SDDP
from vtkmodules.vtkRenderingCore import vtkColorTransferFunction

from vtkillum.core.lights import DirectionalLight, PointLight
from vtkillum.filters.base import IlluminationFilterBase
from vtkillum.io.convert import add_point_array, point_array


class Recorder(IlluminationFilterBase):
    """Minimal subclass: records what compute() got and returns simple arrays."""

    def __init__(self):
        super().__init__()
        self.calls = []

    def compute(self, volume, params):
        self.calls.append((volume, params))
        params.progress(0.5)
        shape = params.output_shape
        alpha = params.transfer_function.alpha(volume.scalars.mean())
        return {
            "mean": np.full(shape, volume.scalars.mean(), np.float32),
            "rgb": np.broadcast_to(params.transfer_function.color(1.0), shape + (3,)),
            "alpha": np.full(shape, alpha, np.float32),
        }


def opacity_point():
    otf = vtkPiecewiseFunction()
    otf.AddPoint(0.0, 0.5)
    return otf


def whole_extent(alg):
    alg.UpdateInformation()
    return tuple(alg.GetOutputInformation(0).Get(SDDP.WHOLE_EXTENT()))


# --- output grid --------------------------------------------------------------------------------
def test_full_resolution_keeps_the_input_grid(make_image):
    img = make_image()
    img.SetExtent(3, 14, -2, 7, 0, 7)  # extent need not start at 0
    add_point_array(img, "density", np.zeros((12, 10, 8), np.float32), set_active=True)
    c, s = np.cos(0.4), np.sin(0.4)
    img.SetDirectionMatrix(c, 0, s, 0, 1, 0, -s, 0, c)
    f = Recorder()
    f.SetInputData(img)
    assert whole_extent(f) == (3, 14, -2, 7, 0, 7)
    out = f.execute()
    assert out.GetExtent() == (3, 14, -2, 7, 0, 7)
    np.testing.assert_allclose(out.GetSpacing(), img.GetSpacing())
    np.testing.assert_allclose(out.GetOrigin(), img.GetOrigin())
    np.testing.assert_allclose(out.GetBounds(), img.GetBounds())
    assert out.GetPointData().GetScalars().GetName() == "mean"
    # Input arrays are passed through at full resolution (shared, not copied).
    assert out.GetPointData().GetArray("density") is img.GetPointData().GetArray("density")
    f.SetPassInputArrays(False)
    assert f.execute().GetPointData().GetArray("density") is None


@pytest.mark.parametrize("scale, dims", [(0.5, (6, 5, 4)), (0.25, (3, 2, 2))])
def test_lower_resolution_covers_the_same_box(make_image, scale, dims):
    img = make_image()
    img.SetDirectionMatrix(0, -1, 0, 1, 0, 0, 0, 0, 1)
    f = Recorder()
    f.SetInputData(img)
    f.SetOutputScale(scale)
    assert whole_extent(f) == (0, dims[0] - 1, 0, dims[1] - 1, 0, dims[2] - 1)
    info = f.GetOutputInformation(0)
    out = f.execute()
    assert out.GetDimensions() == dims
    np.testing.assert_allclose(out.GetBounds(), img.GetBounds(), atol=1e-12)
    np.testing.assert_allclose(info.Get(vtkDataObject.SPACING()), out.GetSpacing())
    np.testing.assert_allclose(info.Get(vtkDataObject.ORIGIN()), out.GetOrigin())
    np.testing.assert_allclose(info.Get(vtkDataObject.DIRECTION()), (0, -1, 0, 1, 0, 0, 0, 0, 1))
    assert f.calls[-1][1].output_shape == dims
    assert out.GetPointData().GetArray("density") is None  # other grid: nothing passed


def test_output_dimensions_take_precedence(make_image):
    f = Recorder()
    f.SetInputData(make_image())
    f.SetOutputScale(0.5)
    f.SetOutputDimensions(5, 7, 3)
    assert f.execute().GetDimensions() == (5, 7, 3)
    f.SetOutputDimensions(0, 0, 0)
    assert f.execute().GetDimensions() == (6, 5, 4)
    with pytest.raises(ValueError, match=">= 2"):
        f.SetOutputDimensions(1, 7, 3)
    with pytest.raises(ValueError, match=r"\(0, 1\]"):
        f.SetOutputScale(0.0)


# --- MTime ---------------------------------------------------------------------------------------
def test_transfer_function_edits_re_execute(make_image):
    f = Recorder()
    f.SetInputData(make_image())
    ctf, otf = vtkColorTransferFunction(), vtkPiecewiseFunction()
    ctf.AddRGBPoint(0.0, 1.0, 0.0, 0.0)
    otf.AddPoint(0.0, 0.2)
    f.SetColorTransferFunction(ctf)
    f.SetScalarOpacity(otf)
    out = f.execute()
    f.Update()
    assert len(f.calls) == 1  # nothing changed: no second execution
    np.testing.assert_allclose(point_array(out, "alpha"), 0.2, rtol=1e-6)

    otf.AddPoint(0.0, 0.7)  # edit in place
    out = f.execute()
    assert len(f.calls) == 2
    np.testing.assert_allclose(point_array(out, "alpha"), 0.7, rtol=1e-6)
    ctf.AddRGBPoint(0.0, 0.0, 1.0, 0.0)
    out = f.execute()
    assert len(f.calls) == 3
    np.testing.assert_allclose(point_array(out, "rgb")[0, 0, 0], (0, 1, 0))

    replaced = vtkPiecewiseFunction()
    replaced.AddPoint(0.0, 0.1)
    f.SetScalarOpacity(replaced)
    f.execute()
    assert len(f.calls) == 4
    otf.AddPoint(1.0, 1.0)  # the old function is no longer observed
    f.Update()
    assert len(f.calls) == 4


def test_setters_modify_only_on_change():
    f = Recorder()
    f.AddPointLight((1, 2, 3), (4, 5, 6))
    otf = vtkPiecewiseFunction()
    f.SetScalarOpacity(otf)
    same = [
        lambda: f.SetAlbedo(0.9), lambda: f.SetAnisotropy(0.0),
        lambda: f.SetScalarOpacityUnitDistance(0.0), lambda: f.SetDevice("auto"),
        lambda: f.SetOutputScale(1.0), lambda: f.SetOutputDimensions(0, 0, 0),
        lambda: f.SetInputComponent(None), lambda: f.SetNaNPolicy("raise"),
        lambda: f.SetPassInputArrays(True), lambda: f.SetScalarOpacity(otf),
        # another function with the same content: nothing to recompute
        lambda: f.SetScalarOpacity(vtkPiecewiseFunction()),
        lambda: f.SetLight(1, "point", (1, 2, 3), (4, 5, 6)),
        lambda: f.SetLights(f.GetLights()), lambda: f.SetCacheSizeMB(100),
    ]
    changed = [
        lambda: f.SetAlbedo(0.5), lambda: f.SetAnisotropy(0.3),
        lambda: f.SetScalarOpacityUnitDistance(2.0), lambda: f.SetDevice("cpu"),
        lambda: f.SetOutputScale(0.5), lambda: f.SetOutputDimensions(4, 4, 4),
        lambda: f.SetInputComponent(-1), lambda: f.SetNaNPolicy("fill"),
        lambda: f.SetPassInputArrays(False), lambda: f.SetScalarOpacity(opacity_point()),
        lambda: f.SetLight(1, "point", (1, 2, 3), (4, 5, 7)),
        lambda: f.SetLight(0, "point", (1, 2, 3), (4, 5, 7)),
        lambda: f.AddDirectionalLight((0, 0, 1)), lambda: f.RemoveLight(0),
        lambda: f.RemoveAllLights(),
    ]
    for setter in same:
        before = f.GetMTime()
        setter()
        assert f.GetMTime() == before, setter
    for setter in changed:
        before = f.GetMTime()
        setter()
        assert f.GetMTime() > before, setter


def test_property_validation():
    f = Recorder()
    with pytest.raises(ValueError, match="Albedo"):
        f.SetAlbedo(1.5)
    with pytest.raises(ValueError, match="Anisotropy"):
        f.SetAnisotropy(1.0)
    with pytest.raises(ValueError, match="Device"):
        f.SetDevice("gpu")
    with pytest.raises(ValueError, match="NaNPolicy"):
        f.SetNaNPolicy("ignore")
    with pytest.raises(TypeError, match="vtkPiecewiseFunction"):
        f.SetScalarOpacity(vtkColorTransferFunction())
    with pytest.raises(ValueError, match="'directional' or 'point'"):
        f.SetLight(0, "spot", (0, 0, 1))
    with pytest.raises(IndexError, match="1 light"):
        f.SetLight(3, "point", (0, 0, 1))


# --- parameters handed to compute ----------------------------------------------------------------
def test_parameters_reach_compute(make_image):
    f = Recorder()
    f.SetInputData(make_image(spacing=(0.5, 0.4, 0.3)))
    f.RemoveAllLights()
    f.AddDirectionalLight((0, 0, -2), (1, 2, 3))
    f.AddPointLight((1, 1, 1), (5, 5, 5))
    f.SetAlbedo(0.6)
    f.SetAnisotropy(-0.2)
    f.SetDevice("cpu")
    f.execute()
    volume, params = f.calls[-1]
    # compute runs in canonical units (vtkillum.core.units): lengths / L, L = 0.5 here
    assert params.units.length == 0.5 and volume.spacing == pytest.approx((1.0, 0.8, 0.6))
    assert params.unit_distance * params.units.length == pytest.approx(0.4)  # 0: mean spacing
    assert (params.albedo, params.anisotropy, params.device) == (0.6, -0.2, "cpu")
    assert isinstance(params.lights[0], DirectionalLight)
    assert isinstance(params.lights[1], PointLight)
    np.testing.assert_allclose(params.lights[0].direction, (0, 0, -1))
    # No transfer function set: an opacity ramp 0 .. 0.5 over the data range, white.
    lo, hi = volume.value_range
    assert params.transfer_function.alpha(hi) == pytest.approx(0.5)
    assert params.transfer_function.alpha(lo) == pytest.approx(0.0)
    scene = params.scene()
    assert scene.albedo == 0.6 and len(scene.lights) == 2
    f.SetScalarOpacityUnitDistance(2.5)
    f.execute()
    assert f.calls[-1][1].unit_distance == 2.5 / 0.5


def test_progress_is_reported(make_image):
    f = Recorder()
    f.SetInputData(make_image())
    seen = []
    f.AddObserver("ProgressEvent", lambda obj, event: seen.append(obj.GetProgress()))
    f.execute()
    assert 0.5 in seen and seen[-1] == 1.0


# --- time steps and the cache -------------------------------------------------------------------
def test_time_steps_pass_through(time_source):
    f = Recorder()
    f.SetInputConnection(time_source.GetOutputPort())
    f.UpdateInformation()
    info = f.GetOutputInformation(0)
    assert info.Get(SDDP.TIME_STEPS()) == (0.0, 1.0, 2.0)
    assert info.Get(SDDP.TIME_RANGE()) == (0.0, 2.0)
    for t in (1.0, 2.0):
        out = f.execute(time=t)
        assert out.GetInformation().Get(vtkDataObject.DATA_TIME_STEP()) == t
        assert point_array(out, "mean")[0, 0, 0] == pytest.approx(t + 1.75)  # mean of t + x


def test_cache_hit_does_not_execute_upstream(time_source):
    f = Recorder()
    f.SetInputConnection(time_source.GetOutputPort())
    for t in (0.0, 1.0, 2.0):
        f.execute(time=t)
    assert time_source.calls == [0.0, 1.0, 2.0] and len(f.calls) == 3
    for t in (0.0, 2.0, 1.0, 0.0):
        out = f.execute(time=t)
        assert out.GetInformation().Get(vtkDataObject.DATA_TIME_STEP()) == t
        assert point_array(out, "mean")[0, 0, 0] == pytest.approx(t + 1.75)
    assert time_source.calls == [0.0, 1.0, 2.0]  # the upstream did not run again
    assert len(f.calls) == 3  # nor did compute()
    stats = f.GetCacheStatistics()
    assert (stats.hits, stats.misses, stats.entries) == (4, 3, 3)
    # Downstream of a cache hit, a consumer sees the right data too.
    from vtkmodules.vtkImagingCore import vtkImageShiftScale

    shift = vtkImageShiftScale()
    shift.SetInputConnection(f.GetOutputPort())
    shift.SetShift(10.0)
    shift.UpdateTimeStep(2.0)
    assert point_array(shift.GetOutput(), "mean")[0, 0, 0] == pytest.approx(13.75)
    assert time_source.calls == [0.0, 1.0, 2.0]


def test_cache_is_invalidated_by_upstream_and_parameter_changes(time_source):
    f = Recorder()
    f.SetInputConnection(time_source.GetOutputPort())
    for t in (0.0, 1.0):
        f.execute(time=t)
    f.SetAlbedo(0.3)  # parameters changed: recompute, upstream needs to provide t = 0 again
    f.execute(time=0.0)
    assert time_source.calls == [0.0, 1.0, 0.0] and len(f.calls) == 3
    assert f.GetCacheStatistics().invalidations == 2
    time_source.Modified()  # upstream changed
    f.execute(time=0.0)
    f.execute(time=1.0)
    f.execute(time=0.0)
    assert time_source.calls == [0.0, 1.0, 0.0, 0.0, 1.0]
    assert len(f.calls) == 5


def test_memory_budget_evicts_least_recently_used(time_source):
    f = Recorder()
    f.SetInputConnection(time_source.GetOutputPort())
    f.execute(time=0.0)
    entry = f.GetCacheStatistics().bytes
    f.SetCacheSizeMB(2.5 * entry / 2**20)  # room for two outputs
    for t in (1.0, 2.0):
        f.execute(time=t)
    stats = f.GetCacheStatistics()
    assert stats.entries == 2 and stats.evictions == 1 and stats.bytes <= stats.max_bytes
    f.execute(time=2.0)  # hit
    f.execute(time=1.0)  # hit
    assert time_source.calls == [0.0, 1.0, 2.0]
    f.execute(time=0.0)  # evicted: upstream and compute run again
    assert time_source.calls == [0.0, 1.0, 2.0, 0.0] and len(f.calls) == 4
    f.SetCacheSizeMB(0)  # disabled: every new time executes
    assert f.GetCacheStatistics().entries == 0
    f.execute(time=1.0)
    f.execute(time=0.0)
    assert time_source.calls == [0.0, 1.0, 2.0, 0.0, 1.0, 0.0]


def test_static_input_is_computed_once_for_any_time(make_image):
    f = Recorder()
    f.SetInputData(make_image())
    for t in (0.0, 0.5, 3.0):
        f.execute(time=t)
    assert len(f.calls) == 1


# --- input handling -----------------------------------------------------------------------------
def test_non_image_input_is_told_to_resample():
    f = Recorder()
    with pytest.raises(TypeError, match="vtkResampleToImage"):
        f.execute(vtkPolyData())
    assert "not image data" in f.GetLastError()


def test_input_array_selection_and_components(make_image):
    img = make_image()
    rng = np.random.default_rng(3)
    vec = rng.random((12, 10, 8, 3)).astype(np.float32)
    add_point_array(img, "velocity", vec)
    f = Recorder()
    f.SetInputData(img)
    f.execute()
    np.testing.assert_allclose(f.calls[-1][0].scalars, point_array(img, "density"))
    f.SetInputArrayToProcess(0, 0, 0, vtkDataObject.FIELD_ASSOCIATION_POINTS, "velocity")
    with pytest.raises(ValueError, match="3 components"):
        f.execute()
    f.SetInputComponent(2)
    f.execute()
    np.testing.assert_allclose(f.calls[-1][0].scalars, vec[..., 2])
    f.SetInputComponent(-1)
    f.execute()
    np.testing.assert_allclose(f.calls[-1][0].scalars, np.linalg.norm(vec, axis=-1), rtol=1e-6)


def test_cell_data_input(make_image):
    img = make_image()
    img.GetPointData().RemoveArray("density")
    from vtkmodules.util.numpy_support import numpy_to_vtk

    cells = numpy_to_vtk(np.full(11 * 9 * 7, 2.0, np.float32), deep=True)
    cells.SetName("pressure")
    img.GetCellData().AddArray(cells)
    f = Recorder()
    f.SetInputData(img)
    f.SetInputArrayToProcess(0, 0, 0, vtkDataObject.FIELD_ASSOCIATION_CELLS, "pressure")
    f.execute()
    np.testing.assert_allclose(f.calls[-1][0].scalars, 2.0)


def test_nan_policy(make_image):
    values = np.ones((12, 10, 8), np.float32)
    values[3, 4, 5] = np.nan
    f = Recorder()
    f.SetInputData(make_image(values=values))
    with pytest.raises(ValueError, match="NaN"):
        f.execute()
    f.SetNaNPolicy("fill")
    f.execute()
    assert np.isfinite(f.calls[-1][0].scalars).all()
    assert f.GetLastError() is None


def test_no_lights_is_an_error_when_required(make_image):
    f = Recorder()
    f.SetInputData(make_image())
    f.RemoveAllLights()
    with pytest.raises(ValueError, match="AddDirectionalLight"):
        f.execute()


def test_pyvista_input(make_image):
    pv = pytest.importorskip("pyvista")
    grid = pv.ImageData(dimensions=(9, 8, 7), spacing=(0.2, 0.2, 0.2))
    grid.point_data["d"] = np.linspace(0, 1, grid.n_points, dtype=np.float32)
    f = Recorder()
    f.SetOutputScale(0.5)
    out = pv.wrap(f.execute(grid))
    assert out.dimensions == (4, 4, 4)
    np.testing.assert_allclose(out.bounds, grid.bounds)
    assert out.point_data["mean"][0] == pytest.approx(0.5)


def test_filter_and_transfer_functions_are_released():
    otf = vtkPiecewiseFunction()
    otf.AddPoint(0.0, 0.5)
    f = Recorder()
    f.SetScalarOpacity(otf)
    assert otf.HasObserver("ModifiedEvent")
    ref = vtkWeakReference()
    ref.Set(f)
    del f
    gc.collect()
    assert ref.Get() is None  # the observer does not keep the filter alive
    otf.AddPoint(1.0, 1.0)  # the orphaned observer does nothing but remove itself
    assert not otf.HasObserver("ModifiedEvent")


def test_default_cache_is_a_share_of_free_memory(monkeypatch):
    from vtkillum.filters import time_cache

    monkeypatch.setattr(time_cache, "available_memory_mb", lambda: 64000.0)
    assert time_cache.default_cache_mb() == 16000.0
    monkeypatch.setattr(time_cache, "available_memory_mb", lambda: 1000.0)
    assert time_cache.default_cache_mb() == time_cache.FLOOR_MB  # never below the floor
    monkeypatch.setattr(time_cache, "available_memory_mb", lambda: None)
    assert time_cache.default_cache_mb() == time_cache.FLOOR_MB
    assert Recorder().GetCacheSizeMB() >= time_cache.FLOOR_MB


def test_a_series_that_does_not_fit_is_reported_once(time_source):
    from vtkmodules.vtkCommonCore import vtkOutputWindow, vtkStringOutputWindow

    previous = vtkOutputWindow.GetInstance()
    previous.Register(None)
    said = vtkStringOutputWindow()
    vtkOutputWindow.SetInstance(said)
    try:
        f = Recorder()
        f.SetInputConnection(time_source.GetOutputPort())
        out = f.execute(time=0.0)
        entry_mb = out.GetActualMemorySize() / 1024
        f.SetCacheSizeMB(1.5 * entry_mb)  # room for one of the three steps
        for t in (0.0, 1.0, 2.0, 1.0):
            f.execute(time=t)
        text = said.GetOutput()
        assert text.count("keeps 1 of the 3 time steps") == 1, text
        assert "CacheSizeMB" in text
        f.SetCacheSizeMB(4 * entry_mb)  # all three fit: nothing more is said
        for t in (0.0, 1.0, 2.0):
            f.execute(time=t)
        assert said.GetOutput() == text
    finally:
        vtkOutputWindow.SetInstance(previous)
        previous.UnRegister(None)
