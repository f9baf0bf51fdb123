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
    with pytest.raises(ValueError, match="no point or cell array 'nope'"):
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
    with pytest.raises(ValueError, match="photons must be an integer >= 0"):
        grid.illum.photon_density(light, transfer_function=grey(2.0), photons=-1, device="cpu")


# --- issue 15, row 8: the accessor takes the filters' options and checks its arguments -----------
def ramp_grid(n=(7, 6, 5), spacing=0.2):
    grid = pv.ImageData(dimensions=n, spacing=(spacing,) * 3)
    x, y, z = (np.asarray(c) for c in grid.points.T)
    grid["density"] = 0.3 + 0.5 * x + 0.2 * y * z
    return grid


def lit(grid, **kwargs):
    """transmittance of ``grid`` with a fixed transfer function (only the data vary)."""
    return grid.illum.transmittance(DirectionalLight((1, -0.5, -1)),
                                    transfer_function=TransferFunction([0.0, 1.5], [0.0, 0.8]),
                                    opacity_unit_distance=0.5, device="cpu", **kwargs)


def picture(grid, **kwargs):
    return grid.illum.render("single", transfer_function=TransferFunction([0.0, 1.5], [0.0, 0.8]),
                             opacity_unit_distance=0.5, lights=DirectionalLight((1, -0.5, -1)),
                             width=12, height=10, device="cpu", jitter=False, **kwargs)


def test_component_selects_a_component_or_the_magnitude_as_the_filters_do():
    grid = ramp_grid()
    d = np.asarray(grid["density"])
    vectors = np.stack([0.5 * d, d, 0.25 * d], axis=1)
    multi = ramp_grid()
    multi.clear_data()
    multi["v"] = vectors
    with pytest.raises(ValueError, match=r"component=<index> \(0 \.\. 2\) or component='magnitude'"):
        lit(multi)
    expected = lit(grid)["transmittance"]
    np.testing.assert_array_equal(lit(multi, component=1)["transmittance"], expected)
    np.testing.assert_array_equal(picture(multi, component=1).radiance, picture(grid).radiance)
    norm = ramp_grid()
    norm["density"] = np.linalg.norm(vectors, axis=1)
    for magnitude in (-1, "magnitude"):
        np.testing.assert_allclose(lit(multi, component=magnitude)["transmittance"],
                                   lit(norm)["transmittance"], rtol=1e-6)
    # The filters' convention: the component of the filter is InputComponent.
    from vtkillum.filters.light_transmittance import LightTransmittanceFilter

    f = LightTransmittanceFilter()
    f.SetInputComponent(2)
    f.SetLights([DirectionalLight((1, -0.5, -1))])
    f.SetDevice("cpu")
    ctf, otf = pva.transfer_function_to_vtk(TransferFunction([0.0, 1.5], [0.0, 0.8]))
    f.SetColorTransferFunction(ctf)
    f.SetScalarOpacity(otf)
    f.SetScalarOpacityUnitDistance(0.5)
    from_filter = np.asarray(pv.wrap(f.execute(multi))["transmittance"])
    np.testing.assert_array_equal(lit(multi, component=2)["transmittance"], from_filter)
    with pytest.raises(ValueError, match="component 3 is out of range"):
        lit(multi, component=3)
    for bad in (-2, 1.5, "norm", True):
        with pytest.raises(ValueError, match="component must be"):
            lit(multi, component=bad)
    # The default clim is the range of the chosen component (as add_volume's of that array).
    _, otf = pva.transfer_function_from_pyvista(multi, cmap="viridis", component=0)
    assert otf.GetRange() == pytest.approx((vectors[:, 0].min(), vectors[:, 0].max()), rel=1e-6)


def test_nan_policy_fill_replaces_nan_by_the_minimum():
    grid = ramp_grid()
    holes = ramp_grid()
    values = np.asarray(holes["density"]).copy()
    values[[3, 50, 100]] = [np.nan, np.inf, -np.nan]
    holes["density"] = values
    with pytest.raises(ValueError, match="nan_policy='fill'"):
        lit(holes)
    with pytest.raises(ValueError, match="nan_policy='fill'"):
        picture(holes)
    filled = ramp_grid()
    filled["density"] = np.where(np.isfinite(values), values, np.nanmin(values))
    np.testing.assert_array_equal(lit(holes, nan_policy="fill")["transmittance"],
                                  lit(filled)["transmittance"])
    np.testing.assert_array_equal(picture(holes, nan_policy="fill").radiance,
                                  picture(filled).radiance)
    with pytest.raises(ValueError, match="nan_policy must be 'raise' or 'fill'"):
        lit(grid, nan_policy="zero")


