"""Hardware-filtered textures shared by the ray casters (CUDA only).

A renderer that samples a grid millions of times a frame spends most of its time in the
eight loads and seven lerps of a software trilinear sample
(:func:`~vtkillum.core.warp_common.trilinear`). On CUDA the texture units do the same
interpolation in one fetch through a cache built for 3D locality. Each device function
here has two overloads with one name: an **array** overload, the exact software path
(what the CPU always runs), and a **texture** overload. A kernel written once against
these names is compiled for either (``wp.overload`` with the argument types); the
calling code picks arrays or textures.

Accuracy: texture units interpolate with 8-bit fractional weights (CUDA's 9-bit
fixed-point format), so a sample may differ from the exact trilinear value by up to
about 1/256 of the difference between neighbouring grid values; measured on an H200,
rendered images differ from the software path by ~1e-3 of their maximum on average
(``tests/core/test_raycast_textures.py`` asserts the bound on a GPU).

Layouts (unnormalised coordinates, clamp addressing, linear filtering):

* a point-centred scalar grid ``a[i, j, k]`` of shape ``(nx, ny, nz)`` is a texture of
  depth ``nx``, height ``ny``, width ``nz`` (warp's ``(depth, height, width)``): point
  ``(i, j, k)`` is the texel centre ``(k + 0.5, j + 0.5, i + 0.5)``; clamping gives the
  nearest border value outside the grid, as the software path's clamped index does;
* the transfer function's tables (``Medium.color_table`` and ``Medium.sigma_table``) are
  one 1D RGBA float texture, colour in RGB and ``σt`` in A (:func:`optics_texture`);
* per-light grids ``(n_lights, nx, ny, nz)`` are one float texture with the lights
  stacked along the depth axis (``[light * nx + i, j, k]``); samples are clamped into
  their light's slab, so no light filters into another's (:func:`light_texture`);
* an RGB grid is an RGBA half-precision texture in units of its largest component (so
  nothing overflows half precision; relative rounding 2⁻¹¹), multiplied back on
  sampling (:func:`rgb_texture`).

Textures cannot be written by kernels in warp 1.19, so each is a copy of a warp array
(one device copy), made once per grid and kept with it.
"""

from __future__ import annotations

import numpy as np
import warp as wp

from vtkillum.core.device import init_warp
from vtkillum.core.warp_common import (  # noqa: F401 (fetch_*: the overloads' home)
    LightGrid,
    Medium,
    RGBGrid,
    fetch_optics,
    fetch_scalar,
    fits_texture,
    optics_color,
    sample_light_grid,
    sample_rgb,
    texture_from,
)

init_warp()


def textures_available(device: str) -> bool:
    """Whether ``device`` has texture units (a CUDA device)."""
    return wp.get_device(device).is_cuda


# --- device functions: one name, an array overload (exact) and a texture overload ----------------
# (fetch_scalar, fetch_optics and optics_color live in vtkillum.core.warp_common, whose
# generic shadow march uses them; they are re-exported here)
@wp.func
def fetch_light(src: wp.array4d(dtype=wp.float32), grid: LightGrid, li: int, p: wp.vec3):
    """Software trilinear sample of light ``li``'s channel of ``grid`` (``src`` is its data)."""
    return sample_light_grid(grid, li, p)


@wp.func
def fetch_light(src: wp.Texture3D, grid: LightGrid, li: int, p: wp.vec3):  # noqa: F811
    """Hardware-filtered sample of light ``li``'s slab of a :func:`light_texture` of ``grid``;
    the x coordinate is clamped to the slab's end texels, so no light filters into another."""
    u = wp.cw_mul(p, grid.inv_spacing)
    nx = grid.data.shape[1]
    x = wp.clamp(u[0], 0.0, float(nx - 1)) + float(li * nx)
    return wp.texture_sample(src, wp.vec3(u[2] + 0.5, u[1] + 0.5, x + 0.5), dtype=float)


@wp.func
def fetch_rgb(src: wp.array3d(dtype=wp.vec3), grid: RGBGrid, scale: float, p: wp.vec3):
    """Software trilinear sample of an RGB grid (``src`` is its data; ``scale`` unused)."""
    return sample_rgb(grid, p)


@wp.func
def fetch_rgb(src: wp.Texture3D, grid: RGBGrid, scale: float, p: wp.vec3):  # noqa: F811
    """Hardware-filtered sample of an :func:`rgb_texture` of ``grid``, times its unit ``scale``."""
    u = wp.cw_mul(p, grid.inv_spacing)
    v = wp.texture_sample(src, wp.vec3(u[2] + 0.5, u[1] + 0.5, u[0] + 0.5), dtype=wp.vec4f)
    return scale * wp.vec3(v[0], v[1], v[2])


# --- making textures -----------------------------------------------------------------------------
def optics_texture(medium: Medium, current=None):
    """The medium's colour and ``σt`` tables as one 1D RGBA float texture (``current`` is
    overwritten when it fits; see :func:`~vtkillum.core.warp_common.texture_from`). Entry
    ``i`` is texel ``i + 0.5``."""
    n = medium.sigma_table.shape[0]
    packed = wp.empty(n, dtype=wp.vec4f, device=medium.sigma_table.device)
    wp.launch(pack_optics_kernel, dim=n, inputs=[medium.sigma_table, medium.color_table, packed],
              device=packed.device)
    return texture_from(packed, current)


def scalar_texture(scalars):
    """A float ``wp.Texture3D`` of a point-centred scalar grid (warp ``array3d``), or None
    when the grid does not fit a texture."""
    if not fits_texture(scalars.shape):
        return None
    return texture_from(scalars)


def light_texture(data):
    """Per-light grids ``(n_lights, nx, ny, nz)`` (warp ``array4d``, contiguous) as one float
    texture with the lights stacked along depth, or None when that does not fit a texture."""
    n, nx, ny, nz = (int(v) for v in data.shape)
    if not fits_texture((n * nx, ny, nz)):
        return None
    if not data.is_contiguous:
        data = wp.clone(data)
    return texture_from(data.reshape((n * nx, ny, nz)))


def rgb_texture(data, unit: float):
    """An RGB grid (warp ``array3d(vec3)``) as an RGBA half texture in units of ``unit`` (its
    largest component; :func:`fetch_rgb` multiplies it back), or None when it does not fit."""
    if not fits_texture(data.shape):
        return None
    packed = wp.empty(data.shape, dtype=wp.vec4h, device=data.device)
    inv = 1.0 / unit if unit > 0.0 and np.isfinite(unit) else 0.0
    wp.launch(pack_rgb_kernel, dim=data.shape, inputs=[data, float(inv), packed],
              device=data.device)
    return texture_from(packed)


@wp.kernel
def pack_optics_kernel(sigma: wp.array(dtype=wp.float32), color: wp.array(dtype=wp.vec3),
                       out: wp.array(dtype=wp.vec4f)):
    """``out[i] = (color[i], sigma[i])``; ``wp.tid()`` is the table entry."""
    i = wp.tid()
    c = color[i]
    out[i] = wp.vec4f(c[0], c[1], c[2], sigma[i])


@wp.kernel
def pack_rgb_kernel(data: wp.array3d(dtype=wp.vec3), inv_unit: float,
                    out: wp.array3d(dtype=wp.vec4h)):
    """``out = (data * inv_unit, 0)`` in half precision; ``wp.tid()`` is ``(i, j, k)``."""
    i, j, k = wp.tid()
    v = data[i, j, k] * inv_unit
    out[i, j, k] = wp.vec4h(wp.float16(v[0]), wp.float16(v[1]), wp.float16(v[2]),
                            wp.float16(0.0))
