"""The paper's diffusion operator ``A = I - sigma_hat_s laplace`` on a light grid (eq. 23).

Finite volumes, one control volume of size ``h`` per light-grid point, 7-point
stencil with ``c_a = sigma_hat_s / h_a**2`` per axis (RGB), no flux through the
box faces (Neumann). Shared by the solvers of
:mod:`~vtkillum.core.convection_diffusion.diffusion` and the hierarchy of
:mod:`~vtkillum.core.convection_diffusion.multigrid`: the stencil, the red–black
Gauss–Seidel smoother, ``A x`` and the residual.
"""

from __future__ import annotations

import numpy as np
import warp as wp


def axis_coefficients(scattering, spacing):
    """``sigma_hat_s / h_a**2`` per axis, as three RGB ``wp.vec3``."""
    s = np.asarray(scattering, dtype=np.float64)
    return [wp.vec3(*(s / float(h) ** 2).astype(np.float32)) for h in spacing]


def gauss_seidel(x: wp.array3d, b: wp.array3d, coeffs, sweeps: int, reverse: bool = False) -> None:
    """``sweeps`` red–black Gauss–Seidel sweeps of ``A x = b`` in place.

    ``reverse`` visits black before red (the post-smoother that makes a V-cycle symmetric).
    """
    nx, ny, nz = x.shape
    dim = (nx, ny, (nz + 1) // 2)
    colors = (1, 0) if reverse else (0, 1)
    for _ in range(int(sweeps)):
        for color in colors:
            wp.launch(red_black_kernel, dim=dim, device=x.device, inputs=[x, b, *coeffs, color])



# --- device functions ------------------------------------------------------------------------------

@wp.func
def neighbours(x: wp.array3d(dtype=wp.vec3), i: int, j: int, k: int, cx: wp.vec3, cy: wp.vec3,
               cz: wp.vec3):
    """Off-diagonal sum ``sum c_a x_nbr`` and diagonal ``1 + sum c_a`` over existing neighbours."""
    nx = x.shape[0]
    ny = x.shape[1]
    nz = x.shape[2]
    off = wp.vec3(0.0)
    diag = wp.vec3(1.0, 1.0, 1.0)
    if i > 0:
        off += wp.cw_mul(cx, x[i - 1, j, k])
        diag += cx
    if i < nx - 1:
        off += wp.cw_mul(cx, x[i + 1, j, k])
        diag += cx
    if j > 0:
        off += wp.cw_mul(cy, x[i, j - 1, k])
        diag += cy
    if j < ny - 1:
        off += wp.cw_mul(cy, x[i, j + 1, k])
        diag += cy
    if k > 0:
        off += wp.cw_mul(cz, x[i, j, k - 1])
        diag += cz
    if k < nz - 1:
        off += wp.cw_mul(cz, x[i, j, k + 1])
        diag += cz
    return off, diag


@wp.func
def diagonal(shape: wp.vec3i, i: int, j: int, k: int, cx: wp.vec3, cy: wp.vec3, cz: wp.vec3):
    """Diagonal of ``A`` at a point (``1 + sum c_a`` over its existing neighbours)."""
    d = wp.vec3(1.0, 1.0, 1.0)
    if i > 0:
        d += cx
    if i < shape[0] - 1:
        d += cx
    if j > 0:
        d += cy
    if j < shape[1] - 1:
        d += cy
    if k > 0:
        d += cz
    if k < shape[2] - 1:
        d += cz
    return d


@wp.func
def add_channels(acc: wp.array(dtype=wp.float64), offset: int, v: wp.vec3):
    wp.atomic_add(acc, offset + 0, wp.float64(v[0]))
    wp.atomic_add(acc, offset + 1, wp.float64(v[1]))
    wp.atomic_add(acc, offset + 2, wp.float64(v[2]))


# --- kernels -----------------------------------------------------------------------------------------
@wp.kernel
def red_black_kernel(x: wp.array3d(dtype=wp.vec3), b: wp.array3d(dtype=wp.vec3), cx: wp.vec3,
                     cy: wp.vec3, cz: wp.vec3, color: int):
    """Gauss–Seidel update of the points with ``(i + j + k) % 2 == color``.

    ``wp.tid() = (i, j, kk)``; the point is ``k = 2 kk + ((i + j + color) % 2)``.
    ``cx, cy, cz`` are ``sigma_hat_s / h**2`` (RGB) along x, y, z.
    """
    i, j, kk = wp.tid()
    k = 2 * kk + (i + j + color) % 2
    if k >= x.shape[2]:
        return
    off, diag = neighbours(x, i, j, k, cx, cy, cz)
    x[i, j, k] = wp.cw_div(b[i, j, k] + off, diag)


@wp.kernel
def apply_operator_kernel(x: wp.array3d(dtype=wp.vec3), y: wp.array3d(dtype=wp.vec3), cx: wp.vec3,
                          cy: wp.vec3, cz: wp.vec3):
    """``y = A x`` at point ``wp.tid() = (i, j, k)``."""
    i, j, k = wp.tid()
    off, diag = neighbours(x, i, j, k, cx, cy, cz)
    y[i, j, k] = wp.cw_mul(diag, x[i, j, k]) - off


@wp.kernel
def residual_field_kernel(x: wp.array3d(dtype=wp.vec3), b: wp.array3d(dtype=wp.vec3),
                          r: wp.array3d(dtype=wp.vec3), cx: wp.vec3, cy: wp.vec3, cz: wp.vec3):
    """``r = b - A x`` at point ``wp.tid() = (i, j, k)``."""
    i, j, k = wp.tid()
    off, diag = neighbours(x, i, j, k, cx, cy, cz)
    r[i, j, k] = b[i, j, k] - wp.cw_mul(diag, x[i, j, k]) + off


@wp.kernel
def residual_norm_kernel(x: wp.array3d(dtype=wp.vec3), b: wp.array3d(dtype=wp.vec3), cx: wp.vec3,
                         cy: wp.vec3, cz: wp.vec3, acc: wp.array(dtype=wp.float64)):
    """Add ``sum_i |b - A x|**2`` per channel of line ``wp.tid() = (j, k)`` to ``acc[0:3]``.

    Threads walk along x so that neighbouring threads read neighbouring k (coalesced).
    """
    j, k = wp.tid()
    s = wp.vec3(0.0)
    for i in range(x.shape[0]):
        off, diag = neighbours(x, i, j, k, cx, cy, cz)
        r = b[i, j, k] - wp.cw_mul(diag, x[i, j, k]) + off
        s += wp.cw_mul(r, r)
    add_channels(acc, 0, s)


@wp.kernel
def sum_squares_kernel(a: wp.array3d(dtype=wp.vec3), acc: wp.array(dtype=wp.float64)):
    """Add ``sum_i a**2`` per channel of line ``wp.tid() = (j, k)`` to ``acc[0:3]``."""
    j, k = wp.tid()
    s = wp.vec3(0.0)
    for i in range(a.shape[0]):
        s += wp.cw_mul(a[i, j, k], a[i, j, k])
    add_channels(acc, 0, s)
