"""The ambient radiance cache (tube march, eqs. 14-17) across MPI ranks by segment forwarding.

The one-rank march (:func:`vtkillum.core.ambient.tube_march.field_march_kernel`, the
default ``tube_sampling="field"`` of :class:`~vtkillum.core.ambient.cache.AmbientScatteringCache`)
gives every cache point ``x`` and light its own chain of steps ``2r``: it starts where the
segment from ``x`` towards the light enters the *whole* box (or at a point light), samples
the step field ``σ̂`` ``samples`` times per step at positions ``u`` advanced by ``u += du``
(field index units), multiplies the front by ``T̃`` once per step and blends the last two
fronts by ``η`` at ``x``. The chains are not shared between points (each is anchored at its
own entry point), so there is no plane structure to sweep; instead each chain is handed
from rank to rank along its path:

1. **Start.** Each rank makes one *record* per cache point of its piece and light, with the
   one-rank arithmetic (:func:`~vtkillum.core.ambient.tube_march.march_path`, the same ``du``
   and first ``u``): the march state ``(u, front, partial step sum st, step n, sample s)``,
   the chain's ``n_full``, ``η``, ``E_l(x)`` and the point's index on its origin rank.
2. **Advance.** A rank advances each record it holds while the next sample lies in its
   region (the pieces' point extents, half-open at shared planes, in field index units),
   taking the sample, ``T̃`` and the early stop exactly as the one-rank kernel does
   (``st += σ̂(u); u += du`` in float32, in the same order: every sample at the one-rank
   position, bit for bit).
3. **Forward.** A record whose next sample belongs to another rank goes to that rank; a
   finished one (its value ``((1 - η) L̃f,k + η L̃f,k+1) E``) goes back to its origin. One
   round is one ``Alltoallv`` of packed records; rounds repeat until no record is in flight
   (an ``allreduce``): at most one round per piece a chain crosses, plus one.

The step field ``σ̂ = B ∗ σ̃t`` is computed by each rank for the field points its samples
can touch (one field cell beyond its region), from ``σ̃t`` on its piece widened by the box
half-width plus a field cell (:func:`~vtkillum.core.ambient.distributed.ghosted_ambient_extinction`,
whose ``σt`` ghost layers come from the neighbours), with the one-rank separable box passes
in global indices (:func:`box_mean_axis_block`, the same weights and sums as
:func:`~vtkillum.core.ambient.tube_march.box_mean_axis_kernel`). So the only difference from
the one rank is the float64 rounding of the piece's summed-area table in ``σ̃t`` (1e-6 of its
maximum), which the march carries through ``T̃``: the caches agree within 1e-5 of their
maximum (``tests/distributed/test_ambient_radiance.py``).

Simplified / not covered: only the default step-field march (``tube_sampling="field"``,
software trilinear samples, float32 RGB output); the ``"midpoint"`` and ``"paper"`` samplings
and the half-precision texture path of CUDA are one-rank only. The cache grid is the data
grid (the filters' distributed mode computes on it). Records travel through the host (numpy
buffers; a CUDA-aware MPI could pass device buffers). Message sizes are below 2 GiB per rank
pair and round (88 bytes per record).
"""

# warp needs float(0.0) / int(-1) for variables a loop mutates (a literal is a constant)
# ruff: noqa: UP018, RUF046

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from types import SimpleNamespace

import numpy as np
import warp as wp

from vtkillum.core.ambient.cache import STEP_SAMPLES
from vtkillum.core.ambient.device_table import DeviceTable
from vtkillum.core.ambient.distributed import ghost_levels_for, ghosted_ambient_extinction
from vtkillum.core.ambient.table import load_table
from vtkillum.core.ambient.tube_march import (
    NEGLIGIBLE,
    hat_integral,
    march_path,
    step_field_shape,
)
from vtkillum.core.parallel.comm import Parallel
from vtkillum.core.parallel.decomposition import Decomposition, extent_shape, is_empty, sub_slices
from vtkillum.core.warp_common import Lights, make_lights, table_lerp

