"""Photon tracing (Jönsson et al. 2012, section 3.2, eqs. 6–7) into a retraceable photon map.

A photon leaves a light (:mod:`~vtkillum.core.photon.emission`) and walks through the
volume (local frame, world units):

1. **Free path** (eq. 6). A threshold ``τ* = -ln(1 - u)`` is drawn and the optical
   depth is ray-marched from where the photon enters the box: the distance to the box
   exit is split into equal steps no longer than ``step`` (world units), each with σt
   of the data value at a jittered point of the step (offset ``ξ`` per flight); the
   interaction lies where the accumulated depth reaches ``τ*`` (exactly, within the
   step, for the step's σt). A photon that reaches the box exit escapes. (The paper's
   inversion method; the path tracer uses delta tracking instead.)
2. **Store** the interaction (:mod:`~vtkillum.core.photon.storage`): position, incoming
   travel direction, incoming RGB flux ``Φ``, the data value of the step, the
   Historygram ``H`` (eq. 9: the data bins of every value the photon sampled so far,
   ancestors included), the random-number state, the order ``k`` (1 for light that has
   not scattered yet).
3. **Scattering order**: after its ``S_n``-th interaction the photon stops
   (``max_order``; ``S_n = 1`` gives single scattering; 0 leaves the walk to the
   roulette).
4. **Russian roulette** (eq. 7): the photon scatters with probability
   ``q = max_c Λ color_c(s)`` (``σs/σt`` for a grey medium) and then carries
   ``Φ Λ color(s) / q``, so that coloured media need no spectral sampling; otherwise it
   is absorbed.
5. **Direction**: Henyey–Greenstein importance sampling of the new direction (or the
   optional BRDF of surface-like samples, :mod:`~vtkillum.core.photon.material`).

Every random number of photon ``p`` comes from one PCG stream seeded by
``(seed, p)``, consumed in a fixed order; the state after each interaction is stored,
so a photon retraced from interaction ``j`` repeats exactly what a trace from scratch
would do past ``j`` under the same optical properties (the basis of the "incremental
== full recompute" guarantee of the Historygrams).

On the GPU the tracing queues its work without waiting for the device where it can: with
a bounded ``S_n`` every path ends in one round, and the counts (interactions stored,
added, capped) stay on the device until :meth:`PhotonMap.resolve` reads them once, after
the hash and σ̄t are queued too (:meth:`~vtkillum.core.photon.mapper.PhotonMapper.update`).

A walk that goes on past :data:`MAX_VERTICES` interactions (albedo ~1 without escape) is
cut there and counted (``PhotonMap.stats["capped"]``), never silently. A flight marches
at most ``MAX_STEPS_PER_RAY`` steps across the volume (a smaller ``photon_step`` is
refused), and on the CPU a tracing round is launched in chunks of photons of about
:data:`TRACE_CHUNK_SAMPLES` estimated samples, so Ctrl-C is seen between launches.
"""

from __future__ import annotations

import time

import numpy as np
import warp as wp

from vtkillum.core.device import init_warp, resolve_device
from vtkillum.core.photon.emission import Emitters, emit_photon
from vtkillum.core.photon.historygram import bin_scale, data_bin
from vtkillum.core.photon.material import (
    SurfaceParams,
    no_surface,
    sample_scattering,
    surface_normal,
)
from vtkillum.core.photon.storage import (
    ABSORBED,
    CAPPED,
    ESCAPED,
    INTERACTION_BYTES,
    ORDER_LIMIT,
    OVERFLOW,
    RECORD_BYTES,
    Interactions,
    Record,
    allocate,
    allocate_scratch,
    check_fits,
    compact,
    exclusive_scan,
    free_bytes,
    gather_int_kernel,
    select,
)
from vtkillum.core.photon.tables import DeviceTables, table_range
from vtkillum.core.raymarch import MAX_STEPS_PER_RAY
from vtkillum.core.transfer_function import TABLE_SIZE
from vtkillum.core.warp_common import (
    Medium,
    attach_occupancy,
    capped_kernel,
    device_scalars,
    lookup_color,
    lookup_sigma_t,
    ray_box,
    sample_scalar,
    uniform,
)

init_warp()

