"""The filters' distributed mode without ParaView: each rank updates its own piece
(``UpdatePiece(rank, size, ghosts)``, as ParaView's MPI engine does) of a Wavelet source
and must get its piece of the one-rank output. Run under ``mpirun -np N``; on one rank
the pieces are the whole and the mode is the usual one.
"""

import numpy as np
import pytest

from .conftest import all_ranks, max_abs, point_arrays, whole_and_piece

vtk_ok = pytest.importorskip("vtkmodules.vtkImagingCore")

LIGHTS = [("directional", (1.0, 0.6, -0.4), (1.0, 1.0, 1.0)),
          ("directional", (0.0, 0.0, -1.0), (1.0, 1.0, 1.0)),
          ("point", (4.0, -3.0, 2.0), (30.0, 30.0, 30.0))]


def _source():
    from vtkmodules.vtkImagingCore import vtkRTAnalyticSource

    source = vtkRTAnalyticSource()
    source.SetWholeExtent(-10, 10, -8, 8, -6, 6)
    return source


def _filter(kind):
    from vtkmodules.vtkCommonDataModel import vtkPiecewiseFunction

    from vtkillum.filters import AmbientExtinctionFilter, LightTransmittanceFilter

    f = LightTransmittanceFilter() if kind == "transmittance" else AmbientExtinctionFilter()
    otf = vtkPiecewiseFunction()
    otf.AddPoint(40.0, 0.0)
    otf.AddPoint(280.0, 0.5)
    f.SetScalarOpacity(otf)
    f.SetScalarOpacityUnitDistance(1.0)
    source = _source()
    f.SetInputConnection(source.GetOutputPort())
    f.test_source = source  # the pipeline does not keep a Python source alive
    f.SetDistributed(True)
    f.SetInputArrayToProcess(0, 0, 0, 0, "RTData")
    if kind == "transmittance":
        for light, vec, rgb in LIGHTS:
            (f.AddDirectionalLight if light == "directional" else f.AddPointLight)(vec, rgb)
    else:
        f.SetRadius(2.0)
        f.ComputeRadianceOff()
    return f


# transmittance: the one-rank march across ranks (measured: 0, bit-identical; the plane
# sweep it replaced differed by 5.8e-2 here); ambient: exact but for rounding.
@pytest.mark.parametrize("kind,tol", [("transmittance", 1e-6), ("ambient", 1e-5)])
@pytest.mark.parametrize("ghosts", [0, 1])
def test_distributed_filter_gives_its_piece_of_the_one_rank_output(par, capfd, kind, tol,
                                                                    ghosts):
    from vtkillum.core.parallel import sub_slices

    ref_arrays, got, out, want, whole = whole_and_piece(_filter(kind), _filter(kind), par,
                                                        ghosts)
    ok = tuple(out.GetExtent()) == want
    errors = {}
    for name, values in ref_arrays.items():
        scale = max(float(np.abs(values).max()), 1e-30)
        # transmittance: T is absolute (scale 1); other arrays relative to their maximum
        limit = tol if name == "transmittance" else tol * scale * (3 if kind == "transmittance"
                                                                    else 1)
        errors[name] = max_abs(got[name], values[sub_slices(want, whole)]) \
            if name in got else np.inf
        ok = ok and errors[name] <= limit
    if ghosts and par.size > 1:
        ghost = out.GetPointData().GetArray("vtkGhostType")
        ok = ok and ghost is not None and int(np.asarray(
            [ghost.GetValue(i) for i in range(ghost.GetNumberOfTuples())]).max()) > 0
    log = capfd.readouterr()
    if par.size > 1:
        ok = ok and "(mode: distributed)" in log.out + log.err
    all_ranks(par, ok, f"{kind}: extent {out.GetExtent()} want {want}, errors {errors}")


def test_distributed_off_falls_back_to_the_whole_volume_with_a_reason(par, capfd):
    """``SetDistributed(False)``: mode 1 (the whole volume on every rank), the same arrays
    and one line saying why."""
    f = _filter("transmittance")
    f.SetDistributed(False)
    f.UpdatePiece(par.rank, par.size, 0)
    log = capfd.readouterr()
    text = log.out + log.err
    ok = f.GetOutputDataObject(0).GetPointData().GetArray("transmittance") is not None
    if par.size > 1:
        ok = ok and "whole volume on every rank; not distributed: the Distributed property " \
                    "is off" in text
    all_ranks(par, ok, text[-500:])


def test_transmittance_is_distributed_by_default_and_ramps_over_the_whole_range(par, capfd):
    """No ``SetDistributed`` and no opacity function: the default opacity ramp spans the
    whole volume's data range on every rank (not its piece's), so the pieces still equal
    the one-rank output."""
    from vtkillum.filters import LightTransmittanceFilter

    def make():
        f = LightTransmittanceFilter()
        source = _source()
        f.SetInputConnection(source.GetOutputPort())
        f.test_source = source
        f.AddPointLight((4.0, -3.0, 2.0), (30.0, 30.0, 30.0))
        return f

    from vtkillum.core.parallel import split_extent, sub_slices

    one = make()
    one.Update()
    reference = point_arrays(one.GetOutputDataObject(0))
    whole = one.GetOutputDataObject(0).GetExtent()
    f = make()
    ok = f.GetDistributed()
    f.UpdatePiece(par.rank, par.size, 0)
    got = point_arrays(f.GetOutputDataObject(0))
    cut = sub_slices(split_extent(whole, par.rank, par.size), whole)
    err = max_abs(got["transmittance"], reference["transmittance"][cut])
    ok = ok and err <= 1e-6
    log = capfd.readouterr()
    if par.size > 1:
        ok = ok and "(mode: distributed)" in log.out + log.err
    all_ranks(par, ok, f"default Distributed {f.GetDistributed()}, |dT| {err:.2e}")
