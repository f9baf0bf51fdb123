"""Minimal recomputation on edits: the light transmittance is recomputed only when the
opacity, its unit distance or the lights change; a colour, albedo or anisotropy edit and
an identical transfer function reuse what was computed (also across pyvista accessor
calls, each of which makes a new filter)."""

import numpy as np
import pytest
from vtkmodules.vtkCommonDataModel import vtkPiecewiseFunction
from vtkmodules.vtkRenderingCore import vtkColorTransferFunction

from vtkillum.filters import LightTransmittanceFilter
from vtkillum.io.convert import point_array


@pytest.fixture
def computations(monkeypatch):
    """Counts LightTransmittanceFilter.compute calls (the light-volume computations)."""
    calls = []
    original = LightTransmittanceFilter.compute

    def counted(self, volume, params):
        calls.append(params)
        return original(self, volume, params)

    monkeypatch.setattr(LightTransmittanceFilter, "compute", counted)
    return calls


def functions(opacity=0.4, color=(1.0, 0.5, 0.2)):
    ctf = vtkColorTransferFunction()
    ctf.AddRGBPoint(0.0, *color)
    ctf.AddRGBPoint(1.0, 1.0, 1.0, 1.0)
    otf = vtkPiecewiseFunction()
    otf.AddPoint(0.0, 0.0)
    otf.AddPoint(1.0, opacity)
    return ctf, otf


def lit_filter(make_image):
    f = LightTransmittanceFilter()
    f.SetDevice("cpu")
    f.SetInputData(make_image(dims=(10, 9, 8), values=np.linspace(0, 1, 720).reshape(10, 9, 8)))
    ctf, otf = functions()
    f.SetColorTransferFunction(ctf)
    f.SetScalarOpacity(otf)
    return f, ctf, otf


def test_colour_albedo_and_anisotropy_edits_do_not_recompute(make_image, computations):
    f, ctf, otf = lit_filter(make_image)
    reference = point_array(f.execute(), "transmittance").copy()
    assert len(computations) == 1
    ctf.AddRGBPoint(0.5, 0.0, 1.0, 0.0)        # a colour edit
    f.SetAlbedo(0.3)
    f.SetAnisotropy(0.5)
    out = f.execute()
    assert len(computations) == 1
    np.testing.assert_array_equal(point_array(out, "transmittance"), reference)
    otf.AddPoint(0.5, 0.9)                      # an opacity edit recomputes
    changed = point_array(f.execute(), "transmittance")
    assert len(computations) == 2 and not np.array_equal(changed, reference)
    f.SetScalarOpacityUnitDistance(3.0)         # and so does the unit distance
    f.execute()
    assert len(computations) == 3


def test_an_identical_transfer_function_does_not_even_re_execute(make_image, computations):
    f, ctf, otf = lit_filter(make_image)
    f.execute()
    before = f.GetMTime()
    same_ctf, same_otf = functions()             # new objects, the same content
    f.SetColorTransferFunction(same_ctf)
    f.SetScalarOpacity(same_otf)
    same_otf.Modified()                          # a Modified that changes nothing
    assert f.GetMTime() == before
    f.execute()
    assert len(computations) == 1


def test_pyvista_accessor_calls_reuse_the_light_volume(computations):
    pv = pytest.importorskip("pyvista")
    import vtkillum.pyvista_accessor  # noqa: F401  (registers grid.illum)

    grid = pv.ImageData(dimensions=(10, 9, 8))
    grid["density"] = np.linspace(0, 1, grid.n_points)
    first = grid.illum.transmittance(cmap="viridis", opacity="linear", device="cpu")
    again = grid.illum.transmittance(cmap="viridis", opacity="linear", device="cpu")
    recoloured = grid.illum.transmittance(cmap="gray", opacity="linear", device="cpu",
                                          albedo=0.5)
    assert len(computations) == 1
    for out in (again, recoloured):
        np.testing.assert_array_equal(out["transmittance"], first["transmittance"])
    grid.illum.transmittance(cmap="gray", opacity="sigmoid", device="cpu")
    assert len(computations) == 2
    grid["density"] = np.linspace(1, 0, grid.n_points)  # new data: computed anew
    grid.illum.transmittance(cmap="gray", opacity="sigmoid", device="cpu")
    assert len(computations) == 3
