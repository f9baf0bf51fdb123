"""Transmittance caching: one adaptive volumetric shadow map per virtual light (section 3.4).

An AVSM (Salvi, Vidimče, Lauritzen & Lefohn 2010) stores, per texel of a cube map
centred on the VL, the transmittance along the texel's ray as ``m`` nodes
``(depth d_i, transmittance t_i)`` of a piecewise-linear curve; the implicit first node
is ``(0, 1)`` and beyond the last node the curve stays at ``t_m``.

Construction (one thread per texel): the ray from the VL through the texel centre is
marched to the box exit with the midpoint rule on equal steps no longer than ``step``
(unscaled medium). A step end where the marched curve stops being straight — it leaves
the sleeve of half-width :data:`SLEEVE` around the line from the last node through the
samples since — is *inserted* as a node (the previous sample becomes the node), and
whenever there are more than ``m`` nodes the interior node whose removal changes the
area under the curve least (the triangle it forms with its neighbours) is *removed*:
Salvi et al.'s adaptive insertion and compression, fed front to back. Without the
sleeve every step would be a node, each new node would form a tiny triangle with its
close predecessor, and the greedy removal would erase the corners of a curve (a slab's
entry and exit); with it, empty space and straight pieces cost no node. The march stops
once the transmittance falls below ``stop_t``. Nodes hold the marched values, so a map
is exact at its stored depths.

Lookup at a point ``x`` for the VL at ``x_j``: the direction ``x - x_j`` picks a face and
continuous texel coordinates, the depth is ``|x - x_j|``; each texel's curve is evaluated
at that depth (linear between nodes) and the four nearest texels of the face are blended
bilinearly (*trilinear*: bilinear on the face, linear in depth), or the nearest texel is
used (*point*). Because the map is built for the unscaled medium, a global density
scale ``S`` is applied at lookup as ``T^S`` (eq. 7, exact for a cached curve).

Layout: node ``i`` of texel ``(row, col)`` of cube ``face`` of the map in ``slot`` is
``nodes[(((slot * 6 + face) * R + row) * R + col) * m + i]`` (``vec2(depth, T)``), with
``R`` the resolution per face: texel-major, so that a lookup's scan along one texel's
nodes stays in one cache line (a node-major layout, which puts neighbouring texels'
nodes side by side for the threads of a warp, measured 1.6x slower on an H100: every
step of the scan missed the cache). A slot per VL, handed out by
:class:`ShadowMapPool`.
Faces: ``+x, -x, +y, -y, +z, -z``; on the face of major axis ``a`` the texel
coordinates follow axes ``(a + 1) % 3`` (columns) and ``(a + 2) % 3`` (rows).

Simplifications against the paper: bilinear filtering does not cross cube faces (the
coordinates are clamped to the face), and nodes come from one march per texel (thinned
by the sleeve) rather than from rasterised fragments.
"""

from __future__ import annotations

import functools
import math
from typing import Any

import numpy as np
import warp as wp

from vtkillum.core.warp_common import Medium, block_run, lookup_sigma_t, ray_box, sample_scalar

#: Largest number of nodes per texel (``m``); the paper uses 8–12.
MAX_NODES = 16
#: Lookup filters.
FILTERS = {"point": 0, "trilinear": 1}
#: Default transmittance below which construction stops (before any scale exponent).
STOP_TRANSMITTANCE = 1.0e-4
#: Half-width of the sleeve that decides where the marched curve bends (transmittance).
SLEEVE = wp.constant(1.0e-3)


@wp.struct
class ShadowMaps:
    """All AVSMs on the device: ``nodes`` (see the module docstring), ``resolution`` per
    face, ``node_count`` (m), ``filter`` (0 point, 1 trilinear)."""

    nodes: wp.array(dtype=wp.vec2)
    resolution: int
    node_count: int
    filter: int


