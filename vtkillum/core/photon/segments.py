"""View rays in segments (Jönsson et al. 2012, section 4.3.2, eq. 4).

Each pixel's ray through the volume's box is marched like the ray caster's
(:mod:`vtkillum.core.raymarch`: samples at ``t0 + (k + ξ) Δ``, ``ξ`` a per-pixel jitter)
and its samples are split into ``V_n`` segments of (nearly) equal sample counts: segment
``i`` holds samples ``[i n / V_n, (i + 1) n / V_n)``. A segment stores its radiance
``L_i`` (premultiplied, as seen from its front), its transmittance ``T_i`` and its
Historygram; the pixel is the composite of eq. (4),

    L = Σ_i (Π_{j<i} T_j) L_i ,    alpha = 1 - Π_i T_i ,

so a segment can be recomputed on its own. Per sample of extinction σt the source is
integrated exactly over the step, as in the ray caster:
``L_i += T (1 - e^{-σt Δ}) Λ color(s) ⊙ [direct + L_photon]`` with ``L_photon`` the
photon estimate of eq. (8) (:func:`~vtkillum.core.photon.hashgrid.gather_radiance`) and
``direct = Σ_l p(θ_l) T_l E_l`` by shadow rays (``direct`` mode "exact", with the photons
standing for the scattered light only) or 0 (mode "photons": the paper's setting), and
``L_photon`` from :func:`~vtkillum.core.photon.density.photon_radiance`.

Historygrams of a segment: extinction bins (``hist``) of every sample it marched
(transparent ones included: an edit can make them visible), of the kernel cubes behind
``σ̄t`` where the photon estimate was evaluated, and, with exact direct light, of every
shadow-ray sample; colour bins (``chist``) of the samples where it scattered (σt > 0). The photon estimate depends on photons, whose changes are caught by
the spatial Historygram (:mod:`~vtkillum.core.photon.historygram`).

Occlusion: a segment whose prefix transmittance ``Π_{j<i} T_j`` has dropped below
``1 - early_termination`` is not computed (state 0); the composite computes it when an
edit makes it visible again, so an incremental update takes the same decisions as a
full recompute. A segment itself stops marching once its own transmittance drops below
that threshold.
"""

from __future__ import annotations

import warp as wp

from vtkillum.core.device import init_warp
from vtkillum.core.photon.density import MeanExtinction, kernel_bins, photon_radiance
from vtkillum.core.photon.hashgrid import PhotonGrid
from vtkillum.core.photon.historygram import axis_bits, data_bin
from vtkillum.core.photon.material import SurfaceParams, scattering, surface_normal
from vtkillum.core.raymarch import pixel_ray, sample_count
from vtkillum.core.warp_common import (
    CameraParams,
    Lights,
    Medium,
    light_incidence,
    lookup_color,
    lookup_sigma_t,
    ray_box,
    sample_scalar,
)

init_warp()

#: Segment states.
NOT_COMPUTED = wp.constant(0)
COMPUTED = wp.constant(1)


@wp.struct
class ViewParams:
    """Sampling of the view rays: ``segments`` (``V_n``), ``step`` (world units), ``jitter``
    (0/1), ``seed`` (pixel jitter), ``shadow_seed`` (shadow-ray jitter), ``stop_t`` (``1 -
    early_termination``), ``direct`` (1: shadow rays to the lights), ``bin_lo``,
    ``bin_scale`` (data bins of the Historygrams)."""

    segments: int
    step: float
    jitter: int
    seed: int
    shadow_seed: int
    stop_t: float
    direct: int
    bin_lo: float
    bin_scale: float


@wp.func
def shadow_march(m: Medium, p: wp.vec3, w: wp.vec3, dist: float, step: float, xi: float,
                 stop_t: float, lo: float, scale: float):
    """Transmittance from ``p`` along ``w`` to the box exit or ``dist`` and the data bins used.

    The march of :func:`vtkillum.core.warp_common.shadow_transmittance` (equal steps no
    longer than ``step`` sampled at fraction ``xi``, early stop below ``stop_t``), which
    also ORs the bin of every value it samples into a Historygram. Returns ``(T, H)``.
    """
    tt = ray_box(p, w, m.extent)
    length = wp.min(tt[1], dist)
    hist = wp.uint64(0)
    if length <= 0.0:
        return 1.0, hist
    n = int(wp.ceil(length / step))
    h = length / float(n)
    tau = float(0.0)
    for k in range(n):
        s = sample_scalar(m.scalars, m.inv_spacing, p + ((float(k) + xi) * h) * w)
        hist = hist | data_bin(s, lo, scale)
        tau += lookup_sigma_t(m, s)
        if stop_t > 0.0:
            if wp.exp(-tau * h) < stop_t:
                break
    return wp.exp(-tau * h), hist


