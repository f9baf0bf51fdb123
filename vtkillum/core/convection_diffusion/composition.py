"""Composition of the convected lights (Zhang & Ma 2013, §5.5, eq. 22) and the
first-scattered source of the physically based diffusion.

Direct fluence (both models)
----------------------------
``phi_d(x) = sum_l T_l(x) E_l(x)``, the paper's composed light volume ``L0``
(eq. 22) with ``E_l`` the light's RGB irradiance: constant for a directional light,
``I / max(d, r_s)**2`` for a point light at distance ``d`` (``r_s`` the source
radius). The ``"paper"`` model diffuses it; the ``"physical"`` model shows it only
as a picture of the direct light (the ray caster evaluates ``T_l E_l`` per sample
with the phase function).

First-scattered source (``"physical"``)
---------------------------------------
Light leaves the direct beams where it collides; the fraction ``sigma_s / sigma_t``
of the collisions scatters and becomes the source of the scattered fluence:

    Q_c(x) = sigma_s,c(x) * sum_l E_l,c(x) * <T_l>(x),     sigma_s,c = albedo * <color_c sigma_t>

where ``<.>`` is the mean over the light-grid cell of ``x``
(:func:`~vtkillum.core.convection_diffusion.opacity.light_grid_optics`). The cell mean
of the transmittance matters: on a half-resolution light grid a cell of a thick
medium has an optical size ``tau = sigma_t h`` of several units, and the value at
its centre ``T(x)`` is ``exp(tau/2)``-times smaller than at its entry face. Taking
``sigma_t T(x)`` as the collision rate would lose most of the energy the beam
deposits there (``tau = 10``: 93 %). Inside a homogeneous cell the transmittance is
``T(x) exp(-sigma_t u . (y - x))`` for the light's travel direction ``u``, whose mean
over the box cell is exactly

    <T> = T(x) * prod_a S(sigma_t |u_a| h_a / 2),     S(z) = sinh(z) / z,

so that a column of cells deposits exactly the energy the beam loses
(``sum_cells sigma_t <T> h = 1 - T_exit`` for axis-aligned light with the
short-characteristics convection, whose steps attenuate with the same trapezoidal
``sigma_t``). ``<T>`` is clamped to 1.

Where the source sits: its dipole moment
----------------------------------------
A cell's source is not at its centre, and the light it scatters does not start
isotropic. Both shift the source by a displacement ``delta`` that the diffusion
takes as a dipole density ``p = sum_l Q_l delta_l`` (right-hand side ``Q - div p``,
:mod:`~vtkillum.core.convection_diffusion.radiative`):

* within the cell: the centroid of ``exp(-sigma_t u . y)`` over the box, per axis
  ``-sign(u_a) (h_a / 2) L(sigma_t |u_a| h_a / 2)`` with the Langevin function
  ``L(z) = coth z - 1 / z`` (up to half a cell towards the light in a thick cell);
* forward, by anisotropic scattering: the first moment of the scattered light is
  ``g Q u``, and in the P1 approximation it adds the flux ``g Q u / sigma_tr``: a
  displacement ``g u / sigma_tr`` per channel (one transport mean free path times
  ``g``).

A nearest-neighbour dipole represents a displacement of at most about one cell, so
``sum_a |delta_a| / h_a`` is limited to :data:`MAX_MOVED` = 1 (in thin media, where
``g / sigma_tr`` exceeds a cell, the forward-scattered light mostly leaves before
its next collision anyway). The face-centred divergence of ``p`` can be negative
next to empty cells; those parts are clipped and the rest rescaled to the same
total (:mod:`~vtkillum.core.convection_diffusion.radiative`), since a negative source
would make the lagged flux limiter oscillate. Measured on the suite of
:mod:`~vtkillum.core.convection_diffusion.radiative` (relative RMSE vs ``path``,
without -> with): thick cloud (g 0.4) 0.158 -> 0.143 (energy 0.91 -> 0.93),
point-lit cloud 0.084 -> 0.078, ball albedo 0.99 0.068 -> 0.065, CT 0.105 -> 0.106,
plume (g 0.3) 0.154 -> 0.161.

Cells on the box faces extend half a cell beyond the box, where there is no medium:
the means and centroids above are taken over the part of the cell inside the box
(per full cell volume), so that a column of cells deposits exactly the energy the
beam loses in the box.
"""