class ShadowMapPool:
    """A growable set of AVSM slots on one device.

    Parameters
    ----------
    resolution : int
        Texels per face edge (``R``, at least 2).
    node_count : int
        Nodes per texel (``m``, 2 .. :data:`MAX_NODES`).
    device : str
    """

    def __init__(self, resolution: int, node_count: int, device: str) -> None:
        self.resolution = int(resolution)
        self.node_count = int(node_count)
        if self.resolution < 2:
            raise ValueError(f"avsm_resolution must be at least 2 texels per face, got "
                             f"{resolution}")
        if not 2 <= self.node_count <= MAX_NODES:
            raise ValueError(f"avsm_nodes must lie in [2, {MAX_NODES}] (the paper uses 8-12), "
                             f"got {node_count}")
        self.device = device
        self.capacity = 0
        self.nodes = wp.zeros(0, dtype=wp.vec2, device=device)
        self.epoch = np.zeros(0, np.int64)  # medium version each slot was built for
        self._free: list[int] = []
        self.builds = 0  # AVSMs built so far (statistics)

    @property
    def texels_per_map(self) -> int:
        return 6 * self.resolution * self.resolution

    @property
    def nodes_per_map(self) -> int:
        return self.texels_per_map * self.node_count

    @property
    def nbytes(self) -> int:
        return int(self.capacity * self.nodes_per_map * 8)

    def allocate(self, n: int) -> np.ndarray:
        """``n`` free slots (the pool grows when needed)."""
        n = int(n)
        if len(self._free) < n:
            self._grow(self.capacity + n - len(self._free))
        slots = np.array(sorted(self._free)[:n], np.int32)
        taken = set(slots.tolist())
        self._free = [s for s in self._free if s not in taken]
        return slots

    def release(self, slots) -> None:
        """Return slots to the pool."""
        self._free.extend(int(s) for s in np.asarray(slots).reshape(-1) if s >= 0)

    def _grow(self, capacity: int) -> None:
        capacity = max(int(capacity), int(math.ceil(self.capacity * 1.5)), 16)
        size = capacity * self.nodes_per_map
        try:
            nodes = wp.zeros(size, dtype=wp.vec2, device=self.device)
        except Exception as err:
            raise MemoryError(
                f"could not allocate AVSMs for {capacity} virtual lights "
                f"({size * 8 / 2**20:.0f} MiB on {self.device}): {err}; lower "
                "the VL count, avsm_resolution or avsm_nodes") from err
        if self.capacity > 0:
            wp.copy(nodes, self.nodes, count=self.nodes.size)
        self._free.extend(range(self.capacity, capacity))
        self.epoch = np.concatenate([self.epoch, np.full(capacity - self.capacity, -1, np.int64)])
        self.nodes = nodes
        self.capacity = capacity

    def build(self, medium: Medium, positions, vl_indices, slots, step: float, epoch: int,
              stop_t: float = STOP_TRANSMITTANCE) -> None:
        """Build the AVSMs of VLs ``vl_indices`` (positions on the device) into ``slots``.

        Parameters
        ----------
        medium : Medium
            The unscaled medium.
        positions : wp.array(vec3)
            VL positions (local frame).
        vl_indices, slots : array-like of int
            Which VLs, and the slot each one's map goes to.
        step : float
            Longest marching step along texel rays (world units).
        epoch : int
            Version of the medium, remembered per slot (:attr:`epoch`).
        stop_t : float
            Transmittance at which a texel's march stops.
        """
        vl_indices = np.asarray(vl_indices, np.int32).reshape(-1)
        slots = np.asarray(slots, np.int32).reshape(-1)
        n = len(vl_indices)
        if n == 0:
            return
        R = self.resolution
        wp.launch(build_kernel(self.node_count), dim=(n, 6, R, R),
                  inputs=[medium, positions,
                          wp.array(vl_indices, dtype=wp.int32, device=self.device),
                          wp.array(slots, dtype=wp.int32, device=self.device), R,
                          float(step), float(stop_t), self.nodes],
                  device=self.device)
        self.epoch[slots] = int(epoch)
        self.builds += n

    def maps(self, lookup: str = "trilinear") -> ShadowMaps:
        """The pool as a :class:`ShadowMaps` struct for kernels."""
        if lookup not in FILTERS:
            raise ValueError(f"avsm_lookup must be one of {sorted(FILTERS)}, got {lookup!r}")
        s = ShadowMaps()
        s.nodes = self.nodes if self.capacity > 0 else wp.zeros(self.node_count,
                                                                 dtype=wp.vec2, device=self.device)
        s.resolution = self.resolution
        s.node_count = self.node_count
        s.filter = FILTERS[lookup]
        return s

    def curve(self, slot: int, face: int, row: int, col: int) -> np.ndarray:
        """The nodes ``(m, 2)`` of one texel (host copy, for tests and pictures)."""
        R = self.resolution
        first = (((int(slot) * 6 + int(face)) * R + int(row)) * R + int(col)) * self.node_count
        return self.nodes.numpy()[first:first + self.node_count]


