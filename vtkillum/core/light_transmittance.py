"""Transmittance towards each light, and the unscattered fluence it gives, on a light grid.

For every point ``x`` of a regular *light grid* covering a volume's box, a
shadow ray is marched from ``x`` towards every light ``l``:

    T_l(x) = exp(-integral_0^D sigma_t(x + t w_l) dt)

with ``w_l`` the unit direction towards the light and ``D`` the distance to the
box exit (directional lights) or to the light itself, whichever is nearer
(point lights; outside the box ``sigma_t = 0``). ``sigma_t`` is the project's
grey extinction, sampled trilinearly with post-classification; the march is
:func:`vtkillum.core.warp_common.shadow_transmittance`, the one the ``single``
ray caster uses for its shadow rays. The fluence of the light that
reaches ``x`` without scattering is

    phi(x) = sum_l T_l(x) E_l(x)

(RGB; ``E_l`` the irradiance: constant for directional lights, ``I / d**2`` for
point lights), which is the project's illumination-volume convention
(:mod:`vtkillum.core.illumination`): the ray caster turns it into the
single-scattering source ``sigma_s * phi / (4 pi)``.

The line integral is evaluated with the midpoint rule on equal steps no longer
than ``step_size``; this is exact in homogeneous media and second-order
accurate where ``sigma_t`` is smooth. A march ends once ``T`` falls below
:data:`~vtkillum.core.warp_common.SHADOW_STOP_T` (10⁻⁶, an absolute error no picture
shows): in dense data most rays end long before the box exit.

A shadow ray is never longer than the box diagonal, so a step shorter than
``diagonal / MAX_STEPS_PER_RAY`` (the ray caster's limit,
:data:`vtkillum.core.raymarch.MAX_STEPS_PER_RAY`) is refused with an error naming
the smallest usable step. The grid points are launched in chunks of at most
:data:`CHUNK_SAMPLES` samples, so that Ctrl-C (``KeyboardInterrupt``) stops a long
march on the CPU within about a second.
"""

from __future__ import annotations

import numpy as np
import warp as wp

from vtkillum.core.device import resolve_device
from vtkillum.core.device_arrays import download
from vtkillum.core.raymarch import MAX_STEPS_PER_RAY
from vtkillum.core.warp_common import (
    SHADOW_STOP_T,
    Lights,
    Medium,
    grid_point,
    light_incidence,
    make_lights,
    make_medium,
    shadow_transmittance,
)

#: Upper bound of the shadow-ray samples of one kernel launch (grid points x steps per
#: ray): about 0.1 s of one CPU core, a fraction of a millisecond on a GPU. Python sees
#: Ctrl-C only between launches.
CHUNK_SAMPLES = {"cpu": 1 << 25, "cuda": 1 << 32}


