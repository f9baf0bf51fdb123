"""The ``"ambient-scattering"`` render method (Ament, Sadlo & Weiskopf 2013).

``render(volume, scene, method="ambient-scattering", ...)`` runs the three steps
of section 4.2 through an :class:`~vtkillum.core.ambient.cache.AmbientScatteringCache`
(ambient extinction from a SAT, tube-marched radiance cache, ambient ray
casting), so that repeated renders of the same volume recompute only what an
edit invalidated (the paper's Table 1).

Options (keyword arguments; the ambient ones default to the scene's
``ambient_scattering`` section, see :data:`vtkillum.core.scene.METHOD_OPTIONS`):

``radius``               sphere radius ``r`` (default 4 voxels: the best mean error against
                         the path tracer over the suite of ``docs/ambient_scattering.md``,
                         within 5 % of the best at both 32³ and 64³)
``radius_units``         ``"voxels"`` (``r`` × mean spacing) or ``"world"``
``radiance_cache_scale`` radiance-cache resolution relative to the data (0.5)
``specular``             weight of the optional specular lobe (0: off)
``ambient_occlusion``    ``True`` adds the SAT-based ambient-occlusion term
``ambient_occlusion_strength``  its ambient fluence relative to the sum of the
                         lights' irradiances (0.25)
``gather``               ``"centred"`` (default: in-scattered radiance at the sphere's
                         centre, exact unscattered light, transmittance from the sample)
                         or ``"paper"`` (Algorithm 1 as published: ``L̃o`` with the
                         transmittance from ``x' + r ω``; its energy grows like
                         ``1 + r σt`` and it bands on shells thinner than ``r``); see
                         :mod:`~vtkillum.core.ambient.gather`
``data_textures``        on CUDA, the gather reads the scalars, σ̃t and the transfer
                         function through textures (hardware trilinear filtering of the
                         loads of its primary and shadow rays: about twice the frame rate
                         on large data, images on average within 2e-3 of the maximum of the
                         exact path; True). False: the exact software path, as on the CPU
``hardware_filtering``   also sample the radiance cache, the table and σ̃t of the tube
                         march through CUDA textures (False; faster gathers, slower ``g``
                         and light edits: the cache is copied into a texture). Both are
                         ignored on the CPU, which always runs the exact software path
``step_size``            ray-marching step, world units (default: the scene's)
``jitter``, ``seed``     per-pixel sample offset and its seed (True, 0)
``early_termination``    opacity at which rays stop (0.999; the paper used 0.98)
``cache``                an :class:`AmbientScatteringCache` to use (its own
                         ``hardware_filtering`` and ``data_textures`` apply); by default one
                         cache per device and filtering mode is kept between calls
``table``                a :class:`~vtkillum.core.ambient.table.PreintegrationTable`;
                         by default the one for the scene's albedo (generated on
                         demand if it is not shipped)

The scene's ``albedo`` is the albedo inside the ambient spheres (the table's
``Λ``) and in ``σs``; its ``anisotropy`` is ``g``; its ``shading.shininess`` is the
specular exponent. Returned ``info`` holds the per-stage timings in ms and what
was recomputed.
"""

from __future__ import annotations

import time

import numpy as np
import warp as wp

from vtkillum.core.ambient.cache import AmbientScatteringCache
from vtkillum.core.ambient.gather import GATHER_MODES, gather_device
from vtkillum.core.device import resolve_device
from vtkillum.core.illumination import gradient_threshold
from vtkillum.core.raymarch import RAY_OPTIONS as MARCH_OPTIONS
from vtkillum.core.raymarch import mean_samples, ray_options
from vtkillum.core.render import RenderResult
from vtkillum.core.warp_common import make_camera

AMBIENT_KEYS = ("radius", "radius_units", "radiance_cache_scale", "specular",
                "ambient_occlusion", "ambient_occlusion_strength", "hardware_filtering",
                "data_textures", "gather")
RAY_OPTIONS = {**MARCH_OPTIONS, "cache": None, "table": None}

_DEFAULT_CACHES: dict[tuple, AmbientScatteringCache] = {}