#: Packed record of one chain in flight (or finished, ``s == -1``, on its way home).
RECORD = np.dtype([("idx", np.int64), ("origin", np.int32), ("n", np.int32), ("s", np.int32),
                   ("n_full", np.int32), ("u", np.float32, 3), ("du", np.float32, 3),
                   ("e", np.float32, 3), ("front", np.float32), ("st", np.float32),
                   ("eta", np.float32), ("value", np.float32, 3)])

#: Chains a rank starts per batch (:func:`distributed_radiance_cache`'s ``max_records``).
MAX_RECORDS = 1 << 22

_NO_OWNER = -2
_DONE = -1


@dataclass
class DistributedRadiance:
    """What :func:`distributed_radiance_cache` returns for this rank's piece.

    Attributes
    ----------
    sigma_tilde : ndarray (nx, ny, nz) float32
        ``σ̃t`` (1/world units) on the piece's points.
    radiance : ndarray (n_lights, nx, ny, nz, 3) float32
        ``L̃d`` per light on the piece's points (the lights' irradiance units).
    rounds : int
        Forwarding rounds (``Alltoallv`` exchanges) until no record was in flight.
    forwarded : int
        Records this rank sent to other ranks (chains handed on plus results sent home).
    timings : dict
        Seconds: ``extinction`` (σ̃t and the step field), ``march`` (kernels), ``exchange``.
    """

    sigma_tilde: np.ndarray
    radiance: np.ndarray
    rounds: int = 0
    forwarded: int = 0
    timings: dict = field(default_factory=dict)


# --- device functions and kernels -------------------------------------------------------------------
@wp.kernel
def box_mean_axis_block(src: wp.array3d(dtype=wp.float32), src_origin: wp.vec3i, n: int,
                        half: float, taps: int, axis: int, ratio: float, dst_origin: wp.vec3i,
                        dst: wp.array3d(dtype=wp.float32)):
    """:func:`~vtkillum.core.ambient.tube_march.box_mean_axis_kernel` on a block: ``dst``
    point ``(i, j, k)`` is global point ``dst_origin + (i, j, k)``, ``src[0, 0, 0]`` global
    point ``src_origin``, ``n`` the whole grid's points along ``axis`` (the clamp at the
    whole volume's border). The same weights and sum order, so the same float32 result."""
    i, j, k = wp.tid()
    o = wp.vec3i(i + dst_origin[0], j + dst_origin[1], k + dst_origin[2])
    u = ratio * float(o[axis])
    first = int(wp.floor(u)) - taps
    acc = float(0.0)
    for t in range(2 * taps + 2):
        m = first + t
        w = hat_integral(u + half - float(m)) - hat_integral(u - half - float(m))
        if w > 0.0:
            q = wp.clamp(m, 0, n - 1)
            v = float(0.0)
            if axis == 0:
                v = src[q - src_origin[0], o[1] - src_origin[1], o[2] - src_origin[2]]
            elif axis == 1:
                v = src[o[0] - src_origin[0], q - src_origin[1], o[2] - src_origin[2]]
            else:
                v = src[o[0] - src_origin[0], o[1] - src_origin[1], q - src_origin[2]]
            acc += w * v
    dst[i, j, k] = acc / (2.0 * half)


@wp.func
def block_field_sample(field: wp.array(dtype=wp.float32), local: wp.vec3i, origin: wp.vec3i,
                       dims: wp.vec3i, u: wp.vec3, error: wp.array(dtype=wp.int32)):
    """:func:`~vtkillum.core.ambient.tube_march.field_sample` of the whole ``dims`` field at
    index position ``u`` from the flat block ``field`` (``local`` points from global point
    ``origin``); the same clamps, fractions and lerps. A cell outside the block (a bug)
    sets ``error[0]`` and reads 0."""
    i = wp.clamp(int(u[0]), 0, dims[0] - 2)
    j = wp.clamp(int(u[1]), 0, dims[1] - 2)
    k = wp.clamp(int(u[2]), 0, dims[2] - 2)
    fx = wp.clamp(u[0] - float(i), 0.0, 1.0)
    fy = wp.clamp(u[1] - float(j), 0.0, 1.0)
    fz = wp.clamp(u[2] - float(k), 0.0, 1.0)
    li = i - origin[0]
    lj = j - origin[1]
    lk = k - origin[2]
    result = float(0.0)
    if li < 0 or lj < 0 or lk < 0 or li > local[0] - 2 or lj > local[1] - 2 \
            or lk > local[2] - 2:
        error[0] = 1
    else:
        sz = local[2]
        sy = local[1] * local[2]
        b = (li * local[1] + lj) * sz + lk
        c00 = wp.lerp(field[b], field[b + 1], fz)
        c01 = wp.lerp(field[b + sz], field[b + sz + 1], fz)
        c10 = wp.lerp(field[b + sy], field[b + sy + 1], fz)
        c11 = wp.lerp(field[b + sy + sz], field[b + sy + sz + 1], fz)
        result = wp.lerp(wp.lerp(c00, c01, fy), wp.lerp(c10, c11, fy), fx)
    return result


