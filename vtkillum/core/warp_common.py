"""Warp structures and functions every kernel shares, and the host code that fills them.

Kernels work in a volume's local frame (see :mod:`vtkillum.core.volume`): the
volume spans ``[0, extent]``; camera and lights are mapped into that frame on the
host, so kernels never see the direction matrix. Data are point-centred and
sampled trilinearly, with the transfer function applied after interpolation
(post-classification, as VTK's ray caster does).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import warp as wp

from vtkillum.core.device import init_warp, resolve_device
from vtkillum.core.device_arrays import upload
from vtkillum.core.lights import pack_lights, resolved_radius
from vtkillum.core.transfer_function import MAX_ALPHA, TABLE_SIZE, check_unit_distance

init_warp()

DIRECTIONAL = wp.constant(0)
POINT = wp.constant(1)
#: The transfer function's largest opacity, in kernels.
TABLE_MAX_ALPHA = wp.constant(MAX_ALPHA)
#: Distance used for "infinitely far" (directional lights).
FAR = wp.constant(1.0e30)


@wp.struct
class Medium:
    """Scalar volume plus transfer-function tables: the optical model on the device."""

    scalars: wp.array3d(dtype=wp.float32)  # [i, j, k], point-centred
    extent: wp.vec3  # local-frame size (n - 1) * spacing
    inv_spacing: wp.vec3
    sigma_table: wp.array(dtype=wp.float32)  # sigma_t per table entry (1/world units)
    color_table: wp.array(dtype=wp.vec3)  # colour per table entry
    table_lo: float  # data value of entry 0
    table_scale: float  # entries per data unit
    albedo: float
    g: float  # Henyey–Greenstein anisotropy
    majorant: float  # upper bound of sigma_t over the volume (delta tracking)
    # Blocks of cells where sigma_t may be non-zero (1) or is exactly 0 everywhere (0), see
    # vtkillum.core.empty_space; block extent and its inverse (world units).
    occupied: wp.array3d(dtype=wp.int32)
    block: wp.vec3
    inv_block: wp.vec3


@wp.struct
class RGBGrid:
    """An RGB volume (e.g. an illumination volume) covering ``[0, extent]`` of the local frame."""

    data: wp.array3d(dtype=wp.vec3)
    extent: wp.vec3
    inv_spacing: wp.vec3


@wp.struct
class LightGrid:
    """Per-light scalars (e.g. transmittance ``T_l``) on a grid covering ``[0, extent]``.

    ``data[l, i, j, k]`` is light ``l``'s value at grid point ``[i, j, k]``; ``count`` is
    the number of lights (0: an empty placeholder that kernels never read); ``near`` is
    the distance (world units) that lookups march exactly before reading the grid
    (:func:`vtkillum.core.raycast.cached_transmittance`).
    """

    data: wp.array4d(dtype=wp.float32)
    inv_spacing: wp.vec3
    count: int
    near: float


@wp.struct
class CameraParams:
    """A camera in the local frame; see :mod:`vtkillum.core.camera` for pixel conventions."""

    position: wp.vec3
    right: wp.vec3
    up: wp.vec3
    forward: wp.vec3
    tan_half: float  # tan(view_angle / 2)
    aspect: float  # width / height
    parallel: int
    parallel_scale: float
    width: int
    height: int


@wp.struct
class Lights:
    """Light list: kind (0 directional, 1 point), travel direction or position, RGB, and
    the source radius of point lights (irradiance ``I / max(d, radius)**2``)."""

    kind: wp.array(dtype=wp.int32)
    vec: wp.array(dtype=wp.vec3)
    rgb: wp.array(dtype=wp.vec3)
    radius: wp.array(dtype=wp.float32)
    count: int


# --- sampling -----------------------------------------------------------------------------------
@wp.func
def trilinear_index(p: wp.vec3, inv_spacing: wp.vec3, shape: wp.vec3i):
    """Cell index (clamped so that index + 1 is valid) and fractions for point ``p``."""
    u = wp.cw_mul(p, inv_spacing)
    i = wp.clamp(int(wp.floor(u[0])), 0, shape[0] - 2)
    j = wp.clamp(int(wp.floor(u[1])), 0, shape[1] - 2)
    k = wp.clamp(int(wp.floor(u[2])), 0, shape[2] - 2)
    f = wp.vec3(
        wp.clamp(u[0] - float(i), 0.0, 1.0),
        wp.clamp(u[1] - float(j), 0.0, 1.0),
        wp.clamp(u[2] - float(k), 0.0, 1.0),
    )
    return wp.vec3i(i, j, k), f


@wp.func
def trilinear(a: wp.array3d(dtype=Any), inv_spacing: wp.vec3, p: wp.vec3):
    """Trilinear sample at local position ``p`` of a point-centred grid of any lerp-able dtype.

    Generic over the array's dtype (warp compiles one overload per dtype it is called with),
    so scalar and RGB grids share one body at no run-time cost.
    """
    idx, f = trilinear_index(p, inv_spacing, wp.vec3i(a.shape[0], a.shape[1], a.shape[2]))
    return cell_trilinear(a, idx, f)


@wp.func
def cell_trilinear(a: wp.array3d(dtype=Any), idx: wp.vec3i, f: wp.vec3):
    """Trilinear blend of the 8 points of ``a`` from ``idx`` to ``idx + 1`` with fractions
    ``f`` (what :func:`trilinear` and pieces of a grid, ``piece_sample``, share)."""
    i = idx[0]
    j = idx[1]
    k = idx[2]
    c00 = wp.lerp(a[i, j, k], a[i + 1, j, k], f[0])
    c10 = wp.lerp(a[i, j + 1, k], a[i + 1, j + 1, k], f[0])
    c01 = wp.lerp(a[i, j, k + 1], a[i + 1, j, k + 1], f[0])
    c11 = wp.lerp(a[i, j + 1, k + 1], a[i + 1, j + 1, k + 1], f[0])
    return wp.lerp(wp.lerp(c00, c10, f[1]), wp.lerp(c01, c11, f[1]), f[2])


@wp.func
def sample_scalar(a: wp.array3d(dtype=wp.float32), inv_spacing: wp.vec3, p: wp.vec3):
    """Trilinear sample of a point-centred scalar grid at local position ``p``."""
    return trilinear(a, inv_spacing, p)


@wp.func
def sample_rgb(grid: RGBGrid, p: wp.vec3):
    """Trilinear sample of an RGB grid at local position ``p``."""
    return trilinear(grid.data, grid.inv_spacing, p)


@wp.func
def sample_light_grid(grid: LightGrid, li: int, p: wp.vec3):
    """Trilinear sample of light ``li``'s channel of a :class:`LightGrid` at local position ``p``."""
    a = grid.data
    idx, f = trilinear_index(p, grid.inv_spacing, wp.vec3i(a.shape[1], a.shape[2], a.shape[3]))
    i = idx[0]
    j = idx[1]
    k = idx[2]
    c00 = wp.lerp(a[li, i, j, k], a[li, i + 1, j, k], f[0])
    c10 = wp.lerp(a[li, i, j + 1, k], a[li, i + 1, j + 1, k], f[0])
    c01 = wp.lerp(a[li, i, j, k + 1], a[li, i + 1, j, k + 1], f[0])
    c11 = wp.lerp(a[li, i, j + 1, k + 1], a[li, i + 1, j + 1, k + 1], f[0])
    return wp.lerp(wp.lerp(c00, c10, f[1]), wp.lerp(c01, c11, f[1]), f[2])