def test_cell_arrays_named_with_scalars_are_averaged_onto_the_points():
    grid = ramp_grid()
    cells = pv.ImageData(dimensions=grid.dimensions, spacing=grid.spacing)
    centers = np.asarray(cells.cell_centers().points)
    cells.cell_data["c"] = 0.3 + 0.5 * centers[:, 0] + 0.2 * centers[:, 1] * centers[:, 2]
    cells.point_data["other"] = np.zeros(cells.n_points)  # the active point scalars
    points = cells.cell_data_to_point_data()
    np.testing.assert_array_equal(lit(cells, scalars="c")["transmittance"],
                                  lit(points, scalars="c")["transmittance"])
    np.testing.assert_array_equal(picture(cells, scalars="c").radiance,
                                  picture(points, scalars="c").radiance)
    # Default clim: the range of the converted (point) values, as add_volume takes it.
    _, otf = pva.transfer_function_from_pyvista(cells, "c", cmap="viridis")
    c = np.asarray(points["c"])
    assert otf.GetRange() == pytest.approx((c.min(), c.max()), rel=1e-6)
    with pytest.raises(ValueError, match="no point or cell array 'd'"):
        lit(cells, scalars="d")


def test_clim_is_checked_not_silently_changed():
    grid = ramp_grid()
    for clim in ((1, 0), (0.5, 0.5)):
        with pytest.raises(ValueError, match=r"low < high"):
            grid.illum.transmittance(clim=clim, device="cpu")
        with pytest.raises(ValueError, match=r"low < high"):
            pva.transfer_function_from_pyvista(grid, clim=clim)
    for clim in (0, -2.0, np.inf):
        with pytest.raises(ValueError, match="must be positive and finite"):
            grid.illum.render("emission", clim=clim, width=4, height=4, device="cpu")
    for clim in ((0, np.nan), (0, 1, 2), "wide"):
        with pytest.raises(ValueError, match="clim"):
            grid.illum.optical_properties(clim=clim)
    # A number c is (-c, c), as in add_volume.
    _, otf = pva.transfer_function_from_pyvista(grid, clim=2)
    assert otf.GetRange() == pytest.approx((-2.0, 2.0))


def test_n_colors_is_checked():
    grid = ramp_grid()
    for n in (0, -3, 2.5, True, "256"):
        with pytest.raises(ValueError, match="n_colors must be an integer >= 1"):
            grid.illum.render("emission", n_colors=n, width=4, height=4, device="cpu")
        with pytest.raises(ValueError, match="n_colors must be an integer >= 1"):
            grid.illum.transmittance(n_colors=n, device="cpu")
    assert grid.illum.optical_properties(n_colors=np.int64(2)).n_points == grid.n_points


@pytest.mark.parametrize("dims", [(1, 1, 1), (1, 6, 6), (6, 6, 1)])
def test_degenerate_grids_are_refused_up_front(dims):
    grid = pv.ImageData(dimensions=dims)
    grid["v"] = np.linspace(0.0, 1.0, grid.n_points)
    message = rf"the grid has dimensions \({dims[0]}, {dims[1]}, {dims[2]}\).*at least 2 points"
    for call in (lambda: grid.illum.optical_properties(),
                 lambda: grid.illum.transmittance(device="cpu"),
                 lambda: grid.illum.convection_diffusion(device="cpu"),
                 lambda: grid.illum.render(width=4, height=4, device="cpu"),
                 lambda: pva.add_illuminated_volume(pv.Plotter(off_screen=True), grid)):
        with pytest.raises(ValueError, match=message):
            call()


def test_bad_spacing_and_unit_distance_are_refused():
    grid = ramp_grid()
    with pytest.raises(ValueError, match="opacity_unit_distance must be a positive number"):
        grid.illum.transmittance(opacity_unit_distance=-1.0, device="cpu")
    with pytest.raises(ValueError, match="opacity_unit_distance must be a positive number"):
        grid.illum.render(opacity_unit_distance=0.0, width=4, height=4, device="cpu")
    flat = ramp_grid()
    flat.spacing = (0.2, 0.0, 0.2)
    with pytest.raises(ValueError, match=r"spacing .* must be positive"):
        flat.illum.transmittance(device="cpu")


def _filter_words(message):
    """Names of the filters' properties (``SetOutputScale`` -> ``OutputScale``) in ``message``."""
    import re

    from vtkillum import filters

    properties = {name[3:] for cls in vars(filters).values() if isinstance(cls, type)
                  for name in dir(cls) if name.startswith("Set") and len(name) > 3}
    words = set(re.findall(r"[A-Za-z_]+=?", message))
    return {w for w in words if w in properties or w.startswith("Set")} | (
        {"array_name="} & words)


