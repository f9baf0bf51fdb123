"""The pyvista accessor's inputs (issue 33): one parser for every function's options,
NaN in transfer functions refused, masked arrays refused, ``mesh.illum`` on non-image data."""

from __future__ import annotations

import inspect

import numpy as np
import pytest

pv = pytest.importorskip("pyvista")

import vtkillum.pyvista_accessor as pva  # noqa: E402
from vtkillum import DirectionalLight  # noqa: E402

LIGHT = DirectionalLight((1.0, -0.5, -1.0))

#: Every accessor method with settings that keep it small, and the array that shows its
#: result (None: a RenderResult, compared by radiance).
METHODS = {
    "optical_properties": ({}, "sigma_t"),
    "transmittance": ({"lights": LIGHT, "device": "cpu"}, "transmittance"),
    "convection_diffusion": ({"lights": LIGHT, "device": "cpu", "iterations": 4}, "fluence"),
    "photon_density": ({"lights": LIGHT, "device": "cpu", "photons": 2000}, "fluence"),
    "many_lights": ({"lights": LIGHT, "device": "cpu", "count": 8, "avsm_resolution": 8},
                    "fluence"),
    "ambient_extinction": ({"lights": LIGHT, "device": "cpu", "radius": 1.0,
                            "compute_radiance": False}, "ambient_extinction"),
    "render": ({"method": "single", "lights": LIGHT, "device": "cpu", "width": 12,
                "height": 10}, None),
}


def grid_of(values) -> pv.ImageData:
    """A 7x6x5 grid holding ``values`` (n_points or (n_points, c)) as its active scalars."""
    grid = pv.ImageData(dimensions=(7, 6, 5), spacing=(0.2, 0.2, 0.2))
    grid["v"] = values
    return grid


def field(n=7 * 6 * 5) -> np.ndarray:
    x = np.linspace(0.0, 1.0, n)
    return np.sin(7.0 * x) ** 2


def result_of(method, grid, **kwargs):
    settings, array = METHODS[method]
    out = getattr(grid.illum, method)(**{**settings, **kwargs})
    return np.asarray(out.radiance) if array is None else np.asarray(out[array])


# --- one parser: every method honours component and nan_policy ------------------------------------
@pytest.mark.parametrize("method", sorted(METHODS))
def test_every_method_honours_component(method):
    """Was: many_lights(component=1) ignored it and raised the error it exists to avoid."""
    one = field()
    several = np.stack([one[::-1], one, 0.5 * one], axis=1)
    with pytest.raises(ValueError, match="component"):
        result_of(method, grid_of(several), opacity="linear")
    expected = result_of(method, grid_of(one), opacity="linear")
    np.testing.assert_allclose(result_of(method, grid_of(several), opacity="linear",
                                         component=1), expected, rtol=1e-5, atol=1e-7)


@pytest.mark.parametrize("method", sorted(METHODS))
def test_every_method_honours_nan_policy(method):
    """Was: many_lights(nan_policy='fill') ignored it and raised on the NaN."""
    values = field()
    values[[3, 50, 100]] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        result_of(method, grid_of(values), opacity="linear")
    filled = np.where(np.isfinite(values), values, np.nanmin(values))
    expected = result_of(method, grid_of(filled), opacity="linear")
    np.testing.assert_allclose(result_of(method, grid_of(values), opacity="linear",
                                         nan_policy="fill"), expected, rtol=1e-5, atol=1e-7)


def test_add_to_honours_component_and_nan_policy():
    values = field()
    values[7] = np.nan
    several = np.stack([values, values], axis=1)
    pl = pv.Plotter(off_screen=True, window_size=(32, 32))
    try:
        with pytest.raises(ValueError, match="component"):
            grid_of(several).illum.add_to(pl, nan_policy="fill")
        with pytest.raises(ValueError, match="NaN"):
            grid_of(several).illum.add_to(pl, component=0)
        actor = grid_of(several).illum.add_to(pl, component=0, nan_policy="fill",
                                              illumination="transmittance")
        assert actor is not None
    finally:
        pl.close()


def test_every_function_takes_the_common_arguments_with_the_same_defaults():
    """The parser reads them from each function's own arguments: each must have them all."""
    functions = [pva.optical_properties, pva.transmittance, pva.convection_diffusion,
                 pva.photon_density, pva.many_lights, pva.ambient_extinction, pva.render,
                 pva.add_illuminated_volume, pva.add_computed_volume]
    reference = inspect.signature(pva.transmittance).parameters
    for function in functions:
        parameters = inspect.signature(function).parameters
        for name in pva.COMMON_ARGUMENTS:
            assert name in parameters, (function.__name__, name)
            assert parameters[name].default == reference[name].default, (function.__name__,
                                                                         name)
    with pytest.raises(TypeError, match="common argument"):
        pva._parse_inputs(grid_of(field()), {"scalars": None})