@wp.func
def table_coord(m: Medium, s: float):
    """Continuous table coordinate of data value ``s`` (clamped: constant outside)."""
    n = m.sigma_table.shape[0]
    return wp.clamp((s - m.table_lo) * m.table_scale, 0.0, float(n - 1))


@wp.func
def table_lerp(table: wp.array(dtype=Any), x: float):
    """Linear interpolation of a 1D table at continuous index ``x`` in ``[0, n - 1]``."""
    i = wp.min(int(x), table.shape[0] - 2)
    return wp.lerp(table[i], table[i + 1], x - float(i))


@wp.func
def lookup_sigma_t(m: Medium, s: float):
    """σt (1/world units) of data value ``s``."""
    return table_lerp(m.sigma_table, table_coord(m, s))


@wp.func
def lookup_color(m: Medium, s: float):
    """Scattering colour of data value ``s``."""
    return table_lerp(m.color_table, table_coord(m, s))


@wp.func
def inside_box(p: wp.vec3, extent: wp.vec3):
    return (p[0] >= 0.0 and p[1] >= 0.0 and p[2] >= 0.0
            and p[0] <= extent[0] and p[1] <= extent[1] and p[2] <= extent[2])


def capped_kernel(registers: int, **options):
    """``wp.kernel`` with a cap on the registers per thread of its CUDA code (warp >= 1.10's
    ``cuda_max_registers``; a plain ``wp.kernel`` where warp has no such option, or for a
    cap of 0); ``options`` go to ``wp.kernel`` (e.g. ``name`` and ``module`` for kernels
    made by a factory)."""
    if int(registers) > 0:
        try:
            return wp.kernel(cuda_max_registers=int(registers), **options)
        except TypeError:
            pass
    return wp.kernel(**options) if options else wp.kernel


class HostReader:
    """The values of a small device array on the host, read repeatedly (e.g. a solver's
    residual sums after every iteration): on CUDA through a pinned host array kept between
    reads. ``array.numpy()`` makes a new host array and a pageable copy each time: 44 µs
    for six doubles on an H100, this 15.

    Parameters
    ----------
    array : warp.array
        The device array (contiguous).
    """

    def __init__(self, array: wp.array) -> None:
        self.array = array
        self._host = None
        self._view = None

    def read(self, count: int | None = None) -> np.ndarray:
        """A host copy of the array's current values, or of its first ``count`` entries
        (waits for the work queued before)."""
        n = self.array.shape[0] if count is None else int(count)
        if not self.array.device.is_cuda:
            return self.array.numpy()[:n].copy()  # (a view of the array itself otherwise)
        if self._host is None:
            self._host = wp.empty(self.array.shape, dtype=self.array.dtype, device="cpu",
                                  pinned=True)
            self._view = self._host.numpy()
        wp.copy(self._host, self.array, count=n)
        wp.synchronize_stream(wp.get_stream(self.array.device))
        return self._view[:n].copy()


class HostWriter:
    """Upload new values into a device array, repeatedly (e.g. transfer-function tables on
    every edit): on CUDA through a pinned host array kept between writes, so the copy is
    asynchronous and needs no allocation (``wp.array(values, device=...)`` allocates and
    makes a pageable, synchronous copy every time).

    Parameters
    ----------
    array : warp.array
        The device array (contiguous), overwritten by :meth:`write`.
    """

    def __init__(self, array: wp.array) -> None:
        self.array = array
        cuda = array.device.is_cuda
        self._host = wp.empty(array.shape, dtype=array.dtype, device="cpu", pinned=cuda)
        self._view = self._host.numpy()
        self._done = wp.Event(array.device) if cuda else None
        self._pending = False

    def write(self, values: np.ndarray) -> None:
        """Copy ``values`` (the array's shape, as numpy gives it, or the first entries of a
        1-D array) into the device array, queued after the work before it."""
        if self._pending:  # the previous copy must have left the staging array
            wp.synchronize_event(self._done)
        count = len(values)
        self._view[:count] = values
        wp.copy(self.array, self._host, count=count)
        if self._done is not None:
            wp.get_stream(self.array.device).record_event(self._done)
            self._pending = True


#: Device tables kept by :func:`cached_tables` (most recently used last).
_TABLES: dict = {}
TABLE_CACHE_SIZE = 64