def empty_maps(device: str, node_count: int = 2) -> ShadowMaps:
    """A placeholder :class:`ShadowMaps` for kernels that ray-march instead."""
    s = ShadowMaps()
    s.nodes = wp.zeros(node_count, dtype=wp.vec2, device=device)
    s.resolution = 2
    s.node_count = node_count
    s.filter = 0
    return s


def texel_view(maps: ShadowMaps) -> wp.array:
    """``maps.nodes`` seen as one :func:`texel_type` vector per texel, for
    :func:`lookup_function` (no copy: valid while ``maps.nodes`` is)."""
    n = maps.nodes.shape[0] // maps.node_count
    return wp.array(ptr=maps.nodes.ptr, dtype=texel_type(maps.node_count), shape=(n,),
                    device=maps.nodes.device, copy=False)


def texel_direction_host(face: int, row: int, col: int, resolution: int) -> np.ndarray:
    """Unit direction of a texel centre (numpy mirror of :func:`texel_direction`)."""
    a = face // 2
    sign = 1.0 if face % 2 == 0 else -1.0
    v = np.zeros(3)
    v[a] = sign
    v[(a + 1) % 3] = -1.0 + (col + 0.5) * 2.0 / resolution
    v[(a + 2) % 3] = -1.0 + (row + 0.5) * 2.0 / resolution
    return v / np.linalg.norm(v)


# --- device functions ---------------------------------------------------------------------------
@wp.func
def texel_direction(face: int, s: float, t: float):
    """Unit direction through face coordinates ``(s, t)`` in ``[-1, 1]`` of cube ``face``."""
    a = face // 2
    sign = float(1.0)
    if face % 2 == 1:
        sign = -1.0
    v = wp.vec3(0.0)
    v[a] = sign
    v[(a + 1) % 3] = s
    v[(a + 2) % 3] = t
    return wp.normalize(v)


@wp.func
def cube_coords(v: wp.vec3):
    """Face and coordinates ``(s, t)`` in ``[-1, 1]`` of direction ``v`` (not necessarily unit).

    Written with selects rather than ``v[a]`` for a computed axis ``a``: a vector indexed
    by a run-time value leaves registers for local memory on the GPU.
    """
    ax = wp.abs(v[0])
    ay = wp.abs(v[1])
    az = wp.abs(v[2])
    on_x = ax >= ay and ax >= az
    on_y = (not on_x) and ay >= az
    major = wp.where(on_x, v[0], wp.where(on_y, v[1], v[2]))
    inv = 1.0 / wp.abs(major)
    face = wp.where(on_x, 0, wp.where(on_y, 2, 4)) + wp.where(major < 0.0, 1, 0)
    s = wp.where(on_x, v[1], wp.where(on_y, v[2], v[0])) * inv
    t = wp.where(on_x, v[2], wp.where(on_y, v[0], v[1])) * inv
    return face, s, t


