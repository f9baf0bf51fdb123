"""What photon mapping keeps between frames, and what each edit recomputes.

:class:`PhotonMapper` holds one photon map (``N`` paths), its spatial hash and the view
segments of the last image, and follows the paper's update scheme (sections 4.1–4.3):

================================  =====================================================
edit                              recomputed
================================  =====================================================
transfer function / unit distance with Historygrams: photons whose Historygram meets the
                                  query mask, from their last valid interaction; the hash;
                                  the segments whose Historygram meets the query or whose
                                  box meets the spatial Historygram (then recomposite).
                                  Without Historygrams: everything.
data, lights, albedo, g,          everything (new photon map, hash and segments)
photon count, S_n, seed
camera, image size, step          the segments (the photon map is view-independent)
nothing                           nothing (progressive refinement adds passes)
================================  =====================================================

**Progressive refinement** (:meth:`PhotonMapper.refine`): while nothing changes, extra
passes trace independent photon maps (seeds ``(seed, pass)``) with radii shrinking as
``r_{i+1}³ = r_i³ (i + α) / (i + 1)`` and average their images with the first one:
progressive photon mapping in the memoryless form of Knaus & Zwicker 2011 (the paper's
ref. [5]; Hachisuka et al. 2008 reach the same limit with per-sample statistics). Bias
and variance both vanish as passes accumulate, so the image converges to the path
tracer's. Only the first pass is kept for incremental updates; an edit or a camera move
restarts the average from it.

On CUDA an update queues the trace, the hash and σ̄t and waits for the device once, at
its end (an incremental one also once after the photon query, for the number of photons
to retrace); a render waits once after finding the segments to compute (how many, and
their samples) and once for the image.

Simplifications: the update budget per frame is a number of passes (or seconds) for
:meth:`PhotonMapper.refine`; an incremental update itself always completes (a partly
updated photon map would be inconsistent with the Historygrams).
"""

from __future__ import annotations

import sys
import time

import numpy as np
import warp as wp

from vtkillum.core.photon.density import mean_extinction
from vtkillum.core.photon.emission import make_emitters
from vtkillum.core.photon.hashgrid import build_photon_grid
from vtkillum.core.photon.historygram import (
    ALL_BITS,
    BITS,
    bin_scale,
    kept_count_kernel,
    mark_added_kernel,
    photon_query_kernel,
)
from vtkillum.core.photon.material import make_surface
from vtkillum.core.photon.radius import PILOT_PHOTONS, auto_photons, auto_radius
from vtkillum.core.photon.segments import (
    ViewParams,
    composite_segments,
    new_segments,
    per_sample,
    recompute_flagged,
    segment_query_kernel,
)
from vtkillum.core.photon.storage import select
from vtkillum.core.photon.tracing import PhotonMap, photon_medium
from vtkillum.core.render import RenderResult
from vtkillum.core.warp_common import make_camera, make_lights, stream_seed

DIRECT_MODES = ("exact", "photons")
#: Salts of the seeds derived from the user's seed.
PHOTON_SALT = 0x50484F54
VIEW_SALT = 0x56494557
PILOT_SALT = 0x50494C54
SHADOW_SALT = 0x53484457


def radius_schedule(r0: float, passes: int, alpha: float) -> list[float]:
    """Radii of passes ``0 .. passes-1``: ``r_{i+1}³ = r_i³ (i + α) / (i + 1)`` (i from 1)."""
    radii = [float(r0)]
    for i in range(1, passes):
        radii.append(radii[-1] * ((i + alpha) / (i + 1)) ** (1.0 / 3.0))
    return radii


