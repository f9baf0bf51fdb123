"""The pyvista integration: ``grid.illum`` accessor, conventions, add_illuminated_volume."""

import doctest
import subprocess
import sys

import numpy as np
import pytest

pv = pytest.importorskip("pyvista")

import vtkillum.pyvista_accessor as pva
from vtkillum import DirectionalLight, PointLight, TransferFunction


def slab(n=(6, 6, 11), spacing=0.1, value=1.0):
    grid = pv.ImageData(dimensions=n, spacing=(spacing,) * 3)
    grid["density"] = np.full(grid.n_points, value)
    return grid


def grey(tau_per_unit):
    """Constant extinction ``tau_per_unit`` per world unit (opacity per unit distance 1)."""
    alpha = 1.0 - np.exp(-tau_per_unit)
    return TransferFunction([0.0, 1.0], [alpha, alpha])


def as_ijk(grid, name):
    """A point array as [i, j, k(, c)]."""
    values = np.asarray(grid[name])
    nx, ny, nz = grid.dimensions
    return values.reshape((nz, ny, nx) + values.shape[1:]).transpose(2, 1, 0, *range(3, values.ndim + 2))


def test_docstring_examples_run():
    failures, tried = doctest.testmod(pva, optionflags=doctest.ELLIPSIS)
    assert tried > 20 and failures == 0


def test_accessor_is_registered_on_image_data_only():
    assert isinstance(slab().illum, pva.IllumAccessor)
    assert not hasattr(pv.Sphere(), "illum")
    pva.register()  # idempotent: no second registration, no warning
    assert isinstance(slab().illum, pva.IllumAccessor)


def test_importing_vtkillum_does_not_import_pyvista_or_vtk():
    code = "import sys, vtkillum; print('pyvista' in sys.modules, 'vtkmodules' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120,
                         check=False)
    assert out.returncode == 0, out.stderr
    assert out.stdout.split() == ["False", "False"]


def test_transmittance_of_a_homogeneous_slab_is_beer_lambert():
    grid = slab()
    out = grid.illum.transmittance(DirectionalLight((0, 0, -1)), transfer_function=grey(2.0),
                                   opacity_unit_distance=1.0, device="cpu")
    t = as_ijk(out, "transmittance")
    depth = (10 - np.arange(11)) * 0.1  # light enters at the top (k = 10)
    np.testing.assert_allclose(t[3, 3, :], np.exp(-2.0 * depth), rtol=2e-3, atol=1e-5)
    np.testing.assert_allclose(as_ijk(out, "fluence")[3, 3, :, 0], np.exp(-2.0 * depth),
                               rtol=2e-3, atol=1e-5)
    assert "density" in out.point_data  # full resolution passes the input arrays


def test_light_volume_scale_and_pyvista_lights():
    grid = slab((9, 9, 9))
    light = pv.Light(position=(0.4, 0.4, 5.0), focal_point=(0.4, 0.4, 0.0), intensity=2.0)
    out = grid.illum.transmittance(light, transfer_function=grey(1.0), opacity_unit_distance=1.0,
                                   light_volume_scale=0.5, device="cpu")
    assert out.dimensions == (4, 4, 4) or out.dimensions == (5, 5, 5)
    np.testing.assert_allclose(out.bounds, grid.bounds)
    # pv.Light of intensity 2 (white): irradiance 2 at the unshadowed top.
    top = as_ijk(out, "fluence")[:, :, -1]
    np.testing.assert_allclose(top, 2.0, rtol=1e-5)
    point = pva.lights_from_pyvista(pv.Light(position=(1, 2, 3), positional=True))[0]
    assert isinstance(point, PointLight) and point.position.tolist() == [1.0, 2.0, 3.0]


def test_transfer_functions_match_add_volume():
    grid = pv.ImageData(dimensions=(10, 10, 10))
    grid["v"] = np.linspace(-3.0, 7.0, grid.n_points)
    pl = pv.Plotter(off_screen=True)
    actor = pl.add_volume(grid, scalars="v", cmap="viridis", opacity="sigmoid", clim=(0, 5))
    ctf, otf = pva.transfer_function_from_pyvista(grid, "v", cmap="viridis", opacity="sigmoid",
                                                  clim=(0, 5))
    prop = actor.prop
    for x in np.linspace(-1.0, 6.0, 29):
        np.testing.assert_allclose(ctf.GetColor(x), prop.GetRGBTransferFunction(0).GetColor(x),
                                   atol=1e-6)
        assert otf.GetValue(x) == pytest.approx(prop.GetScalarOpacity(0).GetValue(x), abs=1e-6)
    assert pva.pyvista_unit_distance(grid) == pytest.approx(prop.GetScalarOpacityUnitDistance())
    pl.close()


