"""The physical model's flux-limited diffusion solved across MPI ranks on light-grid blocks
with halo exchange (issue 36): the distributed counterpart of
:class:`~vtkillum.core.convection_diffusion.radiative.RadiativeDiffusion`.

Every rank iterates on its block of the light grid; the data and the light grid are never
gathered whole. Level for level it is the one-rank method:

* **hierarchy**: the one-rank levels (halve the axes with at least 4 points while a level
  has more than ``COARSEST_CELLS``); a coarse cell ``I`` belongs to the rank owning its
  child ``2 I`` (as :mod:`~vtkillum.core.convection_diffusion.distributed_multigrid`).
  Fields live on *ghosted boxes*: the block grown by two points (clipped to the grid),
  on coarse levels also every cell the fine block's prolongation reads. Two layers,
  because a coarse face's homogenized conductance reads the fine face ``2 I + 2``;
* **lagged coefficients**: after a halo exchange of ``phi``, the one-rank face kernels
  (:data:`~vtkillum.core.convection_diffusion.radiative.FACE_KERNELS`, imported) run on
  the ghosted arrays: their bounds tests use the array's shape, and a ghosted box ends
  either at the grid's face or one layer beyond the block, so every face whose lower cell
  the rank owns gets its one-rank value (the faces computed in the ghosts are overwritten
  by their owners' in the halo exchange that follows). The Marshak leakage runs on the
  block's cells that lie on the *global* box faces (:func:`rad_leakage_kernel`);
  the coarse operators are homogenized from the finer level's (the one-rank
  ``coarsening`` arithmetic at global indices, :func:`rad_coarse_coefficients_kernel`);
* **V(2,2) cycle**: red–black Gauss–Seidel with the colour of the global index parity
  and a halo exchange before each colour; the residual on the block, its halo, the mean
  over the children; trilinear prolongation from the coarse level's ghosts;
* **coarse levels gathered**: the first level (below the finest) with at most
  ``gather_cells`` cells, and in any case the coarsest, is gathered onto rank 0: its
  coefficients after every update, its right-hand side in every V-cycle. Rank 0 runs the
  one-rank ``RadiativeDiffusion`` from that level down (its hierarchy from there is the
  same; its finest coefficients are the gathered ones, the coarser ones homogenized by
  the one-rank code) and scatters the correction back;
* **nested iteration** of a cold start: ``Q`` and ``x`` restricted down the distributed
  levels, the gathered level and below iterated on rank 0 by the one-rank nested start,
  the change prolonged back and iterated level by level on the blocks;
* **residual norms, the clip of the displaced source and Anderson's Gram matrix**: sums
  over the owned cells in float64, ``Allreduce``; Anderson's weights are then solved on
  every rank from the same numbers (the one-rank ``anderson_weights_kernel``).

In exact arithmetic the iterates are the one-rank ones. In float32 they differ by the
order of the sums (the residual norms and the Gram matrix: per cell in float64 here, per
tile in float32 on one rank), so the mixing weights and the stopping test can differ in
their last bits and a solve can end one outer iteration earlier or later.

Simplified: always a cold start (no warm start, no captured graphs); ghost transfers go
through host buffers.
"""

from __future__ import annotations

import itertools
import math

import numpy as np
import warp as wp

from vtkillum.core.convection_diffusion.coarsening import (
    coarse_coefficients,
    face_k,
    resistance,
    set_face_k,
)
from vtkillum.core.convection_diffusion.diffusion import DiffusionReport
from vtkillum.core.convection_diffusion.distributed_layout import (
    Halo,
    Layout,
    mpi,
    read_region,
    region,
    write_region,
)
from vtkillum.core.convection_diffusion.distributed_multigrid import (
    block_prolong_add_kernel,
    block_restrict_kernel,
    coarse_ghost,
)
from vtkillum.core.convection_diffusion.multigrid import child_of, restrict_kernel
from vtkillum.core.convection_diffusion.radiative import (
    ANDERSON_MAX_WEIGHT,
    ANDERSON_SLOTS,
    COARSE_SWEEPS,
    COARSEST_CELLS,
    COARSEST_ITERATIONS,
    FACE_KERNELS,
    FLOAT32_EPS,
    LIMITERS,
    MEDIUM_DEPTH,
    NESTED_ITERATIONS,
    POST_SMOOTH,
    PRE_SMOOTH,
    RadiativeDiffusion,
    anderson_mix_kernel,
    anderson_weights_kernel,
    clip_rescale_kernel,
    counted_kernel,
    gauss_seidel_point,
    gradient_sq,
    limited_vec,
    medium_kernel,
    neighbours,
    stalled,
)
from vtkillum.core.warp_common import axis_offset, component

#: Levels (below the finest) with at most this many cells are gathered onto rank 0.
GATHER_CELLS = 4096
#: Ghost layers of every level (a homogenized coarse face reads the fine face ``2 I + 2``).
GHOST = 2
#: MPI tags: ``HALO_TAG + 16 level + n`` for array ``n`` of a level's halo exchange.
HALO_TAG = 7000


def _vec3(shape, device):
    return wp.zeros(shape, dtype=wp.vec3, device=device)