def test_error_messages_name_only_arguments_the_accessor_takes():
    grid = ramp_grid()
    vectors = ramp_grid()
    vectors.clear_data()
    vectors["v"] = np.ones((vectors.n_points, 3))
    holes = ramp_grid()
    holes["density"] = np.where(np.arange(holes.n_points) == 4, np.nan, 1.0)
    two = ramp_grid()
    two.clear_data()
    two.point_data.set_array(np.zeros(two.n_points), "a")
    two.point_data.set_array(np.ones(two.n_points), "b")
    cases = {
        "light_volume_scale": lambda: grid.illum.transmittance(light_volume_scale=2.0,
                                                               device="cpu"),
        "device": lambda: grid.illum.transmittance(device="gpu"),
        "step_size": lambda: grid.illum.transmittance(step_size=-1.0, device="cpu"),
        "iterations": lambda: grid.illum.convection_diffusion(iterations=-1, device="cpu"),
        "solver": lambda: grid.illum.convection_diffusion(solver="magic", device="cpu"),
        "radius": lambda: grid.illum.ambient_extinction(radius=-1.0, device="cpu"),
        "radius_units": lambda: grid.illum.ambient_extinction(radius_units="m", device="cpu"),
        "output_scale": lambda: grid.illum.optical_properties(output_scale=3.0),
        "albedo": lambda: grid.illum.optical_properties(albedo=2.0),
        "passes": lambda: grid.illum.photon_density(passes=0, device="cpu"),
        "direct_light": lambda: grid.illum.photon_density(direct_light="x", device="cpu"),
        "component": lambda: vectors.illum.transmittance(device="cpu"),
        "nan_policy": lambda: holes.illum.optical_properties(),
        "scalars": lambda: two.illum.optical_properties(),
        "n_colors": lambda: grid.illum.optical_properties(n_colors=0),
        "clim": lambda: grid.illum.optical_properties(clim=(1, 0)),
        "opacity_unit_distance": lambda: grid.illum.optical_properties(opacity_unit_distance=-1),
    }
    for argument, call in cases.items():
        with pytest.raises((TypeError, ValueError)) as info:
            call()
        message = str(info.value)
        assert argument in message, (argument, message)
        assert not _filter_words(message), (argument, message)


def test_add_illuminated_volume_takes_component_nan_policy_and_cell_arrays():
    grid = ramp_grid((10, 10, 10), spacing=0.2)
    d = np.asarray(grid["density"])
    other = pv.ImageData(dimensions=grid.dimensions, spacing=grid.spacing)
    other["v"] = np.stack([np.zeros_like(d), d], axis=1)
    holes = grid.copy()
    holes["density"] = np.where(d == d.min(), np.nan, d)
    filled = grid.copy()
    filled["density"] = np.where(d == d.min(), np.nanmin(holes["density"]), d)
    cells = pv.ImageData(dimensions=grid.dimensions, spacing=grid.spacing)
    cells.cell_data["c"] = np.linspace(0.2, 1.0, cells.n_cells)
    shots = {}
    for key, data, kwargs in (("grid", grid, {}), ("component", other, {"component": 1}),
                              ("holes", holes, {"nan_policy": "fill"}),
                              ("filled", filled, {}), ("cells", cells, {"scalars": "c"}),
                              ("points", cells.cell_data_to_point_data(), {"scalars": "c"})):
        pl = pv.Plotter(off_screen=True, window_size=(32, 32))
        pva.add_illuminated_volume(pl, data, transfer_function=TransferFunction([0.0, 1.5],
                                                                                [0.0, 0.8]),
                                   opacity_unit_distance=0.5, exposure=8.0, jitter=False, **kwargs)
        pl.camera_position = [(3.0, 2.5, 4.0), grid.center, (0, 1, 0)]
        shots[key] = pl.screenshot(return_img=True).astype(float)
        pl.close()
    assert shots["grid"].max() > 20
    np.testing.assert_array_equal(shots["component"], shots["grid"])
    np.testing.assert_array_equal(shots["holes"], shots["filled"])
    np.testing.assert_array_equal(shots["cells"], shots["points"])
    with pytest.raises(ValueError, match="component=<index>"):
        pva.add_illuminated_volume(pv.Plotter(off_screen=True), other)


def test_many_lights_accessor_gives_the_illumination_and_the_virtual_lights():
    grid = slab()
    light = DirectionalLight((0, 0, -1))
    out, vls = grid.illum.many_lights(light, transfer_function=grey(2.0), albedo=0.9,
                                      opacity_unit_distance=1.0, count=16, avsm_resolution=8,
                                      device="cpu", return_virtual_lights=True)
    t = as_ijk(out, "transmittance")
    depth = (10 - np.arange(11)) * 0.1
    np.testing.assert_allclose(t[3, 3, :], np.exp(-2.0 * depth), rtol=2e-3, atol=1e-5)
    assert as_ijk(out, "scattered_fluence").max() > 0
    assert vls.n_points > 0 and "radiance" in vls.point_data
    with pytest.raises(ValueError, match="count"):
        grid.illum.many_lights(light, transfer_function=grey(2.0), count=0, device="cpu")