# --- NaN in transfer functions ------------------------------------------------------------------
@pytest.mark.parametrize("opacity", [[0.0, np.nan, 1.0], [0.0, np.inf, 1.0], np.nan,
                                     np.array([0.2, 0.4, -np.inf])])
@pytest.mark.parametrize("method", ["transmittance", "many_lights", "render"])
def test_nan_in_opacity_is_refused(method, opacity):
    """Was: opacity=[0, nan, 1] accepted, and the volume became fully transparent."""
    with pytest.raises(ValueError, match="opacit") as caught:
        result_of(method, grid_of(field()), opacity=opacity)
    assert "finite" in str(caught.value) or "between 0 and 1" in str(caught.value)


def test_nan_in_opacity_is_refused_by_transfer_function_from_pyvista():
    with pytest.raises(ValueError, match="index 1"):
        pva.transfer_function_from_pyvista(grid_of(field()), opacity=[0.0, np.nan, 1.0])


def test_a_masked_opacity_or_illumination_is_refused():
    grid = grid_of(field())
    masked = np.ma.masked_array([0.0, 0.5, 1.0], mask=[False, True, False])
    with pytest.raises(ValueError, match="masked"):
        grid.illum.transmittance(opacity=masked, device="cpu")
    fluence = np.ma.masked_array(np.ones((7, 6, 5, 3)), mask=False)
    fluence[0, 0, 0, 0] = np.ma.masked
    with pytest.raises(ValueError, match="illumination: a masked array"):
        grid.illum.render("illumination", illumination=fluence, width=8, height=8,
                          device="cpu")


# --- non-image data -----------------------------------------------------------------------------
@pytest.mark.parametrize("make", [pv.Sphere, lambda: pv.Sphere().cast_to_unstructured_grid(),
                                  lambda: pv.RectilinearGrid(np.arange(3.0), np.arange(3.0),
                                                             np.arange(3.0))])
def test_illum_on_other_datasets_says_to_resample_onto_image_data(make):
    """Was: a bare AttributeError: 'PolyData' object has no attribute 'illum'."""
    mesh = make()
    with pytest.raises(AttributeError) as caught:
        mesh.illum  # noqa: B018
    message = str(caught.value)
    assert type(mesh).__name__ in message and "pv.ImageData" in message
    assert ".sample(mesh)" in message
    assert not hasattr(mesh, "illum")
    assert isinstance(grid_of(field()).illum, pva.IllumAccessor)  # image data still works


def test_illum_on_a_multiblock_says_to_pick_an_image_block():
    with pytest.raises(AttributeError, match="ImageData block"):
        pv.MultiBlock([grid_of(field())]).illum  # noqa: B018
    assert isinstance(pv.MultiBlock([grid_of(field())])[0].illum, pva.IllumAccessor)


# --- the picture of render(filename=...) --------------------------------------------------------
def test_render_filename_is_written_all_or_nothing(tmp_path, monkeypatch):
    import errno
    import os

    from vtkillum.io import writers

    grid = grid_of(field())
    out = tmp_path / "r.png"
    out.write_bytes(b"old picture")

    def full_open(path, mode="r", *args, **kwargs):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(writers, "open", full_open, raising=False)
    with pytest.raises(writers.DiskFullError, match="no space left on device"):
        grid.illum.render("emission", width=8, height=8, device="cpu", filename=out)
    assert os.listdir(tmp_path) == ["r.png"] and out.read_bytes() == b"old picture"
    monkeypatch.undo()
    grid.illum.render("emission", width=8, height=8, device="cpu", filename=out)
    assert os.listdir(tmp_path) == ["r.png"] and out.read_bytes()[:4] == b"\x89PNG"


@pytest.mark.parametrize("argument", ["scalars", "component", "nan_policy", "clim",
                                      "n_colors", "opacity_unit_distance"])
def test_a_100_kb_argument_is_cut_in_the_message(argument):
    long = "x" * 100_000
    with pytest.raises(ValueError) as caught:
        grid_of(field()).illum.transmittance(device="cpu", **{argument: long})
    assert len(str(caught.value)) < 600 and "(100002 characters)" in str(caught.value)
