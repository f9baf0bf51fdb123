"""Ambient extinction volume ``σ̃t`` from a 3D summed-area table (Ament et al. 2013, eqs. 12–13).

``σ̃t(x)`` is the mean extinction in the sphere ``S_r(x)``; as in the paper the
sphere is replaced by the axis-aligned cube ``C_r(x)`` of the same volume
(side ``(4π/3)^(1/3) r ≈ 1.612 r``), whose integral a summed-area table (SAT)
gives in constant time for any ``r``.

Discretisation
--------------
``σt`` is taken at the grid points (the transfer function applied to each data
value) and treated as constant over each point's dual cell
``[i - 1/2, i + 1/2]³`` (voxel units), and as 0 outside the volume (empty space
around the data, as the renderers assume). Then

    σ̃t(x_ijk) = (1 / V) ∫_{C_r(x_ijk)} σt dV,    V = (2h)³ the cube's volume,

with half-width ``h = (π/6)^(1/3) r`` per axis in voxels (``r / spacing`` per
axis when ``r`` is in world units, so anisotropic grids get a true cube). The
cube's faces need not fall on cell faces: the exclusive SAT ``S[a, b, c] =
Σ_{i<a, j<b, k<c} σt`` interpolated trilinearly at a fractional corner is
*exactly* the integral of the piecewise-constant field up to that corner (the
integral is multilinear inside a cell), so the eight-corner inclusion–exclusion
of interpolated SAT values is the exact cube integral for any real ``r``. Near
the border the part of the cube outside the volume contributes 0 and ``V`` is
still the full cube volume (paper eq. 13 divides by ``V_s`` too).

Precision: the SAT is accumulated and stored in float64 (its corner values reach
``N σt`` for ``N`` voxels, 8·10⁷ at 432³; float32 would lose the cube sums of thin
regions in the rounding of those large numbers). ``σ̃t`` itself is float32.

Separable evaluation (the default): the cube is a product of intervals and ``σt`` is
constant per cell, so the cube integral is separable, ``Σ_ijk wx_i wy_j wz_k σt_ijk``
with the 1D overlap weights ``w``. :func:`ambient_extinction` therefore computes it by
three 1D passes (:func:`box_pass`), each one thread per grid line that walks the line
once, keeping in float64 registers the running sums up to the window's two fractional
ends: the same integral the SAT's eight interpolated corners give (equal within float
rounding, ``tests/core/test_ambient_sat.py``), with no float64 table. Each pass reads
two values and writes one per point (12 bytes), against the SAT's fill, three prefix
passes and 64 float64 corner reads per point: at 1024³ on an H200 the SAT and the cube
means took 94 + 244 ms of a 415 ms transfer-function edit. A table given as ``sat``
(e.g. kept to try many radii) is still used as before.
"""

from __future__ import annotations

import numpy as np
import warp as wp

from vtkillum.core.device import init_warp, resolve_device
from vtkillum.core.warp_common import Medium, grid_index, lookup_sigma_t

init_warp()

#: Half-width of the cube of a sphere's volume, per unit radius: (π/6)^(1/3).
CUBE_HALF_WIDTH = float((np.pi / 6.0) ** (1.0 / 3.0))


def ambient_extinction(sigma_t, spacing, radius: float, device: str | None = None,
                       sat=None):
    """The ambient extinction volume ``σ̃t`` on the grid of ``sigma_t``.

    Parameters
    ----------
    sigma_t : ndarray (nx, ny, nz) or wp.array3d(float32)
        Extinction at the grid points (1/world units), indexed ``[i, j, k]``.
    spacing : (3,) float
        Grid spacing (world units).
    radius : float
        Sphere radius ``r`` in world units.
    device : str, optional
        Warp device (where ``sigma_t`` lives, if it is a warp array).
    sat : wp.array3d(float64), optional
        A summed-area table of ``sigma_t`` from :func:`summed_area_table`, to reuse
        it when only the radius changes.

    Returns
    -------
    wp.array3d(float32)
        ``σ̃t`` at each grid point (1/world units), on ``device``.
    """
    device = resolve_device(device)
    sig = _as_device_grid(sigma_t, device)
    h = cube_half_width(radius, spacing)
    out = wp.empty(sig.shape, dtype=wp.float32, device=device)
    if sat is not None:
        wp.launch(cube_mean_kernel, dim=sig.shape, inputs=[sat, wp.vec3d(*h), out],
                  device=device)
        return out
    # three separable passes: x into out, y into a temporary, z back into out (scaled)
    tmp = wp.empty(sig.shape, dtype=wp.float32, device=device)
    box_pass(sig, out, 0, h[0], 1.0, device)
    box_pass(out, tmp, 1, h[1], 1.0, device)
    box_pass(tmp, out, 2, h[2], 1.0 / (8.0 * h[0] * h[1] * h[2]), device)
    return out


