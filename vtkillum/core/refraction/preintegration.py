"""Pre-integration tables: opacity, medium colour and particle colour between two planes.

Between two light (or view) planes a ray crosses a segment of length ``ℓ`` along
which the data value is taken to vary linearly from ``s_a`` to ``s_b`` (the
pre-integration assumption). Over such a segment

* particle extinction: ``τ = ℓ · mean(σt)``, opacity ``α = 1 - exp(-τ)``
  (σt from the opacity transfer function, ``σt = -ln(1 - α_tf) / u``);
* medium filtering: ``M_c = exp(-ℓ · mean(κ_c))`` with ``κ_c = -ln(m_c) / u``
  (:mod:`~vtkillum.core.refraction.optics`);
* particle colour: the σt-weighted mean ``mean(σt · c) / mean(σt)``,

where ``mean(f) = ∫ f(s) ds / (s_b - s_a)`` over the data values. The kernels get
one table per quantity sampled at :data:`TABLE_SIZE` data values, and its running
integral; a mean is the difference of the integral at both ends divided by their
distance (exact for the piecewise-linear table), or, for ends less than two table
entries apart, the exact average of the one to three linear pieces between them
(the difference of two large float32 integrals would lose precision there). The
paper's 2D pre-integration tables hold the same numbers for fixed ``ℓ``; the 1D
running integrals take any segment length, which the plane sweep needs (oblique and
bending rays cross planes at different lengths).

With η ≡ 1 and m ≡ white (κ = 0) the tables reduce to plain extinction and the
scattering colour of the project's optical model (``DESIGN.md``).

On CUDA the sweep samples the data through a 3D texture (:func:`data_texture`): the
texture units interpolate trilinearly (block-linear storage, so a plane at any
orientation reads neighbouring points from one cache line, and one fetch replaces eight
loads and their index arithmetic; 8-bit fractional weights, as in
:mod:`~vtkillum.core.ambient.textures`). On the CPU it interpolates the array exactly
(:func:`~vtkillum.core.warp_common.sample_scalar`; warp's software texture filtering
would be about 1.5x slower there).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import warp as wp

from vtkillum.core.device import resolve_device
from vtkillum.core.transfer_function import TABLE_SIZE
from vtkillum.core.warp_common import (
    MAX_TEXTURE_EXTENT,
    compiled_for_cuda,
    device_scalars,
    fits_texture,
    sample_scalar,
    texture_from,
)


@wp.struct
class RefractiveMedium:
    """Scalar volume plus the refractive optical model on the device (local frame).

    ``extinction[i] = (σt, κ_r, κ_g, κ_b)`` and ``source[i] = σt · colour`` at table
    entry ``i`` (1/world units), with running integrals over the entry index;
    ``eta[i]`` the refractive index. Entry ``i`` holds data value
    ``table_lo + i / table_scale``. The data are sampled at texture coordinates (grid
    point ``[i, j, k]`` at ``(k, j, i) + 0.5``, :func:`data_coordinate`): on CUDA from
    ``data``, the scalar volume as a texture (:func:`data_texture`), on the CPU from
    ``scalars``.
    """

    scalars: wp.array3d(dtype=wp.float32)  # [i, j, k], point-centred
    data: wp.Texture3D  # the same, trilinear, clamped to the box (CUDA only)
    extent: wp.vec3  # (n - 1) * spacing, world units
    spacing: wp.vec3
    inv_spacing: wp.vec3
    table_lo: float
    table_scale: float  # entries per data unit
    extinction: wp.array(dtype=wp.vec4)
    extinction_integral: wp.array(dtype=wp.vec4)
    source: wp.array(dtype=wp.vec3)
    source_integral: wp.array(dtype=wp.vec3)
    eta: wp.array(dtype=wp.float32)
    eta_varies: int  # 0: η constant, no gradients are evaluated
    eta_outside: float  # η of the space around the volume's box
    medium_white: int  # 1: κ = 0 everywhere
    albedo: float
    g: float  # Henyey–Greenstein anisotropy


def make_refractive_medium(volume, transfer_function, optics, unit_distance: float,
                           albedo: float = 0.9, anisotropy: float = 0.0,
                           device: str | None = None, size: int = TABLE_SIZE,
                           arrays: dict | None = None) -> RefractiveMedium:
    """Upload ``volume`` (cached with it) and the pre-integration tables.

    Parameters
    ----------
    volume : vtkillum.core.volume.Volume
    transfer_function : vtkillum.core.transfer_function.TransferFunction
    optics : vtkillum.core.refraction.optics.RefractiveOptics
    unit_distance : float
        Opacity unit distance ``u`` (world units), also the medium colour's.
    albedo, anisotropy : float
        Scattering albedo and HG ``g``.
    device : str, optional
    size : int
        Table entries.
    arrays : dict, optional
        Device tables of an earlier call to overwrite in place (same shapes): keeps
        the array addresses, so a captured CUDA graph stays valid after a transfer-
        function edit. Filled with the new arrays when empty.

    Notes
    -----
    ``eta_outside``, the index of the space around the box, is the median of η over
    the data values on the volume's six faces (the medium the volume sits in), so a
    volume immersed in water (η = 1.33 on its faces) does not refract at its box.
    """
    device = resolve_device(device)
    tables = preintegration_tables(volume, transfer_function, optics, unit_distance, size)
    m = RefractiveMedium()
    m.scalars = device_scalars(volume, device)
    m.data = data_texture(volume, m.scalars) if wp.get_device(device).is_cuda else None
    m.extent = wp.vec3(*volume.extent.astype(np.float32))
    m.spacing = wp.vec3(*volume.spacing.astype(np.float32))
    m.inv_spacing = wp.vec3(*(1.0 / volume.spacing).astype(np.float32))
    m.table_lo = float(tables["lo"])
    m.table_scale = float((size - 1) / (tables["hi"] - tables["lo"]))
    dtypes = {"extinction": wp.vec4, "extinction_integral": wp.vec4, "source": wp.vec3,
              "source_integral": wp.vec3, "eta": wp.float32}
    arrays = {} if arrays is None else arrays
    for name, dtype in dtypes.items():
        host = np.ascontiguousarray(tables[name])
        old = arrays.get(name)
        if old is not None and old.shape[0] == host.shape[0] and str(old.device) == device:
            old.assign(wp.array(host, dtype=dtype, device="cpu"))
        else:
            arrays[name] = wp.array(host, dtype=dtype, device=device)
        setattr(m, name, arrays[name])
    m.eta_varies = int(not optics.eta_constant)
    m.eta_outside = float(tables["eta_outside"])
    m.medium_white = int(optics.medium_white)
    m.albedo = float(albedo)
    m.g = float(anisotropy)
    return m


def data_texture(volume, scalars):
    """``volume``'s scalars (``scalars``: their device array) as a linearly filtered, clamped
    ``wp.Texture3D`` (made once per Volume and device, 4 bytes a grid point)."""
    shape = tuple(int(n) for n in volume.dims)
    if not fits_texture(shape):
        raise ValueError(
            f"the refraction method samples the volume through a 3D texture of at most "
            f"{MAX_TEXTURE_EXTENT} points per axis; this volume has {shape}. Resample it")
    return volume.derived(f"scalar_texture@{scalars.device}", None,
                          lambda: texture_from(scalars))


def preintegration_tables(volume, transfer_function, optics, unit_distance: float,
                          size: int = TABLE_SIZE) -> dict:
    """The host tables of :class:`RefractiveMedium` (numpy, float32) and their value range.

    Returns a dict with ``extinction`` (size, 4), ``extinction_integral`` (size, 4),
    ``source`` (size, 3), ``source_integral`` (size, 3), ``eta`` (size,), ``lo``,
    ``hi`` (data values of the first and last entries) and ``eta_outside``.
    """
    lo, hi = volume.value_range
    for a, b in (transfer_function.domain(), optics.domain()):
        lo, hi = min(lo, a), max(hi, b)
    if hi <= lo:
        hi = lo + 1.0
    v = np.linspace(lo, hi, int(size))
    sigma = transfer_function.sigma_t(v, unit_distance)
    colour = transfer_function.color(v)
    kappa = optics.kappa(v, unit_distance)
    extinction = np.concatenate([sigma[:, None], kappa], 1)
    source = sigma[:, None] * colour
    faces = np.concatenate([f.reshape(-1) for f in _faces(volume.scalars)])
    return {
        "extinction": extinction.astype(np.float32),
        "extinction_integral": running_integral(extinction).astype(np.float32),
        "source": source.astype(np.float32),
        "source_integral": running_integral(source).astype(np.float32),
        "eta": optics.eta_at(v).astype(np.float32),
        "lo": float(lo),
        "hi": float(hi),
        "eta_outside": float(np.median(optics.eta_at(faces))),
    }


def running_integral(values: np.ndarray) -> np.ndarray:
    """Integral of the piecewise-linear ``values`` from entry 0 to each entry (trapezoids)."""
    v = np.asarray(values, dtype=np.float64)
    out = np.zeros_like(v)
    out[1:] = np.cumsum(0.5 * (v[1:] + v[:-1]), axis=0)
    return out


def _faces(a: np.ndarray):
    return (a[0], a[-1], a[:, 0], a[:, -1], a[:, :, 0], a[:, :, -1])


# --- device functions ---------------------------------------------------------------------------
@wp.func
def table_coordinate(m: RefractiveMedium, s: float):
    """Continuous table entry of data value ``s`` (clamped: constant outside the table)."""
    return wp.clamp((s - m.table_lo) * m.table_scale, 0.0, float(m.eta.shape[0] - 1))


@wp.func
def table_value(values: wp.array(dtype=Any), x: float):
    """Linear interpolation of a table at continuous entry ``x`` in ``[0, n - 1]``."""
    i = wp.min(int(x), values.shape[0] - 2)
    return wp.lerp(values[i], values[i + 1], x - float(i))


@wp.func
def table_antiderivative(values: wp.array(dtype=Any), integral: wp.array(dtype=Any), x: float):
    """Integral of the piecewise-linear table from entry 0 to ``x`` (entry units)."""
    i = wp.min(int(x), values.shape[0] - 2)
    t = x - float(i)
    return integral[i] + values[i] * t + (values[i + 1] - values[i]) * (0.5 * t * t)


@wp.func
def table_mean(values: wp.array(dtype=Any), integral: wp.array(dtype=Any), xa: float, xb: float):
    """Mean of the piecewise-linear table over the entries between ``xa`` and ``xb``."""
    lo = wp.min(xa, xb)
    hi = wp.max(xa, xb)
    width = hi - lo
    if width >= 2.0:
        return (table_antiderivative(values, integral, hi)
                - table_antiderivative(values, integral, lo)) / width
    if width <= 0.0:
        return table_value(values, lo)
    # At most three linear pieces: the mean of each is its value at its midpoint.
    total = values[0] * 0.0
    a = lo
    for _piece in range(3):
        if a < hi:
            b = wp.min(wp.floor(a) + 1.0, hi)
            total += table_value(values, 0.5 * (a + b)) * (b - a)
            a = b
    return total / width


@wp.func
def data_coordinate(m: RefractiveMedium, p: wp.vec3):
    """Texture coordinates of local position ``p`` in ``m.data`` (one unit per grid point)."""
    u = wp.cw_mul(p, m.inv_spacing)
    return wp.vec3(u[2] + 0.5, u[1] + 0.5, u[0] + 0.5)


@wp.func
def data_fetch(m: RefractiveMedium, c: wp.vec3):
    """Data value at texture coordinates ``c`` (trilinear, clamped to the box)."""
    if compiled_for_cuda() != 0:
        return wp.texture_sample(m.data, c, dtype=float)
    return sample_scalar(m.scalars, wp.vec3(1.0), wp.vec3(c[2] - 0.5, c[1] - 0.5, c[0] - 0.5))


@wp.func
def data_value(m: RefractiveMedium, p: wp.vec3):
    """Data value at local position ``p`` (trilinear, clamped to the box)."""
    return data_fetch(m, data_coordinate(m, p))


@wp.func
def segment_extinction(m: RefractiveMedium, sa: float, sb: float):
    """Mean ``(σt, κ_r, κ_g, κ_b)`` over a segment whose data value runs from ``sa`` to ``sb``."""
    return table_mean(m.extinction, m.extinction_integral, table_coordinate(m, sa),
                      table_coordinate(m, sb))


@wp.func
def segment_source(m: RefractiveMedium, sa: float, sb: float):
    """Mean ``σt · colour`` over a segment whose data value runs from ``sa`` to ``sb``."""
    return table_mean(m.source, m.source_integral, table_coordinate(m, sa),
                      table_coordinate(m, sb))
