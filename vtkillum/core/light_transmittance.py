"""Transmittance towards each light, and the unscattered fluence it gives, on a light grid.

For every point ``x`` of a regular *light grid* covering a volume's box, the
transmittance along the shadow ray from ``x`` towards every light ``l`` is

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

Line integrals are evaluated with the midpoint rule on equal steps no longer
than ``step_size``; this is exact in homogeneous media and second-order
accurate where ``sigma_t`` is smooth. A march ends once ``T`` falls below
:data:`~vtkillum.core.warp_common.SHADOW_STOP_T` (10⁻⁶, an absolute error no picture
shows): in dense data most rays end long before the box exit.

Point lights: one exact shadow ray per grid point (cost O(N⁴) for N³ points).

Directional lights: chained ray segments (the default, ``segment_planes = L = 16``).
All shadow rays of a directional light are parallel, so a ray's far part has already
been integrated by the points it passes. With ``a`` the dominant axis of ``w`` in the
volume's local frame (``|w_a|`` largest), the grid planes normal to ``a`` are numbered
``r = 0, 1, ...`` from the light-side face and taken in slabs:

* planes ``r <= L`` march exactly to the box exit (at most ``L`` planes away);
* a point ``p`` of plane ``r`` in ``(sL, (s + 1)L]`` marches exactly (same step rule,
  midpoint samples, empty-block skipping) towards the light until the ray meets plane
  ``r_b = sL`` at ``q``, ``m = r - r_b`` planes (``m * h_a / |w_a|`` world units,
  ``h_a`` the grid spacing along ``a``) away, and
  ``T(p) = exp(-tau(p, q)) T(q)`` with ``T(q)`` interpolated bilinearly in plane ``r_b``,
  already finished by the slab before (``q`` clamped to the plane's box);
* a ray that leaves the box through a side before plane ``r_b`` is exact:
  ``T(p) = exp(-tau)`` of its part inside;
* where ``T(q) < SHADOW_STOP_T`` the point takes ``T(q)`` without a march, and a
  segment's march stops once the product falls below ``SHADOW_STOP_T`` (an error of at
  most 10⁻⁶, absolute, as for the exact rays).

The one error source is the bilinear interpolation at every ``L``-th plane. For an
axis-aligned light ``q`` is a grid point and the chain equals the exact rays (to float32
rounding, where both marches take the same samples, e.g. ``step_size`` dividing ``h_a``).
For an oblique light every chain link reads its plane at the same in-plane fractions
``f = frac(L h_a w_b / (h_b w_a))`` (``b`` an in-plane axis) and blurs a sharp shadow
edge like a random walk of ``N / L`` steps of variance ``f (1 - f)`` cells²: by about
``sqrt(N / L * f (1 - f))`` grid cells after ``N`` planes (at most 1.4 cells at N = 128,
2.8 cells at N = 512 for ``L = 16``), and not at all where ``L h_a w_b / (h_b w_a)`` is
an integer. The interpolation is linear in ``T``, so the blur neither brightens nor
darkens on average. In homogeneous media the chain is exact where the light enters
through the light-side face; where it enters through a side face, the box edge is a
kink of ``T`` that the interpolation smooths like a shadow edge. Measured against the
exact rays (``tests/core/test_transmittance_chained.py``, L = 16):

* 56³ grid of hard-edged balls (shadow edges a fraction of a cell wide), four oblique
  lights: mean ``|dT|`` 5.7e-3 to 1.8e-2, mean ``dT`` at most 1.1e-3; a sharp edge a
  cell off gives max ``|dT|`` up to 0.85, but every chained value lies within the exact
  grid's range over the 5³ points around it to 0.016 (the shadows are blurred, not moved);
* smooth Gaussian blobs, 64³-128³: mean ``|dT|`` 2e-4 to 4e-4, max 0.015;
* homogeneous box, light entering through side faces: max ``|dT|`` 0.03 at the kink;
* the ``transmittance`` picture of the hard-edged balls at 48³: mean difference 1.7e-3
  of the mean radiance.

Cost: each point marches at most ``L`` planes, ``O(N³ L)`` samples instead of the exact
rays' ``O(N⁴)``, in about ``N / L`` launches per light (a slab's points depend only on the
slab before). The ratio grows as ``N / L``: on one CPU core 2.2x at 64³, 3.3x at 96³,
4.1x at 128³ (measured, two oblique lights). ``segment_planes=0`` (or None) gives the
exact rays for every light.

A shadow ray is never longer than the box diagonal, so a step shorter than
``diagonal / MAX_STEPS_PER_RAY`` (the ray caster's limit,
:data:`vtkillum.core.raymarch.MAX_STEPS_PER_RAY`) is refused with an error naming
the smallest usable step. The grid points are launched in chunks of at most
:data:`CHUNK_SAMPLES` samples, so that Ctrl-C (``KeyboardInterrupt``) stops a long
march on the CPU within about a second.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import warp as wp

from vtkillum.core.device import resolve_device
from vtkillum.core.device_arrays import download
from vtkillum.core.lights import DIRECTIONAL as DIRECTIONAL_KIND
from vtkillum.core.lights import pack_lights
from vtkillum.core.raymarch import MAX_STEPS_PER_RAY
from vtkillum.core.warp_common import (
    SHADOW_STOP_T,
    Lights,
    Medium,
    axis_offset,
    component,
    grid_point,
    light_incidence,
    make_lights,
    make_medium,
    ray_box,
    shadow_march,
    shadow_transmittance,
)

#: Upper bound of the shadow-ray samples of one kernel launch (grid points x steps per
#: ray): about 0.1 s of one CPU core, a fraction of a millisecond on a GPU. Python sees
#: Ctrl-C only between launches.
CHUNK_SAMPLES = {"cpu": 1 << 25, "cuda": 1 << 32}

#: Default ``segment_planes`` of :func:`light_transmittance`: planes between the chained
#: segments' interpolations (directional lights).
SEGMENT_PLANES = 16


def light_transmittance(volume, transfer_function, unit_distance: float, lights, shape=None,
                        step_size: float | None = None, device: str | None = None,
                        progress=None, on_device: bool = False,
                        segment_planes: int | None = SEGMENT_PLANES, textures: bool = True):
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
    segment_planes : int or None
        Directional lights: grid planes ``L`` between the chained segments' bilinear
        interpolations (module docstring); default :data:`SEGMENT_PLANES`. ``0`` or None:
        one exact shadow ray per grid point, as for point lights (which always get them).
    textures : bool
        On CUDA the chained segments read the data and the transfer function through
        hardware-filtered textures (:mod:`vtkillum.core.textures`; each sample within
        about 1/256 of a neighbour difference of the exact one). The exact rays
        (``segment_planes=0``, point lights) always read the arrays: they are the
        reference the distributed march reproduces bit for bit. Ignored on the CPU.

    Returns
    -------
    transmittance : ndarray (n_lights, nx', ny', nz') float32
        ``T_l`` in [0, 1], indexed ``[l, i, j, k]``.
    fluence : ndarray (nx', ny', nz', 3) float32
        ``sum_l T_l E_l``, RGB, in the lights' irradiance units (intensity / world
        unit² for point lights).

    With ``on_device=True`` both are warp arrays on ``device`` (``array4d`` of float32,
    ``array3d`` of vec3) instead.

    Notes
    -----
    Chained segments blur sharp shadow edges of oblique directional lights by about
    ``sqrt(N / L * f (1 - f))`` cells; the module docstring gives the measured errors.
    """
    lights = list(lights)
    if not lights:
        raise ValueError("light_transmittance needs at least one light; add a directional or "
                         "point light")
    shape = _grid_shape(volume, shape)
    segment_planes = _segment_planes(segment_planes)
    if step_size is None:
        step_size = 0.5 * float(np.min(volume.spacing))
    if not (np.isfinite(step_size) and step_size > 0):
        raise ValueError(f"step_size must be positive and finite, got {step_size}")
    steps_per_ray = max_steps_per_ray(volume, step_size)
    device = resolve_device(device)

    medium = make_medium(volume, transfer_function, unit_distance, device=device)
    packed = make_lights(lights, volume, device)
    spacing = volume.extent / (np.asarray(shape) - 1)
    grid_spacing = wp.vec3(*spacing.astype(np.float32))
    n_lights = len(lights)
    transmittance = wp.zeros((n_lights, *shape), dtype=wp.float32, device=device)

    # The launches, planned on the host: (light, kernel inputs, count) of at most
    # CHUNK_SAMPLES samples each, so that progress is reported and Ctrl-C is seen between
    # them.
    budget = CHUNK_SAMPLES["cpu" if device == "cpu" else "cuda"]
    kinds, vecs, _rgb = pack_lights(lights, volume.direction, volume.origin)
    plan = []
    for li in range(n_lights):
        if kinds[li] == DIRECTIONAL_KIND and segment_planes:
            plan += _chain_launches(li, -vecs[li].astype(np.float64), shape, spacing,
                                    segment_planes, step_size, steps_per_ray, budget)
        else:
            plan += _ray_launches(li, shape, steps_per_ray, budget)
    sources = _chain_sources(volume, medium, device, textures)
    for done, (kernel, inputs, count) in enumerate(plan, 1):
        head = [medium, packed] if kernel is transmittance_kernel else \
            [medium, *sources, packed]
        if kernel is not transmittance_kernel:
            kernel = chained_overload(sources[0] is not medium.scalars)
        wp.launch(kernel, dim=count,
                  inputs=[*head, *inputs, grid_spacing, float(step_size), transmittance],
                  device=device)
        if progress is not None or (device == "cpu" and len(plan) > 1):
            wp.synchronize_device(device)  # the launch ends here: Ctrl-C lands after it
        if progress is not None:
            progress(done / len(plan))

    fluence = wp.zeros(shape, dtype=wp.vec3, device=device)
    wp.launch(fluence_kernel, dim=shape, inputs=[packed, transmittance, grid_spacing, fluence],
              device=device)
    if on_device:
        return transmittance, fluence
    return download(transmittance), download(fluence).reshape(*shape, 3)


