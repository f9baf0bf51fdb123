"""Empty-space classification: which blocks of a volume are surely transparent.

The volume's cells are grouped into blocks of ``BLOCK`` × ``BLOCK`` × ``BLOCK``
cells. A block is *empty* when the extinction is 0 everywhere inside it. With
post-classification (the transfer function applied to the trilinearly
interpolated value) this is decided by the block's data range, not by σt at
its points: every value between the block's minimum and maximum can occur, so
the block is empty only if the transfer function has ``σt = 0`` on that whole
range. The range per block depends on the data only (computed once); the
emptiness test per transfer function is O(1) per block with a prefix count of
the non-zero entries of the σt lookup table.

Every :class:`~vtkillum.core.warp_common.Medium` carries its blocks' occupancy
(:func:`vtkillum.core.warp_common.attach_occupancy`): shadow rays
(:func:`~vtkillum.core.warp_common.shadow_transmittance`) and the AVSM construction of the
many-lights method skip the samples of empty blocks, which would add exactly 0 to their
optical depth; the ambient gather leaps over them (:mod:`vtkillum.core.ambient.gather`).
A sample that rounding puts a hair across a block face could mix in a point of the
neighbouring block with a weight of ~1e-7; otherwise the results are bit-identical.
"""

from __future__ import annotations

import numpy as np
import warp as wp

from vtkillum.core.device import init_warp, resolve_device
from vtkillum.core.warp_common import Medium, table_coord

init_warp()

#: Cells per block edge.
BLOCK = 8


def block_ranges(scalars, device: str | None = None):
    """Minimum and maximum data value per block: wp.array4d(float32) ``(bx, by, bz, 2)``.

    ``scalars`` is the device copy of the volume ``(nx, ny, nz)``; block ``b`` covers
    points ``BLOCK * b .. BLOCK * (b + 1)`` (inclusive: the cells' corner points).
    """
    device = resolve_device(device)
    shape = block_shape(scalars.shape)
    out = wp.empty(shape + (2,), dtype=wp.float32, device=device)
    wp.launch(block_range_kernel, dim=shape, inputs=[scalars, BLOCK, out], device=device)
    return out


