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
    holds about ``band_pixels`` pixels (at least one row); ``progress(fraction)`` is called
    between bands (not after the last). The device is synchronised before returning.

    Returns
    -------
    radiance : wp.array2d(vec3) (H, W)
    alpha : wp.array2d(float32) (H, W)
    samples : wp.array2d(int32) (H, W)
    bands : int
        Number of launches.
    """
    rows = max(1, min(height, band_pixels // max(width, 1)))
    tiles = [(row0, 0, min(rows, height - row0), width) for row0 in range(0, height, rows)]
    return _launch(kernel, inputs, width, height, tiles, device, progress, False)


def launch_tiles(kernel, inputs: list, width: int, height: int, band_pixels: int, device: str,
                 progress=None, work=None):
    """Like :func:`launch_row_bands`, but a band may also be a part of one row.

    For kernels whose work per pixel can be large: bands of whole rows while a row holds
    at most ``band_pixels`` pixels, else runs of ``band_pixels`` (at least 1) pixels of
    one row. The kernel's last five parameters must be ``row0, col0, radiance, alpha,
    samples`` (``wp.tid()`` = ``(row - row0, col - col0)``). ``work`` (optional, ``(H, W)``,
    e.g. :func:`pixel_work`) weighs the progress reports: a band of empty rows then counts
    for little, so that the time-left estimate does not run ahead.
    """
    band_pixels = max(1, int(band_pixels))
    if band_pixels >= width:
        rows = max(1, min(height, band_pixels // max(width, 1)))
        tiles = [(row0, 0, min(rows, height - row0), width) for row0 in range(0, height, rows)]
    else:
        tiles = [(row, col0, 1, min(band_pixels, width - col0)) for row in range(height)
                 for col0 in range(0, width, band_pixels)]
    return _launch(kernel, inputs, width, height, tiles, device, progress, True, work)


def pixel_work(cam: CameraParams, extent, width: int, height: int, device: str) -> np.ndarray:
    """``(H, W)`` length of each pixel's ray inside the box (world units): the part of a
    pixel's cost that grows with its samples (0 where the ray misses)."""
    out = wp.zeros((int(height), int(width)), dtype=wp.float32, device=device)
    wp.launch(chord_kernel, dim=(int(height), int(width)),
              inputs=[cam, wp.vec3(*np.asarray(extent, np.float32)), out], device=device)
    return out.numpy()


def _launch(kernel, inputs, width, height, tiles, device, progress, with_col0, work=None):
    radiance = wp.zeros((height, width), dtype=wp.vec3, device=device)
    alpha = wp.zeros((height, width), dtype=wp.float32, device=device)
    samples = wp.zeros((height, width), dtype=wp.int32, device=device)
    weights = np.ones(len(tiles))
    if work is not None and progress is not None:
        # Every pixel costs a little (its ray set-up), and more with its chord's length.
        floor = 0.02 * max(float(np.mean(work)), 1e-30)
        weights = np.array([float(np.sum(work[r0:r0 + rows, c0:c0 + cols])) + floor * rows * cols
                            for r0, c0, rows, cols in tiles])
    done = np.cumsum(weights) / max(float(np.sum(weights)), 1e-300)
    for n, (row0, col0, rows, cols) in enumerate(tiles):
        offsets = [row0, col0] if with_col0 else [row0]
        wp.launch(kernel, dim=(rows, cols), inputs=[*inputs, *offsets, radiance, alpha, samples],
                  device=device)
        if progress is not None and n + 1 < len(tiles):
            wp.synchronize_device(device)
            progress(float(done[n]))
    wp.synchronize_device(device)
    return radiance, alpha, samples, len(tiles)


@wp.func
def pixel_ray(cam: CameraParams, extent: wp.vec3, row: int, col: int):
    """Ray through the centre of pixel ``(row, col)`` and its span inside ``[0, extent]``.

    Returns ``(origin, unit direction, t0, t1)``: the box lies between ``t0`` (never behind
    the camera) and ``t1``; ``t0 >= t1`` means the ray misses it.
    """
    o, d = camera_ray(cam, float(col) + 0.5, float(row) + 0.5)
    tt = ray_box(o, d, extent)
    return o, d, wp.max(tt[0], 0.0), tt[1]


@wp.kernel
def chord_kernel(cam: CameraParams, extent: wp.vec3, out: wp.array2d(dtype=wp.float32)):
    """Ray length inside the box of pixel ``wp.tid() = (row, col)`` (:func:`pixel_work`)."""
    row, col = wp.tid()
    _o, _d, t0, t1 = pixel_ray(cam, extent, row, col)
    out[row, col] = wp.max(t1 - t0, 0.0)


@wp.func
def sample_count(t0: float, t1: float, step: float, xi: float):
    """Samples at ``t0 + (k + xi) step`` strictly before ``t1`` (ties within 1e-4 step dropped)."""
    return int(wp.ceil((t1 - t0) / step - xi - 1.0e-4))


def mean_samples(samples) -> float:
    """Mean of a ``(H, W)`` int32 sample-count image, reduced on its device (a float64 sum
    per row by atomic adds, then ``H`` numbers to the host) instead of downloading the
    whole image."""
    rows = wp.zeros(samples.shape[0], dtype=wp.float64, device=samples.device)
    wp.launch(row_sum_kernel, dim=samples.shape, inputs=[samples, rows], device=samples.device)
    return float(rows.numpy().sum()) / max(int(samples.shape[0] * samples.shape[1]), 1)


@wp.kernel
def row_sum_kernel(samples: wp.array2d(dtype=wp.int32), out: wp.array(dtype=wp.float64)):
    """``out[row] += samples[row, col]``; ``wp.tid()`` is ``(row, col)``."""
    row, col = wp.tid()
    wp.atomic_add(out, row, wp.float64(samples[row, col]))
