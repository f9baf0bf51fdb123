"""Rendering with virtual lights (paper eqs. 4–5) plus exact single scattering.

One thread per pixel marches the view ray twice (:func:`view_kernel`), and one thread
per multiple-scattering position sums the virtual lights (:func:`vl_kernel`):

1. **Single scattering** from the real lights, exactly as the project's ``single``
   ray caster does it (:func:`vtkillum.core.raycast.single_scatter_light` at every
   step, the same step sizes, jitter and early termination), together with the alpha
   of the ray. Fine shadows therefore stay sharp, as in the paper.
2. **Multiple scattering** from the virtual lights at ``S`` positions ``x_t`` on the
   view ray (``view_samples``), drawn by inverting the ray's cumulative opacity at
   stratified levels ``alpha (i + u) / S``: positions distributed as
   ``sigma_t T(x, x_t) / alpha`` so that

       L_ms = alpha / S * sum_t (sigma_s / sigma_t)(x_t) * sum_j L_j(x_t)

   estimates ``integral T(x, x_t) sigma_s(x_t) sum_j L_j(x_t) dt`` without bias (the paper
   uses ``S`` uniform positions, eq. 4; sampling by opacity puts them where they matter).
   With ``L_j`` the light that VL ``j`` scatters towards the camera at ``x_t``:

   * virtual point lights (eq. 4):
     ``L_j = f(w_j . -w) T(x_j, x_t) f(w . d) / |x_t - x_j|^2 * power_j``
   * virtual spherical lights of radius ``r`` (eq. 5): one direction ``w`` drawn
     uniformly in the cone the sphere subtends at ``x_t`` (solid angle
     ``Omega = 2 pi (1 - cos theta)``, ``sin theta = min(1, r / |x_t - x_j|)``, so a
     shading point inside the sphere sees a hemisphere) and ``1 / |x_t - x_j|^2``
     replaced by ``Omega / (pi r^2)`` = ``1 / (pi r^2 p(Omega))``. Bounded (at most
     ``2 / r^2``), and equal to the point light's ``1 / d^2 (1 + r^2 / (4 d^2) + ...)``
     far away, so the estimate tends to the unregularised one as ``r`` shrinks.
   * clamped virtual lights (``VirtualLights.clamped``,
     :mod:`~vtkillum.core.many_lights.clamp`): ``1 / |x_t - x_j|^2`` replaced by the
     clamped term ``(1 - b) / d^2`` times the transmittance plus the compensation
     ``b A_j`` (no transmittance; the two phase functions averaged over the direction in
     between, :func:`spread_phase`), ``b`` a smooth window of radius ``r``; no cone sample.

   ``w`` points from ``x_t`` towards the VL, ``d`` is the view ray's direction, ``w_j``
   the direction in which light arrived at the VL, ``f`` the HG phase function (light
   travel direction vs. scattered direction) and ``power_j`` the VL's
   ``beta_j sigma_s(x_j) / P`` (:mod:`~vtkillum.core.many_lights.contribution`). The
   transmittance ``T(x_j, x_t)`` is ray-marched towards the VL's centre (exact mode,
   ``shadow_transmittance``) or read from the VL's AVSM (raised to the global density
   scale).

Returned radiance is ``single + multiple``; the two parts are also returned
separately. The illumination filter uses :func:`scattered_fluence`, the same VL sum at
grid points without the phase function at the receiving point (an isotropic fluence).
"""

from __future__ import annotations

import functools
from typing import Any

import numpy as np
import warp as wp

from vtkillum.core.many_lights.avsm import (
    ShadowMaps,
    avsm_lookup,
    lookup_function,
    texel_view,
)
from vtkillum.core.many_lights.clamp import clamped_geometry
from vtkillum.core.raycast import single_scatter_light
from vtkillum.core.raymarch import mean_samples, pixel_ray, sample_count
from vtkillum.core.warp_common import (
    CameraParams,
    Lights,
    Medium,
    block_run,
    grid_point,
    hg_phase,
    lookup_color,
    lookup_sigma_t,
    orthonormal_basis,
    sample_scalar,
    shadow_transmittance,
    uniform,
)

#: Transmittance modes of the VL connections.
TRANSMITTANCE = {"ray-marching": 0, "avsm": 1}
RAY_MARCHED = wp.constant(0)

