"""Distributed chained shadow-ray segments: the one-rank light grid of directional lights,
slab by slab across the ranks.

The one-rank method (:mod:`vtkillum.core.light_transmittance`, ``segment_planes = L``)
takes a directional light's grid planes in slabs from the light-side face
(:func:`~vtkillum.core.light_transmittance.chain_slabs`): the first slab marches exact rays
to the box exit; a point of a later slab marches to the plane its slab looks back to and
multiplies by ``T`` there, interpolated bilinearly in that plane
(:func:`~vtkillum.core.light_transmittance.chain_link`). Here every rank holds one piece
(VTK's split) and, slab after slab:

* starts the segments of its points in the slab with the one-rank float32 operations
  (whole-grid positions, the same link, step count, step and stop level) and marches them
  through its cells; a segment that leaves its cells becomes a record forwarded to the
  rank owning the next sample, exactly like the exact rays of
  :mod:`vtkillum.core.parallel.transmittance` (whose march and record exchange it uses);
* finishes its points: ``T = T(q) exp(-tau h)`` (``T(q)`` where the link is done);
* gathers the slab's last plane, the next slab's look-back plane, from every rank that
  holds part of it: a ``MAX`` all-reduce of the whole plane (zeros elsewhere; pieces that
  share boundary points computed them identically).

The sums are the one-rank sums in its order, so the grid equals the one-rank chained grid
(read from the arrays: ``light_transmittance(..., textures=False)``) bit for bit; the
tests allow 1e-6. Cost: the one-rank segments plus, per slab, the forwarding rounds and one
all-reduce of a plane (``N / L`` of them per light).
"""

from __future__ import annotations

import numpy as np
import warp as wp

from vtkillum.core.light_transmittance import chain_link, chain_slabs, link_transmittance
from vtkillum.core.parallel.transmittance import (
    _NCOL,
    FINISHED,
    Blocks,
    continue_records,
    forward_records,
    march_segment,
    ray_setup,
)
from vtkillum.core.warp_common import (
    Lights,
    Medium,
    component,
    grid_point,
    light_incidence,
    ray_box,
)

#: ``k`` of a point outside the slab being marched (nothing to do).
IDLE = -2


def chained_light(par, medium: Medium, g: Blocks, lights: Lights, li: int, toward,
                  whole_dims, lo_idx, shape, planes: int, out) -> None:
    """Fill ``out[li]`` (numpy ``(n_lights, *shape)`` float32, this piece's points) with
    the chained grid of directional light ``li`` (``toward``: its unit direction towards
    the light in the local frame). Collective over ``par.comm``."""
    dev = par.device
    comm = par.comm
    axis, first, direction, slabs = chain_slabs(toward, whole_dims, planes)
    b, c = (axis + 1) % 3, (axis + 2) % 3
    plane = wp.zeros((int(whole_dims[b]), int(whole_dims[c])), dtype=wp.float32, device=dev)
    dims = wp.vec3i(*(int(v) for v in whole_dims))
    tau = np.zeros((1, *shape), np.float32)
    for r0, r1, look_back in slabs:
        k_out = wp.zeros(shape, dtype=wp.int32, device=dev)
        tau_out = wp.zeros(shape, dtype=wp.float32, device=dev)
        dest = wp.zeros(shape, dtype=wp.int32, device=dev)
        slab = wp.vec3i(axis, first, direction)
        wp.launch(chain_start_kernel, dim=shape,
                  inputs=[medium, g, lights, li, slab, r0, r1, look_back, dims, plane, k_out,
                          tau_out, dest], device=dev)
        k_np, tau_np, dest_np = k_out.numpy(), tau_out.numpy(), dest.numpy()
        active = k_np != IDLE
        done = active & (dest_np == FINISHED)
        tau[0][done] = tau_np[done]
        ijk = np.nonzero(active & ~done)
        outgoing = []
        if ijk[0].size:
            rows = np.empty((ijk[0].size, _NCOL), np.int32)
            rows[:, 0] = par.rank
            for a in range(3):
                rows[:, 1 + a] = ijk[a] + lo_idx[a]
            rows[:, 4] = 0  # the light's slot in `tau`
            rows[:, 5] = k_np[ijk]
            rows[:, 6] = tau_np[ijk].view(np.int32)
            outgoing.append((rows, dest_np[ijk]))
        _forward(par, medium, g, lights, li, slab, look_back, dims, plane, tau, lo_idx,
                 outgoing)
        t_dev = wp.array(tau[0], dtype=wp.float32, device=dev)
        result = wp.array(out[li], dtype=wp.float32, device=dev)
        wp.launch(chain_finish_kernel, dim=shape,
                  inputs=[g, lights, li, slab, r0, r1, look_back, dims, plane, t_dev, result],
                  device=dev)
        out[li] = result.numpy()
        # the next slab's look-back plane, from every piece that holds part of it
        index = first + direction * (r1 - 1)
        local = np.zeros((int(whole_dims[b]), int(whole_dims[c])), np.float32)
        if lo_idx[axis] <= index < lo_idx[axis] + shape[axis]:
            sl = [slice(None)] * 3
            sl[axis] = index - lo_idx[axis]
            values = out[li][tuple(sl)]  # the other two axes in increasing order
            local[lo_idx[b]:lo_idx[b] + shape[b], lo_idx[c]:lo_idx[c] + shape[c]] = \
                values.T if b > c else values
        gathered = local
        if par.size > 1:
            gathered = np.empty_like(local)
            comm.Allreduce(local, gathered, op=_mpi_max())
        plane = wp.array(gathered, dtype=wp.float32, device=dev)