@wp.func
def ray_setup(m: Medium, cam: CameraParams, vp: ViewParams, row: int, col: int):
    """Origin, direction, entry ``t0``, jitter ``ξ`` and sample count of pixel ``(row, col)``."""
    o, d, t0, t1 = pixel_ray(cam, m.extent, row, col)
    xi = float(0.5)
    n = int(0)
    if t0 < t1:
        if vp.jitter != 0:
            state = wp.rand_init(vp.seed, row * cam.width + col)
            xi = wp.randf(state)
        n = sample_count(t0, t1, vp.step, xi)
    return o, d, t0, xi, n


@wp.func
def segment_samples(n: int, segments: int, i: int):
    """Sample indices ``[k0, k1)`` of segment ``i`` of a ray with ``n`` samples."""
    return (i * n) // segments, ((i + 1) * n) // segments


@wp.func
def compute_segment(m: Medium, cam: CameraParams, lights: Lights, grid: PhotonGrid,
                    me: MeanExtinction, sp: SurfaceParams, vp: ViewParams, row: int, col: int,
                    i: int):
    """Radiance, transmittance and Historygrams (extinction, colour) of segment ``i`` of
    pixel ``(row, col)``."""
    o, d, t0, xi, n = ray_setup(m, cam, vp, row, col)
    k0, k1 = segment_samples(n, vp.segments, i)
    state = wp.rand_init(vp.shadow_seed, (row * cam.width + col) * vp.segments + i)
    rad = wp.vec3(0.0)
    trans = float(1.0)
    hist = wp.uint64(0)
    chist = wp.uint64(0)
    for k in range(k0, k1):
        p = o + (t0 + (float(k) + xi) * vp.step) * d
        s = sample_scalar(m.scalars, m.inv_spacing, p)
        hist = hist | data_bin(s, vp.bin_lo, vp.bin_scale)
        sig = lookup_sigma_t(m, s)
        if sig > 0.0:
            chist = chist | data_bin(s, vp.bin_lo, vp.bin_scale)
            a = 1.0 - wp.exp(-sig * vp.step)
            surf, normal = surface_normal(m, sp, p, s)
            light = photon_radiance(grid, me, p, -d, m.g, surf, normal, sp)
            if grid.count > 0:
                hist = hist | kernel_bins(me, p)
            if vp.direct != 0:
                sxi = float(0.5)
                if vp.jitter != 0:
                    sxi = wp.randf(state)
                for li in range(lights.count):
                    wl, dist, e = light_incidence(lights, li, p)
                    t_l, h_l = shadow_march(m, p, wl, dist, vp.step, sxi, vp.stop_t,
                                            vp.bin_lo, vp.bin_scale)
                    hist = hist | h_l
                    light += (scattering(-wl, -d, m.g, surf, normal, sp) * t_l) * e
            rad += (trans * a * m.albedo) * wp.cw_mul(lookup_color(m, s), light)
            trans *= 1.0 - a
            if trans < vp.stop_t:
                break
    return rad, trans, hist, chist


