"""Light distribution by tube marching (Ament et al. 2013, section 4.2.2, eqs. 14–17).

For every point ``x`` of the radiance cache and every light, the light's front is
carried from where it enters the volume (or from a point light inside it) to
``x`` in steps of ``Δx = 2r``, through a chain of touching spheres of radius
``r`` (Fig. 3 of the paper):

    L̃f(x_0) = E_l(x)                                               (eq. 15)
    L̃f(x_i) = L̃f(x_{i-1}) · T̃(r σ̄_i, g),  σ̄_i = mean of σ̃t over [x_{i-1}, x_i]   (eq. 16)
    L̃d(x)   = (1 - η) L̃f(x_k) + η L̃f(x_{k+1}),  η = |x - x_k| / 2r      (eq. 17)

``E_l(x)`` is the light's unattenuated irradiance at ``x`` (``E`` of a directional
light, ``I / max(d, r)²`` of a point light, so the inverse-square fall-off is exact at
``x`` rather than stepped; within one radius of the light it is held at ``I / r²``,
the mean irradiance over an ambient sphere that contains the light, instead of
diverging at the light), and ``x_0`` is the entry point of the segment from
``x`` towards the light into the volume's box (or the point light itself).

Differences from the paper, and why
-----------------------------------
* The per-step factor is the tabulated *front transmittance* ``T̃`` instead of
  ``L̃o(0, r σ̃t, g)`` (see :mod:`vtkillum.core.ambient.table`: the latter is a
  radiance per unit front, ``p(1; g)`` in empty space, and would dim light by
  4π per step in empty space for g = 0). With ``T̃``, empty space transmits
  light unchanged, absorbing media follow Beer–Lambert exactly, and forward
  scattering carries light further than backward scattering.
* ``σ̃t`` of step ``i`` is its mean along the step (midpoint rule, samples no further
  apart than the smallest data spacing: :func:`default_substeps`), not one sample (the
  paper writes ``σ̃t(x_{i-1})``, the sphere's entry point; the step's centre would do as
  well). One sample per step of ``2r`` lets shells thinner than ``r`` slip through: the
  SAT cube of the sphere's volume reaches only ``0.81 r`` from its centre, so a shell in
  the gap between two samples casts no shadow at all, and how much of a shell a sample
  sees depends on where the steps (which start at the box face) happen to fall. Behind
  a shell of optical depth 3 the front then varied from 0.19 to 1.0 (``r = 4`` voxels) as
  the shell moved through one step; with the mean it is 0.23-0.25, the table's
  ``T̃(1.5)`` (test: ``test_thin_shell_shadows_wherever_it_lies_on_the_step_grid``).
* That mean costs one ``σ̃t`` sample per data spacing along the light path, as many as a
  shadow ray (``tube_sampling="midpoint"``). By default (``"field"``) the march instead takes
  the paper's one sample per step, at the step's middle, of the *step field*
  ``σ̂ = B_2r ∗ σ̃t`` (:func:`step_extinction_field`): ``σ̃t`` averaged over the cube of side
  ``2r`` around each point, computed once per transfer-function or radius edit. Along an
  axis the boxes of consecutive steps tile the light path, so the optical depth the steps
  collect is exactly the line integral of ``σ̃t``, wherever a shell lies on the step grid;
  along other directions the box's smooth footprint (a box convolved with the SAT cube)
  keeps it within a few per cent. The price is a lateral blur of ``r`` on top of the
  ``σ̃t`` cube's (soft shadows a little softer). A light or ``g`` edit then costs the
  paper's ``|path| / 2r`` samples per cache point instead of ``|path| / h``: 16× fewer at
  ``r = 8`` voxels (accuracy against the path tracer: ``docs/ambient_scattering.md``).

The cache is a regular grid covering the volume's box ``[0, extent]`` at
``scale`` times the data resolution (0.5 by default, as in the paper), one RGB
grid per light, sampled trilinearly by the gather.

With a texture of ``σ̃t`` passed (``sigma_tilde_texture``, CUDA's hardware filtering, see
:mod:`~vtkillum.core.ambient.textures`) the march samples ``σ̃t`` through it and the cache
is written as half-precision RGBA into a staging array and copied into one texture for the
gather. Half precision halves that copy and the gather's cache reads; so that no light can
overflow it, each light's radiance is stored in units of its brightest irradiance
(:func:`radiance_unit`: ``max(E)`` of a directional light, ``max(I) / r²`` of a point light),
so stored values lie in [0, 1] with a relative rounding of 2⁻¹¹.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import Any

import numpy as np
import warp as wp

from vtkillum.core.ambient.textures import fetch_scalar
from vtkillum.core.device import init_warp, resolve_device
from vtkillum.core.resample import scaled_shape
from vtkillum.core.warp_common import (
    POINT,
    Lights,
    light_incidence,
    ray_box,
    table_lerp,
    texture_from,
    trilinear_index,
)

init_warp()

#: Front level (relative to the light) below which marching stops: the rest adds nothing.
NEGLIGIBLE = wp.constant(1.0e-7)
#: Cache points per thread brick (i, j, k): consecutive threads march neighbouring points in
#: all three directions, so their samples of ``σ̃t`` share cache lines (H200, Table 1 sizes:
#: 5 % faster than rows along k at 432³, 22 % at 256²×276).
BRICK = (8, 8, 8)
BRICK_I = wp.constant(BRICK[0])
BRICK_J = wp.constant(BRICK[1])
BRICK_K = wp.constant(BRICK[2])
#: Grid intervals of the step field per side of its box (:func:`step_field_shape`).
FIELD_POINTS_PER_BOX = 8


@wp.struct
class RadianceGrid:
    """Distributed radiance ``L̃d`` per light on a grid covering ``[0, extent]``."""

    data: wp.array4d(dtype=wp.vec3)  # [light, i, j, k], RGB in irradiance units (None: texture)
    extent: wp.vec3
    inv_spacing: wp.vec3  # grid points per world unit along x, y, z
    points: wp.vec3i  # grid points along x, y, z


@dataclass
class RadianceCache:
    """Host handle of a radiance cache (see :func:`radiance_cache`).

    Attributes
    ----------
    grid : RadianceGrid
        Device struct the gather samples.
    shape : (int, int, int)
        Cache grid points along x, y, z.
    texture : wp.Texture3D or None
        With hardware filtering: the cache as one RGBA texture, lights stacked along its
        depth (``grid.data`` is then None); else None.
    staging : wp.array4d(vec4h) or None
        With hardware filtering: the half-precision RGBA cache ``[light, i, j, k]`` the texture
        was copied from, in units of :func:`radiance_unit`.
    lights : Lights or None
        With hardware filtering: the lights the cache was marched for (for :meth:`numpy`).
    radius : float
        The sphere radius ``r`` it was marched with (world units).
    replay : wp.Launch or None
        The step-field march as recorded, replayed by the next :func:`radiance_cache` with
        this cache as ``out`` and the same inputs (``replay_key``): a g or light edit, whose
        arrays are overwritten in place, then costs one launch and no argument packing.
    replay_key : tuple or None
        The inputs ``replay`` was recorded with.
    """

    grid: RadianceGrid
    shape: tuple
    texture: object = None
    staging: object = None
    lights: Lights | None = None
    radius: float = 0.0
    replay: object = None
    replay_key: tuple | None = None

    def numpy(self) -> np.ndarray:
        """The cache as ``(n_lights, nx, ny, nz, 3)`` float32 (irradiance units)."""
        if self.texture is not None:
            rgb = self.lights.rgb.numpy().astype(np.float64)
            units = rgb.max(axis=1)
            units[self.lights.kind.numpy() == POINT] /= self.radius * self.radius
            values = self.staging.numpy()[..., :3].astype(np.float32)
            return values * units.astype(np.float32)[:, None, None, None, None]
        return self.grid.data.numpy()


def radiance_cache(sigma_tilde, data_spacing, extent, lights: Lights, transmittance,
                   sigma_max: float, radius: float, scale: float = 0.5,
                   device: str | None = None, shape=None,
                   out: RadianceCache | None = None,
                   sigma_tilde_texture=None, substeps: int | None = None,
                   step_field=None, step_field_texture=None) -> RadianceCache:
    """Distribute every light by tube marching and cache the result.

    Parameters
    ----------
    sigma_tilde : wp.array3d(float32)
        Ambient extinction ``σ̃t`` on the data grid (1/world units), see
        :func:`vtkillum.core.ambient.sat.ambient_extinction`.
    data_spacing : (3,) float
        Spacing of the data grid (world units).
    extent : (3,) float
        The volume's local-frame size (world units); the cache covers ``[0, extent]``.
    lights : Lights
        Light list in the volume's local frame (:func:`~vtkillum.core.warp_common.make_lights`).
    transmittance : ndarray (n_sigma,) or wp.array(float32)
        Front transmittance ``T̃`` at the scene's ``g`` over ``[0, sigma_max]`` (uniform),
        :meth:`~vtkillum.core.ambient.table.PreintegrationTable.transmittance_slice`.
    sigma_max : float
        Optical radius ``r σ̃t`` of the last transmittance entry.
    radius : float
        Sphere radius ``r`` (world units); the marching step is ``2r``.
    scale : float
        Cache resolution relative to the data (per axis, in (0, 1]; 0.5 as in the paper):
        ``round((n - 1) * scale) + 1`` points per axis.
    device : str, optional
        Warp device.
    shape : (int, int, int), optional
        Explicit cache grid points per axis (each >= 2); overrides ``scale``.
    out : RadianceCache, optional
        A previous cache to overwrite when it has the same grid and light count (and is
        on ``device``): a light or ``g`` edit then allocates nothing. Otherwise ignored.
    sigma_tilde_texture : wp.Texture3D, optional
        ``sigma_tilde`` as a texture (:func:`~vtkillum.core.warp_common.texture_from`):
        the march samples it by hardware filtering and the result also comes as an RGBA
        texture (:attr:`RadianceCache.texture`). CUDA only; see
        :mod:`~vtkillum.core.ambient.textures` for the accuracy.
    substeps : int, optional
        Samples of ``σ̃t`` per step of ``2r`` whose mean enters ``T̃`` (see the module
        docstring); default :func:`default_substeps` (no longer than the smallest data
        spacing). 1 is the paper's single sample per step. Not with ``step_field``.
    step_field : wp.array3d(float32), optional
        The step field ``σ̂`` of ``sigma_tilde`` for this ``radius``
        (:func:`step_extinction_field`): the march then samples it once per step, at the
        step's middle (the default of :class:`~vtkillum.core.ambient.cache.AmbientScatteringCache`),
        instead of averaging ``σ̃t`` along the step. ``sigma_tilde_texture`` then only selects
        the half-precision texture output.
    step_field_texture : wp.Texture3D, optional
        ``step_field`` as a texture (:func:`~vtkillum.core.warp_common.texture_from`,
        CUDA): the march samples it by hardware trilinear filtering (one fetch instead of
        eight loads per step; the field is smooth, so the 8-bit interpolation weights cost
        little: see :class:`~vtkillum.core.ambient.cache.AmbientScatteringCache`).

    Returns
    -------
    RadianceCache
    """
    device = resolve_device(device)
    key = None
    if step_field is not None:
        key = _replay_key(step_field, sigma_tilde, data_spacing, extent, lights, transmittance,
                          sigma_max, radius, scale, device, shape,
                          sigma_tilde_texture is not None, substeps,
                          None if step_field_texture is None else id(step_field_texture))
        if key is not None and out is not None and out.replay is not None \
                and out.replay_key == key:
            out.replay.launch()  # the same inputs, overwritten in place (a g or light edit)
            if out.texture is not None:
                texture_from(out.staging.reshape((lights.count * out.shape[0],) + out.shape[1:]),
                             out.texture)
            return out
    scale = float(scale)
    if not (0.0 < scale <= 1.0):
        raise ValueError(f"radiance_cache_scale must lie in (0, 1], got {scale}")
    radius = float(radius)
    if not (np.isfinite(radius) and radius > 0):
        raise ValueError(f"the ambient radius must be positive, got {radius}")
    dims = np.asarray(sigma_tilde.shape)
    if shape is None:
        shape = scaled_shape(dims, scale)
    else:
        shape = tuple(int(n) for n in shape)
        if len(shape) != 3 or min(shape) < 2:
            raise ValueError(f"radiance cache shape must be three integers >= 2, got {shape}")
    extent = np.asarray(extent, dtype=np.float64)
    if not isinstance(transmittance, wp.array):
        transmittance = wp.array(np.asarray(transmittance, dtype=np.float32), dtype=wp.float32,
                                 device=device)
    if step_field is not None:
        if step_field.ndim != 3 or min(step_field.shape) < 2:
            raise ValueError(f"the step field must be a 3D grid of at least 2 points per axis, "
                             f"got shape {tuple(step_field.shape)}")
        substeps = 1 if substeps is None else substeps
    elif substeps is None:
        substeps = default_substeps(radius, data_spacing)
    if isinstance(substeps, bool) or int(substeps) != substeps or substeps < 1:
        raise ValueError(f"tube-march substeps must be an integer >= 1, got {substeps!r}")
    data_shape = (lights.count,) + shape
    hardware = sigma_tilde_texture is not None
    kept = out.staging if (out is not None and hardware) else (
        out.grid.data if out is not None else None)
    if (kept is not None and tuple(kept.shape) == data_shape
            and kept.device == wp.get_device(device)):
        grid = out.grid
        target = kept
    else:  # the kernel writes every point: no need to clear
        grid = RadianceGrid()
        target = wp.empty(data_shape, dtype=wp.vec4h if hardware else wp.vec3, device=device)
        grid.data = None if hardware else target
    grid.points = wp.vec3i(*shape)
    grid.extent = wp.vec3(*extent.astype(np.float32))
    grid.inv_spacing = wp.vec3(*((np.asarray(shape) - 1) / np.maximum(extent, 1e-30))
                               .astype(np.float32))
    if step_field is not None:  # the field's own grid over the same box
        inv_data = wp.vec3(*((np.asarray(step_field.shape) - 1)
                             / np.maximum(extent, 1e-30)).astype(np.float32))
    else:
        inv_data = wp.vec3(*(1.0 / np.asarray(data_spacing, dtype=np.float64))
                           .astype(np.float32))
    spacing = wp.vec3(*(extent / (np.asarray(shape) - 1)).astype(np.float32))
    bricks = [-(-n // b) for n, b in zip(shape, BRICK)]
    threads = lights.count * int(np.prod(bricks)) * int(np.prod(BRICK))
    replay = None
    if threads > 0:
        # table entries per unit σ̃t, with the radius folded in: one multiply per step
        lookup_scale = radius * (transmittance.shape[0] - 1) / float(sigma_max)
        if step_field is not None:
            if step_field_texture is not None:
                source = step_field_texture
            else:  # flat, contiguous: the kernel indexes it with 32-bit offsets
                source = step_field if step_field.is_contiguous else step_field.contiguous()
                source = source.reshape((source.size,))
            kernel = field_march_kernel(int(substeps), hardware, step_field_texture is not None)
            replay = wp.launch(kernel, dim=threads,
                               inputs=[source, wp.vec3i(*step_field.shape), inv_data, lights,
                                       transmittance, float(lookup_scale), radius, spacing,
                                       wp.vec3i(*shape), wp.vec3i(*bricks), grid.extent,
                                       target],
                               device=device, record_cmd=True)
            replay.launch()
        else:
            kernel = tube_march_texture if hardware else tube_march_software
            source = sigma_tilde_texture if hardware else sigma_tilde
            wp.launch(kernel, dim=threads,
                      inputs=[source, inv_data, lights,
                              transmittance, float(lookup_scale), radius, int(substeps), spacing,
                              wp.vec3i(*shape), wp.vec3i(*bricks), grid.extent, target],
                      device=device)
    key = key if replay is not None else None
    if not hardware:
        return RadianceCache(grid, shape, replay=replay, replay_key=key)
    # lights stacked along the texture's depth: [light * nx + i, j, k]
    stacked = target.reshape((lights.count * shape[0], shape[1], shape[2]))
    texture = texture_from(stacked, out.texture if out is not None else None)
    return RadianceCache(grid, shape, texture, target, lights, radius, replay, key)


def _replay_key(step_field, sigma_tilde, data_spacing, extent, lights: Lights, transmittance,
                sigma_max, radius, scale, device, shape, hardware: bool, substeps, texture):
    """Everything a recorded step-field march depends on (arrays by address: a g or light
    edit overwrites them in place); None when it cannot be replayed (a host table is
    uploaded afresh by every call)."""
    if not isinstance(transmittance, wp.array):
        return None
    table = (transmittance.ptr, transmittance.shape)
    return (device, step_field.ptr, tuple(step_field.shape), tuple(sigma_tilde.shape),
            tuple(np.ravel(data_spacing)),
            tuple(np.ravel(extent)), id(lights), lights.count,
            None if lights.count == 0 else (lights.kind.ptr, lights.vec.ptr, lights.rgb.ptr,
                                            lights.radius.ptr),
            table, sigma_max, radius, scale, None if shape is None else tuple(shape),
            hardware, substeps, texture)


def step_extinction_field(sigma_tilde, spacing, radius: float, device: str | None = None,
                          samples: int = 1, out=None):
    """The step field ``σ̂``: ``σ̃t`` averaged over the axis-aligned cube of side ``2r / samples``.

    Sampled ``samples`` times per tube step of length ``2r``, each at the middle of its share,
    it gives the step's optical depth without a sample per data spacing (see the module
    docstring). The cube is a separable box filter of half-width ``a = r / (samples ·
    spacing)`` data voxels per axis of the trilinear interpolant of ``σ̃t`` (what the march
    would sample), exact for any ``a`` and output position: data point ``m`` weighs the
    integral of its interpolation hat over the box; the border value is repeated outside
    the grid, as the march's clamped trilinear samples see it.

    The field is as smooth as its box, so it is kept on a coarser grid over the same box
    (:func:`step_field_shape`: :data:`FIELD_POINTS_PER_BOX` intervals per box side, never
    more points than the data's): 217³ for 432³ data at ``r = 8`` voxels, which halves this
    stage of a transfer-function edit. Interpolating between its points adds an error of
    the order of the field's curvature times the grid spacing squared: with 8 intervals per
    side the shell tests stay within 2 % (4 intervals let a shell's shadow vary by 12 %
    along a diagonal).

    Parameters
    ----------
    sigma_tilde : wp.array3d(float32)
        Ambient extinction on the data grid.
    spacing : (3,) float
        Data grid spacing (world units).
    radius : float
        Sphere radius ``r`` (world units).
    device : str, optional
        Warp device (``sigma_tilde``'s).
    samples : int
        Samples per tube step the field is made for.
    out : wp.array3d(float32), optional
        A previous field to overwrite when it has the shape and device (reused across edits).

    Returns
    -------
    wp.array3d(float32)
        ``σ̂`` on the grid of :func:`step_field_shape` covering the data's box.
    """
    device = resolve_device(device)
    radius = float(radius)
    if not (np.isfinite(radius) and radius > 0):
        raise ValueError(f"the ambient radius must be positive, got {radius}")
    dims = tuple(sigma_tilde.shape)
    shape = step_field_shape(dims, spacing, radius, samples)
    half = radius / samples / np.asarray(spacing, dtype=np.float64).reshape(3)
    src = sigma_tilde
    for axis in range(3):
        current = list(src.shape)
        current[axis] = shape[axis]
        last = axis == 2
        if last and out is not None and tuple(out.shape) == shape \
                and out.device == wp.get_device(device):
            dst = out
        else:
            dst = wp.empty(tuple(current), dtype=wp.float32, device=device)
        a = float(half[axis])
        # data points per output point along the axis (the same box: the ends coincide)
        ratio = (dims[axis] - 1) / max(shape[axis] - 1, 1)
        wp.launch(box_mean_axis_kernel, dim=dst.shape,
                  inputs=[src, a, int(np.ceil(a)) + 2, axis, float(ratio), dst],
                  device=device)
        src = dst
    return src


def step_field_shape(dims, spacing, radius: float, samples: int = 1) -> tuple:
    """Points per axis of :func:`step_extinction_field`'s grid: :data:`FIELD_POINTS_PER_BOX`
    intervals per side ``2r / samples`` of the box at least, at most the data's ``dims``, at
    least 2."""
    dims = np.asarray(dims, dtype=np.int64)
    extent = (dims - 1) * np.asarray(spacing, dtype=np.float64).reshape(3)
    box = 2.0 * float(radius) / samples
    wanted = np.ceil(extent * FIELD_POINTS_PER_BOX / box - 1e-9).astype(np.int64) + 1
    return tuple(int(n) for n in np.clip(wanted, 2, np.maximum(dims, 2)))


def default_substeps(radius: float, data_spacing) -> int:
    """Samples of ``σ̃t`` per tube step ``2r``: spaced no further apart than the smallest data
    spacing (so that a shell thinner than ``r`` cannot fall between them), at least 1."""
    return max(1, int(np.ceil(2.0 * float(radius) / float(np.min(data_spacing)) - 1e-9)))


# --- device functions -----------------------------------------------------------------------------
@wp.func
def step_extinction(sigma_tilde: Any, inv_data_spacing: wp.vec3, start: wp.vec3, travel: wp.vec3,
                    length: float, substeps: int):
    """Mean ``σ̃t`` over the segment ``start + u travel``, ``u`` in ``[0, length]``: the midpoint
    rule with ``substeps`` samples."""
    acc = float(0.0)
    h = length / float(substeps)
    for s in range(substeps):
        acc += fetch_scalar(sigma_tilde, inv_data_spacing, start + ((float(s) + 0.5) * h) * travel)
    return acc / float(substeps)


@wp.func
def sample_radiance(grid: RadianceGrid, light: int, p: wp.vec3):
    """Trilinear sample of light ``light``'s cache at local position ``p`` (clamped to the box).

    The cache is 4D (a light index in front), so it takes the cell and fractions from
    :func:`~vtkillum.core.warp_common.trilinear_index` and does its own eight reads.
    """
    a = grid.data
    idx, f = trilinear_index(p, grid.inv_spacing, wp.vec3i(a.shape[1], a.shape[2], a.shape[3]))
    i = idx[0]
    j = idx[1]
    k = idx[2]
    c00 = wp.lerp(a[light, i, j, k], a[light, i + 1, j, k], f[0])
    c10 = wp.lerp(a[light, i, j + 1, k], a[light, i + 1, j + 1, k], f[0])
    c01 = wp.lerp(a[light, i, j, k + 1], a[light, i + 1, j, k + 1], f[0])
    c11 = wp.lerp(a[light, i, j + 1, k + 1], a[light, i + 1, j + 1, k + 1], f[0])
    return wp.lerp(wp.lerp(c00, c10, f[1]), wp.lerp(c01, c11, f[1]), f[2])


@wp.func
def radiance_unit(lights: Lights, li: int, radius: float):
    """Brightest irradiance of light ``li`` anywhere: ``max(E)``, or ``max(I) / r²`` of a point
    light (held there within one radius); the half-precision cache stores ``L̃d`` in this unit."""
    c = lights.rgb[li]
    u = wp.max(c[0], wp.max(c[1], c[2]))
    if lights.kind[li] == POINT:
        u = u / (radius * radius)
    return u


@wp.func
def store_radiance(out: wp.array4d(dtype=wp.vec3), li: int, i: int, j: int, k: int,
                   v: wp.vec3, unit: float):
    """Write ``L̃d`` into the RGB cache (irradiance units; ``unit`` unused)."""
    out[li, i, j, k] = v


@wp.func
def store_radiance(out: wp.array4d(dtype=wp.vec4h), li: int, i: int, j: int,  # noqa: F811
                   k: int, v: wp.vec3, unit: float):
    """Write ``L̃d / unit`` into the half-precision RGBA staging array (alpha unused)."""
    w = v * wp.where(unit > 0.0, 1.0 / unit, 0.0)
    out[li, i, j, k] = wp.vec4h(wp.float16(w[0]), wp.float16(w[1]), wp.float16(w[2]),
                                wp.float16(0.0))


# --- kernels --------------------------------------------------------------------------------------
@wp.func
def hat_integral(t: float):
    """``∫_{-∞}^{t} max(0, 1 - |x|) dx``: the linear-interpolation weight's antiderivative."""
    v = float(1.0)
    if t <= -1.0:
        v = 0.0
    elif t <= 0.0:
        v = 0.5 * (t + 1.0) * (t + 1.0)
    elif t < 1.0:
        v = 1.0 - 0.5 * (1.0 - t) * (1.0 - t)
    return v


@wp.kernel
def box_mean_axis_kernel(src: wp.array3d(dtype=wp.float32), half: float, taps: int, axis: int,
                         ratio: float, dst: wp.array3d(dtype=wp.float32)):
    """One axis of :func:`step_extinction_field`: ``dst`` = the mean of ``src``'s linear
    interpolant (border value repeated) over ``[u - half, u + half]`` along ``axis``, ``u =
    ratio · o`` the source position of output point ``o`` (the other axes map one to one).
    Each source point weighs the integral of its hat function over the box: exact for the
    interpolant, whatever the box's ends (``taps`` >= ``half + 1``)."""
    i, j, k = wp.tid()
    n = src.shape[axis]
    o = wp.vec3i(i, j, k)
    u = ratio * float(o[axis])
    first = int(wp.floor(u)) - taps
    acc = float(0.0)
    for t in range(2 * taps + 2):
        m = first + t
        w = hat_integral(u + half - float(m)) - hat_integral(u - half - float(m))
        if w > 0.0:
            q = wp.clamp(m, 0, n - 1)
            v = float(0.0)
            if axis == 0:
                v = src[q, j, k]
            elif axis == 1:
                v = src[i, q, k]
            else:
                v = src[i, j, q]
            acc += w * v
    dst[i, j, k] = acc / (2.0 * half)


@wp.func
def cache_point(tid: int, bricks: wp.vec3i):
    """Light and cache point ``(li, i, j, k)`` of thread ``tid``: ``(light, brick, point in
    brick)`` with k fastest, ``bricks`` bricks of :data:`BRICK` points per axis."""
    per_brick = BRICK_I * BRICK_J * BRICK_K
    b = tid / per_brick
    q = tid - b * per_brick
    per_light = bricks[0] * bricks[1] * bricks[2]
    li = b / per_light
    b = b - li * per_light
    i = (b / (bricks[1] * bricks[2])) * BRICK_I + q / (BRICK_J * BRICK_K)
    j = ((b / bricks[2]) % bricks[1]) * BRICK_J + (q / BRICK_K) % BRICK_J
    k = (b % bricks[2]) * BRICK_K + q % BRICK_K
    return li, i, j, k


@wp.func
def march_path(lights: Lights, li: int, p: wp.vec3, radius: float, extent: wp.vec3):
    """The front's path to ``p`` from light ``li``: unit direction to the light, the
    irradiance ``E_l(p)`` of eq. 15 (a point light's held at ``I / r²`` within one radius),
    the point where the front starts (the box face towards the light, or the point light),
    the whole steps of ``2r`` from there and the fraction ``η`` of eq. 17 left over."""
    to_light, dist, e = light_incidence(lights, li, p)
    if lights.kind[li] == POINT:
        # Inside one radius of a point light the sphere contains it: no 1/d² divergence.
        r = wp.max(radius, lights.radius[li])
        e = lights.rgb[li] / wp.max(dist * dist, r * r)
    tt = ray_box(p, to_light, extent)
    length = wp.max(wp.min(tt[1], dist), 0.0)
    steps = length / (2.0 * radius)
    n_full = int(wp.floor(steps))
    return to_light, e, p + length * to_light, n_full, steps - float(n_full)


@wp.kernel
def tube_march_kernel(sigma_tilde: Any, inv_data_spacing: wp.vec3,
                      lights: Lights, transmittance: wp.array(dtype=wp.float32),
                      lookup_scale: float, radius: float, substeps: int, spacing: wp.vec3,
                      shape: wp.vec3i,
                      bricks: wp.vec3i, extent: wp.vec3, out: Any):
    """March one light's front to one cache point (eqs. 15–17).

    ``wp.tid()`` enumerates ``(light, brick, point in brick)``: bricks of
    :data:`BRICK` cache points, ``bricks`` of them per axis (k fastest, in bricks and
    inside them); threads beyond the grid's ``shape`` return. Point ``(i, j, k)`` lies at
    ``(i, j, k) * spacing`` (world units, local frame); ``lookup_scale`` is
    ``r (n - 1) / sigma_max``, the transmittance table's entries per unit ``σ̃t``; ``extent``
    the box (world units). Writes ``L̃d`` (RGB irradiance units) to ``out[light, i, j, k]``.
    Generic: ``sigma_tilde`` an array3d(float32) and ``out`` an array4d(vec3) (software
    trilinear), or a ``wp.Texture3D`` and an array4d(vec4h) in units of
    :func:`radiance_unit` (:data:`tube_march_texture`).
    """
    li, i, j, k = cache_point(wp.tid(), bricks)
    if i >= shape[0] or j >= shape[1] or k >= shape[2]:
        return
    p = wp.vec3(float(i) * spacing[0], float(j) * spacing[1], float(k) * spacing[2])
    to_light, e, entry, n_full, eta = march_path(lights, li, p, radius, extent)
    step = 2.0 * radius
    travel = -to_light
    last = float(transmittance.shape[0] - 1)
    front = float(1.0)
    for n in range(n_full):
        st = step_extinction(sigma_tilde, inv_data_spacing, entry + (float(2 * n) * radius) * travel,
                             travel, step, substeps)
        front *= table_lerp(transmittance, wp.clamp(st * lookup_scale, 0.0, last))
        if front < NEGLIGIBLE:
            front = 0.0
            break
    beyond = front
    if eta > 0.0 and front > 0.0:
        st = step_extinction(sigma_tilde, inv_data_spacing,
                             entry + (float(2 * n_full) * radius) * travel, travel, step, substeps)
        beyond = front * table_lerp(transmittance, wp.clamp(st * lookup_scale, 0.0, last))
    store_radiance(out, li, i, j, k, ((1.0 - eta) * front + eta * beyond) * e,
                   radiance_unit(lights, li, radius))


#: The exact software path (the default).
tube_march_software = wp.overload(tube_march_kernel, {
    "sigma_tilde": wp.array3d(dtype=wp.float32), "out": wp.array4d(dtype=wp.vec3)})
#: Hardware texture filtering of ``σ̃t`` (CUDA), half-precision RGBA output for the cache texture.
tube_march_texture = wp.overload(tube_march_kernel, {
    "sigma_tilde": wp.Texture3D, "out": wp.array4d(dtype=wp.vec4h)})


@wp.func
def field_sample(field: wp.array(dtype=wp.float32), dims: wp.vec3i, u: wp.vec3):
    """Trilinear sample of the flat ``(nx, ny, nz)`` grid ``field`` at index position ``u``
    (clamped): 32-bit offsets from one base instead of eight 3D index computations."""
    i = wp.clamp(int(u[0]), 0, dims[0] - 2)
    j = wp.clamp(int(u[1]), 0, dims[1] - 2)
    k = wp.clamp(int(u[2]), 0, dims[2] - 2)
    fx = wp.clamp(u[0] - float(i), 0.0, 1.0)
    fy = wp.clamp(u[1] - float(j), 0.0, 1.0)
    fz = wp.clamp(u[2] - float(k), 0.0, 1.0)
    sz = dims[2]
    sy = dims[1] * dims[2]
    b = (i * dims[1] + j) * sz + k
    c00 = wp.lerp(field[b], field[b + 1], fz)
    c01 = wp.lerp(field[b + sz], field[b + sz + 1], fz)
    c10 = wp.lerp(field[b + sy], field[b + sy + 1], fz)
    c11 = wp.lerp(field[b + sy + sz], field[b + sy + sz + 1], fz)
    return wp.lerp(wp.lerp(c00, c01, fy), wp.lerp(c10, c11, fy), fx)


@wp.func
def field_sample(field: wp.Texture3D, dims: wp.vec3i, u: wp.vec3):  # noqa: F811
    """Hardware-filtered sample of the step field's texture at index position ``u``
    (clamp addressing; ``dims`` unused)."""
    return wp.texture_sample(field, wp.vec3(u[2] + 0.5, u[1] + 0.5, u[0] + 0.5), dtype=float)


@functools.cache
def field_march_kernel(samples: int, half: bool, texture: bool = False):
    """The march of :func:`tube_march_kernel` on a step field (:func:`step_extinction_field`):
    ``samples`` samples per step of ``2r`` (unrolled), each at the middle of its share,
    positions advanced incrementally in the field's index units. ``half``: the
    half-precision RGBA output of the texture path, else RGB float. ``texture``: the field
    is a ``wp.Texture3D`` (hardware trilinear filtering), else a flat float array."""
    SAMPLES = int(samples)

    @wp.kernel(module="unique")
    def march(field: Any, dims: wp.vec3i, inv_field: wp.vec3,
              lights: Lights, transmittance: wp.array(dtype=wp.float32), lookup_scale: float,
              radius: float, spacing: wp.vec3, shape: wp.vec3i, bricks: wp.vec3i,
              extent: wp.vec3, out: Any):
        li, i, j, k = cache_point(wp.tid(), bricks)
        if i >= shape[0] or j >= shape[1] or k >= shape[2]:
            return
        p = wp.vec3(float(i) * spacing[0], float(j) * spacing[1], float(k) * spacing[2])
        to_light, e, entry, n_full, eta = march_path(lights, li, p, radius, extent)
        h = 2.0 * radius / float(wp.static(SAMPLES))
        du = wp.cw_mul(-h * to_light, inv_field)  # one sample to the next
        u = wp.cw_mul(entry, inv_field) + 0.5 * du
        last = float(transmittance.shape[0] - 1)
        scale = lookup_scale / float(wp.static(SAMPLES))
        front = float(1.0)
        n = int(0)
        while n < n_full:
            st = float(0.0)
            for _s in range(wp.static(SAMPLES)):
                st += field_sample(field, dims, u)
                u += du
            front *= table_lerp(transmittance, wp.clamp(st * scale, 0.0, last))
            if front < NEGLIGIBLE:
                front = 0.0
                n = n_full
            n += 1
        beyond = front
        if eta > 0.0 and front > 0.0:
            st = float(0.0)
            for _s in range(wp.static(SAMPLES)):
                st += field_sample(field, dims, u)
                u += du
            beyond = front * table_lerp(transmittance, wp.clamp(st * scale, 0.0, last))
        store_radiance(out, li, i, j, k, ((1.0 - eta) * front + eta * beyond) * e,
                       radiance_unit(lights, li, radius))

    out_type = wp.array4d(dtype=wp.vec4h) if half else wp.array4d(dtype=wp.vec3)
    field_type = wp.Texture3D if texture else wp.array(dtype=wp.float32)
    return wp.overload(march, {"field": field_type, "out": out_type})
