"""The core's piece split is VTK's, and the halo exchange fills ghosts with the owners' values."""

import numpy as np
import pytest

from vtkillum.core.parallel import Decomposition, halo_exchange, split_extent, sub_slices

from .conftest import all_ranks

WHOLES = [(0, 20, 0, 20, 0, 20), (-10, 10, 0, 4, 3, 9), (0, 40, 0, 7, 0, 11),
          (0, 5, 0, 33, 0, 2), (0, 1, 0, 1, 0, 1), (0, 0, 0, 15, 0, 9)]


@pytest.mark.parametrize("whole", WHOLES)
def test_split_is_vtk_extent_translator(whole):
    vtk_tr = pytest.importorskip("vtkmodules.vtkCommonExecutionModel").vtkExtentTranslator
    translator = vtk_tr()
    for pieces in (1, 2, 3, 4, 5, 7, 8, 16):
        for piece in range(pieces):
            for ghosts in (0, 1, 3):
                translator.SetWholeExtent(*whole)
                translator.SetPiece(piece)
                translator.SetNumberOfPieces(pieces)
                translator.SetGhostLevel(ghosts)
                translator.PieceToExtent()
                assert split_extent(whole, piece, pieces, ghosts) == \
                    tuple(translator.GetExtent()), (whole, piece, pieces, ghosts)


@pytest.mark.parametrize("pieces", [2, 3, 4, 8])
def test_owner_extents_tile_the_whole(pieces):
    d = Decomposition.of((0, 12, 0, 9, 0, 17), pieces)
    count = np.zeros((13, 10, 18), int)
    for p in range(pieces):
        count[sub_slices(d.owner_extent(p), d.whole)] += 1
    assert (count == 1).all()


@pytest.mark.parametrize("whole", [(0, 30, 0, 9, 0, 9), (0, 9, 0, 30, 0, 9),
                                   (0, 9, 0, 9, 0, 30), (0, 16, 0, 16, 0, 16)])
@pytest.mark.parametrize("ghosts", [1, 2, 7])
def test_halo_exchange_fills_ghosts_from_their_owners(par, whole, ghosts):
    d = Decomposition.of(whole, par.size)
    shape = tuple(whole[2 * a + 1] - whole[2 * a] + 1 for a in range(3))
    field = np.arange(np.prod(shape) * 2, dtype=np.float32).reshape(*shape, 2)
    mine = d.extents[par.rank]
    got = halo_exchange(field[sub_slices(mine, whole)], d, par.rank, ghosts, par.comm)
    want = field[sub_slices(d.ghosted(par.rank, ghosts), whole)]
    all_ranks(par, got.shape == want.shape and np.array_equal(got, want),
              f"ghosts {ghosts} of piece {mine}")


def test_halo_exchange_of_warp_arrays(par):
    import warp as wp

    whole = (0, 9, 0, 9, 0, 13)
    d = Decomposition.of(whole, par.size)
    field = np.random.default_rng(1).random((10, 10, 14)).astype(np.float32)
    local = wp.array(field[sub_slices(d.extents[par.rank], whole)], dtype=wp.float32,
                     device=par.device)
    got = halo_exchange(local, d, par.rank, 2, par.comm)
    all_ranks(par, isinstance(got, wp.array) and str(got.device) == str(local.device)
              and np.array_equal(got.numpy(),
                                 field[sub_slices(d.ghosted(par.rank, 2), whole)]))
