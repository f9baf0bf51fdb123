"""Historygrams (Jönsson et al. 2012, sections 4.2–4.3, eqs. 9–11).

A Historygram is a set of parameter bins that a computed object (a photon
interaction, a view-ray segment) has used, stored as a 64-bit mask:

* **Data bins** (eq. 11). The data range ``[lo, hi]`` of the volume is split into
  :data:`BITS` equal bins; a data value ``s`` maps to
  ``δ(s) = 1 << clamp(floor(64 (s - lo) / (hi - lo)), 0, 63)``. (The paper writes
  ``floor(x (p - 1))`` for ``x`` in [0, 1], which leaves the last bit to ``x = 1``
  alone; equal bins use all 64.) An object ORs ``δ(s)`` of every data value it
  samples into its mask (eq. 9): photons along their whole path (a scattered photon
  inherits its ancestors' bits), segments along their samples (and, with exact direct
  light, along their shadow rays). Because the bins hold data values and not optical
  properties, the masks do not depend on the transfer function.
* **Two masks per object.** The paper keeps one mask; here every object keeps the bins
  whose **extinction** it used (``hist``: every sample of a march) apart from the bins
  whose **colour** it used (``chist``: where it scattered -- a photon's roulette, a view
  sample's ``σs``). A colour edit then leaves alone the photons that never scattered in
  the edited material (with ``S_n = 1``: all of them) and the segments that only passed
  through it transparently.
* **Query mask** (eq. 10, Fig. 3). A transfer-function edit is turned into the bins
  whose optical properties changed (:func:`query_masks`: σt and colour apart): :func:`query_mask` compares the σt and colour
  tables the kernels interpolate before and after the edit and sets the bins of
  every data interval that an entry which changed influences (an entry at ``v_i``
  is interpolated for ``s`` in ``(v_{i-1}, v_{i+1})``; the mapper makes the same masks on
  the device, with the tables: :mod:`vtkillum.core.photon.tables`). An object is invalid iff
  ``(hist & Q_σ) | (chist & Q_c) != 0``: the test is exact for the kernels' own lookups, never missing a
  change, so an incremental update equals a full recompute.
* **Spatial Historygram** (section 4.3.2). One 64-bit mask per axis over the volume's
  extent: where photon interactions were removed or added, the bit of their
  coordinate is set on each axis. A segment whose bounding box, grown by the photon
  radius, meets set bits on all three axes is recomputed even if its own data bins
  did not change (an occluder that was removed lights a region of other data values).
  The paper describes it and leaves it out; here it is on by default
  (``spatial_historygram``).
"""

from __future__ import annotations

import numpy as np
import warp as wp

from vtkillum.core.device import init_warp
from vtkillum.core.photon.storage import Interactions

init_warp()

#: Bits of a Historygram (one ``uint64``).
BITS = 64
ALL_BITS = (1 << BITS) - 1


@wp.func
def data_bin(s: float, lo: float, scale: float):
    """``δ(s)``: the data bin of value ``s`` as a one-bit ``uint64`` (``scale = 64 / (hi - lo)``)."""
    b = wp.clamp(int(wp.floor((s - lo) * scale)), 0, 63)
    return wp.uint64(1) << wp.uint64(b)


@wp.func
def axis_bits(a: float, b: float, lo: float, scale: float):
    """Mask of the spatial bins ``[floor((a - lo) scale), floor((b - lo) scale)]`` (clamped)."""
    i0 = wp.clamp(int(wp.floor((a - lo) * scale)), 0, 63)
    i1 = wp.clamp(int(wp.floor((b - lo) * scale)), 0, 63)
    mask = wp.uint64(0)
    for i in range(i0, i1 + 1):
        mask = mask | (wp.uint64(1) << wp.uint64(i))
    return mask


@wp.func
def spatial_bits(p: wp.vec3, scale: wp.vec3):
    """Per-axis one-bit masks of local position ``p`` (``scale = 64 / extent``)."""
    return (axis_bits(p[0], p[0], 0.0, scale[0]), axis_bits(p[1], p[1], 0.0, scale[1]),
            axis_bits(p[2], p[2], 0.0, scale[2]))