from __future__ import annotations

import numpy as np
import warp as wp

from vtkillum.core.convection_diffusion.convection import POINT_KIND
from vtkillum.core.warp_common import cached_tables, grid_point

#: Largest optical depth of a cell axis evaluated (beyond: the source is at the entry face).
MAX_RATE = wp.constant(80.0)
#: Largest displacement of a cell's source, ``sum_a |delta_a| / h_a`` (cells).
MAX_MOVED = wp.constant(1.0)


def light_tables(kinds, vecs, rgbs, device):
    """The packed lights as device arrays (kind, vector, colour per light) for the
    composition kernels, which visit every light at each point in one launch (uploaded
    once per set of lights: :func:`~vtkillum.core.warp_common.cached_tables`)."""
    kinds = np.asarray(kinds, dtype=np.int32)
    vecs = np.asarray(vecs, dtype=np.float32).reshape(-1, 3)
    rgbs = np.asarray(rgbs, dtype=np.float32).reshape(-1, 3)
    return cached_tables(
        ("compose-tables", str(device), kinds.tobytes(), vecs.tobytes(), rgbs.tobytes()),
        lambda: (wp.array(kinds, dtype=wp.int32, device=device),
                 wp.array(vecs, dtype=wp.vec3, device=device),
                 wp.array(rgbs, dtype=wp.vec3, device=device)))


def compose_direct(transmittances: wp.array4d, kinds, vecs, rgbs, spacing,
                   source_radius: float, out: wp.array3d) -> None:
    """``out = sum_l T_l E_l`` (eq. 22) on the light grid.

    Parameters
    ----------
    transmittances : warp.array4d of float32
        ``T_l = transmittances[l]`` for light ``l`` (the first ``len(kinds)`` slots).
    kinds, vecs, rgbs : arrays
        Packed lights (:func:`vtkillum.core.lights.pack_lights`), local frame.
    spacing : (3,) float
        Light-grid spacing (world units).
    source_radius : float
        Point lights' source radius ``r_s`` (world units).
    out : warp.array3d of vec3
        Overwritten.
    """
    h = wp.vec3(*np.asarray(spacing, dtype=np.float32))
    wp.launch(compose_kernel, dim=out.shape, device=out.device,
              inputs=[transmittances, len(kinds), *light_tables(kinds, vecs, rgbs, out.device),
                      out, h, float(source_radius)])


def first_scattered_source(transmittances, kinds, vecs, rgbs, spacing, source_radius: float,
                           sigma: wp.array3d, color_sigma: wp.array3d, albedo: float,
                           out: wp.array3d, displacement=None, anisotropy: float = 0.0) -> None:
    """``out = Q``, the first-scattered source of the physical model (see the module docstring).

    Parameters
    ----------
    transmittances, kinds, vecs, rgbs, spacing, source_radius
        As :func:`compose_direct` (``transmittances[l]``: the beam of light ``l``).
    sigma : warp.array3d of float32
        Cell-mean extinction ``sigma_t`` (1/world units).
    color_sigma : warp.array3d of vec3
        Cell-mean ``color * sigma_t`` (1/world units).
    albedo : float
        Single-scattering albedo ``Λ``.
    out : warp.array3d of vec3
        Overwritten; units of the lights' irradiance per world unit.
    displacement : (3,) warp.array3d of vec3, optional
        Overwritten with the source's dipole moment per axis (x, y, z; RGB each),
        ``sum_l Q_l delta_l`` with the displacement ``delta_l`` of the module docstring.
    anisotropy : float
        Henyey–Greenstein ``g`` (the forward displacement ``g u / sigma_tr``).
    """
    px, py, pz = displacement if displacement is not None else (out,) * 3
    h = wp.vec3(*np.asarray(spacing, dtype=np.float32))
    wp.launch(first_scattered_kernel, dim=out.shape, device=out.device,
              inputs=[transmittances, len(kinds), *light_tables(kinds, vecs, rgbs, out.device),
                      sigma, color_sigma, out, h, float(source_radius), float(albedo),
                      float(anisotropy), int(displacement is not None), px, py, pz])


