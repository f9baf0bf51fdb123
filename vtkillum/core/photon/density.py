"""The photon density estimate (Jönsson et al. 2012, eq. 8) and the photon-density volume.

Photons are stored at every interaction with their incoming flux ``Φ_p`` and travel
direction ``ω_p``. Interactions happen with density σt per unit length of photon track,
so the flux of the photons within a sphere ``S(x)`` of radius ``r`` estimates
``∫_S σt φ``, and with the phase function ``∫_S σt L_i``. Dividing by the kernel volume
``V = 4/3 π r³`` and by the **mean extinction over the kernel** ``σ̄t(x)`` gives

    L_i(x, ω_o) ≈ Σ_{|x_p - x| <= r}  p(ω_p · ω_o) Φ_p  /  (V σ̄t(x))
    φ(x)        ≈ Σ_{|x_p - x| <= r}  Φ_p               /  (V σ̄t(x))

(in-scattered radiance towards ``ω_o`` with the Henyey–Greenstein phase ``p``; fluence).
The source term of a view sample is then ``σs(x) L_i(x, ω_o)`` with σs at the sample.
The paper's eq. (8) divides by σs at ``x`` instead; with the kernel mean the numerator
and the denominator see the same part of the medium, so the estimate stays unbiased
next to a dense surface, where half of the sphere is empty (dividing by σt at ``x``
underestimates the light there by up to 2x: the thick-cloud scene came out 20 % too
dark at a radius of 2 voxels). ``σ̄t`` is the mean over the cube of the sphere's volume
(side ``(4π/3)^{1/3} r``), from three exact box filters of the piecewise-linear σt
(:func:`mean_extinction`).

Historygram: ``σ̄t(x)`` depends on the data within that cube, so an object that
evaluates it ORs the bins of every voxel in the cubes around the 8 grid points it
interpolates (:attr:`MeanExtinction.mask`, the same box filter with OR instead of sum,
computed once per volume and radius).

What the photons stand for (``min_order``): with ``min_order = 2`` only photons that
have scattered at least once count -- the **scattered** light of the project's
illumination-volume convention (:mod:`vtkillum.core.illumination`), the direct light
coming exactly from per-light transmittance (or shadow rays) with the phase function.
With ``min_order = 1`` the photons carry all the light, as in the paper; the direct
light then takes the photon noise and, on a grid, loses its phase function (stored as an
isotropic fluence).

:func:`fluence_grid` evaluates ``φ`` at the points of a grid covering the box: the
``scattered_fluence`` of :class:`~vtkillum.core.illumination.IlluminationVolume`.
"""

from __future__ import annotations

import numpy as np
import warp as wp

from vtkillum.core.device import init_warp
from vtkillum.core.photon.hashgrid import PhotonGrid, gather_flux, gather_phase_flux
from vtkillum.core.photon.historygram import data_bin
from vtkillum.core.photon.material import SurfaceParams
from vtkillum.core.warp_common import (
    Medium,
    grid_point,
    lookup_sigma_t,
    sample_scalar,
    trilinear_index,
)

init_warp()

#: Side of the cube with the volume of the unit sphere.
CUBE_SIDE = (4.0 * np.pi / 3.0) ** (1.0 / 3.0)


@wp.struct
class MeanExtinction:
    """``σ̄t`` (1/world units) and the data bins of each data point's kernel cube."""

    sigma: wp.array3d(dtype=wp.float32)
    mask: wp.array3d(dtype=wp.uint64)
    inv_spacing: wp.vec3


def box_reach(half: float) -> int:
    """Grid offsets a box of half-width ``half`` (grid units) touches on each side."""
    return int(np.ceil(half)) + 1 if half > 1e-6 else 0


def mean_extinction(medium: Medium, volume, radius: float, device: str,
                    mask: wp.array | None = None, bins=(0.0, 0.0)) -> MeanExtinction:
    """``σ̄t`` on the data grid for photon radius ``radius`` (and the bins mask).

    Parameters
    ----------
    medium : Medium
        Scalars and σt table.
    volume : vtkillum.core.volume.Volume
    radius : float
        Photon radius, world units.
    device : str
    mask : wp.array3d(uint64), optional
        A mask computed before for the same volume and radius (it does not depend on
        the transfer function); when omitted, :func:`kernel_mask` (kept with the volume).
    bins : (lo, scale)
        Data binning of the Historygrams (:func:`~vtkillum.core.photon.historygram.bin_scale`).

    Notes
    -----
    The cube of the sphere's volume has half-width ``h_a = (4π/3)^{1/3} r / 2`` along each
    axis; σt (piecewise linear between the data points, 0 outside the box) is averaged
    over it exactly, one axis at a time; the box ends where the volume does.
    """
    dims = tuple(volume.dims)
    half = 0.5 * CUBE_SIDE * float(radius) / np.asarray(volume.spacing, np.float64)
    a = wp.empty(dims, dtype=wp.float32, device=device)
    b = wp.empty(dims, dtype=wp.float32, device=device)
    wp.launch(sigma_points_kernel, dim=dims, inputs=[medium, a], device=device)
    for axis in range(3):
        wp.launch(box_mean_kernel, dim=dims, inputs=[a, axis, float(half[axis]), b],
                  device=device)
        a, b = b, a
    me = MeanExtinction()
    me.sigma = a
    me.inv_spacing = wp.vec3(*(1.0 / volume.spacing).astype(np.float32))
    if mask is None:
        mask = kernel_mask(medium, volume, radius, device, bins)
    me.mask = mask
    return me