@wp.func
def texel_transmittance(nodes: wp.array(dtype=wp.vec2), first: int, count: int, depth: float):
    """The piecewise-linear curve of one texel at ``depth`` (implicit first node (0, 1));
    its nodes are ``nodes[first + i]``."""
    d0 = float(0.0)
    t0 = float(1.0)
    for i in range(count):
        nd = nodes[first + i]
        if depth <= nd[0]:
            if nd[0] > d0:
                return t0 + (nd[1] - t0) * (depth - d0) / (nd[0] - d0)
            return nd[1]
        d0 = nd[0]
        t0 = nd[1]
    return t0


@wp.func
def avsm_transmittance(sm: ShadowMaps, slot: int, origin: wp.vec3, x: wp.vec3):
    """Cached transmittance from the VL at ``origin`` (its map in ``slot``) to ``x``."""
    v = x - origin
    return avsm_lookup(sm, slot, v, wp.length(v))


@wp.func
def map_footprint(sm: ShadowMaps, slot: int, v: wp.vec3):
    """The texels a lookup along ``v`` reads in the map in ``slot``.

    Returns ``(texel, fx, fy)``: the flat index ``((slot * 6 + face) * R + row) * R + col``
    of the nearest texel (point filter; weights 0) or of the first of the four that are
    blended (trilinear: ``texel + 1``, ``texel + R``, ``texel + R + 1`` with the bilinear
    weights ``fx``, ``fy``).
    """
    face, s, t = cube_coords(v)
    R = sm.resolution
    base = (slot * 6 + face) * R
    fu = (s + 1.0) * 0.5 * float(R) - 0.5
    fv = (t + 1.0) * 0.5 * float(R) - 0.5
    if sm.filter == 0:
        c = wp.clamp(int(wp.floor(fu + 0.5)), 0, R - 1)
        r = wp.clamp(int(wp.floor(fv + 0.5)), 0, R - 1)
        return (base + r) * R + c, 0.0, 0.0
    c0 = wp.clamp(int(wp.floor(fu)), 0, R - 2)
    r0 = wp.clamp(int(wp.floor(fv)), 0, R - 2)
    return ((base + r0) * R + c0, wp.clamp(fu - float(c0), 0.0, 1.0),
            wp.clamp(fv - float(r0), 0.0, 1.0))


@wp.func
def avsm_lookup(sm: ShadowMaps, slot: int, v: wp.vec3, depth: float):
    """:func:`avsm_transmittance` for the offset ``v = x - origin`` of length ``depth``."""
    if depth <= 0.0:
        return 1.0
    texel, fx, fy = map_footprint(sm, slot, v)
    m = sm.node_count
    first = texel * m
    if sm.filter == 0:
        return texel_transmittance(sm.nodes, first, m, depth)
    row = sm.resolution * m
    t00 = texel_transmittance(sm.nodes, first, m, depth)
    t01 = texel_transmittance(sm.nodes, first + m, m, depth)
    t10 = texel_transmittance(sm.nodes, first + row, m, depth)
    t11 = texel_transmittance(sm.nodes, first + row + m, m, depth)
    return wp.lerp(wp.lerp(t00, t01, fx), wp.lerp(t10, t11, fx), fy)


@functools.cache
def texel_type(count: int):
    """The vector of one texel's ``count`` nodes, ``(d_0, t_0, d_1, t_1, ...)``: the type of
    :func:`texel_view`."""
    return wp.types.vector(length=2 * int(count), dtype=wp.float32)


