"""A filter asked for one piece of a split volume (ParaView's MPI engine asks each rank for
its own) computes the whole volume's illumination and returns its piece of it: the same
values as one process, never the illumination of the piece alone."""

import numpy as np
import pytest
from vtkmodules.util.numpy_support import vtk_to_numpy
from vtkmodules.vtkImagingCore import vtkRTAnalyticSource

from vtkillum.filters import LightTransmittanceFilter
from vtkillum.filters.base import piece_extents


def pipeline():
    source = vtkRTAnalyticSource()
    source.SetWholeExtent(-8, 8, -8, 8, -8, 8)
    lit = LightTransmittanceFilter()
    lit.SetInputConnection(source.GetOutputPort())
    lit.SetDevice("cpu")
    lit.RemoveAllLights()
    lit.AddDirectionalLight((0.3, 0.2, -1.0))  # across every piece boundary along z
    return lit


def values(image, extent):
    """The transmittance of ``image`` on ``extent`` (x fastest), as a flat array."""
    full = image.GetExtent()
    t = vtk_to_numpy(image.GetPointData().GetArray("transmittance"))
    dims = [full[2 * a + 1] - full[2 * a] + 1 for a in range(3)]
    t = t.reshape(dims[2], dims[1], dims[0])
    s = [slice(extent[2 * a] - full[2 * a], extent[2 * a + 1] - full[2 * a] + 1)
         for a in (2, 1, 0)]
    return t[s[0], s[1], s[2]].ravel()


@pytest.mark.parametrize("pieces", [2, 3, 4])
def test_each_piece_is_cut_from_the_whole_result(pieces):
    whole = pipeline()
    whole.Update()
    reference = whole.GetOutputDataObject(0)
    covered = set()
    for piece in range(pieces):
        lit = pipeline()
        lit.UpdatePiece(piece, pieces, 0)
        out = lit.GetOutputDataObject(0)
        extent, owned = piece_extents((-8, 8, -8, 8, -8, 8), piece, pieces)
        assert out.GetExtent() == extent == owned
        np.testing.assert_array_equal(values(out, extent), values(reference, extent))
        assert out.GetPointData().GetArray("vtkGhostType") is None
        covered.add(extent)
    assert len(covered) == pieces


def test_ghost_levels_are_marked():
    lit = pipeline()
    lit.UpdatePiece(0, 2, 1)
    out = lit.GetOutputDataObject(0)
    extent, owned = piece_extents((-8, 8, -8, 8, -8, 8), 0, 2, 1)
    assert out.GetExtent() == extent != owned
    ghosts = vtk_to_numpy(out.GetCellData().GetArray("vtkGhostType"))
    assert ghosts.any() and not ghosts.all()
