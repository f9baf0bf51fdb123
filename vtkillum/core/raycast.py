"""Warp ray caster: emission–absorption, single scattering, and illumination-volume shading.

Three render methods share one ray-marching kernel (one thread per pixel):

``emission`` (:func:`render_emission`)
    Classic emission–absorption DVR, discretised like VTK's GPU ray caster in
    composite mode: per step of length ``Δ`` (world units)
    ``α = 1 - exp(-σt(s) Δ)`` (σt from the transfer function, so this is VTK's
    opacity correction ``1 - (1 - α_tf) ** (Δ / u)``), ``C += T α color(s)``,
    ``T *= 1 - α``. Post-classification: the scalar is interpolated, then looked up.
``single`` (:func:`render_single`)
    Single scattering with ray-marched shadow rays to every light (to the box exit
    for directional lights, to the light for point lights) and the
    Henyey–Greenstein phase function. Per step the source is integrated exactly
    for the step's own attenuation: ``T (1 - exp(-σt Δ)) / σt · σs · Σ_l p(θ_l) T_l E_l``
    with ``σs = albedo · color · σt``; there is no emission term.
``illumination`` (:func:`render_illuminated`)
    Like ``single`` but the in-scattered light comes from a precomputed
    :class:`~vtkillum.core.illumination.IlluminationVolume` (per-light
    transmittance ``T_l`` and scattered fluence ``φ_s``) and the Phong factor of
    Zhang & Ma 2013 eq. 24: source ``σs [Σ_l p(θ_l) T_l E_l + φ_s / (4π)] · S``; see
    :mod:`vtkillum.core.illumination` for the convention. This is where the
    illumination methods (convection–diffusion, ambient scattering, photons, ...) plug in.

Sampling: rays go through pixel centres; samples lie at ``t0 + (k + ξ) Δ`` for
``k = 0, 1, ...`` inside the volume's box. With ``jitter=True`` (default) ``ξ`` is a
per-pixel random number in ``[0, 1)``, which turns wood-grain banding into noise
and makes the expected number of samples exactly ``length / Δ``. Without jitter
``ξ = 0`` for ``emission`` (VTK's convention: the first sample on the entry face,
so the images agree) and ``ξ = 1/2`` for the scattering modes: sample ``k`` then
stands for the step ``[kΔ, (k+1)Δ]`` past the entry point, whose attenuation it
integrates exactly, and evaluating the light at the step's midpoint keeps the
shading error second order in ``σt Δ`` instead of first. Shadow rays split their length into
equal segments no longer than ``Δ`` sampled at ``(k + ξ')`` (``ξ' = 1/2`` without
jitter), so a homogeneous medium's shadow is exact. Rays stop once
``alpha > early_termination``; shadow rays once their transmittance drops below
``1 - early_termination``.
"""

from __future__ import annotations

import functools
import time
from typing import Any

import numpy as np
import warp as wp

from vtkillum.core.device import resolve_device
from vtkillum.core.empty_space import BLOCK
from vtkillum.core.illumination import IlluminationVolume, gradient_threshold, shading_terms
from vtkillum.core.raymarch import (
    RAY_OPTIONS,
    launch_tiles,
    mean_samples,
    pixel_ray,
    pixel_work,
    ray_options,
    sample_count,
)
from vtkillum.core.render import RenderResult
from vtkillum.core.textures import (
    fetch_light,
    fetch_optics,
    fetch_rgb,
    fetch_scalar,
    light_texture,
    optics_color,
    optics_texture,
    rgb_texture,
    scalar_texture,
    textures_available,
)
from vtkillum.core.warp_common import (
    SHADOW_STOP_T,
    CameraParams,
    LightGrid,
    Lights,
    Medium,
    RGBGrid,
    block_run,
    hg_phase,
    inside_box,
    light_incidence,
    make_camera,
    make_light_grid,
    make_lights,
    make_medium,
    make_rgb_grid,
    ray_box,
    shadow_transmittance,
    view_normal,
)

