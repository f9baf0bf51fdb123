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

import numpy as np
import warp as wp

from vtkillum.core.device import init_warp
from vtkillum.core.photon.density import MeanExtinction, kernel_bins, photon_radiance
from vtkillum.core.photon.hashgrid import PhotonGrid
from vtkillum.core.photon.historygram import axis_bits, data_bin
from vtkillum.core.photon.material import SurfaceParams, scattering, surface_normal
from vtkillum.core.photon.storage import (
    exclusive_scan,
    gather_int_kernel,
    scan_total_kernel,
    select,
)
from vtkillum.core.raymarch import pixel_ray, sample_count
from vtkillum.core.warp_common import (
    CameraParams,
    Lights,
    Medium,
    capped_kernel,
    light_incidence,
    lookup_color,
    lookup_sigma_t,
    ray_box,
    sample_scalar,
)

init_warp()

#: Parts of the per-segment launch on the CPU (progress reports in between).
CPU_PROGRESS_STEPS = 20
#: Devices (name prefixes) on which photon-only segments are gathered one thread per
#: sample (:func:`composite_segments`).
SAMPLE_PARALLEL_DEVICES = ("cuda",)
#: Samples whose light is held at once by the per-sample gather (16 bytes each: the light
#: and the sample's work item).
SAMPLES_PER_BATCH = 1 << 27
#: Register cap and block size of the per-sample gather on CUDA: the kernel waits on
#: memory, and fewer registers let more warps wait together than the 118 it takes uncapped
#: (H100, Cornell box 512², before the isotropic phase: 55 ms uncapped, 40.5 with 64, 38.6
#: with 48; after it: 27.3 with 64, 26.4 with 48, 25.2 with 40; blocks of 128 or 256
#: alike).
SAMPLE_REGISTERS = 40
SAMPLE_BLOCK = 256
#: Which samples a warp of the per-sample gather takes: ``"ray"``, 32 consecutive samples of
#: one segment; ``"across"``, sample ``k`` of 32 consecutive work items (neighbouring
#: pixels of a tile: their spheres meet the same hash rows), warps padded to the longest
#: of the 32 (H100, Cornell box 512²: gather kernel 24.7 -> 22.6 ms, shading 2.5 -> 2.2 ms,
#: the same bits). "across" needs one more wait (for the number of warps), so batches of
#: fewer than :data:`ACROSS_MIN_SAMPLES` samples (the few segments of an edit) go "ray".
SAMPLE_ORDER = "across"
ACROSS_MIN_SAMPLES = 1 << 23
#: A batch whose padded warps would hold more than this many times its samples (work items
#: of very different lengths side by side) goes "ray" (bounds the light buffer).
ACROSS_MAX_PADDING = 2.0
#: Register cap of :func:`shade_segment_kernel` on CUDA (0: none).
SHADE_REGISTERS = 0

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


@wp.func
def segment_transmittance(m: Medium, cam: CameraParams, vp: ViewParams, row: int, col: int,
                          i: int):
    """Transmittance of segment ``i`` of pixel ``(row, col)``: what :func:`compute_segment`
    returns as ``T`` (the same samples and products, the same early stop), without the light;
    and the number of samples :func:`compute_segment` marches."""
    o, d, t0, xi, n = ray_setup(m, cam, vp, row, col)
    k0, k1 = segment_samples(n, vp.segments, i)
    trans = float(1.0)
    k_end = k1
    for k in range(k0, k1):
        p = o + (t0 + (float(k) + xi) * vp.step) * d
        s = sample_scalar(m.scalars, m.inv_spacing, p)
        sig = lookup_sigma_t(m, s)
        if sig > 0.0:
            a = 1.0 - wp.exp(-sig * vp.step)
            trans *= 1.0 - a
            if trans < vp.stop_t:
                k_end = k + 1
                break
    return trans, k_end - k0


@wp.kernel
def segment_transmittance_kernel(m: Medium, cam: CameraParams, vp: ViewParams,
                                 seg_t: wp.array(dtype=wp.float32),
                                 seg_state: wp.array(dtype=wp.int32),
                                 trans: wp.array(dtype=wp.float32),
                                 length: wp.array(dtype=wp.int32)):
    """``wp.tid()`` = segment entry ``pixel * V_n + i``: its transmittance (stored, or
    :func:`segment_transmittance` when not computed, with the samples it marches), what
    :func:`visible_segments_kernel` takes for it -- every segment at once, occluded or not."""
    idx = wp.tid()
    if seg_state[idx] == NOT_COMPUTED:
        row, col, i = segment_of(cam, vp, idx)
        t, n = segment_transmittance(m, cam, vp, row, col, i)
        trans[idx] = t
        length[idx] = n
    else:
        trans[idx] = seg_t[idx]
        length[idx] = 0