@wp.func
def in_region(u: wp.vec3, a: wp.vec3, b: wp.vec3):
    """Whether ``u`` lies in the half-open box ``[a, b)``."""
    return u[0] >= a[0] and u[0] < b[0] and u[1] >= a[1] and u[1] < b[1] \
        and u[2] >= a[2] and u[2] < b[2]


@wp.func
def owner_of(u: wp.vec3, lo: wp.array(dtype=wp.vec3), hi: wp.array(dtype=wp.vec3), me: int):
    """The rank whose region ``[lo, hi)`` (field index units; ±1e30 at the whole box's
    faces) holds ``u``, ``me`` tried first; -2 for none."""
    owner = int(-2)
    if in_region(u, lo[me], hi[me]):
        owner = me
    else:
        for r in range(lo.shape[0]):
            if owner < 0 and in_region(u, lo[r], hi[r]):
                owner = r
    return owner


@wp.kernel
def start_records(lights: Lights, radius: float, spacing: wp.vec3, first: wp.vec3i,
                  local: wp.vec3i, extent: wp.vec3, inv_field: wp.vec3, samples: int,
                  offset: int, u: wp.array(dtype=wp.vec3), du: wp.array(dtype=wp.vec3),
                  e: wp.array(dtype=wp.vec3), n_full: wp.array(dtype=wp.int32),
                  eta: wp.array(dtype=wp.float32)):
    """One record per (light, piece point): the one-rank kernel's set-up of the march
    (``march_path``, ``du``, the first ``u``) for global cache point ``first + (a, b, c)``;
    thread ``t`` makes the rank's pair ``offset + t`` (light-major, k fastest)."""
    t = wp.tid()
    g = t + offset
    per_light = local[0] * local[1] * local[2]
    li = g / per_light
    q = g - li * per_light
    i = first[0] + q / (local[1] * local[2])
    j = first[1] + (q / local[2]) % local[1]
    k = first[2] + q % local[2]
    p = wp.vec3(float(i) * spacing[0], float(j) * spacing[1], float(k) * spacing[2])
    to_light, el, entry, nf, et = march_path(lights, li, p, radius, extent)
    h = 2.0 * radius / float(samples)
    d = wp.cw_mul(-h * to_light, inv_field)
    u[t] = wp.cw_mul(entry, inv_field) + 0.5 * d
    du[t] = d
    e[t] = el
    n_full[t] = nf
    eta[t] = et


