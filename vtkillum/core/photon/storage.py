"""The photon interaction buffer: one implicit linked list per photon path.

Jönsson et al. (section 5) keep photon interactions in "an implicitly linked list
where the photon interaction id determines the index into the list", so that a
Historygram query can walk back from a photon's last interaction. Here the
interactions of photon ``p`` occupy the contiguous range
``[start[p], start[p] + count[p])`` of the buffer, in scattering order: interaction
``start[p] + k`` is the photon's ``(k + 1)``-th interaction (``order = k + 1``; order 1
is light that has not scattered yet). ``start`` is the exclusive prefix sum of
``count``, so the layout is a function of the per-photon counts alone: a photon map
updated incrementally and one traced from scratch with the same seed are the same
bytes.

Per interaction (:class:`Interactions`, 68 bytes): position (local frame), incoming
travel direction, incoming RGB flux, the data value that placed it (its colour drives
the roulette), the Historygrams of everything the photon used up to here (extinction
and colour bins), the random-number state after placing it
(a retrace continues from here), the scattering order and the owning photon.

A retrace (:func:`vtkillum.core.photon.tracing.retrace`) replaces the tail of some
paths: it writes the new interactions to a scratch buffer (:class:`Record`: one
interaction's fields side by side, so that a thread's store or load is one contiguous
piece of memory), then :func:`compact` builds the new buffer in three parallel copies
(kept prefixes, new tails, path tables). When the work items are not in photon order (a
full trace in the order of :func:`~vtkillum.core.photon.tracing.emission_order`) the new
tails are copied in the order of the destination (:func:`copy_scratch_by_photon_kernel`):
reads of whole records from scattered places, writes in order, instead of nine scattered
writes per interaction.
"""

from __future__ import annotations

import os

import warp as wp

from vtkillum.core.device import init_warp

init_warp()

#: Bytes per stored interaction (see :class:`Interactions`).
INTERACTION_BYTES = 3 * 12 + 4 + 8 + 8 + 4 + 4 + 4
#: Bytes per photon path: start, count, end reason (int32) and path Historygrams (uint64).
PATH_BYTES = 4 + 4 + 4 + 8 + 8

#: Why a photon path ended (``PhotonMap.end``).
ESCAPED = wp.constant(0)
ABSORBED = wp.constant(1)
ORDER_LIMIT = wp.constant(2)
CAPPED = wp.constant(3)
OVERFLOW = wp.constant(4)  # scratch full: continue in the next round
END_NAMES = {0: "escaped", 1: "absorbed", 2: "order_limit", 3: "capped"}


@wp.struct
class Interactions:
    """Structure of arrays of photon interactions (see the module docstring)."""

    pos: wp.array(dtype=wp.vec3)
    dir: wp.array(dtype=wp.vec3)
    flux: wp.array(dtype=wp.vec3)
    value: wp.array(dtype=wp.float32)
    hist: wp.array(dtype=wp.uint64)
    chist: wp.array(dtype=wp.uint64)
    rng: wp.array(dtype=wp.uint32)
    order: wp.array(dtype=wp.int32)
    owner: wp.array(dtype=wp.int32)


@wp.struct
class Record:
    """One interaction in the tracing scratch (the fields of :class:`Interactions`)."""

    pos: wp.vec3
    dir: wp.vec3
    flux: wp.vec3
    value: wp.float32
    hist: wp.uint64
    chist: wp.uint64
    rng: wp.uint32
    order: wp.int32
    owner: wp.int32


#: Bytes per scratch record (the struct's C layout: 8-byte aligned).
RECORD_BYTES = 72


def allocate_scratch(n: int, device: str) -> wp.array:
    """Uninitialised scratch records for ``n`` interactions (at least one)."""
    return wp.empty(max(int(n), 1), dtype=Record, device=device)


def allocate(n: int, device: str) -> Interactions:
    """Uninitialised interaction arrays for ``n`` interactions (at least one slot)."""
    n = max(int(n), 1)
    it = Interactions()
    it.pos = wp.empty(n, dtype=wp.vec3, device=device)
    it.dir = wp.empty(n, dtype=wp.vec3, device=device)
    it.flux = wp.empty(n, dtype=wp.vec3, device=device)
    it.value = wp.empty(n, dtype=wp.float32, device=device)
    it.hist = wp.empty(n, dtype=wp.uint64, device=device)
    it.chist = wp.empty(n, dtype=wp.uint64, device=device)
    it.rng = wp.empty(n, dtype=wp.uint32, device=device)
    it.order = wp.empty(n, dtype=wp.int32, device=device)
    it.owner = wp.empty(n, dtype=wp.int32, device=device)
    return it