@functools.cache
def lookup_function(count: int):
    """:func:`avsm_lookup` for maps of ``count`` nodes per texel, made on first use.

    ``lookup(sm, texels, slot, v, depth)`` with ``texels`` the maps as one vector per
    texel (:func:`texel_view`). Each texel's curve is evaluated by counting its
    nodes before the depth and reading the two nodes around it, instead of a scan that
    stops at the first node behind the depth: the loads no longer wait for one another,
    the threads of a warp no longer wait for the one with the longest scan, and a texel's
    depths are read at constant offsets from one address (an index into ``sm.nodes``
    costs an address computation per node). Same values as :func:`avsm_lookup` (tested).
    """
    COUNT = int(count)

    @wp.func
    def texel_counted(texels: wp.array(dtype=Any), nodes: wp.array(dtype=wp.vec2), texel: int,
                      depth: float):
        """:func:`texel_transmittance` of texel ``texel`` (``COUNT`` nodes)."""
        x = texels[texel]
        k = int(0)
        for i in range(wp.static(COUNT)):
            k += wp.where(x[2 * i] < depth, 1, 0)
        first = texel * wp.static(COUNT)
        d0 = float(0.0)
        t0 = float(1.0)
        if k > 0:
            node = nodes[first + k - 1]
            d0 = node[0]
            t0 = node[1]
        if k == wp.static(COUNT):
            return t0
        nd = nodes[first + k]
        if nd[0] > d0:
            return t0 + (nd[1] - t0) * (depth - d0) / (nd[0] - d0)
        return nd[1]

    @wp.func
    def lookup(sm: ShadowMaps, texels: wp.array(dtype=Any), slot: int, v: wp.vec3,
               depth: float):
        """:func:`avsm_lookup` for maps of ``COUNT`` nodes per texel."""
        if depth <= 0.0:
            return 1.0
        texel, fx, fy = map_footprint(sm, slot, v)
        if sm.filter == 0:
            return texel_counted(texels, sm.nodes, texel, depth)
        R = sm.resolution
        t00 = texel_counted(texels, sm.nodes, texel, depth)
        t01 = texel_counted(texels, sm.nodes, texel + 1, depth)
        t10 = texel_counted(texels, sm.nodes, texel + R, depth)
        t11 = texel_counted(texels, sm.nodes, texel + R + 1, depth)
        return wp.lerp(wp.lerp(t00, t01, fx), wp.lerp(t10, t11, fx), fy)

    return lookup


# --- construction kernels ---------------------------------------------------------------------
@functools.cache
def node_insertion(count: int):
    """The ``wp.func`` ``insert_node(D, T, n, depth, trans) -> (D, T, n)`` of the
    construction for ``count`` nodes per texel (``D``, ``T``: vectors of ``count + 1``
    floats holding ``n <= count`` nodes), made on first use.

    Appends node ``(depth, trans)``; if that makes ``count + 1`` nodes, removes the
    interior node whose triangle with its neighbours has the smallest area (Salvi et al.
    2010; the implicit node (0, 1) is the left neighbour of node 0, the last node is never
    removed; the first of equal areas goes). Every index is a compile-time constant
    (unrolled selects), so the vectors stay in registers.
    """
    COUNT = int(count)

    @wp.func
    def insert_node(D: Any, T: Any, n: int, depth: float, trans: float):
        for i in range(wp.static(COUNT + 1)):
            D[i] = wp.where(i == n, depth, D[i])
            T[i] = wp.where(i == n, trans, T[i])
        n += 1
        if n > wp.static(COUNT):
            best = int(0)
            best_area = float(1.0e30)
            for j in range(wp.static(COUNT)):
                dl = float(0.0)
                tl = float(1.0)
                if j > 0:
                    dl = D[j - 1]
                    tl = T[j - 1]
                area = wp.abs((D[j] - dl) * (T[j + 1] - tl) - (D[j + 1] - dl) * (T[j] - tl))
                if area < best_area:
                    best_area = area
                    best = j
            for j in range(wp.static(COUNT)):
                D[j] = wp.where(j >= best, D[j + 1], D[j])
                T[j] = wp.where(j >= best, T[j + 1], T[j])
            n -= 1
        return D, T, n

    return insert_node


