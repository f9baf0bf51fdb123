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
numpy's order of the grid, so no transposition is needed on either side. The ambient
mapper's float textures (:func:`pack_scalar`, :func:`pack_grey`) are in VTK's point order,
x fastest. Texels are held as 3D warp arrays (:func:`texel_shape`): a 1024³ grid's
4.3 billion values exceed what one warp array axis can index (2³¹).
"""

from __future__ import annotations

import numpy as np
import warp as wp

from vtkillum.core.device import init_warp
from vtkillum.core.device_arrays import STATS_THREADS

init_warp()


@wp.kernel
def _pack_transmittance(t: wp.array4d(dtype=wp.float32), lights: wp.vec4i, count: int,
                        scale: wp.vec4, out: wp.array3d(dtype=wp.uint16)):
    x, y, z = wp.tid()
    for k in range(4):
        value = float(0.0)
        if k < count:
            value = wp.rint(wp.clamp(t[lights[k], x, y, z] * scale[k], 0.0, 65535.0))
        out[x, y, z * 4 + k] = wp.uint16(value)


@wp.kernel
def _pack_fluence(s: wp.array3d(dtype=wp.vec3), scale: wp.vec4,
                  out: wp.array3d(dtype=wp.uint16)):
    x, y, z = wp.tid()
    v = s[x, y, z]
    for k in range(3):
        out[x, y, z * 4 + k] = wp.uint16(wp.rint(wp.clamp(v[k] * scale[k], 0.0, 65535.0)))
    out[x, y, z * 4 + 3] = wp.uint16(0)


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


def texel_shape(grid_shape, components: int = 4, x_fastest: bool = False) -> tuple:
    """Shape of the 3D warp array holding the texels of a grid of points ``grid_shape``
    ``(nx, ny, nz)`` with ``components`` per point: ``(nx, ny, nz * components)`` in the
    z-major order of the light grids, ``(nz, ny, nx * components)`` with x fastest (VTK's
    point order). Its C order is the texture's texel order."""
    nx, ny, nz = (int(n) for n in grid_shape)
    return (nz, ny, nx * components) if x_fastest else (nx, ny, nz * components)


def pack_transmittance(transmittance: wp.array, lights: list, out: wp.array) -> list:
    """Pack up to 4 lights of a device transmittance ``(n_lights, nx, ny, nz)`` (values in
    [0, 1], as :class:`~vtkillum.core.illumination.IlluminationVolume` checks them) into
    ``out`` (uint16, :func:`texel_shape`, on the same device); channels past
    ``len(lights)`` are 0. Returns the shader's factors ``q`` (all 1)."""
    if not 1 <= len(lights) <= 4:
        raise ValueError(f"1 to 4 lights a texture, got {len(lights)}")
    _check_out(out, texel_shape(transmittance.shape[1:]), wp.uint16, transmittance.device)
    index = wp.vec4i(*(list(lights) + [0] * (4 - len(lights))))
    wp.launch(_pack_transmittance, dim=transmittance.shape[1:],
              inputs=[transmittance, index, len(lights), wp.vec4(65535.0, 65535.0, 65535.0,
                                                                 65535.0), out],
              device=transmittance.device)
    return [1.0] * 4


def pack_fluence(scattered: wp.array, out: wp.array, tops: list | None = None) -> list:
    """Pack a device RGB fluence ``(nx, ny, nz)`` of vec3 into ``out`` (uint16,
    :func:`texel_shape`, same device), each channel scaled by its maximum (``tops``,
    default :func:`fluence_tops`). Returns the shader's factors ``q``."""
    _check_out(out, texel_shape(scattered.shape), wp.uint16, scattered.device)
    scale, q = texel_scales(fluence_tops(scattered) if tops is None else tops)
    wp.launch(_pack_fluence, dim=scattered.shape,
              inputs=[scattered, wp.vec4(*scale), out], device=scattered.device)
    return q


# --- float32 textures in VTK's point order (x fastest): the ambient mapper's inputs ---------------
@wp.kernel
def _scalar_x_fastest(src: wp.array3d(dtype=wp.float32), out: wp.array3d(dtype=wp.float32)):
    k, j, i = wp.tid()  # i fastest: the writes are consecutive
    out[k, j, i] = src[i, j, k]


@wp.kernel
def _grey_x_fastest(src: wp.array4d(dtype=wp.vec3), channel: wp.vec4i, divisor: wp.vec4d,
                    count: int, out: wp.array3d(dtype=wp.float32)):
    k, j, i = wp.tid()
    for light in range(4):
        value = float(0.0)
        if light < count:
            if divisor[light] > wp.float64(0.0):
                v = src[light, i, j, k]
                value = wp.float32(wp.float64(v[channel[light]]) / divisor[light])
        out[k, j, i * 4 + light] = value


