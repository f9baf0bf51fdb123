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
accurate where ``sigma_t`` is smooth.
"""

from __future__ import annotations

import numpy as np
import warp as wp

from vtkillum.core.device import resolve_device
from vtkillum.core.warp_common import (
    Lights,
    Medium,
    grid_point,
    light_incidence,
    make_lights,
    make_medium,
    shadow_transmittance,
)


def light_transmittance(volume, transfer_function, unit_distance: float, lights, shape=None,
                        step_size: float | None = None, device: str | None = None,
                        progress=None):
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
        Called as ``progress(fraction_done)`` after each light.

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
    device = resolve_device(device)

    medium = make_medium(volume, transfer_function, unit_distance, device=device)
    packed = make_lights(lights, volume, device)
    grid_spacing = wp.vec3(*(volume.extent / (np.asarray(shape) - 1)).astype(np.float32))
    n_lights = len(lights)
    transmittance = wp.zeros((n_lights, *shape), dtype=wp.float32, device=device)

    # One launch per light so that progress can be reported between launches; each launch
    # still runs one thread per (light, grid point).
    for li in range(n_lights):
        wp.launch(transmittance_kernel, dim=(1, *shape),
                  inputs=[medium, packed, li, grid_spacing, float(step_size), transmittance],
                  device=device)
        if progress is not None:
            wp.synchronize_device(device)
            progress((li + 1) / n_lights)

    fluence = wp.zeros(shape, dtype=wp.vec3, device=device)
    wp.launch(fluence_kernel, dim=shape, inputs=[packed, transmittance, grid_spacing, fluence],
              device=device)
    return transmittance.numpy(), fluence.numpy().reshape(*shape, 3)


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
def transmittance_kernel(medium: Medium, lights: Lights, first_light: int, grid_spacing: wp.vec3,
                         step_size: float, out: wp.array4d(dtype=wp.float32)):
    """Shadow ray from one light-grid point towards one light.

    ``wp.tid()`` = ``(o, i, j, k)``: light ``first_light + o``, grid point ``[i, j, k]``
    (x, y, z) at local position ``(i, j, k) * grid_spacing`` (world units).
    Writes the transmittance (unitless) to ``out[first_light + o, i, j, k]``.
    """
    offset, i, j, k = wp.tid()
    li = first_light + offset
    p = grid_point(i, j, k, grid_spacing)
    w, dist, _irradiance = light_incidence(lights, li, p)
    out[li, i, j, k] = shadow_transmittance(medium, p, w, dist, step_size, 0.5, 0.0)


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