def render_ambient_scattering(volume, scene, width: int, height: int, device: str | None = None,
                              progress=None, **options) -> RenderResult:
    """Render ``volume`` with ambient volume scattering (see the module docstring).

    Parameters
    ----------
    volume : vtkillum.core.volume.Volume
    scene : vtkillum.core.scene.Scene
    width, height : int
        Image size in pixels.
    device : str, optional
        Warp device.
    progress : callable, optional
        ``progress(fraction)`` while the image is gathered.
    **options
        See the module docstring.

    Returns
    -------
    RenderResult
        Linear radiance (H, W, 3), alpha (H, W) and ``info`` with ``timings_ms``
        (``sat``, ``extinction``, ``radiance``, ``gather``) and ``recomputed``.
    """
    t_start = time.perf_counter()
    device = resolve_device(device)
    opts = parse_options(options, volume, scene)
    cache = opts["cache"] or default_cache(device, opts["hardware_filtering"],
                                           opts["data_textures"])
    if cache.device != device:
        raise ValueError(f"the ambient cache lives on {cache.device}, the render asks for "
                         f"{device}; pass a cache made for {device}")
    state = cache.update(volume, scene.resolved_transfer_function(volume),
                         scene.resolved_unit_distance(volume), scene.albedo, scene.anisotropy,
                         scene.lights, opts["radius"], opts["radius_units"],
                         opts["radiance_cache_scale"], opts["table"])
    cam = make_camera(scene.resolved_camera(volume), volume, int(width), int(height))
    grad_eps = gradient_threshold(volume)
    t_gather = time.perf_counter()
    table = state.scattered_slice if opts["gather"] == "centred" else state.table_slice
    radiance, alpha, samples = gather_device(
        state.medium, state.sigma_tilde, state.radiance.grid, state.lights, cam,
        table, state.table.sigma_max, state.radius, opts["step_size"],
        opts["jitter"], opts["seed"], opts["early_termination"], opts["specular"],
        float(scene.shading["shininess"]), grad_eps, opts["ambient_occlusion"], device, progress,
        state.occupied, volume.spacing, state.textures, opts["gather"])
    samples_mean = mean_samples(samples)
    t_end = time.perf_counter()
    if progress is not None:
        progress(1.0)
    info = {
        "method": "ambient-scattering",
        "device": device,
        "radius_world": state.radius,
        "step_size": opts["step_size"],
        "table_shape": state.table.shape,
        "table_albedo": state.table.albedo,
        "radiance_cache_shape": state.radiance.shape,
        "gather": opts["gather"],
        "recomputed": list(state.recomputed),
        "hardware_filtering": state.textures is not None and state.textures.radiance is not None,
        "data_textures": state.textures is not None,
        "timings_ms": {"sat": state.timings["sat_ms"],
                       "extinction": state.timings["extinction_ms"],
                       "radiance": state.timings["radiance_ms"],
                       "gather": 1e3 * (t_end - t_gather),
                       # the extinction stage's parts, when it ran
                       **{k[:-3]: v for k, v in state.timings.items()
                          if k in ("sigma_tilde_ms", "step_field_ms", "textures_ms")}},
        "mean_samples_per_pixel": samples_mean,
        "total_s": t_end - t_start,
    }
    if not (state.table.g[0] <= scene.anisotropy <= state.table.g[-1]):
        info["warning"] = (f"anisotropy {scene.anisotropy} is outside the table's g range "
                           f"[{state.table.g[0]:g}, {state.table.g[-1]:g}]; clamped")
    if wp.get_device(device).is_cuda:  # kept there until read (RenderResult.device)
        return RenderResult(info=info, device=(radiance, alpha))
    return RenderResult(radiance.numpy().reshape(int(height), int(width), 3), alpha.numpy(), info)


def default_cache(device: str, hardware_filtering: bool = False,
                  data_textures: bool = True) -> AmbientScatteringCache:
    """The cache kept between calls on ``device`` with that filtering mode (holds the last
    volume's arrays)."""
    key = (device, bool(hardware_filtering), bool(data_textures))
    if key not in _DEFAULT_CACHES:
        _DEFAULT_CACHES[key] = AmbientScatteringCache(device, bool(hardware_filtering),
                                                      data_textures=bool(data_textures))
    return _DEFAULT_CACHES[key]


def release_default_caches() -> None:
    """Drop the caches kept between calls (frees their device memory)."""
    _DEFAULT_CACHES.clear()


def parse_options(options: dict, volume, scene) -> dict:
    """Merge keyword options over the scene's ``ambient_scattering`` section and validate."""
    known = set(AMBIENT_KEYS) | set(RAY_OPTIONS)
    unknown = set(options) - known
    if unknown:
        raise ValueError(f"unknown ambient-scattering option(s) {sorted(unknown)}; "
                         f"known: {sorted(known)}")
    section = dict(scene.options.get("ambient_scattering", {}))
    opts = dict(RAY_OPTIONS)
    opts.update({k: section[k] for k in AMBIENT_KEYS if k in section})
    opts.update(options)
    for key, default in (("radius", 4.0), ("radius_units", "voxels"),
                         ("radiance_cache_scale", 0.5), ("specular", 0.0),
                         ("ambient_occlusion", False), ("ambient_occlusion_strength", 0.25),
                         ("hardware_filtering", False), ("data_textures", True),
                         ("gather", "centred")):
        opts.setdefault(key, default)
    opts.update(ray_options(opts, volume, scene))
    spec = opts["specular"]
    if isinstance(spec, bool) or not (isinstance(spec, (int, float, np.floating)) and spec >= 0):
        raise ValueError(f"ambient_scattering.specular must be a number >= 0, got {spec!r}")
    ao = opts["ambient_occlusion"]
    if not isinstance(ao, (bool, np.bool_)):
        raise ValueError(f"ambient_scattering.ambient_occlusion must be true or false, got {ao!r}")
    strength = opts["ambient_occlusion_strength"]
    if isinstance(strength, bool) or not (isinstance(strength, (int, float, np.floating))
                                          and strength >= 0):
        raise ValueError("ambient_scattering.ambient_occlusion_strength must be a number >= 0, "
                         f"got {strength!r}")
    opts["ambient_occlusion"] = float(strength) if ao else 0.0
    for name in ("hardware_filtering", "data_textures"):
        if not isinstance(opts[name], (bool, np.bool_)):
            raise ValueError(f"ambient_scattering.{name} must be true or false, got "
                             f"{opts[name]!r}")
        opts[name] = bool(opts[name])
    if opts["gather"] not in GATHER_MODES:
        raise ValueError(f"ambient_scattering.gather must be one of {sorted(GATHER_MODES)}, "
                         f"got {opts['gather']!r}")
    opts["specular"] = float(spec)
    scale = opts["radiance_cache_scale"]
    if isinstance(scale, bool) or not (isinstance(scale, (int, float, np.floating))
                                       and 0 < scale <= 1):
        raise ValueError(f"ambient_scattering.radiance_cache_scale must lie in (0, 1], "
                         f"got {scale!r}")
    cache = opts["cache"]
    if cache is not None and not isinstance(cache, AmbientScatteringCache):
        raise ValueError("cache must be an AmbientScatteringCache")
    return opts