def free_bytes(device: str, limit_mb: float | None = None) -> int:
    """Bytes that may still be allocated on ``device`` (``limit_mb`` caps it)."""
    if str(device).startswith("cuda"):
        free = int(wp.get_device(device).free_memory)
    else:
        free = _host_available()
    if limit_mb is not None:
        free = min(free, int(float(limit_mb) * 2**20))
    return free


def _host_available() -> int:
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    try:
        return os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (ValueError, OSError, AttributeError):
        return 1 << 34


def check_fits(n_photons: int, interactions_per_photon: float, scratch_per_photon: int,
               device: str, limit_mb: float | None = None) -> None:
    """Raise ``MemoryError`` (saying how many photons fit) unless a photon map fits.

    The estimate counts the path tables, the interactions (twice: old and new buffer
    while compacting) and the tracing scratch (``scratch_per_photon`` slots each).
    """
    per_photon = (PATH_BYTES * 3 + 16 + INTERACTION_BYTES
                  * (2.0 * interactions_per_photon + scratch_per_photon))
    available = free_bytes(device, limit_mb)
    need = per_photon * n_photons
    if need > available:
        fit = int(available // per_photon)
        raise MemoryError(
            f"{n_photons:,} photons need about {need / 2**20:,.0f} MiB on {device} "
            f"({per_photon:.0f} bytes per photon at {interactions_per_photon:.1f} stored "
            f"interactions each) but {available / 2**20:,.0f} MiB are available: at most "
            f"about {fit:,} photons fit; use fewer photons (and more progressive passes)")


def exclusive_scan(counts: wp.array, out: wp.array) -> int:
    """Exclusive prefix sum of int32 ``counts`` into ``out``; returns the total."""
    n = counts.shape[0]
    if n == 0:
        return 0
    wp.utils.array_scan(counts, out, inclusive=False)
    total = wp.empty(1, dtype=wp.int64, device=counts.device)
    wp.launch(scan_total_kernel, dim=1, inputs=[counts, out, total], device=counts.device)
    return int(total.numpy()[0])  # one wait and one copy


@wp.kernel
def scan_total_kernel(counts: wp.array(dtype=wp.int32), offsets: wp.array(dtype=wp.int32),
                      total: wp.array(dtype=wp.int64)):
    """``total[0]``: the sum of ``counts`` from its exclusive prefix sum ``offsets``."""
    n = counts.shape[0]
    total[0] = wp.int64(offsets[n - 1]) + wp.int64(counts[n - 1])


def compact(old: Interactions, old_total: int, start: wp.array, keep: wp.array,
            new_start: wp.array, scratch: wp.array, capacity: int,
            work_photon: wp.array, work_count: wp.array, new_total: int,
            device: str, work_of: wp.array | None = None) -> Interactions:
    """New interaction buffer: each photon's first ``keep[p]`` old interactions, then its
    scratch interactions (work item ``w`` owns scratch ``[w * capacity, ... + work_count[w])``).

    ``new_total``: size of the new buffer (the interactions it will hold, or more).
    ``work_of``: each photon's work item (-1: none), given when the work items are not in
    photon order: the tails are then copied in the order of the destination.
    """
    new = allocate(new_total, device)
    if old_total > 0:
        wp.launch(copy_kept_kernel, dim=old_total, inputs=[old, start, keep, new_start, new],
                  device=device)
    n_work = work_photon.shape[0]
    if n_work > 0 and work_of is not None:
        wp.launch(copy_scratch_by_photon_kernel, dim=(work_of.shape[0], capacity),
                  inputs=[scratch, capacity, work_of, work_count, keep, new_start, new],
                  device=device)
    elif n_work > 0:
        wp.launch(copy_scratch_kernel, dim=(n_work, capacity),
                  inputs=[scratch, capacity, work_photon, work_count, keep, new_start, new],
                  device=device)
    return new


@wp.kernel
def gather_int_kernel(idx: wp.array(dtype=wp.int32), src: wp.array(dtype=wp.int32),
                      out: wp.array(dtype=wp.int32)):
    """``wp.tid()`` indexes ``idx``: ``out[i] = src[idx[i]]``."""
    i = wp.tid()
    out[i] = src[idx[i]]


def select(flags: wp.array, values: wp.array, device: str,
           total: int | None = None) -> tuple[wp.array, wp.array]:
    """Indices ``p`` with ``flags[p] != 0`` and their ``values[p]``, in order (on the device).

    ``total``: the number of flags set, when known (no wait for the device then)."""
    n = flags.shape[0]
    offsets = wp.empty(n, dtype=wp.int32, device=device)
    if total is None:
        total = exclusive_scan(flags, offsets)
    elif total > 0:
        wp.utils.array_scan(flags, offsets, inclusive=False)
    idx = wp.empty(max(total, 0), dtype=wp.int32, device=device)
    val = wp.empty(max(total, 0), dtype=wp.int32, device=device)
    if total > 0:
        wp.launch(select_kernel, dim=n, inputs=[flags, offsets, values, idx, val],
                  device=device)
    return idx, val


@wp.func
def copy_interaction(src: Interactions, i: int, dst: Interactions, j: int):
    dst.pos[j] = src.pos[i]
    dst.dir[j] = src.dir[i]
    dst.flux[j] = src.flux[i]
    dst.value[j] = src.value[i]
    dst.hist[j] = src.hist[i]
    dst.chist[j] = src.chist[i]
    dst.rng[j] = src.rng[i]
    dst.order[j] = src.order[i]
    dst.owner[j] = src.owner[i]


@wp.kernel
def copy_kept_kernel(old: Interactions, start: wp.array(dtype=wp.int32),
                     keep: wp.array(dtype=wp.int32), new_start: wp.array(dtype=wp.int32),
                     dst: Interactions):
    """``wp.tid()`` indexes old interactions; the first ``keep[p]`` of photon ``p`` move to
    ``new_start[p] + k``."""
    i = wp.tid()
    p = old.owner[i]
    k = i - start[p]
    if k < keep[p]:
        copy_interaction(old, i, dst, new_start[p] + k)


@wp.func
def store_record(r: Record, dst: Interactions, j: int):
    dst.pos[j] = r.pos
    dst.dir[j] = r.dir
    dst.flux[j] = r.flux
    dst.value[j] = r.value
    dst.hist[j] = r.hist
    dst.chist[j] = r.chist
    dst.rng[j] = r.rng
    dst.order[j] = r.order
    dst.owner[j] = r.owner


@wp.kernel
def copy_scratch_kernel(scratch: wp.array(dtype=Record), capacity: int,
                        work_photon: wp.array(dtype=wp.int32),
                        work_count: wp.array(dtype=wp.int32), keep: wp.array(dtype=wp.int32),
                        new_start: wp.array(dtype=wp.int32), dst: Interactions):
    """``wp.tid()`` = (work item, slot); slot ``k`` of the work item's scratch goes after the
    photon's kept prefix."""
    w, k = wp.tid()
    if k < work_count[w]:
        p = work_photon[w]
        store_record(scratch[w * capacity + k], dst, new_start[p] + keep[p] + k)


@wp.kernel
def copy_scratch_by_photon_kernel(scratch: wp.array(dtype=Record), capacity: int,
                                  work_of: wp.array(dtype=wp.int32),
                                  work_count: wp.array(dtype=wp.int32),
                                  keep: wp.array(dtype=wp.int32),
                                  new_start: wp.array(dtype=wp.int32), dst: Interactions):
    """``wp.tid()`` = (photon, slot): what :func:`copy_scratch_kernel` copies, in the order of
    the destination (``work_of[p]``: the photon's work item, -1: none)."""
    p, k = wp.tid()
    w = work_of[p]
    if w < 0:
        return
    if k < work_count[w]:
        store_record(scratch[w * capacity + k], dst, new_start[p] + keep[p] + k)


@wp.kernel
def select_kernel(flags: wp.array(dtype=wp.int32), offsets: wp.array(dtype=wp.int32),
                  values: wp.array(dtype=wp.int32), idx: wp.array(dtype=wp.int32),
                  val: wp.array(dtype=wp.int32)):
    """``wp.tid()`` indexes entries; flagged ones are written in order to ``idx``/``val``."""
    p = wp.tid()
    if flags[p] != 0:
        idx[offsets[p]] = p
        val[offsets[p]] = values[p]