def _chain_sources(volume, medium, device: str, textures: bool) -> tuple:
    """What the chained segments sample: the medium's arrays, or on CUDA with ``textures``
    their textures (kept with the volume like the ray caster's; the arrays where a grid
    does not fit a texture)."""
    from vtkillum.core.textures import optics_texture, scalar_texture, textures_available

    if not (textures and textures_available(device)):
        return medium.scalars, medium.sigma_table
    scalars = volume.derived(f"scalars_texture@{device}", id(medium.scalars),
                             lambda: (medium.scalars, scalar_texture(medium.scalars)))[1]
    if scalars is None:
        return medium.scalars, medium.sigma_table
    optics = volume.derived(f"optics_texture@{device}", id(medium.sigma_table),
                            lambda: (medium.sigma_table, optics_texture(medium)))[1]
    return scalars, optics


def _segment_planes(value) -> int:
    """``segment_planes`` checked: a non-negative integer (None: 0, the exact rays)."""
    if value is None:
        return 0
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)) \
            or value < 0:
        raise ValueError(f"segment_planes must be a non-negative integer (0 or None: exact "
                         f"shadow rays), got {value!r}")
    return int(value)


def _ray_launches(li: int, shape, steps_per_ray: int, budget: int) -> list:
    """Launches of :func:`transmittance_kernel`: runs of grid points in C order."""
    n_points = int(np.prod(shape))
    chunk = int(min(n_points, max(1, budget // steps_per_ray)))
    return [(transmittance_kernel, [li, first], min(chunk, n_points - first))
            for first in range(0, n_points, chunk)]


def chain_slabs(toward, shape, planes: int) -> tuple[int, int, int, list]:
    """The slabs of chained segments for a directional light (the module docstring).

    ``toward`` is the unit direction towards the light in the local frame. Returns
    ``(axis, first, direction, slabs)``: plane ``r`` (counted from the light-side face) has
    index ``first + direction * r`` along ``axis``; each slab is ``(r0, r1, look_back)``,
    its planes ``r0 <= r < r1`` and the plane its segments end on (-1: exact rays to the
    box exit, the first slab). Shared by the one-rank launches and the distributed march
    (:mod:`vtkillum.core.parallel.chained`), so both take the same slabs.
    """
    axis = int(np.argmax(np.abs(toward)))
    n_a = int(shape[axis])
    # Planes numbered from the light-side face: r -> index first + direction * r.
    first, direction = (n_a - 1, -1) if toward[axis] > 0 else (0, 1)
    slabs = []
    r0, look_back = 0, -1  # the first slab: planes 0..planes, exact to the box exit
    while r0 < n_a:
        r1 = min(n_a, (planes + 1 if look_back < 0 else r0 + planes))
        slabs.append((r0, r1, look_back))
        look_back = r1 - 1
        r0 = r1
    return axis, first, direction, slabs


def _chain_launches(li: int, toward, shape, spacing, planes: int, step_size: float,
                    steps_per_ray: int, budget: int) -> list:
    """Launches of :func:`chained_kernel` for directional light ``li``, slab after slab
    (:func:`chain_slabs`), each a run of points of one slab (plane after plane from the
    light side, C order within a plane)."""
    axis, first, direction, slabs = chain_slabs(toward, shape, planes)
    b, c = (axis + 1) % 3, (axis + 2) % 3
    plane_points = int(shape[b]) * int(shape[c])
    # A segment spans at most `planes` planes, and so does an exact ray from r <= planes.
    segment = planes * float(spacing[axis]) / abs(float(toward[axis]))
    steps = int(min(steps_per_ray, np.ceil(segment / step_size) + 1))
    chunk = int(max(1, budget // steps))
    launches = []
    for r0, r1, look_back in slabs:
        n_points = (r1 - r0) * plane_points
        for start in range(0, n_points, chunk):
            launches.append((chained_kernel,
                             [li, axis, first, direction, r0, start, look_back,
                              wp.vec3i(*(int(n) for n in shape))],
                             min(chunk, n_points - start)))
    return launches


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
def chained_kernel(medium: Medium, scalars: Any, optics: Any, lights: Lights, li: int,
                   axis: int, first_plane: int,
                   direction: int, r0: int, first_point: int, look_back: int,
                   shape: wp.vec3i, grid_spacing: wp.vec3, step_size: float,
                   out: wp.array4d(dtype=wp.float32)):
    """One chained shadow-ray segment towards directional light ``li`` (module docstring).

    ``wp.tid()`` = ``t``: point number ``n = first_point + t`` of a slab whose first plane
    is ``r0`` (planes counted from the light-side face: plane ``r`` has index
    ``first_plane + direction * r`` along ``axis``); ``n`` runs over the planes, then the
    in-plane axes ``(axis + 1) % 3`` and ``(axis + 2) % 3`` in that order. ``shape`` is the
    grid's ``(nx, ny, nz)`` and ``grid_spacing`` its spacing (world units). ``scalars`` and
    ``optics`` are the medium's arrays or their textures (:func:`chained_overload`).
    ``look_back`` is the plane (counted as ``r``) whose transmittance the segments end on;
    -1 marches exactly to the box exit. Writes the transmittance (unitless) to
    ``out[li, i, j, k]``.
    """
    n = first_point + wp.tid()
    b = (axis + 1) % 3
    c = (axis + 2) % 3
    nb = component(shape, b)
    nc = component(shape, c)
    plane = n // (nb * nc)
    rest = n - plane * nb * nc
    ib = rest // nc
    ic = rest - ib * nc
    idx = axis_offset(axis, first_plane + direction * (r0 + plane)) + axis_offset(b, ib) \
        + axis_offset(c, ic)
    p = grid_point(idx[0], idx[1], idx[2], grid_spacing)
    w, dist, _irradiance = light_incidence(lights, li, p)
    if look_back < 0:
        out[li, idx[0], idx[1], idx[2]] = shadow_march(medium, scalars, optics, p, w, dist,
                                                       step_size, 0.5, SHADOW_STOP_T)
        return
    length, inside, back, jb, jc, fb, fc = chain_link(medium.extent, grid_spacing, shape, axis,
                                                      first_plane, direction, look_back, p, w)
    corners = wp.vec4(0.0)
    if inside != 0:
        corners = grid_corners(out, li, axis, back, jb, jc)
    t_far, stop, done = link_transmittance(inside, corners, fb, fc)
    if done != 0:  # T(q) < SHADOW_STOP_T: at most SHADOW_STOP_T too bright, as a stopped ray
        out[li, idx[0], idx[1], idx[2]] = t_far
        return
    out[li, idx[0], idx[1], idx[2]] = t_far * shadow_march(medium, scalars, optics, p, w,
                                                           length, step_size, 0.5, stop)


@wp.func
def chain_link(extent: wp.vec3, grid_spacing: wp.vec3, shape: wp.vec3i, axis: int,
               first_plane: int, direction: int, look_back: int, p: wp.vec3, w: wp.vec3):
    """Where grid point ``p``'s chain meets plane ``look_back`` (module docstring).

    Returns ``(length, inside, back, jb, jc, fb, fc)``: the segment's length from ``p``
    along the unit direction ``w`` to the plane (world units); ``inside = 1`` where the ray
    meets the plane inside the box (else it leaves through a side first and is exact);
    the plane's index ``back`` along ``axis``; the in-plane cell ``(jb, jc)`` (along axes
    ``(axis + 1) % 3`` and ``(axis + 2) % 3``) and fractions of the meeting point ``q``.
    :func:`link_transmittance` turns the cell's corner values into ``T(q)``. Shared by the
    one-rank kernel and the distributed one (:mod:`vtkillum.core.parallel.chained`), which
    read the corners from their own stores: the same float32 operations.
    """
    b = (axis + 1) % 3
    c = (axis + 2) % 3
    nb = component(shape, b)
    nc = component(shape, c)
    back = first_plane + direction * look_back
    ha = component(grid_spacing, axis)
    length = (float(back) * ha - component(p, axis)) / component(w, axis)
    inside = int(0)
    jb = int(0)
    jc = int(0)
    fb = float(0.0)
    fc = float(0.0)
    if ray_box(p, w, extent)[1] >= length * (1.0 - 1.0e-5):
        q = p + length * w
        ub = wp.clamp(component(q, b) / component(grid_spacing, b), 0.0, float(nb - 1))
        uc = wp.clamp(component(q, c) / component(grid_spacing, c), 0.0, float(nc - 1))
        jb = wp.min(int(wp.floor(ub)), nb - 2)
        jc = wp.min(int(wp.floor(uc)), nc - 2)
        fb = ub - float(jb)
        fc = uc - float(jc)
        inside = 1
    return length, inside, back, jb, jc, fb, fc


@wp.func
def link_transmittance(inside: int, v: wp.vec4, fb: float, fc: float):
    """``(t_far, stop, done)`` of a chain link: ``T(q)`` bilinearly from the corners ``v``
    (``(jb, jc)``, ``(jb+1, jc)``, ``(jb, jc+1)``, ``(jb+1, jc+1)``; 1 where the ray does not
    meet the plane inside the box), the stop level of the segment's march
    (``SHADOW_STOP_T / T(q)``) and ``done = 1`` where ``T(q) < SHADOW_STOP_T`` (the point
    takes ``T(q)``)."""
    t_far = float(1.0)
    stop = float(SHADOW_STOP_T)
    done = int(0)
    if inside != 0:
        t_far = (1.0 - fc) * ((1.0 - fb) * v[0] + fb * v[1]) + fc * ((1.0 - fb) * v[2]
                                                                      + fb * v[3])
        if t_far < SHADOW_STOP_T:
            done = 1
        else:
            stop = SHADOW_STOP_T / t_far
    return t_far, stop, done


@wp.func
def grid_corners(out: wp.array4d(dtype=wp.float32), li: int, axis: int, back: int, jb: int,
                 jc: int):
    """``T`` of light ``li`` at in-plane points ``(jb, jc)``, ``(jb+1, jc)``, ``(jb, jc+1)``,
    ``(jb+1, jc+1)`` of plane ``back`` along ``axis`` of the grid being filled."""
    b = (axis + 1) % 3
    c = (axis + 2) % 3
    base = axis_offset(axis, back) + axis_offset(b, jb) + axis_offset(c, jc)
    db = axis_offset(b, 1)
    dc = axis_offset(c, 1)
    return wp.vec4(out[li, base[0], base[1], base[2]],
                   out[li, base[0] + db[0], base[1] + db[1], base[2] + db[2]],
                   out[li, base[0] + dc[0], base[1] + dc[1], base[2] + dc[2]],
                   out[li, base[0] + db[0] + dc[0], base[1] + db[1] + dc[1],
                       base[2] + db[2] + dc[2]])


def chained_overload(textures: bool):
    """:func:`chained_kernel` sampling the medium's arrays (exact) or, on CUDA, their
    hardware-filtered textures (:mod:`vtkillum.core.textures`)."""
    if textures:
        return wp.overload(chained_kernel, {"scalars": wp.Texture3D, "optics": wp.Texture1D})
    return wp.overload(chained_kernel, {"scalars": wp.array3d(dtype=wp.float32),
                                        "optics": wp.array(dtype=wp.float32)})


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
