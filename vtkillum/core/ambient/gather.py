"""Ambient ray casting (Ament et al. 2013, section 4.2.3, Algorithm 1, eqs. 18–21).

One primary ray per pixel marches through the volume. Two estimators share the kernel
(``mode``); both use the tube-marched radiance cache ``L̃d,j``, the ambient extinction
``σ̃t`` and the preintegration table at the scene's ``g``, with ``ω`` the direction
towards the camera, ``ω_j`` light ``j``'s travel direction at ``x'``,
``θ_j = arccos(ω · ω_j)``, ``τ = r σ̃t(x')`` and ``σs = Λ · color · σt`` (DESIGN.md); there
is no emission term, and the returned alpha is ``1 - T`` along the whole primary ray.

``"centred"`` (default)
    The in-scattered radiance at the sphere's *centre* ``x'``, attenuated to the camera
    from ``x'`` like every other method::

        J̃ += T(x', x_c) (1 - exp(-σt Δt)) Λ color ⊙ L̃(x', ω)
        L̃(x', ω) = Σ_j L̃d,j(x_j) [p(θ_j) T_j(x_j, x') + M(θ_j, τ, g)]

    with ``x_j = x' + min(r, d_j) (-ω_j)`` where light ``j`` enters the sphere (not past a
    point light at distance ``d_j``), ``T_j`` the transmittance of the real medium from
    ``x_j`` to ``x'`` (a short shadow ray of ``r``, sampled at the step ``Δt``; midpoint,
    or a random offset per sample with jitter) and ``M = L̃o - U`` the table's *scattered*
    part (:attr:`~vtkillum.core.ambient.table.PreintegrationTable.scattered`): ``U``, the
    part of ``L̃o`` that crossed the sphere without an interaction, is the light of eq.
    11's boundary scattered at the far side and carried back across the whole sphere;
    its place is taken by the exact unscattered light at the centre, ``p · T_j``. In
    optically thin regions (``M → 0``) this is exact single scattering. ``M`` is used as
    in-scattered radiance at the centre: in a thick homogeneous medium the image is then
    ``Λ M``, the table's exit radiance from a sphere whose boundary light carried its
    own factor ``Λ`` (eq. 11 leaves it out).
``"paper"``
    Algorithm 1 as published::

        J̃ += T(x_o, x_c) · σs(x') ⊙ L̃(x', ω, r) · Δt                       (eq. 20)
        L̃(x', ω, r) = Σ_j L̃d,j(x_j) · L̃o(θ_j, r σ̃t(x'), g)                 (eq. 21)

    with ``x_j = x' - r ω_j`` and the transmittance taken from ``x_o = x' + r ω``, the
    sphere's exit point towards the viewer (lines 5 and 20–22: "the attenuation inside
    the sphere is already in the table"). ``L̃o`` is the radiance *leaving* a sphere,
    already integrated over its diameter, and the gather integrates it again as a source
    density while the first ``r`` of matter along each ray is not attenuated at all: in
    an optically thick medium the image is ``(1 + r σt) Λ L̃o``, so it grows linearly with
    ``r`` (2-7 times the path tracer's energy on thick clouds for ``r = 2-8`` voxels), and
    on shells thinner than ``r`` the pixel follows the optical depth of the interpolated
    shell instead of saturating, which draws the voxel grid's terraces as rings and
    bands (``builtin:ct:96``). Its unscattered term also darkens back-scattered light by
    ``exp(-2 τ |cos θ|)``. Kept to reproduce the paper; see ``docs/ambient_scattering.md``
    for the comparison with the path tracer.

Sampling follows the project's ray caster: samples at ``t0 + (k + ξ) Δt`` inside
the box with a per-pixel jitter ``ξ`` (or ``ξ = 0``), early termination once the
opacity (``"paper"``: the shifted opacity) exceeds ``early_termination``, and empty
samples (``σt = 0``) skip the table and cache look-ups (section 6: "the extra texture
access can be avoided in empty regions"). Blocks of the volume that are surely empty
(:mod:`~vtkillum.core.empty_space`) are leapt over (``"paper"``: once the shifted
point ``x_o`` has left all matter seen so far behind), which changes no pixel.

Speed without changing the result
---------------------------------
* Each warp of 32 threads shades a tile of :data:`TILE` pixels (4 wide, 8 high) rather
  than 32 pixels of one row: its rays stay together through the volume, share cache
  lines and end at similar depths.
* ``"paper"``: when the radius is a whole number ``m`` of steps (as with the defaults in
  voxels), ``x_o`` of sample ``k`` *is* sample ``k - m``, so its ``σt`` is taken from a delay line
  of the last :data:`DELAY` samples instead of a second trilinear look-up (samples leapt
  over as empty, or before the box, count as 0, as the look-up would give).

Hardware filtering (CUDA)
-------------------------
With ``textures`` (:class:`~vtkillum.core.ambient.textures.AmbientTextures`) the data
scalars, ``σ̃t``, the (half-precision) radiance cache, the table slice (``M`` or ``L̃o``) and
the transfer function's colour/``σt`` tables (one RGBA 1D texture) are sampled by the GPU's texture units (one fetch per sample instead of eight, or four, loads;
see :mod:`~vtkillum.core.ambient.textures` for the accuracy: within 2e-3 of the maximum on
average). When ``textures.radiance`` is None (the cache's default on CUDA, ``data_textures``)
only the scalars, ``σ̃t`` and the transfer function come from textures -- the loads of the
primary and the short shadow rays -- while the radiance cache and the table slice are read
from their arrays as computed, so that a ``g`` or light edit copies nothing into a texture.
The gradient of the optional specular term is still taken from the scalar array. Without
``textures`` (and always on the CPU) every sample is the exact software trilinear
interpolation.

Optional terms, as in the paper's comparisons (Figs. 6d, 6e)
------------------------------------------------------------
* Specular highlights: ``ks · max(n·h, 0)^shininess / (4π)`` is added to each
  light's phase function (``"centred"``: attenuated like the unscattered light,
  ``p · T_j``) or to its ``L̃o`` (``"paper"``), driven by the same distributed light
  ``L̃d,j(x_j)``, with ``n`` the normalised central-difference
  gradient flipped towards the viewer and ``h`` the half vector; no highlight
  where the gradient vanishes.
* SAT-based ambient occlusion: an ambient light of fluence
  ``strength · Σ_j E_j(x')`` from all directions (``E_j`` the light's unattenuated
  irradiance), occluded by ``V = exp(-r σ̃t(x'))``, the transmittance along one
  radius of the ambient sphere; source ``σs · V · strength · Σ E_j / (4π)``.
  Simplification vs. Schlegel et al. 2011: one SAT cube (the ``σ̃t`` already
  computed) instead of several nested ones.
"""