def cached_tables(key, build):
    """Small device arrays (per-light parameters that kernels read) built by ``build()``
    once per ``key``, and reused by later calls with the same key: an upload is a
    synchronous copy, which costs an interactive update more than its launches. At most
    :data:`TABLE_CACHE_SIZE` keys are kept, the least recently used dropped first; the
    key must hold the device and everything the tables are built from."""
    tables = _TABLES.pop(key, None)
    if tables is None:
        tables = build()
    _TABLES[key] = tables
    while len(_TABLES) > TABLE_CACHE_SIZE:
        _TABLES.pop(next(iter(_TABLES)))
    return tables


@wp.func_native("""
#if defined(__CUDA_ARCH__)
return 1;
#else
return 0;
#endif
""")
def compiled_for_cuda() -> int:
    """1 in code compiled for a CUDA device, 0 in code compiled for the CPU: a branch on it
    is resolved by the compiler, so each device keeps only its own path (a run-time flag
    in a kernel argument would keep both, and their registers, on the GPU)."""
    ...


#: Largest texture extent along any axis that every CUDA GPU of compute capability >= 3 supports.
MAX_TEXTURE_EXTENT = 16384


def fits_texture(shape) -> bool:
    """Whether a grid of ``shape`` (depth, height, width) fits a 3D texture."""
    return all(1 <= int(n) <= MAX_TEXTURE_EXTENT for n in shape)


def texture_from(array, current=None):
    """A linearly filtered, clamped ``wp.Texture3D`` (``wp.Texture2D``, ``wp.Texture1D``)
    holding ``array``.

    ``array`` is a contiguous warp array of shape ``(depth, height, width)`` (or
    ``(height, width)``, or ``(width,)``) of float32, vec4 or vec4h. ``current`` is
    overwritten (one device copy, no allocation) when it has the same shape, element type
    and channel count and lives on the same device; otherwise a new texture is made.
    """
    channels = int(getattr(array.dtype, "_length_", 1))  # vec4: 4, float32: 1
    scalar = getattr(array.dtype, "_wp_scalar_type_", array.dtype)
    shape = tuple(int(n) for n in array.shape[:3])
    cls = {1: wp.Texture1D, 2: wp.Texture2D, 3: wp.Texture3D}[len(shape)]
    if (isinstance(current, cls) and _texture_shape(current) == shape
            and current.num_channels == channels and current.dtype == scalar
            and current.device == array.device):
        current.copy_from(array)
        return current
    return cls(array, filter_mode=wp.TextureFilterMode.LINEAR,
               address_mode=wp.TextureAddressMode.CLAMP, normalized_coords=False,
               device=array.device)


def _texture_shape(texture) -> tuple:
    """A texture's array shape: ``(width,)``, ``(height, width)`` or ``(depth, height, width)``."""
    if isinstance(texture, wp.Texture1D):
        return (texture.width,)
    if isinstance(texture, wp.Texture2D):
        return (texture.height, texture.width)
    return (texture.depth, texture.height, texture.width)


@wp.func
def grid_index(primary: int, p: int, a: int, b: int):
    """Point index with ``p`` on the primary axis and ``a, b`` on the other two in order."""
    if primary == 0:
        return wp.vec3i(p, a, b)
    if primary == 1:
        return wp.vec3i(a, p, b)
    return wp.vec3i(a, b, p)


@wp.func
def axis_offset(axis: int, value: int):
    """``value`` times the unit index vector of ``axis``.

    Built with selects, like :func:`component`: indexing a vector with a
    run-time axis (``p[axis]``) makes CUDA keep it in local memory.
    """
    return wp.vec3i(wp.where(axis == 0, value, 0), wp.where(axis == 1, value, 0),
                    wp.where(axis == 2, value, 0))


@wp.func
def component(v: Any, axis: int):
    """``v[axis]`` for a run-time ``axis`` (see :func:`axis_offset`)."""
    return wp.where(axis == 0, v[0], wp.where(axis == 1, v[1], v[2]))


@wp.func
def grid_point(i: int, j: int, k: int, spacing: wp.vec3):
    """Local position of point ``[i, j, k]`` of a regular grid with ``spacing`` starting at 0."""
    return wp.vec3(float(i) * spacing[0], float(j) * spacing[1], float(k) * spacing[2])


@wp.func
def sigma_t_at(m: Medium, p: wp.vec3):
    """Extinction at local position ``p`` (0 outside the volume)."""
    if not inside_box(p, m.extent):
        return 0.0
    return lookup_sigma_t(m, sample_scalar(m.scalars, m.inv_spacing, p))


@wp.func
def ray_box(o: wp.vec3, d: wp.vec3, extent: wp.vec3):
    """Entry and exit distances of the ray ``o + t d`` through ``[0, extent]`` (t0 > t1: miss)."""
    t0 = float(-1.0e30)
    t1 = float(1.0e30)
    for a in range(3):
        if wp.abs(d[a]) < 1.0e-12:
            if o[a] < 0.0 or o[a] > extent[a]:
                t0 = 1.0e30
                t1 = -1.0e30
        else:
            inv = 1.0 / d[a]
            ta = (0.0 - o[a]) * inv
            tb = (extent[a] - o[a]) * inv
            t0 = wp.max(t0, wp.min(ta, tb))
            t1 = wp.min(t1, wp.max(ta, tb))
    return wp.vec2(t0, t1)


@wp.func
def scalar_gradient(a: wp.array3d(dtype=wp.float32), inv_spacing: wp.vec3, p: wp.vec3):
    """Central-difference gradient at ``p``, one voxel either side (data units per world unit)."""
    sx = 1.0 / inv_spacing[0]
    sy = 1.0 / inv_spacing[1]
    sz = 1.0 / inv_spacing[2]
    return wp.vec3(
        (sample_scalar(a, inv_spacing, p + wp.vec3(sx, 0.0, 0.0))
         - sample_scalar(a, inv_spacing, p - wp.vec3(sx, 0.0, 0.0))) / (2.0 * sx),
        (sample_scalar(a, inv_spacing, p + wp.vec3(0.0, sy, 0.0))
         - sample_scalar(a, inv_spacing, p - wp.vec3(0.0, sy, 0.0))) / (2.0 * sy),
        (sample_scalar(a, inv_spacing, p + wp.vec3(0.0, 0.0, sz))
         - sample_scalar(a, inv_spacing, p - wp.vec3(0.0, 0.0, sz))) / (2.0 * sz),
    )