@functools.cache
def build_kernel(count: int):
    """The construction kernel for ``count`` nodes per texel, made on first use.

    The kernel keeps a texel's nodes in vectors of ``count + 1`` registers that it only
    indexes with compile-time constants (:func:`node_insertion`); with a run-time
    ``count`` they were indexed at run time, lived in local memory and were copied in and
    out at every insertion: 42 -> 22 ms for 1006 maps of 40^2 x 6 texels, 8 nodes, on an
    H100, with bit-identical nodes.
    """
    COUNT = int(count)
    NodeVec = wp.types.vector(length=COUNT + 1, dtype=wp.float32)
    insert_node = node_insertion(COUNT)

    @wp.kernel(module="unique")
    def build(m: Medium, positions: wp.array(dtype=wp.vec3), vl_index: wp.array(dtype=wp.int32),
              slots: wp.array(dtype=wp.int32), R: int, step: float, stop_t: float,
              nodes: wp.array(dtype=wp.vec2)):
        """March one texel ray of one VL's cube map and store its compressed curve.

        ``wp.tid()`` is ``(b, face, row, col)``: VL ``vl_index[b]`` (map ``slots[b]``), cube
        face, texel row and column. Depths in world units, transmittance unitless; writes
        the ``COUNT`` nodes of the texel (layout in the module docstring).
        """
        b, face, row, col = wp.tid()
        x0 = positions[vl_index[b]]
        d = texel_direction(face, -1.0 + (float(col) + 0.5) * 2.0 / float(R),
                            -1.0 + (float(row) + 0.5) * 2.0 / float(R))
        length = ray_box(x0, d, m.extent)[1]
        D = NodeVec()
        T = NodeVec()
        n = int(0)
        if length > 0.0:
            steps = int(wp.ceil(length / step))
            h = length / float(steps)
            tau = float(0.0)
            # Sleeve of the line from the last inserted node (anchor) through the samples since.
            anchor_d = float(0.0)
            anchor_t = float(1.0)
            lo = float(-1.0e30)
            hi = float(1.0e30)
            prev_d = float(0.0)
            prev_t = float(1.0)
            # Runs of steps inside one block: an empty block's samples add exactly 0.
            run_empty = int(0)
            run_last = int(-1)
            for k in range(steps):
                if k > run_last:
                    run_empty, run_last = block_run(m, x0, d, h, k, 0.5)
                if run_empty == 0:
                    tau += lookup_sigma_t(m, sample_scalar(m.scalars, m.inv_spacing,
                                                           x0 + ((float(k) + 0.5) * h) * d)) * h
                tk = wp.exp(-tau)
                dk = float(k + 1) * h
                span = dk - anchor_d
                new_lo = wp.max(lo, (tk - SLEEVE - anchor_t) / span)
                new_hi = wp.min(hi, (tk + SLEEVE - anchor_t) / span)
                if new_lo > new_hi and k > 0:
                    # The previous sample ends a straight piece: it becomes a node.
                    D, T, n = insert_node(D, T, n, prev_d, prev_t)
                    anchor_d = prev_d
                    anchor_t = prev_t
                    span = dk - anchor_d
                    lo = (tk - SLEEVE - anchor_t) / span
                    hi = (tk + SLEEVE - anchor_t) / span
                else:
                    lo = new_lo
                    hi = new_hi
                prev_d = dk
                prev_t = tk
                if tk < stop_t:
                    break
            D, T, n = insert_node(D, T, n, prev_d, prev_t)
        first = (((slots[b] * 6 + face) * R + row) * R + col) * wp.static(COUNT)
        # Unused nodes repeat the last one (the curve stays at its last value).
        last_d = float(0.0)
        last_t = float(1.0)
        for i in range(wp.static(COUNT)):
            if i < n:
                last_d = D[i]
                last_t = T[i]
        for i in range(wp.static(COUNT)):
            if i < n:
                nodes[first + i] = wp.vec2(D[i], T[i])
            else:
                nodes[first + i] = wp.vec2(last_d, last_t)

    return build
