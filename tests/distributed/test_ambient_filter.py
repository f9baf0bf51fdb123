"""``AmbientExtinctionFilter`` with the radiance cache in distributed mode: each rank updates
its own piece (``UpdatePiece(rank, size, ghosts)``, as ParaView's MPI engine does) of a
Wavelet source and must get its piece of the one-rank output, ghost levels marked. Run under
``mpirun -np N python -m pytest tests/distributed/test_ambient_filter.py``.

Tolerance: 1e-5 of each array's maximum (the march is the one-rank march sample for sample;
only the summed-area table of ``σ̃t`` rounds differently on a piece).
"""

import numpy as np
import pytest

from .conftest import all_ranks, max_abs, whole_and_piece

vtk_ok = pytest.importorskip("vtkmodules.vtkImagingCore")

TOL = 1e-5
WHOLE = (-10, 10, -8, 8, -6, 6)


def _filter(split_axis: int, radiance: bool = True):
    from vtkmodules.vtkCommonDataModel import vtkPiecewiseFunction
    from vtkmodules.vtkImagingCore import vtkRTAnalyticSource

    from vtkillum.filters import AmbientExtinctionFilter

    source = vtkRTAnalyticSource()
    # the longest axis is split first: put it along split_axis
    order = [(21, 17, 13), (13, 21, 17), (17, 13, 21)][split_axis]
    extent = []
    for n in order:
        extent += [-(n // 2), n // 2]
    source.SetWholeExtent(*extent)
    f = AmbientExtinctionFilter()
    otf = vtkPiecewiseFunction()
    otf.AddPoint(40.0, 0.0)
    otf.AddPoint(280.0, 0.9)
    f.SetScalarOpacity(otf)
    f.SetScalarOpacityUnitDistance(1.0)
    f.SetInputConnection(source.GetOutputPort())
    f.test_source = source  # the pipeline does not keep a Python source alive
    f.SetDistributed(True)
    f.SetInputArrayToProcess(0, 0, 0, 0, "RTData")
    f.SetRadius(1.5)
    f.SetAnisotropy(0.4)
    f.SetComputeRadiance(radiance)
    f.AddDirectionalLight((1.0, 0.6, -0.4), (1.0, 1.0, 1.0))
    f.AddDirectionalLight((0.0, 0.0, -1.0), (1.0, 0.5, 0.2))
    f.AddDirectionalLight((-1.0, 0.0, 0.0), (0.3, 0.3, 0.3))
    # inside the block of the last piece along the split axis, and one outside the box
    inside = [0.0, 0.0, 0.0]
    inside[split_axis] = 7.3
    f.AddPointLight(tuple(inside), (30.0, 30.0, 30.0))
    f.AddPointLight((-14.0, 3.0, 9.0), (300.0, 300.0, 300.0))
    return f


@pytest.mark.parametrize("split_axis", [0, 1, 2])
@pytest.mark.parametrize("ghosts", [0, 2])
def test_radiance_cache_filter_gives_its_piece_of_the_one_rank_output(par, capfd, split_axis,
                                                                      ghosts):
    from vtkillum.core.parallel import sub_slices

    ref_arrays, got, out, want, whole = whole_and_piece(_filter(split_axis), _filter(split_axis), par,
                                                        ghosts)
    ok = tuple(out.GetExtent()) == want
    names = {"ambient_extinction", "ambient_radiance"} | {f"ambient_radiance_{i}"
                                                          for i in range(5)}
    ok = ok and names <= set(ref_arrays) and names <= set(got)
    errors = {}
    for name in names & set(ref_arrays):
        values = ref_arrays[name]
        scale = max(float(np.abs(values).max()), 1e-30)
        errors[name] = max_abs(got[name], values[sub_slices(want, whole)]) / scale \
            if name in got else np.inf
        ok = ok and errors[name] <= TOL
    if ghosts and par.size > 1:
        ghost = out.GetPointData().GetArray("vtkGhostType")
        ok = ok and ghost is not None and int(np.asarray(
            [ghost.GetValue(i) for i in range(ghost.GetNumberOfTuples())]).max()) > 0
    log = capfd.readouterr()
    if par.size > 1:
        ok = ok and "(mode: distributed)" in log.out + log.err
    all_ranks(par, ok, f"axis {split_axis}: extent {out.GetExtent()} want {want}, relative "
                       f"errors {errors}")


def test_ghost_levels_hold_the_step_field(par):
    from vtkillum.core.ambient.distributed import ghost_levels_for

    f = _filter(0)
    f.UpdateInformation()
    info = f.GetInputInformation(0, 0)
    with_radiance = f.distributed_ghost_levels(info)
    f.ComputeRadianceOff()
    alone = f.distributed_ghost_levels(info)
    all_ranks(par, alone == ghost_levels_for(1.5, (1, 1, 1)) and with_radiance > alone,
              f"ghost levels {alone} / {with_radiance}")
