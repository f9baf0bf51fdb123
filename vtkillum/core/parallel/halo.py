"""Ghost layers and face messages between the pieces of a decomposition.

Two tools, both on numpy blocks laid over VTK extents (index ``[i, j, k, ...]``, x
fastest-varying *last*: the project's ``[i, j, k]`` order) and both taking warp arrays
too (copied through the host; a CUDA-aware MPI could pass device pointers, which this
does not attempt):

* :func:`halo_exchange` -- collective: every rank hands in its piece's values and gets
  them back widened by ``ghost_levels`` points on every side (clamped to the whole
  extent), the ghost points filled from the pieces that own them. Works for any ghost
  width (several pieces away) and any piece layout the extent translator makes,
  corners and edges included.
* :class:`Mailbox` -- non-blocking point-to-point blocks for sweeps: post receives of
  faces from upstream pieces, send faces downstream, and take whichever arrives
  first. :func:`flow_faces` says which boundary planes of a piece a flow enters and
  leaves by, and which pieces are across them.

Messages carry one numpy array each, dtype and shape agreed on both sides beforehand
(every rank knows every piece's extent, :class:`~vtkillum.core.parallel.decomposition.
Decomposition`). Use a communicator of your own (``comm.Dup()``) if your messages may
overlap with someone else's in flight; :func:`halo_exchange` completes every message
before it returns.
"""

from __future__ import annotations

import numpy as np

from vtkillum.core.parallel.comm import world
from vtkillum.core.parallel.decomposition import (
    Decomposition,
    extent_shape,
    intersect,
    is_empty,
    sub_slices,
)

#: Tag of :func:`halo_exchange`'s messages (kept away from small user tags).
HALO_TAG = 7301


def _contains(outer, inner) -> bool:
    return all(outer[2 * a] <= inner[2 * a] and inner[2 * a + 1] <= outer[2 * a + 1]
               for a in range(3))


def halo_plan(decomposition: Decomposition, piece: int, ghost_levels: int):
    """Who sends what to whom in :func:`halo_exchange` for ``piece``.

    Returns ``(receive, send)``: lists of ``(other piece, extent)``. ``receive`` are the
    regions of ``piece``'s ghosted extent owned by another piece (and not already in
    ``piece``'s own extent); ``send`` the regions of other pieces' ghosted extents that
    ``piece`` owns. Both sides compute the same plan, so no sizes are exchanged.
    """
    d = decomposition
    mine = d.extents[piece]
    receive, send = [], []
    if ghost_levels <= 0 or is_empty(mine):
        return receive, send
    ghosted = d.ghosted(piece, ghost_levels)
    owned = d.owner_extent(piece)
    for q in range(d.pieces):
        if q == piece or is_empty(d.extents[q]):
            continue
        region = intersect(ghosted, d.owner_extent(q))
        if not is_empty(region) and not _contains(mine, region):
            receive.append((q, region))
        region = intersect(d.ghosted(q, ghost_levels), owned)
        if not is_empty(region) and not _contains(d.extents[q], region):
            send.append((q, region))
    return receive, send


def halo_exchange(local, decomposition: Decomposition, piece: int, ghost_levels: int,
                  comm=None, tag: int = HALO_TAG):
    """``local`` widened by ``ghost_levels`` points, the ghosts filled by their owners.

    Collective over ``comm``: every rank calls it with its own piece.

    Parameters
    ----------
    local : ndarray or warp array, shape (nx, ny, nz, ...)
        Values on ``decomposition.extents[piece]`` (index ``[i, j, k, ...]``); trailing
        axes (components) travel along.
    decomposition : Decomposition
        The piece layout (the same on every rank).
    piece : int
        This rank's piece (usually its rank).
    ghost_levels : int
        Points added on every side (clamped to the whole extent).
    comm : mpi4py communicator, optional
        Default ``MPI_COMM_WORLD``; piece ``q`` lives on rank ``q``.
    tag : int
        Message tag.

    Returns
    -------
    ndarray or warp array
        Values on ``decomposition.ghosted(piece, ghost_levels)``, same kind (and warp
        device) as ``local``. Points on a boundary plane shared with another piece keep
        ``local``'s values.
    """
    comm = world(comm)
    device = getattr(local, "device", None) if not isinstance(local, np.ndarray) else None
    host = np.ascontiguousarray(local.numpy() if device is not None else local)
    mine = decomposition.extents[piece]
    if host.shape[:3] != extent_shape(mine):
        raise ValueError(f"piece {piece} holds extent {mine} (points {extent_shape(mine)}), "
                         f"the array has shape {host.shape}")
    ghosted = decomposition.ghosted(piece, ghost_levels) if ghost_levels > 0 else mine
    out = np.zeros(extent_shape(ghosted) + host.shape[3:], dtype=host.dtype)
    receive, send = halo_plan(decomposition, piece, ghost_levels)
    requests, buffers = [], []
    for q, region in receive:
        buf = np.empty(extent_shape(region) + host.shape[3:], dtype=host.dtype)
        buffers.append((region, buf))
        requests.append(comm.Irecv(buf, source=q, tag=tag))
    for q, region in send:
        block = np.ascontiguousarray(host[sub_slices(region, mine)])
        buffers.append((None, block))  # kept alive until the send completes
        requests.append(comm.Isend(block, dest=q, tag=tag))
    if requests:
        _waitall(requests)
    for region, buf in buffers:
        if region is not None:
            out[sub_slices(region, ghosted)] = buf
    out[sub_slices(mine, ghosted)] = host
    if device is not None:
        import warp as wp

        return wp.array(out, dtype=local.dtype, device=device)
    return out