@wp.kernel
def advance_records(field: wp.array(dtype=wp.float32), local: wp.vec3i, origin: wp.vec3i,
                    dims: wp.vec3i, lo: wp.array(dtype=wp.vec3), hi: wp.array(dtype=wp.vec3),
                    me: int, transmittance: wp.array(dtype=wp.float32), lookup_scale: float,
                    samples: int,
                    u: wp.array(dtype=wp.vec3), du: wp.array(dtype=wp.vec3),
                    front: wp.array(dtype=wp.float32), st: wp.array(dtype=wp.float32),
                    n: wp.array(dtype=wp.int32), s: wp.array(dtype=wp.int32),
                    n_full: wp.array(dtype=wp.int32), eta: wp.array(dtype=wp.float32),
                    e: wp.array(dtype=wp.vec3), dest: wp.array(dtype=wp.int32),
                    value: wp.array(dtype=wp.vec3), error: wp.array(dtype=wp.int32)):
    """March each record while its next sample is this rank's: the one-rank loop
    (``field_march_kernel``) resumed at step ``n``, sample ``s``. ``dest``: the rank of the
    next sample, or -1 when the chain is done (``value`` = ``L̃d``)."""
    t = wp.tid()
    last = float(transmittance.shape[0] - 1)
    scale = lookup_scale / float(samples)
    pu = u[t]
    d = du[t]
    f = front[t]
    acc = st[t]
    nn = n[t]
    ss = s[t]
    nf = n_full[t]
    et = eta[t]
    beyond = f
    out = int(-1)
    going = int(1)
    while going == 1:
        if nn >= nf and not (nn == nf and et > 0.0 and f > 0.0):
            beyond = f  # no step beyond (η = 0, or the front died): as the one rank
            going = 0
        else:
            owner = owner_of(pu, lo, hi, me)
            if owner != me:
                out = owner
                going = 0
            else:
                acc += block_field_sample(field, local, origin, dims, pu, error)
                pu += d
                ss += 1
                if ss == samples:
                    factor = table_lerp(transmittance, wp.clamp(acc * scale, 0.0, last))
                    if nn < nf:
                        f *= factor
                        if f < NEGLIGIBLE:
                            f = 0.0
                            nn = nf
                        nn += 1
                    else:  # the step beyond x (eq. 17's L̃f(x_{k+1}))
                        beyond = f * factor
                        nn += 1
                        going = 0
                    acc = 0.0
                    ss = 0
    if out == -1:
        value[t] = ((1.0 - et) * f + et * beyond) * e[t]
    u[t] = pu
    front[t] = f
    st[t] = acc
    n[t] = nn
    s[t] = ss
    dest[t] = out


# --- host ---------------------------------------------------------------------------------------------
def _regions(decomposition: Decomposition, whole, field_dims) -> tuple[np.ndarray, np.ndarray]:
    """Each piece's sample region ``[lo, hi)`` in field index units (float32; ±1e30 on the
    whole box's faces, so clamped and out-of-box samples have an owner)."""
    pieces = decomposition.pieces
    lo = np.full((pieces, 3), 1e30, np.float32)  # empty pieces own nothing
    hi = np.full((pieces, 3), -1e30, np.float32)
    for q, ext in enumerate(decomposition.extents):
        if is_empty(ext):
            continue
        for a in range(3):
            n = whole[2 * a + 1] - whole[2 * a]
            a0, a1 = ext[2 * a] - whole[2 * a], ext[2 * a + 1] - whole[2 * a]
            nf = field_dims[a] - 1
            lo[q, a] = -1e30 if a0 == 0 else np.float32((a0 * nf) / max(n, 1))
            hi[q, a] = 1e30 if a1 == n else np.float32((a1 * nf) / max(n, 1))
    return lo, hi


def _field_range(ext, whole, field_dims) -> tuple[np.ndarray, np.ndarray]:
    """Global field points a piece's samples touch: one cell beyond its region (float32
    rounding of the region's faces included), clamped to the field."""
    f0, f1 = np.zeros(3, np.int64), np.zeros(3, np.int64)
    for a in range(3):
        n = max(whole[2 * a + 1] - whole[2 * a], 1)
        nf = field_dims[a] - 1
        a0, a1 = ext[2 * a] - whole[2 * a], ext[2 * a + 1] - whole[2 * a]
        f0[a] = max(math.floor(a0 * nf / n) - 1, 0)
        f1[a] = min(math.floor(a1 * nf / n) + 2, nf)
    return f0, f1


def _data_range(f0, f1, ratio, taps, dims) -> tuple[np.ndarray, np.ndarray]:
    """Data points the box passes read for field points ``[f0, f1]`` (with one point of
    margin for the float32 ``ratio · o``)."""
    d0 = np.array([max(math.floor(ratio[a] * f0[a]) - taps[a] - 1, 0) for a in range(3)])
    d1 = np.array([min(math.floor(ratio[a] * f1[a]) + taps[a] + 2, dims[a] - 1)
                   for a in range(3)])
    return d0, d1