class PhotonMapper:
    """Photon map, hash and view segments of one volume, updated incrementally.

    Parameters
    ----------
    device : str
        Warp device.
    photons : int
        Photon paths per map ``P_n`` (> 0); 0: chosen by a pilot trace at each full trace
        (:func:`~vtkillum.core.photon.radius.auto_photons`: enough photons for
        ``kernel_photons`` in a kernel of the old default radius of 2 voxels, within
        bounds) and kept through incremental updates.
    radius : float
        Photon radius ``r`` of the first pass, world units (> 0); 0: chosen from the photon
        map after each full trace (:func:`~vtkillum.core.photon.radius.auto_radius`,
        ``kernel_photons`` per kernel) and kept through incremental updates.
    max_order : int
        ``S_n``: most interactions per photon (1: single scattering; 0: unbounded).
    segments : int
        View-ray segments ``V_n`` (>= 1).
    seed : int
        Seed of photons and view jitter.
    historygrams : bool
        Update incrementally after transfer-function edits (else recompute everything).
    spatial_historygram : bool
        Also recompute segments near changed photons (section 4.3.2).
    direct : {"exact", "photons"}
        "exact": direct light by shadow rays, photons for the scattered light (order
        >= 2); "photons": photons for all light (the paper's setting).
    alpha : float
        Radius reduction of progressive passes, in (0, 1).
    photon_step : float, optional
        Ray-marching step of photon flights (world units); default half the smallest
        voxel spacing.
    memory_limit_mb : float, optional
        Cap on device memory for the photon map (default: what is free).
    surface : dict, optional
        ``surface_range``, ``surface_gradient``, ``surface_diffuse``, ``surface_specular``,
        ``surface_shininess``: the optional BRDF of surface-like samples
        (:mod:`~vtkillum.core.photon.material`); default off.
    kernel_photons : int
        Photons per kernel the automatic radius aims at (``radius`` 0).
    """

    def __init__(self, device: str, photons: int, radius: float, max_order: int = 0,
                 segments: int = 8, seed: int = 0, historygrams: bool = True,
                 spatial_historygram: bool = True, direct: str = "exact", alpha: float = 2 / 3,
                 photon_step: float | None = None, memory_limit_mb: float | None = None,
                 surface: dict | None = None, kernel_photons: int = 128) -> None:
        check_config(photons, radius, max_order, segments, direct, alpha, kernel_photons)
        self.device = device
        keep_pool_memory(device)
        self.photons = int(photons)
        self.auto_photons = self.photons == 0
        self.auto_radius = float(radius) == 0.0
        self.kernel_photons = int(kernel_photons)
        self.radius = float(radius)
        self.max_order = int(max_order)
        self.segments = int(segments)
        self.seed = int(seed)
        self.historygrams = bool(historygrams)
        self.spatial_historygram = bool(spatial_historygram)
        self.direct = direct
        self.alpha = float(alpha)
        self.photon_step = photon_step
        self.memory_limit_mb = memory_limit_mb
        self.surface_options = dict(surface or {})
        self.surface = None
        self.min_order = 2 if direct == "exact" else 1
        self.map: PhotonMap | None = None
        self.grid = None
        self.extinction = None
        self.medium = None
        self.tables = None
        self.lights = None
        self.emitters = None
        self._volume = None
        self._light_key = None
        self._view = None  # (key, ViewParams, camera params, width, height)
        self._seg = None  # segment arrays
        self._pending_query = (0, 0)  # (extinction bins, colour bins)
        self._pending_spatial = np.zeros(3, np.uint64)
        self._full_pending = True
        self._accum = None  # (radiance sum, alpha sum, passes)
        self._pinned = None  # sets of page-locked host buffers of the image (CUDA)
        self._query_buffers = None  # the photon query's flags and restarts (kept: 2 × 4 N bytes)
        self.last_update: dict = {}
        self.last_render: dict = {}
        self.pilot: dict = {}  # the automatic photon count's pilot trace

    # --- photons ---------------------------------------------------------------------------------
    def update(self, volume, transfer_function, unit_distance: float, albedo: float, g: float,
               lights) -> dict:
        """Bring the photon map up to date with the optical model; returns what was done.

        The returned dict (also :attr:`last_update`) holds ``mode`` ("full",
        "incremental", "unchanged"), ``photons_retraced``, ``photon_fraction``,
        ``interactions_removed``, ``interactions_added``, ``query_bins`` and ``ms`` per
        stage (``trace``, ``query``, ``hash``).
        """
        device = self.device
        t0 = time.perf_counter()
        light_key = (volume.content_key, tuple(volume.dims), tuple(volume.spacing),
                     tuple(volume.origin), volume.direction.tobytes(), float(albedo), float(g),
                     repr([l.to_dict() for l in lights]))
        full = (self.map is None or light_key != self._light_key or not self.historygrams)
        medium, tables = photon_medium(volume, transfer_function, unit_distance, albedo, g,
                                       device, None if full else (self.medium, self.tables))
        step = self.photon_step or 0.5 * float(np.min(volume.spacing))
        stats = {"mode": "unchanged", "photons_retraced": 0, "photon_fraction": 0.0,
                 "interactions_removed": 0, "interactions_added": 0, "query_bins": 0,
                 "ms": {"query": 0.0, "trace": 0.0, "hash": 0.0}}
        pending = None
        if full:
            self._volume = volume
            self.medium, self.tables = medium, tables
            # Every upload before the first launch: a copy from pageable host memory waits
            # for the work queued before it.
            self.lights = make_lights(lights, volume, device)
            self.surface = make_surface(self.surface_options, volume)
            if self.auto_photons:
                self.photons = self._photons_from_pilot(volume, medium, lights, step)
            self.emitters, _ = make_emitters(lights, volume, self.photons, device)
            self.map = PhotonMap(self.photons, device, stream_seed(self.seed, 0, PHOTON_SALT),
                                 self.max_order, step, self.memory_limit_mb, self.surface)
            if self.auto_radius:
                # The radius comes from the photons: trace (and wait) first.
                trace = self.map.trace(medium, self.emitters, volume.value_range)
                self.radius = self._radius_from_map(volume)
            # σ̄t needs no photons: queued first, the device works on it while the host
            # prepares the trace.
            self.extinction = mean_extinction(self.medium, volume, self.radius, device,
                                              None, bin_scale(volume.value_range))
            if not self.auto_radius:
                trace = self.map.trace(medium, self.emitters, volume.value_range,
                                       resolve=False)
            stats.update(mode="full", photons_retraced=self.photons, photon_fraction=1.0,
                         query_bins=BITS)
            stats["ms"]["trace"] = trace["ms"]
            self._light_key = light_key
            self._full_pending = True
            self._pending_query = (ALL_BITS, ALL_BITS)
        else:
            hq = (tables.sigma_bins, tables.color_bins)
            self.medium, self.tables = medium, tables
            if hq[0] or hq[1]:
                inc, pending = self._incremental(volume, hq)
                stats.update(inc)
        if stats["mode"] != "unchanged":
            t_hash = time.perf_counter()
            # The hash only moves when photons did; σ̄t only when σt did (and was made first
            # in a full update). All queued without waiting: one wait at the end.
            grid_count = None
            if stats["mode"] == "full" or stats["photons_retraced"] > 0:
                pm = self.map
                self.grid, grid_count = build_photon_grid(
                    pm.interactions, pm.capacity if pm._total is None else pm.total,
                    volume.extent, self.radius, self.min_order, device,
                    stored=pm._counters if pm._total is None else None, defer=True)
            if stats["mode"] != "full" and stats.get("sigma_changed", True):
                self.extinction = mean_extinction(self.medium, volume, self.radius, device,
                                                  self.extinction.mask,
                                                  bin_scale(volume.value_range))
            if grid_count is not None or stats["mode"] == "full" or stats["sigma_changed"]:
                wp.synchronize_device(device)  # (else nothing was queued since the query)
            trace = self.map.resolve()
            if grid_count is not None:
                self.grid.count = int(grid_count.numpy()[0])
            if stats["photons_retraced"] > 0:
                stats["interactions_added"] = trace["interactions_added"]
            if pending is not None:
                self._pending_spatial |= pending.numpy()[:3]
            stats["ms"]["hash"] = 1e3 * (time.perf_counter() - t_hash)
            self._accum = None
        stats["ms"]["total"] = 1e3 * (time.perf_counter() - t0)
        stats["interactions"] = self.map.total
        stats["capped"] = self.map.stats.get("capped", 0)
        self.last_update = stats
        return stats

    def _radius_from_map(self, volume, pm: PhotonMap | None = None) -> float:
        """The automatic radius of the current map (or of ``pm``), from its gathered
        photons."""
        pm = self.map if pm is None else pm
        return auto_radius(self._gathered(pm), volume.extent, volume.mean_spacing(),
                           self.kernel_photons)

    def _gathered(self, pm: PhotonMap) -> np.ndarray:
        n = pm.total
        order = pm.interactions.order.numpy()[:n]
        return pm.interactions.pos.numpy()[:n][order >= self.min_order]

    def _photons_from_pilot(self, volume, medium, lights, step: float) -> int:
        """Photon count of the automatic mode: a pilot map of :data:`PILOT_PHOTONS` (its
        own seed) says how densely photons land (:func:`auto_photons`)."""
        emitters, _ = make_emitters(lights, volume, PILOT_PHOTONS, self.device)
        pilot = PhotonMap(PILOT_PHOTONS, self.device, stream_seed(self.seed, 0, PILOT_SALT),
                          self.max_order, step, self.memory_limit_mb, self.surface)
        pilot.trace(medium, emitters, volume.value_range)
        count = auto_photons(self._gathered(pilot), PILOT_PHOTONS, volume.extent,
                             volume.mean_spacing(), self.kernel_photons)
        self.pilot = {"photons": PILOT_PHOTONS, "gathered": int(len(self._gathered(pilot))),
                      "chosen": count}
        return count

    def _incremental(self, volume, hq: tuple):
        """Query the photons (one wait, for how many to retrace) and queue their retrace;
        returns the stats and the device array to read at the end of :meth:`update` (the
        spatial Historygram, None when it is read already)."""
        device = self.device
        pm = self.map
        t0 = time.perf_counter()
        n = pm.n_photons
        self._pending_query = (self._pending_query[0] | int(hq[0]),
                               self._pending_query[1] | int(hq[1]))
        stats = {"mode": "incremental", "photons_retraced": 0, "sigma_changed": bool(hq[0]),
                 "photon_fraction": 0.0, "query_bins": (int(hq[0]) | int(hq[1])).bit_count(),
                 "interactions_removed": 0, "ms": {"query": 0.0, "trace": 0.0, "hash": 0.0}}
        hist_or, chist_or = pm.path_masks
        if not ((int(hq[0]) & hist_or) | (int(hq[1]) & chist_or)):
            # No path used a changed bin (the OR of all their Historygrams): every photon is
            # valid, with no launch and no wait.
            stats["ms"]["query"] = 1e3 * (time.perf_counter() - t0)
            return stats, None
        if self._query_buffers is None or self._query_buffers[0].shape[0] != n:
            self._query_buffers = (wp.empty(n, dtype=wp.int32, device=device),
                                   wp.empty(n, dtype=wp.int32, device=device))
        flags, restart = self._query_buffers
        # Spatial Historygram (3 axes), interactions removed, photons flagged.
        spatial = wp.zeros(5, dtype=wp.uint64, device=device)
        scale = wp.vec3(*(BITS / np.asarray(volume.extent, np.float64)).astype(np.float32))
        wp.launch(photon_query_kernel, dim=n,
                  inputs=[pm.start, pm.count, pm.path_hist, pm.path_chist, pm.interactions,
                          wp.uint64(hq[0]), wp.uint64(hq[1]), self.min_order, scale, flags,
                          restart, spatial],
                  device=device)
        queried = spatial.numpy()  # the one wait
        n_removed, n_flagged = int(queried[3]), int(queried[4])
        n_work = n_flagged
        t_trace = time.perf_counter()
        if n_work:
            photons, restarts = select(flags, restart, device, n_flagged)
            kept = wp.empty(n_work, dtype=wp.int32, device=device)
            wp.launch(kept_count_kernel, dim=n_work, inputs=[photons, restarts, pm.start, kept],
                      device=device)
            pm.retrace(self.medium, self.emitters, volume.value_range, photons, restarts,
                       resolve=False)
            wp.launch(mark_added_kernel, dim=n_work,
                      inputs=[photons, kept, pm.start, pm.count, pm.interactions,
                              self.min_order, scale, spatial], device=device)
        t_end = time.perf_counter()
        if not n_work:  # the spatial Historygram is complete: no photon was added
            self._pending_spatial |= queried[:3]
            spatial = None
        stats.update(photons_retraced=n_work, photon_fraction=n_work / n,
                     interactions_removed=n_removed)
        stats["ms"].update(query=1e3 * (t_trace - t0), trace=1e3 * (t_end - t_trace))
        return stats, spatial

    # --- images ----------------------------------------------------------------------------------
    def render(self, volume, camera, width: int, height: int, step: float, jitter: bool = True,
               seed: int = 0, early_termination: float = 0.999, progress=None) -> RenderResult:
        """The image of the current photon map: segments recomputed as the pending edits say.

        A new camera, size or sampling recomputes every segment; otherwise only the
        segments invalidated since the last render (none if nothing changed).
        """
        if self.map is None:
            raise ValueError("call update(volume, transfer_function, ...) before render()")
        device = self.device
        t0 = time.perf_counter()
        view_key = (repr(camera.to_dict()), int(width), int(height), float(step), bool(jitter),
                    int(seed), float(early_termination))
        n_seg = int(width) * int(height) * self.segments
        recomputed = 0
        queried = False
        if self._view is None or self._view[0] != view_key or self._full_pending:
            vp = self._view_params(volume, step, jitter, seed, early_termination)
            cam = make_camera(camera, volume, int(width), int(height))
            self._view = (view_key, vp, cam, int(width), int(height))
            self._seg = new_segments(n_seg, device)
            self._accum = None
            mode = "full"
        elif any(self._pending_query) or self._pending_spatial.any():
            _, vp, cam, _, _ = self._view
            queried = True
            flags = wp.empty(n_seg, dtype=wp.int32, device=device)
            # The samples of the flagged segments are counted in the same pass where the
            # recompute goes sample by sample.
            lengths = per_sample(vp, device)
            seg_len = wp.empty(n_seg if lengths else 1, dtype=wp.int32, device=device)
            counts = wp.zeros(2, dtype=wp.int32, device=device)  # flagged, their samples
            scale = wp.vec3(*(BITS / np.asarray(volume.extent, np.float64)).astype(np.float32))
            sx, sy, sz = (wp.uint64(int(v)) for v in self._pending_spatial)
            # A segment meets the spatial Historygram only where all three axes have bits:
            # with an empty axis (no photon moved) no segment sets up its ray for it.
            use_spatial = self.spatial_historygram and bool(self._pending_spatial.all())
            wp.launch(segment_query_kernel, dim=n_seg,
                      inputs=[self.medium, cam, vp, self._seg["hist"], self._seg["chist"],
                              self._seg["state"], self._seg["samples"],
                              wp.uint64(self._pending_query[0]),
                              wp.uint64(self._pending_query[1]), sx, sy, sz,
                              int(use_spatial), scale, self.radius, int(lengths),
                              flags, seg_len, counts],
                      device=device)
            recomputed = recompute_flagged(self.medium, cam, self.lights, self.grid,
                                           self.extinction, self.surface, vp, self._seg, flags,
                                           device, seg_len if lengths else None, counts)
            mode = "incremental"
        else:
            _, vp, cam, _, _ = self._view
            mode = "unchanged"
        t_seg = time.perf_counter()
        # Without a σt edit since the last composite, the visible segments are all stored.
        find_visible = mode == "full" or self._pending_query[0] != 0
        radiance, alpha, computed = composite_segments(
            self.medium, cam, self.lights, self.grid, self.extinction, self.surface, vp,
            self._seg, int(width), int(height), device,
            None if progress is None else (lambda f: progress(0.95 * f)), find_visible)
        self._pending_query = (0, 0)
        self._pending_spatial[:] = 0
        self._full_pending = False
        rad_host, alpha_host, n_computed = self._to_host(radiance, alpha, computed)  # waits
        t_end = time.perf_counter()
        info = {"mode": mode, "segments": n_seg,
                "segments_recomputed": recomputed + n_computed,
                "segment_fraction": (recomputed + n_computed) / max(n_seg, 1),
                "segments_queried": queried,
                "ms": {"segments": 1e3 * (t_seg - t0), "composite": 1e3 * (t_end - t_seg)}}
        self.last_render = info
        result = RenderResult(rad_host, alpha_host, {"photon_render": info})
        if mode == "unchanged" and self._accum is not None and self._accum[2] > 1:
            rad_sum, alpha_sum, done = self._accum  # keep the progressive average
            result = RenderResult((rad_sum / done).astype(np.float32),
                                  (alpha_sum / done).astype(np.float32), result.info)
        else:
            # One pass, float32 (refine() sums in float64 from there).
            self._accum = (rad_host, alpha_host, 1)
        info["passes"] = self._accum[2]
        if progress is not None:
            progress(1.0)
        return result

    def _to_host(self, radiance: wp.array, alpha: wp.array, computed: wp.array):
        """The image (host arrays, float32, the caller's to keep) and the count of segments
        computed.

        On CUDA the image is copied to page-locked buffers (a copy to pageable memory is
        several times slower) and handed out as they are, without another copy: a set of
        buffers is used again only once nothing outside the mapper refers to the arrays it
        handed out last (every view of them refers to them), else another set is made
        (up to :data:`HOST_BUFFER_SETS`, then the image is copied out).
        """
        if not wp.get_device(self.device).is_cuda:
            return (radiance.numpy().copy(), alpha.numpy().copy(),
                    int(computed.numpy()[0]))
        if self._pinned is None or self._pinned[0][0].shape != radiance.shape:
            self._pinned = []
        free = next((s for s in self._pinned if self._unreferenced(s)), None)
        copy_out = False
        if free is None and len(self._pinned) < HOST_BUFFER_SETS:
            h, w = radiance.shape
            free = [wp.empty((h, w), dtype=wp.vec3, device="cpu", pinned=True),
                    wp.empty((h, w), dtype=wp.float32, device="cpu", pinned=True),
                    wp.empty(1, dtype=wp.int32, device="cpu", pinned=True), None, None]
            self._pinned.append(free)
        elif free is None:
            free, copy_out = self._pinned[0], True
        rad, al, cnt = free[:3]
        wp.copy(rad, radiance)
        wp.copy(al, alpha)
        wp.copy(cnt, computed)
        wp.synchronize_device(self.device)
        if copy_out:
            return rad.numpy().copy(), al.numpy().copy(), int(cnt.numpy()[0])
        free[3], free[4] = rad.numpy(), al.numpy()  # the arrays handed out
        return free[3], free[4], int(cnt.numpy()[0])

    def _unreferenced(self, buffers: list) -> bool:
        """Whether the arrays last handed out from ``buffers`` are referred to only by the
        mapper (the set itself and the progressive average)."""
        for i in (3, 4):
            view = buffers[i]
            if view is None:
                continue
            own = 3 + int(self._accum is not None and (self._accum[0] is view
                                                       or self._accum[1] is view))
            if sys.getrefcount(view) > own:  # the list entry, the name, the argument
                return False
        return True

    def refine(self, volume, camera, width: int, height: int, step: float, passes: int = 1,
               jitter: bool = True, seed: int = 0, early_termination: float = 0.999,
               budget_s: float | None = None, progress=None) -> RenderResult:
        """Add progressive passes (independent photon maps, shrinking radius) to the image.

        Call after :meth:`render` with the same view; ``passes`` more passes are traced
        (fewer if ``budget_s`` seconds run out first, at least one). Returns the average of
        all passes so far (``info["passes"]``).
        """
        if self._accum is None or self._view is None:
            raise ValueError("refine() continues the image of the last render(); render first")
        rad_sum, alpha_sum, done = self._accum
        rad_sum = rad_sum.astype(np.float64)
        alpha_sum = alpha_sum.astype(np.float64)
        first = done
        start = time.perf_counter()
        radii = radius_schedule(self.radius, done + int(passes), self.alpha)
        for k in range(first, first + int(passes)):
            if budget_s is not None and k > first and time.perf_counter() - start > budget_s:
                break
            pm = PhotonMap(self.photons, self.device, stream_seed(self.seed, k, PHOTON_SALT),
                           self.max_order, self.map.step, self.memory_limit_mb, self.surface)
            pm.trace(self.medium, self.emitters, volume.value_range)
            grid = build_photon_grid(pm.interactions, pm.total, volume.extent, radii[k],
                                     self.min_order, self.device)
            me = mean_extinction(self.medium, volume, radii[k], self.device,
                                 bins=bin_scale(volume.value_range))
            del pm
            vp = self._view_params(volume, step, jitter, stream_seed(seed, k, VIEW_SALT),
                                   early_termination)
            vp.segments = 1
            cam = self._view[2]
            h, w = int(height), int(width)
            seg = new_segments(h * w, self.device)
            radiance, alpha, _ = composite_segments(self.medium, cam, self.lights, grid, me,
                                                    self.surface, vp, seg, w, h, self.device)
            rad_sum = rad_sum + radiance.numpy()
            alpha_sum = alpha_sum + alpha.numpy()
            done += 1
            if progress is not None:
                progress((k + 1 - first) / max(int(passes), 1))
        self._accum = (rad_sum, alpha_sum, done)
        return RenderResult((rad_sum / done).astype(np.float32),
                            (alpha_sum / done).astype(np.float32),
                            {"passes": done, "radius_last": radii[done - 1]})

    def fluence(self, volume, shape, passes: int = 1, progress=None, on_device: bool = False):
        """Photon fluence ``φ`` on a grid of ``shape`` points covering the volume's box.

        Pass 0 uses the kept photon map; passes 1 .. ``passes - 1`` trace independent maps
        with the shrinking radii of :func:`radius_schedule` and are averaged in.
        Returns (nx, ny, nz, 3) float32, the lights' irradiance units; with ``on_device``
        a warp ``array3d(vec3)`` on the mapper's device instead (no download: for a
        renderer on that device).
        """
        from vtkillum.core.photon.density import accumulate_fluence, fluence_grid

        if self.map is None:
            raise ValueError("call update(volume, transfer_function, ...) before fluence()")
        shape = tuple(int(n) for n in shape)
        first = fluence_grid(self.grid, self.extinction, shape, volume.extent, self.device,
                             to_numpy=False)
        if int(passes) <= 1:
            return first if on_device else first.numpy().reshape(*shape, 3)
        radii = radius_schedule(self.radius, int(passes), self.alpha)
        # The passes are summed in float64 on the device: one copy to the host at the end.
        total = wp.zeros(shape, dtype=wp.vec3d, device=self.device)
        accumulate_fluence(total, first, self.device)
        for k in range(1, int(passes)):
            if progress is not None:
                progress(k / passes)
            pm = PhotonMap(self.photons, self.device, stream_seed(self.seed, k, PHOTON_SALT),
                           self.max_order, self.map.step, self.memory_limit_mb, self.surface)
            pm.trace(self.medium, self.emitters, volume.value_range)
            grid = build_photon_grid(pm.interactions, pm.total, volume.extent, radii[k],
                                     self.min_order, self.device)
            del pm
            me = mean_extinction(self.medium, volume, radii[k], self.device,
                                 bins=bin_scale(volume.value_range))
            accumulate_fluence(total, fluence_grid(grid, me, shape, volume.extent, self.device,
                                                   to_numpy=False), self.device)
        if on_device:
            mean = wp.empty(shape, dtype=wp.vec3, device=self.device)
            wp.launch(mean_fluence_kernel, dim=shape, inputs=[total, 1.0 / int(passes), mean],
                      device=self.device)
            return mean
        return (total.numpy().reshape(*shape, 3) / int(passes)).astype(np.float32)

    def segments_numpy(self) -> dict:
        """The stored segments as numpy arrays (``rad``, ``t``, ``hist``, ``state``), each
        indexed ``pixel * V_n + i`` with ``pixel = row * width + col``."""
        if self._seg is None:
            return {}
        return {name: a.numpy().copy() for name, a in self._seg.items() if name != "samples"}

    @property
    def passes(self) -> int:
        """Passes averaged into the current image (0 before the first render)."""
        return 0 if self._accum is None else self._accum[2]

    def _view_params(self, volume, step, jitter, seed, early_termination) -> ViewParams:
        vp = ViewParams()
        vp.segments = self.segments
        vp.step = float(step)
        vp.jitter = int(bool(jitter))
        vp.seed = int(seed)
        vp.shadow_seed = stream_seed(seed, 0, SHADOW_SALT)
        vp.stop_t = float(1.0 - early_termination)
        vp.direct = int(self.direct == "exact")
        vp.bin_lo, vp.bin_scale = bin_scale(volume.value_range)
        return vp