@wp.func
def view_normal(m: Medium, p: wp.vec3, d: wp.vec3, grad_eps: float):
    """Unit data gradient at ``p`` facing the viewer, or the zero vector where it vanishes.

    ``d`` is the ray direction (pointing away from the camera); the normal is flipped to
    face the camera (two-sided lighting). "Vanishes" means ``|gradient| <= grad_eps``
    (data units per world unit, see :func:`vtkillum.core.illumination.gradient_threshold`).
    """
    grad = scalar_gradient(m.scalars, m.inv_spacing, p)
    glen = wp.length(grad)
    if glen <= grad_eps:
        return wp.vec3(0.0)
    n = grad / glen
    if wp.dot(n, d) > 0.0:
        n = -n
    return n


@wp.func
def block_run(m: Medium, o: wp.vec3, d: wp.vec3, h: float, k: int, frac: float):
    """Whether sample ``k`` of a march, ``o + (k + frac) h d``, lies in an exactly empty
    block of ``m`` (1 or 0), and the last step ``>= k`` whose sample is in the same block.

    Returns ``(empty, last)``. A march skips the samples of an empty block: they would add
    exactly 0 to its optical depth (:mod:`vtkillum.core.empty_space`).
    """
    p = o + ((float(k) + frac) * h) * d
    bi = wp.clamp(int(wp.floor(p[0] * m.inv_block[0])), 0, m.occupied.shape[0] - 1)
    bj = wp.clamp(int(wp.floor(p[1] * m.inv_block[1])), 0, m.occupied.shape[1] - 1)
    bk = wp.clamp(int(wp.floor(p[2] * m.inv_block[2])), 0, m.occupied.shape[2] - 1)
    lo = wp.cw_mul(wp.vec3(float(bi), float(bj), float(bk)), m.block)
    t_exit = ray_box(o - lo, d, m.block)[1]
    # Last step whose sample (j + frac) h is before the exit (at least k: p is inside),
    # clamped in floating point first: a huge block (no skipping) or step ratio must not
    # overflow the integer.
    last_f = wp.ceil(t_exit / h - frac) - 1.0
    last = k
    if last_f > float(k):
        last = int(wp.min(last_f, 1.0e9))
    return 1 - wp.min(m.occupied[bi, bj, bk], 1), last


# --- sources: one name, an array overload (exact) and a texture overload (vtkillum.core.textures)
@wp.func
def fetch_scalar(src: wp.array3d(dtype=wp.float32), inv_spacing: wp.vec3, p: wp.vec3):
    """Software trilinear sample of a point-centred scalar grid at local position ``p``."""
    return sample_scalar(src, inv_spacing, p)


@wp.func
def fetch_scalar(src: wp.Texture3D, inv_spacing: wp.vec3, p: wp.vec3):  # noqa: F811
    """Hardware-filtered sample of a point-centred scalar grid at local position ``p``."""
    u = wp.cw_mul(p, inv_spacing)
    return wp.texture_sample(src, wp.vec3(u[2] + 0.5, u[1] + 0.5, u[0] + 0.5), dtype=float)


@wp.func
def fetch_optics(src: wp.array(dtype=wp.float32), m: Medium, s: float):
    """``σt`` of data value ``s`` in the fourth component (software lerp of ``m.sigma_table``;
    ``src`` is that table); the colour comes from :func:`optics_color`."""
    return wp.vec4(0.0, 0.0, 0.0, lookup_sigma_t(m, s))


@wp.func
def fetch_optics(src: wp.Texture1D, m: Medium, s: float):  # noqa: F811
    """Colour (xyz) and ``σt`` (w) of data value ``s`` by one hardware-filtered fetch of the
    :func:`optics_texture` (same table coordinate as the software lerps)."""
    return wp.texture_sample(src, table_coord(m, s) + 0.5, dtype=wp.vec4f)


@wp.func
def optics_color(src: wp.array(dtype=wp.float32), m: Medium, s: float, optics: wp.vec4):
    """Scattering colour of data value ``s`` (software lerp of ``m.color_table``)."""
    return lookup_color(m, s)


@wp.func
def optics_color(src: wp.Texture1D, m: Medium, s: float, optics: wp.vec4):  # noqa: F811
    """Scattering colour from the :func:`fetch_optics` result (already fetched)."""
    return wp.vec3(optics[0], optics[1], optics[2])


#: Shadow rays (``single``'s, the light grids') stop once the transmittance is below this:
#: light 10⁻⁶ of its source is invisible in any picture, while marching on through dense
#: data to the box exit is most of a light grid's cost. (A stop at the primary ray's
#: early-termination level, 10⁻², left ``single`` up to 16x too bright deep in opaque data.)
SHADOW_STOP_T = wp.constant(1.0e-6)


@wp.func
def shadow_transmittance(m: Medium, p: wp.vec3, w: wp.vec3, dist: float, step: float,
                         xi: float, stop_t: float):
    """:func:`shadow_march` reading ``m``'s own arrays (exact software interpolation)."""
    return shadow_march(m, m.scalars, m.sigma_table, p, w, dist, step, xi, stop_t)