def _exchange(par: Parallel, buckets: list) -> np.ndarray:
    """One round: ``buckets[q]`` (RECORD arrays) to rank ``q``; returns what arrived."""
    from vtkillum.core.parallel.comm import mpi

    MPI = mpi()
    send_counts = np.array([len(b) * RECORD.itemsize for b in buckets], np.int64)
    recv_counts = np.empty_like(send_counts)
    par.comm.Alltoall(send_counts, recv_counts)
    if send_counts.max(initial=0) >= 2**31 or recv_counts.sum() >= 2**31:
        raise ValueError("a forwarding round exceeds 2 GiB: too many records per rank")
    sendbuf = np.concatenate([np.ascontiguousarray(b).view(np.uint8) for b in buckets]) \
        if send_counts.sum() else np.zeros(0, np.uint8)
    recvbuf = np.empty(int(recv_counts.sum()), np.uint8)
    sdispl = np.concatenate([[0], np.cumsum(send_counts)[:-1]]).astype(np.int64)
    rdispl = np.concatenate([[0], np.cumsum(recv_counts)[:-1]]).astype(np.int64)
    par.comm.Alltoallv([sendbuf, (send_counts.astype(np.int32), sdispl.astype(np.int32)),
                        MPI.BYTE],
                       [recvbuf, (recv_counts.astype(np.int32), rdispl.astype(np.int32)),
                        MPI.BYTE])
    return recvbuf.view(RECORD)


def _whole_geometry(volume, piece_data_extent, whole, origin=None):
    """A stand-in for the whole volume (lights are mapped into its local frame); ``origin``
    its first point when known (else derived from the piece's, within rounding)."""
    first = np.asarray(piece_data_extent[0::2], np.float64) - np.asarray(whole[0::2])
    direction = np.asarray(volume.direction, np.float64)
    if origin is None:
        origin = np.asarray(volume.origin, np.float64) - direction @ (first * np.asarray(
            volume.spacing, np.float64))
    dims = extent_shape(whole)
    return SimpleNamespace(dims=dims, spacing=np.asarray(volume.spacing, np.float64),
                           origin=origin, direction=direction,
                           extent=(np.asarray(dims) - 1) * np.asarray(volume.spacing, np.float64))


_STATE = (("u", wp.vec3), ("du", wp.vec3), ("front", wp.float32), ("st", wp.float32),
          ("n", wp.int32), ("s", wp.int32), ("n_full", wp.int32), ("eta", wp.float32),
          ("e", wp.vec3))


def _start(march, begin: int, count: int, rank: int, radiance: np.ndarray):
    """Start this rank's (light, point) pairs ``begin .. begin + count`` and advance them as
    far as this rank's region goes; the chains done here go straight into ``radiance``.
    Returns the others as records and their destination ranks."""
    dev = march.dev
    if count == 0:
        return np.zeros(0, RECORD), np.zeros(0, np.int32)
    arrays = {"u": wp.empty(count, dtype=wp.vec3, device=dev),
              "du": wp.empty(count, dtype=wp.vec3, device=dev),
              "e": wp.empty(count, dtype=wp.vec3, device=dev),
              "n_full": wp.empty(count, dtype=wp.int32, device=dev),
              "eta": wp.empty(count, dtype=wp.float32, device=dev),
              "front": wp.full(count, 1.0, dtype=wp.float32, device=dev),
              "st": wp.zeros(count, dtype=wp.float32, device=dev),
              "n": wp.zeros(count, dtype=wp.int32, device=dev),
              "s": wp.zeros(count, dtype=wp.int32, device=dev)}
    wp.launch(start_records, dim=count,
              inputs=[march.lights, march.radius, march.spacing, march.first, march.local,
                      march.extent, march.inv_field, march.samples, int(begin), arrays["u"],
                      arrays["du"], arrays["e"], arrays["n_full"], arrays["eta"]], device=dev)
    dest, value = _advance_arrays(march, arrays, count)
    done = dest == _DONE
    radiance[begin + np.flatnonzero(done)] = value[done]
    away = np.flatnonzero(~done)
    records = np.zeros(len(away), RECORD)
    records["idx"] = begin + away
    records["origin"] = rank
    for name, _ in _STATE:
        records[name] = arrays[name].numpy()[away]
    return records, dest[away]