def _forward(par, medium, g, lights, li, slab, look_back, dims, plane, tau, lo_idx,
             outgoing) -> None:
    """The slab's segments forwarded until finished (the exact rays' protocol,
    :func:`~vtkillum.core.parallel.transmittance.forward_records`)."""
    head = [medium, g, lights, li, slab, look_back, dims, plane]
    forward_records(par, tau, lo_idx, outgoing,
                    lambda rows: continue_records(chain_continue_kernel, head, rows, par.device))


def _mpi_max():
    from vtkillum.core.parallel.comm import mpi

    return mpi().MAX


# --- kernels ------------------------------------------------------------------------------------
@wp.func
def segment_setup(g: Blocks, lights: Lights, li: int, slab: wp.vec3i,
                  look_back: int, dims: wp.vec3i, plane: wp.array2d(dtype=wp.float32),
                  p: wp.vec3):
    """The one-rank segment of grid point ``p``: direction, step count, step, stop level,
    ``T(q)`` and whether the link alone gives ``T`` (``done``). The first slab
    (``look_back < 0``) marches the exact ray (:func:`ray_setup`); later slabs the link's
    length, clipped at the box like the one-rank march."""
    if look_back < 0:
        w, n, h, tau_stop = ray_setup(lights, li, p, g)
        return w, n, h, tau_stop, 1.0, 0
    w, _dist, _e = light_incidence(lights, li, p)
    length, inside, _back, jb, jc, fb, fc = chain_link(g.extent, g.spacing, dims, slab[0],
                                                       slab[1], slab[2], look_back, p, w)
    corners = wp.vec4(0.0)
    if inside != 0:  # the gathered plane, indexed [b, c] like the grid's plane
        corners = wp.vec4(plane[jb, jc], plane[jb + 1, jc], plane[jb, jc + 1],
                          plane[jb + 1, jc + 1])
    t_far, stop, done = link_transmittance(inside, corners, fb, fc)
    n = int(0)
    h = float(0.0)
    tau_stop = float(1.0e30)
    if done == 0:
        seg = wp.min(ray_box(p, w, g.extent)[1], length)
        if seg > 0.0:
            n = int(wp.ceil(seg / g.step))
            h = seg / float(n)
            tau_stop = -wp.log(stop) / h
    return w, n, h, tau_stop, t_far, done


@wp.func
def in_slab(g: Blocks, slab: wp.vec3i, r0: int, r1: int, i: int, j: int, k: int):
    """Whether piece point ``(i, j, k)`` lies on a plane ``r0 <= r < r1`` of the slab."""
    index = component(wp.vec3i(g.lo[0] + i, g.lo[1] + j, g.lo[2] + k), slab[0])
    r = (index - slab[1]) * slab[2]
    return r >= r0 and r < r1


