"""The ``"photon"`` render method: volumetric photon mapping with Historygrams.

``render(volume, scene, method="photon", ...)`` traces a photon map
(:mod:`~vtkillum.core.photon.tracing`), hashes it
(:mod:`~vtkillum.core.photon.hashgrid`) and ray-marches the view rays in ``V_n``
segments with the photon gather of eq. (8) at every sample
(:mod:`~vtkillum.core.photon.segments`), through a
:class:`~vtkillum.core.photon.mapper.PhotonMapper` kept with the volume: a new camera
re-renders the segments only, a transfer-function edit updates photons and segments
incrementally (Historygrams), and ``passes > 1`` adds progressive passes with a
shrinking radius.

Options (keyword arguments; the photon ones default to the scene's ``photon``
section, see :data:`vtkillum.core.scene.METHOD_OPTIONS`; on the command line
``--option photons=400000`` etc.):

``photons``             photon paths ``P_n`` per pass; 0 (default): from a pilot trace, enough
                        for ``kernel_photons`` in a kernel of 2 voxels, 200 000 to 1 000 000
                        (:func:`~vtkillum.core.photon.radius.auto_photons`); 200000 was the
                        default
``radius``              photon radius in voxels (× mean spacing) of the first pass; 0
                        (default): chosen from the photon map so that a kernel holds
                        ``kernel_photons`` (128) photons where three quarters of them hold
                        more (:mod:`~vtkillum.core.photon.radius`); 2 was the default
``max_order``           ``S_n``: interactions per photon at most; 1 = single scattering,
                        0 = unbounded (Russian roulette only; default)
``segments``            view-ray segments ``V_n`` (8)
``seed``                seed of photons and view jitter (0)
``historygrams``        incremental updates after transfer-function edits (True)
``spatial_historygram`` also recompute segments near changed photons (True)
``direct``              ``"exact"`` (default): direct light by shadow rays, photons for the
                        scattered light; ``"photons"``: photons for all light (the paper)
``passes``              progressive passes averaged (1)
``alpha``               radius reduction per pass (2/3)
``surface_range``       data values ``[lo, hi]`` that may scatter like a surface (a BRDF
                        instead of the HG phase where the data gradient is steep;
                        ``[0, 0]``: off, the default), with ``surface_gradient`` (0.02,
                        relative to data range per voxel), ``surface_diffuse`` (0.6),
                        ``surface_specular`` (0.4), ``surface_shininess`` (40); see
                        :mod:`~vtkillum.core.photon.material`
``step_size``, ``jitter``, ``early_termination``  view-ray sampling (scene step, True, 0.999)
``photon_step``         ray-marching step of photon flights, world units (half a voxel)
``memory_limit_mb``     cap on the photon map's memory (default: what the device has free)
``mapper``              a :class:`PhotonMapper` to use (its own settings apply)

Returned ``info`` holds ``photon_update`` (what the photon update did),
``photon_render`` (segments recomputed), ``passes``, ``radius_world`` and
``timings_ms``.
"""

from __future__ import annotations

import time

import numpy as np

from vtkillum.core.device import resolve_device
from vtkillum.core.photon.mapper import PhotonMapper, check_config
from vtkillum.core.photon.material import SURFACE_DEFAULTS, make_surface, surface_key
from vtkillum.core.raymarch import ray_options
from vtkillum.core.render import RenderResult

#: The scene section's fields and their defaults (mirrors ``METHOD_OPTIONS["photon"]``).
PHOTON_DEFAULTS = {"photons": 0, "radius": 0.0, "kernel_photons": 128, "max_order": 0,
                   "segments": 8, "seed": 0,
                   "historygrams": True, "spatial_historygram": True, "direct": "exact",
                   "passes": 1, "alpha": 2.0 / 3.0, **SURFACE_DEFAULTS}
EXTRA = {"step_size": None, "jitter": True, "early_termination": 0.999, "photon_step": None,
         "memory_limit_mb": None, "mapper": None}


