"""ConvectionDiffusionLightFilter: arrays, geometry, properties, partial recomputation, time."""

import numpy as np
import pytest
from helpers import constant_opacity_filter, offscreen_window, read_window_rgb
from vtkmodules.vtkCommonDataModel import vtkDataObject

from vtkillum.core.transfer_function import TransferFunction
from vtkillum.filters.convection_diffusion_light import ConvectionDiffusionLightFilter
from vtkillum.io.convert import point_array


def make_filter(alpha=0.5):
    return constant_opacity_filter(ConvectionDiffusionLightFilter, alpha)


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


# --- both mapper paths ------------------------------------------------------------------------------
def test_light_volume_renders_in_both_mapper_paths(make_image):
    pytest.importorskip("vtkmodules.vtkRenderingVolumeOpenGL2")
    from vtkmodules.vtkRenderingCore import vtkRenderer

    from vtkillum.core.camera import Camera
    from vtkillum.core.illumination import IlluminationVolume
    from vtkillum.core.lights import DirectionalLight
    from vtkillum.core.raycast import render_illuminated
    from vtkillum.core.render import render
    from vtkillum.core.scene import Scene
    from vtkillum.core.tonemap import tonemap
    from vtkillum.io.convert import volume_from_image_data
    from vtkillum.mappers import ComputeVolumeRenderer, IlluminatedVolume

    size, stop = 40, 1.0 - 1.0 / 255.0
    img = make_image(dims=(24, 20, 16), spacing=(0.5, 0.5, 0.5), origin=(0.0, 0.0, 0.0))
    volume = volume_from_image_data(img)
    tf = TransferFunction([0.0, 0.3, 1.0], [0.0, 0.0, 0.5], [[1, 1, 1], [1, 0.8, 0.5], [0.6, 0.8, 1]])
    light = DirectionalLight((1.0, -0.6, -0.3), (25.0, 25.0, 25.0))
    cd = {"scattering": [0.3, 0.4, 0.6]}
    scene = Scene(transfer_function=tf, opacity_unit_distance=1.0, lights=[light],
                  camera=Camera.looking_at_bounds(volume.bounds, direction=(-0.3, -0.2, -1.0)),
                  options={"convection_diffusion": cd})
    f = make_filter()
    f.SetTransferFunction(tf)
    f.AddDirectionalLight(light.direction, light.irradiance)
    f.SetScattering(*cd["scattering"])
    f.SetInputData(img)
    f.Update()
    fluence = point_array(f.GetOutputDataObject(0), "fluence")
    reference = render_illuminated(volume, scene, size, size, "cpu", jitter=False,
                                   early_termination=stop,
                                   illumination=IlluminationVolume.for_volume(volume, fluence))
    assert 0.4 < reference.radiance.max() < 1.0  # the 8-bit range, unclipped

    # OpenGL path, fed by the filter's output port.
    renderer = vtkRenderer()
    renderer.AddVolume(IlluminatedVolume(img, scene, illumination=f.GetOutputPort(), jitter=False))
    window = offscreen_window(renderer, scene.camera, size, size)
    diff = np.abs(read_window_rgb(window) - reference.radiance) / reference.radiance.max()
    window.Finalize()
    assert diff.mean() < 3e-3 and np.percentile(diff, 99) < 1.2e-2, diff.mean()

    # Compute path with the registered method: the same light volume, the same image.
    renderer = vtkRenderer()
    window = offscreen_window(renderer, scene.camera, size, size)
    shown = ComputeVolumeRenderer(renderer, volume, scene, method="convection-diffusion",
                                  device="cpu", jitter=False, early_termination=stop)
    image = read_window_rgb(window)
    direct = render(volume, scene, "convection-diffusion", size, size, device="cpu",
                    jitter=False, early_termination=stop)
    np.testing.assert_allclose(direct.radiance, reference.radiance, rtol=1e-4, atol=1e-5)
    expected = tonemap(direct.radiance, direct.alpha, (0.0, 0.0, 0.0), gamma=1.0)
    assert np.abs(image * 255.0 - expected).max() <= 1.0
    shown.detach()
    window.Finalize()
