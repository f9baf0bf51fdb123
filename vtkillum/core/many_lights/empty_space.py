"""Empty bricks for the AVSM construction: texel rays skip what is surely transparent.

The volume's blocks of :data:`~vtkillum.core.empty_space.BLOCK`³ cells are classified by
:mod:`vtkillum.core.empty_space` (a block is empty when its data range maps to σt = 0 in
the transfer function, so that every trilinear sample inside it has σt = 0). A march
may skip the samples inside an empty block and add nothing to the optical depth: the
maps are the same as with every sample taken (bit-identical in the tests; only a sample
that rounding puts a hair across a block face could mix in a neighbouring point, with a
weight of ~1e-7).

Texel rays from a VL inside a body cross the air around it for much of their length
(:func:`vtkillum.core.many_lights.avsm.build_kernel`).
"""

from __future__ import annotations

import warp as wp

from vtkillum.core.empty_space import BLOCK, block_ranges, occupancy
from vtkillum.core.warp_common import Medium, ray_box


@wp.struct
class EmptyBricks:
    """``occupied[bi, bj, bk]`` is 0 where block ``(bi, bj, bk)`` is exactly transparent;
    ``size`` is a block's extent (world units) and ``inv_size`` its inverse per axis."""

    occupied: wp.array3d(dtype=wp.int32)
    size: wp.vec3
    inv_size: wp.vec3


def empty_bricks(medium: Medium, spacing, device: str) -> EmptyBricks:
    """Classify the blocks of ``medium`` (its scalars and σt table) on ``device``.

    Parameters
    ----------
    medium : Medium
    spacing : sequence of 3 float
        Voxel spacing (world units) of ``medium.scalars``.
    device : str
    """
    out = EmptyBricks()
    out.occupied = occupancy(medium, block_ranges(medium.scalars, device), device)
    size = [BLOCK * float(h) for h in spacing]
    out.size = wp.vec3(*size)
    out.inv_size = wp.vec3(*[1.0 / s for s in size])
    return out


def no_bricks(device: str) -> EmptyBricks:
    """An :class:`EmptyBricks` with no empty block (marches sample every step)."""
    out = EmptyBricks()
    out.occupied = wp.ones((1, 1, 1), dtype=wp.int32, device=device)
    out.size = wp.vec3(1.0e30)
    out.inv_size = wp.vec3(0.0)
    return out


@wp.func
def brick_run(bricks: EmptyBricks, o: wp.vec3, d: wp.vec3, h: float, k: int):
    """Whether the ``k``-th midpoint sample ``o + (k + 1/2) h d`` lies in an empty block,
    and the last step ``>= k`` whose sample is still inside that block.

    Returns ``(empty, last)``, ``empty`` 1 or 0.
    """
    p = o + ((float(k) + 0.5) * h) * d
    bi = wp.clamp(int(wp.floor(p[0] * bricks.inv_size[0])), 0, bricks.occupied.shape[0] - 1)
    bj = wp.clamp(int(wp.floor(p[1] * bricks.inv_size[1])), 0, bricks.occupied.shape[1] - 1)
    bk = wp.clamp(int(wp.floor(p[2] * bricks.inv_size[2])), 0, bricks.occupied.shape[2] - 1)
    lo = wp.cw_mul(wp.vec3(float(bi), float(bj), float(bk)), bricks.size)
    t_exit = ray_box(o - lo, d, bricks.size)[1]
    # Last step whose midpoint (j + 1/2) h is before the exit (at least k: p is inside).
    last = wp.max(k, int(wp.ceil(t_exit / h - 0.5)) - 1)
    return 1 - wp.min(bricks.occupied[bi, bj, bk], 1), last