@wp.kernel
def chain_start_kernel(m: Medium, g: Blocks, lights: Lights, li: int, slab: wp.vec3i, r0: int,
                       r1: int, look_back: int, dims: wp.vec3i,
                       plane: wp.array2d(dtype=wp.float32), k_out: wp.array3d(dtype=wp.int32),
                       tau_out: wp.array3d(dtype=wp.float32), dest: wp.array3d(dtype=wp.int32)):
    """Start the segment of piece point ``wp.tid()`` if it is in the slab (``slab`` = axis,
    first plane index, direction); writes the next sample (:data:`IDLE` outside the slab),
    the sum so far and the rank to go on (-1: finished)."""
    i, j, k = wp.tid()
    if not in_slab(g, slab, r0, r1, i, j, k):
        k_out[i, j, k] = IDLE
        dest[i, j, k] = FINISHED
        return
    p = grid_point(g.lo[0] + i, g.lo[1] + j, g.lo[2] + k, g.spacing)
    w, n, h, tau_stop, _t_far, _done = segment_setup(g, lights, li, slab, look_back, dims,
                                                     plane, p)
    s, tau, d = march_segment(m, g, p, w, n, h, tau_stop, 0, 0.0)
    k_out[i, j, k] = s
    tau_out[i, j, k] = tau
    dest[i, j, k] = d


@wp.kernel
def chain_continue_kernel(m: Medium, g: Blocks, lights: Lights, li: int, slab: wp.vec3i,
                          look_back: int, dims: wp.vec3i, plane: wp.array2d(dtype=wp.float32),
                          rows: wp.array2d(dtype=wp.int32), tau_in: wp.array(dtype=wp.float32),
                          k_out: wp.array(dtype=wp.int32), tau_out: wp.array(dtype=wp.float32),
                          dest: wp.array(dtype=wp.int32)):
    """Go on with received segment record ``wp.tid()`` (columns
    :data:`~vtkillum.core.parallel.transmittance.RECORD_COLUMNS`)."""
    r = wp.tid()
    p = grid_point(rows[r, 1], rows[r, 2], rows[r, 3], g.spacing)
    w, n, h, tau_stop, _t_far, _done = segment_setup(g, lights, li, slab, look_back, dims,
                                                     plane, p)
    s, tau, d = march_segment(m, g, p, w, n, h, tau_stop, rows[r, 5], tau_in[r])
    k_out[r] = s
    tau_out[r] = tau
    dest[r] = d


@wp.kernel
def chain_finish_kernel(g: Blocks, lights: Lights, li: int, slab: wp.vec3i, r0: int, r1: int,
                        look_back: int, dims: wp.vec3i, plane: wp.array2d(dtype=wp.float32),
                        tau: wp.array3d(dtype=wp.float32), out: wp.array3d(dtype=wp.float32)):
    """``T = T(q) exp(-tau h)`` (``T(q)`` where the link is done or the segment has no
    length) at the slab's piece points; the one-rank kernel's expressions."""
    i, j, k = wp.tid()
    if not in_slab(g, slab, r0, r1, i, j, k):
        return
    p = grid_point(g.lo[0] + i, g.lo[1] + j, g.lo[2] + k, g.spacing)
    _w, n, h, _stop, t_far, done = segment_setup(g, lights, li, slab, look_back, dims,
                                                 plane, p)
    t = t_far
    if done == 0 and n > 0:
        t = t_far * wp.exp(-tau[i, j, k] * h)
    out[i, j, k] = t


@wp.kernel
def piece_fluence_kernel(g: Blocks, lights: Lights, transmittance: wp.array4d(dtype=wp.float32),
                         fluence: wp.array3d(dtype=wp.vec3)):
    """``sum_l T_l E_l`` at piece point ``wp.tid()`` (whole-grid position; the one-rank
    fluence's expression)."""
    i, j, k = wp.tid()
    p = grid_point(g.lo[0] + i, g.lo[1] + j, g.lo[2] + k, g.spacing)
    acc = wp.vec3(0.0, 0.0, 0.0)
    for li in range(lights.count):
        _w, _dist, e = light_incidence(lights, li, p)
        acc += transmittance[li, i, j, k] * e
    fluence[i, j, k] = acc
