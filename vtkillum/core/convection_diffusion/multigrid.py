"""Geometric multigrid for the light-volume diffusion ``(I - sigma_hat_s laplace) x = b``.

The operator is the finite-volume one of :mod:`~vtkillum.core.convection_diffusion.stencil` (one
cell per light-grid point, zero flux through the box). Multigrid treats the grid
as cell-centred, which works for any number of points (126 x 126 x 57 as well as
powers of two):

* Coarsening halves every axis with at least 4 cells (``n_c = ceil(n / 2)``);
  the coarse spacing keeps the box length, ``h_c = h n / n_c``. It stops once a
  grid has at most ``COARSEST_POINTS`` cells or no axis can be halved.
* Restriction: a coarse cell's right-hand side is the mean residual of its (up
  to 8) child cells, each child's residual computed in the restriction itself.
* Prolongation: trilinear interpolation between coarse cell centres (clamped at
  the box, i.e. the Neumann condition), added to the fine solution.
* Coarse operators are re-discretised with the coarse spacing.
* Smoothing: 2 red–black Gauss–Seidel sweeps before (red first) and 2 after
  (black first), so the cycle is symmetric.
* The coarsest grid is solved exactly with its inverse matrix (computed once on
  the host with numpy, applied by a dense matrix-vector kernel): no host round
  trip per cycle.

The identity term makes the problem well conditioned on coarse grids, so the
convergence per V-cycle does not degrade with resolution or ``sigma_hat_s``.
"""

from __future__ import annotations

import numpy as np
import warp as wp

from vtkillum.core.convection_diffusion.stencil import (
    axis_coefficients,
    gauss_seidel,
    neighbours,
)

#: Largest grid solved directly (cells). The dense solve is one thread per row, so a
#: smaller grid with one more level is faster: 512 cells took 0.25-0.39 ms of a 0.7-0.85 ms
#: V-cycle at 128³ on an H100 (16 warps, each thread a 512-long dot product), 64 cells a few
#: microseconds, the extra 8³ level some 30 µs.
COARSEST_POINTS = 64
#: Red–black sweeps before and after the coarse-grid correction.
PRE_SMOOTH = 2
POST_SMOOTH = 2