def test_rgba_output_through_the_accessor():
    grid = slab()
    tf = TransferFunction([0.0, 1.0], [0.4, 0.4], [[1.0, 0.5, 0.25]] * 2)
    out = grid.illum.transmittance(DirectionalLight((0, 0, -1)), transfer_function=tf,
                                   opacity_unit_distance=1.0, albedo=1.0, rgba=True,
                                   exposure=4 * np.pi, device="cpu")
    rgba = as_ijk(out, "illuminated_rgba")
    assert rgba.dtype == np.uint8 and rgba.shape[-1] == 4
    assert out.active_scalars_name == "illuminated_rgba"
    fluence = as_ijk(out, "fluence")[..., 0]
    expected = np.round(255 * np.array([1.0, 0.5, 0.25])[None] * fluence[3, 3, :, None])
    np.testing.assert_allclose(rgba[3, 3, :, :3], expected, atol=1.0)
    assert np.all(rgba[..., 3] == round(255 * 0.4))


def test_other_filters_through_the_accessor():
    grid = slab((8, 8, 8), spacing=0.2)
    grid["density"] = np.linspace(0.0, 1.0, grid.n_points)
    props = grid.illum.optical_properties(cmap="bone", opacity="linear")
    assert {"sigma_t", "sigma_s", "sigma_a", "scattering_color"} <= set(props.point_data.keys())
    cd = grid.illum.convection_diffusion(DirectionalLight((1, 0, 0)), opacity="linear",
                                         scattering=0.01, device="cpu")
    assert cd["fluence"].shape[1] == 3 and np.all(np.asarray(cd["fluence"]) >= 0)
    amb = grid.illum.ambient_extinction(DirectionalLight((1, 0, 0)), opacity="linear",
                                        radius=2.0, device="cpu")
    assert "ambient_extinction" in amb.point_data


def test_render_methods_and_png(tmp_path):
    grid = slab((9, 9, 9), spacing=0.25)
    light = DirectionalLight((1, -1, -1))
    common = {"transfer_function": grey(0.8), "opacity_unit_distance": 1.0, "lights": light,
                  "width": 24, "height": 24, "device": "cpu"}
    single = grid.illum.render("single", **common)
    lit = grid.illum.transmittance(light, transfer_function=grey(0.8), opacity_unit_distance=1.0,
                                   device="cpu")
    via_volume = grid.illum.render("illumination", illumination=lit, filename=tmp_path / "a.png",
                                   **common)
    # Single scattering and the ray caster fed the transmittance volume agree.
    assert single.radiance.mean() > 0
    np.testing.assert_allclose(via_volume.radiance.mean(), single.radiance.mean(), rtol=0.05)
    from vtkillum.core.tonemap import read_png

    assert read_png(tmp_path / "a.png").shape == (24, 24, 3)


def test_add_illuminated_volume_shadows_darken_the_image():
    grid = slab((12, 12, 12), spacing=0.2)
    images = {}
    for illumination in (None, "transmittance"):
        pl = pv.Plotter(off_screen=True, window_size=(48, 48))
        actor = pva.add_illuminated_volume(
            pl, grid, illumination=illumination, transfer_function=grey(3.0),
            opacity_unit_distance=1.0, lights=DirectionalLight((0, 0, -1)), exposure=12.0)
        assert actor in pl.renderer.actors.values()
        pl.camera_position = [(0, -6, 1.1), (1.1, 1.1, 1.1), (0, 0, 1)]
        images[illumination] = pl.screenshot().astype(float)
        pl.close()
    unshadowed, shadowed = images[None], images["transmittance"]
    assert unshadowed.max() > 30
    assert shadowed.mean() < 0.8 * unshadowed.mean()


def test_clear_errors():
    grid = slab()
    with pytest.raises(TypeError, match="ImageData"):
        pva.transmittance(pv.Sphere())
    with pytest.raises(ValueError, match="either transfer_function"):
        grid.illum.transmittance(transfer_function=grey(1.0), cmap="bone")
    with pytest.raises(ValueError, match="no point array 'nope'"):
        grid.illum.optical_properties("nope")
    with pytest.raises(TypeError, match="pyvista.Light"):
        pva.lights_from_pyvista(["sun"])
    with pytest.raises(ValueError, match="name one of"):
        pva.add_illuminated_volume(pv.Plotter(off_screen=True), grid, illumination="magic")


