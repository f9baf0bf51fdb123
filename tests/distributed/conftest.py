"""Fixtures for the distributed core's tests, which run on every rank of
``mpirun -np N python -m pytest tests/distributed`` (and on one process without mpirun).

Every rank runs every test in the same order; a test's collective calls must be made on
all ranks, so checks go through :func:`all_ranks` (an assertion that fails on one rank
fails on all, instead of leaving the others waiting in the next collective).
"""

import os

import numpy as np
import pytest

os.environ.setdefault("VTKILLUM_DEVICE", "cpu")


@pytest.fixture(scope="session")
def par():
    """The :class:`~vtkillum.core.parallel.Parallel` of ``MPI_COMM_WORLD`` (one rank
    without mpi4py)."""
    from vtkillum.core.parallel import Parallel

    return Parallel.create()


def all_ranks(par, ok: bool, message: str = "") -> None:
    """Assert ``ok`` on every rank: fails everywhere when it fails on one rank."""
    oks = par.comm.allgather((bool(ok), message))
    bad = [(r, m) for r, (o, m) in enumerate(oks) if not o]
    assert not bad, "; ".join(f"rank {r}: {m}" for r, m in bad)


def max_abs(a, b) -> float:
    """Largest absolute difference (0 for empty arrays)."""
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    return float(np.abs(a - b).max()) if a.size else 0.0


def point_arrays(image) -> dict:
    """The point arrays of ``image`` as numpy, ghost markers left out."""
    from vtkillum.io.convert import point_array

    pd = image.GetPointData()
    return {pd.GetArrayName(i): point_array(image, pd.GetArrayName(i))
            for i in range(pd.GetNumberOfArrays()) if pd.GetArrayName(i) != "vtkGhostType"}


def whole_and_piece(whole_filter, piece_filter, par, ghosts: int):
    """Run ``whole_filter`` on the whole volume and ``piece_filter`` on this rank's piece
    with ``ghosts`` levels; returns ``(reference arrays, piece arrays, piece output, the
    extent it should have, the whole extent)``."""
    from vtkillum.core.parallel import split_extent

    whole_filter.Update()
    reference = whole_filter.GetOutputDataObject(0)
    whole = reference.GetExtent()
    piece_filter.UpdatePiece(par.rank, par.size, ghosts)
    out = piece_filter.GetOutputDataObject(0)
    want = split_extent(whole, par.rank, par.size, ghosts)
    return point_arrays(reference), point_arrays(out), out, want, whole