def box_pass(src, dst, axis: int, half: float, scale: float, device: str) -> None:
    """``dst = scale ·`` the integral of ``src`` (constant per cell) over ``[i - half, i +
    half]`` along ``axis`` (voxels; 0 outside the grid), for every point ``i`` of every line.

    One thread per line along ``axis``; ``src`` and ``dst`` may not be the same array.
    """
    shape = tuple(int(n) for n in src.shape)
    if axis == 2 and 2.0 * half + 2.0 <= WINDOW_READS:
        # Along the contiguous axis a thread per line reads a different line per warp lane
        # (uncoalesced); a thread per point summing its short window reads neighbours.
        wp.launch(box_window_kernel, dim=shape, inputs=[src, dst, float(half), float(scale)],
                  device=device)
        return
    lines = tuple(n for a, n in enumerate(shape) if a != axis)
    wp.launch(box_pass_kernel, dim=lines,
              inputs=[src, dst, int(axis), float(half), float(scale)], device=device)


#: Longest window (cells) summed point by point along the contiguous axis (:func:`box_pass`).
WINDOW_READS = 64


def cube_half_width(radius: float, spacing) -> np.ndarray:
    """Half-width (voxels, per axis) of the cube with the volume of a sphere of ``radius``.

    ``radius`` is in world units; the result is ``(π/6)^(1/3) radius / spacing``.
    """
    radius = float(radius)
    if not (np.isfinite(radius) and radius > 0):
        raise ValueError(f"the ambient radius must be positive and finite, got {radius}")
    sp = np.asarray(spacing, dtype=np.float64).reshape(3)
    return CUBE_HALF_WIDTH * radius / sp


def summed_area_table(sigma_t, device: str | None = None):
    """Exclusive 3D summed-area table in float64, shape ``(nx + 1, ny + 1, nz + 1)``.

    ``S[a, b, c] = Σ_{i<a, j<b, k<c} sigma_t[i, j, k]``; the first plane of each axis is 0.
    Built as three prefix-sum passes, one thread per grid line.
    """
    device = resolve_device(device)
    sig = _as_device_grid(sigma_t, device)
    nx, ny, nz = sig.shape
    sat = wp.zeros((nx + 1, ny + 1, nz + 1), dtype=wp.float64, device=device)
    wp.launch(sat_fill_kernel, dim=sig.shape, inputs=[sig, sat], device=device)
    wp.launch(sat_prefix_x_kernel, dim=(ny + 1, nz + 1), inputs=[sat], device=device)
    wp.launch(sat_prefix_y_kernel, dim=(nx + 1, nz + 1), inputs=[sat], device=device)
    wp.launch(sat_prefix_z_kernel, dim=(nx + 1, ny + 1), inputs=[sat], device=device)
    return sat


def sigma_t_grid(medium: Medium, device: str | None = None):
    """``σt`` of the transfer function at every grid point of ``medium``: wp.array3d(float32)."""
    device = resolve_device(device)
    out = wp.empty(medium.scalars.shape, dtype=wp.float32, device=device)
    wp.launch(sigma_t_grid_kernel, dim=medium.scalars.shape, inputs=[medium, out], device=device)
    return out


def cube_mean_reference(sigma_t: np.ndarray, spacing, radius: float) -> np.ndarray:
    """Brute-force ``σ̃t`` in numpy (for tests): explicit overlap weights of every cell.

    Each cell ``[i - 1/2, i + 1/2]`` overlaps the cube ``[c - h, c + h]`` by
    ``max(0, min(i + 1/2, c + h) - max(i - 1/2, c - h))`` per axis; the mean is the
    weighted sum over all cells divided by ``(2h)³``. O(n⁶): small volumes only.
    """
    s = np.asarray(sigma_t, dtype=np.float64)
    h = cube_half_width(radius, spacing)
    weights = []
    for axis, n in enumerate(s.shape):
        c = np.arange(n)[:, None]
        i = np.arange(n)[None, :]
        w = np.minimum(i + 0.5, c + h[axis]) - np.maximum(i - 0.5, c - h[axis])
        weights.append(np.maximum(w, 0.0))
    wx, wy, wz = weights
    total = np.einsum("ai,bj,ck,ijk->abc", wx, wy, wz, s, optimize=True)
    return total / np.prod(2 * h)