class Multigrid:
    """A grid hierarchy with its work arrays; :meth:`vcycle` improves a solution in place.

    Parameters
    ----------
    shape : (3,) int
        Finest grid (light-grid points per axis).
    spacing : (3,) float
        Finest spacing (world units).
    scattering : (3,) float
        ``sigma_hat_s`` per RGB channel (world units²).
    device : str
        Warp device.
    """

    def __init__(self, shape, spacing, scattering, device: str):
        self.device = device
        self.shapes = [tuple(int(n) for n in shape)]
        self.spacings = [np.asarray(spacing, dtype=np.float64)]
        while int(np.prod(self.shapes[-1])) > COARSEST_POINTS:
            n = np.asarray(self.shapes[-1])
            halve = n >= 4
            if not halve.any():
                break
            nc = np.where(halve, (n + 1) // 2, n)
            self.spacings.append(self.spacings[-1] * n / nc)
            self.shapes.append(tuple(int(v) for v in nc))
        self.coeffs = [axis_coefficients(scattering, h) for h in self.spacings]
        # Work arrays: solution and rhs on each coarse level.
        self.x = [None] + [wp.zeros(s, dtype=wp.vec3, device=device) for s in self.shapes[1:]]
        self.b = [None] + [wp.zeros(s, dtype=wp.vec3, device=device) for s in self.shapes[1:]]
        inverse = coarse_inverse(self.shapes[-1], self.spacings[-1], scattering)
        self.inverse = wp.array(inverse, dtype=wp.float32, device=device)

    @property
    def levels(self) -> int:
        return len(self.shapes)

    def vcycle(self, x: wp.array3d, b: wp.array3d, level: int = 0) -> None:
        """One V(2,2) cycle for ``A x = b`` on ``level`` (0 = finest), in place."""
        if level == self.levels - 1:
            wp.launch(dense_solve_kernel, dim=int(np.prod(self.shapes[level])),
                      device=self.device, inputs=[self.inverse, b, x])
            return
        coeffs = self.coeffs[level]
        gauss_seidel(x, b, coeffs, PRE_SMOOTH)
        xc, bc = self.x[level + 1], self.b[level + 1]
        ratio = wp.vec3i(*(np.asarray(self.shapes[level]) != np.asarray(self.shapes[level + 1]))
                         .astype(int) + 1)
        # the residual is only restricted: computed per child inside the restriction (no
        # residual field written and read back)
        wp.launch(residual_restrict_kernel, dim=self.shapes[level + 1], device=self.device,
                  inputs=[x, b, bc, *coeffs, ratio])
        xc.zero_()
        self.vcycle(xc, bc, level + 1)
        wp.launch(prolong_add_kernel, dim=self.shapes[level], device=self.device,
                  inputs=[xc, x, ratio])
        gauss_seidel(x, b, coeffs, POST_SMOOTH, reverse=True)


def coarse_inverse(shape, spacing, scattering) -> np.ndarray:
    """Inverse of the operator on a small grid, per channel: ``(3, N, N)`` float32."""
    n = int(np.prod(shape))
    lap = np.zeros((n, n))
    idx = np.arange(n).reshape(shape)
    for a in range(3):
        lo = np.take(idx, np.arange(shape[a] - 1), axis=a).ravel()
        hi = np.take(idx, np.arange(1, shape[a]), axis=a).ravel()
        w = 1.0 / float(spacing[a]) ** 2
        np.add.at(lap, (lo, lo), w)
        np.add.at(lap, (hi, hi), w)
        np.add.at(lap, (lo, hi), -w)
        np.add.at(lap, (hi, lo), -w)
    eye = np.eye(n)
    return np.stack([np.linalg.inv(eye + float(s) * lap) for s in scattering]).astype(np.float32)


# --- kernels -------------------------------------------------------------------------------------
@wp.kernel
def restrict_kernel(r: wp.array3d(dtype=wp.vec3), bc: wp.array3d(dtype=wp.vec3), ratio: wp.vec3i):
    """Coarse right-hand side at coarse cell ``wp.tid() = (I, J, K)``: mean of its children.

    ``ratio[a]`` is 2 where axis ``a`` was halved, else 1; children beyond an odd fine
    grid's end are skipped.
    """
    ci, cj, ck = wp.tid()
    bc[ci, cj, ck] = children_mean(r, ci, cj, ck, ratio)


@wp.func
def children_mean(a: wp.array3d(dtype=wp.vec3), ci: int, cj: int, ck: int, ratio: wp.vec3i):
    """Mean of ``a`` over the existing children of coarse cell ``(ci, cj, ck)``."""
    s = wp.vec3(0.0)
    count = float(0.0)
    shape = wp.vec3i(a.shape[0], a.shape[1], a.shape[2])
    for child in range(8):
        i, j, k, ok = child_of(ci, cj, ck, ratio, child, shape)
        if ok:
            s += a[i, j, k]
            count += 1.0
    return s / count


@wp.func
def child_of(ci: int, cj: int, ck: int, ratio: wp.vec3i, child: int, shape: wp.vec3i):
    """Fine cell ``child`` (0-7: ``(u, v, w) = (child >> 2, (child >> 1) & 1, child & 1)``
    along x, y, z) of coarse cell ``(ci, cj, ck)`` and whether it exists (``u < ratio[0]``
    etc., and inside a fine grid of ``shape``, which an odd grid's last coarse cell
    overhangs).

    Kernels visit the children in a constant loop ``for child in range(8)``, which warp
    unrolls (the bit operations then fold away): a child number split by run-time integer
    divisions by the ratios cost more than the coarse coefficients themselves.
    """
    u = child >> 2
    v = (child >> 1) & 1
    w = child & 1
    i = ci * ratio[0] + u
    j = cj * ratio[1] + v
    k = ck * ratio[2] + w
    ok = (u < ratio[0] and v < ratio[1] and w < ratio[2] and i < shape[0] and j < shape[1]
          and k < shape[2])
    return i, j, k, ok


@wp.kernel
def residual_restrict_kernel(x: wp.array3d(dtype=wp.vec3), b: wp.array3d(dtype=wp.vec3),
                             bc: wp.array3d(dtype=wp.vec3), cx: wp.vec3, cy: wp.vec3,
                             cz: wp.vec3, ratio: wp.vec3i):
    """:func:`restrict_kernel` of the residual ``b - A x``, each child's residual computed
    where it is summed (the values of ``residual_field_kernel`` then ``restrict_kernel``)."""
    ci, cj, ck = wp.tid()
    s = wp.vec3(0.0)
    count = float(0.0)
    shape = wp.vec3i(x.shape[0], x.shape[1], x.shape[2])
    for child in range(8):
        i, j, k, ok = child_of(ci, cj, ck, ratio, child, shape)
        if ok:
            off, diag = neighbours(x, i, j, k, cx, cy, cz)
            s += b[i, j, k] - wp.cw_mul(diag, x[i, j, k]) + off
            count += 1.0
    bc[ci, cj, ck] = s / count


@wp.func
def coarse_coordinate(i: int, ratio: int, n_coarse: int):
    """Cell-centre coordinate of fine cell ``i`` in coarse cell units, clamped to the grid."""
    if ratio == 1:
        return float(i)
    return wp.clamp((float(i) + 0.5) * 0.5 - 0.5, 0.0, float(n_coarse - 1))


@wp.kernel
def prolong_add_kernel(xc: wp.array3d(dtype=wp.vec3), x: wp.array3d(dtype=wp.vec3),
                       ratio: wp.vec3i):
    """Add the trilinearly interpolated coarse correction at fine cell ``wp.tid() = (i, j, k)``."""
    i, j, k = wp.tid()
    u = coarse_coordinate(i, ratio[0], xc.shape[0])
    v = coarse_coordinate(j, ratio[1], xc.shape[1])
    w = coarse_coordinate(k, ratio[2], xc.shape[2])
    i0 = wp.min(int(u), xc.shape[0] - 1)
    j0 = wp.min(int(v), xc.shape[1] - 1)
    k0 = wp.min(int(w), xc.shape[2] - 1)
    i1 = wp.min(i0 + 1, xc.shape[0] - 1)
    j1 = wp.min(j0 + 1, xc.shape[1] - 1)
    k1 = wp.min(k0 + 1, xc.shape[2] - 1)
    fu = u - float(i0)
    fv = v - float(j0)
    fw = w - float(k0)
    c00 = wp.lerp(xc[i0, j0, k0], xc[i1, j0, k0], fu)
    c10 = wp.lerp(xc[i0, j1, k0], xc[i1, j1, k0], fu)
    c01 = wp.lerp(xc[i0, j0, k1], xc[i1, j0, k1], fu)
    c11 = wp.lerp(xc[i0, j1, k1], xc[i1, j1, k1], fu)
    x[i, j, k] = x[i, j, k] + wp.lerp(wp.lerp(c00, c10, fv), wp.lerp(c01, c11, fv), fw)


@wp.kernel
def dense_solve_kernel(inverse: wp.array3d(dtype=wp.float32), b: wp.array3d(dtype=wp.vec3),
                       x: wp.array3d(dtype=wp.vec3)):
    """``x = A^-1 b`` on the coarsest grid; ``wp.tid()`` is the row (C-order flat index).

    ``inverse[c]`` is the inverse matrix of channel ``c``.
    """
    row = wp.tid()
    ny = b.shape[1]
    nz = b.shape[2]
    acc = wp.vec3(0.0)
    for col in range(inverse.shape[1]):
        bv = b[col // (ny * nz), (col // nz) % ny, col % nz]
        acc += wp.vec3(inverse[0, row, col] * bv[0], inverse[1, row, col] * bv[1],
                       inverse[2, row, col] * bv[2])
    x[row // (ny * nz), (row // nz) % ny, row % nz] = acc