EMISSION = wp.constant(0)
SINGLE = wp.constant(1)
ILLUMINATION = wp.constant(2)
MODE_NAMES = {EMISSION: "emission", SINGLE: "single", ILLUMINATION: "illumination"}

#: Options every ray-cast method accepts, with their defaults. ``near_cells``: how far
#: (in light-grid cells) ``illumination`` marches the direct light's shadow ray exactly
#: before reading the cached transmittance (0: read the grid at the sample).
#: ``near_tolerance``: the march is skipped (the grid read at the sample) where the optical
#: depth of the near field cannot exceed this (see :func:`cached_transmittance`; 0: never
#: skipped). ``textures``:
#: on CUDA, ``emission`` and ``illumination`` read the data, the transfer function and the
#: illumination grids through hardware-filtered textures (:mod:`vtkillum.core.textures`:
#: one fetch per sample instead of eight loads; images within ~1e-3 of the exact path);
#: ignored on the CPU, and ``single`` (the reference) always reads arrays.
RAYCAST_OPTIONS = {**RAY_OPTIONS, "near_cells": 2.0, "near_tolerance": 0.02, "textures": True}

#: Most pixels per kernel launch when the image is tiled into row bands (progress reporting).
TILE_PIXELS = {"cpu": 1 << 14, "cuda": 1 << 20}

#: Refuse settings whose worst case needs more samples than this for one pixel: the
#: samples of the primary ray plus, for each of them, every sample of its shadow rays
#: (``single``: to the box exit or the light; ``illumination``: the exact near march).
#: Under half a second of one CPU core, so that a launch of one pixel stays interruptible.
MAX_SAMPLES_PER_PIXEL = 1 << 26

#: Worst-case samples per kernel launch: the bands shrink (to parts of a row) as the work
#: per pixel grows, so that a CPU launch takes well under a second and Ctrl-C (seen
#: between launches) works; on CUDA a band keeps at least ``CUDA_MIN_BAND_PIXELS``.
BAND_SAMPLES = {"cpu": 1 << 24, "cuda": 1 << 38}
CUDA_MIN_BAND_PIXELS = 1 << 16


def render_emission(volume, scene, width, height, device=None, progress=None, **options):
    """Emission–absorption rendering, discretised like ``vtkGPUVolumeRayCastMapper``.

    Parameters
    ----------
    volume : vtkillum.core.volume.Volume
    scene : vtkillum.core.scene.Scene
        Uses transfer function, opacity unit distance, camera and step size.
    width, height : int
        Image size in pixels.
    device : str, optional
        Warp device.
    progress : callable, optional
        ``progress(fraction_done)``, called after each tile and with 1.0 at the end.
    step_size : float, optional
        Ray-marching step in world units; overrides ``scene.resolved_step_size``.
    jitter : bool
        Random per-pixel start offset in ``[0, step_size)`` (default True). Pass False
        for VTK's deterministic sampling.
    seed : int
        Seed of the per-pixel jitter hash.
    early_termination : float
        Stop a ray once its alpha exceeds this (default 0.999; 1 disables).

    Returns
    -------
    vtkillum.core.render.RenderResult
        Radiance is the premultiplied emitted colour ``Σ T α color``; alpha is
        ``1 - T``; ``info`` holds timings and the mean number of samples per pixel.
    """
    return _render(EMISSION, volume, scene, width, height, device, progress, None, options)


def render_single(volume, scene, width, height, device=None, progress=None, **options):
    """Single scattering with ray-marched shadow rays (HG phase function, no emission).

    Parameters are those of :func:`render_emission`; the scene's albedo,
    anisotropy and lights are used as well. Radiance is in the units of the lights'
    irradiance per steradian.
    """
    return _render(SINGLE, volume, scene, width, height, device, progress, None, options)


