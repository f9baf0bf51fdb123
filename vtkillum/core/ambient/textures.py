"""Optional hardware texture filtering of the ambient-scattering grids (CUDA only).

With ``hardware_filtering`` on, the tube march and the gather read ``σ̃t``, the
radiance cache and the data scalars through ``wp.Texture3D`` objects (CUDA
texture units, trilinear filtering in hardware: one fetch instead of eight
loads per sample) instead of the software trilinear interpolation of
:func:`~vtkillum.core.warp_common.trilinear`.

Accuracy: the texture units interpolate with 8-bit fractional weights (CUDA's
9-bit fixed-point format), so a sample may differ from the exact trilinear value
by up to about 1/256 of the difference between neighbouring grid values. On an
H200, single samples of smooth grids differed from the software path by up to
~4e-4 of the value range (mean ~3e-5); the tests require images and radiance
caches to agree within 2e-3 of their maximum on average (3e-2 at most). The default path stays the exact software one.

Layout: a point-centred grid ``a[i, j, k]`` of shape ``(nx, ny, nz)`` is a texture
of depth ``nx``, height ``ny`` and width ``nz`` (warp's ``(depth, height, width)``)
with unnormalised coordinates, so point ``(i, j, k)`` is the texel centre
``(k + 0.5, j + 0.5, i + 0.5)``; clamp addressing gives the value of the nearest
border point outside the grid, as the software path's clamping does. The radiance
cache of all lights is one RGBA half-precision texture with the lights stacked along the
depth axis (``[light * nx + i, j, k]``), each light in units of its brightest irradiance
(:func:`~vtkillum.core.ambient.tube_march.radiance_unit`, so nothing overflows; relative
rounding 2⁻¹¹); samples are clamped into their light's slab, so no light's radiance
filters into another's. The table slice ``L̃o(θ, r σ̃t)`` is a 2D float texture
(θ rows, ``r σ̃t`` columns), bilinearly filtered. The transfer function's tables
(``Medium.color_table`` and ``Medium.sigma_table``) are one 1D RGBA float texture
(colour in RGB, ``σt`` in A; :func:`optics_texture`), so one fetch per sample gives
both instead of two software lerps of 4096-entry arrays; likewise the gather reads the
data scalars and ``σ̃t`` from one two-channel texture (:func:`data_texture`).

Textures cannot be written by kernels in warp 1.19 (``surface_access`` only exposes a
raw CUDA handle), so each grid is computed into a warp array and copied into its
texture (a device-to-array copy, about 0.1 ms for a 216³ half-precision RGBA cache on an
H200).
"""

from __future__ import annotations

from dataclasses import dataclass

import warp as wp

from vtkillum.core.device import init_warp

# The overloads shared with the ray caster live in vtkillum.core.textures; the gather and
# the tube march import them from here with the ambient-only ones below.
from vtkillum.core.textures import (  # noqa: F401
    fetch_optics,
    fetch_scalar,
    optics_color,
    optics_texture,
    textures_available,
)
from vtkillum.core.warp_common import sample_scalar, texture_from

init_warp()


@dataclass
class AmbientTextures:
    """The textures the gather samples instead of arrays (see the module docstring).

    Attributes
    ----------
    scalars : wp.Texture3D
        The data scalars and ``σ̃t`` side by side (two channels, :func:`data_texture`),
        ``(nx, ny, nz)``: one fetch gives the gather both.
    sigma_tilde : wp.Texture3D
        Ambient extinction ``σ̃t``, float, ``(nx, ny, nz)`` (for the tube march).
    radiance : wp.Texture3D
        Radiance cache, RGBA half precision, lights stacked along the depth axis.
    table : wp.Texture2D or None
        The table slice ``L̃o`` at the scene's ``g`` (None: the gather makes one from the
        table array it is given).
    optics : wp.Texture1D or None
        The transfer function's colour (RGB) and ``σt`` (A) tables (:func:`optics_texture`;
        None: the gather makes one from the medium).
    scattered : wp.Texture2D or None
        The table's scattered part ``M`` at the scene's ``g`` (the centred gather's table;
        None: the gather makes one from the array it is given).
    """

    scalars: object
    sigma_tilde: object
    radiance: object
    table: object = None
    optics: object = None
    scattered: object = None


#: Whether a device has texture units (a CUDA device): the shared test, under the name the
#: ambient cache uses.
hardware_filtering_available = textures_available


def data_texture(scalars, sigma_tilde, current=None):
    """The scalars and ``σ̃t`` (warp arrays of one shape) as one two-channel float texture
    (``current`` is overwritten when it fits; see :func:`texture_from`)."""
    pair = wp.empty(scalars.shape, dtype=wp.vec2f, device=scalars.device)
    wp.launch(pack_data_kernel, dim=scalars.shape, inputs=[scalars, sigma_tilde, pair],
              device=scalars.device)
    return texture_from(pair, current)


# --- device functions: one name, an array overload (exact) and a texture overload ----------------
# (the radiance cache's pair, ``fetch_radiance``, is in :mod:`~vtkillum.core.ambient.gather`)
@wp.func
def fetch_data(src: wp.array3d(dtype=wp.float32), inv_spacing: wp.vec3, p: wp.vec3):
    """The scalar at ``p`` (software trilinear) in the first component; ``σ̃t`` is not
    fetched here (see :func:`fetch_ambient`)."""
    return wp.vec2(sample_scalar(src, inv_spacing, p), 0.0)


@wp.func
def fetch_data(src: wp.Texture3D, inv_spacing: wp.vec3, p: wp.vec3):  # noqa: F811
    """Scalar and ``σ̃t`` at ``p`` by one hardware-filtered fetch of the :func:`data_texture`."""
    u = wp.cw_mul(p, inv_spacing)
    return wp.texture_sample(src, wp.vec3(u[2] + 0.5, u[1] + 0.5, u[0] + 0.5), dtype=wp.vec2f)


@wp.func
def fetch_ambient(src: wp.array3d(dtype=wp.float32), inv_spacing: wp.vec3, p: wp.vec3,
                  data: wp.vec2):
    """``σ̃t`` at ``p`` by software trilinear interpolation of ``src``."""
    return sample_scalar(src, inv_spacing, p)


@wp.func
def fetch_ambient(src: int, inv_spacing: wp.vec3, p: wp.vec3, data: wp.vec2):  # noqa: F811
    """``σ̃t`` from the :func:`fetch_data` result (already fetched with the scalar)."""
    return data[1]


@wp.kernel
def pack_data_kernel(scalars: wp.array3d(dtype=wp.float32),
                     sigma_tilde: wp.array3d(dtype=wp.float32),
                     out: wp.array3d(dtype=wp.vec2f)):
    """``out[i, j, k] = (scalars, sigma_tilde)[i, j, k]``; ``wp.tid()`` is ``(i, j, k)``."""
    i, j, k = wp.tid()
    out[i, j, k] = wp.vec2f(scalars[i, j, k], sigma_tilde[i, j, k])