@wp.kernel
def visible_from_kernel(vp: ViewParams, width: int, trans: wp.array(dtype=wp.float32),
                        length: wp.array(dtype=wp.int32), seg_state: wp.array(dtype=wp.int32),
                        flags: wp.array(dtype=wp.int32), seg_len: wp.array(dtype=wp.int32)):
    """:func:`visible_segments_kernel` from the transmittances and lengths of
    :func:`segment_transmittance_kernel` (the same products in the same order)."""
    row, col = wp.tid()
    base = (row * width + col) * vp.segments
    prefix = float(1.0)
    for i in range(vp.segments):
        if prefix < vp.stop_t:
            break
        idx = base + i
        if seg_state[idx] == NOT_COMPUTED:
            flags[idx] = 1
            seg_len[idx] = length[idx]
        prefix *= trans[idx]


@wp.kernel
def visible_segments_kernel(m: Medium, cam: CameraParams, vp: ViewParams,
                            seg_t: wp.array(dtype=wp.float32),
                            seg_state: wp.array(dtype=wp.int32), flags: wp.array(dtype=wp.int32),
                            seg_len: wp.array(dtype=wp.int32)):
    """Flag the segments that :func:`composite_kernel` would compute: not stored yet and not
    occluded (prefix transmittance ``>= stop_t``), the prefix taking the stored ``T`` of
    computed segments and :func:`segment_transmittance` of the others; ``seg_len``: the
    samples each flagged segment marches.

    ``wp.tid()`` = ``(row, col)``; ``flags``, ``seg_len`` (zeroed) indexed ``pixel * V_n + i``.
    """
    row, col = wp.tid()
    base = (row * cam.width + col) * vp.segments
    prefix = float(1.0)
    for i in range(vp.segments):
        if prefix < vp.stop_t:
            break
        idx = base + i
        if seg_state[idx] == NOT_COMPUTED:
            flags[idx] = 1
            t, n = segment_transmittance(m, cam, vp, row, col, i)
            seg_len[idx] = n
            prefix *= t
        else:
            prefix *= seg_t[idx]


@wp.func
def tiled_segment(t: int, tiles_x: int, tiles: int):
    """Segment ``i`` and pixel ``(row, col)`` of thread ``t`` in the tile order: ``V_n``
    images of ``tiles`` tiles of 8×4 pixels (``tiles_x`` per row of tiles), 32 threads a
    tile."""
    lane = t % 32
    tile = t // 32
    i = tile // tiles
    tile = tile - i * tiles
    ty = tile // tiles_x
    return i, ty * 4 + lane // 8, (tile - ty * tiles_x) * 8 + lane % 8


@wp.kernel
def compute_flagged_kernel(m: Medium, cam: CameraParams, lights: Lights, grid: PhotonGrid,
                           me: MeanExtinction, sp: SurfaceParams, vp: ViewParams,
                           tiles_x: int, tiles: int, flags: wp.array(dtype=wp.int32),
                           seg_rad: wp.array(dtype=wp.vec3), seg_t: wp.array(dtype=wp.float32),
                           seg_hist: wp.array(dtype=wp.uint64),
                           seg_chist: wp.array(dtype=wp.uint64),
                           seg_state: wp.array(dtype=wp.int32),
                           computed: wp.array(dtype=wp.int32), first: int):
    """Compute every flagged segment, each on its own thread (stored as computed; counted).

    ``first + wp.tid()`` runs over ``V_n`` images of ``tiles`` tiles of 8×4 pixels
    (``tiles_x`` per row of tiles), 32 threads a tile: a warp marches one segment of 32
    neighbouring pixels, whose rays and photon queries are alike.
    """
    t = wp.tid() + first
    i, row, col = tiled_segment(t, tiles_x, tiles)
    if row >= cam.height or col >= cam.width:
        return
    idx = (row * cam.width + col) * vp.segments + i
    if flags[idx] == 0:
        return
    r, tr, h, c = compute_segment(m, cam, lights, grid, me, sp, vp, row, col, i)
    seg_rad[idx] = r
    seg_t[idx] = tr
    seg_hist[idx] = h
    seg_chist[idx] = c
    seg_state[idx] = COMPUTED
    wp.atomic_add(computed, 0, 1)


def new_segments(n: int, device: str) -> dict:
    """Storage of ``n`` segments, none computed: radiance ``rad``, transmittance ``t``,
    Historygrams ``hist`` and ``chist``, ``state`` and the ``samples`` their march took
    (-1: not kept)."""
    return {"rad": wp.zeros(n, dtype=wp.vec3, device=device),
            "t": wp.ones(n, dtype=wp.float32, device=device),
            "hist": wp.zeros(n, dtype=wp.uint64, device=device),
            "chist": wp.zeros(n, dtype=wp.uint64, device=device),
            "state": wp.zeros(n, dtype=wp.int32, device=device),
            "samples": wp.full(n, -1, dtype=wp.int32, device=device)}


