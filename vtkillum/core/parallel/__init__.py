"""Distributed ground for the illumination methods: ranks, pieces, ghosts, faces.

numpy + warp + mpi4py (imported lazily: the package imports without it, and a single
process runs the distributed functions on one rank). The pieces are VTK's
(:mod:`~vtkillum.core.parallel.decomposition`), so a filter under ParaView's MPI engine
passes the piece it was asked for straight in.

* :mod:`~vtkillum.core.parallel.comm` -- the communicator (``MPI_COMM_WORLD`` or one
  given) and one warp device per rank (``cuda:<local rank>``, else ``cpu``).
* :mod:`~vtkillum.core.parallel.decomposition` -- :func:`split_extent` (exactly
  ``vtkExtentTranslator``'s block split) and :class:`Decomposition`.
* :mod:`~vtkillum.core.parallel.halo` -- :func:`halo_exchange` (ghost layers of any
  width) and :class:`Mailbox` / :func:`flow_faces` (face messages for sweeps).
* :mod:`~vtkillum.core.parallel.transmittance` -- the distributed ``transmittance``: a
  pipelined sweep across ranks in each light's order.
"""

from vtkillum.core.parallel.comm import Parallel, SelfComm, local_rank, rank_device, world
from vtkillum.core.parallel.decomposition import (
    EMPTY,
    Decomposition,
    extent_shape,
    intersect,
    is_empty,
    split_extent,
    sub_slices,
)
from vtkillum.core.parallel.halo import Mailbox, flow_faces, halo_exchange, halo_plan

__all__ = [
    "EMPTY", "Decomposition", "Mailbox", "Parallel", "SelfComm", "extent_shape", "flow_faces",
    "halo_exchange", "halo_plan", "intersect", "is_empty", "local_rank", "rank_device",
    "split_extent", "sub_slices", "world",
]