class _Level:
    """One distributed level: layout, halo, medium, coefficients and work arrays."""

    def __init__(self, comm, layout: Layout, spacing, device):
        self.layout = layout
        self.halo = Halo(comm, layout)
        self.shape = tuple(int(v) for v in layout.shape)
        self.spacing = np.asarray(spacing, dtype=np.float64)
        self.h = wp.vec3(*self.spacing.astype(np.float32))
        self.inv_h = wp.vec3(*(1.0 / self.spacing).astype(np.float32))
        local = layout.local_shape
        self.sigma_a, self.sigma_tr, self.absorb = (_vec3(local, device) for _ in range(3))
        # face coefficients on the ghosted box: k[a][p] is the face between p and p + e_a
        self.kx, self.ky, self.kz = (_vec3(local, device) for _ in range(3))
        self.x, self.b, self.r = (_vec3(local, device) for _ in range(3))
        self.q = self.sol = self.estimate = None
        self.off = wp.vec3i(*layout.ghost()[0])
        self.blo = wp.vec3i(*layout.lo)
        self.n = wp.vec3i(*layout.shape)

    @property
    def coefficients(self):
        return [self.kx, self.ky, self.kz, self.absorb]

    def nested_arrays(self, device) -> None:
        if self.q is None:
            self.q, self.sol, self.estimate = (_vec3(self.layout.local_shape, device)
                                               for _ in range(3))


def _ghost_box(lo, hi, shape, extra=None):
    """Block ``[lo, hi)`` grown by :data:`GHOST` (clipped), united with box ``extra``."""
    if not np.all(hi > lo):
        return extra if extra is not None else (lo.copy(), lo.copy())
    glo, ghi = np.maximum(lo - GHOST, 0), np.minimum(hi + GHOST, shape)
    if extra is not None and np.all(extra[1] > extra[0]):
        glo, ghi = np.minimum(glo, extra[0]), np.maximum(ghi, extra[1])
    return glo, ghi