def bin_scale(value_range) -> tuple[float, float]:
    """``(lo, scale)`` of :func:`data_bin` for a volume's data range."""
    lo, hi = (float(v) for v in value_range)
    return lo, BITS / (hi - lo) if hi > lo else 0.0


def interval_mask(a: float, b: float, value_range) -> int:
    """Data bins meeting the closed interval ``[a, b]`` (data units), as a Python int."""
    lo, hi = (float(v) for v in value_range)
    if hi <= lo:
        return 1  # one value: everything lives in bin 0
    width = (hi - lo) / BITS
    eps = 1e-6 * (hi - lo)
    i0 = int(np.clip(np.floor((a - eps - lo) / width), 0, BITS - 1))
    i1 = int(np.clip(np.floor((b + eps - lo) / width), 0, BITS - 1))
    if b + eps < lo or a - eps > hi:
        return 0
    return sum(1 << i for i in range(i0, i1 + 1))


def query_masks(old_tables, new_tables, value_range) -> tuple[int, int]:
    """Query Historygrams ``H_q`` of a transfer-function edit (eq. 10, Fig. 3), split by what
    changed: ``(extinction bins, colour bins)``.

    Parameters
    ----------
    old_tables, new_tables : (sigma, color)
        The σt (n,) and colour (n, 3) tables the kernels interpolate, both sampled at
        the same ``n`` data values spanning ``value_range`` (see
        :func:`vtkillum.core.photon.tracing.photon_tables`).
    value_range : (float, float)
        The volume's data range, the domain of the bins.

    Returns
    -------
    (int, int)
        64-bit masks (Python ints) of the bins whose σt changed and of the bins whose
        colour changed; ``(0, 0)`` when nothing did.
    """
    s0, c0 = (np.asarray(a) for a in old_tables)
    s1, c1 = (np.asarray(a) for a in new_tables)
    if s0.shape != s1.shape or c0.shape != c1.shape:
        return ALL_BITS, ALL_BITS
    lo, hi = (float(v) for v in value_range)
    n = s0.shape[0]
    v = np.linspace(lo, hi, n)
    masks = []
    ne = c0 != c1
    # (np.any over the last axis of a thin array is several times slower than the ORs)
    colour_changed = ne[:, 0] | ne[:, 1] | ne[:, 2] if ne.ndim == 2 and ne.shape[1] == 3 \
        else np.any(ne, axis=-1)
    for changed in (s0 != s1, colour_changed):
        i = np.flatnonzero(changed)
        masks.append(intervals_mask(v[np.maximum(i - 1, 0)], v[np.minimum(i + 1, n - 1)],
                                    value_range))
    return masks[0], masks[1]


def intervals_mask(a: np.ndarray, b: np.ndarray, value_range) -> int:
    """The OR of :func:`interval_mask` over the intervals ``[a[i], b[i]]`` (``a <= b``), in
    one pass (an edit can change thousands of table entries)."""
    a = np.asarray(a, np.float64)
    b = np.asarray(b, np.float64)
    if a.size == 0:
        return 0
    lo, hi = (float(v) for v in value_range)
    if hi <= lo:
        return 1
    width = (hi - lo) / BITS
    eps = 1e-6 * (hi - lo)
    keep = ~((b + eps < lo) | (a - eps > hi))
    i0 = np.clip(np.floor((a[keep] - eps - lo) / width), 0, BITS - 1).astype(np.int64)
    i1 = np.clip(np.floor((b[keep] + eps - lo) / width), 0, BITS - 1).astype(np.int64)
    edges = (np.bincount(i0, minlength=BITS + 1)[:BITS + 1]
             - np.bincount(i1 + 1, minlength=BITS + 1)[:BITS + 1])
    covered = np.flatnonzero(np.cumsum(edges[:BITS]) > 0)
    return sum(1 << int(k) for k in covered)


