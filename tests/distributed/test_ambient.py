"""Distributed ambient extinction (ghost layers for the sphere, then the SAT) against the
one-rank core, on every rank of ``mpirun -np N python -m pytest tests/distributed``.

Tolerance: 1e-6 of the largest ``σ̃t`` (the float64 summed-area tables of a piece and of
the whole volume round differently; the cubes are the same).
"""

import numpy as np
import pytest

from vtkillum.core.ambient.distributed import distributed_ambient_extinction, ghost_levels_for
from vtkillum.core.ambient.sat import ambient_extinction, sigma_t_grid
from vtkillum.core.parallel import Decomposition, sub_slices
from vtkillum.core.transfer_function import TransferFunction
from vtkillum.core.volume import Volume
from vtkillum.core.warp_common import make_medium

from .conftest import all_ranks, max_abs
from .volumes import ORIGIN, SHAPES, SPACING, blobs, piece_volume, whole_extent

TOL = 1e-6
TF = TransferFunction(scalars=[0.0, 1.5], opacity=[0.0, 0.6], colors=[[1, 1, 1], [1, 1, 1]])


@pytest.mark.parametrize("axis_name", sorted(SHAPES))
@pytest.mark.parametrize("radius", [0.6, 2.0, 4.5])  # world units: 1.2, 4 and 9 voxels
def test_ambient_extinction_matches_one_rank(par, axis_name, radius):
    shape = SHAPES[axis_name]
    whole = whole_extent(shape)
    field = blobs(shape)
    extent = Decomposition.of(whole, par.size).extents[par.rank]
    got = distributed_ambient_extinction(piece_volume(field, extent, whole), extent, whole, TF,
                                         1.0, radius, comm=par.comm)
    volume = Volume(field, SPACING, ORIGIN)
    medium = make_medium(volume, TF, 1.0, device=par.device)
    ref = ambient_extinction(sigma_t_grid(medium, par.device), SPACING, radius,
                             device=par.device).numpy()[sub_slices(extent, whole)]
    scale = float(np.abs(ref).max())
    all_ranks(par, got.shape == ref.shape and max_abs(got, ref) <= TOL * scale,
              f"radius {radius}: max diff {max_abs(got, ref):.3g} of {scale:.3g}")


def test_ghost_levels_cover_the_cube():
    # r = 4.5 world units at spacing 0.5: cube half-width 0.806 * 9 = 7.25 voxels -> 9.
    assert ghost_levels_for(4.5, SPACING) == 9
    assert ghost_levels_for(0.1, SPACING) == 2