@wp.func
def shadow_march(m: Medium, scalars: Any, optics: Any, p: wp.vec3, w: wp.vec3, dist: float,
                 step: float, xi: float, stop_t: float):
    """Transmittance from ``p`` along unit ``w`` to the box exit or ``dist``, whichever is nearer.

    The length is split into equal segments no longer than ``step`` (world units), each
    sampled at fraction ``xi`` of its length (the midpoint rule for ``xi = 0.5``, exact in
    homogeneous media). The march stops early once the transmittance drops below
    ``stop_t`` (0: never), returning the transmittance reached: at most ``stop_t`` too
    bright (:data:`SHADOW_STOP_T` makes that invisible). Samples in exactly empty blocks
    of the volume are skipped (:func:`block_run`): they add 0, so the result is the same.
    ``scalars`` and ``optics`` are ``m``'s arrays (exact) or their textures
    (:mod:`vtkillum.core.textures`).
    """
    tt = ray_box(p, w, m.extent)
    length = wp.min(tt[1], dist)
    if length <= 0.0:
        return 1.0
    n = int(wp.ceil(length / step))
    h = length / float(n)
    tau_stop = float(1.0e30)  # in units of 1/h: no exp per sample
    if stop_t > 0.0:
        tau_stop = -wp.log(stop_t) / h
    tau = float(0.0)
    k = int(0)
    while k < n:
        empty, last = block_run(m, p, w, h, k, xi)
        if empty != 0:
            k = last + 1
        else:
            while k <= last and k < n:
                q = p + ((float(k) + xi) * h) * w
                tau += fetch_optics(optics, m, fetch_scalar(scalars, m.inv_spacing, q))[3]
                k += 1
                if tau > tau_stop:
                    return wp.exp(-tau * h)
    return wp.exp(-tau * h)


# --- phase function ------------------------------------------------------------------------------
@wp.func
def hg_phase(cos_theta: float, g: float):
    """Henyey–Greenstein phase function, normalised to 1 over the sphere.

    ``cos_theta`` is between the light's travel direction and the scattered direction.
    """
    denom = 1.0 + g * g - 2.0 * g * cos_theta
    return (1.0 - g * g) / (4.0 * wp.pi * denom * wp.sqrt(denom))


@wp.func
def orthonormal_basis(n: wp.vec3):
    """Two unit vectors completing ``n`` to a right-handed basis (Duff et al. 2017)."""
    sign = wp.where(n[2] >= 0.0, 1.0, -1.0)
    a = -1.0 / (sign + n[2])
    b = n[0] * n[1] * a
    t = wp.vec3(1.0 + sign * n[0] * n[0] * a, sign * b, -sign * n[0])
    s = wp.vec3(b, sign + n[1] * n[1] * a, -n[1])
    return t, s


@wp.func
def sample_hg(wi: wp.vec3, g: float, u1: float, u2: float):
    """Sample a scattered direction for light travelling along ``wi`` (pdf = hg_phase)."""
    cos_t = float(0.0)
    if wp.abs(g) < 1.0e-3:
        cos_t = 1.0 - 2.0 * u1
    else:
        sq = (1.0 - g * g) / (1.0 - g + 2.0 * g * u1)
        cos_t = (1.0 + g * g - sq * sq) / (2.0 * g)
    cos_t = wp.clamp(cos_t, -1.0, 1.0)
    sin_t = wp.sqrt(wp.max(0.0, 1.0 - cos_t * cos_t))
    phi = 2.0 * wp.pi * u2
    t, s = orthonormal_basis(wi)
    return wp.normalize(sin_t * wp.cos(phi) * t + sin_t * wp.sin(phi) * s + cos_t * wi)


# --- random numbers ----------------------------------------------------------------------------
# PCG-RXS-M-XS constants (the generator behind wp.rand_init / wp.randf).
PCG_MULTIPLIER = wp.constant(wp.uint32(747796405))
PCG_INCREMENT = wp.constant(wp.uint32(2891336453))
PCG_OUTPUT_MULTIPLIER = wp.constant(wp.uint32(277803737))


@wp.func
def uniform(state: wp.uint32):
    """Advance a PCG state (as ``wp.randf`` does); returns ``(u in [0, 1), new state)``.

    The same stream as ``wp.randf``, written out because a ``wp.func`` receives the state
    by value: returning the new state makes the stream explicit through helper functions.
    """
    b = state * PCG_MULTIPLIER + PCG_INCREMENT
    c = ((b >> ((b >> wp.uint32(28)) + wp.uint32(4))) ^ b) * PCG_OUTPUT_MULTIPLIER
    s = (c >> wp.uint32(22)) ^ c
    return float(s >> wp.uint32(8)) * (1.0 / 16777216.0), s


@wp.func
def free_path(sigma: float, state: wp.uint32):
    """Exponential distance with rate ``sigma``; returns ``(t, state)``.

    For ``sigma <= 0`` the distance is 1e30 and no random number is used.
    """
    if sigma <= 0.0:
        return 1.0e30, state
    u, state = uniform(state)
    return -wp.log(1.0 - u) / sigma, state


# --- lights and camera ---------------------------------------------------------------------------
@wp.func
def light_incidence(lights: Lights, li: int, p: wp.vec3):
    """Unit direction from ``p`` towards light ``li``, its distance, and the RGB irradiance at ``p``.

    Point lights give ``I / max(d, r)**2`` with ``r`` their source radius (bounded next to
    the light, see :mod:`vtkillum.core.lights`).
    """
    if lights.kind[li] == DIRECTIONAL:
        return -lights.vec[li], FAR, lights.rgb[li]
    d = lights.vec[li] - p
    dist = wp.max(wp.length(d), 1.0e-20)
    r = wp.max(dist, lights.radius[li])
    return d / dist, dist, lights.rgb[li] / (r * r)


@wp.func
def camera_ray(cam: CameraParams, x: float, y: float):
    """Origin and unit direction through image position ``(x, y)`` in pixels (x right, y down)."""
    nx = 2.0 * x / float(cam.width) - 1.0
    ny = 1.0 - 2.0 * y / float(cam.height)
    if cam.parallel != 0:
        o = cam.position + (nx * cam.aspect * cam.parallel_scale) * cam.right + (
            ny * cam.parallel_scale) * cam.up
        return o, cam.forward
    d = cam.forward + (nx * cam.aspect * cam.tan_half) * cam.right + (ny * cam.tan_half) * cam.up
    return cam.position, wp.normalize(d)


# --- host side -----------------------------------------------------------------------------------
def device_scalars(volume, device: str):
    """``volume.scalars`` as a float32 warp array on ``device``, uploaded once per Volume and
    device (a Volume's data do not change) and shared by every method."""
    return volume.derived(f"scalars@{device}", None,
                          lambda: to_device(volume.scalars, wp.float32, device))