class DistributedRadiativeDiffusion:
    """``-div(D grad phi) + sigma_a phi = Q`` on the light-grid blocks of ``layout``.

    Parameters
    ----------
    comm : mpi4py communicator
    layout : Layout
        The light grid's blocks (any ghosts: fields are copied in and out by block).
    spacing : (3,) float
        Light-grid spacing (world units).
    limiter : str
        One of :data:`~vtkillum.core.convection_diffusion.radiative.LIMITERS`.
    device : str
        This rank's warp device.
    gather_cells : int
        Levels below the finest with at most this many cells go to rank 0.
    """

    def __init__(self, comm, layout: Layout, spacing, limiter: str = "levermore-pomraning",
                 device: str = "cpu", gather_cells: int = GATHER_CELLS) -> None:
        if limiter not in LIMITERS:
            raise ValueError(f"unknown flux limiter {limiter!r}; choose one of {sorted(LIMITERS)}")
        self.comm = comm
        self.device = device
        self.limiter = limiter
        self.anderson = True
        shape = np.asarray(layout.shape, dtype=np.int64)
        top = Layout(shape, layout.blocks, layout.rank,
                     [_ghost_box(lo, hi, shape) for lo, hi in layout.blocks])
        layouts, spacings, self.ratios = [top], [np.asarray(spacing, dtype=np.float64)], []
        while int(np.prod(layouts[-1].shape)) > COARSEST_CELLS:  # the one-rank hierarchy
            n = layouts[-1].shape
            halve = n >= 4
            if not halve.any():
                break
            nc = np.where(halve, (n + 1) // 2, n)
            fine_blocks = layouts[-1].blocks
            blocks = [(np.where(halve, (lo + 1) // 2, lo), np.where(halve, (hi + 1) // 2, hi))
                      for lo, hi in fine_blocks]
            ghosts = [_ghost_box(c[0], c[1], nc, coarse_ghost(f[0], f[1], halve, nc)
                                 if np.all(f[1] > f[0]) else None)
                      for c, f in zip(blocks, fine_blocks)]
            layouts.append(Layout(nc, blocks, layout.rank, ghosts))
            spacings.append(spacings[-1] * n / nc)
            self.ratios.append(wp.vec3i(*(halve.astype(int) + 1)))
        self.count = len(layouts)  # levels of the whole hierarchy
        gathered = None
        if self.count > 1:
            gathered = next((i for i in range(1, self.count)
                             if int(np.prod(layouts[i].shape)) <= gather_cells), self.count - 1)
        self.gathered = gathered
        kept = self.count if gathered is None else gathered + 1
        self.levels = [_Level(comm, lay, h, device) for lay, h in zip(layouts[:kept],
                                                                      spacings[:kept])]
        self.shape = tuple(int(v) for v in shape)
        self.spacing = spacings[0]
        self.d_max = float(np.linalg.norm(self.spacing * (shape - 1)))
        self.min_sigma = MEDIUM_DEPTH / float(self.spacing.min())
        self._acc = wp.zeros(6, dtype=wp.float64, device=device)
        self._sums = wp.zeros(6, dtype=wp.float64, device=device)
        self._counted = wp.zeros(top.local_shape, dtype=wp.uint8, device=device)
        self.serial = None
        if gathered is not None and comm.Get_rank() == 0:
            self.serial = RadiativeDiffusion(layouts[gathered].shape, spacings[gathered],
                                             limiter, device)
            self.serial.d_max = self.d_max  # the finest grid's box diagonal on every level
            self.serial._has_medium = True
            self._gx = _vec3(self.serial.shape, device)
            self._gb = _vec3(self.serial.shape, device)
        self._aa = None

    @property
    def distributed_levels(self) -> int:
        """Levels iterated on the blocks (the gathered level's coefficients and right-hand
        sides are computed there too)."""
        return self.count if self.gathered is None else self.gathered

    @property
    def gathered_shape(self):
        return None if self.gathered is None else self.levels[self.gathered].shape

    # --- moving fields between layouts -------------------------------------------------------
    def load(self, src: wp.array, src_layout: Layout, dst: wp.array | None = None) -> wp.array:
        """The block of ghosted array ``src`` (of ``src_layout``, the same blocks) on this
        solver's finest ghosted box, its ghosts exchanged."""
        top = self.levels[0]
        if dst is None:
            dst = wp.zeros(top.layout.local_shape, dtype=src.dtype, device=self.device)
        if not top.layout.empty:
            write_region(dst, top.layout.block_region(),
                         read_region(src, src_layout.block_region()))
        self._exchange(0, dst)
        return dst

    def store(self, src: wp.array, dst: wp.array, dst_layout: Layout) -> None:
        """Write this solver's finest block of ``src`` into ``dst`` (of ``dst_layout``)."""
        top = self.levels[0]
        if not top.layout.empty:
            write_region(dst, dst_layout.block_region(),
                         read_region(src, top.layout.block_region()))

    def _gather(self, level: _Level, *arrays) -> list | None:
        """Rank 0: the whole grid of each of ``arrays`` (level's ghosted arrays) from every
        rank's block, one ``gather`` for all; other ranks: None."""
        lay = level.layout
        parts = self.comm.gather([read_region(a, lay.block_region()) if not lay.empty else None
                                  for a in arrays], root=0)
        if self.comm.Get_rank() != 0:
            return None
        out = []
        for n, arr in enumerate(arrays):
            comps = (3,) if arr.dtype == wp.vec3 else ()
            whole = np.zeros(level.shape + comps, dtype=np.float32)
            for (lo, hi), p in zip(lay.blocks, parts):
                if p[n] is not None:
                    whole[region(lo, hi, (0, 0, 0))] = p[n]
            out.append(whole)
        return out

    def _scatter(self, level: _Level, whole, arr) -> None:
        lay = level.layout
        pieces = None
        if self.comm.Get_rank() == 0:
            pieces = [whole[region(lo, hi, (0, 0, 0))] if np.all(hi > lo) else None
                      for lo, hi in lay.blocks]
        mine = self.comm.scatter(pieces, root=0)
        if mine is not None:
            write_region(arr, lay.block_region(), mine)

    def _exchange(self, index: int, *arrays) -> None:
        """Fill the ghosts of ``arrays`` (level ``index``'s ghosted arrays) from their
        owners: every array's messages posted at once, one wait (a round of latency, not
        one per array)."""
        halo = self.levels[index].halo
        if not halo.sends and not halo.recvs:
            return
        MPI = mpi()
        requests, received, outgoing = [], [], []
        for n, arr in enumerate(arrays):
            tag = HALO_TAG + 16 * index + n
            comps = (3,) if arr.dtype == wp.vec3 else ()
            for q, sl in halo.recvs:
                buf = np.empty(tuple(v.stop - v.start for v in sl) + comps, dtype=np.float32)
                requests.append(self.comm.Irecv(buf, source=q, tag=tag))
                received.append((arr, sl, buf))
            for q, sl in halo.sends:
                buf = read_region(arr, sl)
                outgoing.append(buf)
                requests.append(self.comm.Isend(buf, dest=q, tag=tag))
        MPI.Request.Waitall(requests)
        for arr, sl, buf in received:
            write_region(arr, sl, buf)

    # --- medium and coefficients -------------------------------------------------------------
    def set_medium(self, sigma: wp.array3d, color_sigma: wp.array3d, albedo: float,
                   anisotropy: float) -> None:
        """``sigma_a``, ``sigma_tr`` on every level from the finest block's ``sigma`` and
        ``color_sigma`` (ghosted arrays of this solver's finest layout, ghosts exchanged:
        :meth:`load`); collective."""
        top = self.levels[0]
        wp.launch(medium_kernel, dim=top.layout.local_shape, device=self.device,
                  inputs=[sigma, color_sigma, float(albedo), float(anisotropy), top.sigma_a,
                          top.sigma_tr, top.absorb])
        wp.launch(counted_kernel, dim=top.layout.local_shape, device=self.device,
                  inputs=[top.sigma_tr, self.min_sigma, self._counted])
        for index in range(1, len(self.levels)):
            for name in ("sigma_a", "sigma_tr"):
                self._restrict(index, getattr(self.levels[index - 1], name),
                               getattr(self.levels[index], name))
        if self.gathered is not None:
            g = self.levels[self.gathered]
            wholes = self._gather(g, g.sigma_a, g.sigma_tr)
            if self.serial is not None:
                s = self.serial.levels
                s[0].sigma_a.assign(wholes[0])
                s[0].sigma_tr.assign(wholes[1])
                for fine, coarse in itertools.pairwise(s):
                    ratio = self.serial._ratio(fine, coarse)
                    for a, b in ((fine.sigma_a, coarse.sigma_a), (fine.sigma_tr, coarse.sigma_tr)):
                        wp.launch(restrict_kernel, dim=coarse.shape, device=self.device,
                                  inputs=[a, b, ratio])

    def _restrict(self, index: int, fine_arr, coarse_arr) -> None:
        """``coarse_arr`` (level ``index``) = mean of ``fine_arr``'s children (level
        ``index - 1``), the fine halo exchanged first, the coarse one after."""
        fine, coarse = self.levels[index - 1], self.levels[index]
        self._exchange(index - 1, fine_arr)
        if not coarse.layout.empty:
            wp.launch(block_restrict_kernel, dim=coarse.layout.block_shape, device=self.device,
                      inputs=[fine_arr, coarse_arr, self.ratios[index - 1], fine.off, coarse.off,
                              coarse.blo, fine.n])
        self._exchange(index, coarse_arr)

    def update_coefficients(self, x: wp.array3d, start: int = 0) -> None:
        """Lagged face coefficients and leakage of level ``start`` from ``x`` (its ghosted
        array), homogenized down to the gathered level, whose coefficients go to rank 0
        (homogenized further there); collective."""
        lv = self.levels[start]
        limiter = LIMITERS[self.limiter]
        self._exchange(start, x)
        if not lv.layout.empty:
            local = lv.layout.local_shape
            for axis, (kernel, k) in enumerate(zip(FACE_KERNELS, (lv.kx, lv.ky, lv.kz))):
                dim = tuple(n - 1 if a == axis else n for a, n in enumerate(local))
                if min(dim) > 0:
                    wp.launch(kernel, dim=dim, device=self.device,
                              inputs=[x, lv.sigma_tr, k, lv.inv_h, self.d_max, limiter])
            wp.launch(rad_leakage_kernel, dim=lv.layout.block_shape, device=self.device,
                      inputs=[x, lv.sigma_tr, lv.sigma_a, lv.absorb, lv.h, self.d_max, limiter,
                              lv.off, lv.blo, lv.n])
        self._exchange(start, *lv.coefficients)
        for index in range(start + 1, len(self.levels)):
            fine, coarse = self.levels[index - 1], self.levels[index]
            if not coarse.layout.empty:
                wp.launch(rad_coarse_coefficients_kernel, dim=(4, *coarse.layout.block_shape),
                          device=self.device,
                          inputs=[*fine.coefficients, *coarse.coefficients,
                                  self.ratios[index - 1], fine.off, coarse.off, coarse.blo,
                                  fine.n, coarse.n])
            self._exchange(index, *coarse.coefficients)
        if self.gathered is not None:
            g = self.levels[self.gathered]
            wholes = self._gather(g, *g.coefficients)
            if self.serial is not None:
                s = self.serial.levels
                s[0].kx.assign(wholes[0][:-1])
                s[0].ky.assign(wholes[1][:, :-1])
                s[0].kz.assign(wholes[2][:, :, :-1])
                s[0].absorb.assign(wholes[3])
                for fine, coarse in itertools.pairwise(s):
                    coarse_coefficients(fine, coarse, self.serial._ratio(fine, coarse),
                                        self.device)

    # --- multigrid ---------------------------------------------------------------------------
    def _smooth(self, index: int, x, b, sweeps: int, reverse: bool = False) -> None:
        lv = self.levels[index]
        colors = (1, 0) if reverse else (0, 1)
        for _ in range(int(sweeps)):
            for color in colors:
                self._exchange(index, x)
                if not lv.layout.empty:
                    wp.launch(rad_red_black_kernel, dim=lv.layout.block_shape,
                              device=self.device,
                              inputs=[x, b, *lv.coefficients, color, lv.off, lv.blo])

    def vcycle(self, x: wp.array3d, b: wp.array3d, index: int = 0) -> None:
        """One V(2,2) cycle on level ``index`` for the current coefficients; collective."""
        if index == self.gathered:
            self._gathered_vcycle(x, b)
            return
        if index == self.count - 1:  # a finest grid too small to coarsen: the coarse sweeps
            self._smooth(index, x, b, COARSE_SWEEPS)
            return
        lv, coarse = self.levels[index], self.levels[index + 1]
        self._smooth(index, x, b, PRE_SMOOTH)
        self._exchange(index, x)
        if not lv.layout.empty:
            wp.launch(rad_residual_kernel, dim=lv.layout.block_shape, device=self.device,
                      inputs=[x, b, lv.r, *lv.coefficients, lv.off, lv.blo])
        self._restrict(index + 1, lv.r, coarse.b)
        coarse.x.zero_()
        self.vcycle(coarse.x, coarse.b, index + 1)
        self._exchange(index + 1, coarse.x)
        if not lv.layout.empty:
            wp.launch(block_prolong_add_kernel, dim=lv.layout.block_shape, device=self.device,
                      inputs=[coarse.x, x, self.ratios[index], lv.off, coarse.off, lv.blo,
                              coarse.n])
        self._smooth(index, x, b, POST_SMOOTH, reverse=True)

    def _gathered_vcycle(self, x, b) -> None:
        """The gathered level's V-cycle on rank 0 (the one-rank code from zero), the
        result scattered into the blocks of ``x``."""
        g = self.levels[self.gathered]
        whole = self._gather(g, b)
        xs = None
        if self.serial is not None:
            self._gb.assign(whole[0])
            self._gx.zero_()
            self.serial.vcycle(self._gx, self._gb, 0)
            xs = self._gx.numpy()
        self._scatter(g, xs, x)

    def _nested_start(self, q: wp.array3d, x: wp.array3d) -> None:
        """Nested iteration from ``x`` (the one-rank ``_nested_start`` from the coarsest
        grid): restrictions on the blocks, the gathered levels on rank 0, the distributed
        levels iterated fine-ward; collective."""
        levels, gi = self.levels, self.gathered
        for index in range(1, gi + 1):
            levels[index].nested_arrays(self.device)
            src_q, src_x = (q, x) if index == 1 else (levels[index - 1].q,
                                                      levels[index - 1].estimate)
            self._restrict(index, src_q, levels[index].q)
            self._restrict(index, src_x, levels[index].estimate)
        g = levels[gi]
        wholes = self._gather(g, g.q, g.estimate)
        change = None
        if self.serial is not None:
            s = self.serial
            wq, we = wholes
            sq = wp.array(wq, dtype=wp.vec3, device=self.device)
            sol = wp.array(we, dtype=wp.vec3, device=self.device)
            if len(s.levels) > 1:
                s._nested_start(sq, sol)
            iterations = COARSEST_ITERATIONS if gi == self.count - 1 else NESTED_ITERATIONS
            for _ in range(iterations):
                s.update_coefficients(sol, 0)
                s.vcycle(sol, sq, 0)
            change = sol.numpy() - we
        self._scatter(g, change, g.x)
        for index in range(gi, 0, -1):
            lv, fine = levels[index], levels[index - 1]
            if index < gi:
                for _ in range(NESTED_ITERATIONS):
                    self.update_coefficients(lv.sol, index)
                    self.vcycle(lv.sol, lv.q, index)
                if not lv.layout.empty:
                    wp.launch(rad_difference_kernel, dim=lv.layout.local_shape,
                              device=self.device, inputs=[lv.sol, lv.estimate, lv.x])
            target = x
            if index > 1:
                target = fine.sol
                wp.copy(target, fine.estimate)
            self._exchange(index, lv.x)
            if not fine.layout.empty:
                wp.launch(block_prolong_add_kernel, dim=fine.layout.block_shape,
                          device=self.device,
                          inputs=[lv.x, target, self.ratios[index - 1], fine.off, lv.off,
                                  fine.blo, lv.n])

    # --- norms ---------------------------------------------------------------------------------
    def _reduce(self) -> list:
        local = self._acc.numpy().astype(np.float64)
        total = np.empty_like(local)
        self.comm.Allreduce(local, total, op=mpi().SUM)
        return total.tolist()

    def residual(self, x, rhs) -> tuple[float, float]:
        """The one-rank relative correction (``RadiativeDiffusion.residual``), its sums
        over the blocks in float64, reduced over the ranks; and its float32 floor."""
        top = self.levels[0]
        self._exchange(0, x)
        self._acc.zero_()
        if not top.layout.empty:
            wp.launch(rad_residual_norm_kernel, dim=top.layout.block_shape, device=self.device,
                      inputs=[x, rhs, *top.coefficients, self._counted, self._acc, top.off,
                              top.blo])
        sums = self._reduce()
        floor = 4.0 * FLOAT32_EPS
        if not all(math.isfinite(v) for v in sums):
            return float("inf"), floor
        n = [math.sqrt(v) for v in sums]
        rel = 0.0
        for c in range(3):
            if n[c] > 0.0:
                rel = max(rel, 1.0 if n[3 + c] == 0.0 else n[c] / max(n[3 + c], 1e-300))
        return rel, floor

    def _displaced(self, q, displacement, rhs) -> None:
        """``rhs = Q - div p``, its negative parts clipped and the rest rescaled to the
        global total per channel (the one-rank ``displaced_source_kernel`` and
        ``clip_rescale_kernel``)."""
        top = self.levels[0]
        self._exchange(0, *displacement)
        self._acc.zero_()
        if not top.layout.empty:
            wp.launch(rad_displaced_source_kernel, dim=top.layout.block_shape,
                      device=self.device,
                      inputs=[q, *displacement, top.h, rhs, top.off, top.blo, top.n, self._acc])
        self._sums.assign(np.asarray(self._reduce(), dtype=np.float64))
        wp.launch(clip_rescale_kernel, dim=top.layout.local_shape, device=self.device,
                  inputs=[rhs, self._sums])

    # --- the solve ----------------------------------------------------------------------------
    def solve(self, q: wp.array3d, x: wp.array3d, max_iterations: int = 100,
              tolerance: float = 1e-4, method: str = "multigrid", displacement=None,
              cold: bool = True) -> DiffusionReport:
        """Improve ``x`` in place (ghosted arrays of this solver's finest layout: :meth:`load`)
        as ``RadiativeDiffusion.solve``; collective, every rank returns the same report."""
        if method not in ("multigrid", "gauss-seidel"):
            raise ValueError(f"the physical diffusion model is solved with 'multigrid' or "
                             f"'gauss-seidel', not {method!r}")
        report = DiffusionReport()
        self.update_coefficients(x)
        rhs = q
        if displacement is not None:
            rhs = wp.zeros_like(q)
            self._displaced(q, displacement, rhs)
        res, floor = self.residual(x, rhs)
        report.residuals.append(res)
        if res <= max(tolerance, floor):
            report.converged = True
            return report
        if cold and method == "multigrid" and self.count > 1:
            report.nested = True
            self._nested_start(rhs, x)
            self.update_coefficients(x)
            res, floor = self.residual(x, rhs)
        best_res = res if np.isfinite(res) else np.inf
        best = wp.empty_like(x) if method == "multigrid" else None
        save_best = best is not None
        smoothing_only = method != "multigrid"
        aa = self._anderson_start(x) if self.anderson and not smoothing_only else None
        for _ in range(int(max_iterations)):
            if save_best and not smoothing_only:
                wp.copy(best, x)
            if aa is not None and not smoothing_only:
                self._anderson_iteration(x, rhs, aa)
            else:
                if smoothing_only:
                    self._smooth(0, x, rhs, 1)
                else:
                    self.vcycle(x, rhs)
                self.update_coefficients(x)
            save_best = False
            res, floor = self.residual(x, rhs)
            report.iterations += 1
            if best is not None and not smoothing_only:
                if not np.isfinite(res) or res > 10.0 * best_res:
                    wp.copy(x, best)
                    self.update_coefficients(x)
                    res, floor = self.residual(x, rhs)
                    smoothing_only = True
                    report.fallback = True
                elif res < best_res:
                    best_res = res
                    save_best = True
            report.residuals.append(res)
            if res <= max(tolerance, floor):
                report.converged = True
                break
            if not smoothing_only and stalled(report.residuals):
                report.stalled = True
                break
        return report

    def _anderson_start(self, x) -> dict:
        if self._aa is None:
            def field():
                return wp.zeros(x.shape, dtype=wp.vec3, device=self.device)

            def f64(*shape):
                return wp.zeros(shape, dtype=wp.float64, device=self.device)

            self._aa = {"G": [field() for _ in range(ANDERSON_SLOTS)],
                        "F": [field() for _ in range(ANDERSON_SLOTS)],
                        "dots": f64(ANDERSON_SLOTS),
                        "alpha": wp.zeros(ANDERSON_SLOTS, dtype=wp.float32, device=self.device),
                        "gram": f64(ANDERSON_SLOTS, ANDERSON_SLOTS),
                        "valid": wp.zeros(ANDERSON_SLOTS, dtype=wp.int32, device=self.device),
                        "work": f64(ANDERSON_SLOTS + 1, ANDERSON_SLOTS + 1)}
        self._aa["gram"].zero_()
        self._aa["valid"].zero_()
        self._aa["k"] = 0
        return self._aa

    def _anderson_iteration(self, x, rhs, aa) -> None:
        """The one-rank ``_anderson_iteration``: ``G(x)`` by a V-cycle, ``F = G(x) - x`` on
        the block, the Gram row ``<F_slot, F_j>`` summed on the blocks and reduced, the
        weights solved on every rank from the same sums, ``x = sum_j alpha_j G_j``."""
        top = self.levels[0]
        slot = aa["k"] % ANDERSON_SLOTS
        aa["k"] += 1
        G, F = aa["G"], aa["F"]
        wp.copy(G[slot], x)
        self.vcycle(G[slot], rhs)
        self._acc.zero_()
        if not top.layout.empty:
            wp.launch(rad_anderson_dots_kernel, dim=top.layout.block_shape, device=self.device,
                      inputs=[G[slot], x, F[slot], *F, self._acc, top.off, top.blo])
        aa["dots"].assign(np.asarray(self._reduce()[:ANDERSON_SLOTS], dtype=np.float64))
        wp.launch(anderson_weights_kernel, dim=1, device=self.device,
                  inputs=[aa["dots"], aa["gram"], aa["valid"], slot, ANDERSON_MAX_WEIGHT,
                          aa["alpha"], aa["work"]])
        wp.launch(anderson_mix_kernel, dim=x.shape, device=self.device,
                  inputs=[*G, aa["alpha"], x])
        self.update_coefficients(x)


# --- kernels at global indices on ghosted blocks -------------------------------------------------
@wp.kernel
def rad_red_black_kernel(x: wp.array3d(dtype=wp.vec3), b: wp.array3d(dtype=wp.vec3),
                         kx: wp.array3d(dtype=wp.vec3), ky: wp.array3d(dtype=wp.vec3),
                         kz: wp.array3d(dtype=wp.vec3), absorb: wp.array3d(dtype=wp.vec3),
                         color: int, off: wp.vec3i, blo: wp.vec3i):
    """``radiative.red_black_kernel`` at block point ``wp.tid() + blo`` (global parity;
    the one-rank ``gauss_seidel_point`` on the ghosted arrays, whose bounds are the grid's
    at owned points)."""
    ti, tj, tk = wp.tid()
    gi = ti + blo[0]
    gj = tj + blo[1]
    gk = tk + blo[2]
    if (gi + gj + gk) % 2 != color:
        return
    gauss_seidel_point(x, b, kx, ky, kz, absorb, gi - off[0], gj - off[1], gk - off[2])


@wp.kernel
def rad_residual_kernel(x: wp.array3d(dtype=wp.vec3), b: wp.array3d(dtype=wp.vec3),
                        r: wp.array3d(dtype=wp.vec3), kx: wp.array3d(dtype=wp.vec3),
                        ky: wp.array3d(dtype=wp.vec3), kz: wp.array3d(dtype=wp.vec3),
                        absorb: wp.array3d(dtype=wp.vec3), off: wp.vec3i, blo: wp.vec3i):
    """``r = b - A x`` at block point ``wp.tid() + blo``."""
    ti, tj, tk = wp.tid()
    i = ti + blo[0] - off[0]
    j = tj + blo[1] - off[1]
    k = tk + blo[2] - off[2]
    o, diag = neighbours(x, i, j, k, kx, ky, kz)
    diag += absorb[i, j, k]
    r[i, j, k] = b[i, j, k] - wp.cw_mul(diag, x[i, j, k]) + o


@wp.kernel
def rad_residual_norm_kernel(x: wp.array3d(dtype=wp.vec3), b: wp.array3d(dtype=wp.vec3),
                             kx: wp.array3d(dtype=wp.vec3), ky: wp.array3d(dtype=wp.vec3),
                             kz: wp.array3d(dtype=wp.vec3), absorb: wp.array3d(dtype=wp.vec3),
                             counted: wp.array3d(dtype=wp.uint8),
                             acc: wp.array(dtype=wp.float64), off: wp.vec3i, blo: wp.vec3i):
    """``radiative.residual_norm_kernel``'s sums at block point ``wp.tid() + blo``
    (``acc[0:3]``: ``|r / diag|^2``, ``acc[3:6]``: ``max(|x|, |b| / diag)^2``), per cell
    in float64."""
    ti, tj, tk = wp.tid()
    i = ti + blo[0] - off[0]
    j = tj + blo[1] - off[1]
    k = tk + blo[2] - off[2]
    if counted[i, j, k] == wp.uint8(0):
        return
    o, diag = neighbours(x, i, j, k, kx, ky, kz)
    diag += absorb[i, j, k]
    xi = x[i, j, k]
    r = b[i, j, k] - wp.cw_mul(diag, xi) + o
    for c in range(3):
        if diag[c] > 0.0:
            e = r[c] / diag[c]
            v = wp.max(wp.abs(xi[c]), wp.abs(b[i, j, k][c]) / diag[c])
            wp.atomic_add(acc, c, wp.float64(e * e))
            wp.atomic_add(acc, 3 + c, wp.float64(v * v))


@wp.kernel
def rad_leakage_kernel(phi: wp.array3d(dtype=wp.vec3), sigma_tr: wp.array3d(dtype=wp.vec3),
                       sigma_a: wp.array3d(dtype=wp.vec3), absorb: wp.array3d(dtype=wp.vec3),
                       h: wp.vec3, d_max: float, limiter: int, off: wp.vec3i, blo: wp.vec3i,
                       n: wp.vec3i):
    """``radiative.leakage_kernel`` at block point ``wp.tid() + blo`` if it lies on the
    grid's box faces (``leak_at``'s arithmetic with the global faces)."""
    ti, tj, tk = wp.tid()
    g = wp.vec3i(ti + blo[0], tj + blo[1], tk + blo[2])
    on_box = False
    for a in range(3):
        if g[a] == 0 or g[a] == n[a] - 1:
            on_box = True
    if not on_box:
        return
    p = g - off
    d = limited_vec(sigma_tr[p[0], p[1], p[2]], gradient_sq(phi, p, h), phi[p[0], p[1], p[2]],
                    d_max, limiter)
    out = wp.vec3(0.0)
    for a in range(3):
        faces = float(0.0)  # noqa: UP018 (a warp variable)
        if g[a] == 0:
            faces += 1.0
        if g[a] == n[a] - 1:
            faces += 1.0
        if faces > 0.0:
            ha = h[a]
            out += faces * wp.vec3(2.0 * d[0] / ((4.0 * d[0] + ha) * ha),
                                   2.0 * d[1] / ((4.0 * d[1] + ha) * ha),
                                   2.0 * d[2] / ((4.0 * d[2] + ha) * ha))
    absorb[p[0], p[1], p[2]] = sigma_a[p[0], p[1], p[2]] + out


@wp.kernel
def rad_coarse_coefficients_kernel(kx: wp.array3d(dtype=wp.vec3), ky: wp.array3d(dtype=wp.vec3),
                                   kz: wp.array3d(dtype=wp.vec3),
                                   absorb: wp.array3d(dtype=wp.vec3),
                                   ckx: wp.array3d(dtype=wp.vec3), cky: wp.array3d(dtype=wp.vec3),
                                   ckz: wp.array3d(dtype=wp.vec3),
                                   cabsorb: wp.array3d(dtype=wp.vec3), ratio: wp.vec3i,
                                   off_f: wp.vec3i, off_c: wp.vec3i, blo_c: wp.vec3i,
                                   nf: wp.vec3i, nc: wp.vec3i):
    """``coarsening.coarse_coefficients_kernel`` at coarse block cell ``wp.tid()[1:] +
    blo_c`` (global indices; fine arrays read at ``- off_f``, coarse written at
    ``- off_c``)."""
    what, ti, tj, tk = wp.tid()
    ci = ti + blo_c[0]
    cj = tj + blo_c[1]
    ck = tk + blo_c[2]
    c = wp.vec3i(ci, cj, ck)
    lc = c - off_c
    if what == 3:
        s = wp.vec3(0.0)
        count = float(0.0)  # noqa: UP018 (a warp variable)
        for child in range(8):
            i, j, k, ok = child_of(ci, cj, ck, ratio, child, nf)
            if ok:
                s += absorb[i - off_f[0], j - off_f[1], k - off_f[2]]
                count += 1.0
        cabsorb[lc[0], lc[1], lc[2]] = s / count
        return
    a = what
    ca = component(c, a)
    if ca >= component(nc, a) - 1:
        return
    ra = component(ratio, a)
    nfa = component(nf, a)
    last = ca * ra + ra - 1
    e = axis_offset(a, 1)
    g = wp.vec3(0.0)
    channels = float(0.0)  # noqa: UP018 (a warp variable)
    for child in range(8):
        i, j, k, ok = child_of(ci, cj, ck, ratio, child, nf)
        p = wp.vec3i(i, j, k)
        pa = component(p, a)
        if ok and pa == last:
            pl = p - off_f
            r = resistance(face_k(kx, ky, kz, a, pl), 1.0)
            if ra > 1:
                r += resistance(face_k(kx, ky, kz, a, pl - e), 0.5)
                if pa + 2 < nfa:
                    r += resistance(face_k(kx, ky, kz, a, pl + e), 0.5)
            g += wp.vec3(1.0 / r[0], 1.0 / r[1], 1.0 / r[2])
            channels += 1.0
    set_face_k(ckx, cky, ckz, a, lc, g / (channels * float(ra)))


@wp.kernel
def rad_displaced_source_kernel(q: wp.array3d(dtype=wp.vec3), px: wp.array3d(dtype=wp.vec3),
                                py: wp.array3d(dtype=wp.vec3), pz: wp.array3d(dtype=wp.vec3),
                                h: wp.vec3, rhs: wp.array3d(dtype=wp.vec3), off: wp.vec3i,
                                blo: wp.vec3i, n: wp.vec3i, acc: wp.array(dtype=wp.float64)):
    """``radiative.displaced_source_kernel`` at block point ``wp.tid() + blo`` (the
    global box faces), and its per-channel ``sum`` and ``sum max(., 0)`` into ``acc``
    (``channel_sums_kernel`` with ``squares`` 0) in float64."""
    ti, tj, tk = wp.tid()
    gi = ti + blo[0]
    gj = tj + blo[1]
    gk = tk + blo[2]
    i = gi - off[0]
    j = gj - off[1]
    k = gk - off[2]
    out = q[i, j, k]
    if gi < n[0] - 1:
        out -= 0.5 * (px[i, j, k] + px[i + 1, j, k]) / h[0]
    if gi > 0:
        out += 0.5 * (px[i, j, k] + px[i - 1, j, k]) / h[0]
    if gj < n[1] - 1:
        out -= 0.5 * (py[i, j, k] + py[i, j + 1, k]) / h[1]
    if gj > 0:
        out += 0.5 * (py[i, j, k] + py[i, j - 1, k]) / h[1]
    if gk < n[2] - 1:
        out -= 0.5 * (pz[i, j, k] + pz[i, j, k + 1]) / h[2]
    if gk > 0:
        out += 0.5 * (pz[i, j, k] + pz[i, j, k - 1]) / h[2]
    rhs[i, j, k] = out
    for c in range(3):
        wp.atomic_add(acc, c, wp.float64(out[c]))
        wp.atomic_add(acc, 3 + c, wp.float64(wp.max(out[c], 0.0)))


@wp.kernel
def rad_anderson_dots_kernel(g: wp.array3d(dtype=wp.vec3), x: wp.array3d(dtype=wp.vec3),
                             f: wp.array3d(dtype=wp.vec3), f0: wp.array3d(dtype=wp.vec3),
                             f1: wp.array3d(dtype=wp.vec3), f2: wp.array3d(dtype=wp.vec3),
                             f3: wp.array3d(dtype=wp.vec3), acc: wp.array(dtype=wp.float64),
                             off: wp.vec3i, blo: wp.vec3i):
    """``radiative.anderson_dots_kernel`` at block point ``wp.tid() + blo``: ``f = g - x``
    and ``acc[j] += <f, f_j>`` (float64 per cell)."""
    ti, tj, tk = wp.tid()
    i = ti + blo[0] - off[0]
    j = tj + blo[1] - off[1]
    k = tk + blo[2] - off[2]
    v = g[i, j, k] - x[i, j, k]
    f[i, j, k] = v  # before the reads below: f is also one of f0 .. f3
    wp.atomic_add(acc, 0, wp.float64(wp.dot(v, f0[i, j, k])))
    wp.atomic_add(acc, 1, wp.float64(wp.dot(v, f1[i, j, k])))
    wp.atomic_add(acc, 2, wp.float64(wp.dot(v, f2[i, j, k])))
    wp.atomic_add(acc, 3, wp.float64(wp.dot(v, f3[i, j, k])))


@wp.kernel
def rad_difference_kernel(a: wp.array3d(dtype=wp.vec3), b: wp.array3d(dtype=wp.vec3),
                          out: wp.array3d(dtype=wp.vec3)):
    i, j, k = wp.tid()
    out[i, j, k] = a[i, j, k] - b[i, j, k]
