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
paths: it writes the new interactions to a scratch buffer, then
:func:`compact` builds the new buffer in three parallel copies (kept prefixes,
new tails, path tables).
"""

from __future__ import annotations

import os

import numpy as np
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
    last = np.concatenate([out[n - 1:n].numpy(), counts[n - 1:n].numpy()])
    return int(last.sum(dtype=np.int64))


def compact(old: Interactions, old_total: int, start: wp.array, keep: wp.array,
            new_start: wp.array, scratch: Interactions, capacity: int,
            work_photon: wp.array, work_count: wp.array, new_total: int,
            device: str) -> Interactions:
    """New interaction buffer: each photon's first ``keep[p]`` old interactions, then its
    scratch interactions (work item ``w`` owns scratch ``[w * capacity, ... + work_count[w])``).
    """
    new = allocate(new_total, device)
    if old_total > 0:
        wp.launch(copy_kept_kernel, dim=old_total, inputs=[old, start, keep, new_start, new],
                  device=device)
    n_work = work_photon.shape[0]
    if n_work > 0:
        wp.launch(copy_scratch_kernel, dim=(n_work, capacity),
                  inputs=[scratch, capacity, work_photon, work_count, keep, new_start, new],
                  device=device)
    return new


def select(flags: wp.array, values: wp.array, device: str) -> tuple[wp.array, wp.array]:
    """Indices ``p`` with ``flags[p] != 0`` and their ``values[p]``, in order (on the device)."""
    n = flags.shape[0]
    offsets = wp.empty(n, dtype=wp.int32, device=device)
    total = exclusive_scan(flags, offsets)
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


@wp.kernel
def copy_scratch_kernel(scratch: Interactions, capacity: int,
                        work_photon: wp.array(dtype=wp.int32),
                        work_count: wp.array(dtype=wp.int32), keep: wp.array(dtype=wp.int32),
                        new_start: wp.array(dtype=wp.int32), dst: Interactions):
    """``wp.tid()`` = (work item, slot); slot ``k`` of the work item's scratch goes after the
    photon's kept prefix."""
    w, k = wp.tid()
    if k < work_count[w]:
        p = work_photon[w]
        copy_interaction(scratch, w * capacity + k, dst, new_start[p] + keep[p] + k)


@wp.kernel
def select_kernel(flags: wp.array(dtype=wp.int32), offsets: wp.array(dtype=wp.int32),
                  values: wp.array(dtype=wp.int32), idx: wp.array(dtype=wp.int32),
                  val: wp.array(dtype=wp.int32)):
    """``wp.tid()`` indexes entries; flagged ones are written in order to ``idx``/``val``."""
    p = wp.tid()
    if flags[p] != 0:
        idx[offsets[p]] = p
        val[offsets[p]] = values[p]