def kernel_mask(medium: Medium, volume, radius: float, device: str, bins) -> wp.array:
    """The bins mask of :func:`mean_extinction`, kept with the volume (it depends on the
    data, the radius and the binning only, not on the transfer function or the lights)."""
    half = 0.5 * CUBE_SIDE * float(radius) / np.asarray(volume.spacing, np.float64)
    key = (float(radius), float(bins[0]), float(bins[1]))

    def make():
        dims = tuple(volume.dims)
        m0 = wp.empty(dims, dtype=wp.uint64, device=device)
        m1 = wp.empty(dims, dtype=wp.uint64, device=device)
        wp.launch(bins_points_kernel, dim=dims,
                  inputs=[medium.scalars, float(bins[0]), float(bins[1]), m0], device=device)
        for axis in range(3):
            wp.launch(box_or_kernel, dim=dims, inputs=[m0, axis, box_reach(half[axis]), m1],
                      device=device)
            m0, m1 = m1, m0
        return m0

    return volume.derived(f"photon_kernel_mask@{device}", key, make)


@wp.func
def mean_sigma(me: MeanExtinction, x: wp.vec3):
    """``σ̄t`` at local position ``x`` (trilinear)."""
    return sample_scalar(me.sigma, me.inv_spacing, x)


@wp.func
def kernel_bins(me: MeanExtinction, x: wp.vec3):
    """Data bins that ``σ̄t(x)`` depends on: the masks of the 8 grid points around ``x``."""
    a = me.mask
    idx, _f = trilinear_index(x, me.inv_spacing, wp.vec3i(a.shape[0], a.shape[1], a.shape[2]))
    i = idx[0]
    j = idx[1]
    k = idx[2]
    return (a[i, j, k] | a[i + 1, j, k] | a[i, j + 1, k] | a[i + 1, j + 1, k]
            | a[i, j, k + 1] | a[i + 1, j, k + 1] | a[i, j + 1, k + 1]
            | a[i + 1, j + 1, k + 1])


@wp.func
def photon_radiance(grid: PhotonGrid, me: MeanExtinction, x: wp.vec3, wo: wp.vec3, g: float,
                    surface: int, n: wp.vec3, sp: SurfaceParams):
    """In-scattered radiance ``L_i(x, wo)`` from the photons (``wo``: towards the viewer)."""
    sbar = mean_sigma(me, x)
    if sbar <= 0.0:
        return wp.vec3(0.0)
    return gather_phase_flux(grid, x, wo, g, surface, n, sp) / sbar


@wp.func
def photon_fluence(grid: PhotonGrid, me: MeanExtinction, x: wp.vec3):
    """Fluence ``φ(x)`` from the photons."""
    sbar = mean_sigma(me, x)
    if sbar <= 0.0:
        return wp.vec3(0.0)
    return gather_flux(grid, x) / sbar


def fluence_grid(grid: PhotonGrid, me: MeanExtinction, shape, extent, device: str,
                 to_numpy: bool = True):
    """Photon fluence ``φ`` at the points of a grid covering ``[0, extent]``.

    Parameters
    ----------
    grid : PhotonGrid
        Sorted photons (:func:`~vtkillum.core.photon.hashgrid.build_photon_grid`).
    me : MeanExtinction
        ``σ̄t`` for the grid's radius (:func:`mean_extinction`).
    shape : (3,) int
        Grid points per axis (>= 2); point ``[i, j, k]`` is at
        ``(i, j, k) * extent / (shape - 1)``.
    extent : (3,) float
        The volume's box in the local frame.
    device : str
    to_numpy : bool
        Return a numpy array (default) or the device array (``wp.array3d(vec3)``).

    Returns
    -------
    ndarray (nx, ny, nz, 3) float32
        RGB fluence in the lights' irradiance units.

    Notes
    -----
    The points are gathered in bricks of 8×4×1 (x, y, z), one warp a brick: the warp's
    spheres overlap, so its lanes read the same cell rows and photons, and bricks in
    empty space (``σ̄t = 0``) leave at once.
    """
    shape = tuple(int(n) for n in shape)
    spacing = np.asarray(extent, np.float64) / (np.asarray(shape) - 1)
    out = wp.empty(shape, dtype=wp.vec3, device=device)
    bx, by = (shape[0] + 7) // 8, (shape[1] + 3) // 4
    wp.launch(fluence_grid_kernel, dim=bx * by * shape[2] * 32,
              inputs=[grid, me, wp.vec3(*spacing.astype(np.float32)), bx, by, out],
              device=device)
    if not to_numpy:
        return out
    return out.numpy().reshape(*shape, 3)