from __future__ import annotations

import functools
from typing import Any

import numpy as np
import warp as wp

from vtkillum.core.ambient.textures import (
    AmbientTextures,
    fetch_ambient,
    fetch_data,
    fetch_optics,
    optics_color,
    optics_texture,
)
from vtkillum.core.ambient.tube_march import RadianceGrid, radiance_unit, sample_radiance
from vtkillum.core.device import resolve_device
from vtkillum.core.empty_space import BLOCK
from vtkillum.core.raymarch import mean_samples, pixel_ray, sample_count
from vtkillum.core.warp_common import (
    CameraParams,
    Lights,
    Medium,
    hg_phase,
    inside_box,
    light_incidence,
    texture_from,
    view_normal,
)

#: Pixels per kernel launch (the image is launched in row bands for progress reports).
TILE_PIXELS = {"cpu": 1 << 14, "cuda": 1 << 22}
#: Pixels (columns, rows) shaded by the 32 threads of one warp (H200, Supernova 432³ at
#: 512²: 15 % faster than 32 pixels of a row).
TILE = (4, 8)
TILE_W = wp.constant(TILE[0])
TILE_H = wp.constant(TILE[1])
#: Longest delay line (in samples) for reusing ``σt`` at ``x_o``; longer radii sample it.
DELAY = 64
DelayLine = wp.types.vector(length=DELAY, dtype=wp.float32)
#: Estimators of the gather (see the module docstring).
GATHER_MODES = {"centred": 0, "paper": 1}
#: Register cap per thread of the CUDA gather (:func:`gather_kernel`), software and texture
#: sampling, and its threads per block. H100, centred gather at 512² (Supernova / Manix
#: stand-ins): blocks of 128 instead of 256 threads 7.7 → 7.2 ms / 2.3 → 2.0 ms (software),
#: a cap of 96 registers 3.6 → 3.0 / 1.3 → 1.2 ms (textures); capping the software kernel
#: at 64-128 registers was slower or no faster (it is bound by its loads, 95 % L1 hits).
#: Keys: the sources of :func:`gather_kernel`.
GATHER_REGISTERS = {"arrays": 0, "textures": 96, "data_textures": 0}
GATHER_BLOCK = 128