def blobs(n=20):
    grid = pv.ImageData(dimensions=(n, n, n), spacing=(0.1, 0.1, 0.1), origin=(-1.0, 0.5, 0.2))
    x, y, z = (np.asarray(c) for c in grid.points.T)
    c = grid.center
    grid["density"] = np.exp(-((x - c[0]) ** 2 + (y - c[1]) ** 2 + (z - c[2]) ** 2) / 0.25)
    return grid


def test_add_illuminated_volume_is_phase_aware_and_matches_render():
    """The plotter shows the warp caster's phase-aware picture; the lights come with ``lit``."""
    grid = blobs()
    tf = TransferFunction([0.0, 0.3, 1.0], [0.0, 0.2, 0.6], [[1.0, 0.9, 0.7]] * 3)
    light = DirectionalLight((1.0, -0.6, -0.4), (3.0, 3.0, 3.0))
    lit = grid.illum.transmittance(light, transfer_function=tf, opacity_unit_distance=0.2,
                                   device="cpu")
    assert pva.lights_from_pyvista(None)[0].to_dict() != light.to_dict()
    shots, references = {}, {}
    for g in (0.6, 0.0):
        pl = pv.Plotter(off_screen=True, window_size=(48, 48))
        pl.set_background("black")
        actor = pva.add_illuminated_volume(pl, grid, illumination=lit, transfer_function=tf,
                                           opacity_unit_distance=0.2, anisotropy=g,
                                           exposure=6.0, jitter=False)
        assert [l.to_dict() for l in actor.lights] == [light.to_dict()]
        pl.camera_position = [(3.0, 3.5, 4.0), grid.center, (0, 1, 0)]
        shots[g] = pl.screenshot(return_img=True)[..., :3].astype(float) / 255.0
        references[g] = 6.0 * grid.illum.render(
            "illumination", illumination=lit, transfer_function=tf, opacity_unit_distance=0.2,
            anisotropy=g, camera=pl.camera, width=48, height=48, device="cpu", jitter=False,
            early_termination=1.0 - 1.0 / 255.0).radiance
        pl.close()
    for g, shot in shots.items():
        diff = np.abs(shot - references[g]) / references[g].max()
        assert references[g].max() > 0.3
        assert diff.mean() < 3e-3 and np.percentile(diff, 99) < 1.2e-2, (g, diff.mean())
    # g = 0.6 with the camera across the light differs from g = 0 (the phase is applied).
    assert np.abs(shots[0.6] - shots[0.0]).mean() > 10 * 3e-3


def test_illumination_lights_must_match_the_given_lights():
    grid = slab()
    lit = grid.illum.transmittance(DirectionalLight((0, 0, -1)), transfer_function=grey(1.0),
                                   opacity_unit_distance=1.0, device="cpu")
    with pytest.raises(ValueError, match="other lights"):
        grid.illum.render("illumination", illumination=lit, lights=DirectionalLight((1, 0, 0)),
                          transfer_function=grey(1.0), opacity_unit_distance=1.0, width=8,
                          height=8, device="cpu")
    with pytest.raises(ValueError, match="other lights"):
        pva.add_illuminated_volume(pv.Plotter(off_screen=True), grid, illumination=lit,
                                   lights=DirectionalLight((1, 0, 0)),
                                   transfer_function=grey(1.0), opacity_unit_distance=1.0)
    # the same lights given again are fine
    grid.illum.render("illumination", illumination=lit, lights=DirectionalLight((0, 0, -1)),
                      transfer_function=grey(1.0), opacity_unit_distance=1.0, width=8, height=8,
                      device="cpu")


def test_photon_density_accessor_matches_the_filter_convention():
    """grid.illum.photon_density gives an illumination image the renderer applies with the phase."""
    grid = slab()
    light = DirectionalLight((0, 0, -1))
    out = grid.illum.photon_density(light, transfer_function=grey(2.0), opacity_unit_distance=1.0,
                                    photons=2000, max_order=1, device="cpu")
    t = as_ijk(out, "transmittance")
    depth = (10 - np.arange(11)) * 0.1
    np.testing.assert_allclose(t[3, 3, :], np.exp(-2.0 * depth), rtol=2e-3, atol=1e-5)
    assert "scattered_fluence" in out.point_data
    with pytest.raises(ValueError, match="photons must be a positive integer"):
        grid.illum.photon_density(light, transfer_function=grey(2.0), photons=0, device="cpu")