def _advance_arrays(march, arrays: dict, m: int) -> tuple[np.ndarray, np.ndarray]:
    """Run :func:`advance_records` on the device state ``arrays`` of ``m`` chains (updated in
    place); returns ``dest`` (-1: done) and ``value`` as numpy."""
    dev = march.dev
    dest = wp.empty(m, dtype=wp.int32, device=dev)
    value = wp.zeros(m, dtype=wp.vec3, device=dev)
    wp.launch(advance_records, dim=m,
              inputs=[march.field, march.local_field, march.field_origin, march.fdims,
                      march.lo, march.hi, march.rank, march.transmittance, march.lookup_scale,
                      march.samples, arrays["u"], arrays["du"], arrays["front"], arrays["st"],
                      arrays["n"], arrays["s"], arrays["n_full"], arrays["eta"], arrays["e"],
                      dest, value, march.error], device=dev)
    dest = dest.numpy()
    if int(march.error.numpy()[0]):
        raise RuntimeError(f"rank {march.rank}: a tube-march sample fell outside the "
                           "step-field block (a bug in the ghost widths)")
    if np.any(dest == _NO_OWNER):
        raise RuntimeError(f"rank {march.rank}: a tube-march sample has no owner")
    return dest, value.numpy()


def _advance(march, records: np.ndarray) -> np.ndarray:
    """:func:`advance_records` on ``records`` (updated in place); returns each record's
    destination rank (its origin when done, ``s`` then -1)."""
    m = len(records)
    if m == 0:
        return np.zeros(0, np.int32)
    arrays = {name: wp.array(np.ascontiguousarray(records[name]), dtype=dtype, device=march.dev)
              for name, dtype in _STATE}
    dest, value = _advance_arrays(march, arrays, m)
    for name in ("u", "front", "st", "n", "s"):
        records[name] = arrays[name].numpy()
    records["value"] = value
    done = dest == _DONE
    dest = np.where(done, records["origin"], dest).astype(np.int32)
    records["s"][done] = -1
    return dest