#: Pixels per launch (progress reporting between launches).
BAND_PIXELS = {"cpu": 1 << 12, "cuda": 1 << 20}
#: The HG phase function for g = 0.
ISOTROPIC_PHASE = wp.constant(1.0 / (4.0 * np.pi))
#: Pixels of one warp of :func:`avsm_vl_kernel`: a tile of 8 rows x 4 columns (at one level).
TILE_ROWS = wp.constant(8)
TILE_COLS = wp.constant(4)


@wp.struct
class VirtualLights:
    """The VLs on the device: ``position`` (local frame), incident travel ``direction``,
    ``power`` (RGB, see the module docstring), AVSM ``slot``, ``radius`` of each spherical
    or clamped light (world units; 0: a point light), ``near`` the compensation amplitude
    ``A_j`` of a clamped light (:mod:`~vtkillum.core.many_lights.clamp`); ``count``, and
    ``clamped`` (1: the radius is a clamping radius, 0: a VSL's)."""

    position: wp.array(dtype=wp.vec3)
    direction: wp.array(dtype=wp.vec3)
    power: wp.array(dtype=wp.vec3)
    slot: wp.array(dtype=wp.int32)
    radius: wp.array(dtype=wp.float32)
    near: wp.array(dtype=wp.float32)
    count: int
    clamped: int


#: One VL for :func:`avsm_vl_kernel`: position (0-2), radius (3), direction (4-6), AVSM slot
#: (7, exact as a float below 2^24), power (8-10), compensation amplitude ``A_j`` (11).
VLRecord = wp.types.vector(length=12, dtype=wp.float32)


@wp.kernel
def record_kernel(vls: VirtualLights, records: wp.array(dtype=VLRecord)):
    """Pack VL ``wp.tid()`` into its :data:`VLRecord`."""
    j = wp.tid()
    p = vls.position[j]
    d = vls.direction[j]
    w = vls.power[j]
    rec = VLRecord()
    rec[0] = p[0]
    rec[1] = p[1]
    rec[2] = p[2]
    rec[3] = vls.radius[j]
    rec[4] = d[0]
    rec[5] = d[1]
    rec[6] = d[2]
    rec[7] = float(vls.slot[j])
    rec[8] = w[0]
    rec[9] = w[1]
    rec[10] = w[2]
    rec[11] = vls.near[j]
    records[j] = rec


@wp.struct
class GatherParams:
    """View-ray sampling (``step``, ``jitter``, ``seed``, ``stop_alpha``), the number of
    multiple-scattering positions per ray (``view_samples``), the VL transmittance mode
    (0 ray marching with ``vl_step``, 1 AVSM raised to ``scale``), and which terms to add
    (``single``, ``multiple``: 0 or 1)."""

    step: float
    jitter: int
    seed: int
    stop_alpha: float
    view_samples: int
    transmittance: int
    vl_step: float
    scale: float
    single: int
    multiple: int


def gather_params(step: float, jitter: bool, seed: int, early_termination: float,
                  view_samples: int, transmittance: str, vl_step: float, scale: float,
                  single: bool = True, multiple: bool = True) -> GatherParams:
    """A :class:`GatherParams` from validated options."""
    p = GatherParams()
    p.step = float(step)
    p.jitter = int(bool(jitter))
    p.seed = int(seed)
    p.stop_alpha = float(early_termination)
    p.view_samples = int(view_samples)
    p.transmittance = TRANSMITTANCE[transmittance]
    p.vl_step = float(vl_step)
    p.scale = float(scale)
    p.single = int(bool(single))
    p.multiple = int(bool(multiple))
    return p


def render_image(medium: Medium, cam: CameraParams, lights: Lights, vls: VirtualLights,
                 maps: ShadowMaps, params: GatherParams, width: int, height: int, device: str,
                 progress=None):
    """Launch :func:`gather_kernel` over the image in row bands.

    Returns
    -------
    single, multiple : ndarray (H, W, 3) float32
        The two radiance terms (linear).
    alpha : ndarray (H, W) float32
    mean_samples : float
        Mean number of view-ray steps per pixel.
    """
    single = wp.zeros((height, width), dtype=wp.vec3, device=device)
    multiple = wp.zeros((height, width), dtype=wp.vec3, device=device)
    alpha = wp.zeros((height, width), dtype=wp.float32, device=device)
    samples = wp.zeros((height, width), dtype=wp.int32, device=device)
    gather_device(medium, cam, lights, vls, maps, params, single, multiple, alpha, samples,
                  device, progress)
    return (single.numpy().reshape(height, width, 3), multiple.numpy().reshape(height, width, 3),
            alpha.numpy(), mean_samples(samples))