def render_photon(volume, scene, width: int, height: int, device: str | None = None,
                  progress=None, **options) -> RenderResult:
    """Render ``volume`` by photon mapping (see the module docstring for the options)."""
    t0 = time.perf_counter()
    device = resolve_device(device)
    opts = parse_options(options, volume, scene)
    mapper = opts["mapper"]
    if mapper is None:
        config = tuple((k, opts[k]) for k in ("photons", "radius", "kernel_photons",
                                              "max_order", "segments",
                                              "seed", "historygrams", "spatial_historygram",
                                              "direct", "alpha", "photon_step",
                                              "memory_limit_mb")) + surface_key(opts)
        mapper = volume.derived("photon_mapper", (device, config),
                                lambda: make_mapper(volume, device, opts))
    elif mapper.device != device:
        raise ValueError(f"the photon mapper lives on {mapper.device}, the render asks for "
                         f"{device}")
    update = mapper.update(volume, scene.resolved_transfer_function(volume),
                           scene.resolved_unit_distance(volume), scene.albedo, scene.anisotropy,
                           scene.lights)
    if progress is not None:
        progress(0.3)
    camera = scene.resolved_camera(volume)
    t_render = time.perf_counter()
    result = mapper.render(volume, camera, width, height, opts["step_size"], opts["jitter"],
                           opts["seed"], opts["early_termination"],
                           None if progress is None else (lambda f: progress(0.3 + 0.7 * f)))
    more = int(opts["passes"]) - mapper.passes
    if more > 0:
        result = mapper.refine(volume, camera, width, height, opts["step_size"], more,
                               opts["jitter"], opts["seed"], opts["early_termination"])
    t_end = time.perf_counter()
    if progress is not None:
        progress(1.0)
    info = {"method": "photon", "device": device, "photons": mapper.photons,
            "radius_world": mapper.radius, "max_order": mapper.max_order,
            "segments": mapper.segments, "direct": mapper.direct, "passes": mapper.passes,
            "photon_update": update, "photon_render": dict(mapper.last_render),
            "timings_ms": {"update": update["ms"]["total"],
                           "render": 1e3 * (t_end - t_render)},
            "total_s": t_end - t0}
    return RenderResult(result.radiance, result.alpha, info)


def make_mapper(volume, device: str, opts: dict) -> PhotonMapper:
    """A :class:`PhotonMapper` for ``volume`` with the parsed options."""
    return PhotonMapper(device, opts["photons"], opts["radius"] * volume.mean_spacing(),
                        opts["max_order"], opts["segments"], opts["seed"],
                        opts["historygrams"], opts["spatial_historygram"], opts["direct"],
                        opts["alpha"], opts["photon_step"], opts["memory_limit_mb"],
                        {k: opts[k] for k in SURFACE_DEFAULTS}, opts["kernel_photons"])


def parse_options(options: dict, volume, scene) -> dict:
    """Merge keyword options over the scene's ``photon`` section and validate them."""
    known = set(PHOTON_DEFAULTS) | set(EXTRA)
    unknown = set(options) - known
    if unknown:
        raise ValueError(f"unknown photon option(s) {sorted(unknown)}; known: {sorted(known)}")
    opts = dict(PHOTON_DEFAULTS)
    opts.update(scene.options.get("photon", {}))
    opts.update(EXTRA)
    opts.update(options)
    check_config(opts["photons"], opts["radius"], opts["max_order"], opts["segments"],
                 opts["direct"], opts["alpha"], opts["kernel_photons"])
    passes = opts["passes"]
    if isinstance(passes, bool) or not float(passes).is_integer() or int(passes) < 1:
        raise ValueError(f"photon.passes must be a positive integer, got {passes!r}")
    for key in ("historygrams", "spatial_historygram"):
        if not isinstance(opts[key], (bool, np.bool_)):
            raise ValueError(f"photon.{key} must be true or false, got {opts[key]!r}")
    step = opts["photon_step"]
    if step is not None and not (np.isfinite(step) and step > 0):
        raise ValueError(f"photon_step must be a positive number of world units, got {step!r}")
    make_surface(opts, volume)  # validates the surface options
    opts.update(ray_options(opts, volume, scene))
    for key in ("photons", "kernel_photons", "max_order", "segments", "passes"):
        opts[key] = int(opts[key])
    opts["radius"] = float(opts["radius"])
    return opts