def composite_segments(m: Medium, cam: CameraParams, lights: Lights, grid: PhotonGrid,
                       me: MeanExtinction, sp: SurfaceParams, vp: ViewParams, seg: dict,
                       width: int, height: int, device: str, progress=None,
                       find_visible: bool = True):
    """Compute the visible segments not stored yet, then composite every pixel (eq. 4).

    The result is :func:`composite_kernel`'s, which computes them in turn per pixel; here
    :func:`visible_segments_kernel` finds them first (the transmittance alone is cheap), so
    that the work spreads over many threads:

    * photons only (``vp.direct == 0``, the paper's setting), on devices in
      :data:`SAMPLE_PARALLEL_DEVICES`: one thread per **sample** gathers its photon
      radiance (:func:`sample_light_kernel`; a warp takes 32 neighbouring samples of one
      ray, whose spheres overlap), then one thread per segment composes them in order
      (:func:`shade_segment_kernel`, the same arithmetic as :func:`compute_segment`, so
      the segments are the same bits). A sample in a dense photon layer (thousands of
      photons in reach next to a point light) no longer holds up the hundreds of samples
      its segment has after it;
    * otherwise one thread per segment (:func:`compute_flagged_kernel`), tiles of 8×4
      pixels per warp.

    On the CPU the per-segment launch runs in :data:`CPU_PROGRESS_STEPS` parts, with
    ``progress(fraction)`` after each (a long gather reports, and Ctrl-C stops it between
    parts). ``seg``: the segment arrays (:func:`new_segments`). Returns
    ``(radiance (height, width) vec3, alpha (height, width) float32, computed (1,) int32)``
    on the device.

    ``find_visible=False`` goes straight to the composite: for segments composited before
    whose transmittances did not change since (no σt edit), every visible one is stored
    and the search would find none (:func:`composite_kernel` would still compute any).
    """
    h, w = int(height), int(width)
    n_seg = h * w * vp.segments
    computed = wp.zeros(1, dtype=wp.int32, device=device)
    tiles_x = (w + 7) // 8
    tiles = tiles_x * ((h + 3) // 4)
    if find_visible:
        flags = wp.zeros(n_seg, dtype=wp.int32, device=device)
        seg_len = wp.zeros(n_seg, dtype=wp.int32, device=device)
        if per_sample(vp, device):
            # Every segment's transmittance in parallel, then the prefix products per pixel
            # (a thread per pixel marching its segments one after the other leaves the GPU
            # mostly idle; marching the occluded ones too costs less).
            trans = wp.empty(n_seg, dtype=wp.float32, device=device)
            length = wp.empty(n_seg, dtype=wp.int32, device=device)
            wp.launch(segment_transmittance_kernel, dim=n_seg,
                      inputs=[m, cam, vp, seg["t"], seg["state"], trans, length],
                      device=device)
            wp.launch(visible_from_kernel, dim=(h, w),
                      inputs=[vp, w, trans, length, seg["state"], flags, seg_len],
                      device=device)
        else:
            wp.launch(visible_segments_kernel, dim=(h, w),
                      inputs=[m, cam, vp, seg["t"], seg["state"], flags, seg_len],
                      device=device)
    if find_visible and per_sample(vp, device):
        _sample_parallel(m, cam, lights, grid, me, sp, vp, seg, flags, seg_len, tiles_x, tiles,
                         computed, device)
    elif find_visible:
        total = vp.segments * tiles * 32
        parts = 1 if wp.get_device(device).is_cuda else CPU_PROGRESS_STEPS
        step = max(32, -(-total // parts // 32) * 32)  # whole warps
        for first in range(0, total, step):
            wp.launch(compute_flagged_kernel, dim=min(step, total - first),
                      inputs=[m, cam, lights, grid, me, sp, vp, tiles_x, tiles, flags,
                              seg["rad"], seg["t"], seg["hist"], seg["chist"], seg["state"],
                              computed, first],
                      device=device)
            if progress is not None:
                progress(min(first + step, total) / total)
    radiance = wp.empty((h, w), dtype=wp.vec3, device=device)  # every pixel is written
    alpha = wp.empty((h, w), dtype=wp.float32, device=device)
    wp.launch(composite_kernel, dim=(h, w),
              inputs=[m, cam, lights, grid, me, sp, vp, seg["rad"], seg["t"], seg["hist"],
                      seg["chist"], seg["state"], seg["samples"], radiance, alpha, computed],
              device=device)
    return radiance, alpha, computed


def _sample_parallel(m, cam, lights, grid, me, sp, vp, seg, flags, seg_len, tiles_x, tiles,
                     computed, device) -> None:
    """The flagged segments by :func:`sample_light_kernel` and :func:`shade_segment_kernel`
    (see :func:`composite_segments`), in batches of at most :data:`SAMPLES_PER_BATCH`
    samples."""
    tflag, tidx = tiled_flags(cam, vp, tiles_x, tiles, flags, device)
    # One wait for both counts: the flagged segments and their samples (seg_len is zero
    # for the others).
    n_work, total = sums(tflag, seg_len, device)
    if n_work == 0:
        return
    work, lengths = tiled_work(tflag, tidx, seg_len, n_work, device)
    gather_work(m, cam, grid, me, sp, vp, seg, work, lengths, device, total)
    wp.launch(add_count_kernel, dim=1, inputs=[computed, n_work], device=device)


def tiled_flags(cam, vp, tiles_x: int, tiles: int, flags: wp.array, device: str):
    """``flags`` (indexed like the segments) in the tile order of
    :func:`compute_flagged_kernel` -- a warp's 32 entries are one segment of the 8×4 pixels
    of a tile, whose rays sample neighbouring places -- with each entry's segment:
    ``(tflag, tidx)``."""
    n_tiled = vp.segments * tiles * 32
    tflag = wp.empty(n_tiled, dtype=wp.int32, device=device)
    tidx = wp.empty(n_tiled, dtype=wp.int32, device=device)
    wp.launch(tiled_flags_kernel, dim=n_tiled,
              inputs=[cam, vp, tiles_x, tiles, flags, tflag, tidx], device=device)
    return tflag, tidx


def tiled_work(tflag, tidx, seg_len, n_work: int, device: str):
    """The ``n_work`` flagged segments of :func:`tiled_flags`, tile by tile, and their samples
    (``seg_len`` is indexed like the segments): ``(work, lengths)``."""
    _, work = select(tflag, tidx, device, n_work)
    lengths = wp.empty(n_work, dtype=wp.int32, device=device)
    wp.launch(gather_int_kernel, dim=n_work, inputs=[work, seg_len, lengths], device=device)
    return work, lengths


def sums(a: wp.array, b: wp.array, device: str) -> tuple[int, int]:
    """The sums of two int32 arrays, read with one wait."""
    scratch = wp.empty(max(a.shape[0], b.shape[0], 1), dtype=wp.int32, device=device)
    counts = wp.zeros(2, dtype=wp.int64, device=device)
    for i, x in enumerate((a, b)):
        if x.shape[0] > 0:
            out = scratch[:x.shape[0]]
            wp.utils.array_scan(x, out, inclusive=False)
            wp.launch(scan_total_kernel, dim=1, inputs=[x, out, counts[i:i + 1]],
                      device=device)
    s0, s1 = (int(c) for c in counts.numpy())
    return s0, s1


def recompute_flagged(m: Medium, cam: CameraParams, lights: Lights, grid: PhotonGrid,
                      me: MeanExtinction, sp: SurfaceParams, vp: ViewParams, seg: dict,
                      flags: wp.array, device: str, seg_len: wp.array | None = None,
                      counts: wp.array | None = None) -> int:
    """Recompute the stored segments flagged in ``flags`` (indexed like the segments) with
    :func:`recompute_segments`; returns how many. Where :func:`per_sample`, ``seg_len``
    holds the samples of each flagged segment (0 for the others) and ``counts`` the
    number of flagged segments and their samples (from :func:`segment_query_kernel`),
    read with one wait."""
    if not per_sample(vp, device):
        work, _ = select(flags, flags, device)
        recompute_segments(m, cam, lights, grid, me, sp, vp, seg, work, device)
        return int(work.shape[0])
    # The work list tile by tile (as the full render's): a warp of the gather then holds
    # neighbouring rays, not the segments of a few rays at different depths.
    tiles_x = (cam.width + 7) // 8
    tiles = tiles_x * ((cam.height + 3) // 4)
    tflag, tidx = tiled_flags(cam, vp, tiles_x, tiles, flags, device)
    n_work, total = (int(c) for c in counts.numpy())  # (the one wait)
    if n_work == 0:
        return 0
    work, lengths = tiled_work(tflag, tidx, seg_len, n_work, device)
    gather_work(m, cam, grid, me, sp, vp, seg, work, lengths, device, total)
    return n_work


def per_sample(vp: ViewParams, device: str) -> bool:
    """Whether segments are computed one thread per sample (photons only, on a device of
    :data:`SAMPLE_PARALLEL_DEVICES`)."""
    return vp.direct == 0 and str(device).startswith(tuple(SAMPLE_PARALLEL_DEVICES))


def recompute_segments(m: Medium, cam: CameraParams, lights: Lights, grid: PhotonGrid,
                       me: MeanExtinction, sp: SurfaceParams, vp: ViewParams, seg: dict,
                       work: wp.array, device: str) -> None:
    """Recompute the stored segments listed in ``work`` (entries ``pixel * V_n + i``), each
    on its own (the paper's load-balanced update): one thread per sample where
    :func:`per_sample` (the same bits as :func:`compute_segment`), else one per segment."""
    n_work = int(work.shape[0])
    if n_work == 0:
        return
    if per_sample(vp, device):
        lengths = wp.empty(n_work, dtype=wp.int32, device=device)
        wp.launch(segment_lengths_kernel, dim=n_work, inputs=[m, cam, vp, work, lengths],
                  device=device)
        gather_work(m, cam, grid, me, sp, vp, seg, work, lengths, device)
        return
    wp.launch(recompute_kernel, dim=n_work,
              inputs=[m, cam, lights, grid, me, sp, vp, work, seg["rad"], seg["t"],
                      seg["hist"], seg["chist"]], device=device)


@wp.struct
class SegmentRay:
    """The ray of a work item's segment (:func:`ray_setup`): origin ``o``, direction ``d``,
    entry ``t0``, jitter ``xi``; ``k0``: the segment's first sample."""

    o: wp.vec3
    d: wp.vec3
    t0: float
    xi: float
    k0: int


def gather_work(m, cam, grid, me, sp, vp, seg, work, lengths, device,
                total: int | None = None) -> None:
    """Compute the segments of ``work`` (``lengths``: the samples each marches) by
    :func:`sample_light_kernel` and :func:`shade_segment_kernel`, in batches of at most
    :data:`SAMPLES_PER_BATCH` samples.

    :func:`segment_rays_kernel` writes each work item's ray. Then, per :data:`SAMPLE_ORDER`,
    either the samples of a batch are one flat list (work item after work item), a thread
    each (:func:`sample_segments_kernel` writes each sample's work item): warps hold 32
    consecutive samples of a ray; or a warp holds sample ``k`` of 32 consecutive work items
    (:func:`sample_light_across_kernel`). ``total``: the sum of ``lengths`` when known (no
    wait for it then).
    """
    n_work = int(work.shape[0])
    offsets = wp.empty(n_work, dtype=wp.int32, device=device)
    if total is None:
        total = exclusive_scan(lengths, offsets)
    else:
        wp.utils.array_scan(lengths, offsets, inclusive=False)
    if total <= SAMPLES_PER_BATCH:
        batches = [(0, n_work, 0, total)]
    else:  # split the work list where the sample count crosses the budget
        off = offsets.numpy()
        ends = np.append(off, total)
        batches, w0 = [], 0
        while w0 < n_work:
            w1 = int(np.searchsorted(off, off[w0] + SAMPLES_PER_BATCH, side="left"))
            w1 = min(max(w1, w0 + 1), n_work)
            batches.append((w0, w1, int(off[w0]), int(ends[w1] - off[w0])))
            w0 = w1
    size = max(b[3] for b in batches)
    rays = wp.empty(n_work, dtype=SegmentRay, device=device)
    wp.launch(segment_rays_kernel, dim=n_work, inputs=[m, cam, vp, work, rays], device=device)
    across = SAMPLE_ORDER == "across" and total >= ACROSS_MIN_SAMPLES
    flat = None  # the ray order's buffers (light, sample_work), made when first needed
    for w0, w1, base, count in batches:
        done = None
        if across:
            done = _sample_light_across(m, grid, me, sp, vp, rays, lengths, w0, w1, count,
                                        device)
        if done is not None:
            light, first = done
            stride = 32
        else:
            if flat is None:
                flat = (wp.empty(max(size, 1), dtype=wp.vec3, device=device),
                        wp.empty(max(size, 1), dtype=wp.int32, device=device))
            light, sample_work = flat
            first, stride = offsets, 1  # (``first`` is read only with stride 32)
        if done is None and count > 0:
            wp.launch(sample_segments_kernel, dim=(w1 - w0) * 32,
                      inputs=[offsets, lengths, w0, base, sample_work], device=device)
            wp.launch(sample_light_kernel, dim=count,
                      inputs=[m, grid, me, sp, vp, rays, offsets, sample_work, base, light],
                      device=device, block_dim=SAMPLE_BLOCK)
        wp.launch(shade_segment_kernel, dim=w1 - w0,
                  inputs=[m, cam, me, grid, vp, work, offsets, lengths, w0, base, first,
                          stride, light, seg["rad"], seg["t"], seg["hist"], seg["chist"],
                          seg["state"], seg["samples"]], device=device)


@wp.kernel
def segment_rays_kernel(m: Medium, cam: CameraParams, vp: ViewParams,
                        work: wp.array(dtype=wp.int32), rays: wp.array(dtype=SegmentRay)):
    """``wp.tid()`` indexes the work list: the ray of its segment."""
    w = wp.tid()
    row, col, i = segment_of(cam, vp, work[w])
    o, d, t0, xi, n = ray_setup(m, cam, vp, row, col)
    k0, _k1 = segment_samples(n, vp.segments, i)
    r = SegmentRay()
    r.o = o
    r.d = d
    r.t0 = t0
    r.xi = xi
    r.k0 = k0
    rays[w] = r


def _sample_light_across(m, grid, me, sp, vp, rays, lengths, w0, w1, count, device):
    """:func:`sample_light_across_kernel` over work items ``[w0, w1)`` (``count`` samples;
    one wait: for the number of warps); returns the light (32 entries a warp) and each
    group's first warp, or None (nothing done) where the warps would be padded more than
    :data:`ACROSS_MAX_PADDING` times."""
    groups = -(-(w1 - w0) // 32)
    spans = wp.empty(groups, dtype=wp.int32, device=device)
    wp.launch(group_span_kernel, dim=groups, inputs=[lengths, w0, w1, spans], device=device)
    first = wp.empty(groups, dtype=wp.int32, device=device)
    warps = exclusive_scan(spans, first)
    if 32 * warps > ACROSS_MAX_PADDING * max(count, 1):
        return None
    light = wp.empty(max(32 * warps, 1), dtype=wp.vec3, device=device)
    if warps > 0:
        warp_group = wp.empty(warps, dtype=wp.int32, device=device)
        wp.launch(warp_groups_kernel, dim=groups, inputs=[spans, first, warp_group],
                  device=device)
        wp.launch(sample_light_across_kernel, dim=warps * 32,
                  inputs=[m, grid, me, sp, vp, rays, lengths, warp_group, first, w0, w1,
                          light], device=device, block_dim=SAMPLE_BLOCK)
    return light, first


@wp.kernel
def group_span_kernel(lengths: wp.array(dtype=wp.int32), w0: int, w1: int,
                      spans: wp.array(dtype=wp.int32)):
    """``wp.tid()`` = group ``g`` of work items ``w0 + 32 g ...`` (32, fewer at the end):
    the most samples one of them has."""
    g = wp.tid()
    a = w0 + 32 * g
    longest = int(0)
    for w in range(a, wp.min(a + 32, w1)):
        longest = wp.max(longest, lengths[w])
    spans[g] = longest


@wp.kernel
def warp_groups_kernel(spans: wp.array(dtype=wp.int32), first: wp.array(dtype=wp.int32),
                       warp_group: wp.array(dtype=wp.int32)):
    """``wp.tid()`` = group ``g``: ``warp_group[first[g] + j] = g`` for its ``spans[g]`` warps."""
    g = wp.tid()
    for j in range(spans[g]):
        warp_group[first[g] + j] = g


@capped_kernel(SAMPLE_REGISTERS)
def sample_light_across_kernel(m: Medium, grid: PhotonGrid, me: MeanExtinction,
                               sp: SurfaceParams, vp: ViewParams,
                               rays: wp.array(dtype=SegmentRay),
                               lengths: wp.array(dtype=wp.int32),
                               warp_group: wp.array(dtype=wp.int32),
                               first: wp.array(dtype=wp.int32), w0: int, w1: int,
                               light: wp.array(dtype=wp.vec3)):
    """:func:`sample_light_kernel` with the samples taken across work items: warp ``v`` of
    group ``g = warp_group[v]`` holds sample ``k = v - first[g]`` of work items ``w0 + 32 g +
    lane`` (lanes past a work item's samples idle); the light into ``light[wp.tid()]``."""
    t = wp.tid()
    v = t // 32
    g = warp_group[v]
    w = w0 + 32 * g + (t - 32 * v)
    if w >= w1:
        return
    kl = v - first[g]
    if kl >= lengths[w]:
        return
    sample_light(m, grid, me, sp, vp, rays[w], kl, light, t)


@wp.kernel
def sample_segments_kernel(offsets: wp.array(dtype=wp.int32), lengths: wp.array(dtype=wp.int32),
                           w0: int, base: int, sample_work: wp.array(dtype=wp.int32)):
    """32 threads per work item ``w = w0 + wp.tid() // 32``: ``sample_work[s - base] = w`` for
    its samples ``s`` in ``[offsets[w], offsets[w] + lengths[w])``."""
    t = wp.tid()
    w = w0 + t // 32
    lane = t - (w - w0) * 32
    a = offsets[w] - base
    for kl in range(lane, lengths[w], 32):
        sample_work[a + kl] = w


@wp.func
def segment_of(cam: CameraParams, vp: ViewParams, idx: int):
    """``(row, col, i)`` of segment entry ``idx = (row * width + col) * V_n + i``."""
    pix = idx // vp.segments
    i = idx - pix * vp.segments
    row = pix // cam.width
    return row, pix - row * cam.width, i


@wp.kernel
def tiled_flags_kernel(cam: CameraParams, vp: ViewParams, tiles_x: int, tiles: int,
                       flags: wp.array(dtype=wp.int32), tflag: wp.array(dtype=wp.int32),
                       tidx: wp.array(dtype=wp.int32)):
    """``wp.tid()`` runs over segments in the tile order of :func:`compute_flagged_kernel`:
    the flag and the entry of each."""
    t = wp.tid()
    i, row, col = tiled_segment(t, tiles_x, tiles)
    tflag[t] = 0
    tidx[t] = 0
    if row >= cam.height or col >= cam.width:
        return
    idx = (row * cam.width + col) * vp.segments + i
    tflag[t] = flags[idx]
    tidx[t] = idx


@wp.kernel
def segment_lengths_kernel(m: Medium, cam: CameraParams, vp: ViewParams,
                           work: wp.array(dtype=wp.int32), lengths: wp.array(dtype=wp.int32)):
    """``wp.tid()`` indexes the work list: the samples its segment marches
    (:func:`segment_transmittance`)."""
    w = wp.tid()
    row, col, i = segment_of(cam, vp, work[w])
    _t, n = segment_transmittance(m, cam, vp, row, col, i)
    lengths[w] = n


@wp.kernel
def add_count_kernel(counter: wp.array(dtype=wp.int32), n: int):
    """``counter[0] += n``."""
    counter[0] = counter[0] + n


@capped_kernel(SAMPLE_REGISTERS)
def sample_light_kernel(m: Medium, grid: PhotonGrid, me: MeanExtinction, sp: SurfaceParams,
                        vp: ViewParams, rays: wp.array(dtype=SegmentRay),
                        offsets: wp.array(dtype=wp.int32), sample_work: wp.array(dtype=wp.int32),
                        base: int, light: wp.array(dtype=wp.vec3)):
    """``wp.tid()`` = ``s - base``: sample ``s`` of the flat sample list, sample ``s -
    offsets[w]`` of work item ``w = sample_work[s - base]``'s segment: its photon radiance
    (as :func:`compute_segment` computes it; samples with σt = 0 are not read) into
    ``light[s - base]``."""
    t = wp.tid()
    w = sample_work[t]
    sample_light(m, grid, me, sp, vp, rays[w], base + t - offsets[w], light, t)


@wp.func
def sample_light(m: Medium, grid: PhotonGrid, me: MeanExtinction, sp: SurfaceParams,
                 vp: ViewParams, r: SegmentRay, kl: int, light: wp.array(dtype=wp.vec3),
                 t: int):
    """The photon radiance at sample ``kl`` of ray ``r``'s segment into ``light[t]`` (not
    written where σt = 0: the shading does not read it there)."""
    p = r.o + (r.t0 + (float(r.k0 + kl) + r.xi) * vp.step) * r.d
    s = sample_scalar(m.scalars, m.inv_spacing, p)
    sig = lookup_sigma_t(m, s)
    if sig > 0.0:
        surf, normal = surface_normal(m, sp, p, s)
        light[t] = photon_radiance(grid, me, p, -r.d, m.g, surf, normal, sp)


@capped_kernel(SHADE_REGISTERS)
def shade_segment_kernel(m: Medium, cam: CameraParams, me: MeanExtinction, grid: PhotonGrid,
                         vp: ViewParams, work: wp.array(dtype=wp.int32),
                         offsets: wp.array(dtype=wp.int32), lengths: wp.array(dtype=wp.int32),
                         w0: int, base: int, first: wp.array(dtype=wp.int32), stride: int,
                         light: wp.array(dtype=wp.vec3), seg_rad: wp.array(dtype=wp.vec3),
                         seg_t: wp.array(dtype=wp.float32), seg_hist: wp.array(dtype=wp.uint64),
                         seg_chist: wp.array(dtype=wp.uint64),
                         seg_state: wp.array(dtype=wp.int32),
                         seg_samples: wp.array(dtype=wp.int32)):
    """``wp.tid()`` = ``w - w0``: :func:`compute_segment` of work item ``w`` (photons only)
    with the light of each sample read from ``light``: laid out sample after sample of each
    work item (``stride`` 1, :func:`sample_light_kernel`) or across the 32 work items of a
    group (``stride`` 32, :func:`sample_light_across_kernel`: neighbouring threads here read
    neighbouring entries). Keeps the samples it marched in ``seg_samples`` (a later query
    without a σt change reads them instead of marching again)."""
    w = w0 + wp.tid()
    idx = work[w]
    row, col, i = segment_of(cam, vp, idx)
    o, d, t0, xi, n = ray_setup(m, cam, vp, row, col)
    k0, k1 = segment_samples(n, vp.segments, i)
    at = offsets[w] - base - k0
    if stride != 1:
        g = (w - w0) // 32
        at = 32 * first[g] + (w - w0 - 32 * g) - 32 * k0
    k_end = k0 + lengths[w]  # where the same products stop (a guard: never reached before)
    rad = wp.vec3(0.0)
    trans = float(1.0)
    hist = wp.uint64(0)
    chist = wp.uint64(0)
    for k in range(k0, k1):
        if k >= k_end:
            break
        p = o + (t0 + (float(k) + xi) * vp.step) * d
        s = sample_scalar(m.scalars, m.inv_spacing, p)
        hist = hist | data_bin(s, vp.bin_lo, vp.bin_scale)
        sig = lookup_sigma_t(m, s)
        if sig > 0.0:
            chist = chist | data_bin(s, vp.bin_lo, vp.bin_scale)
            a = 1.0 - wp.exp(-sig * vp.step)
            lt = light[at + stride * k]
            if grid.count > 0:
                hist = hist | kernel_bins(me, p)
            rad += (trans * a * m.albedo) * wp.cw_mul(lookup_color(m, s), lt)
            trans *= 1.0 - a
            if trans < vp.stop_t:
                break
    seg_rad[idx] = rad
    seg_t[idx] = trans
    seg_hist[idx] = hist
    seg_chist[idx] = chist
    seg_state[idx] = COMPUTED
    seg_samples[idx] = lengths[w]


@wp.kernel
def composite_kernel(m: Medium, cam: CameraParams, lights: Lights, grid: PhotonGrid,
                     me: MeanExtinction, sp: SurfaceParams, vp: ViewParams, seg_rad: wp.array(dtype=wp.vec3),
                     seg_t: wp.array(dtype=wp.float32), seg_hist: wp.array(dtype=wp.uint64),
                     seg_chist: wp.array(dtype=wp.uint64), seg_state: wp.array(dtype=wp.int32),
                     seg_samples: wp.array(dtype=wp.int32), radiance: wp.array2d(dtype=wp.vec3),
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
            seg_samples[idx] = -1  # (not counted here)
            wp.atomic_add(computed, 0, 1)
        total += prefix * seg_rad[idx]
        prefix *= seg_t[idx]
    radiance[row, col] = total
    alpha[row, col] = 1.0 - prefix


@wp.kernel
def segment_query_kernel(m: Medium, cam: CameraParams, vp: ViewParams,
                         seg_hist: wp.array(dtype=wp.uint64), seg_chist: wp.array(dtype=wp.uint64),
                         seg_state: wp.array(dtype=wp.int32),
                         seg_samples: wp.array(dtype=wp.int32), query: wp.uint64,
                         cquery: wp.uint64, sx: wp.uint64, sy: wp.uint64, sz: wp.uint64,
                         use_spatial: int, spatial_scale: wp.vec3, radius: float,
                         lengths: int, flags: wp.array(dtype=wp.int32),
                         seg_len: wp.array(dtype=wp.int32), counts: wp.array(dtype=wp.int32)):
    """Flag the stored segments an edit invalidates.

    ``wp.tid()`` indexes segments (``pixel * V_n + i``). A computed segment is invalid when
    its Historygrams meet the query masks (extinction ``query``, colour ``cquery``), or
    (``use_spatial``) when its bounding box grown by the photon ``radius`` meets set bits of
    the spatial Historygram on all three axes (``sx``, ``sy``, ``sz``: 64 bins over
    ``[0, extent_a]``, ``spatial_scale = 64 / extent``). With ``lengths`` != 0, also the
    samples each flagged segment marches (:func:`segment_transmittance`; 0 for the others)
    into ``seg_len``, as :func:`recompute_flagged` needs them: without a σt change
    (``query`` 0) the march stops where it stopped when the segment was computed, so the
    count kept then (``seg_samples``, -1 where none was kept) is read instead. Adds the
    flagged segments and their samples to ``counts[0]`` and ``counts[1]`` (zeroed by the
    caller), so that :func:`recompute_flagged` needs no sums of its own.
    """
    idx = wp.tid()
    flags[idx] = 0
    if lengths != 0:
        seg_len[idx] = 0
    if seg_state[idx] != COMPUTED:
        return
    hit = int(0)
    if ((seg_hist[idx] & query) | (seg_chist[idx] & cquery)) != wp.uint64(0):
        hit = 1
    elif use_spatial != 0:
        pix = idx // vp.segments
        i = idx - pix * vp.segments
        row = pix // cam.width
        col = pix - row * cam.width
        o, d, t0, xi, n = ray_setup(m, cam, vp, row, col)
        k0, k1 = segment_samples(n, vp.segments, i)
        if k1 > k0:
            pa = o + (t0 + (float(k0) + xi) * vp.step) * d
            pb = o + (t0 + (float(k1 - 1) + xi) * vp.step) * d
            lo = wp.min(pa, pb) - wp.vec3(radius)
            hi = wp.max(pa, pb) + wp.vec3(radius)
            if ((axis_bits(lo[0], hi[0], 0.0, spatial_scale[0]) & sx) != wp.uint64(0)
                    and (axis_bits(lo[1], hi[1], 0.0, spatial_scale[1]) & sy) != wp.uint64(0)
                    and (axis_bits(lo[2], hi[2], 0.0, spatial_scale[2]) & sz) != wp.uint64(0)):
                hit = 1
    if hit == 0:
        return
    flags[idx] = 1
    wp.atomic_add(counts, 0, 1)
    if lengths != 0:
        count = seg_samples[idx]
        if query != wp.uint64(0) or count < 0:
            srow, scol, si = segment_of(cam, vp, idx)
            _t, count = segment_transmittance(m, cam, vp, srow, scol, si)
        seg_len[idx] = count
        wp.atomic_add(counts, 1, count)


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
