"""The paper's diffusion ``(I - sigma_hat_s laplace) x = b`` (eq. 23) solved by multigrid
across MPI ranks, with halo exchange (issue 36).

The same V(2,2) cycle as the one-rank
:class:`~vtkillum.core.convection_diffusion.multigrid.Multigrid`, level for level:

* the same hierarchy: a coarse cell ``I`` has the fine children ``2 I`` and ``2 I + 1``
  along each halved axis; it belongs to the rank that owns child ``2 I``, so a block
  ``[lo, hi)`` coarsens to ``[ceil(lo / 2), ceil(hi / 2))`` (possibly empty) and the
  coarse grids and spacings are the one-rank ones;
* red–black Gauss–Seidel with the colour of the *global* index parity and a one-layer
  halo exchange before each colour: a colour's points read only the other colour, so the
  sweep gives the one-rank values whatever the block boundaries;
* the residual on the block, its halo exchanged (a coarse cell's child ``2 I + 1`` may
  sit on the next rank), then the mean over the children; trilinear prolongation of the
  coarse correction with the coarse level's halo;
* once a level has at most ``gather_cells`` cells (:data:`GATHER_CELLS`), or cannot be
  halved further, it is gathered onto rank 0, which runs the one-rank
  :class:`~vtkillum.core.convection_diffusion.multigrid.Multigrid` V-cycle from that level
  down (its hierarchy from there is the same) and scatters the correction back. Small
  levels cost latency, not work: one gather and one scatter replace the halo exchanges of
  all coarser levels.

Convergence is measured as :meth:`DiffusionSolver.solve` does (``max_c ||b - A x||_c /
||b||_c``, float64 sums reduced over the ranks), with its float32 floor. In exact
arithmetic the iterates are the one-rank ones; in float32 they differ only by the order of
the residual's sums, so a solve can stop one V-cycle earlier or later than one rank's.
"""

from __future__ import annotations

import numpy as np
import warp as wp

from vtkillum.core.convection_diffusion.diffusion import DiffusionReport, residual_floor
from vtkillum.core.convection_diffusion.distributed_layout import (
    Halo,
    Layout,
    mpi,
    read_region,
    region,
    write_region,
)
from vtkillum.core.convection_diffusion.multigrid import (
    COARSEST_POINTS,
    POST_SMOOTH,
    PRE_SMOOTH,
    Multigrid,
    coarse_coordinate,
)
from vtkillum.core.convection_diffusion.stencil import axis_coefficients

#: Levels with at most this many cells are gathered onto rank 0 (a 16³ grid).
GATHER_CELLS = 4096
#: MPI tags of the multigrid's halo exchanges.
HALO_TAG = 2000