def _as_device_grid(sigma_t, device: str):
    if isinstance(sigma_t, wp.array):
        if sigma_t.ndim != 3:
            raise ValueError(f"sigma_t must be a 3D grid, got {sigma_t.ndim} dimensions")
        return sigma_t
    a = np.asarray(sigma_t, dtype=np.float32)
    if a.ndim != 3 or min(a.shape) < 1:
        raise ValueError(f"sigma_t must be a 3D array (nx, ny, nz), got shape {a.shape}")
    if not np.all(np.isfinite(a)) or np.any(a < 0):
        raise ValueError("sigma_t must be finite and non-negative")
    return wp.array(np.ascontiguousarray(a), dtype=wp.float32, device=device)


# --- kernels --------------------------------------------------------------------------------------
@wp.kernel
def sigma_t_grid_kernel(m: Medium, out: wp.array3d(dtype=wp.float32)):
    """``wp.tid()`` = grid point ``(i, j, k)``; writes σt (1/world units) of its data value."""
    i, j, k = wp.tid()
    out[i, j, k] = lookup_sigma_t(m, m.scalars[i, j, k])


@wp.kernel
def sat_fill_kernel(sig: wp.array3d(dtype=wp.float32), sat: wp.array3d(dtype=wp.float64)):
    """``wp.tid()`` = grid point ``(i, j, k)``; copies σt to ``sat[i+1, j+1, k+1]`` (float64)."""
    i, j, k = wp.tid()
    sat[i + 1, j + 1, k + 1] = wp.float64(sig[i, j, k])


@wp.kernel
def sat_prefix_x_kernel(sat: wp.array3d(dtype=wp.float64)):
    """``wp.tid()`` = ``(b, c)``: running sum along x of line ``sat[:, b, c]``."""
    b, c = wp.tid()
    acc = wp.float64(0.0)
    for a in range(sat.shape[0]):
        acc += sat[a, b, c]
        sat[a, b, c] = acc


@wp.kernel
def sat_prefix_y_kernel(sat: wp.array3d(dtype=wp.float64)):
    """``wp.tid()`` = ``(a, c)``: running sum along y of line ``sat[a, :, c]``."""
    a, c = wp.tid()
    acc = wp.float64(0.0)
    for b in range(sat.shape[1]):
        acc += sat[a, b, c]
        sat[a, b, c] = acc


@wp.kernel
def sat_prefix_z_kernel(sat: wp.array3d(dtype=wp.float64)):
    """``wp.tid()`` = ``(a, b)``: running sum along z of line ``sat[a, b, :]``."""
    a, b = wp.tid()
    acc = wp.float64(0.0)
    for c in range(sat.shape[2]):
        acc += sat[a, b, c]
        sat[a, b, c] = acc


@wp.func
def line_sum(src: wp.array3d(dtype=wp.float32), axis: int, u: int, v: int, count: int):
    """Sum (float64) of the first ``count`` points of the line ``(u, v)`` along ``axis``."""
    acc = wp.float64(0.0)
    for j in range(count):
        p = grid_index(axis, j, u, v)
        acc += wp.float64(src[p[0], p[1], p[2]])
    return acc


@wp.kernel
def box_pass_kernel(src: wp.array3d(dtype=wp.float32), dst: wp.array3d(dtype=wp.float32),
                    axis: int, half: float, scale: float):
    """One line of :func:`box_pass`; ``wp.tid()`` = the line's indices along the other axes.

    Cell ``j`` spans line coordinate ``[j, j + 1]`` (point ``j`` at its centre ``j + 1/2``).
    With ``P(x) = ∫_0^x`` of the cell-constant line, point ``i``'s window is
    ``P(i + 1/2 + half) - P(i + 1/2 - half)``. Both ends advance one cell per point, so
    ``P`` at each is a running sum (float64) of the cells entirely before it plus the
    fraction of the cell it lies in (constant along the line); ends outside ``[0, n]`` see
    0 before the line and the whole line after it.
    """
    u, v = wp.tid()
    n = src.shape[axis]
    ends = wp.vec2d(wp.float64(0.5) - wp.float64(half), wp.float64(0.5) + wp.float64(half))
    lo_floor = wp.floor(ends[0])
    hi_floor = wp.floor(ends[1])
    m_lo = int(lo_floor)
    m_hi = int(hi_floor)
    f_lo = ends[0] - lo_floor
    f_hi = ends[1] - hi_floor
    # running sums of the cells before each end, at point 0
    s_lo = line_sum(src, axis, u, v, wp.min(wp.max(m_lo, 0), n))
    s_hi = line_sum(src, axis, u, v, wp.min(wp.max(m_hi, 0), n))
    for i in range(n):
        a = s_hi
        if m_hi >= 0 and m_hi < n:
            q = grid_index(axis, m_hi, u, v)
            c = wp.float64(src[q[0], q[1], q[2]])
            a += f_hi * c
            s_hi += c
        b = s_lo
        if m_lo >= 0 and m_lo < n:
            q = grid_index(axis, m_lo, u, v)
            c = wp.float64(src[q[0], q[1], q[2]])
            b += f_lo * c
            s_lo += c
        m_hi += 1
        m_lo += 1
        o = grid_index(axis, i, u, v)
        dst[o[0], o[1], o[2]] = wp.float32(wp.max(a - b, wp.float64(0.0)) * wp.float64(scale))


