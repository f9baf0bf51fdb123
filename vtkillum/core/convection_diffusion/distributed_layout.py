"""Blocks of a grid over MPI ranks and their one-layer halo exchange (for the distributed
convection–diffusion, :mod:`~vtkillum.core.convection_diffusion.distributed`).

A :class:`Layout` is a global grid shape and one box per rank (``[lo, hi)`` point indices,
any boxes that tile the grid: a Cartesian split, or the recursive bisection of VTK's
extent translator). Each rank keeps its fields on its *ghosted box*, its block grown by one
point on every side (clipped to the grid), so that 7-point stencils and the convection's
upwind reads find their neighbours locally. Who sends what to whom is found by
intersecting boxes, so no neighbour structure is assumed: a block may touch several
blocks across one face.

mpi4py is imported only when a communicator is needed (``vtkillum.core`` must import on
machines without it).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import warp as wp


def mpi():
    """The ``mpi4py.MPI`` module (imported on first use)."""
    from mpi4py import MPI

    return MPI


def owner_blocks(shape, count: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """The ``[lo, hi)`` blocks of a grid of ``shape`` points that ranks own when it is split
    into ``count`` pieces the VTK way (``vtkExtentTranslator``, block mode; the shared
    boundary planes go to the lower piece's neighbour: :meth:`Decomposition.owner_extent`)."""
    from vtkillum.core.parallel import Decomposition

    whole = tuple(v for n in shape for v in (0, int(n) - 1))
    d = Decomposition.of(whole, count)
    return [extent_block(d.owner_extent(p)) for p in range(count)]


def extent_block(extent) -> tuple[np.ndarray, np.ndarray]:
    """A VTK extent ``(x0, x1, y0, y1, z0, z1)`` (inclusive; empty: ``x1 < x0``) as
    ``[lo, hi)``."""
    e = np.asarray(extent, dtype=np.int64).reshape(3, 2)
    lo, hi = e[:, 0], e[:, 1] + 1
    if np.any(hi <= lo):
        return np.zeros(3, np.int64), np.zeros(3, np.int64)
    return lo, hi


def split_blocks(shape, count: int, axis: int | None = None) -> list[tuple[np.ndarray, np.ndarray]]:
    """``count`` boxes tiling a grid of ``shape`` points: slabs along ``axis``, or (None)
    :func:`owner_blocks` (VTK's pieces)."""
    shape = np.asarray(shape, dtype=np.int64)
    if axis is not None:
        cuts = [int(v) for v in np.linspace(0, shape[axis], count + 1).round()]
        out = []
        for r in range(count):
            lo, hi = np.zeros(3, np.int64), shape.copy()
            lo[axis], hi[axis] = cuts[r], cuts[r + 1]
            out.append((lo, hi))
        return out

    return owner_blocks(shape, count)


def intersect(alo, ahi, blo, bhi):
    """``(lo, hi)`` of two boxes' intersection, or None when empty."""
    lo, hi = np.maximum(alo, blo), np.minimum(ahi, bhi)
    return (lo, hi) if np.all(hi > lo) else None


def region(lo, hi, origin) -> tuple:
    """Slices of box ``[lo, hi)`` in an array whose ``[0, 0, 0]`` is ``origin``."""
    return tuple(slice(int(a - o), int(b - o)) for a, b, o in zip(lo, hi, origin))


@dataclass
class Layout:
    """A grid of ``shape`` points split into one box per rank.

    Attributes
    ----------
    shape : (3,) int
        Global points per axis.
    blocks : list of (lo, hi)
        Rank ``r``'s points ``[lo, hi)`` (may be empty on coarse levels).
    rank : int
        This rank.
    ghosts : list of (lo, hi), optional
        Each rank's ghosted box; default its block grown by one point (clipped). A coarse
        multigrid level passes larger ones (what its fine block's prolongation reads).
    """

    shape: np.ndarray
    blocks: list
    rank: int
    ghosts: list = field(default=None, repr=False)

    def __post_init__(self) -> None:
        self.shape = np.asarray(self.shape, dtype=np.int64)
        self.blocks = [(np.asarray(lo, np.int64), np.asarray(hi, np.int64))
                       for lo, hi in self.blocks]
        count = sum(int(np.prod(np.maximum(hi - lo, 0))) for lo, hi in self.blocks
                    if np.all(hi > lo))
        if count != int(np.prod(self.shape)):
            raise ValueError(f"the blocks {[(lo.tolist(), hi.tolist()) for lo, hi in self.blocks]} "
                             f"do not tile a grid of {self.shape.tolist()} points")
        if self.ghosts is None:
            self.ghosts = [self._ghost(lo, hi) for lo, hi in self.blocks]
        self.ghosts = [(np.asarray(lo, np.int64), np.asarray(hi, np.int64))
                       for lo, hi in self.ghosts]

    def _ghost(self, lo, hi):
        if not np.all(hi > lo):
            return lo.copy(), lo.copy()
        return np.maximum(lo - 1, 0), np.minimum(hi + 1, self.shape)

    @property
    def lo(self) -> np.ndarray:
        return self.blocks[self.rank][0]

    @property
    def hi(self) -> np.ndarray:
        return self.blocks[self.rank][1]

    @property
    def empty(self) -> bool:
        return not np.all(self.hi > self.lo)

    def ghost(self, rank: int | None = None):
        """``(lo, hi)`` of a rank's ghosted box (its block and one layer around it)."""
        return self.ghosts[self.rank if rank is None else rank]

    @property
    def local_shape(self) -> tuple:
        """Shape of this rank's arrays (the ghosted box; at least one point per axis)."""
        glo, ghi = self.ghost()
        return tuple(max(int(v), 1) for v in ghi - glo)

    @property
    def block_shape(self) -> tuple:
        return tuple(int(v) for v in np.maximum(self.hi - self.lo, 0))

    def block_region(self) -> tuple:
        """Slices of this rank's block in its ghosted arrays."""
        return region(self.lo, self.hi, self.ghost()[0])


class Halo:
    """The one-layer halo exchange of a :class:`Layout`: every rank sends the part of its
    block inside each other rank's ghosted box, and receives the ghosts of its own."""

    def __init__(self, comm, layout: Layout) -> None:
        self.comm = comm
        self.layout = layout
        me = layout.rank
        glo, _ = layout.ghost()
        self.sends, self.recvs = [], []
        for q in range(len(layout.blocks)):
            if q == me:
                continue
            box = intersect(*layout.blocks[me], *layout.ghost(q))
            if box is not None:
                self.sends.append((q, region(*box, glo)))
            box = intersect(*layout.blocks[q], *layout.ghost())
            if box is not None:
                self.recvs.append((q, region(*box, glo)))

    def exchange(self, arr: wp.array, tag: int = 0) -> None:
        """Fill the ghosts of ``arr`` (this rank's ghosted array) from their owners."""
        exchange_regions(self.comm, arr, self.sends, self.recvs, tag)


def exchange_regions(comm, arr, sends, recvs, tag: int = 0) -> None:
    """Send ``arr[slices]`` to each ``(rank, slices)`` of ``sends`` and write what each
    ``(rank, slices)`` of ``recvs`` sends into ``arr[slices]`` (non-blocking, then wait)."""
    if not sends and not recvs:
        return
    requests, received = [], []
    comps = _components(arr)
    for q, sl in recvs:
        buf = np.empty(tuple(s.stop - s.start for s in sl) + comps, dtype=np.float32)
        requests.append(comm.Irecv(buf, source=q, tag=tag))
        received.append((sl, buf))
    outgoing = []
    for q, sl in sends:
        buf = read_region(arr, sl)
        outgoing.append(buf)
        requests.append(comm.Isend(buf, dest=q, tag=tag))
    mpi().Request.Waitall(requests)
    for sl, buf in received:
        write_region(arr, sl, buf)


def read_region(arr, sl) -> np.ndarray:
    """``arr[sl]`` as a contiguous host array (on the CPU through a numpy view)."""
    view = arr.numpy()[sl] if arr.device.is_cpu else arr[sl].numpy()
    return np.ascontiguousarray(view, dtype=np.float32)


def write_region(arr, sl, values) -> None:
    """``arr[sl] = values`` (on the CPU through a numpy view of the array)."""
    if arr.device.is_cpu:
        arr.numpy()[sl] = values
    else:
        arr[sl].assign(values)


def _components(arr) -> tuple:
    return (3,) if arr.dtype == wp.vec3 else ()