class DistributedMultigrid:
    """The distributed V-cycle on the light-grid blocks of ``layout``.

    Parameters
    ----------
    comm : mpi4py communicator
    layout : Layout
        The finest level's blocks (the light grid's).
    spacing : (3,) float
        Finest spacing (world units).
    scattering : (3,) float
        ``sigma_hat_s`` per RGB channel (world units²).
    device : str
        This rank's warp device.
    gather_cells : int
        Levels of at most this many cells go to rank 0 (the finest level never does).
    """

    def __init__(self, comm, layout: Layout, spacing, scattering, device: str,
                 gather_cells: int = GATHER_CELLS) -> None:
        self.comm = comm
        self.device = device
        self.scattering = np.asarray(scattering, dtype=np.float64)
        self.layouts = [layout]
        self.spacings = [np.asarray(spacing, dtype=np.float64)]
        self.ratios = []
        gathered = None
        while True:
            n = self.layouts[-1].shape
            halve = n >= 4
            if int(np.prod(n)) <= COARSEST_POINTS or not halve.any():
                gathered = len(self.layouts) - 1 if len(self.layouts) > 1 else None
                break
            if len(self.layouts) > 1 and int(np.prod(n)) <= gather_cells:
                gathered = len(self.layouts) - 1
                break
            nc = np.where(halve, (n + 1) // 2, n)
            blocks = [(np.where(halve, (lo + 1) // 2, lo), np.where(halve, (hi + 1) // 2, hi))
                      for lo, hi in self.layouts[-1].blocks]
            self.layouts.append(Layout(nc, blocks, layout.rank,
                                       [coarse_ghost(lo, hi, halve, nc)
                                        for lo, hi in self.layouts[-1].blocks]))
            self.spacings.append(self.spacings[-1] * n / nc)
            self.ratios.append(wp.vec3i(*(halve.astype(int) + 1)))
        # levels [0, gathered) are distributed; `gathered` (or, for a fine grid that cannot
        # be coarsened, none) runs on rank 0
        self.gathered = gathered
        self.distributed_levels = len(self.layouts) if gathered is None else gathered
        self.gathered_shape = (tuple(int(v) for v in self.layouts[gathered].shape)
                               if gathered is not None else None)
        self.halos = [Halo(comm, lay) for lay in self.layouts]
        self.coeffs = [axis_coefficients(self.scattering, h) for h in self.spacings]
        shapes = [lay.local_shape for lay in self.layouts]
        self.x = [None] + [wp.zeros(s, dtype=wp.vec3, device=device) for s in shapes[1:]]
        self.b = [None] + [wp.zeros(s, dtype=wp.vec3, device=device) for s in shapes[1:]]
        self.r = [wp.zeros(s, dtype=wp.vec3, device=device) for s in shapes]
        self._acc = wp.zeros(3, dtype=wp.float64, device=device)
        self._serial = None
        if gathered is not None and comm.Get_rank() == 0:
            self._serial = Multigrid(self.gathered_shape, self.spacings[gathered],
                                     self.scattering, device)
        if gathered is None:  # a fine grid too small to coarsen: Gauss–Seidel sweeps only
            self.distributed_levels = 1
        #: Relative residual below which float32 round-off dominates.
        self.floor = residual_floor(self.scattering, self.spacings[0])

    # --- public ----------------------------------------------------------------------------
    def solve(self, b: wp.array3d, x: wp.array3d, max_iterations: int = 100,
              tolerance: float = 1e-4) -> DiffusionReport:
        """Improve ``x`` (this rank's ghosted array) in place towards ``A x = b``; collective."""
        tolerance = max(float(tolerance), self.floor)
        report = DiffusionReport()
        b_norm = np.sqrt(self._sum_squares(b))
        report.residuals.append(self.residual(x, b, b_norm))
        if not np.any(self.scattering > 0):
            wp.copy(x, b)
            report.residuals.append(0.0)
            report.iterations, report.converged = 1, True
            return report
        if report.residuals[-1] <= tolerance:
            report.converged = True
            return report
        for _ in range(int(max_iterations)):
            self.vcycle(x, b)
            report.iterations += 1
            report.residuals.append(self.residual(x, b, b_norm))
            if report.residuals[-1] <= tolerance:
                break
        report.converged = report.residuals[-1] <= tolerance
        return report

    def residual(self, x, b, b_norm) -> float:
        """``max_c ||b - A x||_c / ||b||_c`` over the whole grid."""
        lay = self.layouts[0]
        self.halos[0].exchange(x, HALO_TAG)
        self._acc.zero_()
        if not lay.empty:
            wp.launch(block_residual_norm_kernel, dim=lay.block_shape, device=self.device,
                      inputs=[x, b, *self.coeffs[0], *self._geometry(0), self._acc])
        r = np.sqrt(self._reduce())
        return float(np.max(np.where(b_norm > 0, r / np.maximum(b_norm, 1e-300), 0.0)))

    def vcycle(self, x: wp.array3d, b: wp.array3d, level: int = 0) -> None:
        """One V(2,2) cycle on ``level`` (0 = finest), in place; collective."""
        if level == self.gathered:
            self._gathered_solve(x, b, level)
            return
        lay = self.layouts[level]
        self._smooth(x, b, level, PRE_SMOOTH, reverse=False)
        if level + 1 == len(self.layouts):  # the finest grid could not be coarsened
            return
        r = self.r[level]
        self.halos[level].exchange(x, HALO_TAG + level)
        if not lay.empty:
            wp.launch(block_residual_kernel, dim=lay.block_shape, device=self.device,
                      inputs=[x, b, r, *self.coeffs[level], *self._geometry(level)])
        self.halos[level].exchange(r, HALO_TAG + level)
        coarse = self.layouts[level + 1]
        xc, bc = self.x[level + 1], self.b[level + 1]
        if not coarse.empty:
            wp.launch(block_restrict_kernel, dim=coarse.block_shape, device=self.device,
                      inputs=[r, bc, self.ratios[level], wp.vec3i(*lay.ghost()[0]),
                              wp.vec3i(*coarse.ghost()[0]), wp.vec3i(*coarse.lo),
                              wp.vec3i(*lay.shape)])
        xc.zero_()
        self.vcycle(xc, bc, level + 1)
        self.halos[level + 1].exchange(xc, HALO_TAG + level + 1)
        if not lay.empty:
            wp.launch(block_prolong_add_kernel, dim=lay.block_shape, device=self.device,
                      inputs=[xc, x, self.ratios[level], wp.vec3i(*lay.ghost()[0]),
                              wp.vec3i(*coarse.ghost()[0]), wp.vec3i(*lay.lo),
                              wp.vec3i(*coarse.shape)])
        self._smooth(x, b, level, POST_SMOOTH, reverse=True)

    # --- internals -------------------------------------------------------------------------
    def _geometry(self, level: int):
        lay = self.layouts[level]
        return wp.vec3i(*lay.ghost()[0]), wp.vec3i(*lay.lo), wp.vec3i(*lay.shape)

    def _smooth(self, x, b, level: int, sweeps: int, reverse: bool) -> None:
        lay = self.layouts[level]
        colors = (1, 0) if reverse else (0, 1)
        for _ in range(sweeps):
            for color in colors:
                self.halos[level].exchange(x, HALO_TAG + level)
                if not lay.empty:
                    wp.launch(block_red_black_kernel, dim=lay.block_shape, device=self.device,
                              inputs=[x, b, *self.coeffs[level], color, *self._geometry(level)])

    def _gathered_solve(self, x, b, level: int) -> None:
        """Gather ``b`` of ``level`` onto rank 0, one one-rank V-cycle from zero there,
        scatter the result back into the blocks of ``x``."""
        lay = self.layouts[level]
        part = read_region(b, lay.block_region()) if not lay.empty else None
        parts = self.comm.gather(part, root=0)
        pieces = None
        if self.comm.Get_rank() == 0:
            whole = np.zeros(tuple(int(v) for v in lay.shape) + (3,), dtype=np.float32)
            for (lo, hi), p in zip(lay.blocks, parts):
                if p is not None:
                    whole[region(lo, hi, (0, 0, 0))] = p
            bw = wp.array(whole, dtype=wp.vec3, device=self.device)
            xw = wp.zeros(bw.shape, dtype=wp.vec3, device=self.device)
            self._serial.vcycle(xw, bw)
            xs = xw.numpy()
            pieces = [xs[region(lo, hi, (0, 0, 0))] if np.all(hi > lo) else None
                      for lo, hi in lay.blocks]
        mine = self.comm.scatter(pieces, root=0)
        if mine is not None:
            write_region(x, lay.block_region(), mine)

    def _sum_squares(self, a) -> np.ndarray:
        lay = self.layouts[0]
        self._acc.zero_()
        if not lay.empty:
            wp.launch(block_sum_squares_kernel, dim=lay.block_shape, device=self.device,
                      inputs=[a, wp.vec3i(*lay.ghost()[0]), wp.vec3i(*lay.lo), self._acc])
        return self._reduce()

    def _reduce(self) -> np.ndarray:
        local = self._acc.numpy().astype(np.float64)
        total = np.empty_like(local)
        self.comm.Allreduce(local, total, op=mpi().SUM)
        return total


def coarse_ghost(lo, hi, halve, nc):
    """A coarse level's ghosted box for fine block ``[lo, hi)``: its coarse block and one
    layer around it, and every coarse cell the fine block's prolongation interpolates from
    (a one-point fine block may own no coarse cell but still read two)."""
    if not np.all(hi > lo):
        return lo // 2, lo // 2
    glo = np.where(halve, lo // 2 - 1, lo - 1)
    ghi = np.where(halve, (hi - 1) // 2 + 2, hi + 1)
    return np.maximum(glo, 0), np.minimum(ghi, nc)


# --- device functions and kernels ----------------------------------------------------------------
@wp.func
def global_neighbours(x: wp.array3d(dtype=wp.vec3), i: int, j: int, k: int, g: wp.vec3i,
                      n: wp.vec3i, cx: wp.vec3, cy: wp.vec3, cz: wp.vec3):
    """``stencil.neighbours`` at local ``(i, j, k)`` = global ``g`` of a grid of ``n``
    points: the box faces are the global ones, neighbours read from the ghosted array."""
    off = wp.vec3(0.0)
    diag = wp.vec3(1.0, 1.0, 1.0)
    if g[0] > 0:
        off += wp.cw_mul(cx, x[i - 1, j, k])
        diag += cx
    if g[0] < n[0] - 1:
        off += wp.cw_mul(cx, x[i + 1, j, k])
        diag += cx
    if g[1] > 0:
        off += wp.cw_mul(cy, x[i, j - 1, k])
        diag += cy
    if g[1] < n[1] - 1:
        off += wp.cw_mul(cy, x[i, j + 1, k])
        diag += cy
    if g[2] > 0:
        off += wp.cw_mul(cz, x[i, j, k - 1])
        diag += cz
    if g[2] < n[2] - 1:
        off += wp.cw_mul(cz, x[i, j, k + 1])
        diag += cz
    return off, diag


@wp.kernel
def block_red_black_kernel(x: wp.array3d(dtype=wp.vec3), b: wp.array3d(dtype=wp.vec3),
                           cx: wp.vec3, cy: wp.vec3, cz: wp.vec3, color: int, off: wp.vec3i,
                           blo: wp.vec3i, n: wp.vec3i):
    """Gauss–Seidel update of the block's points with global ``(i + j + k) % 2 == color``;
    ``wp.tid()`` is the point relative to the block's first ``blo``."""
    ti, tj, tk = wp.tid()
    g = wp.vec3i(ti + blo[0], tj + blo[1], tk + blo[2])
    if (g[0] + g[1] + g[2]) % 2 != color:
        return
    i = g[0] - off[0]
    j = g[1] - off[1]
    k = g[2] - off[2]
    o, diag = global_neighbours(x, i, j, k, g, n, cx, cy, cz)
    x[i, j, k] = wp.cw_div(b[i, j, k] + o, diag)


@wp.kernel
def block_residual_kernel(x: wp.array3d(dtype=wp.vec3), b: wp.array3d(dtype=wp.vec3),
                          r: wp.array3d(dtype=wp.vec3), cx: wp.vec3, cy: wp.vec3, cz: wp.vec3,
                          off: wp.vec3i, blo: wp.vec3i, n: wp.vec3i):
    """``r = b - A x`` at block point ``wp.tid()``."""
    ti, tj, tk = wp.tid()
    g = wp.vec3i(ti + blo[0], tj + blo[1], tk + blo[2])
    i = g[0] - off[0]
    j = g[1] - off[1]
    k = g[2] - off[2]
    o, diag = global_neighbours(x, i, j, k, g, n, cx, cy, cz)
    r[i, j, k] = b[i, j, k] - wp.cw_mul(diag, x[i, j, k]) + o


@wp.kernel
def block_residual_norm_kernel(x: wp.array3d(dtype=wp.vec3), b: wp.array3d(dtype=wp.vec3),
                               cx: wp.vec3, cy: wp.vec3, cz: wp.vec3, off: wp.vec3i,
                               blo: wp.vec3i, n: wp.vec3i, acc: wp.array(dtype=wp.float64)):
    """Add ``|b - A x|²`` per channel at block point ``wp.tid()`` to ``acc``."""
    ti, tj, tk = wp.tid()
    g = wp.vec3i(ti + blo[0], tj + blo[1], tk + blo[2])
    i = g[0] - off[0]
    j = g[1] - off[1]
    k = g[2] - off[2]
    o, diag = global_neighbours(x, i, j, k, g, n, cx, cy, cz)
    r = b[i, j, k] - wp.cw_mul(diag, x[i, j, k]) + o
    wp.atomic_add(acc, 0, wp.float64(r[0] * r[0]))
    wp.atomic_add(acc, 1, wp.float64(r[1] * r[1]))
    wp.atomic_add(acc, 2, wp.float64(r[2] * r[2]))


@wp.kernel
def block_sum_squares_kernel(a: wp.array3d(dtype=wp.vec3), off: wp.vec3i, blo: wp.vec3i,
                             acc: wp.array(dtype=wp.float64)):
    """Add ``a²`` per channel at block point ``wp.tid()`` to ``acc``."""
    ti, tj, tk = wp.tid()
    v = a[ti + blo[0] - off[0], tj + blo[1] - off[1], tk + blo[2] - off[2]]
    wp.atomic_add(acc, 0, wp.float64(v[0] * v[0]))
    wp.atomic_add(acc, 1, wp.float64(v[1] * v[1]))
    wp.atomic_add(acc, 2, wp.float64(v[2] * v[2]))


@wp.kernel
def block_restrict_kernel(r: wp.array3d(dtype=wp.vec3), bc: wp.array3d(dtype=wp.vec3),
                          ratio: wp.vec3i, off_f: wp.vec3i, off_c: wp.vec3i, blo_c: wp.vec3i,
                          n_f: wp.vec3i):
    """Coarse right-hand side at coarse block cell ``wp.tid()``: the mean residual of its
    existing children (``multigrid.children_mean`` at global indices)."""
    ti, tj, tk = wp.tid()
    ci = ti + blo_c[0]
    cj = tj + blo_c[1]
    ck = tk + blo_c[2]
    s = wp.vec3(0.0)
    count = float(0.0)  # noqa: UP018 (a warp variable the loop may change)
    for child in range(8):
        u = child >> 2
        v = (child >> 1) & 1
        w = child & 1
        i = ci * ratio[0] + u
        j = cj * ratio[1] + v
        k = ck * ratio[2] + w
        if u < ratio[0] and v < ratio[1] and w < ratio[2] and i < n_f[0] and j < n_f[1] and k < n_f[2]:
            s += r[i - off_f[0], j - off_f[1], k - off_f[2]]
            count += 1.0
    bc[ci - off_c[0], cj - off_c[1], ck - off_c[2]] = s / count


@wp.kernel
def block_prolong_add_kernel(xc: wp.array3d(dtype=wp.vec3), x: wp.array3d(dtype=wp.vec3),
                             ratio: wp.vec3i, off_f: wp.vec3i, off_c: wp.vec3i, blo: wp.vec3i,
                             n_c: wp.vec3i):
    """``multigrid.prolong_add_kernel`` at fine block point ``wp.tid()``, global indices,
    the coarse values read from the coarse level's ghosted array."""
    ti, tj, tk = wp.tid()
    gi = ti + blo[0]
    gj = tj + blo[1]
    gk = tk + blo[2]
    u = coarse_coordinate(gi, ratio[0], n_c[0])
    v = coarse_coordinate(gj, ratio[1], n_c[1])
    w = coarse_coordinate(gk, ratio[2], n_c[2])
    i0 = wp.min(int(u), n_c[0] - 1)
    j0 = wp.min(int(v), n_c[1] - 1)
    k0 = wp.min(int(w), n_c[2] - 1)
    i1 = wp.min(i0 + 1, n_c[0] - 1)
    j1 = wp.min(j0 + 1, n_c[1] - 1)
    k1 = wp.min(k0 + 1, n_c[2] - 1)
    fu = u - float(i0)
    fv = v - float(j0)
    fw = w - float(k0)
    i0 -= off_c[0]
    i1 -= off_c[0]
    j0 -= off_c[1]
    j1 -= off_c[1]
    k0 -= off_c[2]
    k1 -= off_c[2]
    c00 = wp.lerp(xc[i0, j0, k0], xc[i1, j0, k0], fu)
    c10 = wp.lerp(xc[i0, j1, k0], xc[i1, j1, k0], fu)
    c01 = wp.lerp(xc[i0, j0, k1], xc[i1, j0, k1], fu)
    c11 = wp.lerp(xc[i0, j1, k1], xc[i1, j1, k1], fu)
    i = gi - off_f[0]
    j = gj - off_f[1]
    k = gk - off_f[2]
    x[i, j, k] = x[i, j, k] + wp.lerp(wp.lerp(c00, c10, fv), wp.lerp(c01, c11, fv), fw)