def gather(medium: Medium, sigma_tilde, cache: RadianceGrid, lights: Lights, camera: CameraParams,
           table, sigma_max: float, radius: float, step: float, jitter: bool = True,
           seed: int = 0, early_termination: float = 0.999, specular: float = 0.0,
           shininess: float = 32.0, grad_eps: float = 0.0, ambient_occlusion: float = 0.0,
           device: str | None = None, progress=None, occupied=None, spacing=None,
           textures: AmbientTextures | None = None, mode: str = "centred"):
    """Render one image by ambient ray casting.

    Parameters
    ----------
    medium : Medium
        Volume and optical model (``medium.albedo`` is ``Λ``).
    sigma_tilde : wp.array3d(float32)
        Ambient extinction on the data grid (1/world units).
    cache : RadianceGrid
        Tube-marched radiance per light (:func:`~vtkillum.core.ambient.tube_march.radiance_cache`).
    lights : Lights
        Light list in the local frame (same order as the cache).
    camera : CameraParams
        Camera in the local frame; gives the image size.
    table : ndarray (n_theta, n_sigma) or wp.array2d(float32)
        At the scene's ``g`` over θ in [0, π] × ``r σ̃t`` in [0, sigma_max]: the scattered
        part ``M`` of the table (``mode="centred"``,
        :meth:`~vtkillum.core.ambient.table.PreintegrationTable.scattered_slice`) or ``L̃o``
        itself (``mode="paper"``, :meth:`~vtkillum.core.ambient.table.PreintegrationTable.g_slice`).
    sigma_max : float
        Optical radius of the table's last column.
    radius : float
        Sphere radius ``r`` (world units).
    step : float
        Ray-marching step ``Δt`` (world units).
    jitter : bool
        Per-pixel random offset of the samples (turns banding into noise).
    seed : int
        Seed of the jitter.
    early_termination : float
        Stop a ray once its (shifted) opacity exceeds this.
    specular, shininess : float
        Weight and exponent of the optional specular lobe (0: off).
    grad_eps : float
        Gradient magnitude (data units per world unit) below which there is no normal.
    ambient_occlusion : float
        Strength of the optional SAT-based ambient term (0: off).
    device : str, optional
        Warp device.
    progress : callable, optional
        ``progress(fraction)`` after each row band.
    occupied : wp.array3d(int32), optional
        Block occupancy for empty-space skipping
        (:func:`~vtkillum.core.empty_space.occupancy`); none: no skipping.
    spacing : (3,) float, optional
        Data spacing (world units), needed with ``occupied``.
    textures : AmbientTextures, optional
        Sample scalars, ``σ̃t`` and the cache from these textures (hardware filtering,
        CUDA only; :attr:`AmbientState.textures <vtkillum.core.ambient.cache.AmbientState>`)
        instead of ``medium.scalars``, ``sigma_tilde`` and ``cache.data``.
    mode : {"centred", "paper"}
        The estimator (see the module docstring): ``"centred"`` (default) or the paper's
        Algorithm 1 as published (``"paper"``).

    Returns
    -------
    radiance : ndarray (H, W, 3) float32
    alpha : ndarray (H, W) float32
    mean_samples : float
        Mean number of samples per pixel.
    """
    radiance, alpha, samples = gather_device(
        medium, sigma_tilde, cache, lights, camera, table, sigma_max, radius, step, jitter, seed,
        early_termination, specular, shininess, grad_eps, ambient_occlusion, device, progress,
        occupied, spacing, textures, mode)
    height, width = radiance.shape
    rad = radiance.numpy().astype(np.float32).reshape(height, width, 3)
    return rad, alpha.numpy().astype(np.float32), mean_samples(samples)


