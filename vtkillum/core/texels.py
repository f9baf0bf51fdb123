"""16-bit texels of light grids, packed where the grids live (warp kernels).

The OpenGL mapper (:class:`~vtkillum.mappers.illuminated_volume_mapper.IlluminatedVolume`)
draws per-light transmittance and scattered fluence from 4-component, 16-bit normalised
3D textures: ``stored = rint(clip(v * float32(65535 / top), 0, 65535))`` per channel, with
``top = 1`` for transmittances and the channel's maximum for fluences (the mapper's
``pack_channels`` does this in numpy). The kernels here give the same texels, bit for bit,
from the warp arrays a light method leaves on its device, so that a grid computed on a GPU
reaches an OpenGL texture without a trip through the host (see
:mod:`vtkillum.mappers.texture_upload`).

Texel order: the texture is z-major, ``[x, y, z, 4]`` in C order (z fastest), which is
numpy's order of the grid, so no transposition is needed on either side.
"""

from __future__ import annotations

import numpy as np
import warp as wp

from vtkillum.core.device import init_warp
from vtkillum.core.device_arrays import STATS_THREADS

init_warp()


@wp.kernel
def _pack_transmittance(t: wp.array4d(dtype=wp.float32), lights: wp.vec4i, count: int,
                        scale: wp.vec4, out: wp.array(dtype=wp.uint16)):
    x, y, z = wp.tid()
    ny = t.shape[2]
    nz = t.shape[3]
    base = ((x * ny + y) * nz + z) * 4
    for k in range(4):
        value = float(0.0)
        if k < count:
            value = wp.rint(wp.clamp(t[lights[k], x, y, z] * scale[k], 0.0, 65535.0))
        out[base + k] = wp.uint16(value)


@wp.kernel
def _pack_fluence(s: wp.array3d(dtype=wp.vec3), scale: wp.vec4,
                  out: wp.array(dtype=wp.uint16)):
    x, y, z = wp.tid()
    ny = s.shape[1]
    nz = s.shape[2]
    base = ((x * ny + y) * nz + z) * 4
    v = s[x, y, z]
    for k in range(3):
        out[base + k] = wp.uint16(wp.rint(wp.clamp(v[k] * scale[k], 0.0, 65535.0)))
    out[base + 3] = wp.uint16(0)


@wp.kernel
def _channel_maxima(s: wp.array(dtype=wp.vec3), n: int, threads: int,
                    out: wp.array(dtype=wp.float32)):
    """Thread ``wp.tid()`` takes points ``tid, tid + threads, ...`` and folds its own
    maxima into ``out``: one atomic per thread and channel, not per point (a 512³ grid's
    134 million atomics on three addresses take most of a second on a GPU)."""
    t = wp.tid()
    top = wp.vec3(-3.0e38, -3.0e38, -3.0e38)
    i = t
    while i < n:
        top = wp.max(top, s[i])
        i += threads
    for k in range(3):
        wp.atomic_max(out, k, top[k])


def fluence_tops(scattered: wp.array) -> list[float]:
    """Each RGB channel's maximum of a device fluence grid (one launch, three numbers back)."""
    if not scattered.is_contiguous:
        raise ValueError("fluence_tops needs a contiguous grid")
    n = int(scattered.size)
    flat = wp.array(ptr=scattered.ptr, dtype=wp.vec3, shape=(n,), device=scattered.device)
    threads = max(1, min(n, STATS_THREADS["cpu" if scattered.device.is_cpu else "cuda"]))
    out = wp.full(3, -np.inf, dtype=wp.float32, device=scattered.device)
    wp.launch(_channel_maxima, dim=threads, inputs=[flat, n, threads, out],
              device=scattered.device)
    return [float(v) for v in out.numpy()]


def texel_scales(tops) -> tuple[list, list]:
    """``(scale, q)`` of up to 4 channels with maxima ``tops`` (1 for transmittances):
    ``float32(65535 / top)`` per channel (0 for a channel without a positive finite top,
    stored as 0) and the shader's factor. The rule of every 16-bit light texel, packed
    here or by the mapper's ``pack_channels`` on the host."""
    scale, q = [0.0] * 4, [1.0] * 4
    for k, top in enumerate(tops):
        if top > 0 and np.isfinite(top):
            q[k] = float(top)
            scale[k] = float(np.float32(65535.0 / top))
    return scale, q


def fluence_factors(tops) -> list:
    """The shader's factors ``q`` of a fluence packed with channel maxima ``tops``."""
    return texel_scales(tops)[1]


def texel_count(grid_shape) -> int:
    """uint16 values of the 4-component texture of a grid with points ``grid_shape``."""
    return 4 * int(np.prod(grid_shape))


def pack_transmittance(transmittance: wp.array, lights: list, out: wp.array) -> list:
    """Pack up to 4 lights of a device transmittance ``(n_lights, nx, ny, nz)`` (values in
    [0, 1], as :class:`~vtkillum.core.illumination.IlluminationVolume` checks them) into
    ``out`` (uint16, :func:`texel_count` long, on the same device); channels past
    ``len(lights)`` are 0. Returns the shader's factors ``q`` (all 1)."""
    if not 1 <= len(lights) <= 4:
        raise ValueError(f"1 to 4 lights a texture, got {len(lights)}")
    _check_out(out, transmittance.shape[1:], transmittance.device)
    index = wp.vec4i(*(list(lights) + [0] * (4 - len(lights))))
    wp.launch(_pack_transmittance, dim=transmittance.shape[1:],
              inputs=[transmittance, index, len(lights), wp.vec4(65535.0, 65535.0, 65535.0,
                                                                 65535.0), out],
              device=transmittance.device)
    return [1.0] * 4


def pack_fluence(scattered: wp.array, out: wp.array, tops: list | None = None) -> list:
    """Pack a device RGB fluence ``(nx, ny, nz)`` of vec3 into ``out`` (uint16,
    :func:`texel_count` long, same device), each channel scaled by its maximum (``tops``,
    default :func:`fluence_tops`). Returns the shader's factors ``q``."""
    _check_out(out, scattered.shape, scattered.device)
    scale, q = texel_scales(fluence_tops(scattered) if tops is None else tops)
    wp.launch(_pack_fluence, dim=scattered.shape,
              inputs=[scattered, wp.vec4(*scale), out], device=scattered.device)
    return q


def _check_out(out: wp.array, grid_shape, device) -> None:
    if out.dtype != wp.uint16 or out.ndim != 1 or out.shape[0] != texel_count(grid_shape):
        raise ValueError(f"texels: need {texel_count(grid_shape)} uint16 values, got "
                         f"{out.shape} {out.dtype}")
    if str(out.device) != str(device):
        raise ValueError(f"texels on {out.device}, grid on {device}")
