"""Ambient extinction ``σ̃t`` across MPI ranks: ghost layers for the sphere, then the SAT.

``σ̃t(x)`` is the mean extinction over the cube ``C_r(x)`` of the ambient sphere's volume
(:mod:`vtkillum.core.ambient.sat`): it reads ``σt`` only within ``h = (π/6)^(1/3) r``
(per axis, in voxels) of ``x``, and takes ``σt = 0`` outside the volume. So each rank

1. evaluates ``σt`` on its piece's points (transfer-function tables over the *whole*
   data range, agreed by one ``allgather`` of the pieces' ranges, as the one-rank
   tables cover the whole volume's range),
2. widens it by ``ceil(max h) + 1`` ghost points on every side from the pieces that own
   them (:func:`vtkillum.core.parallel.halo_exchange`; clamped at the whole volume's
   boundary, where the one-rank method's "0 outside" holds on both),
3. runs the one-rank summed-area table and cube means on the widened block and keeps its
   piece.

The cube of every point of the piece lies inside the widened block, or outside the whole
volume where both take 0, so the result is the one-rank result; the only difference is
the float64 rounding of the (smaller) summed-area table: within 1e-6 relative of the
largest ``σ̃t`` (``tests/distributed/test_ambient.py``). The data are never gathered:
each rank receives ``ghost`` planes of ``σt`` from its neighbours, nothing else.

The radiance cache (the tube march, eqs. 14-17) across ranks is
:mod:`vtkillum.core.ambient.distributed_radiance`: each chain of steps ``2r`` (anchored at
its light's entry into the whole box) is handed from rank to rank with its march state,
the step field built from :func:`ghosted_ambient_extinction`'s widened ``σ̃t``.
"""

from __future__ import annotations

import math

import numpy as np
import warp as wp

from vtkillum.core.ambient.sat import ambient_extinction, cube_half_width, sigma_t_grid
from vtkillum.core.parallel.comm import Parallel
from vtkillum.core.parallel.decomposition import Decomposition, sub_slices
from vtkillum.core.parallel.halo import halo_exchange
from vtkillum.core.parallel.transmittance import block_medium, global_value_range


def _contains(outer, inner) -> bool:
    return all(outer[2 * a] <= inner[2 * a] and inner[2 * a + 1] <= outer[2 * a + 1]
               for a in range(3))


def ghost_levels_for(radius: float, spacing) -> int:
    """Ghost points per side that hold every cube of ``radius`` (world units) around a
    piece's points: ``ceil(max h) + 1`` with ``h`` the cube's half-width in voxels (the
    cube overlaps the dual cells of the points within ``h + 1/2``)."""
    return math.ceil(float(np.max(cube_half_width(radius, spacing)))) + 1


def distributed_ambient_extinction(volume, piece_extent, whole_extent, transfer_function,
                                   unit_distance: float, radius: float, comm=None,
                                   device: str | None = None, data_extent=None) -> np.ndarray:
    """``σ̃t`` on this rank's piece, computed from ghost layers (collective over ``comm``).

    Parameters
    ----------
    volume : vtkillum.core.volume.Volume
        This rank's piece of the data (points ``piece_extent``).
    piece_extent, whole_extent : tuple of 6 int
        VTK extents; rank ``r`` must hold VTK's piece ``r`` of ``comm.Get_size()``.
    transfer_function, unit_distance
        The optical model.
    radius : float
        Ambient sphere radius in world units.
    comm : mpi4py communicator or Parallel, optional
        Default ``MPI_COMM_WORLD``.
    device : str, optional
        Warp device; default one per rank.
    data_extent : tuple of 6 int, optional
        The points ``volume`` holds, when it is more than the piece (ghost levels a VTK
        pipeline delivered). When they hold every ghost point needed, no message is
        exchanged; otherwise the piece is cut out and the ghosts come from the neighbours.

    Returns
    -------
    ndarray (nx, ny, nz) float32
        ``σ̃t`` (1/world units) on the piece's points.
    """
    par = Parallel.create(comm, device)
    sigma_tilde, ghosted = ghosted_ambient_extinction(
        volume, piece_extent, whole_extent, transfer_function, unit_distance, radius, 0, par,
        data_extent)
    return np.ascontiguousarray(sigma_tilde[sub_slices(tuple(int(v) for v in piece_extent),
                                                       ghosted)])


def ghosted_ambient_extinction(volume, piece_extent, whole_extent, transfer_function,
                               unit_distance: float, radius: float, extra: int, par: Parallel,
                               data_extent=None) -> tuple[np.ndarray, tuple]:
    """``σ̃t`` on this rank's piece widened by ``extra`` points on every side (clamped to the
    whole extent), as the one-rank method has it there (collective over ``par.comm``;
    ``extra`` must be the same on every rank).

    ``σt`` is widened by ``extra`` plus :func:`ghost_levels_for` points, so the cube of every
    point of the widened piece lies in the block (or outside the whole volume, where both
    take 0). Parameters as :func:`distributed_ambient_extinction`.

    Returns
    -------
    sigma_tilde : ndarray float32
        ``σ̃t`` on ``ghosted``.
    ghosted : tuple of 6 int
        The widened extent.
    """
    whole_extent = tuple(int(v) for v in whole_extent)
    piece_extent = tuple(int(v) for v in piece_extent)
    data_extent = piece_extent if data_extent is None else tuple(int(v) for v in data_extent)
    decomposition = Decomposition.checked(whole_extent, piece_extent, par.rank, par.size,
                                          volume.dims, data_extent)
    if not _contains(data_extent, piece_extent):
        raise ValueError(f"the data extent {data_extent} does not hold the piece {piece_extent}")
    inner = decomposition.ghosted(par.rank, int(extra))
    ghosts = ghost_levels_for(radius, volume.spacing) + int(extra)
    ghosted = decomposition.ghosted(par.rank, ghosts)
    # The tables span the whole data range: ghost points included, every rank's range.
    value_range = global_value_range(volume, par.comm)
    medium = block_medium(volume, transfer_function, unit_distance, value_range, par.device)
    sigma_t = sigma_t_grid(medium, par.device).numpy()
    # Where every rank's pipeline delivered its ghosts, no messages; else all exchange (a
    # collective decision: a rank that skipped would leave its neighbours waiting).
    if all(par.comm.allgather(_contains(data_extent, ghosted))):
        widened = sigma_t[sub_slices(ghosted, data_extent)]
    else:
        own = np.ascontiguousarray(sigma_t[sub_slices(piece_extent, data_extent)])
        widened = halo_exchange(own, decomposition, par.rank, ghosts, par.comm)
    sigma_tilde = ambient_extinction(wp.array(widened, dtype=wp.float32, device=par.device),
                                     volume.spacing, radius, device=par.device).numpy()
    return np.ascontiguousarray(sigma_tilde[sub_slices(inner, ghosted)]), inner