def block_shape(dims) -> tuple:
    """Blocks per axis for a grid of ``dims`` points."""
    return tuple(max(1, -(-(int(n) - 1) // BLOCK)) for n in dims)


def occupancy(medium: Medium, ranges, device: str | None = None, sigma_table=None):
    """1 for blocks where σt may be non-zero, 0 for surely empty ones: wp.array3d(int32).

    Parameters
    ----------
    medium : Medium
        Gives the σt lookup table and its data-value mapping.
    ranges : wp.array4d(float32)
        From :func:`block_ranges`.
    sigma_table : ndarray, optional
        A host copy of ``medium.sigma_table`` (saves the download).
    """
    device = resolve_device(device)
    sig = medium.sigma_table.numpy() if sigma_table is None else np.asarray(sigma_table)
    nonzero = np.concatenate([[0], np.cumsum(sig > 0)]).astype(np.int32)  # prefix counts
    counts = wp.array(nonzero, dtype=wp.int32, device=device)
    shape = tuple(ranges.shape[:3])
    out = wp.empty(shape, dtype=wp.int32, device=device)
    wp.launch(occupancy_kernel, dim=shape, inputs=[medium, ranges, counts, out], device=device)
    return out


@wp.kernel
def block_range_kernel(scalars: wp.array3d(dtype=wp.float32), block: int,
                       out: wp.array4d(dtype=wp.float32)):
    """``wp.tid()`` = block ``(bi, bj, bk)``; writes the min and max of its points."""
    bi, bj, bk = wp.tid()
    lo = float(1.0e30)
    hi = float(-1.0e30)
    i1 = wp.min(block * (bi + 1), scalars.shape[0] - 1)
    j1 = wp.min(block * (bj + 1), scalars.shape[1] - 1)
    k1 = wp.min(block * (bk + 1), scalars.shape[2] - 1)
    for i in range(block * bi, i1 + 1):
        for j in range(block * bj, j1 + 1):
            for k in range(block * bk, k1 + 1):
                v = scalars[i, j, k]
                lo = wp.min(lo, v)
                hi = wp.max(hi, v)
    out[bi, bj, bk, 0] = lo
    out[bi, bj, bk, 1] = hi


@wp.kernel
def occupancy_kernel(m: Medium, ranges: wp.array4d(dtype=wp.float32),
                     nonzero: wp.array(dtype=wp.int32), out: wp.array3d(dtype=wp.int32)):
    """``wp.tid()`` = block; 1 if the σt table has a non-zero entry over the block's range.

    The table is interpolated linearly, so the entries bracketing the range count
    (``floor`` of the low end to ``ceil`` of the high end).
    """
    bi, bj, bk = wp.tid()
    lo = int(wp.floor(table_coord(m, ranges[bi, bj, bk, 0])))
    hi = wp.min(int(wp.ceil(table_coord(m, ranges[bi, bj, bk, 1]))), m.sigma_table.shape[0] - 1)
    # nonzero[i] = number of non-zero entries among the first i
    out[bi, bj, bk] = wp.where(nonzero[hi + 1] - nonzero[lo] > 0, 1, 0)


def block_sigma_max(medium: Medium, ranges, device: str | None = None):
    """Largest σt that may occur in each block **or its 26 neighbours**: wp.array3d(float32).

    With post-classification every value of a block's data range can occur in it, so its
    largest σt is the table's maximum over that range (entries bracketing the range, as
    :func:`occupancy_kernel` counts them): the maxima of the whole :data:`CHUNK`-entry
    chunks inside the range (kept per transfer function, one small array) and the entries
    of the partial chunks at its ends, so a block reads at most ``2 CHUNK + n / CHUNK``
    values. The neighbours' maximum is taken as well, so the bound holds within one block
    of any point of the block: what the ray caster needs to decide that the exact
    near-field march of a shadow ray (a few voxels long) cannot change its transmittance
    by more than a set amount (:func:`vtkillum.core.raycast.cached_transmittance`).
    """
    device = resolve_device(device)
    n = int(medium.sigma_table.shape[0])
    chunks = wp.empty(max(1, -(-n // CHUNK)), dtype=wp.float32, device=device)
    wp.launch(chunk_max_kernel, dim=chunks.shape[0], inputs=[medium.sigma_table, chunks],
              device=device)
    shape = tuple(ranges.shape[:3])
    own = wp.empty(shape, dtype=wp.float32, device=device)
    wp.launch(block_sigma_max_kernel, dim=shape, inputs=[medium, ranges, chunks, own],
              device=device)
    out = wp.empty(shape, dtype=wp.float32, device=device)
    wp.launch(dilate_max_kernel, dim=shape, inputs=[own, out], device=device)
    return out


#: Table entries per chunk of :func:`block_sigma_max`'s chunk maxima.
CHUNK = wp.constant(64)


@wp.kernel
def chunk_max_kernel(table: wp.array(dtype=wp.float32), out: wp.array(dtype=wp.float32)):
    """``out[c] = max(table[c CHUNK : (c + 1) CHUNK])``; ``wp.tid()`` is the chunk."""
    c = wp.tid()
    v = float(0.0)
    for i in range(c * CHUNK, wp.min((c + 1) * CHUNK, table.shape[0])):
        v = wp.max(v, table[i])
    out[c] = v


@wp.kernel
def block_sigma_max_kernel(m: Medium, ranges: wp.array4d(dtype=wp.float32),
                           chunks: wp.array(dtype=wp.float32),
                           out: wp.array3d(dtype=wp.float32)):
    """``wp.tid()`` = block; the σt table's maximum over the entries bracketing its range
    (1/world units): whole chunks from ``chunks``, partial ones entry by entry."""
    bi, bj, bk = wp.tid()
    lo = int(wp.floor(table_coord(m, ranges[bi, bj, bk, 0])))
    hi = wp.min(int(wp.ceil(table_coord(m, ranges[bi, bj, bk, 1]))), m.sigma_table.shape[0] - 1)
    v = float(0.0)
    i = lo
    while i <= hi:
        if i % CHUNK == 0 and i + CHUNK - 1 <= hi:
            v = wp.max(v, chunks[i // CHUNK])
            i += CHUNK
        else:
            v = wp.max(v, m.sigma_table[i])
            i += 1
    out[bi, bj, bk] = v


@wp.kernel
def dilate_max_kernel(src: wp.array3d(dtype=wp.float32), out: wp.array3d(dtype=wp.float32)):
    """``out[b] = max of src over b's 3x3x3 neighbourhood`` (clipped at the borders)."""
    bi, bj, bk = wp.tid()
    v = float(0.0)
    for di in range(-1, 2):
        for dj in range(-1, 2):
            for dk in range(-1, 2):
                i = bi + di
                j = bj + dj
                k = bk + dk
                if i >= 0 and j >= 0 and k >= 0 and i < src.shape[0] and j < src.shape[1] \
                        and k < src.shape[2]:
                    v = wp.max(v, src[i, j, k])
    out[bi, bj, bk] = v
