"""The convection–diffusion filter's distributed mode without ParaView: each rank updates its
own piece (``UpdatePiece(rank, size, ghosts)``, as ParaView's MPI engine asks) of a Wavelet
source and must get its piece of the one-rank output (the light grid at half the data's
resolution), for both diffusion models. Run under ``mpirun -np N python -m pytest``; on one
rank the piece is the whole and the usual mode runs.

Tolerance: 1e-5 of each array's maximum (the distributed core equals one rank on the light
grid, bit for bit up to the physical model's flux-limited solve on the blocks, whose sums
are reduced in another order: within 1e-5 of the maximum, ``test_convection_diffusion.py``;
the filter adds only the display fluence's irradiance, the same per-point arithmetic).
"""

import numpy as np
import pytest

from .conftest import all_ranks, max_abs, whole_and_piece

pytest.importorskip("vtkmodules.vtkImagingCore")
pytest.importorskip("mpi4py")

LIGHTS = [("directional", (1.0, 0.6, -0.4), (1.0, 1.0, 1.0)),
          ("point", (4.0, -3.0, 2.0), (30.0, 30.0, 30.0))]


def _filter(model, distributed=True, solver="multigrid"):
    from vtkmodules.vtkCommonDataModel import vtkPiecewiseFunction
    from vtkmodules.vtkImagingCore import vtkRTAnalyticSource

    from vtkillum.filters import ConvectionDiffusionLightFilter

    f = ConvectionDiffusionLightFilter()
    otf = vtkPiecewiseFunction()
    otf.AddPoint(40.0, 0.0)
    otf.AddPoint(280.0, 0.6)
    f.SetScalarOpacity(otf)
    f.SetScalarOpacityUnitDistance(1.0)
    f.SetAlbedo(0.9)
    f.SetAnisotropy(0.4)
    f.SetDiffusionModel(model)
    f.SetScattering(2.0)
    f.SetSolver(solver)
    f.SetTolerance(1e-6)
    source = vtkRTAnalyticSource()
    source.SetWholeExtent(-10, 10, -8, 8, -6, 6)
    f.SetInputConnection(source.GetOutputPort())
    f.test_source = source  # the pipeline does not keep a Python source alive
    f.SetDistributed(distributed)
    f.SetInputArrayToProcess(0, 0, 0, 0, "RTData")
    for light, vec, rgb in LIGHTS:
        (f.AddDirectionalLight if light == "directional" else f.AddPointLight)(vec, rgb)
    return f


@pytest.mark.parametrize("model", ["physical", "paper"])
@pytest.mark.parametrize("ghosts", [0, 1])
def test_distributed_filter_gives_its_piece_of_the_one_rank_output(par, capfd, model, ghosts):
    from vtkillum.core.parallel import sub_slices

    ref_arrays, got, out, want, whole = whole_and_piece(_filter(model, distributed=False), _filter(model), par,
                                                        ghosts)
    ok = tuple(out.GetExtent()) == want
    errors = {}
    for name, values in ref_arrays.items():
        scale = max(float(np.abs(values).max()), 1e-30)
        errors[name] = (max_abs(got[name], values[sub_slices(want, whole)]) / scale
                        if name in got else np.inf)
        ok = ok and errors[name] <= 1e-5
    ok = ok and set(got) == set(ref_arrays)
    if ghosts and par.size > 1:
        ghost = out.GetPointData().GetArray("vtkGhostType")
        ok = ok and ghost is not None and int(np.asarray(
            [ghost.GetValue(i) for i in range(ghost.GetNumberOfTuples())]).max()) > 0
    text = "".join(capfd.readouterr())
    if par.size > 1:
        ok = ok and "(mode: distributed)" in text and "distributed convection" in text
    all_ranks(par, ok, f"{model}: extent {out.GetExtent()} want {want}, errors {errors}")


def test_paper_model_with_another_solver_falls_back_with_a_reason(par, capfd):
    f = _filter("paper", solver="cg")
    f.UpdatePiece(par.rank, par.size, 0)
    text = "".join(capfd.readouterr())
    ok = f.GetOutputDataObject(0).GetNumberOfPoints() > 0
    if par.size > 1:
        ok = ok and "not distributed: the paper model's distributed diffusion solves" in text
    all_ranks(par, ok, text[-500:])
