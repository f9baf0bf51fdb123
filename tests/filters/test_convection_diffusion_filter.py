"""ConvectionDiffusionLightFilter: arrays, geometry, properties, partial recomputation, time."""

import numpy as np
import pytest
from helpers import constant_opacity_filter, offscreen_window, read_window_rgb
from vtkmodules.vtkCommonDataModel import vtkDataObject

from vtkillum.core.convection_diffusion.solver import DEFAULT_TOLERANCE
from vtkillum.core.transfer_function import TransferFunction
from vtkillum.filters.convection_diffusion_light import ConvectionDiffusionLightFilter
from vtkillum.io.convert import point_array
from vtkillum.io.illumination_arrays import illumination_from_image, lights_from_field


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
    pd = out.GetPointData()
    names = [pd.GetArrayName(i) for i in range(pd.GetNumberOfArrays())]
    assert names == ["fluence", "transmittance", "scattered_fluence"]
    assert pd.GetScalars().GetName() == "fluence"
    lights = lights_from_field(out)
    assert len(lights) == 1 and np.allclose(lights[0].irradiance, (1.0, 2.0, 3.0))
    x = np.linspace(0.0, 5.0, 6)  # distance travelled inside the box (world units)
    T = point_array(out, "transmittance")
    np.testing.assert_allclose(T[:, 2, 1], np.exp(-np.log(2.0) * x), rtol=1e-5)
    direct = np.outer(np.exp(-np.log(2.0) * x), [1.0, 2.0, 3.0])
    scattered = point_array(out, "scattered_fluence")
    assert scattered.min() >= 0 and scattered[:, 2, 1].max() > 0  # albedo 0.9: scattered light
    np.testing.assert_allclose(point_array(out, "fluence")[:, 2, 1],
                               direct + scattered[:, 2, 1], rtol=1e-5)
    # The paper model without diffusion: the composed light, isotropic, no transmittance.
    f.SetDiffusionModel("paper")
    out = f.execute(img)
    assert out.GetPointData().GetArray("transmittance") is None
    np.testing.assert_allclose(point_array(out, "fluence")[:, 2, 1], direct, rtol=1e-5)
    np.testing.assert_allclose(point_array(out, "scattered_fluence")[:, 2, 1], direct, rtol=1e-5)


def test_properties(make_image):
    f = make_filter()
    assert f.GetLightVolumeScale() == 0.5 and f.GetScattering() == (0.0, 0.0, 0.0)
    assert f.GetDiffusionModel() == "physical" and f.GetTolerance() == DEFAULT_TOLERANCE
    before = f.GetMTime()
    f.SetScattering(0.0)
    f.SetIterations(0)
    f.SetTolerance(DEFAULT_TOLERANCE)
    f.SetSolver("multigrid")
    f.SetDiffusionModel("physical")
    assert f.GetMTime() == before  # unchanged values do not re-execute
    f.SetDiffusionModel("paper")
    assert f.GetDiffusionModel() == "paper" and f.GetMTime() > before
    f.SetScattering(0.1, 0.2, 0.3)
    assert f.GetScattering() == (0.1, 0.2, 0.3) and f.GetMTime() > before
    f.SetLightVolumeScale(1.0)
    assert f.GetOutputScale() == 1.0
    for setter, value, match in [(f.SetScattering, -1.0, "Scattering"),
                                 (f.SetIterations, 1.5, "Iterations"),
                                 (f.SetTolerance, 0.0, "Tolerance"),
                                 (f.SetSolver, "jacobi", "Solver"),
                                 (f.SetSourceRadius, -1.0, "SourceRadius"),
                                 (f.SetDiffusionModel, "stam", "DiffusionModel"),
                                 (f.SetLightVolumeScale, 2.0, "LightVolumeScale")]:
        with pytest.raises(ValueError, match=match):
            setter(value)


def test_only_what_changed_is_recomputed(make_image):
    f = make_filter(alpha=0.3)
    f.AddDirectionalLight((1, 0, 0))
    f.AddPointLight((3.0, -0.5, 1.5), (2.0, 2.0, 2.0))
    f.SetTolerance(1e-5)
    img = make_image(dims=(16, 12, 10))
    f.execute(img)
    s = f.GetLastUpdateStats()
    assert (s.opacity, s.convected, s.composed) == (True, [0, 1], True)
    f.SetScattering(0.05)  # the paper's sigma_hat_s: nothing to do for the physical model
    f.execute()
    s = f.GetLastUpdateStats()
    assert (s.opacity, s.convected, s.composed, s.diffused) == (False, [], False, False)
    f.SetAlbedo(0.8)  # sigma_s: the source and the diffusion
    fluence = point_array(f.execute(), "fluence").copy()
    s = f.GetLastUpdateStats()
    assert (s.opacity, s.convected, s.composed, s.diffused) == (False, [], True, True)
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
    g.SetAlbedo(0.8)
    g.SetTolerance(1e-5)
    np.testing.assert_allclose(point_array(g.execute(img), "fluence"),
                               point_array(f.execute(), "fluence"), rtol=1e-3, atol=1e-5)
    assert not np.allclose(fluence, point_array(f.execute(), "fluence"))


def test_iteration_budget_and_refine(make_image):
    f = make_filter(alpha=0.3)
    f.AddDirectionalLight((1, -1, 0))
    f.SetLightVolumeScale(1.0)
    f.SetDiffusionModel("paper")
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