#: Sets of page-locked host buffers an image may be handed out in (more while the caller
#: keeps earlier images; beyond, images are copied out of the first set).
HOST_BUFFER_SETS = 4
#: Device memory the CUDA memory pool keeps for reuse instead of handing it back at each
#: synchronisation (fraction of the device's memory; at least what warp has set). A trace
#: and a gather allocate and free about a gigabyte of buffers each time (4 M photons, 512²
#: with 7 segments); handed back, it must be mapped again the next time.
POOL_KEEP = 0.25


def keep_pool_memory(device: str) -> None:
    """Raise the release threshold of ``device``'s memory pool to :data:`POOL_KEEP` (CUDA
    devices with memory pools; nothing elsewhere)."""
    try:
        d = wp.get_device(device)
        if not (d.is_cuda and d.is_mempool_supported and d.is_mempool_enabled):
            return
        want = int(POOL_KEEP * d.total_memory)
        if wp.get_mempool_release_threshold(d) < want:
            wp.set_mempool_release_threshold(d, want)
    except (RuntimeError, ValueError, AttributeError):
        pass


def check_config(photons, radius, max_order, segments, direct, alpha,
                 kernel_photons=128) -> None:
    """Raise ``ValueError`` naming the first invalid photon-mapping setting."""
    if isinstance(photons, bool) or not float(photons).is_integer() or int(photons) < 0:
        raise ValueError(f"photon.photons must be an integer >= 0 (0: automatic), got "
                         f"{photons!r}")
    if not (np.isfinite(radius) and radius >= 0):
        raise ValueError(f"photon.radius must be a number >= 0 (0: automatic), got "
                         f"{radius!r}")
    if isinstance(kernel_photons, bool) or not float(kernel_photons).is_integer() or \
            int(kernel_photons) < 1:
        raise ValueError(f"photon.kernel_photons must be a positive integer, got "
                         f"{kernel_photons!r}")
    if isinstance(max_order, bool) or not float(max_order).is_integer() or int(max_order) < 0:
        raise ValueError(f"photon.max_order (S_n) must be an integer >= 0 (0: unbounded), got "
                         f"{max_order!r}")
    if isinstance(segments, bool) or not float(segments).is_integer() or int(segments) < 1:
        raise ValueError(f"photon.segments (V_n) must be a positive integer, got {segments!r}")
    if direct not in DIRECT_MODES:
        raise ValueError(f"photon.direct must be one of {DIRECT_MODES}, got {direct!r}")
    if not (0.0 < float(alpha) < 1.0):
        raise ValueError(f"photon.alpha must lie in (0, 1), got {alpha!r}")


@wp.kernel
def mean_fluence_kernel(total: wp.array3d(dtype=wp.vec3d), inv_passes: float,
                        out: wp.array3d(dtype=wp.vec3)):
    """``out = total / passes`` in single precision; ``wp.tid()`` is the grid point."""
    i, j, k = wp.tid()
    v = total[i, j, k] * wp.float64(inv_passes)
    out[i, j, k] = wp.vec3(wp.float32(v[0]), wp.float32(v[1]), wp.float32(v[2]))
