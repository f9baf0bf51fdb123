"""ConvectionDiffusionLightFilter: arrays, geometry, properties, partial recomputation, time."""

import numpy as np
import pytest
from vtkmodules.vtkCommonDataModel import vtkDataObject

from vtkillum.core.transfer_function import TransferFunction
from vtkillum.filters.convection_diffusion_light import ConvectionDiffusionLightFilter
from vtkillum.io.convert import point_array


def make_filter(alpha=0.5):
    f = ConvectionDiffusionLightFilter()
    f.SetDevice("cpu")
    f.SetTransferFunction(TransferFunction([0.0, 2.0], [alpha, alpha]))
    f.SetScalarOpacityUnitDistance(1.0)
    f.RemoveAllLights()
    return f


def test_half_resolution_light_volume_in_world_space(make_image):
    # Grid x points along world -y: light travelling along world -y crosses the box along i.
    img = make_image(dims=(11, 8, 6), spacing=(0.5, 0.5, 0.5), origin=(2.0, 1.0, -1.0),
                     values=np.ones((11, 8, 6)))
    img.SetDirectionMatrix(0, 1, 0, -1, 0, 0, 0, 0, 1)
    f = make_filter()
    f.AddDirectionalLight((0, -1, 0), (1.0, 2.0, 3.0))
    out = f.execute(img)
    assert out.GetDimensions() == (6, 4, 3)  # LightVolumeScale 0.5 by default
    np.testing.assert_allclose(out.GetBounds(), img.GetBounds())
    names = [out.GetPointData().GetArrayName(i) for i in range(out.GetPointData().GetNumberOfArrays())]
    assert names == ["fluence", "direct_fluence", "transmittance_0"]
    x = np.linspace(0.0, 5.0, 6)  # distance travelled inside the box (world units)
    T = point_array(out, "transmittance_0")
    np.testing.assert_allclose(T[:, 2, 1], np.exp(-np.log(2.0) * x), rtol=1e-5)
    np.testing.assert_allclose(point_array(out, "fluence")[:, 2, 1],
                               np.outer(np.exp(-np.log(2.0) * x), [1.0, 2.0, 3.0]), rtol=1e-5)


def test_properties(make_image):
    f = make_filter()
    assert f.GetLightVolumeScale() == 0.5 and f.GetScattering() == (0.0, 0.0, 0.0)
    before = f.GetMTime()
    f.SetScattering(0.0)
    f.SetIterations(0)
    f.SetTolerance(1e-4)
    f.SetSolver("multigrid")
    assert f.GetMTime() == before  # unchanged values do not re-execute
    f.SetScattering(0.1, 0.2, 0.3)
    assert f.GetScattering() == (0.1, 0.2, 0.3) and f.GetMTime() > before
    f.SetLightVolumeScale(1.0)
    assert f.GetOutputScale() == 1.0
    for setter, value, match in [(f.SetScattering, -1.0, "Scattering"),
                                 (f.SetIterations, 1.5, "Iterations"),
                                 (f.SetTolerance, 0.0, "Tolerance"),
                                 (f.SetSolver, "jacobi", "Solver"),
                                 (f.SetSourceRadius, -1.0, "SourceRadius"),
                                 (f.SetLightVolumeScale, 2.0, "LightVolumeScale")]:
        with pytest.raises(ValueError, match=match):
            setter(value)


def test_only_what_changed_is_recomputed(make_image):
    f = make_filter(alpha=0.3)
    f.AddDirectionalLight((1, 0, 0))
    f.AddPointLight((3.0, -0.5, 1.5), (2.0, 2.0, 2.0))
    img = make_image(dims=(16, 12, 10))
    f.execute(img)
    s = f.GetLastUpdateStats()
    assert (s.opacity, s.convected, s.composed) == (True, [0, 1], True)
    f.SetScattering(0.05)
    fluence = point_array(f.execute(), "fluence").copy()
    s = f.GetLastUpdateStats()
    assert (s.opacity, s.convected, s.composed, s.diffused) == (False, [], False, True)
    f.SetLight(1, "point", (3.0, -0.5, 1.5), (1.0, 0.0, 0.0))  # colour only
    f.execute()
    s = f.GetLastUpdateStats()
    assert (s.opacity, s.convected, s.composed) == (False, [], True)
    f.SetLight(0, "directional", (0, 1, 0))  # one light moved
    f.execute()
    assert f.GetLastUpdateStats().convected == [0]
    f.GetScalarOpacity().AddPoint(1.0, 0.9)  # editing the opacity function: everything
    f.execute()
    s = f.GetLastUpdateStats()
    assert (s.opacity, s.convected) == (True, [0, 1])
    # The incremental result equals a fresh filter's.
    g = make_filter(alpha=0.3)
    g.SetScalarOpacity(f.GetScalarOpacity())
    g.SetLights(f.GetLights())
    g.SetScattering(0.05)
    np.testing.assert_allclose(point_array(g.execute(img), "fluence"),
                               point_array(f.execute(), "fluence"), rtol=1e-3, atol=1e-5)
    assert not np.allclose(fluence, point_array(f.execute(), "fluence"))


def test_iteration_budget_and_refine(make_image):
    f = make_filter(alpha=0.3)
    f.AddDirectionalLight((1, -1, 0))
    f.SetLightVolumeScale(1.0)
    f.SetScattering(0.2)
    f.SetTolerance(1e-5)
    f.SetIterations(1)
    f.execute(make_image(dims=(24, 20, 16)))
    assert not f.GetConverged()
    residuals = [f.GetLastUpdateStats().diffusion.residuals[-1]]
    while f.Refine():
        f.execute()
        residuals.append(f.GetLastUpdateStats().diffusion.residuals[-1])
        assert len(residuals) < 30
    assert f.GetConverged() and len(residuals) > 2
    assert np.all(np.diff(residuals) < 0)


def test_time_steps_warm_start_and_cache(time_source):
    f = ConvectionDiffusionLightFilter()
    f.SetDevice("cpu")
    f.SetInputConnection(time_source.GetOutputPort())
    f.SetTransferFunction(TransferFunction([0.0, 6.0], [0.0, 0.6]))
    f.SetLightVolumeScale(1.0)
    f.SetScattering(0.1)
    f.SetSolver("cg")
    results = {}
    for t in (0.0, 1.0, 2.0):
        results[t] = point_array(f.execute(time=t), "fluence").copy()
        assert f.GetLastUpdateStats().warm_start == (t > 0)
    assert not np.allclose(results[0.0], results[2.0])
    calls = len(time_source.calls)
    out = f.execute(time=1.0)  # cached: neither upstream nor the solver runs
    assert out.GetInformation().Get(vtkDataObject.DATA_TIME_STEP()) == 1.0
    np.testing.assert_array_equal(point_array(out, "fluence"), results[1.0])
    assert len(time_source.calls) == calls