def accumulate_fluence(total: wp.array, fluence: wp.array, device: str) -> None:
    """``total += fluence`` (float64 sum of float32 grids, on the device)."""
    wp.launch(accumulate_kernel, dim=total.shape, inputs=[total, fluence], device=device)


@wp.kernel
def accumulate_kernel(total: wp.array3d(dtype=wp.vec3d), add: wp.array3d(dtype=wp.vec3)):
    """``wp.tid()`` = ``(i, j, k)``: ``total += add`` in float64."""
    i, j, k = wp.tid()
    a = add[i, j, k]
    total[i, j, k] = total[i, j, k] + wp.vec3d(wp.float64(a[0]), wp.float64(a[1]),
                                               wp.float64(a[2]))


@wp.kernel
def fluence_grid_kernel(grid: PhotonGrid, me: MeanExtinction, spacing: wp.vec3, bx: int,
                        by: int, out: wp.array3d(dtype=wp.vec3)):
    """``wp.tid()`` = 32 threads per brick of 8×4×1 points ``(i, j, k)`` of the output grid
    (``bx`` × ``by`` bricks per z slice), a point at ``(i, j, k) * spacing`` (local frame,
    world units); writes the photon fluence there (RGB)."""
    t = wp.tid()
    lane = t % 32
    brick = t // 32
    k = brick // (bx * by)
    brick = brick - k * (bx * by)
    bj = brick // bx
    i = (brick - bj * bx) * 8 + lane % 8
    j = bj * 4 + lane // 8
    if i >= out.shape[0] or j >= out.shape[1]:
        return
    out[i, j, k] = photon_fluence(grid, me, grid_point(i, j, k, spacing))


@wp.kernel
def sigma_points_kernel(m: Medium, out: wp.array3d(dtype=wp.float32)):
    """``wp.tid()`` = data point ``(i, j, k)``: its σt (1/world units)."""
    i, j, k = wp.tid()
    out[i, j, k] = lookup_sigma_t(m, m.scalars[i, j, k])


@wp.kernel
def bins_points_kernel(scalars: wp.array3d(dtype=wp.float32), lo: float, scale: float,
                       out: wp.array3d(dtype=wp.uint64)):
    """``wp.tid()`` = data point ``(i, j, k)``: the bin of its value."""
    i, j, k = wp.tid()
    out[i, j, k] = data_bin(scalars[i, j, k], lo, scale)


@wp.func
def hat_integral(t: float):
    """``∫_{-inf}^{t} hat``, the antiderivative of the linear interpolation basis."""
    if t <= -1.0:
        return 0.0
    if t <= 0.0:
        return 0.5 * (t + 1.0) * (t + 1.0)
    if t <= 1.0:
        return 1.0 - 0.5 * (1.0 - t) * (1.0 - t)
    return 1.0


@wp.kernel
def box_mean_kernel(src: wp.array3d(dtype=wp.float32), axis: int, half: float,
                    dst: wp.array3d(dtype=wp.float32)):
    """``wp.tid()`` = point ``(i, j, k)``: mean along ``axis`` of the piecewise-linear
    interpolant of ``src`` over ``[x - half, x + half]`` (grid units), the part outside the
    grid counting as 0 (no medium there); ``half = 0``: the point value."""
    i, j, k = wp.tid()
    if half <= 1.0e-6:
        dst[i, j, k] = src[i, j, k]
        return
    x = i
    n = src.shape[0]
    if axis == 1:
        x = j
        n = src.shape[1]
    elif axis == 2:
        x = k
        n = src.shape[2]
    lo = wp.max(float(x) - half, 0.0)
    hi = wp.min(float(x) + half, float(n - 1))
    reach = int(wp.ceil(half)) + 1
    acc = float(0.0)
    for o in range(-reach, reach + 1):
        c = x + o
        if c >= 0 and c < n:
            w = hat_integral(hi - float(c)) - hat_integral(lo - float(c))
            if axis == 0:
                acc += w * src[c, j, k]
            elif axis == 1:
                acc += w * src[i, c, k]
            else:
                acc += w * src[i, j, c]
    dst[i, j, k] = acc / (2.0 * half)


@wp.kernel
def box_or_kernel(src: wp.array3d(dtype=wp.uint64), axis: int, half: int,
                  dst: wp.array3d(dtype=wp.uint64)):
    """``wp.tid()`` = point ``(i, j, k)``: OR of ``src`` over ``2 half + 1`` points along
    ``axis``."""
    i, j, k = wp.tid()
    acc = wp.uint64(0)
    for o in range(-half, half + 1):
        a = i
        b = j
        c = k
        if axis == 0:
            a = i + o
        elif axis == 1:
            b = j + o
        else:
            c = k + o
        if a >= 0 and b >= 0 and c >= 0 and a < src.shape[0] and b < src.shape[1] \
                and c < src.shape[2]:
            acc = acc | src[a, b, c]
    dst[i, j, k] = acc