@wp.kernel
def _grey_error(src: wp.array4d(dtype=wp.vec3), light: int, channel: int, colour: wp.vec3d,
                n: int, threads: int, out: wp.array(dtype=wp.float32)):
    """Thread ``wp.tid()`` takes points ``tid, tid + threads, ...`` of light ``light`` and
    folds into ``out`` its largest ``|L - (L[channel] / colour[channel]) colour|`` (float64
    arithmetic, as the host) and largest ``|L|``."""
    t = wp.tid()
    ny = src.shape[2]
    nz = src.shape[3]
    worst = wp.float64(0.0)
    top = wp.float64(0.0)
    p = t
    while p < n:
        v = src[light, p // (ny * nz), (p // nz) % ny, p % nz]
        g = wp.float64(v[channel]) / colour[channel]
        for c in range(3):
            value = wp.float64(v[c])
            worst = wp.max(worst, wp.abs(value - g * colour[c]))
            top = wp.max(top, wp.abs(value))
        p += threads
    wp.atomic_max(out, 0, wp.float32(worst))
    wp.atomic_max(out, 1, wp.float32(top))


def pack_scalar(src: wp.array, out: wp.array) -> None:
    """Copy a float32 grid ``(nx, ny, nz)`` into ``out`` (float32, ``texel_shape(shape, 1,
    x_fastest=True)``, same device) in VTK's point order, x fastest: what
    ``add_point_array`` makes on the host, bit for bit."""
    _check_out(out, texel_shape(src.shape, 1, x_fastest=True), wp.float32, src.device)
    wp.launch(_scalar_x_fastest, dim=src.shape[::-1], inputs=[src, out], device=src.device)


def _grey_divisors(colours, count: int) -> tuple[list, list]:
    """``(channel, divisor)`` per light: the colour's largest channel and its value (0 for
    a dark light, whose grey channel is 0), as the host's ``grey_radiance``."""
    channel, divisor = [0] * 4, [0.0] * 4
    for light in range(count):
        colour = colours[light]
        channel[light] = int(np.argmax(colour))
        if colour[channel[light]] > 0.0:
            divisor[light] = float(colour[channel[light]])
    return channel, divisor


def _grey_colours(cache: wp.array, colours) -> np.ndarray:
    colours = np.asarray(colours, dtype=np.float64).reshape(-1, 3)
    count = int(cache.shape[0])
    if not 1 <= count <= 4 or colours.shape[0] < count:
        raise ValueError(f"1 to 4 lights with a colour each, got {count} and {len(colours)}")
    return colours


def check_grey(cache: wp.array, colours) -> None:
    """Check on the device that light ``j`` of an RGB grid ``(n_lights <= 4, nx, ny, nz)``
    of vec3 is a grey factor times ``colours[j]`` (largest deviation at most 1e-4 of the
    light's largest value, float64 arithmetic, as the host's ``grey_radiance``).

    Raises
    ------
    RuntimeError
        Naming the first light that is not.
    """
    colours = _grey_colours(cache, colours)
    channel, divisor = _grey_divisors(colours, int(cache.shape[0]))
    n = int(np.prod(cache.shape[1:]))
    threads = max(1, min(n, STATS_THREADS["cpu" if cache.device.is_cpu else "cuda"]))
    for light in range(int(cache.shape[0])):
        if divisor[light] <= 0.0:
            continue
        errors = wp.zeros(2, dtype=wp.float32, device=cache.device)
        wp.launch(_grey_error, dim=threads,
                  inputs=[cache, light, channel[light], wp.vec3d(*colours[light]), n, threads,
                          errors], device=cache.device)
        worst, top = (float(v) for v in errors.numpy())
        if worst > 1e-4 * (top + 1e-30):
            raise RuntimeError(f"the radiance cache of light {light} is not grey times its "
                               "colour; the OpenGL path cannot store it (use the compute path)")


def pack_grey(cache: wp.array, colours, out: wp.array) -> None:
    """One grey channel per light of an RGB grid ``(n_lights <= 4, nx, ny, nz)`` of vec3 whose
    light ``j`` is ``f_j * colours[j]`` (:func:`check_grey` proves it): ``f_j = L_j[c] /
    colours[j][c]`` (``c`` the colour's largest channel, float64 division as on the host),
    into ``out`` (float32, ``texel_shape((nx, ny, nz), 4, x_fastest=True)``; unused
    channels and dark lights 0). The ambient mapper's radiance-cache texture, bit for bit its host twin
    ``ambient_volume_mapper.grey_radiance`` laid out by ``add_point_array``."""
    colours = _grey_colours(cache, colours)
    _check_out(out, texel_shape(cache.shape[1:], 4, x_fastest=True), wp.float32,
               cache.device)
    channel, divisor = _grey_divisors(colours, int(cache.shape[0]))
    wp.launch(_grey_x_fastest, dim=tuple(cache.shape[1:])[::-1],
              inputs=[cache, wp.vec4i(*channel), wp.vec4d(*divisor), int(cache.shape[0]), out],
              device=cache.device)


def _check_out(out: wp.array, shape: tuple, dtype, device) -> None:
    if out.dtype != dtype or tuple(out.shape) != tuple(shape) or not out.is_contiguous:
        raise ValueError(f"texels: need a contiguous {shape} array of {dtype.__name__}, got "
                         f"{out.shape} {out.dtype.__name__}")
    if str(out.device) != str(device):
        raise ValueError(f"texels on {out.device}, grid on {device}")