# --- device functions ----------------------------------------------------------------------------
@wp.func
def light_at(kind: int, vec: wp.vec3, rgb: wp.vec3, x: wp.vec3, source_radius: float):
    """Irradiance ``E`` (RGB) and unit travel direction ``u`` of a light at ``x``."""
    if kind == POINT_KIND:
        d = x - vec
        dist = wp.length(d)
        r = wp.max(dist, source_radius)
        u = wp.vec3(0.0)
        if dist > 0.0:
            u = d / dist
        return rgb / (r * r), u
    return rgb, vec


@wp.func
def axis_moments(k: float, lo: float, hi: float, h: float):
    """``log`` of the mean of ``exp(-k y)`` over ``y`` in ``[-lo, hi]`` per cell length ``h``
    (zero outside), and its centroid: one axis of a cell clipped to the box, ``y`` along
    the light's travel (``lo`` upstream).

    With ``x = k w`` (``w = lo + hi``): mean ``(1 - e^-x) / (k h)``, centroid
    ``w (1/x - 1/(e^x - 1)) - lo``. Below ``x = 0.5`` both by their Taylor series (first
    omitted terms below 2e-7 relative there): in float32 the centroid's closed form cancels
    as ``eps / x^2`` (6 % of the cell at ``x = 1e-3``) and ``1 - e^-x`` as ``eps / x``; the
    uniform cell that stood in below ``x = 1e-3`` was off by up to ``x / 2`` in the log.
    """
    w = lo + hi
    x = k * w
    if x < 0.5:
        x2 = x * x
        # (1 - e^-x) / x and 1/x - 1/(e^x - 1)
        ratio = 1.0 + x * (-0.5 + x * (1.0 / 6.0 + x * (-1.0 / 24.0 + x * (
            1.0 / 120.0 + x * (-1.0 / 720.0 + x * (1.0 / 5040.0))))))
        f = 0.5 + x * (-1.0 / 12.0 + x2 * (1.0 / 720.0 - x2 * (1.0 / 30240.0)))
        return k * lo + wp.log(ratio) + wp.log(w / h), w * f - lo
    e = wp.exp(-x)
    log_mean = k * lo + wp.log(1.0 - e) - wp.log(k * h)
    centroid = w * (1.0 / x - e / (1.0 - e)) - lo
    return log_mean, centroid


@wp.func
def cell_exposure(t: float, sigma: float, u: wp.vec3, h: wp.vec3, idx: wp.vec3i,
                  shape: wp.vec3i):
    """``<T>`` over the cell of point ``idx`` (clipped to the box, per full cell volume) from
    the value ``t`` at the point, for a homogeneous cell; and the centroid of
    ``sigma T`` in the cell relative to the point (world units)."""
    log_t = float(-1.0e30)
    if t > 0.0:
        log_t = wp.log(t)
    offset = wp.vec3(0.0)
    for a in range(3):
        lower = 0.5 * h[a]
        upper = 0.5 * h[a]
        if idx[a] == 0:
            lower = 0.0
        if idx[a] == shape[a] - 1:
            upper = 0.0
        s = float(1.0)
        lo = lower
        hi = upper
        if u[a] < 0.0:
            s = -1.0
            lo = upper
            hi = lower
        lm, c = axis_moments(wp.min(sigma * wp.abs(u[a]), MAX_RATE / h[a]), lo, hi, h[a])
        log_t += lm
        offset[a] = s * c
    mean = float(0.0)
    if t > 0.0:
        mean = wp.min(wp.exp(log_t), 1.0)
    return mean, offset


# --- kernels -------------------------------------------------------------------------------------
@wp.kernel
def compose_kernel(T: wp.array4d(dtype=wp.float32), count: int, kinds: wp.array(dtype=wp.int32),
                   vecs: wp.array(dtype=wp.vec3), rgbs: wp.array(dtype=wp.vec3),
                   out: wp.array3d(dtype=wp.vec3), h: wp.vec3, source_radius: float):
    """Eq. 22 at light-grid point ``wp.tid() = (i, j, k)``: ``out = sum_l T_l E_l`` over the
    ``count`` lights (one launch for all: the sum stays in registers).

    ``E = rgb`` (irradiance) for a directional light, ``rgb / max(d, source_radius)**2``
    (intensity over squared distance, world units) for a point light at ``vec``.
    """
    i, j, k = wp.tid()
    x = grid_point(i, j, k, h)
    acc = wp.vec3(0.0)
    for n in range(count):
        e, _u = light_at(kinds[n], vecs[n], rgbs[n], x, source_radius)
        acc = acc + T[n, i, j, k] * e
    out[i, j, k] = acc


