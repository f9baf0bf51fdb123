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

Simplifications: the update budget per frame is a number of passes (or seconds) for
:meth:`PhotonMapper.refine`; an incremental update itself always completes (a partly
updated photon map would be inconsistent with the Historygrams).
"""

from __future__ import annotations

import time

import numpy as np
import warp as wp

from vtkillum.core.photon.density import mean_extinction
from vtkillum.core.photon.emission import make_emitters
from vtkillum.core.photon.material import make_surface
from vtkillum.core.photon.hashgrid import build_photon_grid
from vtkillum.core.photon.historygram import (
    ALL_BITS,
    BITS,
    bin_scale,
    kept_count_kernel,
    mark_added_kernel,
    photon_query_kernel,
    query_masks,
)
from vtkillum.core.photon.segments import (
    ViewParams,
    composite_segments,
    recompute_kernel,
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
        Photon paths per map ``P_n`` (> 0).
    radius : float
        Photon radius ``r`` of the first pass, world units (> 0).
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
    """

    def __init__(self, device: str, photons: int, radius: float, max_order: int = 0,
                 segments: int = 8, seed: int = 0, historygrams: bool = True,
                 spatial_historygram: bool = True, direct: str = "exact", alpha: float = 2 / 3,
                 photon_step: float | None = None, memory_limit_mb: float | None = None,
                 surface: dict | None = None) -> None:
        check_config(photons, radius, max_order, segments, direct, alpha)
        self.device = device
        self.photons = int(photons)
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
        self.last_update: dict = {}
        self.last_render: dict = {}

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
        medium, tables = photon_medium(volume, transfer_function, unit_distance, albedo, g,
                                       device)
        step = self.photon_step or 0.5 * float(np.min(volume.spacing))
        stats = {"mode": "unchanged", "photons_retraced": 0, "photon_fraction": 0.0,
                 "interactions_removed": 0, "interactions_added": 0, "query_bins": 0,
                 "ms": {"query": 0.0, "trace": 0.0, "hash": 0.0}}
        full = (self.map is None or light_key != self._light_key or not self.historygrams)
        if full:
            self._volume = volume
            self.lights = make_lights(lights, volume, device)
            self.surface = make_surface(self.surface_options, volume)
            self.emitters, _ = make_emitters(lights, volume, self.photons, device)
            self.map = PhotonMap(self.photons, device, stream_seed(self.seed, 0, PHOTON_SALT),
                                 self.max_order, step, self.memory_limit_mb, self.surface)
            self.medium, self.tables = medium, tables
            trace = self.map.trace(medium, self.emitters, volume.value_range)
            stats.update(mode="full", photons_retraced=self.photons, photon_fraction=1.0,
                         interactions_added=trace["interactions_added"], query_bins=BITS)
            stats["ms"]["trace"] = trace["ms"]
            self._light_key = light_key
            self._full_pending = True
            self._pending_query = (ALL_BITS, ALL_BITS)
        else:
            hq = query_masks(self.tables, tables, volume.value_range)
            self.medium, self.tables = medium, tables
            if hq[0] or hq[1]:
                stats.update(self._incremental(volume, hq))
        if stats["mode"] != "unchanged":
            t_hash = time.perf_counter()
            # The hash only moves when photons did; σ̄t only when σt did.
            if stats["mode"] == "full" or stats["photons_retraced"] > 0:
                self.grid = build_photon_grid(self.map.interactions, self.map.total,
                                              volume.extent, self.radius, self.min_order,
                                              device)
            if stats["mode"] == "full" or stats.get("sigma_changed", True):
                self.extinction = mean_extinction(
                    self.medium, volume, self.radius, device,
                    None if stats["mode"] == "full" else self.extinction.mask,
                    bin_scale(volume.value_range))
            wp.synchronize_device(device)
            stats["ms"]["hash"] = 1e3 * (time.perf_counter() - t_hash)
            self._accum = None
        stats["ms"]["total"] = 1e3 * (time.perf_counter() - t0)
        stats["interactions"] = self.map.total
        stats["capped"] = self.map.stats.get("capped", 0)
        self.last_update = stats
        return stats

    def _incremental(self, volume, hq: tuple) -> dict:
        device = self.device
        pm = self.map
        t0 = time.perf_counter()
        n = pm.n_photons
        flags = wp.empty(n, dtype=wp.int32, device=device)
        restart = wp.empty(n, dtype=wp.int32, device=device)
        spatial = wp.zeros(3, dtype=wp.uint64, device=device)
        removed = wp.zeros(1, dtype=wp.int32, device=device)
        scale = wp.vec3(*(BITS / np.asarray(volume.extent, np.float64)).astype(np.float32))
        wp.launch(photon_query_kernel, dim=n,
                  inputs=[pm.start, pm.count, pm.path_hist, pm.path_chist, pm.interactions,
                          wp.uint64(hq[0]), wp.uint64(hq[1]), self.min_order, scale, flags,
                          restart, spatial, removed],
                  device=device)
        photons, restarts = select(flags, restart, device)
        n_work = int(photons.shape[0])
        kept = wp.zeros(max(n_work, 1), dtype=wp.int32, device=device)
        if n_work:
            wp.launch(kept_count_kernel, dim=n_work, inputs=[photons, restarts, pm.start, kept],
                      device=device)
        wp.synchronize_device(device)
        t_trace = time.perf_counter()
        added = 0
        if n_work:
            trace = pm.retrace(self.medium, self.emitters, volume.value_range, photons,
                               restarts)
            added = trace["interactions_added"]
            wp.launch(mark_added_kernel, dim=n_work,
                      inputs=[photons, kept, pm.start, pm.count, pm.interactions,
                              self.min_order, scale, spatial], device=device)
        wp.synchronize_device(device)
        t_end = time.perf_counter()
        self._pending_query = (self._pending_query[0] | int(hq[0]),
                               self._pending_query[1] | int(hq[1]))
        self._pending_spatial |= spatial.numpy()
        return {"mode": "incremental", "photons_retraced": n_work, "sigma_changed": bool(hq[0]),
                "photon_fraction": n_work / n, "interactions_removed": int(removed.numpy()[0]),
                "interactions_added": int(added),
                "query_bins": (int(hq[0]) | int(hq[1])).bit_count(),
                "ms": {"query": 1e3 * (t_trace - t0), "trace": 1e3 * (t_end - t_trace),
                       "hash": 0.0}}

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
            self._seg = {"rad": wp.zeros(n_seg, dtype=wp.vec3, device=device),
                         "t": wp.ones(n_seg, dtype=wp.float32, device=device),
                         "hist": wp.zeros(n_seg, dtype=wp.uint64, device=device),
                         "chist": wp.zeros(n_seg, dtype=wp.uint64, device=device),
                         "state": wp.zeros(n_seg, dtype=wp.int32, device=device)}
            self._accum = None
            mode = "full"
        elif any(self._pending_query) or self._pending_spatial.any():
            _, vp, cam, _, _ = self._view
            queried = True
            flags = wp.empty(n_seg, dtype=wp.int32, device=device)
            scale = wp.vec3(*(BITS / np.asarray(volume.extent, np.float64)).astype(np.float32))
            spatial = wp.array(self._pending_spatial, dtype=wp.uint64, device=device)
            wp.launch(segment_query_kernel, dim=n_seg,
                      inputs=[self.medium, cam, vp, self._seg["hist"], self._seg["chist"],
                              self._seg["state"], wp.uint64(self._pending_query[0]),
                              wp.uint64(self._pending_query[1]), spatial,
                              int(self.spatial_historygram), scale, self.radius, flags],
                      device=device)
            work, _ = select(flags, flags, device)
            recomputed = int(work.shape[0])
            if recomputed:
                wp.launch(recompute_kernel, dim=recomputed,
                          inputs=[self.medium, cam, self.lights, self.grid, self.extinction,
                                  self.surface, vp, work, self._seg["rad"], self._seg["t"], self._seg["hist"],
                                  self._seg["chist"]],
                          device=device)
            mode = "incremental"
        else:
            _, vp, cam, _, _ = self._view
            mode = "unchanged"
        t_seg = time.perf_counter()
        radiance, alpha, computed = composite_segments(
            self.medium, cam, self.lights, self.grid, self.extinction, self.surface, vp,
            self._seg, int(width), int(height), device,
            None if progress is None else (lambda f: progress(0.95 * f)))
        wp.synchronize_device(device)
        t_end = time.perf_counter()
        self._pending_query = (0, 0)
        self._pending_spatial[:] = 0
        self._full_pending = False
        n_computed = int(computed.numpy()[0])
        info = {"mode": mode, "segments": n_seg,
                "segments_recomputed": recomputed + n_computed,
                "segment_fraction": (recomputed + n_computed) / max(n_seg, 1),
                "segments_queried": queried,
                "ms": {"segments": 1e3 * (t_seg - t0), "composite": 1e3 * (t_end - t_seg)}}
        self.last_render = info
        result = RenderResult(radiance.numpy().astype(np.float32),
                              alpha.numpy().astype(np.float32), {"photon_render": info})
        if mode == "unchanged" and self._accum is not None and self._accum[2] > 1:
            rad_sum, alpha_sum, done = self._accum  # keep the progressive average
            result = RenderResult((rad_sum / done).astype(np.float32),
                                  (alpha_sum / done).astype(np.float32), result.info)
        else:
            self._accum = (result.radiance.astype(np.float64), result.alpha.astype(np.float64), 1)
        info["passes"] = self._accum[2]
        if progress is not None:
            progress(1.0)
        return result

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
            seg = {"rad": wp.zeros(h * w, dtype=wp.vec3, device=self.device),
                   "t": wp.ones(h * w, dtype=wp.float32, device=self.device),
                   "hist": wp.zeros(h * w, dtype=wp.uint64, device=self.device),
                   "chist": wp.zeros(h * w, dtype=wp.uint64, device=self.device),
                   "state": wp.zeros(h * w, dtype=wp.int32, device=self.device)}
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

    def fluence(self, volume, shape, passes: int = 1, progress=None) -> np.ndarray:
        """Photon fluence ``φ`` on a grid of ``shape`` points covering the volume's box.

        Pass 0 uses the kept photon map; passes 1 .. ``passes - 1`` trace independent maps
        with the shrinking radii of :func:`radius_schedule` and are averaged in.
        Returns (nx, ny, nz, 3) float32, the lights' irradiance units.
        """
        from vtkillum.core.photon.density import accumulate_fluence, fluence_grid

        if self.map is None:
            raise ValueError("call update(volume, transfer_function, ...) before fluence()")
        shape = tuple(int(n) for n in shape)
        first = fluence_grid(self.grid, self.extinction, shape, volume.extent, self.device,
                             to_numpy=False)
        if int(passes) <= 1:
            return first.numpy().reshape(*shape, 3)
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
        return (total.numpy().reshape(*shape, 3) / int(passes)).astype(np.float32)

    def segments_numpy(self) -> dict:
        """The stored segments as numpy arrays (``rad``, ``t``, ``hist``, ``state``), each
        indexed ``pixel * V_n + i`` with ``pixel = row * width + col``."""
        if self._seg is None:
            return {}
        return {name: a.numpy().copy() for name, a in self._seg.items()}

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


def check_config(photons, radius, max_order, segments, direct, alpha) -> None:
    """Raise ``ValueError`` naming the first invalid photon-mapping setting."""
    if isinstance(photons, bool) or not float(photons).is_integer() or int(photons) < 1:
        raise ValueError(f"photon.photons must be a positive integer, got {photons!r}")
    if not (np.isfinite(radius) and radius > 0):
        raise ValueError(f"photon.radius must be positive, got {radius!r}")
    if isinstance(max_order, bool) or not float(max_order).is_integer() or int(max_order) < 0:
        raise ValueError(f"photon.max_order (S_n) must be an integer >= 0 (0: unbounded), got "
                         f"{max_order!r}")
    if isinstance(segments, bool) or not float(segments).is_integer() or int(segments) < 1:
        raise ValueError(f"photon.segments (V_n) must be a positive integer, got {segments!r}")
    if direct not in DIRECT_MODES:
        raise ValueError(f"photon.direct must be one of {DIRECT_MODES}, got {direct!r}")
    if not (0.0 < float(alpha) < 1.0):
        raise ValueError(f"photon.alpha must lie in (0, 1), got {alpha!r}")