def test_progress_per_stage_and_per_iteration(make_image):
    f = make_filter(alpha=0.4)
    f.AddDirectionalLight((1, 0, 0))
    f.AddDirectionalLight((0, 1, 0))
    f.AddPointLight((1.0, 1.0, 1.0))
    f.SetTolerance(1e-5)
    seen = []
    f.AddObserver("ProgressEvent", lambda obj, event: seen.append(obj.GetProgress()))
    f.execute(make_image(dims=(16, 12, 10)))
    stats = f.GetLastUpdateStats()
    inner = [p for p in seen if 0.0 < p < 1.0]
    # opacity, the three lights (one batch), composition, every diffusion iteration
    assert len(inner) >= 3 + stats.diffusion.iterations - 1, (seen, stats.diffusion.iterations)
    assert stats.diffusion.iterations >= 3 and np.all(np.diff(inner) >= 0)


def test_time_steps_warm_start_and_cache(time_source):
    f = ConvectionDiffusionLightFilter()
    f.SetDevice("cpu")
    f.SetInputConnection(time_source.GetOutputPort())
    f.SetTransferFunction(TransferFunction([0.0, 6.0], [0.0, 0.6]))
    f.SetLightVolumeScale(1.0)
    f.SetTolerance(1e-4)
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
SIZE, STOP = 40, 1.0 - 1.0 / 255.0


def mapper_case(make_image):
    """Data, scene (g = 0.3) and the filter's light volume as the warp caster sees it."""
    from vtkillum.core.camera import Camera
    from vtkillum.core.lights import DirectionalLight
    from vtkillum.core.raycast import render_illuminated
    from vtkillum.core.scene import Scene
    from vtkillum.io.convert import volume_from_image_data

    img = make_image(dims=(24, 20, 16), spacing=(0.5, 0.5, 0.5), origin=(0.0, 0.0, 0.0))
    volume = volume_from_image_data(img)
    tf = TransferFunction([0.0, 0.3, 1.0], [0.0, 0.0, 0.5], [[1, 1, 1], [1, 0.8, 0.5], [0.6, 0.8, 1]])
    light = DirectionalLight((1.0, -0.6, -0.3), (18.0, 18.0, 18.0))
    scene = Scene(transfer_function=tf, opacity_unit_distance=1.0, lights=[light],
                  albedo=0.9, anisotropy=0.3,
                  camera=Camera.looking_at_bounds(volume.bounds, direction=(-0.3, -0.2, -1.0)))
    f = make_filter()
    f.SetTransferFunction(tf)
    f.SetAnisotropy(0.3)
    f.AddDirectionalLight(light.direction, light.irradiance)
    f.SetInputData(img)
    f.Update()
    illumination = illumination_from_image(f.GetOutputDataObject(0), volume)
    assert illumination.transmittance.shape[0] == 1 and illumination.scattered.max() > 0
    reference = render_illuminated(volume, scene, SIZE, SIZE, "cpu", jitter=False,
                                   early_termination=STOP, illumination=illumination)
    assert 0.4 < reference.radiance.max() < 1.0, reference.radiance.max()  # 8 bits, unclipped
    return img, volume, scene, f, reference


def test_light_volume_feeds_the_opengl_mapper(make_image):
    """The filter's output port drives the OpenGL mapper like the warp ray caster."""
    pytest.importorskip("vtkmodules.vtkRenderingVolumeOpenGL2")
    from vtkmodules.vtkRenderingCore import vtkRenderer

    from vtkillum.mappers import IlluminatedVolume

    img, volume, scene, f, reference = mapper_case(make_image)
    renderer = vtkRenderer()
    renderer.AddVolume(IlluminatedVolume(img, scene, illumination=f.GetOutputPort(), jitter=False))
    window = offscreen_window(renderer, scene.camera, SIZE, SIZE)
    diff = np.abs(read_window_rgb(window) - reference.radiance) / reference.radiance.max()
    window.Finalize()
    assert diff.mean() < 3e-3 and np.percentile(diff, 99) < 1.2e-2, diff.mean()


def test_compute_path_renders_the_registered_method(make_image):
    """The compute mapper with ``convection-diffusion``: the filter's light volume, the same
    image."""
    pytest.importorskip("vtkmodules.vtkRenderingVolumeOpenGL2")
    from vtkmodules.vtkRenderingCore import vtkRenderer

    from vtkillum.core.render import render
    from vtkillum.core.tonemap import tonemap
    from vtkillum.mappers import ComputeVolumeRenderer

    img, volume, scene, f, reference = mapper_case(make_image)
    renderer = vtkRenderer()
    window = offscreen_window(renderer, scene.camera, SIZE, SIZE)
    shown = ComputeVolumeRenderer(renderer, volume, scene, method="convection-diffusion",
                                  device="cpu", jitter=False, early_termination=STOP)
    image = read_window_rgb(window)
    direct = render(volume, scene, "convection-diffusion", SIZE, SIZE, device="cpu",
                    jitter=False, early_termination=STOP)
    np.testing.assert_allclose(direct.radiance, reference.radiance, rtol=1e-3, atol=1e-4)
    expected = tonemap(direct.radiance, direct.alpha, (0.0, 0.0, 0.0), gamma=1.0)
    assert np.abs(image * 255.0 - expected).max() <= 1.0
    shown.detach()
    window.Finalize()