def query_mask(old_tables, new_tables, value_range) -> int:
    """The single query Historygram of the paper: every bin whose σt or colour changed."""
    sigma, color = query_masks(old_tables, new_tables, value_range)
    return sigma | color


def mask_bins(mask: int) -> list[int]:
    """The bin indices set in a 64-bit mask."""
    return [i for i in range(BITS) if (int(mask) >> i) & 1]




# --- kernels -------------------------------------------------------------------------------------


@wp.kernel
def photon_query_kernel(start: wp.array(dtype=wp.int32), count: wp.array(dtype=wp.int32),
                        path_hist: wp.array(dtype=wp.uint64),
                        path_chist: wp.array(dtype=wp.uint64), it: Interactions,
                        query: wp.uint64, cquery: wp.uint64, min_order: int,
                        spatial_scale: wp.vec3,
                        flags: wp.array(dtype=wp.int32), restart: wp.array(dtype=wp.int32),
                        spatial: wp.array(dtype=wp.uint64)):
    """Find each photon's first invalid interaction (section 4.3.1).

    ``wp.tid()`` indexes photon paths. A path whose Historygrams miss the queries
    (extinction bins ``query``, colour bins ``cquery``) is valid. Otherwise walk back
    from its last interaction while the interaction's Historygrams meet them: ``restart[p]`` is the last valid interaction (buffer
    index; -1: none, retrace from the light) and ``flags[p] = 1``. Removed interactions
    of order ``>= min_order`` set their position's bits in the spatial Historygram
    (``spatial[a]``, 64 bins over ``[0, extent_a]``); ``spatial[3]`` counts them all,
    ``spatial[4]`` the photons flagged (one array: one copy to the host).
    """
    p = wp.tid()
    flags[p] = 0
    restart[p] = -1
    if ((path_hist[p] & query) | (path_chist[p] & cquery)) == wp.uint64(0):
        return
    s0 = start[p]
    j = s0 + count[p] - 1
    while j >= s0:
        if ((it.hist[j] & query) | (it.chist[j] & cquery)) == wp.uint64(0):
            break
        if it.order[j] >= min_order:
            bx, by, bz = spatial_bits(it.pos[j], spatial_scale)
            wp.atomic_or(spatial, 0, bx)
            wp.atomic_or(spatial, 1, by)
            wp.atomic_or(spatial, 2, bz)
        j -= 1
    wp.atomic_add(spatial, 3, wp.uint64(s0 + count[p] - 1 - j))
    wp.atomic_add(spatial, 4, wp.uint64(1))
    flags[p] = 1
    if j >= s0:
        restart[p] = j


@wp.kernel
def mark_added_kernel(photons: wp.array(dtype=wp.int32), kept: wp.array(dtype=wp.int32),
                      start: wp.array(dtype=wp.int32), count: wp.array(dtype=wp.int32),
                      it: Interactions, min_order: int, spatial_scale: wp.vec3,
                      spatial: wp.array(dtype=wp.uint64)):
    """``wp.tid()`` indexes retraced photons: interactions past the ``kept[w]`` kept ones are
    new; those of order ``>= min_order`` set their bits in the spatial Historygram."""
    w = wp.tid()
    p = photons[w]
    for j in range(start[p] + kept[w], start[p] + count[p]):
        if it.order[j] >= min_order:
            bx, by, bz = spatial_bits(it.pos[j], spatial_scale)
            wp.atomic_or(spatial, 0, bx)
            wp.atomic_or(spatial, 1, by)
            wp.atomic_or(spatial, 2, bz)


@wp.kernel
def kept_count_kernel(photons: wp.array(dtype=wp.int32), restart: wp.array(dtype=wp.int32),
                      start: wp.array(dtype=wp.int32), kept: wp.array(dtype=wp.int32)):
    """``wp.tid()`` indexes photons to retrace: how many of their interactions stay."""
    w = wp.tid()
    j = restart[w]
    kept[w] = 0
    if j >= 0:
        kept[w] = j - start[photons[w]] + 1
