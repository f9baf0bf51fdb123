"""What the image-order ray marchers share: sampling options, pixel rays, row-band launches.

The ray caster (:mod:`vtkillum.core.raycast`) and the ambient gather
(:mod:`vtkillum.core.ambient.gather`) march one primary ray per pixel, through the
pixel's centre, across the volume's box ``[0, extent]`` (local frame). Samples lie at
``t0 + (k + ξ) Δ`` strictly before the box exit, with ``Δ`` the step in world units
and ``ξ`` a per-pixel offset in ``[0, 1)`` (random with jitter). Both launch the image
in bands of whole rows so that progress can be reported between launches, and write
premultiplied radiance, alpha and the number of samples per pixel.
"""

from __future__ import annotations

import numpy as np
import warp as wp

from vtkillum.core.warp_common import CameraParams, camera_ray, ray_box

#: Options every ray marcher accepts, with their defaults.
RAY_OPTIONS = {"step_size": None, "jitter": True, "seed": 0, "early_termination": 0.999}

#: Refuse step sizes that would need more samples than this along the volume diagonal.
MAX_STEPS_PER_RAY = 1 << 20


def ray_options(opts: dict, volume, scene) -> dict:
    """Validated :data:`RAY_OPTIONS` from ``opts`` (missing ones take their defaults).

    Returns ``step_size`` (world units; ``None`` means the scene's resolved step), ``jitter``
    (bool), ``seed`` (int in ``[0, 2**31)``) and ``early_termination`` (in ``(0, 1]``).
    """
    step = opts.get("step_size", RAY_OPTIONS["step_size"])
    step = scene.resolved_step_size(volume) if step is None else step
    if not (isinstance(step, (int, float, np.floating)) and np.isfinite(step) and step > 0):
        raise ValueError(f"step_size must be a positive number of world units, got {step!r}")
    diagonal = float(np.linalg.norm(volume.extent))
    if diagonal / step > MAX_STEPS_PER_RAY:
        raise ValueError(
            f"step_size {step:g} needs {diagonal / step:.3g} samples across the volume; use at "
            f"least {diagonal / MAX_STEPS_PER_RAY:.3g} world units"
        )
    stop = opts.get("early_termination", RAY_OPTIONS["early_termination"])
    if not (isinstance(stop, (int, float, np.floating)) and 0.0 < stop <= 1.0):
        raise ValueError(f"early_termination must lie in (0, 1], got {stop!r}")
    seed = opts.get("seed", RAY_OPTIONS["seed"])
    if not isinstance(seed, (int, np.integer)) or isinstance(seed, bool) or not 0 <= seed < 2**31:
        raise ValueError(f"seed must be an integer in [0, 2**31), got {seed!r}")
    return {"step_size": float(step), "jitter": bool(opts.get("jitter", RAY_OPTIONS["jitter"])),
            "seed": int(seed), "early_termination": float(stop)}


def launch_row_bands(kernel, inputs: list, width: int, height: int, band_pixels: int,
                     device: str, progress=None):
    """Launch a per-pixel ``kernel`` over the image in bands of whole rows.

    The kernel's last four parameters must be ``row0, radiance, alpha, samples``
    (``wp.tid()`` = ``(row - row0, col)``); ``inputs`` are the ones before them. Each band
    holds about ``band_pixels`` pixels; ``progress(fraction)`` is called between bands (not
    after the last). The device is synchronised before returning.

    Returns
    -------
    radiance : wp.array2d(vec3) (H, W)
    alpha : wp.array2d(float32) (H, W)
    samples : wp.array2d(int32) (H, W)
    bands : int
        Number of launches.
    """
    radiance = wp.zeros((height, width), dtype=wp.vec3, device=device)
    alpha = wp.zeros((height, width), dtype=wp.float32, device=device)
    samples = wp.zeros((height, width), dtype=wp.int32, device=device)
    rows = max(1, min(height, band_pixels // max(width, 1)))
    bands = (height + rows - 1) // rows
    for n, row0 in enumerate(range(0, height, rows)):
        wp.launch(kernel, dim=(min(rows, height - row0), width),
                  inputs=[*inputs, row0, radiance, alpha, samples], device=device)
        if progress is not None and n + 1 < bands:
            wp.synchronize_device(device)
            progress((n + 1) / bands)
    wp.synchronize_device(device)
    return radiance, alpha, samples, bands


@wp.func
def pixel_ray(cam: CameraParams, extent: wp.vec3, row: int, col: int):
    """Ray through the centre of pixel ``(row, col)`` and its span inside ``[0, extent]``.

    Returns ``(origin, unit direction, t0, t1)``: the box lies between ``t0`` (never behind
    the camera) and ``t1``; ``t0 >= t1`` means the ray misses it.
    """
    o, d = camera_ray(cam, float(col) + 0.5, float(row) + 0.5)
    tt = ray_box(o, d, extent)
    return o, d, wp.max(tt[0], 0.0), tt[1]


@wp.func
def sample_count(t0: float, t1: float, step: float, xi: float):
    """Samples at ``t0 + (k + xi) step`` strictly before ``t1`` (ties within 1e-4 step dropped)."""
    return int(wp.ceil((t1 - t0) / step - xi - 1.0e-4))