def render_illuminated(volume, scene, width, height, device=None, progress=None,
                       illumination=None, **options):
    """Ray casting shaded by a precomputed illumination volume (Zhang & Ma 2013, eq. 24).

    Parameters
    ----------
    illumination : IlluminationVolume or ndarray (nx, ny, nz, 3)
        Per-light transmittance and scattered fluence covering the volume's box, with
        one transmittance channel per scene light; an array is taken as an isotropic
        scattered fluence (:meth:`IlluminationVolume.for_volume`).
    **others
        As :func:`render_emission`; the scene's albedo, lights (for the Phong
        directions) and ``shading`` are used as well.
    """
    if illumination is None:
        raise ValueError(
            "render_illuminated needs illumination=IlluminationVolume(...) (or an (nx, ny, nz, 3) "
            "fluence array); compute one with an illumination method first"
        )
    if not isinstance(illumination, IlluminationVolume):
        illumination = IlluminationVolume.for_volume(volume, illumination)
    illumination.check_matches(volume, scene.lights)
    return _render(ILLUMINATION, volume, scene, width, height, device, progress, illumination,
                   options)


def _parse_options(options: dict, volume, scene) -> dict:
    unknown = set(options) - set(RAYCAST_OPTIONS)
    if unknown:
        raise ValueError(
            f"unknown ray-casting option(s) {sorted(unknown)}; known: {sorted(RAYCAST_OPTIONS)}"
        )
    opts = ray_options(options, volume, scene)
    near = options.get("near_cells", RAYCAST_OPTIONS["near_cells"])
    if not (isinstance(near, (int, float, np.floating)) and np.isfinite(near) and near >= 0):
        raise ValueError(f"near_cells must be a non-negative number of light-grid cells, got "
                         f"{near!r}")
    opts["near_cells"] = float(near)
    tol = options.get("near_tolerance", RAYCAST_OPTIONS["near_tolerance"])
    if not (isinstance(tol, (int, float, np.floating)) and np.isfinite(tol) and 0 <= tol < 1):
        raise ValueError(f"near_tolerance must be an optical depth in [0, 1), got {tol!r}")
    opts["near_tolerance"] = float(tol)
    textures = options.get("textures", RAYCAST_OPTIONS["textures"])
    if not isinstance(textures, (bool, np.bool_)):
        raise ValueError(f"textures must be true or false, got {textures!r}")
    opts["textures"] = bool(textures)
    return opts


def samples_per_pixel(volume, step: float, n_lights: int = 0, shadow_length: float = 0.0) -> int:
    """Worst-case samples of one pixel: ``n (1 + n_lights m)``.

    ``n = ceil(diagonal / step)`` samples along the primary ray and, at each, one shadow
    ray per light of ``m = ceil(min(shadow_length, diagonal) / step)`` samples (shadow
    rays end at the box exit, so never longer than its diagonal). ``step`` in world units.
    """
    diagonal = float(np.linalg.norm(volume.extent))
    n = int(np.ceil(diagonal / step))
    m = int(np.ceil(min(float(shadow_length), diagonal) / step)) if n_lights else 0
    return n * (1 + int(n_lights) * m)


def check_samples_per_pixel(volume, step: float, n_lights: int, shadow_length: float,
                            method: str, limit: int = MAX_SAMPLES_PER_PIXEL) -> int:
    """:func:`samples_per_pixel`, or ``ValueError`` naming the smallest usable ``step_size``."""
    work = samples_per_pixel(volume, step, n_lights, shadow_length)
    if work <= limit:
        return work
    diagonal = float(np.linalg.norm(volume.extent))
    shadow = min(float(shadow_length), diagonal)
    # n (1 + L m) <= limit with n = D / s, m = S / s: L D S x^2 + D x - limit <= 0, x = 1 / s.
    a, b = n_lights * diagonal * shadow, diagonal
    x = (-b + np.sqrt(b * b + 4.0 * a * limit)) / (2.0 * a) if a > 0 else limit / b
    smallest = 1.0 / x
    while samples_per_pixel(volume, smallest, n_lights, shadow_length) > limit:
        smallest *= 1.0 + 1e-6
    smallest = _round_up(smallest)
    n = int(np.ceil(diagonal / step))
    m = int(np.ceil(shadow / step))
    raise ValueError(
        f"step_size {step:g} needs up to {work:.3g} samples per pixel with method {method!r} "
        f"({n} along the ray, each with {n_lights} shadow ray(s) of up to {m}); at most "
        f"{limit:.3g} are allowed: use a step_size of at least {smallest:.3g} world units"
        + (" (or fewer lights)" if n_lights > 1 else "")
    )