#: Safety cap on the interactions of one photon (counted in ``stats["capped"]``).
MAX_VERTICES = 10_000
#: Scratch slots per photon in the first tracing round when ``S_n`` is unbounded.
FIRST_ROUND_SLOTS = 8
#: Largest scratch slots per work item in later rounds.
MAX_ROUND_SLOTS = 4096
#: Estimated samples per tracing launch (``FLIGHTS_PER_PHOTON`` flights of ``diagonal /
#: step`` samples per photon): CPU launches stay well under a second, so Ctrl-C is seen.
TRACE_CHUNK_SAMPLES = {"cpu": 1 << 23, "cuda": 1 << 62}
FLIGHTS_PER_PHOTON = 4
#: Register cap of the tracing kernel on CUDA (more warps waiting on the volume at once;
#: H100, 4 M photons: 8.6 -> 7.9 ms, from 126 registers).
TRACE_REGISTERS = 64
#: Devices (name prefixes) on which photons are traced in the order of where they leave
#: the lights (:func:`emission_order`; the CPU has no warps to keep together).
COHERENT_DEVICES = ("cuda",)
#: Threads of :func:`path_masks_kernel` (each ORs every ``MASK_THREADS``-th path).
MASK_THREADS = 1 << 16
#: :attr:`PhotonMap.path_masks` before a trace is resolved: every bin.
PATH_MASK_ALL = (1 << 64) - 1


@wp.struct
class TraceParams:
    """What a tracing launch needs besides the medium and the lights.

    ``seed``: the photon map's seed (photon ``p`` uses ``rand_init(seed, p)``);
    ``step``: longest ray-marching step (world units); ``max_order``: ``S_n`` (0:
    unbounded); ``max_vertices``: safety cap; ``capacity``: scratch slots per work item;
    ``bin_lo``, ``bin_scale``: the data binning of the Historygrams.
    """

    seed: int
    step: float
    max_order: int
    max_vertices: int
    capacity: int
    bin_lo: float
    bin_scale: float


def photon_tables(transfer_function, unit_distance: float, value_range, size: int = TABLE_SIZE):
    """σt and colour tables sampled at ``size`` values spanning exactly the data range.

    The kernels only ever look up values inside the data range (trilinear interpolation
    stays within it), so tables over that range alone keep the same entries through any
    transfer-function edit, and :func:`~vtkillum.core.photon.historygram.query_mask` can
    compare them entry by entry. The mapper makes the same tables on the device
    (:class:`~vtkillum.core.photon.tables.DeviceTables`); this host version is their
    reference (the tests hold the two within one float32 step).

    Returns
    -------
    sigma : ndarray (size,) float32
    color : ndarray (size, 3) float32
    lo, hi : float
    """
    lo, hi = table_range(value_range)
    v = np.linspace(lo, hi, size)
    sigma, color = transfer_function.sigma_t_and_color(v, unit_distance)
    return sigma.astype(np.float32), color.astype(np.float32), lo, hi


def photon_medium(volume, transfer_function, unit_distance: float, albedo: float, g: float,
                  device: str, previous: tuple | None = None):
    """A :class:`Medium` whose tables are :class:`~vtkillum.core.photon.tables.DeviceTables`
    (returned as well: they hold the query Historygrams of the edit from ``previous``).

    ``previous``: ``(medium, tables)`` of the same volume, albedo and g (an earlier call);
    the tables say which bins the edit changed, and where no σt entry changed, the
    block occupancy is reused (a colour edit touches the colour table alone). The tables
    equal :func:`photon_tables` to float32 rounding.
    """
    device = resolve_device(device)
    tables = DeviceTables(transfer_function, unit_distance, volume.value_range, device,
                          None if previous is None else previous[1])
    m = Medium()  # make_medium's fields, with these tables (not make_medium's own)
    m.scalars = device_scalars(volume, device)
    m.extent = wp.vec3(*volume.extent.astype(np.float32))
    m.inv_spacing = wp.vec3(*(1.0 / volume.spacing).astype(np.float32))
    m.albedo = float(albedo)
    m.g = float(g)
    m.sigma_table = tables.sigma
    m.color_table = tables.color
    m.table_lo = float(tables.lo)
    m.table_scale = float(tables.scale)
    m.majorant = tables.peak * 1.0001 + 1e-12
    old = previous[0] if previous is not None else None
    if old is not None and not tables.sigma_changed and old.scalars is m.scalars:
        m.occupied, m.block, m.inv_block = old.occupied, old.block, old.inv_block
    else:
        attach_occupancy(m, volume, None, device)
    return m, tables