@wp.kernel
def first_scattered_kernel(T: wp.array4d(dtype=wp.float32), count: int,
                           kinds: wp.array(dtype=wp.int32), vecs: wp.array(dtype=wp.vec3),
                           rgbs: wp.array(dtype=wp.vec3), sigma: wp.array3d(dtype=wp.float32),
                           color_sigma: wp.array3d(dtype=wp.vec3),
                           out: wp.array3d(dtype=wp.vec3), h: wp.vec3, source_radius: float,
                           albedo: float, g: float, with_displacement: int,
                           px: wp.array3d(dtype=wp.vec3), py: wp.array3d(dtype=wp.vec3),
                           pz: wp.array3d(dtype=wp.vec3)):
    """``out = sum_l Q_l``, ``Q_l = albedo <color sigma_t> E_l <T_l>``, over the ``count``
    lights at point ``wp.tid() = (i, j, k)`` (one launch for all: the sums stay in registers).

    With ``with_displacement``: also ``(px, py, pz) = sum_l Q_l delta_l`` per channel (see
    the module docstring). ``h`` is the light-grid spacing (world units), ``vecs[l]`` the
    light's unit travel direction (directional) or position (point) in the local frame.
    """
    i, j, k = wp.tid()
    shape = wp.vec3i(sigma.shape[0], sigma.shape[1], sigma.shape[2])
    acc, mx, my, mz = first_scattered_at(T, count, kinds, vecs, rgbs, sigma, color_sigma, h,
                                         source_radius, albedo, g, with_displacement, i, j, k,
                                         wp.vec3i(i, j, k), shape)
    out[i, j, k] = acc
    if with_displacement != 0:
        px[i, j, k] = mx
        py[i, j, k] = my
        pz[i, j, k] = mz


@wp.func
def first_scattered_at(T: wp.array4d(dtype=wp.float32), count: int,
                       kinds: wp.array(dtype=wp.int32), vecs: wp.array(dtype=wp.vec3),
                       rgbs: wp.array(dtype=wp.vec3), sigma: wp.array3d(dtype=wp.float32),
                       color_sigma: wp.array3d(dtype=wp.vec3), h: wp.vec3,
                       source_radius: float, albedo: float, g: float, with_displacement: int,
                       i: int, j: int, k: int, cell_index: wp.vec3i, shape: wp.vec3i):
    """``(sum_l Q_l, and with_displacement its moments sum_l Q_l delta_l along x, y, z)`` of
    :func:`first_scattered_kernel` for the point stored at ``[i, j, k]`` whose index in the
    whole light grid of ``shape`` points is ``cell_index`` (the same on one rank; a block's
    global index when distributed: the cell's box faces are the whole grid's)."""
    x = grid_point(cell_index[0], cell_index[1], cell_index[2], h)
    st = sigma[i, j, k]
    cs = color_sigma[i, j, k]
    acc = wp.vec3(0.0)
    mx = wp.vec3(0.0)
    my = wp.vec3(0.0)
    mz = wp.vec3(0.0)
    for n in range(count):
        e, u = light_at(kinds[n], vecs[n], rgbs[n], x, source_radius)
        tm, cell = cell_exposure(T[n, i, j, k], st, u, h, cell_index, shape)
        q = (albedo * tm) * wp.cw_mul(cs, e)
        acc = acc + q
        if with_displacement != 0:
            dx = wp.vec3(0.0)
            dy = wp.vec3(0.0)
            dz = wp.vec3(0.0)
            for c in range(3):
                sigma_tr = st - g * albedo * cs[c]
                d = cell
                if sigma_tr > 0.0:
                    d = d + (g / sigma_tr) * u
                moved = wp.abs(d[0]) / h[0] + wp.abs(d[1]) / h[1] + wp.abs(d[2]) / h[2]
                if moved > MAX_MOVED:
                    d = d * (MAX_MOVED / moved)
                dx[c] = d[0] * q[c]
                dy[c] = d[1] * q[c]
                dz[c] = d[2] * q[c]
            mx = mx + dx
            my = my + dy
            mz = mz + dz
    return acc, mx, my, mz