def _waitall(requests) -> None:
    from vtkillum.core.parallel.comm import mpi

    mpi().Request.Waitall(requests)


def flow_faces(decomposition: Decomposition, piece: int, velocity) -> tuple[list, list]:
    """Boundary planes by which a flow with ``velocity`` enters and leaves ``piece``.

    ``velocity`` is in index space (x, y, z components along i, j, k; only signs matter).
    A low plane on ``axis`` is an inflow when ``velocity[axis] > 0``, a high plane when it
    is ``< 0``; planes with a zero component are neither.

    Returns
    -------
    inflow, outflow : list of (axis, side, [(other piece, shared extent), ...])
        ``side`` 0: the low plane, 1: the high plane; the pieces across it and the
        rectangle of points shared with each (see
        :meth:`~vtkillum.core.parallel.decomposition.Decomposition.face_contacts`).
        Planes on the whole extent's boundary have no contacts and are left out.
    """
    inflow, outflow = [], []
    for axis in range(3):
        v = float(velocity[axis])
        if v == 0.0:
            continue
        for side in (0, 1):
            contacts = decomposition.face_contacts(piece, axis, side)
            if not contacts:
                continue
            entering = (side == 0) == (v > 0.0)
            (inflow if entering else outflow).append((axis, side, contacts))
    return inflow, outflow


class Mailbox:
    """Non-blocking sends and receives of numpy blocks, for sweeps across pieces.

    ::

        box = Mailbox(comm)
        box.expect(("face", light, axis), source=q, shape=(ny, nz), dtype=np.float32, tag=t)
        ...
        box.send(q2, block, tag=t2)                # returns at once; the block is kept
        key, block = box.next()                    # whichever expected block came first
        box.finish()                               # waits for every send

    Keys are yours; :meth:`next` returns them in arrival order, :meth:`wait` one by key.
    """

    def __init__(self, comm=None) -> None:
        self.comm = world(comm)
        self._recv_keys: list = []
        self._recv_reqs: list = []
        self._recv_bufs: list = []
        self._sends: list = []

    def expect(self, key, source: int, shape, dtype, tag: int) -> None:
        """Post a receive of a ``shape``/``dtype`` block from rank ``source`` with ``tag``."""
        buf = np.empty(tuple(int(s) for s in shape), dtype=dtype)
        self._recv_keys.append(key)
        self._recv_bufs.append(buf)
        self._recv_reqs.append(self.comm.Irecv(buf, source=source, tag=tag))

    def send(self, dest: int, block, tag: int) -> None:
        """Start sending ``block`` (copied to a contiguous host array) to rank ``dest``."""
        if not isinstance(block, np.ndarray):
            block = block.numpy()
        block = np.ascontiguousarray(block)
        self._sends.append((self.comm.Isend(block, dest=dest, tag=tag), block))
        self._reap_sends()

    @property
    def pending(self) -> int:
        """Receives posted and not yet returned."""
        return len(self._recv_reqs)

    def next(self):
        """``(key, block)`` of the first expected block to arrive (blocks until one does)."""
        if not self._recv_reqs:
            raise RuntimeError("no receive is pending")
        from vtkillum.core.parallel.comm import mpi

        index = mpi().Request.Waitany(self._recv_reqs)
        self._recv_reqs.pop(index)
        return self._recv_keys.pop(index), self._recv_bufs.pop(index)

    def wait(self, key):
        """The block expected under ``key`` (blocks until it arrives)."""
        index = self._recv_keys.index(key)
        self._recv_reqs.pop(index).Wait()
        return self._recv_keys.pop(index), self._recv_bufs.pop(index)

    def _reap_sends(self) -> None:
        self._sends = [(r, b) for r, b in self._sends if not r.Test()]

    def finish(self) -> None:
        """Wait for every send started (receives still pending are an error)."""
        if self._recv_reqs:
            raise RuntimeError(f"{len(self._recv_reqs)} expected blocks never taken")
        if self._sends:
            _waitall([r for r, _ in self._sends])
        self._sends = []
