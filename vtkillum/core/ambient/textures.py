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
(θ rows, ``r σ̃t`` columns), bilinearly filtered.

Textures cannot be written by kernels in warp 1.19 (``surface_access`` only exposes a
raw CUDA handle), so each grid is computed into a warp array and copied into its
texture (a device-to-array copy, about 0.1 ms for a 216³ half-precision RGBA cache on an
H200).
"""

from __future__ import annotations

from dataclasses import dataclass

import warp as wp

from vtkillum.core.device import init_warp
from vtkillum.core.warp_common import sample_scalar

init_warp()

#: Largest texture extent along any axis that every CUDA GPU of compute capability >= 3 supports.
MAX_TEXTURE_EXTENT = 16384


@dataclass
class AmbientTextures:
    """The textures the gather samples instead of arrays (see the module docstring).

    Attributes
    ----------
    scalars : wp.Texture3D
        The data scalars, float, ``(nx, ny, nz)``.
    sigma_tilde : wp.Texture3D
        Ambient extinction ``σ̃t``, float, ``(nx, ny, nz)``.
    radiance : wp.Texture3D
        Radiance cache, RGBA half precision, lights stacked along the depth axis.
    table : wp.Texture2D or None
        The table slice ``L̃o`` at the scene's ``g`` (None: the gather makes one from the
        table array it is given).
    """

    scalars: object
    sigma_tilde: object
    radiance: object
    table: object = None


def hardware_filtering_available(device: str) -> bool:
    """Whether ``device`` has texture units (a CUDA device)."""
    return wp.get_device(device).is_cuda


def fits_texture(shape) -> bool:
    """Whether a grid of ``shape`` (depth, height, width) fits a 3D texture."""
    return all(1 <= int(n) <= MAX_TEXTURE_EXTENT for n in shape)


def texture_from(array, current=None):
    """A linearly filtered, clamped ``wp.Texture3D`` (or ``wp.Texture2D``) holding ``array``.

    ``array`` is a contiguous warp array of shape ``(depth, height, width)`` (or
    ``(height, width)``) of float32, vec4 or vec4h. ``current`` is overwritten (one device
    copy, no allocation) when it has the same shape, element type and channel count and
    lives on the same device; otherwise a new texture is made.
    """
    channels = int(getattr(array.dtype, "_length_", 1))  # vec4: 4, float32: 1
    scalar = getattr(array.dtype, "_wp_scalar_type_", array.dtype)
    shape = tuple(int(n) for n in array.shape[:3])
    cls = wp.Texture2D if len(shape) == 2 else wp.Texture3D
    if (isinstance(current, cls) and _texture_shape(current) == shape
            and current.num_channels == channels and current.dtype == scalar
            and current.device == array.device):
        current.copy_from(array)
        return current
    return cls(array, filter_mode=wp.TextureFilterMode.LINEAR,
               address_mode=wp.TextureAddressMode.CLAMP, normalized_coords=False,
               device=array.device)


def _texture_shape(texture) -> tuple:
    """A texture's array shape: ``(height, width)`` or ``(depth, height, width)``."""
    if isinstance(texture, wp.Texture2D):
        return (texture.height, texture.width)
    return (texture.depth, texture.height, texture.width)


# --- device functions: one name, an array overload (exact) and a texture overload ----------------
# (the radiance cache's pair, ``fetch_radiance``, is in :mod:`~vtkillum.core.ambient.gather`)
@wp.func
def fetch_scalar(src: wp.array3d(dtype=wp.float32), inv_spacing: wp.vec3, p: wp.vec3):
    """Software trilinear sample of a point-centred scalar grid at local position ``p``."""
    return sample_scalar(src, inv_spacing, p)


@wp.func
def fetch_scalar(src: wp.Texture3D, inv_spacing: wp.vec3, p: wp.vec3):  # noqa: F811
    """Hardware-filtered sample of a point-centred scalar grid at local position ``p``."""
    u = wp.cw_mul(p, inv_spacing)
    return wp.texture_sample(src, wp.vec3(u[2] + 0.5, u[1] + 0.5, u[0] + 0.5), dtype=float)