def gather_device(medium: Medium, sigma_tilde, cache: RadianceGrid, lights: Lights,
                  camera: CameraParams, table, sigma_max: float, radius: float, step: float,
                  jitter: bool = True, seed: int = 0, early_termination: float = 0.999,
                  specular: float = 0.0, shininess: float = 32.0, grad_eps: float = 0.0,
                  ambient_occlusion: float = 0.0, device: str | None = None, progress=None,
                  occupied=None, spacing=None, textures: AmbientTextures | None = None,
                  mode: str = "centred"):
    """:func:`gather` without the download: warp arrays radiance (H, W) vec3, alpha, samples.

    The device is synchronised before returning (for timing the kernel alone).
    """
    device = resolve_device(device)
    if mode not in GATHER_MODES:
        raise ValueError(f"gather mode must be one of {sorted(GATHER_MODES)}, got {mode!r}")
    if occupied is None:  # one block covering everything, marked occupied: no skipping
        occupied = wp.ones((1, 1, 1), dtype=wp.int32, device=device)
        block = np.full(3, 1.0e30)
    else:
        if spacing is None:
            raise ValueError("gather: pass the data spacing together with the occupancy grid")
        block = BLOCK * np.asarray(spacing, dtype=np.float64)
    if not isinstance(table, wp.array):
        table = wp.array(np.asarray(table, dtype=np.float32), dtype=wp.float32, device=device)
    table_size = wp.vec2i(*table.shape)
    if textures is None:
        kind = "arrays"
        sources = [medium.scalars, sigma_tilde, cache.data, medium.sigma_table]
    else:
        if not wp.get_device(device).is_cuda:
            raise ValueError("gather: hardware-filtered textures need a CUDA device; on the CPU "
                             "pass textures=None (the exact software path)")
        optics = textures.optics if textures.optics is not None else optics_texture(medium)
        if textures.radiance is None:  # the data and the transfer function only
            kind = "data_textures"
            sources = [textures.scalars, 0, cache.data, optics]
        else:
            kind = "textures"
            given = textures.scattered if mode == "centred" else textures.table
            table = given if given is not None else texture_from(table)
            # textures.scalars holds σ̃t too (sigma_tilde=0 selects that overload)
            sources = [textures.scalars, 0, textures.radiance, optics]
    registers = 0 if device == "cpu" else GATHER_REGISTERS[kind]
    kernel = gather_kernel(mode, kind, registers)
    inputs = [medium, *sources, cache, lights, camera, table, table_size, float(sigma_max),
              float(radius),
              float(step), int(bool(jitter)), int(seed), float(early_termination),
              float(specular), float(shininess), float(grad_eps), float(ambient_occlusion),
              occupied, wp.vec3(*block.astype(np.float32)),
              wp.vec3(*(1.0 / block).astype(np.float32)), delay_samples(radius, step)]
    width, height = int(camera.width), int(camera.height)
    # every pixel is written: no need to clear
    radiance = wp.empty((height, width), dtype=wp.vec3, device=device)
    alpha = wp.empty((height, width), dtype=wp.float32, device=device)
    samples = wp.empty((height, width), dtype=wp.int32, device=device)
    band_pixels = TILE_PIXELS["cpu" if device == "cpu" else "cuda"]
    rows = max(TILE[1], (band_pixels // max(width, 1)) // TILE[1] * TILE[1])
    tiles_x = -(-width // TILE[0])
    for row0 in range(0, height, rows):
        band = min(rows, height - row0)
        threads = tiles_x * -(-band // TILE[1]) * TILE[0] * TILE[1]
        wp.launch(kernel, dim=threads,
                  inputs=[*inputs, row0, row0 + band, tiles_x, radiance, alpha, samples],
                  device=device, block_dim=GATHER_BLOCK)
        if progress is not None and row0 + band < height:
            wp.synchronize_device(device)
            progress((row0 + band) / height)
    wp.synchronize_device(device)
    return radiance, alpha, samples


def delay_samples(radius: float, step: float) -> int:
    """``m`` with ``radius = m * step`` (to float rounding) and ``1 <= m <= DELAY``, else -1."""
    m = int(round(radius / step))
    if 1 <= m <= DELAY and abs(m * step - radius) <= 1.0e-6 * radius:
        return m
    return -1


# --- device functions -----------------------------------------------------------------------------
@wp.func
def fetch_radiance(src: wp.array4d(dtype=wp.vec3), cache: RadianceGrid, lights: Lights,
                   light: int, radius: float, p: wp.vec3):
    """Software trilinear sample of light ``light``'s cache at ``p`` (``src`` is ``cache.data``)."""
    return sample_radiance(cache, light, p)


@wp.func
def fetch_radiance(src: wp.Texture3D, cache: RadianceGrid, lights: Lights,  # noqa: F811
                   light: int, radius: float, p: wp.vec3):
    """Hardware-filtered sample of light ``light``'s slab of the stacked RGBA cache texture.

    The depth coordinate is clamped into the light's slab (texel centres
    ``light * nx + 0.5 .. light * nx + nx - 0.5``) so no other light filters in; the
    texture holds the radiance in units of
    :func:`~vtkillum.core.ambient.tube_march.radiance_unit`.
    """
    u = wp.cw_mul(p, cache.inv_spacing)
    nx = cache.points[0]
    x = wp.clamp(u[0], 0.0, float(nx - 1)) + float(light * nx) + 0.5
    v = wp.texture_sample(src, wp.vec3(u[2] + 0.5, u[1] + 0.5, x), dtype=wp.vec4f)
    return radiance_unit(lights, light, radius) * wp.vec3(v[0], v[1], v[2])


@wp.func
def sigma_t_from(m: Medium, scalars: Any, optics: Any, p: wp.vec3):
    """Extinction at local position ``p`` (0 outside the volume), scalars from ``scalars``,
    the transfer function from ``optics`` (:func:`~vtkillum.core.ambient.textures.fetch_optics`)."""
    if not inside_box(p, m.extent):
        return 0.0
    return fetch_optics(optics, m, fetch_data(scalars, m.inv_spacing, p)[0])[3]


@wp.func
def segment_transmittance(m: Medium, scalars: Any, optics: Any, p: wp.vec3, w: wp.vec3,
                          length: float, step: float, xi: float):
    """Transmittance of the real medium from ``p`` along unit ``w`` over ``length`` (world
    units): equal segments no longer than ``step``, each sampled at fraction ``xi`` (0.5: the
    midpoint rule); ``σt`` as :func:`sigma_t_from` (0 outside the volume)."""
    if length <= 0.0:
        return 1.0
    n = int(wp.ceil(length / step))
    h = length / float(n)
    tau = float(0.0)
    for q in range(n):
        tau += sigma_t_from(m, scalars, optics, p + ((float(q) + xi) * h) * w)
    return wp.exp(-tau * h)


@wp.func
def lookup_table(table: wp.array2d(dtype=wp.float32), size: wp.vec2i, cos_theta: float,
                 optical_radius: float, sigma_max: float):
    """Bilinear ``L̃o`` at ``θ = arccos(cos_theta)`` and ``r σ̃t`` (both axes clamped); ``size``
    is the table's ``(n_theta, n_sigma)``."""
    nt = size[0]
    ns = size[1]
    u = wp.acos(wp.clamp(cos_theta, -1.0, 1.0)) * (float(nt - 1) / wp.pi)
    v = wp.clamp(optical_radius / sigma_max * float(ns - 1), 0.0, float(ns - 1))
    i = wp.clamp(int(u), 0, nt - 2)
    j = wp.min(int(v), ns - 2)
    fu = wp.clamp(u - float(i), 0.0, 1.0)
    fv = v - float(j)
    a = wp.lerp(table[i, j], table[i + 1, j], fu)
    b = wp.lerp(table[i, j + 1], table[i + 1, j + 1], fu)
    return wp.lerp(a, b, fv)


@wp.func
def lookup_table(table: wp.Texture2D, size: wp.vec2i, cos_theta: float,  # noqa: F811
                 optical_radius: float, sigma_max: float):
    """:func:`lookup_table` by hardware bilinear filtering of the slice as a texture (θ rows,
    ``r σ̃t`` columns: texel ``(j + 0.5, i + 0.5)`` is entry ``[i, j]``; clamp addressing)."""
    nt = size[0]
    ns = size[1]
    u = wp.acos(wp.clamp(cos_theta, -1.0, 1.0)) * (float(nt - 1) / wp.pi)
    v = wp.clamp(optical_radius / sigma_max * float(ns - 1), 0.0, float(ns - 1))
    return wp.texture_sample(table, wp.vec2(v + 0.5, u + 0.5), dtype=float)


@wp.func
def block_exit(o: wp.vec3, d: wp.vec3, lo: wp.vec3, hi: wp.vec3):
    """Distance along ``o + t d`` at which the ray leaves the box ``[lo, hi]`` it is inside."""
    t = float(1.0e30)
    for a in range(3):
        if d[a] > 1.0e-12:
            t = wp.min(t, (hi[a] - o[a]) / d[a])
        elif d[a] < -1.0e-12:
            t = wp.min(t, (lo[a] - o[a]) / d[a])
    return t


# --- kernel ---------------------------------------------------------------------------------------
@functools.cache
def gather_kernel(mode: str, sources: str, registers: int = 0):
    """The gather kernel of estimator ``mode``, made on first use.

    The estimator is compiled in (``wp.static``: the centred kernel has no branches for the
    ``x_o`` attenuation and delay line of ``"paper"``, and its registers show it).
    ``sources``: ``"arrays"``, the exact software overload; ``"textures"``, everything
    through textures (hardware filtering); ``"data_textures"``, the scalars, ``σ̃t`` and the
    transfer function through textures, the radiance cache and the table from arrays. ``registers`` caps the registers per
    thread on CUDA (0: none): uncapped, the kernel took 147 registers, one block of 256
    threads per multiprocessor (12.5 % occupancy) and stalled on its chains of dependent
    loads (H100, Nsight Compute), but it is bound by the number of its loads rather than by
    occupancy: see :data:`GATHER_REGISTERS`.
    """
    centred = mode == "centred"
    options = {"enable_backward": False, "module": "unique"}
    if registers:
        options["cuda_max_registers"] = int(registers)

    @wp.kernel(**options)
    def ambient_gather_kernel(
        m: Medium,
        scalars: Any,
        sigma_tilde: Any,
        radiance_src: Any,
        optics: Any,
        cache: RadianceGrid,
        lights: Lights,
        cam: CameraParams,
        table: Any,
        table_size: wp.vec2i,
        sigma_max: float,
        radius: float,
        step: float,
        jitter: int,
        seed: int,
        stop_alpha: float,
        specular: float,
        shininess: float,
        grad_eps: float,
        ambient_occlusion: float,
        occupied: wp.array3d(dtype=wp.int32),
        block: wp.vec3,
        inv_block: wp.vec3,
        delay: int,
        row0: int,
        row_end: int,
        tiles_x: int,
        radiance: wp.array2d(dtype=wp.vec3),
        alpha: wp.array2d(dtype=wp.float32),
        samples: wp.array2d(dtype=wp.int32),
    ):
        """Algorithm 1 for one pixel.

        ``wp.tid()`` enumerates tiles of :data:`TILE` pixels of rows ``row0 .. row_end - 1``
        (``tiles_x`` tiles per row of tiles, the pixels of a tile row by row); threads outside
        the image return. Row 0 is at the top. Positions in the volume's local frame,
        ``step`` and ``radius`` in world units, ``σ`` in 1/world units; ``occupied`` flags the
        blocks of size ``block`` (world units, ``inv_block`` its reciprocal) that may hold
        matter (:mod:`~vtkillum.core.empty_space`); ``delay`` is
        :func:`delay_samples` (-1: sample ``σt`` at ``x_o``; ``"paper"`` only); the
        estimator is compiled in (:func:`gather_kernel`). Writes the gathered radiance
        ``J̃`` and ``alpha = 1 - T`` at ``[row, col]``. Generic: ``scalars``, ``sigma_tilde``,
        ``radiance_src``, ``optics`` and ``table`` are ``m.scalars``, the σ̃t array,
        ``cache.data``, ``m.sigma_table`` and the table slice array
        (the software overload) or the two-channel scalar/σ̃t ``wp.Texture3D``, 0
        (σ̃t comes with the scalars), the radiance ``wp.Texture3D``, the RGBA colour/σt
        ``wp.Texture1D`` and a ``wp.Texture2D`` (the texture overload).
        """
        tid = wp.tid()
        tile = tid / (TILE_W * TILE_H)
        lane = tid - tile * (TILE_W * TILE_H)
        row = row0 + (tile / tiles_x) * TILE_H + lane / TILE_W
        c = (tile % tiles_x) * TILE_W + lane % TILE_W
        if row >= row_end or c >= cam.width:
            return
        o, d, t0, t1 = pixel_ray(cam, m.extent, row, c)
        colour = wp.vec3(0.0)
        trans = float(1.0)  # T along the ray up to the sample (alpha)
        trans_out = float(1.0)  # T from the sphere's exit point x_o to the camera (Algorithm 1)
        count = int(0)
        if t0 < t1:
            state = wp.rand_init(seed, row * cam.width + c)
            xi = float(0.0)
            if jitter != 0:
                xi = wp.randf(state)
            n = sample_count(t0, t1, step, xi)
            stop_t = 1.0 - stop_alpha
            # The paper attenuates from x_o = x' + r ω, r closer to the camera; the centred
            # estimator from x' itself.
            shift = wp.where(wp.static(centred), 0.0, radius)
            t_matter = float(-1.0e30)  # position of the last sample with sigma_t > 0
            recent = DelayLine()  # sigma_t of sample k at [k % DELAY] (0: leapt over or none yet)
            k = int(0)
            while k < n:
                t = t0 + (float(k) + xi) * step
                p = o + t * d
                if t - shift > t_matter:
                    # (x_o has) left all matter behind: leap over a surely empty block
                    bi = wp.clamp(int(wp.floor(p[0] * inv_block[0])), 0, occupied.shape[0] - 1)
                    bj = wp.clamp(int(wp.floor(p[1] * inv_block[1])), 0, occupied.shape[1] - 1)
                    bk = wp.clamp(int(wp.floor(p[2] * inv_block[2])), 0, occupied.shape[2] - 1)
                    if occupied[bi, bj, bk] == 0:
                        lo = wp.vec3(float(bi) * block[0], float(bj) * block[1], float(bk) * block[2])
                        t_exit = block_exit(o, d, lo, lo + block)
                        k_next = int(wp.ceil((t_exit - t0) / step - xi))
                        if k_next > k:
                            k = k_next
                            # the last `delay` samples and those leapt over are all empty
                            recent = DelayLine()
                            continue
                data = fetch_data(scalars, m.inv_spacing, p)
                s = data[0]
                opt = fetch_optics(optics, m, s)
                sig = opt[3]
                count += 1
                if sig > 0.0:
                    t_matter = t
                    col = optics_color(optics, m, s, opt)
                    tau_amb = radius * fetch_ambient(sigma_tilde, m.inv_spacing, p, data)
                    normal = wp.vec3(0.0)
                    if specular > 0.0:
                        normal = view_normal(m, p, d, grad_eps)
                    light = wp.vec3(0.0)
                    e_sum = wp.vec3(0.0)
                    for li in range(lights.count):
                        to_light, dist, e = light_incidence(lights, li, p)
                        # cos θ_j = ω · ω_j with ω = -d (to the camera), ω_j = -to_light (travel).
                        cos_theta = wp.dot(d, to_light)
                        lobe = lookup_table(table, table_size, cos_theta, tau_amb, sigma_max)
                        spec = float(0.0)
                        if specular > 0.0 and wp.length_sq(normal) > 0.0:
                            h = wp.normalize(to_light - d)
                            spec = specular * wp.pow(wp.max(wp.dot(normal, h), 0.0), shininess) / (
                                4.0 * wp.pi)
                        if wp.static(centred):
                            # x_j = x' - r ω_j (not past a point light): the light entering the
                            # sphere; the unscattered part reaches x' through the real medium.
                            seg = wp.min(radius, dist)
                            seg_xi = float(0.5)
                            if jitter != 0:
                                seg_xi = wp.randf(state)
                            ld = fetch_radiance(radiance_src, cache, lights, li, radius,
                                                p + seg * to_light)
                            direct = segment_transmittance(m, scalars, optics, p, to_light, seg,
                                                           step, seg_xi)
                            light += ((hg_phase(cos_theta, m.g) + spec) * direct + lobe) * ld
                        else:
                            # at x_j = x' - r ω_j
                            ld = fetch_radiance(radiance_src, cache, lights, li, radius,
                                                p + radius * to_light)
                            light += (lobe + spec) * ld
                        e_sum += e
                    if ambient_occlusion > 0.0:
                        light += (ambient_occlusion * wp.exp(-tau_amb) / (4.0 * wp.pi)) * e_sum
                    if wp.static(centred):
                        # the step's own attenuation integrated exactly, as the ray caster does
                        colour += (trans * (1.0 - wp.exp(-sig * step)) * m.albedo) * wp.cw_mul(
                            col, light)
                    else:
                        colour += (trans_out * step * m.albedo * sig) * wp.cw_mul(col, light)
                trans *= wp.exp(-sig * step)
                if wp.static(centred):
                    if trans < stop_t:
                        break
                else:
                    t_out = t - radius  # x_o = x' + r ω lies r closer to the camera
                    if delay > 0:
                        sig_out = recent[(k - delay + DELAY) % DELAY]  # sample k - delay, at x_o
                        recent[k % DELAY] = sig
                        if t_out > 0.0:
                            trans_out *= wp.exp(-sig_out * step)
                    elif t_out > 0.0:
                        trans_out *= wp.exp(-sigma_t_from(m, scalars, optics, o + t_out * d) * step)
                    if trans_out < stop_t:
                        break
                k += 1
        radiance[row, c] = colour
        alpha[row, c] = 1.0 - trans
        samples[row, c] = count

    arrays = {"scalars": wp.array3d(dtype=wp.float32),
              "sigma_tilde": wp.array3d(dtype=wp.float32),
              "radiance_src": wp.array4d(dtype=wp.vec3), "optics": wp.array(dtype=wp.float32),
              "table": wp.array2d(dtype=wp.float32)}
    data = {"scalars": wp.Texture3D, "sigma_tilde": int, "optics": wp.Texture1D}
    types = {"arrays": arrays, "data_textures": {**arrays, **data},
             "textures": {**data, "radiance_src": wp.Texture3D, "table": wp.Texture2D}}[sources]
    return wp.overload(ambient_gather_kernel, types)