def _round_up(x: float, digits: int = 3) -> float:
    """``x`` rounded up to ``digits`` significant digits (so that the printed value works)."""
    scale = 10.0 ** (digits - 1 - int(np.floor(np.log10(x))))
    return float(np.ceil(x * scale * (1 - 1e-12)) / scale)


def band_pixels(device: str, work: int) -> int:
    """Pixels per launch for ``work`` worst-case samples per pixel (see :data:`BAND_SAMPLES`)."""
    key = "cpu" if device == "cpu" else "cuda"
    pixels = min(TILE_PIXELS[key], max(1, BAND_SAMPLES[key] // max(int(work), 1)))
    return max(pixels, min(CUDA_MIN_BAND_PIXELS, TILE_PIXELS[key])) if key == "cuda" else pixels


def _render(mode, volume, scene, width, height, device, progress, illumination, options):
    """Upload, launch in row tiles, download; see the module docstring."""
    t_start = time.perf_counter()
    opts = _parse_options(options, volume, scene)
    device = resolve_device(device)
    width, height = int(width), int(height)
    ka, kd, ks, shininess = shading_terms(scene.shading)

    tf = scene.resolved_transfer_function(volume)
    medium = make_medium(volume, tf, scene.resolved_unit_distance(volume), scene.albedo,
                         scene.anisotropy, device)
    cam = make_camera(scene.resolved_camera(volume), volume, width, height)
    lights = make_lights(scene.lights, volume, device)
    # The kernel always takes both grids; absent parts are a zero grid / an empty light grid.
    # Grids already on the device (or uploaded once per IlluminationVolume) are used as they
    # are: a camera move moves no volume-sized data.
    scattered = None if illumination is None else illumination.device_scattered(device)
    illum = make_rgb_grid(scattered, volume.extent, device)
    direct = make_light_grid(None if illumination is None else
                             illumination.device_transmittance(device),
                             volume.extent, device, opts["near_cells"])
    grad_eps = gradient_threshold(volume)
    # Shadow rays per sample: to every light for single scattering, the exact near march
    # of every cached light for illumination volumes, none for emission.
    n_lights, shadow_length = {SINGLE: (len(scene.lights), np.inf),
                               ILLUMINATION: (direct.count, direct.near)}.get(mode, (0, 0.0))
    work = check_samples_per_pixel(volume, opts["step_size"], n_lights, shadow_length,
                                   MODE_NAMES[mode])

    sources = _sources(mode, opts["textures"], volume, medium, illum, direct, illumination,
                       device)
    near_bound, near_tol = _near_bound(mode, opts["near_tolerance"], volume, medium, direct,
                                       device)
    wp.synchronize_device(device)
    t_upload = time.perf_counter()

    has_scattered = illumination is not None and illumination.has("scattered")
    kernel = raycast_overload(sources["textures"], mode, has_scattered, direct.count > 0,
                              kd != 0.0 or ks != 0.0)
    radiance, alpha, samples, n_tiles = launch_tiles(
        kernel,
        [medium, sources["scalars"], sources["optics"], cam, lights, illum, sources["rgb"],
         sources["rgb_unit"], direct, sources["light"], near_bound, near_tol,
         opts["step_size"],
         int(opts["jitter"]), opts["seed"], opts["early_termination"],
         wp.vec4(ka, kd, ks, shininess), float(grad_eps)],
        width, height, band_pixels(device, work), device, progress,
        None if progress is None else pixel_work(cam, volume.extent, width, height, device))
    t_render = time.perf_counter()

    # On CUDA the image stays there until someone reads it (RenderResult.radiance/alpha): a
    # tone map on the device (the compute mapper's) downloads 8-bit pixels only. On the CPU
    # the arrays are host memory already (views, no copy).
    on_host = not wp.get_device(device).is_cuda
    host = (radiance.numpy().reshape(height, width, 3), alpha.numpy()) if on_host \
        else (None, None)
    samples_mean = mean_samples(samples)
    t_end = time.perf_counter()
    if progress is not None:
        progress(1.0)
    info = {
        "method": MODE_NAMES[mode],
        "device": device,
        "step_size": opts["step_size"],
        "jitter": opts["jitter"],
        "textures": sources["textures"],
        "tiles": n_tiles,
        "mean_samples_per_pixel": samples_mean,
        "setup_s": t_upload - t_start,
        "render_s": t_render - t_upload,
        "download_s": t_end - t_render,  # the sample count's (the image: when read)
        "total_s": t_end - t_start,
    }
    return RenderResult(*host, info, device=None if on_host else (radiance, alpha))


def _sources(mode, textures: bool, volume, medium, illum, direct, illumination, device) -> dict:
    """What the kernel samples: the arrays (exact), or on CUDA with ``textures`` their
    hardware-filtered textures, each made once and kept with its data (the scalars and the
    transfer function's tables with the volume, the light grids with the
    IlluminationVolume), so a camera move makes none. Falls back to the arrays when a
    grid does not fit a texture."""
    arrays = {"textures": False, "scalars": medium.scalars, "optics": medium.sigma_table,
              "rgb": illum.data, "rgb_unit": 1.0, "light": direct.data}
    if not (textures and mode != SINGLE and textures_available(device)):
        return arrays
    scalars = volume.derived(f"scalars_texture@{device}", id(medium.scalars),
                             lambda: (medium.scalars, scalar_texture(medium.scalars)))[1]
    optics = volume.derived(f"optics_texture@{device}", id(medium.sigma_table),
                            lambda: (medium.sigma_table, optics_texture(medium)))[1]
    rgb, unit, light = _empty_textures(device)
    if illumination is not None and illumination.has("scattered"):
        unit = max(float(illumination.scattered_range[1]), 0.0)
        rgb = illumination.device_texture("scattered", device,
                                          lambda grid: rgb_texture(grid, unit))
    if illumination is not None and illumination.has("transmittance"):
        light = illumination.device_texture("transmittance", device, light_texture)
    if scalars is None or rgb is None or light is None:
        return arrays
    return {"textures": True, "scalars": scalars, "optics": optics, "rgb": rgb,
            "rgb_unit": unit if unit > 0.0 else 1.0, "light": light}


def _near_bound(mode, tol: float, volume, medium, direct, device):
    """The per-block ``σt`` bound that lets :func:`cached_transmittance` skip thin near
    fields, and the tolerance (0 where skipping does not apply: no near field, no block
    classification, or a near field longer than a block, beyond what the bound covers)."""
    from vtkillum.core.empty_space import block_ranges, block_sigma_max

    block_edge = float(np.min(np.asarray(volume.spacing))) * BLOCK
    usable = (mode == ILLUMINATION and tol > 0.0 and direct.count > 0 and direct.near > 0.0
              and direct.near <= block_edge and float(medium.inv_block[0]) > 0.0)
    if not usable:
        return _NO_BOUND.setdefault(device, wp.zeros((1, 1, 1), dtype=wp.float32,
                                                     device=device)), 0.0
    ranges = volume.derived(f"block_ranges@{device}", medium.scalars.ptr,
                            lambda: block_ranges(medium.scalars, device))
    bound = volume.derived(f"near_bound@{device}", id(medium.sigma_table),
                           lambda: (medium.sigma_table,
                                    block_sigma_max(medium, ranges, device=device)))[1]
    return bound, tol


_NO_BOUND: dict[str, object] = {}
_EMPTY_TEXTURES: dict[str, tuple] = {}


def _empty_textures(device: str) -> tuple:
    """Zero RGB and light textures (2³) standing in for absent grids, one set per device."""
    if device not in _EMPTY_TEXTURES:
        zero_rgb = wp.zeros((2, 2, 2), dtype=wp.vec3, device=device)
        zero_light = wp.zeros((1, 2, 2, 2), dtype=wp.float32, device=device)
        _EMPTY_TEXTURES[device] = (rgb_texture(zero_rgb, 1.0), 1.0, light_texture(zero_light))
    return _EMPTY_TEXTURES[device]


# --- device functions ---------------------------------------------------------------------------
@wp.func
def single_scatter_light(m: Medium, lights: Lights, p: wp.vec3, d: wp.vec3, step: float,
                         xi: float, stop_t: float):
    """``Σ_l p(θ_l) T_l E_l`` at ``p`` for a primary ray travelling along ``d``."""
    acc = wp.vec3(0.0)
    for li in range(lights.count):
        wl, dist, e = light_incidence(lights, li, p)
        # θ is between the light's travel direction (-wl) and the direction to the camera (-d).
        phase = hg_phase(wp.dot(wl, d), m.g)
        acc += (phase * shadow_transmittance(m, p, wl, dist, step, xi, stop_t)) * e
    return acc


@wp.func
def cached_transmittance(m: Medium, scalars: Any, optics: Any, direct: LightGrid,
                         light_src: Any, near_bound: wp.array3d(dtype=wp.float32),
                         near_tol: float, li: int, p: wp.vec3, wl: wp.vec3, dist: float,
                         step: float, xi: float):
    """``T_l(p)``: an exact march over the first ``direct.near`` towards the light, then the grid.

    The grid is read one cell towards the light rather than at ``p``: interpolating it
    across a sharp surface mixes points in front of and behind the surface, a
    grid-aligned error that shows as rings and bands; the short exact march resolves the
    surface instead (see :mod:`vtkillum.core.illumination`). ``scalars``, ``optics`` and
    ``light_src`` are the arrays (exact) or textures (:mod:`vtkillum.core.textures`).

    Where the medium is thin the march is skipped and the grid read at ``p``:
    ``near_bound`` holds, per block of ``m``, the largest ``σt`` within one block of it
    (:func:`~vtkillum.core.empty_space.block_sigma_max`), so where
    ``near · bound ≤ near_tol`` the near field attenuates by at most ``1 - exp(-near_tol)``
    and the grid at ``p`` and the march-plus-grid differ by at most about that fraction of
    ``T`` (both approximate the same ``T(p) = T_near · T(q)``). ``near_tol = 0`` never skips.
    """
    near = wp.min(direct.near, dist)
    if near > 0.0 and near_tol > 0.0:
        bi = wp.clamp(int(wp.floor(p[0] * m.inv_block[0])), 0, near_bound.shape[0] - 1)
        bj = wp.clamp(int(wp.floor(p[1] * m.inv_block[1])), 0, near_bound.shape[1] - 1)
        bk = wp.clamp(int(wp.floor(p[2] * m.inv_block[2])), 0, near_bound.shape[2] - 1)
        if near * near_bound[bi, bj, bk] <= near_tol:
            near = 0.0
    t = float(1.0)
    if near > 0.0:
        t = near_transmittance(m, scalars, optics, p, wl, near, step, xi)
    q = p + near * wl
    if near < dist and inside_box(q, m.extent):
        t = t * fetch_light(light_src, direct, li, q)
    return t


@wp.func
def near_transmittance(m: Medium, scalars: Any, optics: Any, p: wp.vec3, w: wp.vec3,
                       dist: float, step: float, xi: float):
    """:func:`~vtkillum.core.warp_common.shadow_transmittance` over the few steps of the near
    field, without early stop and without the empty-block test: the same value to the bit
    (a sample in an exactly empty block adds exactly 0), for a fraction of the cost, since
    over 4-8 steps the test (a ray-box intersection per block) costs more than the samples
    it would skip. Sampling every ``step`` matters: voxel-long segments (half the samples)
    left rings of 3.7 % of the image on a one-voxel-sharp sphere instead of 1.1 %
    (``tests/core/test_transmittance_render.py::test_no_rings_on_a_sharp_sphere``).
    """
    tt = ray_box(p, w, m.extent)
    length = wp.min(tt[1], dist)
    if length <= 0.0:
        return 1.0
    n = int(wp.ceil(length / step))
    h = length / float(n)
    tau = float(0.0)
    for k in range(n):
        q = p + ((float(k) + xi) * h) * w
        tau += fetch_optics(optics, m, fetch_scalar(scalars, m.inv_spacing, q))[3]
    return wp.exp(-tau * h)


@wp.func
def cached_direct_light(m: Medium, scalars: Any, optics: Any, lights: Lights, direct: LightGrid,
                        light_src: Any, near_bound: wp.array3d(dtype=wp.float32),
                        near_tol: float, p: wp.vec3, d: wp.vec3, step: float, xi: float):
    """``Σ_l p(θ_l) T_l E_l`` at ``p`` with ``T_l`` from :func:`cached_transmittance`."""
    acc = wp.vec3(0.0)
    for li in range(direct.count):
        wl, dist, e = light_incidence(lights, li, p)
        phase = hg_phase(wp.dot(wl, d), m.g)
        acc += (phase * cached_transmittance(m, scalars, optics, direct, light_src, near_bound,
                                             near_tol, li, p, wl, dist, step, xi)) * e
    return acc


@wp.func
def phong_factor(m: Medium, lights: Lights, p: wp.vec3, d: wp.vec3, shading: wp.vec4,
                 grad_eps: float):
    """``S = ka + kd mean|n.l| + ks mean max(n.h, 0)^shininess`` (see ``illumination.py``)."""
    ka = shading[0]
    kd = shading[1]
    ks = shading[2]
    if kd == 0.0 and ks == 0.0:
        return ka
    n = view_normal(m, p, d, grad_eps)
    if wp.length_sq(n) == 0.0:
        return ka + kd  # no surface: diffuse as if facing the lights, no highlight
    v = -d
    diff = float(0.0)
    spec = float(0.0)
    for li in range(lights.count):
        wl, dist, e = light_incidence(lights, li, p)
        diff += wp.abs(wp.dot(n, wl))
        h = wp.normalize(wl + v)
        spec += wp.pow(wp.max(wp.dot(n, h), 0.0), shading[3])
    count = float(lights.count)
    return ka + kd * diff / count + ks * spec / count


# --- kernels ------------------------------------------------------------------------------------
@functools.lru_cache(maxsize=None)
def raycast_kernel(mode: int, scattered: bool = True, direct: bool = True, phong: bool = True):
    """The primary-ray kernel of ``mode`` (EMISSION, SINGLE, ILLUMINATION), compiled for it.

    The mode and, for ILLUMINATION, whether the volume has a scattered fluence and direct
    light and whether the Phong factor can differ from ``ka`` are compile-time constants
    (``wp.static``): each kernel holds only its own code. One kernel for every mode, with
    the mode a run-time argument, kept every branch's registers: the illumination path at
    512³ took 14 ms without its near-field march against 5.7 for emission on an H200.

    One thread per pixel, ``wp.tid()`` = ``(row - row0, col - col0)`` of the image (row 0 at
    the top). Positions are in the volume's local frame (world units); ``step`` in world
    units. ``scalars``, ``optics``, ``rgb_src`` and ``light_src`` are the data, the
    transfer function's tables, the scattered fluence and the per-light grids as arrays
    (``m.scalars``, ``m.sigma_table``, ``illum.data``, ``direct_grid.data``: exact) or as
    textures (:mod:`vtkillum.core.textures`; ``rgb_unit`` the RGB texture's unit).
    ``near_bound`` and ``near_tol``: where the near-field march may be skipped
    (:func:`cached_transmittance`). Samples in exactly empty blocks of ``m`` are skipped by
    whole blocks (they add exactly nothing, and draw no random numbers). Writes
    premultiplied radiance and alpha = 1 - transmittance at ``[row, col]``, and the number
    of samples evaluated.
    """
    def raycast(
        m: Medium,
        scalars: Any,
        optics: Any,
        cam: CameraParams,
        lights: Lights,
        illum: RGBGrid,
        rgb_src: Any,
        rgb_unit: float,
        direct_grid: LightGrid,
        light_src: Any,
        near_bound: wp.array3d(dtype=wp.float32),
        near_tol: float,
        step: float,
        jitter: int,
        seed: int,
        stop_alpha: float,
        shading: wp.vec4,
        grad_eps: float,
        row0: int,
        col0: int,
        radiance: wp.array2d(dtype=wp.vec3),
        alpha: wp.array2d(dtype=wp.float32),
        samples: wp.array2d(dtype=wp.int32),
    ):
        r, cc = wp.tid()
        row = row0 + r
        c = col0 + cc
        o, d, t0, t1 = pixel_ray(cam, m.extent, row, c)
        colour = wp.vec3(0.0)
        trans = float(1.0)
        count = int(0)
        if t0 < t1:
            state = wp.rand_init(seed, row * cam.width + c)
            # Fixed offset: VTK's entry-face sample for emission, step midpoints for lighting.
            xi = float(wp.static(0.0 if mode == EMISSION else 0.5))
            if jitter != 0:
                xi = wp.randf(state)
            n = sample_count(t0, t1, step, xi)
            start = o + t0 * d
            k = int(0)
            while k < n:
                empty, last = block_run(m, start, d, step, k, xi)
                if empty != 0:
                    k = last + 1
                    continue
                last = wp.min(last, n - 1)
                while k <= last:
                    p = o + (t0 + (float(k) + xi) * step) * d  # as every caster places them
                    k += 1
                    s = fetch_scalar(scalars, m.inv_spacing, p)
                    opt = fetch_optics(optics, m, s)
                    sig = opt[3]
                    count += 1
                    if sig > 0.0:
                        a = 1.0 - wp.exp(-sig * step)
                        col = optics_color(optics, m, s, opt)
                        src = wp.vec3(0.0)
                        if wp.static(mode == EMISSION):
                            src = col
                        elif wp.static(mode == SINGLE):
                            shadow_xi = float(0.5)
                            if jitter != 0:
                                shadow_xi = wp.randf(state)
                            src = m.albedo * wp.cw_mul(col, single_scatter_light(
                                m, lights, p, d, step, shadow_xi, SHADOW_STOP_T))
                        else:
                            light = wp.vec3(0.0)
                            if wp.static(scattered):
                                light = fetch_rgb(rgb_src, illum, rgb_unit, p) / (4.0 * wp.pi)
                            if wp.static(direct):
                                shadow_xi = float(0.5)
                                if jitter != 0:
                                    shadow_xi = wp.randf(state)
                                light += cached_direct_light(
                                    m, scalars, optics, lights, direct_grid, light_src,
                                    near_bound, near_tol, p, d, step, shadow_xi)
                            s_fac = shading[0]
                            if wp.static(phong):
                                s_fac = phong_factor(m, lights, p, d, shading, grad_eps)
                            src = (m.albedo * s_fac) * wp.cw_mul(col, light)
                        colour += (trans * a) * src
                        trans *= 1.0 - a
                        if 1.0 - trans > stop_alpha:
                            k = n  # ends both loops
                            last = -1
        radiance[row, c] = colour
        alpha[row, c] = 1.0 - trans
        samples[row, c] = count

    name = f"raycast_{MODE_NAMES[mode]}" + (
        f"_{int(scattered)}{int(direct)}{int(phong)}" if mode == ILLUMINATION else "")
    return wp.kernel(raycast, name=name, module="unique")


def raycast_overload(textures: bool, mode: int = ILLUMINATION, scattered: bool = True,
                     direct: bool = True, phong: bool = True):
    """:func:`raycast_kernel` compiled for arrays (exact; every device) or for textures
    (CUDA)."""
    if textures:
        types = {"scalars": wp.Texture3D, "optics": wp.Texture1D, "rgb_src": wp.Texture3D,
                 "light_src": wp.Texture3D}
    else:
        types = {"scalars": wp.array3d(dtype=wp.float32), "optics": wp.array(dtype=wp.float32),
                 "rgb_src": wp.array3d(dtype=wp.vec3),
                 "light_src": wp.array4d(dtype=wp.float32)}
    if mode != ILLUMINATION:  # the flags are the illumination path's: one kernel per mode
        scattered = direct = phong = True
    return wp.overload(raycast_kernel(mode, bool(scattered), bool(direct), bool(phong)), types)