def make_medium(volume, transfer_function, unit_distance: float, albedo: float = 0.9,
                anisotropy: float = 0.0, device: str | None = None,
                scalars: wp.array3d | None = None, skip_empty: bool = True) -> Medium:
    """Upload a volume and its optical model.

    Parameters
    ----------
    volume : vtkillum.core.volume.Volume
    transfer_function : vtkillum.core.transfer_function.TransferFunction
    unit_distance : float
        Opacity unit distance ``u`` (world units).
    albedo, anisotropy : float
        Single-scattering albedo and HG ``g``.
    device : str, optional
        Warp device (see :func:`vtkillum.core.device.resolve_device`).
    scalars : wp.array3d(float32), optional
        ``volume.scalars`` already on ``device``: only the transfer-function tables are
        uploaded, so a cache can follow a transfer-function edit without copying the volume
        again.
    skip_empty : bool
        Classify the volume's blocks (:func:`attach_occupancy`) so that marches skip the
        exactly transparent ones; False marks every block occupied (for comparisons).
    """
    device = resolve_device(device)
    if scalars is None:
        scalars = device_scalars(volume, device)
    elif tuple(scalars.shape) != tuple(volume.dims):
        raise ValueError(f"uploaded scalars of shape {tuple(scalars.shape)} do not belong to a "
                         f"volume of {tuple(volume.dims)} points; upload the volume's own scalars")
    # The tables and the block occupancy depend only on the optical model and the data: kept
    # with the volume, so a camera move rebuilds and uploads none of them. Shared: nobody
    # may write into a medium's arrays (MediumTables clones the tables it rewrites).
    key = (transfer_function.scalars.tobytes(), transfer_function.opacity.tobytes(),
           transfer_function.colors.tobytes(), float(unit_distance), scalars.ptr,
           bool(skip_empty))
    m = volume.derived(f"medium@{device}", key, lambda: _new_medium(
        volume, transfer_function, unit_distance, device, scalars, skip_empty))
    out = Medium()
    for name in ("scalars", "extent", "inv_spacing", "sigma_table", "color_table", "table_lo",
                 "table_scale", "majorant", "occupied", "block", "inv_block"):
        setattr(out, name, getattr(m, name))
    out.albedo = float(albedo)
    out.g = float(anisotropy)
    return out


def _new_medium(volume, transfer_function, unit_distance: float, device: str, scalars,
                skip_empty: bool) -> Medium:
    """A :class:`Medium` with new tables and occupancy (see :func:`make_medium`)."""
    sig, col, lo, hi = transfer_function.lookup_tables(unit_distance, volume.value_range)
    m = Medium()
    m.scalars = scalars
    m.extent = wp.vec3(*volume.extent.astype(np.float32))
    m.inv_spacing = wp.vec3(*(1.0 / volume.spacing).astype(np.float32))
    m.sigma_table = wp.array(sig, dtype=wp.float32, device=device)
    m.color_table = wp.array(col, dtype=wp.vec3, device=device)
    set_table_range(m, lo, hi, len(sig))
    # Trilinear interpolation stays within the data range, so the table's maximum over it bounds σt.
    vlo, vhi = volume.value_range
    x = np.linspace(lo, hi, len(sig))
    in_range = (x >= vlo - (hi - lo) / len(sig)) & (x <= vhi + (hi - lo) / len(sig))
    m.majorant = float(sig[in_range].max() if in_range.any() else sig.max()) * 1.0001 + 1e-12
    attach_occupancy(m, volume, sig, device, skip_empty)
    return m


def set_table_range(m: Medium, lo: float, hi: float, size: int) -> None:
    """Place ``m``'s tables of ``size`` entries on the data values ``[lo, hi]``."""
    m.table_lo = float(lo)
    m.table_scale = float((size - 1) / (hi - lo))


class MediumTables:
    """A :class:`Medium` without block occupancy (every block marked occupied) whose
    transfer-function tables are rebuilt in place, on the device, on every edit.

    For a cache that follows transfer-function edits of one uploaded volume (the
    convection–diffusion light grid): :func:`make_medium` builds the tables with numpy,
    allocates and uploads them and an occupancy grid each time, which on an H100's host
    cost more than the resampling kernel that reads them. Here the entries' data values
    and the control points go up (one asynchronous copy through :class:`HostWriter`) and
    :func:`tf_table_kernel` evaluates :meth:`TransferFunction.lookup_tables`'s
    interpolation in float64 on the device: the tables equal the host's to within a unit
    in the last place of float32 (the device may fuse a multiply and an add). The medium's
    ``majorant`` is σt of the largest control-point opacity, a bound on the tables (what
    the resampling needs none of).
    """

    def __init__(self, device: str) -> None:
        self.device = device
        self._medium = None
        self._key = None
        self._pack = None
        self._writer = None
        self._launch = None

    def medium(self, volume, transfer_function, unit_distance: float,
               scalars: wp.array3d) -> Medium:
        """The medium of ``volume`` (already on the device as ``scalars``) for the transfer
        function (albedo 0.9 and ``g = 0``, as :func:`make_medium`'s defaults)."""
        check_unit_distance(unit_distance)
        tf = transfer_function
        key = (scalars.ptr, tuple(scalars.shape), tuple(np.round(volume.extent, 12)))
        if key != self._key:
            self._medium = make_medium(volume, tf, unit_distance, device=self.device,
                                       scalars=scalars, skip_empty=False)
            # Tables of its own: they are rewritten in place below, and make_medium's are
            # shared with every other medium of this volume and transfer function.
            self._medium.sigma_table = wp.clone(self._medium.sigma_table)
            self._medium.color_table = wp.clone(self._medium.color_table)
            self._key = key
            self._pack = None  # the recorded launch writes the new medium's tables
            return self._medium
        m = self._medium
        size, n = TABLE_SIZE, tf.scalars.size
        lo, hi = tf.table_range(volume.value_range)
        columns = np.column_stack([tf.opacity, tf.colors])
        pack = np.concatenate([np.linspace(lo, hi, size), tf.scalars, columns.T.ravel(),
                               columns.min(axis=0), columns.max(axis=0)])
        if self._pack is None or self._pack.shape[0] < pack.size:
            self._pack = wp.empty(size + 5 * max(n, 64) + 8, dtype=wp.float64,
                                  device=self.device)
            self._writer = HostWriter(self._pack)
            self._launch = wp.launch(tf_table_kernel, dim=size, device=self.device,
                                     record_cmd=True,
                                     inputs=[self._pack, size, n, float(unit_distance),
                                             m.sigma_table, m.color_table])
        self._writer.write(pack)
        self._launch.set_param_at_index(2, n)
        self._launch.set_param_at_index(3, float(unit_distance))
        self._launch.launch()
        set_table_range(m, lo, hi, size)
        m.majorant = float(tf.sigma_t(tf.scalars, unit_distance).max()) * 1.0001 + 1e-12
        return m