def light_transmittance(volume, transfer_function, unit_distance: float, lights, shape=None,
                        step_size: float | None = None, device: str | None = None,
                        progress=None, on_device: bool = False):
    """Transmittance towards each light and the unscattered RGB fluence on a light grid.

    Parameters
    ----------
    volume : vtkillum.core.volume.Volume
        The data; its box (origin, spacing, direction) defines the light grid's box.
    transfer_function : vtkillum.core.transfer_function.TransferFunction
        Opacity (and colour, unused here) as functions of the data value.
    unit_distance : float
        Opacity unit distance ``u`` (world units): ``sigma_t = -ln(1 - alpha) / u``.
    lights : sequence of DirectionalLight or PointLight
        World-space lights (:mod:`vtkillum.core.lights`); at least one.
    shape : (3,) int, optional
        Points of the light grid along x, y, z (each >= 2); default the volume's
        dimensions. The grid spans the same box: point ``[i, j, k]`` sits at local
        position ``(i, j, k) * extent / (shape - 1)``.
    step_size : float, optional
        Longest marching step along shadow rays (world units); default half the
        smallest voxel spacing.
    device : str, optional
        Warp device; see :func:`vtkillum.core.device.resolve_device`.
    progress : callable, optional
        Called as ``progress(fraction_done)`` after each launch (see :data:`CHUNK_SAMPLES`).
    on_device : bool
        Return the warp arrays on ``device`` instead of numpy copies (for a renderer on the
        same device: no download, no upload).

    Returns
    -------
    transmittance : ndarray (n_lights, nx', ny', nz') float32
        ``T_l`` in [0, 1], indexed ``[l, i, j, k]``.
    fluence : ndarray (nx', ny', nz', 3) float32
        ``sum_l T_l E_l``, RGB, in the lights' irradiance units (intensity / world
        unit² for point lights).
    """
    lights = list(lights)
    if not lights:
        raise ValueError("light_transmittance needs at least one light; add a directional or "
                         "point light")
    shape = _grid_shape(volume, shape)
    if step_size is None:
        step_size = 0.5 * float(np.min(volume.spacing))
    if not (np.isfinite(step_size) and step_size > 0):
        raise ValueError(f"step_size must be positive and finite, got {step_size}")
    steps_per_ray = max_steps_per_ray(volume, step_size)
    device = resolve_device(device)

    medium = make_medium(volume, transfer_function, unit_distance, device=device)
    packed = make_lights(lights, volume, device)
    grid_spacing = wp.vec3(*(volume.extent / (np.asarray(shape) - 1)).astype(np.float32))
    n_lights = len(lights)
    transmittance = wp.zeros((n_lights, *shape), dtype=wp.float32, device=device)

    # Launches of at most CHUNK_SAMPLES samples each (whole lights or runs of grid points in
    # C order), so that progress is reported and Ctrl-C is seen between them.
    n_points = int(np.prod(shape))
    budget = CHUNK_SAMPLES["cpu" if device == "cpu" else "cuda"]
    chunk = int(min(n_points, max(1, budget // steps_per_ray)))
    launches = n_lights * ((n_points + chunk - 1) // chunk)
    done = 0
    for li in range(n_lights):
        for first in range(0, n_points, chunk):
            count = min(chunk, n_points - first)
            wp.launch(transmittance_kernel, dim=count,
                      inputs=[medium, packed, li, first, grid_spacing, float(step_size),
                              transmittance], device=device)
            done += 1
            if progress is not None or launches > 1:
                wp.synchronize_device(device)  # the launch ends here: Ctrl-C lands after it
            if progress is not None:
                progress(done / launches)

    fluence = wp.zeros(shape, dtype=wp.vec3, device=device)
    wp.launch(fluence_kernel, dim=shape, inputs=[packed, transmittance, grid_spacing, fluence],
              device=device)
    if on_device:
        return transmittance, fluence
    return download(transmittance), download(fluence).reshape(*shape, 3)


def max_steps_per_ray(volume, step_size: float) -> int:
    """Most steps a shadow ray through ``volume`` can take; refuses overlong marches.

    Raises
    ------
    ValueError
        When a ray across the box diagonal would need more than
        :data:`~vtkillum.core.raymarch.MAX_STEPS_PER_RAY` steps; the message names the
        smallest usable step.
    """
    diagonal = float(np.linalg.norm(volume.extent))
    steps = diagonal / float(step_size)
    if steps > MAX_STEPS_PER_RAY:
        raise ValueError(
            f"step_size {step_size:g} needs {steps:.3g} samples along a shadow ray across the "
            f"volume (diagonal {diagonal:g}); use at least "
            f"{diagonal / MAX_STEPS_PER_RAY:.3g} world units"
        )
    return max(1, int(np.ceil(steps)))


def _grid_shape(volume, shape) -> tuple[int, int, int]:
    if shape is None:
        return tuple(volume.dims)
    try:
        s = np.asarray(shape, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        s = np.zeros(0)
    if s.shape != (3,) or not np.all(np.isfinite(s)) or np.any(s != np.round(s)):
        raise ValueError(f"shape must be three integers (nx, ny, nz), got {shape!r}")
    s = s.astype(int)
    if np.any(s < 2):
        raise ValueError(f"light grid shape {tuple(s)}: at least 2 points per axis are needed")
    return tuple(int(n) for n in s)


@wp.kernel
def transmittance_kernel(medium: Medium, lights: Lights, li: int, first_point: int,
                         grid_spacing: wp.vec3, step_size: float,
                         out: wp.array4d(dtype=wp.float32)):
    """Shadow ray from one light-grid point towards light ``li``.

    ``wp.tid()`` = ``n``: grid point number ``first_point + n`` in C order of the grid
    ``out.shape[1:]``, i.e. point ``[i, j, k]`` (x, y, z) at local position
    ``(i, j, k) * grid_spacing`` (world units).
    Writes the transmittance (unitless) to ``out[li, i, j, k]``.
    """
    n = first_point + wp.tid()
    nz = out.shape[3]
    nyz = out.shape[2] * nz
    i = n // nyz
    j = (n - i * nyz) // nz
    k = n - i * nyz - j * nz
    p = grid_point(i, j, k, grid_spacing)
    w, dist, _irradiance = light_incidence(lights, li, p)
    out[li, i, j, k] = shadow_transmittance(medium, p, w, dist, step_size, 0.5, SHADOW_STOP_T)


@wp.kernel
def fluence_kernel(lights: Lights, transmittance: wp.array4d(dtype=wp.float32),
                   grid_spacing: wp.vec3, out: wp.array3d(dtype=wp.vec3)):
    """Sum of transmitted irradiance over the lights at one grid point.

    ``wp.tid()`` = ``(i, j, k)``, the light-grid point (x, y, z). Writes RGB fluence
    ``sum_l T_l E_l`` (irradiance units) to ``out[i, j, k]``.
    """
    i, j, k = wp.tid()
    p = grid_point(i, j, k, grid_spacing)
    acc = wp.vec3(0.0, 0.0, 0.0)
    for li in range(lights.count):
        _w, _dist, e = light_incidence(lights, li, p)
        acc += transmittance[li, i, j, k] * e
    out[i, j, k] = acc