@wp.kernel
def composite_kernel(m: Medium, cam: CameraParams, lights: Lights, grid: PhotonGrid,
                     me: MeanExtinction, sp: SurfaceParams, vp: ViewParams, seg_rad: wp.array(dtype=wp.vec3),
                     seg_t: wp.array(dtype=wp.float32), seg_hist: wp.array(dtype=wp.uint64),
                     seg_chist: wp.array(dtype=wp.uint64), seg_state: wp.array(dtype=wp.int32),
                     radiance: wp.array2d(dtype=wp.vec3),
                     alpha: wp.array2d(dtype=wp.float32), computed: wp.array(dtype=wp.int32)):
    """Composite a pixel's segments front to back (eq. 4), computing the visible ones that
    are not stored yet and marking occluded ones as not computed.

    ``wp.tid()`` = ``(row, col)``; segment ``i`` of the pixel is entry
    ``(row * width + col) * V_n + i``. Writes premultiplied radiance and alpha; counts the
    segments computed here.
    """
    row, col = wp.tid()
    base = (row * cam.width + col) * vp.segments
    prefix = float(1.0)
    total = wp.vec3(0.0)
    for i in range(vp.segments):
        idx = base + i
        if prefix < vp.stop_t:
            seg_state[idx] = NOT_COMPUTED
            continue
        if seg_state[idx] == NOT_COMPUTED:
            r, t, h, c = compute_segment(m, cam, lights, grid, me, sp, vp, row, col, i)
            seg_rad[idx] = r
            seg_t[idx] = t
            seg_hist[idx] = h
            seg_chist[idx] = c
            seg_state[idx] = COMPUTED
            wp.atomic_add(computed, 0, 1)
        total += prefix * seg_rad[idx]
        prefix *= seg_t[idx]
    radiance[row, col] = total
    alpha[row, col] = 1.0 - prefix


@wp.kernel
def segment_query_kernel(m: Medium, cam: CameraParams, vp: ViewParams,
                         seg_hist: wp.array(dtype=wp.uint64), seg_chist: wp.array(dtype=wp.uint64),
                         seg_state: wp.array(dtype=wp.int32), query: wp.uint64,
                         cquery: wp.uint64, spatial: wp.array(dtype=wp.uint64),
                         use_spatial: int, spatial_scale: wp.vec3, radius: float,
                         flags: wp.array(dtype=wp.int32)):
    """Flag the stored segments an edit invalidates.

    ``wp.tid()`` indexes segments (``pixel * V_n + i``). A computed segment is invalid when
    its Historygrams meet the query masks (extinction ``query``, colour ``cquery``), or (``use_spatial``) when its bounding box grown
    by the photon ``radius`` meets set bits of the spatial Historygram on all three axes
    (``spatial[a]``: 64 bins over ``[0, extent_a]``, ``spatial_scale = 64 / extent``).
    """
    idx = wp.tid()
    flags[idx] = 0
    if seg_state[idx] != COMPUTED:
        return
    if ((seg_hist[idx] & query) | (seg_chist[idx] & cquery)) != wp.uint64(0):
        flags[idx] = 1
        return
    if use_spatial == 0:
        return
    pix = idx // vp.segments
    i = idx - pix * vp.segments
    row = pix // cam.width
    col = pix - row * cam.width
    o, d, t0, xi, n = ray_setup(m, cam, vp, row, col)
    k0, k1 = segment_samples(n, vp.segments, i)
    if k1 <= k0:
        return
    pa = o + (t0 + (float(k0) + xi) * vp.step) * d
    pb = o + (t0 + (float(k1 - 1) + xi) * vp.step) * d
    lo = wp.min(pa, pb) - wp.vec3(radius)
    hi = wp.max(pa, pb) + wp.vec3(radius)
    if (axis_bits(lo[0], hi[0], 0.0, spatial_scale[0]) & spatial[0]) == wp.uint64(0):
        return
    if (axis_bits(lo[1], hi[1], 0.0, spatial_scale[1]) & spatial[1]) == wp.uint64(0):
        return
    if (axis_bits(lo[2], hi[2], 0.0, spatial_scale[2]) & spatial[2]) == wp.uint64(0):
        return
    flags[idx] = 1


@wp.kernel
def recompute_kernel(m: Medium, cam: CameraParams, lights: Lights, grid: PhotonGrid,
                     me: MeanExtinction, sp: SurfaceParams, vp: ViewParams, work: wp.array(dtype=wp.int32),
                     seg_rad: wp.array(dtype=wp.vec3), seg_t: wp.array(dtype=wp.float32),
                     seg_hist: wp.array(dtype=wp.uint64), seg_chist: wp.array(dtype=wp.uint64)):
    """``wp.tid()`` indexes the list of invalid segments (entries ``pixel * V_n + i``):
    recompute each one independently (the paper's load-balanced update)."""
    w = wp.tid()
    idx = work[w]
    pix = idx // vp.segments
    i = idx - pix * vp.segments
    row = pix // cam.width
    col = pix - row * cam.width
    r, t, h, c = compute_segment(m, cam, lights, grid, me, sp, vp, row, col, i)
    seg_rad[idx] = r
    seg_t[idx] = t
    seg_hist[idx] = h
    seg_chist[idx] = c