class PhotonMap:
    """``N`` photon paths and their stored interactions on one device.

    Parameters
    ----------
    n_photons : int
        Photons traced from the lights (paths); at least 1.
    device : str
        Warp device.
    seed : int
        Seed of the photons' random streams (already mixed with the pass number).
    max_order : int
        ``S_n``: interactions stored per path at most (0: unbounded, roulette only).
    step : float
        Longest ray-marching step of the free-path sampling, world units.
    memory_limit_mb : float, optional
        Cap on the memory the map may use (default: what the device has free).
    surface : SurfaceParams, optional
        Surface-like materials (:mod:`~vtkillum.core.photon.material`); default off.

    Attributes
    ----------
    start, count : wp.array(int32) (N,)
        Each path's interactions are ``interactions[start[p] : start[p] + count[p]]``.
    path_hist : wp.array(uint64) (N,)
        Historygram of everything the path used, including the flight after its last
        interaction (how it escaped) -- a path whose mask misses the query is valid.
    end : wp.array(int32) (N,)
        Why each path ended (:data:`~vtkillum.core.photon.storage.END_NAMES`).
    interactions : Interactions
    total : int
        Stored interactions.
    stats : dict
        Of the last trace/retrace: ``photons`` traced, ``interactions_added``, ``rounds``,
        ``capped``, ``ms``.
    """

    def __init__(self, n_photons: int, device: str, seed: int = 0, max_order: int = 0,
                 step: float = 1.0, memory_limit_mb: float | None = None,
                 surface: SurfaceParams | None = None) -> None:
        self.n_photons = int(n_photons)
        if self.n_photons < 1:
            raise ValueError(f"photons must be a positive number, got {n_photons!r}")
        self.device = device
        self.seed = int(seed)
        self.max_order = int(max_order)
        self.step = float(step)
        self.memory_limit_mb = memory_limit_mb
        self.surface = no_surface() if surface is None else surface
        self.first_slots = (self.max_order if 0 < self.max_order <= FIRST_ROUND_SLOTS
                            else FIRST_ROUND_SLOTS)
        check_fits(self.n_photons, min(self.first_slots, 2), self.first_slots, device,
                   memory_limit_mb)
        n = self.n_photons
        self.start = wp.zeros(n, dtype=wp.int32, device=device)
        self.count = wp.zeros(n, dtype=wp.int32, device=device)
        self.path_hist = wp.zeros(n, dtype=wp.uint64, device=device)
        self.path_chist = wp.zeros(n, dtype=wp.uint64, device=device)
        self.end = wp.zeros(n, dtype=wp.int32, device=device)
        self.interactions: Interactions = allocate(1, device)
        self._total = 0
        self._counters = None  # device (added, capped, total) of a trace not yet resolved
        self._masks = None  # (device, host) OR of every path's (hist, chist), not yet read
        self._mask_buffers = None  # kept: a trace queues no allocation for them
        #: The OR of every path's Historygrams ``(path_hist, path_chist)`` as Python ints
        #: (every bit until a trace is resolved): a query that misses both invalidates no
        #: photon, and needs no look at the paths.
        self.path_masks = (PATH_MASK_ALL, PATH_MASK_ALL)
        self.stats: dict = {}

    @property
    def total(self) -> int:
        """Stored interactions (waits for the device when a trace is still pending)."""
        if self._total is None:
            self.resolve()
        return self._total

    @total.setter
    def total(self, value: int) -> None:
        self._total = int(value)

    @property
    def capacity(self) -> int:
        """Slots of the interaction buffer (at least :attr:`total`)."""
        return int(self.interactions.pos.shape[0])

    def resolve(self) -> dict:
        """Read the counts of the last trace from the device (one wait) into :attr:`stats`
        (``interactions_added``, ``capped``, ``total``) and :attr:`total`."""
        synced = self._counters is not None  # (its copy waits for everything queued)
        if self._counters is not None:
            added, capped, total = (int(c) for c in self._counters.numpy())
            self._counters = None
            if self._total is None:
                self._total = total
            self.stats.update(interactions_added=added, capped=capped)
        if self._masks is not None:
            dev, host = self._masks
            if host is None:
                host = dev.numpy()
            elif not synced:
                wp.synchronize_device(self.device)
            self.path_masks = tuple(int(v) for v in host)
            self._masks = None
        self.stats["total"] = self._total
        return self.stats

    # --- tracing ---------------------------------------------------------------------------------
    def trace(self, medium: Medium, emitters: Emitters, value_range,
              resolve: bool = True) -> dict:
        """Trace every photon from its light (discarding what was stored); ``resolve`` as in
        :meth:`retrace`."""
        self.count.zero_()
        self.start.zero_()
        self.total = 0
        self._counters = None
        photons = emission_order(emitters, self.seed, self.n_photons, self.device)
        restart = wp.full(self.n_photons, -1, dtype=wp.int32, device=self.device)
        return self.retrace(medium, emitters, value_range, photons, restart, resolve,
                            _from_light=True)

    def retrace(self, medium: Medium, emitters: Emitters, value_range, photons: wp.array,
                restart: wp.array, resolve: bool = True, *, _from_light: bool = False) -> dict:
        """Retrace ``photons`` from their interaction ``restart`` (buffer index; -1: the light).

        Each listed photon keeps its interactions up to and including ``restart`` and gets
        a new tail traced from there with the stored random state; all other photons keep
        theirs. ``photons`` must be unique; their order is the order of the work items
        (the stored layout does not depend on it).

        With ``0 < S_n <=`` :data:`FIRST_ROUND_SLOTS` every path ends in one round (its
        scratch holds ``S_n`` interactions), and the round runs without waiting for the
        device: the new buffer is allocated for the most interactions the round can leave
        (the old ones plus ``S_n`` per work item) and the count stays on the device until
        :meth:`resolve` (``resolve=False``: the caller resolves later, so that more work can
        be queued first; :attr:`total` resolves when read). Otherwise rounds continue the
        paths whose scratch overflowed, with the counts read after each.
        """
        t0 = time.perf_counter()
        device = self.device
        diagonal = float(np.linalg.norm(np.asarray(medium.extent, dtype=np.float64)))
        flight = int(np.ceil(diagonal / self.step))
        if flight > MAX_STEPS_PER_RAY:
            raise ValueError(
                f"photon_step {self.step:g} needs {flight} samples per photon flight across "
                f"the volume; use at least {diagonal / MAX_STEPS_PER_RAY:.3g} world units")
        budget = TRACE_CHUNK_SAMPLES["cpu" if device == "cpu" else "cuda"]
        chunk = max(1, budget // (FLIGHTS_PER_PHOTON * flight))
        lo, scale = bin_scale(value_range)
        traced = int(photons.shape[0])
        counters = wp.zeros(3, dtype=wp.int32, device=device)  # added, capped, total
        rounds = 0
        slots = self.first_slots
        if 0 < self.max_order <= FIRST_ROUND_SLOTS and traced > 0:
            params = TraceParams()
            params.seed = self.seed
            params.step = self.step
            params.max_order = self.max_order
            params.max_vertices = MAX_VERTICES
            params.capacity = self.max_order
            params.bin_lo = lo
            params.bin_scale = scale
            if self._one_round(medium, emitters, params, photons, restart, chunk, counters,
                               _from_light):
                self.stats = {"photons": traced, "rounds": 1,
                              "ms": 1e3 * (time.perf_counter() - t0)}
                self._counters = counters
                self._queue_path_masks()
                return self.resolve() if resolve else self.stats
        while photons.shape[0] > 0:
            n_work = int(photons.shape[0])
            if rounds > 0:
                slots = int(min(MAX_ROUND_SLOTS,
                                max(self.first_slots, self.n_photons * self.first_slots // n_work)))
            params = TraceParams()
            params.seed = self.seed
            params.step = self.step
            params.max_order = self.max_order
            params.max_vertices = MAX_VERTICES
            params.capacity = slots
            params.bin_lo = lo
            params.bin_scale = scale
            scratch = _allocate_checked(n_work * slots, device, self.memory_limit_mb,
                                        self.n_photons)
            work_count, work_hist, work_chist, work_end = self._launch_trace(
                medium, emitters, params, photons, restart, scratch, n_work, chunk, wp.zeros)
            keep = wp.clone(self.count)
            new_count = wp.clone(self.count)
            wp.launch(new_counts_kernel, dim=n_work,
                      inputs=[photons, restart, self.start, work_count, work_end, keep,
                              new_count, counters], device=device)
            new_start = wp.empty(self.n_photons, dtype=wp.int32, device=device)
            new_total = exclusive_scan(new_count, new_start)
            _check_total(new_total, self.total, self.n_photons, device, self.memory_limit_mb)
            new = compact(self.interactions, self.total, self.start, keep, new_start, scratch,
                          slots, photons, work_count, new_total, device)
            del scratch
            next_flag = wp.zeros(n_work, dtype=wp.int32, device=device)
            next_restart = wp.zeros(n_work, dtype=wp.int32, device=device)
            wp.launch(finish_paths_kernel, dim=n_work,
                      inputs=[photons, work_hist, work_chist, work_end, new_start, new_count,
                              self.path_hist, self.path_chist, self.end, next_flag,
                              next_restart],
                      device=device)
            self.interactions, self.start, self.count, self.total = new, new_start, new_count, \
                new_total
            work_idx, restart = select(next_flag, next_restart, device)
            finished = photons
            photons = wp.empty(work_idx.shape[0], dtype=wp.int32, device=device)
            if work_idx.shape[0] > 0:
                wp.launch(gather_int_kernel, dim=work_idx.shape[0],
                          inputs=[work_idx, finished, photons], device=device)
            rounds += 1
        self._queue_path_masks()
        self.resolve()
        added, capped, _ = (int(c) for c in counters.numpy())
        self.stats = {"photons": traced, "interactions_added": added, "rounds": rounds,
                      "capped": capped, "total": self.total,
                      "ms": 1e3 * (time.perf_counter() - t0)}
        return self.stats

    def _queue_path_masks(self) -> None:
        """Queue the OR of every path's Historygrams (read by :meth:`resolve`; on CUDA copied
        to page-locked memory in the same queue, so that the wait for the counts covers it)."""
        device = self.device
        if self._mask_buffers is None:
            cuda = wp.get_device(device).is_cuda
            self._mask_buffers = (
                wp.zeros(2, dtype=wp.uint64, device=device),
                wp.zeros(2, dtype=wp.uint64, device="cpu", pinned=True) if cuda else None)
        dev, host = self._mask_buffers
        dev.zero_()
        threads = min(self.n_photons, MASK_THREADS)
        wp.launch(path_masks_kernel, dim=threads,
                  inputs=[self.path_hist, self.path_chist, threads, dev], device=device)
        if host is not None:
            wp.copy(host, dev)
        self._masks = (dev, None if host is None else host.numpy())

    def _launch_trace(self, medium, emitters, params, photons, restart, scratch, n_work: int,
                      chunk: int, allocate):
        """Launch :func:`trace_kernel` over ``n_work`` work items in chunks; returns the
        per-item ``(count, hist, chist, end)`` arrays, made by ``allocate`` (``wp.zeros`` or
        ``wp.empty``)."""
        device = self.device
        work_count = allocate(n_work, dtype=wp.int32, device=device)
        work_hist = allocate(n_work, dtype=wp.uint64, device=device)
        work_chist = allocate(n_work, dtype=wp.uint64, device=device)
        work_end = allocate(n_work, dtype=wp.int32, device=device)
        for w0 in range(0, n_work, chunk):
            wp.launch(trace_kernel, dim=min(chunk, n_work - w0),
                      inputs=[medium, emitters, params, self.surface, photons, restart,
                              self.interactions, w0,
                              scratch, work_count, work_hist, work_chist, work_end],
                      device=device)
        return work_count, work_hist, work_chist, work_end

    def _one_round(self, medium, emitters, params, photons, restart, chunk, counters,
                   from_light: bool) -> bool:
        """The round of :meth:`retrace` when every path ends in it, queued without a wait
        (False, nothing done: the buffers for the most it can leave do not fit).

        ``from_light``: every photon traced from its light (:meth:`trace`, all counts zero,
        work items in the emission order): the results are then gathered in photon order
        (:func:`from_light_paths_kernel`, :func:`~vtkillum.core.photon.storage.compact`),
        reads from scattered places instead of writes."""
        device = self.device
        n_work = int(photons.shape[0])
        slots = int(params.capacity)
        old_total = self.total
        capacity = old_total + n_work * slots
        need = (n_work * slots * RECORD_BYTES + capacity * INTERACTION_BYTES
                + n_work * 32 + self.n_photons * 16)
        if capacity >= 2**31 - 1 or need > free_bytes(device, self.memory_limit_mb):
            return False
        scratch = allocate_scratch(n_work * slots, device)
        work_count, work_hist, work_chist, work_end = self._launch_trace(
            medium, emitters, params, photons, restart, scratch, n_work, chunk, wp.empty)
        new_start = wp.empty(self.n_photons, dtype=wp.int32, device=device)
        if from_light:
            work_of = wp.empty(self.n_photons, dtype=wp.int32, device=device)
            wp.launch(inverse_kernel, dim=n_work, inputs=[photons, work_of], device=device)
            keep = self.count  # zero
            new_count = wp.empty(self.n_photons, dtype=wp.int32, device=device)
            wp.launch(from_light_paths_kernel, dim=self.n_photons,
                      inputs=[work_of, work_count, work_hist, work_chist, work_end, new_count,
                              self.path_hist, self.path_chist, self.end, counters],
                      device=device)
            wp.utils.array_scan(new_count, new_start, inclusive=False)
            wp.launch(total_kernel, dim=1, inputs=[new_start, new_count, counters, 1],
                      device=device)
            new = compact(self.interactions, 0, self.start, keep, new_start, scratch, slots,
                          photons, work_count, capacity, device, work_of)
        else:
            keep = wp.clone(self.count)
            new_count = wp.clone(self.count)
            wp.launch(new_counts_kernel, dim=n_work,
                      inputs=[photons, restart, self.start, work_count, work_end, keep,
                              new_count, counters], device=device)
            wp.utils.array_scan(new_count, new_start, inclusive=False)
            wp.launch(total_kernel, dim=1, inputs=[new_start, new_count, counters, 0],
                      device=device)
            new = compact(self.interactions, old_total, self.start, keep, new_start, scratch,
                          slots, photons, work_count, capacity, device)
            unused = wp.empty(1, dtype=wp.int32, device=device)  # no path overflows here
            wp.launch(finish_paths_kernel, dim=n_work,
                      inputs=[photons, work_hist, work_chist, work_end, new_start, new_count,
                              self.path_hist, self.path_chist, self.end, unused, unused],
                      device=device)
        self.interactions, self.start, self.count = new, new_start, new_count
        self._total = None
        return True

    # --- inspection ------------------------------------------------------------------------------
    def numpy(self) -> dict:
        """Copies of all interaction fields and path tables as numpy arrays (tests, debugging)."""
        n = self.total
        it = self.interactions
        out = {name: getattr(it, name).numpy()[:n].copy() for name in
               ("pos", "dir", "flux", "value", "hist", "chist", "rng", "order", "owner")}
        out.update(start=self.start.numpy().copy(), count=self.count.numpy().copy(),
                   path_hist=self.path_hist.numpy().copy(),
                   path_chist=self.path_chist.numpy().copy(), end=self.end.numpy().copy())
        return out


def emission_order(emitters: Emitters, seed: int, n_photons: int, device: str) -> wp.array:
    """All photons, ordered so that neighbouring work items leave the lights alike.

    A work item traces photon ``order[w]``. Photon ``p``'s start is drawn from its own
    stream, so neighbouring indices leave in unrelated directions and a warp's flights
    diverge (trip counts) and read the volume all over. Sorting the photons by their
    light and a Morton code of the two numbers that place them on it (direction on a
    point light's cone, start point on a directional light's rectangle) lets a warp march
    side by side. On devices not in :data:`COHERENT_DEVICES` (the CPU: no warps) photons
    stay in index order. The photon map does not depend on the order (its layout follows
    the photon index).
    """
    photons = wp.empty(n_photons, dtype=wp.int32, device=device)
    if not str(device).startswith(tuple(COHERENT_DEVICES)) or n_photons < 2:
        wp.launch(iota_kernel, dim=n_photons, inputs=[photons], device=device)
        return photons
    keys = wp.empty(2 * n_photons, dtype=wp.int32, device=device)
    values = wp.empty(2 * n_photons, dtype=wp.int32, device=device)
    wp.launch(emission_key_kernel, dim=n_photons, inputs=[emitters, int(seed), keys, values],
              device=device)
    wp.utils.radix_sort_pairs(keys, values, n_photons)
    wp.copy(photons, values, count=n_photons)
    return photons


def _allocate_checked(n: int, device: str, limit_mb, n_photons: int) -> wp.array:
    need = max(n, 1) * RECORD_BYTES
    if need > free_bytes(device, limit_mb):
        check_fits(n_photons, n / max(n_photons, 1), 0, device, limit_mb)
    return allocate_scratch(n, device)


def _check_total(new_total: int, old_total: int, n_photons: int, device: str, limit_mb) -> None:
    if new_total >= 2**31 - 1:
        raise MemoryError(f"{new_total:,} photon interactions exceed the 32-bit index range; "
                          f"use fewer photons (at most about {n_photons * 2**31 // new_total:,})")
    if new_total * INTERACTION_BYTES > free_bytes(device, limit_mb):
        check_fits(n_photons, new_total / n_photons, 0, device, limit_mb)


# --- kernels -------------------------------------------------------------------------------------
@wp.kernel
def path_masks_kernel(path_hist: wp.array(dtype=wp.uint64), path_chist: wp.array(dtype=wp.uint64),
                      threads: int, out: wp.array(dtype=wp.uint64)):
    """``out[0] |= OR of path_hist``, ``out[1] |= OR of path_chist``; ``wp.tid()`` takes every
    ``threads``-th path (one atomic per thread, not per path)."""
    t = wp.tid()
    h = wp.uint64(0)
    c = wp.uint64(0)
    for p in range(t, path_hist.shape[0], threads):
        h = h | path_hist[p]
        c = c | path_chist[p]
    if h != wp.uint64(0):
        wp.atomic_or(out, 0, h)
    if c != wp.uint64(0):
        wp.atomic_or(out, 1, c)


@capped_kernel(TRACE_REGISTERS)
def trace_kernel(m: Medium, em: Emitters, tp: TraceParams, sp: SurfaceParams,
                 work_photon: wp.array(dtype=wp.int32),
                 work_restart: wp.array(dtype=wp.int32), stored: Interactions, w0: int,
                 scratch: wp.array(dtype=Record), work_count: wp.array(dtype=wp.int32),
                 work_hist: wp.array(dtype=wp.uint64), work_chist: wp.array(dtype=wp.uint64),
                 work_end: wp.array(dtype=wp.int32)):
    """Trace one photon path (or its tail) into scratch.

    ``w0 + wp.tid()`` indexes the work list: photon ``work_photon[w]`` restarts at stored
    interaction ``work_restart[w]`` (-1: emitted afresh) and writes up to ``tp.capacity``
    interactions to ``scratch[w * capacity ...]``. Positions in the local frame (world
    units), flux in the lights' power units. Writes the number written, the path's
    Historygrams at its end and why it ended (``OVERFLOW``: scratch full, to be continued
    from the last interaction written).
    """
    w = w0 + wp.tid()
    p = work_photon[w]
    j = work_restart[w]
    base = w * tp.capacity
    n = int(0)
    x = wp.vec3(0.0)
    d = wp.vec3(0.0, 0.0, 1.0)
    phi = wp.vec3(0.0)
    H = wp.uint64(0)
    C = wp.uint64(0)
    order = int(0)
    s = float(0.0)
    state = wp.uint32(0)
    scatter = int(0)
    if j < 0:
        state = wp.rand_init(tp.seed, p)
        x, d, phi, state = emit_photon(em, state)
    else:
        x = stored.pos[j]
        d = stored.dir[j]
        phi = stored.flux[j]
        s = stored.value[j]
        H = stored.hist[j]
        C = stored.chist[j]
        state = stored.rng[j]
        order = stored.order[j]
        scatter = 1
    end = int(ESCAPED)
    while True:
        if scatter != 0:
            if tp.max_order > 0 and order >= tp.max_order:
                end = ORDER_LIMIT
                break
            if order >= tp.max_vertices:
                end = CAPPED
                break
            C = C | data_bin(s, tp.bin_lo, tp.bin_scale)
            a = m.albedo * lookup_color(m, s)
            q = wp.max(a[0], wp.max(a[1], a[2]))
            u, state = uniform(state)
            if u >= q:
                end = ABSORBED
                break
            phi = wp.cw_mul(phi, a) / q
            u1, state = uniform(state)
            u2, state = uniform(state)
            surf, normal = surface_normal(m, sp, x, s)
            d, weight = sample_scattering(d, m.g, surf, normal, sp, u1, u2)
            if surf != 0:
                phi = phi * weight
        scatter = 1
        box = ray_box(x, d, m.extent)
        t0 = wp.max(box[0], 0.0)
        t1 = box[1]
        if t1 <= t0:
            end = ESCAPED
            break
        u, state = uniform(state)
        tau_star = -wp.log(1.0 - u)
        xi, state = uniform(state)
        length = t1 - t0
        steps = wp.max(int(wp.ceil(length / tp.step)), 1)
        h = length / float(steps)
        tau = float(0.0)
        tc = float(-1.0)
        for i in range(steps):
            sv = sample_scalar(m.scalars, m.inv_spacing, x + (t0 + (float(i) + xi) * h) * d)
            H = H | data_bin(sv, tp.bin_lo, tp.bin_scale)
            sig = lookup_sigma_t(m, sv)
            if sig > 0.0 and tau + sig * h >= tau_star:
                tc = t0 + float(i) * h + (tau_star - tau) / sig
                s = sv
                break
            tau += sig * h
        if tc < 0.0:
            end = ESCAPED
            break
        x = x + tc * d
        order += 1
        rec = Record()
        rec.pos = x
        rec.dir = d
        rec.flux = phi
        rec.value = s
        rec.hist = H
        rec.chist = C
        rec.rng = state
        rec.order = order
        rec.owner = p
        scratch[base + n] = rec
        n += 1
        if tp.max_order > 0 and order >= tp.max_order:
            # What the next round would find on restarting here (before any random number
            # or bin is used): decided now, so paths of S_n interactions need no next round.
            end = ORDER_LIMIT
            break
        if n >= tp.capacity:
            end = OVERFLOW
            break
    work_count[w] = n
    work_hist[w] = H
    work_chist[w] = C
    work_end[w] = end


@wp.kernel
def new_counts_kernel(work_photon: wp.array(dtype=wp.int32), work_restart: wp.array(dtype=wp.int32),
                      start: wp.array(dtype=wp.int32), work_count: wp.array(dtype=wp.int32),
                      work_end: wp.array(dtype=wp.int32), keep: wp.array(dtype=wp.int32),
                      new_count: wp.array(dtype=wp.int32), counters: wp.array(dtype=wp.int32)):
    """``wp.tid()`` indexes the work list: the photon keeps its interactions up to the restart
    and gains the ones just traced (counted in ``counters[0]``; capped paths in
    ``counters[1]``)."""
    w = wp.tid()
    p = work_photon[w]
    j = work_restart[w]
    kept = int(0)
    if j >= 0:
        kept = j - start[p] + 1
    keep[p] = kept
    new_count[p] = kept + work_count[w]
    wp.atomic_add(counters, 0, work_count[w])
    if work_end[w] == CAPPED:
        wp.atomic_add(counters, 1, 1)


@wp.kernel
def finish_paths_kernel(work_photon: wp.array(dtype=wp.int32), work_hist: wp.array(dtype=wp.uint64),
                        work_chist: wp.array(dtype=wp.uint64), work_end: wp.array(dtype=wp.int32),
                        new_start: wp.array(dtype=wp.int32), new_count: wp.array(dtype=wp.int32),
                        path_hist: wp.array(dtype=wp.uint64),
                        path_chist: wp.array(dtype=wp.uint64), end: wp.array(dtype=wp.int32),
                        next_flag: wp.array(dtype=wp.int32), next_restart: wp.array(dtype=wp.int32)):
    """``wp.tid()`` indexes the work list: record how each path ended; paths whose scratch
    overflowed continue from their last interaction in the next round."""
    w = wp.tid()
    p = work_photon[w]
    path_hist[p] = work_hist[w]
    path_chist[p] = work_chist[w]
    end[p] = work_end[w]
    if work_end[w] == OVERFLOW:
        next_flag[w] = 1
        next_restart[w] = new_start[p] + new_count[p] - 1


@wp.kernel
def total_kernel(new_start: wp.array(dtype=wp.int32), new_count: wp.array(dtype=wp.int32),
                 counters: wp.array(dtype=wp.int32), all_added: int):
    """``counters[2]``: the interactions stored (the end of the last path); ``all_added``:
    every one of them was added by this trace (``counters[0]``)."""
    n = new_start.shape[0]
    counters[2] = new_start[n - 1] + new_count[n - 1]
    if all_added != 0:
        counters[0] = counters[2]


@wp.kernel
def inverse_kernel(photons: wp.array(dtype=wp.int32), work_of: wp.array(dtype=wp.int32)):
    """``wp.tid()`` indexes the work list: ``work_of[photons[w]] = w``."""
    w = wp.tid()
    work_of[photons[w]] = w


@wp.kernel
def from_light_paths_kernel(work_of: wp.array(dtype=wp.int32),
                            work_count: wp.array(dtype=wp.int32),
                            work_hist: wp.array(dtype=wp.uint64),
                            work_chist: wp.array(dtype=wp.uint64),
                            work_end: wp.array(dtype=wp.int32),
                            new_count: wp.array(dtype=wp.int32),
                            path_hist: wp.array(dtype=wp.uint64),
                            path_chist: wp.array(dtype=wp.uint64), end: wp.array(dtype=wp.int32),
                            counters: wp.array(dtype=wp.int32)):
    """``wp.tid()`` = photon ``p``, traced from its light as work item ``work_of[p]`` in a
    round that ends every path: its count and how it ended (:func:`new_counts_kernel` and
    :func:`finish_paths_kernel` in photon order; capped paths in ``counters[1]``)."""
    p = wp.tid()
    w = work_of[p]
    new_count[p] = work_count[w]
    path_hist[p] = work_hist[w]
    path_chist[p] = work_chist[w]
    end[p] = work_end[w]
    if work_end[w] == CAPPED:
        wp.atomic_add(counters, 1, 1)


@wp.func
def spread_bits(v: int):
    """The low 10 bits of ``v`` spread to every second bit (a Morton code's half)."""
    x = v & 0x3FF
    x = (x | (x << 8)) & 0x00FF00FF
    x = (x | (x << 4)) & 0x0F0F0F0F
    x = (x | (x << 2)) & 0x33333333
    x = (x | (x << 1)) & 0x55555555
    return x


@wp.kernel
def emission_key_kernel(em: Emitters, seed: int, keys: wp.array(dtype=wp.int32),
                        values: wp.array(dtype=wp.int32)):
    """``wp.tid()`` = photon ``p``: key = its light and the Morton code of the two uniform
    numbers that place it there (the draws of :func:`emit_photon`), value = ``p``."""
    p = wp.tid()
    state = wp.rand_init(seed, p)
    u, state = uniform(state)
    li = int(0)
    while li < em.count - 1 and u >= em.cdf[li]:
        li += 1
    u1, state = uniform(state)
    u2, state = uniform(state)
    a = wp.clamp(int(u1 * 1024.0), 0, 1023)
    b = wp.clamp(int(u2 * 1024.0), 0, 1023)
    keys[p] = (wp.min(li, 1023) << 20) | (spread_bits(a) << 1) | spread_bits(b)
    values[p] = p


@wp.kernel
def iota_kernel(out: wp.array(dtype=wp.int32)):
    """``wp.tid()`` indexes ``out``: ``out[i] = i``."""
    i = wp.tid()
    out[i] = i