@wp.func
def table_column(pack: wp.array(dtype=wp.float64), start: int, j: int, t: wp.float64,
                 lo: wp.float64, hi: wp.float64):
    """``(1 - t) f_j + t f_(j+1)`` of the column at ``pack[start:]``, within ``[lo, hi]``."""
    one = wp.float64(1.0)
    return wp.clamp((one - t) * pack[start + j] + t * pack[start + j + 1], lo, hi)


@wp.kernel
def tf_table_kernel(pack: wp.array(dtype=wp.float64), size: int, n: int,
                    unit_distance: wp.float64, sigma: wp.array(dtype=wp.float32),
                    color: wp.array(dtype=wp.vec3)):
    """Entry ``wp.tid()`` of the transfer function's tables (``lookup_tables``).

    ``pack``: the entries' data values (``size``), the ``n`` control points, the opacity,
    red, green and blue columns (``n`` each), the four columns' minima and their maxima.
    The same float64 steps as the host's ``_interp`` (the halved control points, ``t``
    clamped to [0, 1], the result to the column's range) and σt ``= -ln(1 - min(α,
    MAX_ALPHA)) / u``, with ``ln(1 - α)`` by its series below ``α = 1e-4`` (warp has no
    ``log1p``; the series' error there is below 1e-20 relative).
    """
    i = wp.tid()
    x = pack[i]
    half = wp.float64(0.5)
    v = wp.vec4d()
    if n == 1:
        v = wp.vec4d(pack[size + 1], pack[size + 2], pack[size + 3], pack[size + 4])
    else:
        j = int(0)
        for k in range(n):
            if pack[size + k] <= x:
                j = k
        j = wp.min(j, n - 2)
        lo = half * pack[size + j]
        t = (half * x - lo) / (half * pack[size + j + 1] - lo)
        t = wp.clamp(t, wp.float64(0.0), wp.float64(1.0))
        ranges = size + 5 * n
        for c in range(4):
            v[c] = table_column(pack, size + (c + 1) * n, j, t, pack[ranges + c],
                                pack[ranges + 4 + c])
    a = wp.min(v[0], wp.float64(TABLE_MAX_ALPHA))
    ln = wp.float64(0.0)
    if a < wp.float64(1.0e-4):
        ln = -a * (wp.float64(1.0) + a * (half + a * (wp.float64(1.0 / 3.0)
                                                        + a * (wp.float64(0.25) + a * wp.float64(0.2)))))
    else:
        ln = wp.log(wp.float64(1.0) - a)
    sigma[i] = wp.float32(-ln / unit_distance)
    color[i] = wp.vec3(wp.float32(v[1]), wp.float32(v[2]), wp.float32(v[3]))


def attach_occupancy(m: Medium, volume, sigma_table: np.ndarray, device: str,
                     skip_empty: bool = True) -> None:
    """Fill ``m.occupied``, ``m.block`` and ``m.inv_block`` for ``m``'s scalars and tables.

    The data range per block is computed once per volume and device; the classification
    per transfer function is one small launch (:mod:`vtkillum.core.empty_space`).
    """
    from vtkillum.core.empty_space import BLOCK, block_ranges, occupancy

    if not skip_empty:
        m.occupied = wp.ones((1, 1, 1), dtype=wp.int32, device=device)
        m.block = wp.vec3(1.0e30)
        m.inv_block = wp.vec3(0.0)
        return
    ranges = volume.derived(f"block_ranges@{device}", m.scalars.ptr,
                            lambda: block_ranges(m.scalars, device))
    m.occupied = occupancy(m, ranges, device, sigma_table)
    block = BLOCK * np.asarray(volume.spacing, np.float64)
    m.block = wp.vec3(*block.astype(np.float32))
    m.inv_block = wp.vec3(*(1.0 / block).astype(np.float32))


def make_rgb_grid(data, extent, device: str | None = None) -> RGBGrid:
    """An RGB volume covering ``[0, extent]`` in the local frame, as the kernels read it.

    ``data``: a numpy ``(nx, ny, nz, 3)`` array (uploaded), a warp ``array3d(vec3)`` on
    ``device`` (used as it is, no copy), or None (a zero 2³ grid for kernels that take the
    struct but have no scattered light).
    """
    device = resolve_device(device)
    if data is None:
        data = wp.zeros((2, 2, 2), dtype=wp.vec3, device=device)
    if isinstance(data, wp.array):
        if str(data.device) != str(wp.get_device(device)) or data.dtype != wp.vec3 or \
                data.ndim != 3 or min(data.shape) < 2:
            raise ValueError(f"a device RGB volume must be an array3d of vec3 on {device} with "
                             f"n >= 2, got {data.dtype} {data.shape} on {data.device}")
        shape = tuple(data.shape)
    else:
        host = np.asarray(data, dtype=np.float32)
        if host.ndim != 4 or host.shape[-1] != 3 or min(host.shape[:3]) < 2:
            raise ValueError(f"an RGB volume must have shape (nx, ny, nz, 3) with n >= 2, got "
                             f"{host.shape}")
        shape = host.shape[:3]
        data = upload(host, wp.vec3, device)
    extent = np.asarray(extent, dtype=np.float64)
    g = RGBGrid()
    g.data = data
    g.extent = wp.vec3(*extent.astype(np.float32))
    g.inv_spacing = wp.vec3(*((np.asarray(shape) - 1) / extent).astype(np.float32))
    return g