def gather_device(medium: Medium, cam: CameraParams, lights: Lights, vls: VirtualLights,
                  maps: ShadowMaps, params: GatherParams, single, multiple, alpha, samples,
                  device: str, progress=None) -> None:
    """:func:`render_image` into device arrays ``(H, W)`` (no download; synchronised).

    Per band of rows, three launches: :func:`view_kernel` marches each view ray (single
    scattering, alpha) and places its ``S`` multiple-scattering positions;
    :func:`vl_kernel` (ray-marched VL transmittance) or the kernel of
    :func:`avsm_vl_kernel` sums the VLs' light at every position on a thread of its own; and
    :func:`compose_kernel` adds each pixel's ``S`` terms in order. One thread per
    *position* keeps the 32 threads of a warp on the same VL at the same time (its data
    and its AVSM texels are read once for all of them); a thread per pixel that called
    the VL sum inside its march would wait while its neighbours placed their positions
    at other steps.
    """
    height, width = single.shape
    band = BAND_PIXELS["cpu" if device == "cpu" else "cuda"]
    rows = max(1, min(height, band // max(width, 1)))
    bands = (height + rows - 1) // rows
    S = max(1, params.view_samples)
    position = wp.empty((S, rows, width), dtype=wp.vec3, device=device)
    weight = wp.empty((S, rows, width), dtype=wp.vec3, device=device)
    if params.multiple != 0 and vls.count > 0 and params.transmittance == TRANSMITTANCE["avsm"]:
        texels = texel_view(maps)
        records = wp.empty(vls.count, dtype=VLRecord, device=device)
        wp.launch(record_kernel, dim=vls.count, inputs=[vls, records], device=device)
        slots = S * (-(-rows // TILE_ROWS)) * (-(-width // TILE_COLS)) * 32
        flags, offsets, work = (wp.empty(slots, dtype=wp.int32, device=device)
                                for _ in range(3))
        active = wp.empty(1, dtype=wp.int32, device=device)
    for n, row0 in enumerate(range(0, height, rows)):
        nrows = min(rows, height - row0)
        wp.launch(view_kernel if params.single != 0 else alpha_view_kernel, dim=(nrows, width),
                  inputs=[medium, cam, lights, vls.count, params, row0, single, alpha, samples,
                          position, weight], device=device)
        if params.multiple != 0 and vls.count > 0:
            if params.transmittance == TRANSMITTANCE["avsm"]:
                # The positions with a weight, in tile order (a warp per tile of pixels).
                n_slots = S * (-(-nrows // TILE_ROWS)) * (-(-width // TILE_COLS)) * 32
                wp.launch(active_kernel, dim=n_slots, inputs=[weight, nrows, flags],
                          device=device)
                wp.utils.array_scan(flags[:n_slots], offsets[:n_slots], inclusive=False)
                wp.launch(work_kernel, dim=n_slots, inputs=[flags, offsets, n_slots, work, active],
                          device=device)
                wp.launch(avsm_vl_kernel(maps.node_count), dim=n_slots,
                          inputs=[medium, cam, maps, texels, records, vls.clamped, params, row0,
                                  nrows, work, active, position, weight], device=device,
                          block_dim=128)
            else:
                wp.launch(vl_kernel, dim=(S, nrows, width),
                          inputs=[medium, cam, vls, maps, params, row0, position, weight],
                          device=device)
        wp.launch(compose_kernel, dim=(nrows, width), inputs=[row0, S, weight, multiple],
                  device=device)
        if progress is not None and n + 1 < bands:
            wp.synchronize_device(device)
            progress((n + 1) / bands)
    wp.synchronize_device(device)


def scattered_fluence(medium: Medium, vls: VirtualLights, maps: ShadowMaps, params: GatherParams,
                      shape, extent, device: str) -> np.ndarray:
    """Fluence of the VLs' light at the points of a grid covering ``[0, extent]``.

    ``phi(x) = sum_j power_j f(w_j . -w) T(x_j, x) K_j(x)`` with ``K_j`` the point or
    spherical kernel of the module docstring (one cone sample per VL and point):
    the light that has scattered at least once, as an isotropic fluence for the
    illumination-volume convention. Returns ``(nx, ny, nz, 3)`` float32.
    """
    shape = tuple(int(n) for n in shape)
    spacing = np.asarray(extent, np.float64) / (np.asarray(shape) - 1)
    out = wp.zeros(shape, dtype=wp.vec3, device=device)
    wp.launch(fluence_kernel, dim=shape,
              inputs=[medium, vls, maps, params, wp.vec3(*spacing.astype(np.float32)), out],
              device=device)
    return out.numpy().reshape(*shape, 3)


# --- device functions ---------------------------------------------------------------------------
@wp.func
def cone_direction(axis: wp.vec3, cos_max: float, u1: float, u2: float):
    """A unit vector uniform in the cone of half-angle ``acos(cos_max)`` around ``axis``.

    ``orthonormal_basis`` completes ``axis`` exactly (up to rounding), so the sum needs
    no normalisation.
    """
    c = 1.0 - u1 * (1.0 - cos_max)
    s = wp.sqrt(wp.max(0.0, 1.0 - c * c))
    phi = 2.0 * wp.pi * u2
    t, b = orthonormal_basis(axis)
    return (s * wp.cos(phi)) * t + (s * wp.sin(phi)) * b + c * axis


@wp.func
def vl_transmittance(m: Medium, vls: VirtualLights, sm: ShadowMaps, prm: GatherParams, j: int,
                     x: wp.vec3, toward: wp.vec3, dist: float, xi: float, stop_t: float):
    """``T(x_j, x)``: ray-marched from ``x`` towards VL ``j`` or read from its AVSM."""
    if prm.transmittance == RAY_MARCHED:
        return shadow_transmittance(m, x, toward, dist, prm.vl_step, xi, stop_t)
    t = avsm_lookup(sm, vls.slot[j], x - vls.position[j], dist)
    if prm.scale != 1.0:
        t = wp.pow(wp.max(t, 0.0), prm.scale)
    return t


@wp.func
def vl_geometry(v: wp.vec3, r: float, g: float, clamped: int, state: wp.uint32):
    """Where VL ``j`` is seen from a shading point: ``v`` is the VL's centre minus the point,
    ``r`` its radius (0: a point light), ``g`` the medium's HG parameter, ``clamped`` 1 for
    a clamped VL (``r`` its clamping radius).

    Returns ``(valid, toward, dist, w, kernel, window, state)``: ``toward`` the unit
    direction to the centre at distance ``dist``, ``w`` the direction the phase functions
    see (a cone sample for a spherical light), ``kernel`` the geometry term of the module
    docstring (to be multiplied by the transmittance) and ``window`` the weight ``b`` of a
    clamped VL's compensation (0 otherwise); ``valid`` 0 for a point light at the point
    itself. The cone is not sampled for an isotropic medium (``g = 0``): there ``w`` only
    enters constant phase functions, so the light is the same and the random numbers are
    saved.
    """
    dist = wp.length(v)
    toward = wp.vec3(0.0, 0.0, 1.0)
    if dist > 0.0:
        toward = v * (1.0 / dist)
    w = toward
    kernel = float(0.0)
    window = float(0.0)
    if clamped != 0:
        kernel, window = clamped_geometry(dist, r)
    elif r > 0.0:
        ratio = wp.min(1.0, r / wp.max(dist, 1.0e-30))
        cos_max = wp.sqrt(wp.max(0.0, 1.0 - ratio * ratio))
        if g != 0.0:
            u1, state = uniform(state)
            u2, state = uniform(state)
            w = cone_direction(toward, cos_max, u1, u2)
        kernel = 2.0 * (1.0 - cos_max) / (r * r)
    elif dist > 0.0:
        kernel = 1.0 / (dist * dist)
    return int(dist > 0.0 or r > 0.0), toward, dist, w, kernel, window, state


@wp.func
def spread_phase(incident: wp.vec3, d: wp.vec3, g: float):
    """The two phase functions of a clamped VL's compensation towards the camera.

    Within the sphere the spread light has no direction to the VL, so the pair of
    scatterings is averaged over that direction ``w`` (uniformly, as the compensation's
    energy was): the VL scatters light arriving along ``incident`` into ``-w``, the
    shading point scatters that into ``-d``. Two HG lobes in a row integrate to an HG
    lobe of ``g^2`` (their Legendre coefficients multiply), so the mean of the pair is
    ``f_HG(incident . -d; g^2) / (4 pi)``: ``1 / (4 pi)^2`` for ``g = 0``.
    """
    return ISOTROPIC_PHASE * hg_phase(wp.dot(incident, -d), g * g)


@wp.func
def vl_light(m: Medium, vls: VirtualLights, sm: ShadowMaps, prm: GatherParams, x: wp.vec3,
             d: wp.vec3, receive_phase: int, xi: float, stop_t: float, state: wp.uint32):
    """Light from all VLs at ``x``: ``sum_j L_j`` per unit ``sigma_s`` (RGB).

    With ``receive_phase = 1`` the HG phase function for scattering towards ``-d`` is
    applied at ``x`` (radiance towards the camera); with 0 it is left out (fluence).
    Returns ``(sum, state)``.
    """
    acc = wp.vec3(0.0)
    for j in range(vls.count):
        pw = vls.power[j]
        if pw[0] + pw[1] + pw[2] <= 0.0:
            continue
        valid, toward, dist, w, kernel, window, state = vl_geometry(
            vls.position[j] - x, vls.radius[j], m.g, vls.clamped, state)
        if valid == 0:
            continue
        T = vl_transmittance(m, vls, sm, prm, j, x, toward, dist, xi, stop_t)
        phase = hg_phase(wp.dot(vls.direction[j], -w), m.g)
        spread = window * vls.near[j]
        if receive_phase != 0:
            phase = phase * hg_phase(wp.dot(w, d), m.g)
            spread = spread * spread_phase(vls.direction[j], d, m.g)
        else:
            spread = spread * ISOTROPIC_PHASE
        acc += (phase * T * kernel + spread) * pw
    return acc, state


# --- kernels ------------------------------------------------------------------------------------
@wp.func
def place_positions(m: Medium, o: wp.vec3, d: wp.vec3, t0: float, t1: float, xi: float,
                    k: int, dt: float, tau: float, target: float, total: float, u0: float,
                    prm: GatherParams, placed: int, r: int, c: int,
                    position: wp.array3d(dtype=wp.vec3), weight: wp.array3d(dtype=wp.vec3)):
    """Place the positions whose target optical depth falls in view step ``k`` (optical
    depth ``dt``, ``tau`` before it); returns ``(placed, tau after the step, target)``."""
    S = position.shape[0]
    while placed < S and dt > 0.0 and tau + dt >= target:
        f = (target - tau) / dt
        tx = wp.clamp(t0 + (float(k) + xi - 0.5 + f) * prm.step, t0, t1)
        x = o + tx * d
        col = lookup_color(m, sample_scalar(m.scalars, m.inv_spacing, x))
        position[placed, r, c] = x
        weight[placed, r, c] = (total / float(S) * m.albedo) * col
        placed += 1
        target = -wp.log(wp.max(1.0 - total * (float(placed) + u0) / float(S), 1.0e-30))
    return placed, tau + dt, target


@functools.cache
def _view_kernel(LEAP: bool):
    """:func:`view_kernel` (``LEAP`` False) or :func:`alpha_view_kernel` (True)."""

    @wp.kernel(module="unique")
    def view_kernel(m: Medium, cam: CameraParams, lights: Lights, vl_count: int, prm: GatherParams,
                    row0: int, single_out: wp.array2d(dtype=wp.vec3),
                    alpha: wp.array2d(dtype=wp.float32), samples: wp.array2d(dtype=wp.int32),
                    position: wp.array3d(dtype=wp.vec3), weight: wp.array3d(dtype=wp.vec3)):
        """Single scattering along one view ray and its multiple-scattering positions.

        ``wp.tid()`` is ``(row - row0, col)`` of the image (row 0 at the top). Positions in
        the volume's local frame (world units); writes the single-scattering radiance (the
        lights' units per steradian), alpha and the number of steps at ``[row, col]``, and
        for each level ``l < S`` the position ``x_t`` and its weight
        ``alpha / S * albedo * colour(x_t)`` at ``[l, row - row0, col]`` (weight 0: no
        position), and the number of samples it took (:data:`alpha_view_kernel` leaps over
        those in empty blocks). See the module docstring.
        """
        r, c = wp.tid()
        row = row0 + r
        o, d, t0, t1 = pixel_ray(cam, m.extent, row, c)
        colour = wp.vec3(0.0)
        trans = float(1.0)
        count = int(0)
        S = position.shape[0]
        placed = int(0)
        if t0 < t1:
            state = wp.rand_init(prm.seed, row * cam.width + c)
            xi = float(0.5)
            if prm.jitter != 0:
                xi = wp.randf(state)
            n = sample_count(t0, t1, prm.step, xi)
            stop_t = 1.0 - prm.stop_alpha
            start = o + t0 * d
            used = n
            if wp.static(not LEAP):
                for k in range(n):
                    p = o + (t0 + (float(k) + xi) * prm.step) * d
                    s = sample_scalar(m.scalars, m.inv_spacing, p)
                    sig = lookup_sigma_t(m, s)
                    count += 1
                    if sig > 0.0:
                        a = 1.0 - wp.exp(-sig * prm.step)
                        if prm.single != 0:
                            shadow_xi = float(0.5)
                            if prm.jitter != 0:
                                shadow_xi = wp.randf(state)
                            src = m.albedo * wp.cw_mul(lookup_color(m, s), single_scatter_light(
                                m, lights, p, d, prm.step, shadow_xi, stop_t))
                            colour += (trans * a) * src
                        trans *= 1.0 - a
                        if 1.0 - trans > prm.stop_alpha:
                            used = k + 1
                            break
            else:
                k = int(0)
                run_empty = int(0)
                run_last = int(-1)
                while k < n:
                    if k > run_last:
                        run_empty, run_last = block_run(m, start, d, prm.step, k, xi)
                    if run_empty != 0:
                        k = run_last + 1
                    else:
                        sig = lookup_sigma_t(m, sample_scalar(
                            m.scalars, m.inv_spacing, o + (t0 + (float(k) + xi) * prm.step) * d))
                        count += 1
                        k += 1
                        if sig > 0.0:
                            a = 1.0 - wp.exp(-sig * prm.step)
                            trans *= 1.0 - a
                            if 1.0 - trans > prm.stop_alpha:
                                used = k
                                k = n
            total = 1.0 - trans
            if prm.multiple != 0 and vl_count > 0 and total > 0.0:
                u0, state = uniform(state)
                tau = float(0.0)
                target = -wp.log(wp.max(1.0 - total * u0 / float(S), 1.0e-30))
                if wp.static(not LEAP):
                    for k in range(used):
                        p = o + (t0 + (float(k) + xi) * prm.step) * d
                        sig = lookup_sigma_t(m, sample_scalar(m.scalars, m.inv_spacing, p))
                        placed, tau, target = place_positions(
                            m, o, d, t0, t1, xi, k, sig * prm.step, tau, target, total, u0, prm,
                            placed, r, c, position, weight)
                        if placed == S:
                            break
                else:
                    # Empty blocks add nothing to tau: leap over them.
                    k = int(0)
                    run_empty = int(0)
                    run_last = int(-1)
                    while k < used:
                        if k > run_last:
                            run_empty, run_last = block_run(m, start, d, prm.step, k, xi)
                        if run_empty != 0:
                            k = run_last + 1
                        else:
                            p = o + (t0 + (float(k) + xi) * prm.step) * d
                            sig = lookup_sigma_t(m, sample_scalar(m.scalars, m.inv_spacing, p))
                            placed, tau, target = place_positions(
                                m, o, d, t0, t1, xi, k, sig * prm.step, tau, target, total, u0,
                                prm, placed, r, c, position, weight)
                            k += 1
                            if placed == S:
                                k = used
        for level in range(placed, S):
            weight[level, r, c] = wp.vec3(0.0)
        single_out[row, c] = colour
        alpha[row, c] = 1.0 - trans
        samples[row, c] = count

    return view_kernel


#: Single scattering, alpha and the multiple-scattering positions of each view ray.
view_kernel = _view_kernel(False)
#: :func:`view_kernel` without the single term, leaping over empty blocks: alpha and the
#: same positions (tested). With the single term the lockstep loop of ``view_kernel`` is
#: faster: threads that leap fall out of step with their warp's shadow rays, and the
#: leaping code's registers slowed the single term by a fifth (H100, 800^2 CT: multiple
#: only 4.4 -> 2.6 ms).
alpha_view_kernel = _view_kernel(True)


@wp.kernel(module_options={"fast_math": True}, module="unique")
def vl_kernel(m: Medium, cam: CameraParams, vls: VirtualLights, sm: ShadowMaps,
              prm: GatherParams, row0: int, position: wp.array3d(dtype=wp.vec3),
              weight: wp.array3d(dtype=wp.vec3)):
    """The VLs' light scattered towards the camera at one position of a view ray.

    ``wp.tid()`` is ``(level, row - row0, col)``; replaces the position's weight (see
    :func:`view_kernel`) by ``weight * sum_j L_j`` (radiance, the lights' units per
    steradian). Each position draws its VSL cone samples from a stream of its own.
    Compiled with fast math (approximate division, square root, sine and cosine on the
    GPU, relative errors ~1e-6): the sum over thousands of VLs is bound by arithmetic.
    """
    level, r, c = wp.tid()
    w = weight[level, r, c]
    if w[0] + w[1] + w[2] > 0.0:
        row = row0 + r
        o, d, t0, t1 = pixel_ray(cam, m.extent, row, c)
        S = weight.shape[0]
        state = wp.rand_init(prm.seed ^ 0x5F3759DF, (row * cam.width + c) * S + level)
        shadow_xi = float(0.5)
        if prm.jitter != 0:
            shadow_xi, state = uniform(state)
        light, state = vl_light(m, vls, sm, prm, position[level, r, c], d, 1, shadow_xi,
                                1.0 - prm.stop_alpha, state)
        weight[level, r, c] = wp.cw_mul(w, light)


@wp.func
def tile_order(i: int, S: int, nrows: int, W: int):
    """Position ``(level, r, c)`` of flat index ``i`` in tile order: 32 consecutive indices
    cover a tile of ``TILE_ROWS x TILE_COLS`` pixels of one level; ``inside`` is 0 where the
    tile overhangs the band."""
    tiles_x = (W + TILE_COLS - 1) / TILE_COLS
    tiles = tiles_x * ((nrows + TILE_ROWS - 1) / TILE_ROWS)
    lane = i % 32
    level = (i / 32) / tiles
    tile = (i / 32) % tiles
    r = (tile / tiles_x) * TILE_ROWS + lane / TILE_COLS
    c = (tile % tiles_x) * TILE_COLS + lane % TILE_COLS
    return level, r, c, int(level < S and r < nrows and c < W)


@wp.kernel
def active_kernel(weight: wp.array3d(dtype=wp.vec3), nrows: int, flags: wp.array(dtype=wp.int32)):
    """Flag slot ``wp.tid()`` (:func:`tile_order`) if its position has a weight."""
    i = wp.tid()
    level, r, c, inside = tile_order(i, weight.shape[0], nrows, weight.shape[2])
    flag = int(0)
    if inside != 0:
        w = weight[level, r, c]
        if w[0] + w[1] + w[2] > 0.0:
            flag = 1
    flags[i] = flag


@wp.kernel
def work_kernel(flags: wp.array(dtype=wp.int32), offsets: wp.array(dtype=wp.int32), n: int,
                work: wp.array(dtype=wp.int32), active: wp.array(dtype=wp.int32)):
    """Compact the flagged slots into ``work`` (exclusive ``offsets``); ``active[0]`` is
    their number."""
    i = wp.tid()
    if flags[i] != 0:
        work[offsets[i]] = i
    if i == n - 1:
        active[0] = offsets[i] + flags[i]


@functools.cache
def avsm_vl_kernel(count: int):
    """:func:`vl_kernel` for VL transmittance from AVSMs of ``count`` nodes, made on first use.

    ``wp.tid()`` indexes ``work``: the :func:`tile_order` slots of the band's positions
    with a weight (:func:`active_kernel`, :func:`work_kernel`), ``active[0]`` of them; the VLs come as ``records``
    (:func:`record_kernel`) and the maps also as ``texels``
    (:func:`~vtkillum.core.many_lights.avsm.texel_view`). What makes it 3.8x faster than
    :func:`vl_kernel` with AVSMs (1006 VLs, 800^2, 8 positions per ray, the CT phantom on
    an H100: 102 -> 27 ms, same values):

    * no ray-marching code: the unused branch of ``vl_transmittance`` had raised the
      kernel to 92 registers (25 % occupancy);
    * the counting texel lookup of :func:`~vtkillum.core.many_lights.avsm.lookup_function`,
      each texel's depths read at constant offsets from one address;
    * compact tiles: the 32 positions of a warp are closer together than a row of 32
      pixels, so they read fewer distinct texels of each VL's map at a time; and only the
      positions with a weight, so no warp runs half empty at the silhouette;
    * a VL's data in one record, read at constant offsets from one address;
    * in an isotropic medium, no cone sample and constant phase functions;
    * blocks of 128 threads (the launch in :func:`gather_device`).
    """
    lookup = lookup_function(count)

    @wp.kernel(module_options={"fast_math": True}, module="unique")
    def kernel(m: Medium, cam: CameraParams, sm: ShadowMaps, texels: wp.array(dtype=Any),
               records: wp.array(dtype=VLRecord), clamped: int, prm: GatherParams, row0: int,
               nrows: int,
               work: wp.array(dtype=wp.int32), active: wp.array(dtype=wp.int32),
               position: wp.array3d(dtype=wp.vec3), weight: wp.array3d(dtype=wp.vec3)):
        i = wp.tid()
        if i >= active[0]:
            return
        S = weight.shape[0]
        level, r, c, inside = tile_order(work[i], S, nrows, weight.shape[2])
        wgt = weight[level, r, c]
        row = row0 + r
        o, d, t0, t1 = pixel_ray(cam, m.extent, row, c)
        state = wp.rand_init(prm.seed ^ 0x5F3759DF, (row * cam.width + c) * S + level)
        if prm.jitter != 0:
            xi, state = uniform(state)  # the ray-marched mode's shadow offset: same stream
        x = position[level, r, c]
        acc = wp.vec3(0.0)
        for j in range(records.shape[0]):
            rec = records[j]
            pw = wp.vec3(rec[8], rec[9], rec[10])
            if pw[0] + pw[1] + pw[2] <= 0.0:
                continue
            v = wp.vec3(rec[0], rec[1], rec[2]) - x
            valid, toward, dist, w, kern, window, state = vl_geometry(v, rec[3], m.g, clamped,
                                                                      state)
            if valid == 0:
                continue
            T = lookup(sm, texels, int(rec[7]), -v, dist)
            if prm.scale != 1.0:
                T = wp.pow(wp.max(T, 0.0), prm.scale)
            phase = ISOTROPIC_PHASE * ISOTROPIC_PHASE
            if m.g != 0.0:
                phase = (hg_phase(wp.dot(wp.vec3(rec[4], rec[5], rec[6]), -w), m.g)
                         * hg_phase(wp.dot(w, d), m.g))
            spread = window * rec[11]
            if window > 0.0:
                spread = spread * spread_phase(wp.vec3(rec[4], rec[5], rec[6]), d, m.g)
            acc += (phase * T * kern + spread) * pw
        weight[level, r, c] = wp.cw_mul(wgt, acc)

    return kernel


@wp.kernel
def compose_kernel(row0: int, S: int, terms: wp.array3d(dtype=wp.vec3),
                   multiple_out: wp.array2d(dtype=wp.vec3)):
    """Sum a pixel's ``S`` multiple-scattering terms (in level order: reproducible)."""
    r, c = wp.tid()
    acc = wp.vec3(0.0)
    for level in range(S):
        acc += terms[level, r, c]
    multiple_out[row0 + r, c] = acc


@wp.kernel
def fluence_kernel(m: Medium, vls: VirtualLights, sm: ShadowMaps, prm: GatherParams,
                   spacing: wp.vec3, out: wp.array3d(dtype=wp.vec3)):
    """Scattered fluence of the VLs at one grid point.

    ``wp.tid()`` is the grid point ``(i, j, k)`` (x, y, z) at local position
    ``(i, j, k) * spacing``; writes RGB fluence (irradiance units).
    """
    i, j, k = wp.tid()
    x = grid_point(i, j, k, spacing)
    state = wp.rand_init(prm.seed, (i * out.shape[1] + j) * out.shape[2] + k)
    light, state = vl_light(m, vls, sm, prm, x, wp.vec3(0.0, 0.0, 1.0), 0, 0.5, 0.0, state)
    out[i, j, k] = light
