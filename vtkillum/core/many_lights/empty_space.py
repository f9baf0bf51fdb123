"""Empty bricks: where the transfer function makes the volume exactly transparent.

The volume's cells are grouped into bricks of :data:`BRICK` cells per axis. A brick is
*empty* when ``sigma_t`` is exactly 0 at every point a trilinear sample inside it can
produce: the data values of its points (one layer beyond each face included, so that a
sample that rounding puts just across a face reads only those points) span a
range whose σt-table entries, one entry either side, are all 0. Interpolating zeros
gives zero, so a march may skip the samples inside an empty brick and add nothing to the
optical depth: the result is bit-identical to sampling them.

The AVSM construction (:func:`vtkillum.core.many_lights.avsm.build_kernel`) uses this:
texel rays from a VL inside a body cross the air around it for much of their length.
"""

from __future__ import annotations

import warp as wp

from vtkillum.core.warp_common import Medium, ray_box, table_coord

#: Cells per brick edge.
BRICK = 8


@wp.struct
class EmptyBricks:
    """``empty[bi, bj, bk]`` is 1 where brick ``(bi, bj, bk)`` is exactly transparent;
    ``size`` is a brick's extent (world units) and ``inv_size`` its inverse per axis."""

    empty: wp.array3d(dtype=wp.uint8)
    size: wp.vec3
    inv_size: wp.vec3


def empty_bricks(medium: Medium, spacing, device: str) -> EmptyBricks:
    """Classify the bricks of ``medium`` (its scalars and σt table) on ``device``.

    Parameters
    ----------
    medium : Medium
    spacing : sequence of 3 float
        Voxel spacing (world units) of ``medium.scalars``.
    device : str
    """
    shape = medium.scalars.shape
    bricks = tuple(max(1, (n - 1 + BRICK - 1) // BRICK) for n in shape)
    out = EmptyBricks()
    out.empty = wp.empty(bricks, dtype=wp.uint8, device=device)
    wp.launch(classify_kernel, dim=bricks, inputs=[medium, BRICK, out.empty], device=device)
    size = [BRICK * float(h) for h in spacing]
    out.size = wp.vec3(*size)
    out.inv_size = wp.vec3(*[1.0 / s for s in size])
    return out


def no_bricks(device: str) -> EmptyBricks:
    """An :class:`EmptyBricks` with no empty brick (marches sample every step)."""
    out = EmptyBricks()
    out.empty = wp.zeros((1, 1, 1), dtype=wp.uint8, device=device)
    out.size = wp.vec3(1.0e30)
    out.inv_size = wp.vec3(0.0)
    return out


@wp.kernel
def classify_kernel(m: Medium, B: int, empty: wp.array3d(dtype=wp.uint8)):
    """One brick: 1 if σt is exactly 0 wherever a sample in it can land, else 0."""
    bi, bj, bk = wp.tid()
    nx = m.scalars.shape[0]
    ny = m.scalars.shape[1]
    nz = m.scalars.shape[2]
    lo = float(1.0e30)
    hi = float(-1.0e30)
    for i in range(wp.max(bi * B - 1, 0), wp.min(bi * B + B + 1, nx - 1) + 1):
        for j in range(wp.max(bj * B - 1, 0), wp.min(bj * B + B + 1, ny - 1) + 1):
            for k in range(wp.max(bk * B - 1, 0), wp.min(bk * B + B + 1, nz - 1) + 1):
                s = m.scalars[i, j, k]
                lo = wp.min(lo, s)
                hi = wp.max(hi, s)
    x0 = table_coord(m, lo)
    x1 = table_coord(m, hi)
    n = m.sigma_table.shape[0]
    first = wp.max(int(wp.floor(wp.min(x0, x1))) - 1, 0)
    last = wp.min(int(wp.ceil(wp.max(x0, x1))) + 1, n - 1)
    flag = int(1)
    for t in range(first, last + 1):
        if m.sigma_table[t] != 0.0:
            flag = 0
    empty[bi, bj, bk] = wp.uint8(flag)


@wp.func
def brick_run(bricks: EmptyBricks, o: wp.vec3, d: wp.vec3, h: float, k: int):
    """Whether the ``k``-th midpoint sample ``o + (k + 1/2) h d`` lies in an empty brick,
    and the last step ``>= k`` whose sample is still inside that brick.

    Returns ``(empty, last)``, ``empty`` 1 or 0.
    """
    p = o + ((float(k) + 0.5) * h) * d
    bi = wp.clamp(int(wp.floor(p[0] * bricks.inv_size[0])), 0, bricks.empty.shape[0] - 1)
    bj = wp.clamp(int(wp.floor(p[1] * bricks.inv_size[1])), 0, bricks.empty.shape[1] - 1)
    bk = wp.clamp(int(wp.floor(p[2] * bricks.inv_size[2])), 0, bricks.empty.shape[2] - 1)
    lo = wp.cw_mul(wp.vec3(float(bi), float(bj), float(bk)), bricks.size)
    t_exit = ray_box(o - lo, d, bricks.size)[1]
    # Last step whose midpoint (j + 1/2) h is before the exit (at least k: p is inside).
    last = wp.max(k, int(wp.ceil(t_exit / h - 0.5)) - 1)
    return int(bricks.empty[bi, bj, bk]), last