@wp.kernel
def box_window_kernel(src: wp.array3d(dtype=wp.float32), dst: wp.array3d(dtype=wp.float32),
                      half: float, scale: float):
    """:func:`box_pass` along the last axis, one thread per point ``wp.tid() = (i, j, k)``:
    the cells ``m`` overlapping the window ``[k + 1/2 - half, k + 1/2 + half]`` (cell ``m``
    spans ``[m, m + 1]``), each weighted by its overlap, summed in float64."""
    i, j, k = wp.tid()
    n = src.shape[2]
    lo = wp.float64(k) + wp.float64(0.5) - wp.float64(half)
    hi = wp.float64(k) + wp.float64(0.5) + wp.float64(half)
    first = wp.max(int(wp.floor(lo)), 0)
    last = wp.min(int(wp.ceil(hi)) - 1, n - 1)
    acc = wp.float64(0.0)
    for m in range(first, last + 1):
        w = wp.min(wp.float64(m + 1), hi) - wp.max(wp.float64(m), lo)
        if w > wp.float64(0.0):
            acc += w * wp.float64(src[i, j, m])
    dst[i, j, k] = wp.float32(acc * wp.float64(scale))


@wp.func
def sat_axis(x: wp.float64, n: int):
    """Lower SAT index and weight of the upper one for fractional SAT coordinate ``x``.

    ``x`` is clamped to ``[0, n]`` (outside the grid the running sum is constant).
    """
    xc = wp.min(wp.max(x, wp.float64(0.0)), wp.float64(n))
    i = wp.min(int(xc), n - 1)
    return i, xc - wp.float64(i)


@wp.func
def sat_at(sat: wp.array3d(dtype=wp.float64), x: wp.float64, y: wp.float64, z: wp.float64):
    """Trilinear interpolation of the SAT at fractional index ``(x, y, z)``.

    Equals the integral of the cell-constant field over ``[0, x] × [0, y] × [0, z]``
    in SAT index space (index ``a`` is the cell face at voxel coordinate ``a - 1/2``).
    """
    i, fx = sat_axis(x, sat.shape[0] - 1)
    j, fy = sat_axis(y, sat.shape[1] - 1)
    k, fz = sat_axis(z, sat.shape[2] - 1)
    one = wp.float64(1.0)
    c00 = (one - fx) * sat[i, j, k] + fx * sat[i + 1, j, k]
    c10 = (one - fx) * sat[i, j + 1, k] + fx * sat[i + 1, j + 1, k]
    c01 = (one - fx) * sat[i, j, k + 1] + fx * sat[i + 1, j, k + 1]
    c11 = (one - fx) * sat[i, j + 1, k + 1] + fx * sat[i + 1, j + 1, k + 1]
    return (one - fz) * ((one - fy) * c00 + fy * c10) + fz * ((one - fy) * c01 + fy * c11)


@wp.kernel
def cube_mean_kernel(sat: wp.array3d(dtype=wp.float64), h: wp.vec3d,
                     out: wp.array3d(dtype=wp.float32)):
    """Mean σt over the cube of half-width ``h`` (voxels per axis) around each grid point.

    ``wp.tid()`` = grid point ``(i, j, k)``. Voxel ``i`` spans SAT coordinates
    ``[i, i + 1]``, so the cube ``[i - h, i + h]`` spans ``[i + 1/2 - h, i + 1/2 + h]``.
    """
    i, j, k = wp.tid()
    half = wp.float64(0.5)
    x0 = wp.float64(i) + half - h[0]
    x1 = wp.float64(i) + half + h[0]
    y0 = wp.float64(j) + half - h[1]
    y1 = wp.float64(j) + half + h[1]
    z0 = wp.float64(k) + half - h[2]
    z1 = wp.float64(k) + half + h[2]
    total = (sat_at(sat, x1, y1, z1) - sat_at(sat, x0, y1, z1) - sat_at(sat, x1, y0, z1)
             - sat_at(sat, x1, y1, z0) + sat_at(sat, x0, y0, z1) + sat_at(sat, x0, y1, z0)
             + sat_at(sat, x1, y0, z0) - sat_at(sat, x0, y0, z0))
    volume = wp.float64(8.0) * h[0] * h[1] * h[2]
    out[i, j, k] = wp.float32(wp.max(total, wp.float64(0.0)) / volume)
