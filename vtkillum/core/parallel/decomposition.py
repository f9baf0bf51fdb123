"""Pieces of a structured extent, split exactly as VTK's extent translator splits them.

ParaView's MPI engine hands rank ``p`` of ``n`` the extent that
``vtkExtentTranslator`` (block mode, VTK's default) gives piece ``p`` of ``n`` of the
whole extent. :func:`split_extent` reproduces that split in pure Python (no vtk: the
core must import without it), so a filter can pass the piece it was given straight to
the distributed core, and the core can work out every other rank's piece without
asking it.

Extents are VTK's: ``(x0, x1, y0, y1, z0, z1)`` in point indices, inclusive. Adjacent
pieces share their boundary plane of points (the cells are split, not the points), so a
point on a piece boundary belongs to two or more pieces; :func:`owner_extent` gives each
point one owner (the piece whose half-open extent contains it), which is what the halo
exchange copies from.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: The empty extent VTK returns for a piece with nothing in it.
EMPTY = (0, -1, 0, -1, 0, -1)


def split_extent(whole, piece: int, pieces: int, ghost_levels: int = 0) -> tuple:
    """Extent of ``piece`` of ``pieces`` of ``whole`` as ``vtkExtentTranslator`` splits it.

    Block mode (VTK's default): repeatedly halve the piece count, splitting the axis with
    the most cells (z before y before x on ties) at ``size * (n // 2) // n``; both halves
    keep the split plane of points. ``ghost_levels`` widens the result by that many
    points on every side, clamped to ``whole``. A piece that cannot be made (more pieces
    than cells) is :data:`EMPTY`.
    """
    whole = tuple(int(v) for v in whole)
    piece, pieces = int(piece), int(pieces)
    if not 0 <= piece < pieces:
        return EMPTY
    ext = list(whole)
    while pieces > 1:
        size = [ext[1] - ext[0], ext[3] - ext[2], ext[5] - ext[4]]
        if size[2] >= size[1] and size[2] >= size[0] and size[2] // 2 >= 1:
            axis = 2
        elif size[1] >= size[0] and size[1] // 2 >= 1:
            axis = 1
        elif size[0] // 2 >= 1:
            axis = 0
        else:
            if piece != 0:
                return EMPTY
            break
        first_half = pieces // 2
        mid = size[axis] * first_half // pieces + ext[2 * axis]
        if piece < first_half:
            ext[2 * axis + 1] = mid
            pieces = first_half
        else:
            ext[2 * axis] = mid
            pieces -= first_half
            piece -= first_half
    if ghost_levels > 0:
        for a in range(3):
            ext[2 * a] = max(whole[2 * a], ext[2 * a] - ghost_levels)
            ext[2 * a + 1] = min(whole[2 * a + 1], ext[2 * a + 1] + ghost_levels)
    return tuple(ext)


def is_empty(extent) -> bool:
    """Whether ``extent`` holds no point."""
    return any(extent[2 * a + 1] < extent[2 * a] for a in range(3))


def intersect(a, b) -> tuple:
    """Intersection of two extents (:data:`EMPTY`-like when they do not meet)."""
    out = []
    for axis in range(3):
        out += [max(a[2 * axis], b[2 * axis]), min(a[2 * axis + 1], b[2 * axis + 1])]
    return tuple(out) if not is_empty(out) else EMPTY


def extent_shape(extent) -> tuple[int, int, int]:
    """Points along x, y, z of an extent (0 for an empty one)."""
    if is_empty(extent):
        return (0, 0, 0)
    return tuple(int(extent[2 * a + 1] - extent[2 * a] + 1) for a in range(3))


def sub_slices(extent, within) -> tuple[slice, slice, slice]:
    """Index slices that cut ``extent`` out of an array laid over ``within`` ([i, j, k])."""
    return tuple(slice(extent[2 * a] - within[2 * a], extent[2 * a + 1] - within[2 * a] + 1)
                 for a in range(3))


@dataclass(frozen=True)
class Decomposition:
    """Every piece of ``whole`` split into ``pieces`` the VTK way.

    Attributes
    ----------
    whole : tuple of 6 int
        The whole extent.
    extents : tuple of extents
        ``extents[p]``: piece ``p``'s extent without ghosts (boundary planes shared).
    """

    whole: tuple
    extents: tuple

    @classmethod
    def of(cls, whole, pieces: int) -> Decomposition:
        """The decomposition of ``whole`` into ``pieces`` pieces."""
        whole = tuple(int(v) for v in whole)
        if is_empty(whole):
            raise ValueError(f"cannot split the empty extent {whole}")
        if pieces < 1:
            raise ValueError(f"pieces must be at least 1, got {pieces}")
        return cls(whole, tuple(split_extent(whole, p, pieces) for p in range(pieces)))

    @classmethod
    def checked(cls, whole, piece_extent, rank: int, size: int, dims, data_extent=None) \
            -> Decomposition:
        """The decomposition of ``whole`` into ``size`` pieces, after checking that rank
        ``rank`` holds VTK's piece ``rank`` (``piece_extent``) and that its volume of
        ``dims`` points covers ``data_extent`` (default the piece)."""
        decomposition = cls.of(whole, size)
        piece_extent = tuple(int(v) for v in piece_extent)
        if decomposition.extents[rank] != piece_extent:
            raise ValueError(f"rank {rank} of {size} holds extent {piece_extent}, but VTK's "
                             f"piece {rank} of {decomposition.whole} is "
                             f"{decomposition.extents[rank]}")
        data_extent = piece_extent if data_extent is None else \
            tuple(int(v) for v in data_extent)
        if tuple(dims) != extent_shape(data_extent):
            raise ValueError(f"the piece's volume has {tuple(dims)} points, its extent "
                             f"{data_extent} {extent_shape(data_extent)}")
        return decomposition

    @property
    def pieces(self) -> int:
        """Number of pieces."""
        return len(self.extents)

    def ghosted(self, piece: int, ghost_levels: int) -> tuple:
        """Piece ``piece`` widened by ``ghost_levels`` points, clamped to the whole extent."""
        return split_extent(self.whole, piece, self.pieces, ghost_levels) \
            if not is_empty(self.extents[piece]) else EMPTY

    def owner_extent(self, piece: int) -> tuple:
        """The points piece ``piece`` owns: its extent less the upper boundary planes it
        shares with a following piece (the whole extent's last plane stays).

        The owner extents tile the whole extent without overlap.
        """
        ext = list(self.extents[piece])
        if is_empty(ext):
            return EMPTY
        for a in range(3):
            if ext[2 * a + 1] < self.whole[2 * a + 1]:
                ext[2 * a + 1] -= 1
        return tuple(ext) if not is_empty(ext) else EMPTY

    def piece_of_point(self, ijk) -> int:
        """The piece that owns point ``ijk`` (see :meth:`owner_extent`)."""
        for p in range(self.pieces):
            e = self.owner_extent(p)
            if all(e[2 * a] <= ijk[a] <= e[2 * a + 1] for a in range(3)):
                return p
        raise ValueError(f"point {tuple(ijk)} is outside the whole extent {self.whole}")

    def face_contacts(self, piece: int, axis: int, side: int) -> list[tuple[int, tuple]]:
        """Pieces that share piece ``piece``'s boundary plane on ``axis``/``side``.

        ``side`` 0 is the low plane (``extent[2*axis]``), 1 the high one. Returns
        ``[(other piece, shared extent)]``: the other piece has the same plane as its
        opposite boundary, and ``shared extent`` is the rectangle of points (one plane
        thick) both hold. Empty on the whole extent's own boundary.
        """
        ext = self.extents[piece]
        plane = ext[2 * axis + side]
        if plane == self.whole[2 * axis + side]:
            return []
        mine = list(ext)
        mine[2 * axis] = mine[2 * axis + 1] = plane
        out = []
        for q, other in enumerate(self.extents):
            if q == piece or is_empty(other) or other[2 * axis + 1 - side] != plane:
                continue
            shared = intersect(mine, other)
            if not is_empty(shared):
                out.append((q, shared))
        return out

    def piece_boxes(self) -> np.ndarray:
        """``(pieces, 3, 2)`` int array: each piece's first and last point index per axis."""
        return np.asarray(self.extents, dtype=np.int64).reshape(-1, 3, 2)