def make_light_grid(data: np.ndarray | None, extent, device: str | None = None,
                    near_cells: float = 0.0) -> LightGrid:
    """Upload per-light grids ``(n_lights, nx, ny, nz)`` covering ``[0, extent]``.

    ``None`` gives an empty placeholder (``count = 0``) for kernels that take the struct
    but have no per-light data to read. ``near_cells`` sets :attr:`LightGrid.near` in
    cells of the grid (its largest spacing).
    """
    device = resolve_device(device)
    g = LightGrid()
    if data is None:
        g.data = wp.zeros((1, 2, 2, 2), dtype=wp.float32, device=device)
        g.inv_spacing = wp.vec3(1.0, 1.0, 1.0)
        g.count = 0
        g.near = 0.0
        return g
    if isinstance(data, wp.array):  # already on the device: used as it is
        if str(data.device) != str(wp.get_device(device)) or data.dtype != wp.float32:
            raise ValueError(f"device per-light grids must be float32 on {device}, got "
                             f"{data.dtype} on {data.device}")
    else:
        data = np.asarray(data, dtype=np.float32)
    if data.ndim != 4 or min(data.shape[1:]) < 2:
        raise ValueError(f"per-light grids must have shape (n_lights, nx, ny, nz) with n >= 2, "
                         f"got {tuple(data.shape)}")
    extent = np.asarray(extent, dtype=np.float64)
    g.data = data if isinstance(data, wp.array) else upload(data, wp.float32, device)
    spacing = extent / (np.asarray(data.shape[1:]) - 1)
    g.inv_spacing = wp.vec3(*(1.0 / spacing).astype(np.float32))
    g.count = int(data.shape[0])
    g.near = float(near_cells) * float(spacing.max())
    return g


def make_camera(camera, volume, width: int, height: int) -> CameraParams:
    """Map a :class:`~vtkillum.core.camera.Camera` into ``volume``'s local frame."""
    if int(width) < 1 or int(height) < 1:
        raise ValueError(f"image size must be positive, got {width} x {height}")
    r, u, f = camera.basis()
    c = CameraParams()
    c.position = wp.vec3(*volume.to_local(camera.position).astype(np.float32))
    c.right = wp.vec3(*volume.to_local_direction(r).astype(np.float32))
    c.up = wp.vec3(*volume.to_local_direction(u).astype(np.float32))
    c.forward = wp.vec3(*volume.to_local_direction(f).astype(np.float32))
    c.tan_half = float(np.tan(np.radians(camera.view_angle) / 2))
    c.aspect = float(width) / float(height)
    c.parallel = int(camera.parallel_projection)
    c.parallel_scale = float(camera.parallel_scale)
    c.width = int(width)
    c.height = int(height)
    return c


def make_lights(lights, volume, device: str | None = None) -> Lights:
    """Upload a light list, mapped into ``volume``'s local frame."""
    device = resolve_device(device)
    kinds, vecs, rgb = pack_lights(lights, volume.direction, volume.origin)
    out = Lights()
    radius = [resolved_radius(light, volume) for light in lights]
    out.kind, out.vec, out.rgb, out.radius = upload_packed(
        [(kinds, wp.int32), (vecs, wp.vec3), (rgb, wp.vec3), (radius, wp.float32)], device)
    out.count = len(kinds)
    return out


_NP_SCALARS = {wp.int32: np.int32, wp.uint32: np.uint32, wp.float32: np.float32,
               wp.int64: np.int64, wp.uint64: np.uint64, wp.float64: np.float64}


def upload_packed(arrays, device: str) -> list:
    """Small host arrays on ``device`` with one copy: ``arrays`` is a list of
    ``(values, dtype)``; returns a warp array per entry, each a view into one device buffer
    (which the views keep alive). A copy from pageable memory costs tens of microseconds of
    host time however small, and setting up a trace uploads about a dozen of them."""
    host = []
    offset = 0
    for values, dtype in arrays:
        a = np.ascontiguousarray(values, dtype=_NP_SCALARS[getattr(dtype, "_wp_scalar_type_",
                                                                    dtype)])
        n = a.size // getattr(dtype, "_length_", 1)
        host.append((a, dtype, n, offset))
        offset += -(-a.nbytes // 16) * 16  # 16-byte aligned parts
    buffer = np.zeros(max(offset, 16), np.uint8)
    for a, _, _, at in host:
        buffer[at:at + a.nbytes] = a.view(np.uint8).reshape(-1)
    base = wp.array(buffer, dtype=wp.uint8, device=device)
    views = []
    for _, dtype, n, at in host:
        v = wp.array(ptr=base.ptr + at, dtype=dtype, shape=(n,), device=device)
        v._ref = base  # (the view owns no memory)
        views.append(v)
    return views


def stream_seed(seed: int, index: int, salt: int) -> int:
    """32-bit hash of ``(seed, index)`` as a signed int for ``wp.rand_init``.

    Gives every launch ``index`` of a Monte-Carlo run its own independent streams from one
    user seed; ``salt`` keeps the streams of different estimators apart. The finaliser is
    a murmur-style avalanche (lowbias32), so neighbouring indices give unrelated seeds.
    """
    mask = 0xFFFFFFFF
    x = (int(seed) * 0x9E3779B1 + int(index) * 0x85EBCA77 + int(salt)) & mask
    x ^= x >> 16
    x = (x * 0x7FEB352D) & mask
    x ^= x >> 15
    x = (x * 0x846CA68B) & mask
    x ^= x >> 16
    return x - (1 << 32) if x >= (1 << 31) else x


#: Copy a numpy array to a device, with a clear error when it runs out of memory (the
#: counted upload of :mod:`vtkillum.core.device_arrays`; the name the methods use).
to_device = upload