def distributed_radiance_cache(volume, piece_extent, whole_extent, transfer_function,
                               unit_distance: float, radius: float, lights, albedo: float = 0.9,
                               anisotropy: float = 0.0, comm=None, device: str | None = None,
                               data_extent=None, samples: int = STEP_SAMPLES,
                               table=None, whole_origin=None,
                               max_records: int = MAX_RECORDS) -> DistributedRadiance:
    """``σ̃t`` and the radiance cache ``L̃d`` on this rank's piece (collective over ``comm``).

    The result is the one-rank :class:`~vtkillum.core.ambient.cache.AmbientScatteringCache`
    (``tube_sampling="field"``, ``step_samples=samples``, cache on the data grid) cut to the
    piece, within the rounding of the piece's summed-area table (module docstring).

    Parameters
    ----------
    volume : vtkillum.core.volume.Volume
        This rank's piece of the data (points ``data_extent``, default ``piece_extent``).
    piece_extent, whole_extent : tuple of 6 int
        VTK extents; rank ``r`` holds VTK's piece ``r`` of ``comm.Get_size()``.
    transfer_function, unit_distance
        The optical model.
    radius : float
        Ambient sphere radius in world units.
    lights : list of DirectionalLight / PointLight
        World-space lights (mapped into the whole volume's local frame here).
    albedo, anisotropy : float
        ``Λ`` (selects the preintegration table) and the HG ``g`` of ``T̃``.
    comm : mpi4py communicator or Parallel, optional
        Default ``MPI_COMM_WORLD``.
    device : str, optional
        Warp device; default one per rank.
    data_extent : tuple of 6 int, optional
        The points ``volume`` holds when the pipeline delivered ghost levels.
    samples : int
        Step-field samples per tube step (the cache's ``step_samples``).
    table : PreintegrationTable, optional
        Default :func:`~vtkillum.core.ambient.table.load_table` for ``albedo``.
    whole_origin : (3,) float, optional
        The whole volume's first point (world units), so that point lights land in its
        local frame as on one rank bit for bit; default derived from the piece's origin.
    max_records : int
        Chains started per batch on each rank (a record is 88 bytes on the host, about as
        much on the device): the memory bound of the march, whatever the piece's size.

    Returns
    -------
    DistributedRadiance
    """
    par = Parallel.create(comm, device)
    dev = par.device
    lights = list(lights)
    if not lights:
        raise ValueError("the radiance cache needs at least one light")
    if isinstance(samples, bool) or int(samples) != samples or samples < 1:
        raise ValueError(f"samples must be an integer >= 1, got {samples!r}")
    samples = int(samples)
    whole = tuple(int(v) for v in whole_extent)
    piece_extent = tuple(int(v) for v in piece_extent)
    data_extent = piece_extent if data_extent is None else tuple(int(v) for v in data_extent)
    decomposition = Decomposition.of(whole, par.size)
    dims = np.asarray(extent_shape(whole))
    spacing = np.asarray(volume.spacing, np.float64).reshape(3)
    radius = float(radius)
    timings = {}
    t0 = time.perf_counter()

    # --- the step field on the field points this rank's samples touch ---------------------------
    fdims = np.asarray(step_field_shape(dims, spacing, radius, samples))
    ratio = (dims - 1) / np.maximum(fdims - 1, 1)
    half = radius / samples / spacing
    taps = [int(np.ceil(h)) + 2 for h in half]
    extra = 0
    for ext in decomposition.extents:  # the same ghost width on every rank (collective)
        if is_empty(ext):
            continue
        d0, d1 = _data_range(*_field_range(ext, whole, fdims), ratio, taps, dims)
        rel = np.asarray(ext[0::2]) - np.asarray(whole[0::2])
        rel1 = np.asarray(ext[1::2]) - np.asarray(whole[0::2])
        extra = max(extra, int(np.max(rel - d0)), int(np.max(d1 - rel1)))
    if extra > radiance_ghost_levels(dims, spacing, radius, samples) - ghost_levels_for(
            radius, spacing):
        raise RuntimeError(f"step-field ghost width {extra} exceeds radiance_ghost_levels")
    sigma_block, block = ghosted_ambient_extinction(
        volume, piece_extent, whole, transfer_function, unit_distance, radius, extra, par,
        data_extent)
    f0, f1 = _field_range(piece_extent, whole, fdims)
    d0, d1 = _data_range(f0, f1, ratio, taps, dims)
    b0 = np.asarray(block[0::2]) - np.asarray(whole[0::2])
    b1 = np.asarray(block[1::2]) - np.asarray(whole[0::2])
    if np.any(d0 < b0) or np.any(d1 > b1):
        raise RuntimeError(f"σ̃t block {block} does not hold the data points {d0}-{d1}")
    src = wp.array(sigma_block, dtype=wp.float32, device=dev)
    src_origin = b0.copy()
    for axis in range(3):
        lo_ = [f0[a] if a <= axis else d0[a] for a in range(3)]
        hi_ = [f1[a] if a <= axis else d1[a] for a in range(3)]
        dst = wp.empty(tuple(int(h - lo + 1) for lo, h in zip(lo_, hi_)), dtype=wp.float32,
                       device=dev)
        wp.launch(box_mean_axis_block, dim=dst.shape,
                  inputs=[src, wp.vec3i(*[int(v) for v in src_origin]), int(dims[axis]),
                          float(half[axis]), taps[axis], axis, float(ratio[axis]),
                          wp.vec3i(*[int(v) for v in lo_]), dst], device=dev)
        src, src_origin = dst, np.asarray(lo_)
    field_block = src.contiguous().reshape((src.size,)) if not src.is_contiguous \
        else src.reshape((src.size,))
    local_field = wp.vec3i(*[int(v) for v in src.shape])
    field_origin = wp.vec3i(*[int(v) for v in f0])
    wp.synchronize_device(dev)
    sigma_tilde = np.ascontiguousarray(sigma_block[sub_slices(piece_extent, block)])
    timings["extinction"] = time.perf_counter() - t0

    # --- the march's constants ------------------------------------------------------------------
    t1 = time.perf_counter()
    geometry = _whole_geometry(volume, data_extent, whole, whole_origin)
    wlights = make_lights(lights, geometry, dev)
    if table is None:
        table = load_table(albedo, device=dev)
    dtable = DeviceTable(table, dev)
    dtable.set_g(round(float(anisotropy), 9))
    transmittance = dtable.transmittance_slice
    lookup_scale = radius * (transmittance.shape[0] - 1) / float(table.sigma_max)
    extent = geometry.extent
    local = extent_shape(piece_extent)
    count = len(lights) * int(np.prod(local))
    lo, hi = _regions(decomposition, whole, fdims)
    march = SimpleNamespace(
        dev=dev, rank=par.rank, lights=wlights, radius=radius,
        spacing=wp.vec3(*(extent / (dims - 1)).astype(np.float32)),
        first=wp.vec3i(*[int(v) for v in np.asarray(piece_extent[0::2]) - whole[0::2]]),
        local=wp.vec3i(*local), extent=wp.vec3f(*extent.astype(np.float32)),
        inv_field=wp.vec3(*((fdims - 1) / np.maximum(extent, 1e-30)).astype(np.float32)),
        samples=samples, field=field_block, local_field=local_field, field_origin=field_origin,
        fdims=wp.vec3i(*[int(v) for v in fdims]), lo=wp.array(lo, dtype=wp.vec3, device=dev),
        hi=wp.array(hi, dtype=wp.vec3, device=dev), transmittance=transmittance,
        lookup_scale=float(lookup_scale), error=wp.zeros(1, dtype=wp.int32, device=dev))
    radiance = np.zeros((count, 3), np.float32)
    timings["march"] = time.perf_counter() - t1
    timings["exchange"] = 0.0

    # --- in chunks of records: start, advance, forward, repeat -----------------------------------
    chunk = max(1, int(max_records))
    chunks = max(par.comm.allgather(-(-count // chunk)))  # every rank joins every round
    rounds = forwarded = 0
    for c in range(chunks):
        begin, end = min(c * chunk, count), min((c + 1) * chunk, count)
        t2 = time.perf_counter()
        records, dest = _start(march, begin, end - begin, par.rank, radiance)
        timings["march"] += time.perf_counter() - t2
        while True:
            home = (dest == par.rank) & (records["s"] == -1)
            radiance[records["idx"][home]] = records["value"][home]
            records, dest = records[~home], dest[~home]
            if par.size == 1:
                if len(records):
                    raise RuntimeError("one rank: a record left its only rank")
                break
            t3 = time.perf_counter()
            order = np.argsort(dest, kind="stable")
            cuts = np.searchsorted(dest[order], np.arange(par.size + 1))
            buckets = [records[order[cuts[q]:cuts[q + 1]]] for q in range(par.size)]
            forwarded += len(records)
            arrived = _exchange(par, buckets)
            rounds += 1
            back = arrived["s"] == -1
            radiance[arrived["idx"][back]] = arrived["value"][back]
            records = arrived[~back].copy()
            in_flight = par.comm.allreduce(len(records))
            timings["exchange"] += time.perf_counter() - t3
            if in_flight == 0:
                break
            t2 = time.perf_counter()
            dest = _advance(march, records)
            timings["march"] += time.perf_counter() - t2
    radiance = radiance.reshape((len(lights),) + tuple(local) + (3,))
    return DistributedRadiance(sigma_tilde, radiance, rounds, forwarded, timings)


def radiance_ghost_levels(whole_dims, spacing, radius: float, samples: int = STEP_SAMPLES) -> int:
    """Input ghost levels around any piece that hold everything
    :func:`distributed_radiance_cache` reads (then no ``σt`` is exchanged): the SAT cube's
    (:func:`~vtkillum.core.ambient.distributed.ghost_levels_for`) plus the step field's box
    and one field cell each side, ``ceil(2 ρ) + taps + 2`` with ``ρ`` data points per field
    interval and ``taps = ceil(r / (samples h)) + 2`` (a bound on the ``extra`` computed there
    for every piece layout)."""
    dims = np.asarray(whole_dims, np.int64).reshape(3)
    spacing = np.asarray(spacing, np.float64).reshape(3)
    fdims = np.asarray(step_field_shape(dims, spacing, radius, samples))
    ratio = (dims - 1) / np.maximum(fdims - 1, 1)
    taps = np.ceil(float(radius) / samples / spacing) + 2
    return ghost_levels_for(radius, spacing) + int(np.max(np.ceil(2 * ratio) + taps + 2))
